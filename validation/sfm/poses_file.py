"""poses.json of `pencilcal sfm`: the *camera* poses of a reconstruction (reader and writer).

The file: the reconstruction's summary (`SfmResult.summary`: counts, matching, the model
and database paths relative to the file, the camera, timings, warnings), ``convention``
(`CONVENTION`) and ``frames``, one `SfmFrame.to_dict` per input frame: ``image``,
``index``, ``registered``, ``error``, ``R_cam_from_world`` (3, 3), ``t_cam_from_world``
(3,), ``camera_center`` (3,) (world frame, reconstruction units; null when not
registered), ``colmap_name``, ``num_features``, ``num_points3D``. The world frame and
its scale are the reconstruction's own (arbitrary).

Not to be confused with the poses.json of `pencilcal pnp` (`pencilcal.validation.pnp.poses_file`:
the *board*'s pose in each camera, ``R_cam_from_target`` and ``t_cam_from_target`` in the
board's length unit, with covariance), which has its own reader, `read_board_poses`.

Example
-------
>>> d = read_sfm_poses("sfm/poses.json")                 # doctest: +SKIP
>>> [f.image for f in d["frames"] if f.registered][:2]   # doctest: +SKIP
['000.png', '001.png']
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from pencilcal.toolkit.errors import InputError
from pencilcal.toolkit.io.files import load_frames, write_json

from .result import SfmFrame

__all__ = ["CONVENTION", "write_sfm_poses", "read_sfm_poses"]

# the keys every frame of the file has
_POSE_KEYS = ("image", "registered", "R_cam_from_world", "t_cam_from_world", "camera_center")
#: One-line statement of the pose convention, written into poses.json.
CONVENTION = ("p_cam = R_cam_from_world p_world + t_cam_from_world (OpenCV camera frame: x right, y down, "
              "z forward); camera_center = -R^T t in the world frame; the world frame and its scale are "
              "the reconstruction's own (arbitrary; validation/align.py maps it onto the board frame); "
              "camera intrinsics held fixed at the input camera")


def write_sfm_poses(path, result, force=False, **meta):
    """Write ``poses.json`` for a reconstruction (`SfmResult`), atomically.

    ``{**meta, **result.summary(...), "convention": ..., "frames": [...]}``; paths are
    relative to the file's folder. Each frame: ``image``, ``index``, ``registered``,
    ``error``, ``R_cam_from_world`` (3x3), ``t_cam_from_world``, ``camera_center``
    (world frame, reconstruction units; null when not registered), ``colmap_name``,
    ``num_features``, ``num_points3D``.
    """
    folder = Path(path).parent
    out = dict(meta)
    out.update(result.summary(relative_to=folder if str(folder) else "."))
    out["convention"] = CONVENTION
    out["frames"] = [f.to_dict() for f in result.frames]
    write_json(path, out, force=force)


def read_sfm_poses(path):
    """Read a ``poses.json`` written by `write_sfm_poses` (`pencilcal sfm`).

    Returns the file's object with ``frames`` a list of `SfmFrame` (arrays as ndarrays).
    InputError with a one-line reason for anything malformed (the module docstring has
    an example).
    """
    data, frames = load_frames(path, "sfm poses file", _POSE_KEYS)
    out = []
    for i, (f, where) in enumerate(frames):
        if not isinstance(f["registered"], bool):
            raise InputError(f"{where}: 'registered' must be true or false")
        arrays = {}
        for k, shape in (("R_cam_from_world", (3, 3)), ("t_cam_from_world", (3,)), ("camera_center", (3,))):
            v = f.get(k)
            if v is None:
                if f["registered"]:
                    raise InputError(f"{where}: a registered frame needs '{k}'")
                arrays[k] = None
                continue
            try:
                a = np.array(v, dtype=float)
            except (TypeError, ValueError):
                raise InputError(f"{where}: '{k}' must be numbers") from None
            if a.shape != shape or not np.all(np.isfinite(a)):
                raise InputError(f"{where}: '{k}' must be {'x'.join(map(str, shape))} finite numbers")
            arrays[k] = a
        out.append(SfmFrame(str(f["image"]), int(f.get("index", i)), f["registered"], colmap_name=f.get("colmap_name"),
                            num_features=int(f.get("num_features") or 0),
                            num_points3D=int(f.get("num_points3D") or 0), error=f.get("error"), **arrays))
    res = dict(data)
    res["frames"] = out
    return res
