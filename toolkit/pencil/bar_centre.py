"""A printed bar's centre line from its detected midline, once the plane is known.

A bar's midline (`detect.bars`) is the bisector of its two edges in the image. Under
perspective that is not the image of the printed centre line: along a cut across the bar,
the image of the centre is the harmonic conjugate of the plane's horizon with respect to
the two edges, ``w^2 / (4 V)`` from the bisector towards the horizon (w the width along
the cut, V the distance to the horizon along it, pixels). The shift changes along the
bar (with w and V), so it moves the midline and turns it a little; for 4 mm spokes seen
at 30-60 deg it is 0.01-0.04 px, several times the offset sigma of a low-noise midline,
and it pulls the vertex and the tilt the same way on every spoke.

`centre_lines` removes it once the plane's normal is known (a first fit of the frame):
each midline is taken as the image of a bar lying on that plane, as wide across the
bisector as measured, the bar's two edges are projected, their bisector is formed as the
detector forms it (`detect.pairs`), and the midline is moved by the difference between
that bisector and the centre line at both of its ends. Taking the detected midline for
the centre line costs the shift's own square (~1e-6 px): one step is exact far below the
noise. It needs only what a lines file holds (midline, width), not the edges.

Conventions: segments ``[x1, y1, x2, y2]`` in raw pixels, widths in undistorted pixels
(as `detect.bars.Bars.width_px`), the normal in the camera frame (either sign).

Example
-------
>>> import numpy as np
>>> from pencilcal.toolkit.camera.model import Camera
>>> cam = Camera("pinhole", 640, 480, [[500.0, 0, 319.5], [0, 500.0, 239.5], [0, 0, 1]])
>>> n = np.array([0.0, -np.sin(np.radians(50)), np.cos(np.radians(50))])  # horizon at y = 659
>>> seg = np.array([[320.0, 100.0, 420.0, 100.0], [320.0, 100.0, 320.0, 300.0]])
>>> shift = centre_lines(cam, seg, [10.0, 10.0], n) - seg
>>> np.round(shift, 4).tolist()  # 10^2 / (4 (659 - 100)) towards the horizon; none along the vertical
[[0.0, 0.0447, 0.0, 0.0447], [0.0, 0.0, 0.0, 0.0]]
"""
from __future__ import annotations

import numpy as np

__all__ = ["centre_lines", "centre_offsets"]


def _project(K, X):
    x = X @ K.T
    return x[..., :2] / x[..., 2:3]


def _line(p, q):
    """Unit normals (M, 2) and offsets (M,) of the lines p -> q (n . x + c = 0, n to the left)."""
    u = q - p
    u = u / np.linalg.norm(u, axis=-1, keepdims=True)
    n = np.stack([-u[:, 1], u[:, 0]], -1)
    return n, -np.sum(n * p, -1)


def centre_offsets(K, ideal, width_px, normal):
    """Shifts (M, 2, 2) [px] that move the two ends of each midline (M, 4) [undistorted px]
    onto the image of the centre line of a bar `width_px` (M,) wide on the plane with unit
    `normal` (3,) (camera frame, either sign), K (3, 3) the camera matrix. Zero for a row
    without a positive finite width or whose end points do not both see the plane in front
    of the camera (a line over the horizon)."""
    K = np.asarray(K, float)
    P = np.asarray(ideal, float).reshape(-1, 4)
    w = np.asarray(width_px, float).reshape(-1)
    p1, p2 = P[:, :2], P[:, 2:]
    Kinv = np.linalg.inv(K)
    r1 = np.concatenate([p1, np.ones((len(P), 1))], -1) @ Kinv.T
    r2 = np.concatenate([p2, np.ones((len(P), 1))], -1) @ Kinv.T
    n = np.asarray(normal, float).reshape(3)
    n = n / np.linalg.norm(n)
    n = n if np.sum((r1 + r2) @ n) >= 0 else -n  # the plane n . X = 1 in front of the camera
    z1, z2 = r1 @ n, r2 @ n
    good = (z1 > 0) & (z2 > 0) & np.isfinite(w) & (w > 0) & np.all(np.isfinite(P), -1)
    with np.errstate(all="ignore"):
        X1, X2 = r1 / z1[:, None], r2 / z2[:, None]
        d = X2 - X1
        e = np.cross(n, d)
        e /= np.linalg.norm(e, axis=-1, keepdims=True)  # across the bar, in the plane
        # the half width on the plane that gives the measured width across the midline (first order)
        nm, _ = _line(p1, p2)
        Xc = 0.5 * (X1 + X2)
        KX, Ke = Xc @ K.T, e @ K.T
        Je = (Ke[:, :2] * KX[:, 2:3] - KX[:, :2] * Ke[:, 2:3]) / KX[:, 2:3] ** 2
        h = (0.5 * w / np.abs(np.sum(Je * nm, -1)))[:, None]
        for rescale in (True, False):  # h set so that the model is as wide as measured
            na, ca = _line(_project(K, X1 + h * e), _project(K, X2 + h * e))
            nb, cb = _line(_project(K, X1 - h * e), _project(K, X2 - h * e))
            # their bisector, as detect.pairs forms it; the centre line passes through p1, p2
            s = np.linalg.norm(na + nb, axis=-1)
            N, C = (na + nb) / s[:, None], (ca + cb) / s
            if rescale:
                # the model's width across the bisector at the midline's centre (detect.pairs)
                m = 0.5 * (p1 + p2)
                m = m - (np.sum(N * m, -1) + C)[:, None] * N
                lam_a = (np.sum(na * m, -1) + ca) / np.sum(na * N, -1)
                lam_b = (np.sum(nb * m, -1) + cb) / np.sum(nb * N, -1)
                h = h * (w / np.abs(lam_a - lam_b))[:, None]
        beta = np.stack([np.sum(N * p1, -1) + C, np.sum(N * p2, -1) + C], -1)
        shift = beta[..., None] * N[:, None, :]
    good &= np.all(np.isfinite(shift), (-2, -1))
    return np.where(good[:, None, None], shift, 0.0)


def centre_lines(camera, segments, width_px, normal, ideal=None):
    """The midlines `segments` (M, 4) [raw px] of bars `width_px` (M,) [undistorted px] wide
    moved onto the images of their printed centre lines on the plane with unit `normal`
    (camera frame), in raw pixels (`centre_offsets`; rows it cannot move are returned as
    they are). camera: a `camera.model.Camera`; ideal: (M, 4) the same midlines in
    undistorted pixels when known (a detector's), else undistorted here. With `ideal` given
    returns (raw, ideal): the moved lines in both (the second for `orient_segments`' ideal)."""
    seg = np.asarray(segments, float).reshape(-1, 4)
    given = ideal is not None
    ideal = camera.undistort_pixels(seg.reshape(-1, 2)).reshape(-1, 4) if ideal is None else \
        np.asarray(ideal, float).reshape(-1, 4)
    off = centre_offsets(camera.K, ideal, width_px, normal)
    moved = ideal + off.reshape(-1, 4)
    raw = camera.distort_pixels(moved.reshape(-1, 2)).reshape(-1, 4)
    same = (~np.any(off.reshape(-1, 4) != 0.0, -1) | ~np.all(np.isfinite(raw), -1))[:, None]
    return (np.where(same, seg, raw), np.where(same, ideal, moved)) if given else np.where(same, seg, raw)
