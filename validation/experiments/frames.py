"""The frames an experiment can use: the exact model's labelled lines and a reference pose,
read from a validation dict (`load_validation`) into `Frame` records.

Example
-------
>>> import numpy as np
>>> from pencilcal.validation.experiments.synthetic import synthetic_validation
>>> frames, skipped = usable_frames(synthetic_validation([0.0, 20.0], sigma_deg=0.1))
>>> len(frames), skipped, frames[1].a.shape, round(float(np.degrees(frames[1].tilt_ref)), 6)
(2, [], (8,), 20.0)
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from pencilcal.toolkit.errors import EstimationError
from pencilcal.toolkit.geometry.frames import angle_between

__all__ = ["Frame", "usable_frames", "frames_or_fail", "sigma_line"]


@dataclass
class Frame:
    """One frame's measured lines and reference pose, as the experiments use them.

    index, image: position and name in the validation file.
    a, sigma: (N,) measured image angles and their sd [rad], normalised coordinates.
    spoke: (N,) int spoke labels; th: (N,) their 3D angles [rad] in the target frame.
    x: (2,) measured vertex (normalised); vertex_cov: (2, 2) or None.
    x_ref: (2,) the vertex's image at the reference pose (x when the pencil has no vertex).
    vertex_source: "reference" or "measured" (which one x_ref is).
    R_ref, t_ref: reference pose; tilt_ref: reference tilt [rad] (the file's value).
    orient: the exact model's orientation record; crlb: the file's bound record.
    reference_sigma_deg: the PnP reference's normal sd [deg] (None for truth).
    """

    index: int
    image: str
    a: np.ndarray
    sigma: np.ndarray
    spoke: np.ndarray
    th: np.ndarray
    x: np.ndarray
    vertex_cov: np.ndarray | None
    x_ref: np.ndarray
    vertex_source: str
    R_ref: np.ndarray
    t_ref: np.ndarray | None
    tilt_ref: float
    orient: dict = field(default_factory=dict)
    crlb: dict | None = None
    reference_sigma_deg: float | None = None


def _vertex_image(R, t, vertex):
    if vertex is None or t is None:
        return None
    P = R @ np.array([vertex[0], vertex[1], 0.0]) + t
    if not P[2] > 0:
        return None
    return P[:2] / P[2]


def usable_frames(v):
    """Frames with the exact model's lines and a reference pose.

    Returns (frames: list of Frame, skipped: list of {image, reason}).
    """
    th_all = np.radians(np.asarray(v["pencil"]["angles_deg"], float))
    vertex = v["pencil"].get("vertex")
    out, skipped = [], []
    for i, f in enumerate(v["frames"]):
        if not isinstance(f, dict):
            skipped.append({"image": str(i), "reason": "not a frame record"})
            continue
        name = str(f.get("image", i))
        ex = (f.get("orient") or {}).get("exact") or {}
        if not ex.get("ok"):
            skipped.append({"image": name, "reason": ex.get("error") or f.get("error") or "no exact-model estimate"})
            continue
        ln = ex.get("lines")
        if not isinstance(ln, dict):
            skipped.append({"image": name, "reason": "no orient.exact.lines (validate with --models including exact)"})
            continue
        if ex.get("labels_ambiguous"):
            skipped.append({"image": name, "reason": "spoke labels ambiguous (another labelling fits as well: the fan "
                                                      "shifted by a spoke when no end spoke is seen, or a spurious line "
                                                      "on another labelling's prediction), so the lines' 3D angles are "
                                                      "unknown"})
            continue
        if f.get("R_ref") is None:
            skipped.append({"image": name, "reason": f.get("error") or "no reference pose"})
            continue
        try:
            a = np.asarray(ln["angle"], float)
            s = np.asarray(ln["sigma"], float)
            k = np.asarray(ln["spoke"], int)
            x = np.asarray(ln["vertex"], float).reshape(2)
            R = np.asarray(f["R_ref"], float).reshape(3, 3)
            t = None if f.get("t_ref") is None else np.asarray(f["t_ref"], float).reshape(3)
            cov = None if ln.get("vertex_cov") is None else np.asarray(ln["vertex_cov"], float).reshape(2, 2)
        except (KeyError, TypeError, ValueError) as e:
            skipped.append({"image": name, "reason": f"malformed lines or reference ({type(e).__name__})"})
            continue
        if not (a.shape == s.shape == k.shape and a.ndim == 1 and np.all((k >= 0) & (k < th_all.size))):
            skipped.append({"image": name, "reason": "malformed lines (angle, sigma, spoke differ or bad labels)"})
            continue
        xr = _vertex_image(R, t, vertex)
        src = "reference" if xr is not None else "measured"
        xr = x if xr is None else xr
        tilt = f.get("reference_tilt_deg")
        if tilt is None:
            tilt = math.degrees(float(angle_between(R[:, 2], np.r_[xr, 1.0])))
        ref_sd = None
        best = f.get("pnp_best")
        if f.get("reference") == "pnp" and best and isinstance(f.get("pnp"), dict):
            ref_sd = (f["pnp"].get(best) or {}).get("normal_sigma_deg")
        out.append(Frame(i, name, a, s, k, th_all[k], x, cov, xr, src, R, t, math.radians(float(tilt)), ex,
                         f.get("crlb"), ref_sd))
    return out, skipped



def frames_or_fail(v):
    """`usable_frames` of the validation dict `v`; EstimationError (with the first frame's
    reason) when there is none."""
    frames, skipped = usable_frames(v)
    if not frames:
        why = skipped[0]["reason"] if skipped else "the file has no frames"
        raise EstimationError(f"no frame has both the exact model's lines and a reference pose (e.g. {why})")
    return frames, skipped


def sigma_line(frames):
    """Median line sd [rad] over every used line of every frame."""
    return float(np.median(np.concatenate([f.sigma for f in frames])))
