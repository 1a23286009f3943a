"""Angle wrapping and image-angle conventions: the one home for them in pencilcal.

Conventions
-----------
- Angles are radians in code and degrees only in files and on the command line.
- An *image angle* is ``atan2(dv, du)`` with u to the right and v down (OpenCV pixel axes),
  so a positive angle turns from +u towards +v, i.e. clockwise as seen on screen and
  counter-clockwise about the camera's +z axis (forward).
- A *direction* (an oriented spoke, vertex -> tip) has period 2*pi; a *line* (unoriented)
  has period pi. `wrap_angle` and `wrap_line` map differences into (-pi, pi] and
  (-pi/2, pi/2] respectively; every residual in pencilcal goes through one of them.

Example
-------
>>> import numpy as np
>>> float(wrap_angle(np.radians(350.0)))          # doctest: +ELLIPSIS
-0.174532925...
>>> round(float(np.degrees(wrap_line(np.radians(170.0)))), 9)
-10.0
"""
from __future__ import annotations

import numpy as np

__all__ = [
    "wrap_angle",
    "wrap_line",
    "angle_diff",
    "line_diff",
    "segment_angle",
    "circular_mean",
]


def wrap_angle(angle):
    """Wrap directions (period 2*pi) into (-pi, pi].

    angle: (...) radians. Returns the same shape.
    """
    # remainder(., 2 pi) lies in [0, 2 pi), so pi - remainder(pi - a) lies in (-pi, pi]
    # without a branch (this sits in every estimator's inner loop)
    return np.pi - np.remainder(np.pi - np.asarray(angle, dtype=float), 2.0 * np.pi)


def wrap_line(angle):
    """Wrap line angles (period pi) into (-pi/2, pi/2].

    angle: (...) radians. Returns the same shape.
    """
    return np.pi / 2.0 - np.remainder(np.pi / 2.0 - np.asarray(angle, dtype=float), np.pi)


def angle_diff(a, b):
    """Signed difference a - b of directions, wrapped into (-pi, pi]. Broadcasts."""
    return wrap_angle(np.asarray(a, dtype=float) - np.asarray(b, dtype=float))


def line_diff(a, b):
    """Signed difference a - b of line angles (period pi), wrapped into (-pi/2, pi/2]."""
    return wrap_line(np.asarray(a, dtype=float) - np.asarray(b, dtype=float))


def segment_angle(segments):
    """Image angle of segments from their first to their second end point.

    segments: (..., 4) as [x1, y1, x2, y2]. Returns (...) radians, atan2(dv, du).
    """
    s = np.asarray(segments, dtype=float)
    return np.arctan2(s[..., 3] - s[..., 1], s[..., 2] - s[..., 0])


def circular_mean(angle, weights=None, period=2.0 * np.pi, axis=-1):
    """Weighted circular mean of angles with the given period (2*pi or pi).

    angle: (..., N); weights: broadcastable to angle. Returns (...).
    """
    a = np.asarray(angle, dtype=float) * (2.0 * np.pi / period)
    w = np.ones_like(a) if weights is None else np.broadcast_to(weights, a.shape)
    c = np.sum(w * np.cos(a), axis=axis)
    s = np.sum(w * np.sin(a), axis=axis)
    return np.arctan2(s, c) * (period / (2.0 * np.pi))
