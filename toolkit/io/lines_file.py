"""The lines file (``lines.json``): line segments per frame, in raw (distorted) pixels.

Format (INTERFACES.md)::

    {"frames": [{"image": "000.png", "ok": true,
                 "segments": [[x1, y1, x2, y2], ...],
                 "angle_sigma_deg": [...],            # optional, one per segment
                 "offset_sigma_px": [...],            # optional, one per segment
                 "shafts": [{"midline": [x1, y1, x2, y2], "width_px": 84.0,
                             "angle_sigma_deg": 0.2}]}]}

`segments` is all a reader needs. Pixel (0, 0) is the centre of the top-left pixel.

Example
-------
>>> import tempfile, os
>>> p = os.path.join(tempfile.mkdtemp(), "lines.json")
>>> write_lines(p, [{"image": "a.png", "ok": True, "segments": [[0, 0, 10, 5]]}])
>>> read_lines(p)[0]["segments"].tolist()
[[0.0, 0.0, 10.0, 5.0]]
"""
from __future__ import annotations

import numpy as np

from pencilcal.toolkit.errors import InputError
from pencilcal.toolkit.io.files import load_structured, write_json

__all__ = ["read_lines", "write_lines", "frame_record"]


def _segments(value, where):
    if value is None:
        return np.zeros((0, 4))
    if not isinstance(value, (list, tuple)):
        raise InputError(f"{where}: 'segments' must be a list of [x1, y1, x2, y2]")
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise InputError(f"{where}: 'segments' must contain only numbers") from None
    if arr.size == 0:
        return np.zeros((0, 4))
    if arr.ndim != 2 or arr.shape[1] != 4:
        raise InputError(f"{where}: each segment must be [x1, y1, x2, y2], got shape {arr.shape}")
    return arr


def _per_segment(value, key, n, where):
    """One number per segment for `key` (an optional per-segment list of the format)."""
    try:
        arr = np.asarray(value, float).reshape(-1)
    except (TypeError, ValueError):
        raise InputError(f"{where}: '{key}' must be numbers") from None
    if arr.size != n:
        raise InputError(f"{where}: '{key}' has {arr.size} values for {n} segments")
    return arr


def frame_record(d, where):
    """Validate one frame of a lines file; returns a dict with numpy `segments` (M, 4)."""
    if not isinstance(d, dict):
        raise InputError(f"{where}: each frame must be an object with 'segments'")
    rec = dict(d)
    rec["image"] = str(d.get("image", where))
    rec["ok"] = bool(d.get("ok", True))
    rec["segments"] = _segments(d.get("segments"), where)
    for key in ("angle_sigma_deg", "offset_sigma_px"):
        if d.get(key) is not None:
            rec[key] = _per_segment(d[key], key, rec["segments"].shape[0], where)
    shafts = d.get("shafts")
    if shafts is not None:
        if not isinstance(shafts, list):
            raise InputError(f"{where}: 'shafts' must be a list")
        out = []
        for j, sh in enumerate(shafts):
            if not isinstance(sh, dict) or "midline" not in sh:
                raise InputError(f"{where}: shaft {j} needs a 'midline' [x1, y1, x2, y2]")
            mid = _segments([sh["midline"]], f"{where} shaft {j}")[0]
            out.append({**sh, "midline": mid})
        rec["shafts"] = out
    return rec


def read_lines(path):
    """Read a lines file. Returns a list of frame dicts with `segments` as (M, 4) arrays.

    Raises InputError naming the file when the structure is wrong. Non-finite coordinates
    are kept (the estimators report them per frame).
    """
    data = load_structured(path, "lines file")
    if isinstance(data, dict) and "frames" in data:
        frames = data["frames"]
    else:
        raise InputError(f"{path}: a lines file is an object with a 'frames' list")
    if not isinstance(frames, list):
        raise InputError(f"{path}: 'frames' must be a list")
    return [frame_record(f, f"{path}: frame {i}") for i, f in enumerate(frames)]


def write_lines(path, frames, force=False, meta=None):
    """Write a lines file atomically. frames: dicts with image, ok, segments (M, 4), ..."""
    out = {"frames": list(frames)}
    if meta:
        out = {**meta, **out}
    write_json(path, out, force=force)
