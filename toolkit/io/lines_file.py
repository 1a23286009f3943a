"""The lines file (``lines.json``): line segments per frame, in raw (distorted) pixels.

Format (docs/formats.md)::

    {"valid_region": {"circle": [cx, cy, r]},        # or {"polygon": [[x, y], ...]}
     "frames": [{"image": "000.png", "ok": true,
                 "segments": [[x1, y1, x2, y2], ...],
                 "angle_sigma_deg": [...],            # optional, one per segment
                 "offset_sigma_px": [...],            # optional, one per segment
                 "width_px": [...],                   # optional, bars: one per segment
                 "circle_points": [[x, y], ...],      # optional, radial targets
                 "angle_sigma_error_deg": [...],      # optional, a star's edges: one per segment
                 "vertex_sd_px": 0.4,                 # optional, radial targets: one number
                 "shafts": [{"midline": [x1, y1, x2, y2], "width_px": 84.0,
                             "angle_sigma_deg": 0.2}]}]}

`segments` is all a reader needs. Pixel (0, 0) is the centre of the top-left pixel. One
frame is a `LineFrame`; its `to_dict` is the frame's record. `valid_region` (written once,
for the whole sequence) is the region the lines were looked for in
(`toolkit.detect.region.ValidRegion.to_dict`); `pencilcal ... --mask lines.json` reads it.

Example
-------
>>> import tempfile, os
>>> p = os.path.join(tempfile.mkdtemp(), "lines.json")
>>> write_lines(p, [{"image": "a.png", "ok": True, "segments": [[0, 0, 10, 5]]}])
>>> read_lines(p)[0]["segments"].tolist()
[[0.0, 0.0, 10.0, 5.0]]
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from pencilcal.toolkit.errors import InputError
from pencilcal.toolkit.io.files import is_number, load_structured, write_json

__all__ = ["LineFrame", "read_lines", "write_lines", "frame_record"]


def _all_numbers(value):
    """True when `value` (a number or nested lists of them) holds only numbers; linear time."""
    if isinstance(value, np.ndarray):
        return value.dtype.kind in "iuf"
    if isinstance(value, (list, tuple)):
        return all(_all_numbers(v) if isinstance(v, (list, tuple, np.ndarray)) else is_number(v) for v in value)
    return is_number(value)


def _segments(value, where, key="segments", finite=False):
    """(M, 4) [px] from a list of [x1, y1, x2, y2]; numbers only (a string "12" is refused,
    not converted). Non-finite coordinates are kept unless `finite`."""
    if value is None:
        return np.zeros((0, 4))
    if not isinstance(value, (list, tuple, np.ndarray)):
        raise InputError(f"{where}: '{key}' must be a list of [x1, y1, x2, y2]")
    if not _all_numbers(value):
        raise InputError(f"{where}: '{key}' must contain only numbers")
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise InputError(f"{where}: '{key}' must be a list of [x1, y1, x2, y2] of numbers") from None
    if arr.size == 0:
        return np.zeros((0, 4))
    if arr.ndim != 2 or arr.shape[1] != 4:
        raise InputError(f"{where}: each of '{key}' must be [x1, y1, x2, y2], got shape {arr.shape}")
    if finite and not np.all(np.isfinite(arr)):
        raise InputError(f"{where}: '{key}' must be finite numbers (no NaN or inf)")
    return arr


def _per_segment(value, key, n, where):
    """One finite positive number per segment for `key` (an optional per-segment list of the
    format: a sd or a width), (n,)."""
    if not isinstance(value, (list, tuple, np.ndarray)) or not _all_numbers(value):
        raise InputError(f"{where}: '{key}' must be a list of numbers, one per segment")
    arr = np.asarray(value, float).reshape(-1)
    if arr.size != n:
        raise InputError(f"{where}: '{key}' has {arr.size} values for {n} segments")
    bad = ~(np.isfinite(arr) & (arr > 0))
    if np.any(bad):
        i = int(np.argmax(bad))
        raise InputError(f"{where}: '{key}' must be finite and > 0, got {arr[i]!r} for segment {i}")
    return arr


def _points(value, where, key="circle_points"):
    """(K, 2) [px] finite points from a list of [x, y]."""
    if not isinstance(value, (list, tuple, np.ndarray)) or not _all_numbers(value):
        raise InputError(f"{where}: '{key}' must be a list of [x, y] numbers")
    arr = np.asarray(value, float)
    if arr.size == 0:
        return np.zeros((0, 2))
    if arr.ndim != 2 or arr.shape[1] != 2 or not np.all(np.isfinite(arr)):
        raise InputError(f"{where}: each of '{key}' must be [x, y], finite numbers")
    return arr


def _positive(value, key, where):
    """One finite number > 0 for `key` (a shaft's sd or width)."""
    if not is_number(value) or not (np.isfinite(value) and value > 0):
        raise InputError(f"{where}: '{key}' must be a finite number > 0, got {value!r}")
    return float(value)


# a shaft's numeric keys (detect.shafts.Shaft.to_dict): those > 0, and the other numbers
_SHAFT_POSITIVE = ("width_px", "angle_sigma_deg", "offset_sigma_px", "axis_distance", "axis_direction_sigma_deg",
                   "axis_distance_sigma", "diameter")
_SHAFT_NUMBERS = ("convergence_deg", "score")
# its arrays of finite numbers (edge_cov of the detector, the 3-D axis of lines --shaft-diameter)
_SHAFT_ARRAYS = {"edge_cov": (2, 2, 2), "axis_point": (3,), "axis_direction": (3,), "axis_cov": (4, 4)}


def _shaft_array(value, key, shape, where):
    """(shape) finite float array of a shaft's `key`; covariances symmetric with a positive
    diagonal."""
    if not _all_numbers(value):
        raise InputError(f"{where}: '{key}' must contain only numbers")
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        arr = None
    if arr is None or arr.shape != shape:
        raise InputError(f"{where}: '{key}' must be {'x'.join(map(str, shape))} numbers")
    if not np.all(np.isfinite(arr)):
        raise InputError(f"{where}: '{key}' must be finite")
    if key.endswith("_cov"):
        diag = np.diagonal(arr, axis1=-2, axis2=-1)
        if not (np.all(diag > 0) and np.allclose(arr, np.swapaxes(arr, -1, -2), rtol=1e-6, atol=0.0)):
            raise InputError(f"{where}: '{key}' must be symmetric with a positive diagonal")
    return arr


def _shaft_record(sh, where):
    """Validate one shaft of a frame: midline (4,) [px] finite, its sds and width > 0, its
    edges (K, 4) [px] and other numbers finite. Returns the record with `midline` an array."""
    if not isinstance(sh, dict) or "midline" not in sh:
        raise InputError(f"{where}: needs a 'midline' [x1, y1, x2, y2]")
    mid = sh["midline"]
    if not isinstance(mid, (list, tuple, np.ndarray)):
        raise InputError(f"{where}: 'midline' must be [x1, y1, x2, y2]")
    out = {**sh, "midline": _segments([mid], where, "midline", finite=True)[0]}
    for key in _SHAFT_POSITIVE:
        if sh.get(key) is not None:
            out[key] = _positive(sh[key], key, where)
    for key in _SHAFT_NUMBERS:
        v = sh.get(key)
        if v is not None and not (is_number(v) and np.isfinite(v)):
            raise InputError(f"{where}: '{key}' must be a finite number, got {v!r}")
    v = sh.get("width_sd_px")  # the limb fit's own width sd (`band_width.band_width_sd`)
    if v is not None and not (is_number(v) and np.isfinite(v) and v >= 0):
        raise InputError(f"{where}: 'width_sd_px' must be a finite number >= 0, got {v!r}")
    if sh.get("edges") is not None:
        _segments(sh["edges"], where, "edges", finite=True)
    for key, shape in _SHAFT_ARRAYS.items():
        if sh.get(key) is not None:
            _shaft_array(sh[key], key, shape, where)
    return out


def frame_record(d, where):
    """Validate one frame of a lines file; returns a dict with numpy `segments` (M, 4).

    `where` names the file and frame in the InputError raised for a wrong field: `segments`
    must be numbers ([x1, y1, x2, y2] each; NaN/inf kept: the estimators drop such
    segments and say so), `angle_sigma_deg`, `offset_sigma_px`, `width_px`,
    `angle_sigma_error_deg` one finite number > 0 per segment, `vertex_sd_px` one finite
    number >= 0, `circle_points` finite [x, y] pairs, `ok` a boolean; each shaft
    as `_shaft_record` checks it.

    >>> frame_record({"segments": [[0, 0, 10, 0]], "angle_sigma_deg": ["0.1"]}, "l.json: frame 0")
    Traceback (most recent call last):
    ...
    pencilcal.toolkit.errors.InputError: l.json: frame 0: 'angle_sigma_deg' must be a list of numbers, one per segment
    """
    if not isinstance(d, dict):
        raise InputError(f"{where}: each frame must be an object with 'segments'")
    rec = dict(d)
    rec["image"] = str(d.get("image", where))
    ok = d.get("ok", True)
    if not isinstance(ok, (bool, np.bool_)):
        raise InputError(f"{where}: 'ok' must be true or false, got {ok!r}")
    rec["ok"] = bool(ok)
    rec["segments"] = _segments(d.get("segments"), where)
    for key in ("angle_sigma_deg", "offset_sigma_px", "width_px", "angle_sigma_error_deg"):
        if d.get(key) is not None:
            rec[key] = _per_segment(d[key], key, rec["segments"].shape[0], where)
    if d.get("circle_points") is not None:
        rec["circle_points"] = _points(d["circle_points"], where)
    if d.get("vertex_sd_px") is not None:
        v = d["vertex_sd_px"]
        if not is_number(v) or not np.isfinite(float(v)) or float(v) < 0:
            raise InputError(f"{where}: 'vertex_sd_px' must be one finite number >= 0, got {v!r}")
        rec["vertex_sd_px"] = float(v)
    shafts = d.get("shafts")
    if shafts is not None:
        if not isinstance(shafts, list):
            raise InputError(f"{where}: 'shafts' must be a list")
        rec["shafts"] = [_shaft_record(sh, f"{where} shaft {j}") for j, sh in enumerate(shafts)]
    return rec


_KNOWN = ("image", "ok", "error", "segments", "angle_sigma_deg", "offset_sigma_px", "width_px", "shafts",
          "circle_points")


@dataclass(frozen=True, eq=False)
class LineFrame:
    """One frame of a lines file: M line segments with their uncertainties.

    Attributes
    ----------
    image : str
        The frame's name.
    segments : (M, 4) [px]
        ``[x1, y1, x2, y2]`` in raw (distorted) pixels.
    ok : bool
        False for a frame that could not be read or processed (`error` says why).
    error : str or None
    angle_sigma_deg : (M,) [deg] or None
        sd of each segment's angle.
    offset_sigma_px : (M,) [px] or None
        sd of each segment's perpendicular position at its midpoint.
    width_px : (M,) [px] or None
        Width of each bar whose midline the segment is.
    shafts : list of dict or None
        Instrument shafts, each a record with at least ``midline`` (4,) [px].
    circle_points : (K, 2) [px] or None
        Edge points across rays from a radial target's vertex, some on the images of circles
        about it (`detect.radial`), raw pixels.
    extra : dict
        Any other keys of the record, kept as they are.

    Example
    -------
    >>> f = LineFrame("a.png", np.array([[0.0, 0.0, 10.0, 5.0]]), angle_sigma_deg=np.array([0.1]))
    >>> d = f.to_dict(); list(d)
    ['image', 'ok', 'error', 'segments', 'angle_sigma_deg']
    >>> LineFrame.from_dict(d).angle_sigma_deg.tolist()
    [0.1]
    """

    image: str
    segments: np.ndarray
    ok: bool = True
    error: str | None = None
    angle_sigma_deg: np.ndarray | None = None
    offset_sigma_px: np.ndarray | None = None
    width_px: np.ndarray | None = None
    shafts: list | None = None
    circle_points: np.ndarray | None = None
    extra: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        """The frame's record: image, ok, error, segments, then the optional keys that are
        set (angle_sigma_deg, offset_sigma_px, width_px, shafts, circle_points), then `extra`."""
        rec = {"image": self.image, "ok": self.ok, "error": self.error, "segments": self.segments}
        for key in ("angle_sigma_deg", "offset_sigma_px", "width_px", "shafts", "circle_points"):
            if getattr(self, key) is not None:
                rec[key] = getattr(self, key)
        rec.update(self.extra)
        return rec

    @classmethod
    def from_dict(cls, d, where="frame"):
        """The frame of a record `d` (checked as `frame_record` checks it; InputError names
        `where`)."""
        rec = frame_record(d, where)
        width = rec.get("width_px")
        return cls(image=rec["image"], segments=rec["segments"], ok=rec["ok"], error=rec.get("error"),
                   angle_sigma_deg=rec.get("angle_sigma_deg"), offset_sigma_px=rec.get("offset_sigma_px"),
                   width_px=width, shafts=rec.get("shafts"), circle_points=rec.get("circle_points"),
                   extra={k: v for k, v in rec.items() if k not in _KNOWN})


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


def write_lines(path, frames, force=False, meta=None, valid_region=None):
    """Write a lines file atomically. frames: dicts with image, ok, segments (M, 4), ...;
    meta: top-level keys written before them; valid_region: the sequence's region record
    (``{"circle": [cx, cy, r]}`` or ``{"polygon": [[x, y], ...]}`` [px]), written as
    ``valid_region`` when given."""
    out = {"frames": list(frames)}
    if valid_region is not None:
        out = {"valid_region": valid_region, **out}
    if meta:
        out = {**meta, **out}
    write_json(path, out, force=force)
