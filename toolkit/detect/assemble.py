"""The vertex of a pencil of detected segments, spurious segments rejected.

`assemble_pencil` undistorts the segments (lines, not images) and intersects them with
`pencil.vertex.intersect_lines` (robust: MSAC over pairs of lines, then the weighted
least-squares intersection of the inliers, with covariance). Segments are
``[x1, y1, x2, y2]`` [px]; the vertex is in undistorted pixels.

Example
-------
>>> import numpy as np
>>> v = np.array([300.0, 200.0])
>>> phi = np.radians([0.0, 40.0, 80.0, 120.0])
>>> d = np.stack([np.cos(phi), np.sin(phi)], -1)
>>> segs = np.concatenate([v + 50 * d, v + 150 * d], -1)
>>> segs = np.vstack([segs, [[0.0, 0.0, 100.0, 10.0]]])          # one spurious segment
>>> fit, inl = assemble_pencil(segs, np.radians(0.05))
>>> np.round(fit.vertex, 6).tolist(), inl.tolist()
([300.0, 200.0], [True, True, True, True, False])
"""
from __future__ import annotations

import numpy as np

from pencilcal.toolkit.detect.segments import Segments
from pencilcal.toolkit.detect.working import to_working
from pencilcal.toolkit.errors import EstimationError, InputError
from pencilcal.toolkit.pencil.vertex import intersect_lines

__all__ = ["assemble_pencil"]

_OFFSET_SIGMA_PX = 0.3  # default perpendicular sd of plain (M, 4) segments [px]


def assemble_pencil(segments, angle_sigma=None, camera=None, *, offset_sigma=None, min_length=8.0, **intersect_kw):
    """The vertex of a pencil of segments, spurious segments rejected.

    Parameters
    ----------
    segments : (M, 4) [px] or Segments
        Raw pixel segments, or a `Segments`/`Bars` result (then `angle_sigma` and
        `offset_sigma` default to its own and its undistorted segments are used).
    angle_sigma : scalar or (M,) [rad], optional
        Angle sd of each line; None: the end-point model of `intersect_lines`.
    camera : Camera, optional
        Lens model; None treats the pixels as undistorted.
    offset_sigma : scalar or (M,) [px], optional
        Perpendicular sd at each segment's centre; default 0.3 px for plain arrays.
    min_length : float
        Shorter (undistorted) segments are left out [px].
    **intersect_kw
        Passed to `vertex.intersect_lines` (inlier_confidence, max_pairs, seed, ...).

    Returns
    -------
    fit : vertex.VertexFit
        In undistorted pixels; ``camera.distort_pixels(fit.vertex)`` is the raw vertex.
    inliers : (M,) bool
        Segments that pass through the vertex (False for short or non-finite ones too).

    Raises
    ------
    EstimationError
        Fewer than two usable segments, parallel lines, no common point.

    Example
    -------
    See the module docstring.
    """
    if isinstance(segments, Segments):
        ideal = segments.ideal
        if angle_sigma is None:
            angle_sigma = segments.angle_sigma
        if offset_sigma is None:
            offset_sigma = segments.offset_sigma
    else:
        raw = np.asarray(segments, float)
        if raw.ndim != 2 or raw.shape[1] != 4:
            raise InputError(f"segments: expected shape (M, 4) [x1, y1, x2, y2], got {raw.shape}")
        ideal = to_working(camera, raw) if camera is not None else raw.copy()
    if offset_sigma is None:
        offset_sigma = _OFFSET_SIGMA_PX
    M = ideal.shape[0]
    L = np.hypot(ideal[:, 2] - ideal[:, 0], ideal[:, 3] - ideal[:, 1])
    usable = np.all(np.isfinite(ideal), -1) & (L >= min_length)
    idx = np.flatnonzero(usable)
    if idx.size < 2:
        raise EstimationError(f"vertex: needs at least two usable segments, got {idx.size} of {M}")

    def pick(v):
        if v is None:
            return None
        a = np.asarray(v, float)
        return a if a.ndim == 0 else np.broadcast_to(a, (M,))[idx]

    fit = intersect_lines(ideal[idx], angle_sigma=pick(angle_sigma), offset_sigma=pick(offset_sigma),
                          robust=True, **intersect_kw)
    inliers = np.zeros(M, bool)
    inliers[idx] = fit.inliers
    return fit, inliers
