"""poses.json of `pencilcal pnp`: the *board* poses, one record a frame (reader and writer).

Each frame: ``image``, the pose keys of `PoseResult.to_dict` (``ok``, ``method``,
``R_cam_from_target`` (3, 3), ``t_cam_from_target`` (3,) [board length unit], ``rvec``,
``tvec``, ``reproj_rms_px`` [px], ``corners``, ``cov`` (6, 6), ...; None when not ok), the
corner ``ids`` and, with ``--method all``, every method's record under ``methods``; the
file adds ``cov_convention`` (`COV_CONVENTION`) and the run's settings. The poses map the
*board* frame into each camera.

Not to be confused with the poses.json of `pencilcal sfm` (`pencilcal.validation.sfm.poses_file`:
``registered``, ``R_cam_from_world``, ``t_cam_from_world`` and ``camera_center`` in the
reconstruction's own arbitrary world frame and scale), which has its own reader,
`read_sfm_poses`.

Example
-------
>>> import os, tempfile
>>> p = os.path.join(tempfile.mkdtemp(), "poses.json")
>>> write_board_poses(p, [empty_frame_record("a.png", "no board")], camera="cam.yaml")
>>> d = read_board_poses(p)
>>> d["camera"], d["frames"][0]["ok"], d["frames"][0]["error"]
('cam.yaml', False, 'no board')
"""
from __future__ import annotations

from types import MappingProxyType

import numpy as np

from pencilcal.toolkit.errors import InputError
from pencilcal.toolkit.io.files import load_frames, write_json

from .result import DEFAULT_METHOD, PoseResult

__all__ = ["POSE_KEYS", "COV_CONVENTION", "frame_record", "empty_frame_record", "write_board_poses",
           "read_board_poses"]

#: The keys every poses.json frame has (None where the frame has no pose).
POSE_KEYS = ("image", "ok", "method", "R_cam_from_target", "t_cam_from_target", "rvec", "tvec",
             "reproj_rms_px", "corners", "cov")

#: One-line statement of the covariance convention, written into poses.json.
COV_CONVENTION = ("cov is 6x6 over (d_rot, d_t): R_true = expm(skew(d_rot)) @ R_cam_from_target "
                  "(rotation vector in rad about the camera axes, left perturbation), "
                  "t_true = t_cam_from_target + d_t (target length unit)")


def empty_frame_record(image, error, method=DEFAULT_METHOD, corners=0, ids=None):
    """A poses.json frame with no pose (no board found, undecodable image): ``ok`` false,
    `error`, ``refined`` false, ``lm_iterations`` 0 and every other key of
    `PoseResult.to_dict` None (``flipped`` too: no estimate ran)."""
    rec = {"image": str(image)}
    rec.update({k: None for k in PoseResult(ok=False, method=method).to_dict()})
    rec.update(ok=False, error=str(error), method=method, corners=int(corners), refined=False, lm_iterations=0)
    rec["ids"] = None if ids is None else np.asarray(ids, int).tolist()
    return rec


def frame_record(image, result, ids=None, methods=None):
    """One poses.json frame.

    Parameters
    ----------
    image : str
        Image (file) name.
    result : PoseResult
        The pose that represents the frame; its `PoseResult.to_dict` keys are at the frame
        level, so `POSE_KEYS` (image, ok, method, R_cam_from_target, t_cam_from_target,
        rvec, tvec, reproj_rms_px, corners, cov) are always there (None when not ok).
    ids : (K,) array_like of int, optional
        Corner ids of the correspondences, in the order of ``residuals_px``.
    methods : dict name -> PoseResult, optional
        With --method all: every method's result, written under ``"methods"`` (without the
        per-corner residuals); `result` is then normally ``methods[best_method(methods)]``.

    Returns
    -------
    dict
        ``{"image": image, **result.to_dict(), "ids": ids}`` and ``"methods"`` if given
        (numpy arrays inside; `write_board_poses` writes them).
    """
    rec = {"image": str(image)}
    rec.update(result.to_dict())
    rec["ids"] = None if ids is None else np.asarray(ids, int).tolist()
    if methods is not None:
        rec["methods"] = {m: r.to_dict(residuals=False) for m, r in methods.items()}
    return rec


def write_board_poses(path, frames, force=False, **meta):
    """Write poses.json atomically: ``{**meta, "cov_convention": ..., "frames": frames}``.

    frames: list of dicts from `frame_record` / `empty_frame_record`; meta: the run's
    settings (JSON-ready). Raises InputError if a frame lacks a `POSE_KEYS` key, or if
    `path` exists and not `force`.
    """
    for i, f in enumerate(frames):
        missing = [k for k in POSE_KEYS if k not in f]
        if missing:
            raise InputError(f"poses frame {i} lacks {missing}")
    out = dict(meta)
    out["cov_convention"] = COV_CONVENTION
    out["frames"] = list(frames)
    write_json(path, out, force=force)


# the shape of every array a frame record holds (besides residuals_px (K, 2) and ids (K,))
_ARRAY_SHAPES = MappingProxyType({
    "R_cam_from_target": (3, 3), "t_cam_from_target": (3,), "rvec": (3,), "tvec": (3,), "normal": (3,),
    "cov": (6, 6), "rotation_sigma_deg": (3,), "translation_sigma": (3,), "cov_total": (6, 6),
    "rotation_sigma_total_deg": (3,)})


def _frame_arrays(f, where):
    """A copy of the frame (or method) record `f` with its arrays as ndarrays, checked."""
    out = dict(f)
    for k, shape in _ARRAY_SHAPES.items():
        v = f.get(k)
        if v is None:
            continue
        try:
            a = np.array(v, dtype=float)
        except (TypeError, ValueError):
            raise InputError(f"{where}: '{k}' must be numbers") from None
        if a.shape != shape:
            raise InputError(f"{where}: '{k}' must have shape {shape}, got {a.shape}")
        out[k] = a
    if f.get("intrinsics_sensitivity") is not None:
        a = np.array(f["intrinsics_sensitivity"], dtype=float)
        if a.ndim != 2 or a.shape[0] != 6:
            raise InputError(f"{where}: 'intrinsics_sensitivity' must be 6 x P")
        out["intrinsics_sensitivity"] = a
    if f.get("residuals_px") is not None:
        a = np.array(f["residuals_px"], dtype=float)
        if a.ndim != 2 or a.shape[1] != 2:
            raise InputError(f"{where}: 'residuals_px' must be K x 2")
        out["residuals_px"] = a
    if f.get("ids") is not None:
        out["ids"] = np.array(f["ids"], dtype=int)
    return out


def read_board_poses(path):
    """Read a board poses.json (`pencilcal pnp`) with its pose arrays as numpy arrays.

    Returns the file's object with ``frames`` a list of dicts whose R_cam_from_target
    (3, 3), t_cam_from_target, rvec, tvec, normal (3,), cov (6, 6), residuals_px (K, 2)
    and ids (K,) are ndarrays (None where the file has null); the per-method records under
    ``methods`` likewise. InputError with a one-line reason for anything malformed: every
    frame needs the `POSE_KEYS`, and an ok frame a finite rotation and translation. (The
    module docstring has an example.)
    """
    data, frames = load_frames(path, "poses file", POSE_KEYS)
    out = []
    for f, where in frames:
        if not isinstance(f["ok"], bool):
            raise InputError(f"{where}: 'ok' must be true or false")
        g = _frame_arrays(f, where)
        if g["ok"]:
            for k in ("R_cam_from_target", "t_cam_from_target"):
                if g.get(k) is None or not np.all(np.isfinite(g[k])):
                    raise InputError(f"{where}: an ok frame needs a finite '{k}'")
        if isinstance(f.get("methods"), dict):
            g["methods"] = {m: _frame_arrays(r, f"{where}: method {m}") if isinstance(r, dict) else r
                            for m, r in f["methods"].items()}
        out.append(g)
    res = dict(data)
    res["frames"] = out
    return res

