"""Raw and working pixels: where the detectors fit straight lines and where they sample.

A lens bends straight edges, so the detectors fit lines in *working* pixels: undistorted
pixels (``camera.undistort_pixels``) when a camera is given, the raw pixels themselves
otherwise (``camera=None``). They sample the image in *raw* pixels
(``camera.distort_pixels``). Segments are ``[x1, y1, x2, y2]`` [px], points ``(..., 2)``
[px]; pixel (0, 0) is the centre of the top-left pixel.

Example
-------
>>> import numpy as np
>>> to_working(None, [[0, 0, 10, 5]]).tolist(), to_raw_points(None, np.zeros((2, 2))).shape
([[0.0, 0.0, 10.0, 5.0]], (2, 2))
"""
from __future__ import annotations

import numpy as np

from pencilcal.toolkit.errors import InputError

__all__ = ["check_camera_image", "to_working", "to_working_points", "to_raw", "to_raw_points", "to_raw_smooth", "raw_frame", "blur_scale"]


def check_camera_image(camera, img):
    """Raise InputError unless the image (``img.shape`` (H, W)) has the camera's size
    (nothing to check without a camera)."""
    if camera is not None and (img.shape[1], img.shape[0]) != (camera.width, camera.height):
        raise InputError(f"image is {img.shape[1]}x{img.shape[0]} but the camera was calibrated at "
                         f"{camera.width}x{camera.height}")


def _undistort(camera, px):
    """camera.undistort_pixels, fast: OpenCV's iterative undistortPoints (C++) run to
    convergence, checked by redistorting with the Camera; points that do not come back to
    1e-6 px go through the Camera's own (slower, fold-aware) Newton solver."""
    px = np.asarray(px, float).reshape(-1, 2)
    if camera.model != "opencv" or px.shape[0] == 0:
        return camera.undistort_pixels(px)
    import cv2

    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-14)
    x = cv2.undistortPoints(px.reshape(-1, 1, 2), np.asarray(camera.K), np.asarray(camera.dist),
                            criteria=crit).reshape(-1, 2).astype(float)
    with np.errstate(invalid="ignore"):
        bad = ~(np.max(np.abs(camera.pixels_from_normalized(x) - px), -1) < 1e-6)
    if np.any(bad):
        x[bad] = camera.normalized_from_pixels(px[bad])
    K = np.asarray(camera.K, float)
    return np.stack([K[0, 0] * x[:, 0] + K[0, 1] * x[:, 1] + K[0, 2], K[1, 1] * x[:, 1] + K[1, 2]], -1)


def to_working(camera, raw):
    """Segments (M, 4) [raw px] in working pixels (a copy without a camera)."""
    raw = np.asarray(raw, float).reshape(-1, 4)
    if camera is None:
        return raw.copy()
    return _undistort(camera, raw.reshape(-1, 2)).reshape(-1, 4)


def to_working_points(camera, raw):
    """Points (..., 2) [raw px] in working pixels (a copy without a camera).

    >>> to_working_points(None, [[3.0, 4.0]]).tolist()
    [[3.0, 4.0]]
    """
    raw = np.asarray(raw, float)
    if camera is None:
        return raw.copy()
    return _undistort(camera, raw).reshape(raw.shape)


def to_raw(camera, ideal):
    """Segments (M, 4) [working px] in raw pixels (a copy without a camera)."""
    ideal = np.asarray(ideal, float).reshape(-1, 4)
    if camera is None:
        return ideal.copy()
    return camera.distort_pixels(ideal.reshape(-1, 2)).reshape(-1, 4)


def to_raw_points(camera, pts):
    """Points (..., 2) [working px] in raw pixels (the same array without a camera)."""
    return pts if camera is None else camera.distort_pixels(pts)


def _sparse_columns(S, every):
    """Every `every`-th of S columns, and the last (ascending, each once).

    >>> _sparse_columns(10, 4).tolist(), _sparse_columns(9, 4).tolist(), _sparse_columns(1, 4).tolist()
    ([0, 4, 8, 9], [0, 4, 8], [0])
    """
    cols = np.arange(0, S, every)
    return cols if cols.size and cols[-1] == S - 1 else np.append(cols, S - 1)


def _interpolate_columns(v, cols, S):
    """Values v (M, C, ...) known at columns cols (C,) of S, linear in between: (M, S, ...)."""
    j = np.arange(S)
    k = np.clip(np.searchsorted(cols, j, "right") - 1, 0, max(cols.size - 2, 0))
    k1 = np.minimum(k + 1, cols.size - 1)
    f = (j - cols[k]) / np.maximum(cols[k1] - cols[k], 1)
    f = f.reshape((1, S) + (1,) * (v.ndim - 2))
    return v[:, k] * (1 - f) + v[:, k1] * f


def to_raw_smooth(camera, P, every=4):
    """Raw pixels (K, S, 2) of working points P (K, S, 2) that vary smoothly along S: exact at
    every `every`-th station (and the last), linear in between (the images of straight lines
    bend by far less than a pixel over a few stations). P itself without a camera."""
    if camera is None:
        return P
    S = P.shape[1]
    cols = _sparse_columns(S, every)
    sub = camera.distort_pixels(P[:, cols])
    if cols.size == S:
        return sub
    return _interpolate_columns(sub, cols, S)


def raw_frame(camera, cx, cy, nx, ny, every=8):
    """Where profiles across lines lie in the raw image.

    Parameters
    ----------
    cx, cy : (M, S) [working px]
        Station points along M lines.
    nx, ny : (M, 1) or (M, S)
        Unit normal of each line (working pixels).
    every : int
        The lens map's Jacobian is evaluated at every `every`-th station (and the last) and
        interpolated in between: it changes slowly along a line, and its error only
        rescales a profile by ~1e-6, which moves no edge.

    Returns
    -------
    rx, ry : (M, S) [raw px]
        The stations in raw pixels.
    jx, jy : (M, S)
        Raw displacement per unit of t along the working normal (the local Jacobian of the
        lens map applied to it), exact to second order over the few pixels a profile spans;
        the normal itself without a camera.
    """
    if camera is None:
        return cx, cy, np.broadcast_to(nx, cx.shape), np.broadcast_to(ny, cx.shape)
    K = np.asarray(camera.K, float)
    Kinv2 = np.linalg.inv(K[:2, :2])
    pts = np.stack([cx, cy], -1)
    raw = camera.distort_pixels(pts)
    S = cx.shape[-1]
    cols = _sparse_columns(S, every)
    sub = pts[:, cols]
    J = camera.jacobian_pixels_from_normalized((sub - K[:2, 2]) @ Kinv2.T) @ Kinv2  # d raw / d ideal
    jx = J[..., 0, 0] * nx + J[..., 0, 1] * ny
    jy = J[..., 1, 0] * nx + J[..., 1, 1] * ny
    if cols.size < S:
        # both components at once (the same columns and weights)
        j = _interpolate_columns(np.stack([jx, jy], -1), cols, S)
        jx, jy = j[..., 0], j[..., 1]
    return raw[..., 0], raw[..., 1], jx, jy


def blur_scale(camera, cx, cy, nx, ny, every=8):
    """How much wider an edge's blur is across it in working pixels than in raw ones: an
    edge blurred by sd sigma [raw px] along its raw normal is blurred by sigma * scale
    [working px] along its working normal, scale = |J^-T n| with J the lens map's Jacobian
    (d raw / d working) and n the working normal. A lens's distortion changes it across the
    frame and with the edge's direction (barrel distortion k1 = -0.3 shrinks the image 5 %
    across and 14 % along the radius 400 px from the centre), so one blur in working pixels
    does not fit every edge.

    cx, cy: (M, S) [working px] station points; nx, ny: (M, 1) or (M, S) unit working
    normals; every: as `raw_frame`. Returns (M, S); ones without a camera.

    >>> blur_scale(None, np.zeros((1, 2)), np.zeros((1, 2)), np.ones((1, 1)), np.zeros((1, 1))).tolist()
    [[1.0, 1.0]]
    """
    if camera is None:
        return np.ones(np.shape(cx))
    K = np.asarray(camera.K, float)
    Kinv2 = np.linalg.inv(K[:2, :2])
    pts = np.stack([cx, cy], -1)
    S = pts.shape[1]
    cols = _sparse_columns(S, every)
    J = camera.jacobian_pixels_from_normalized((pts[:, cols] - K[:2, 2]) @ Kinv2.T) @ Kinv2  # d raw / d ideal
    n = np.stack(np.broadcast_arrays(nx, ny), -1)
    n = np.broadcast_to(n, pts.shape)[:, cols]
    m = np.linalg.solve(np.swapaxes(J, -1, -2), n[..., None])[..., 0]  # J^-T n
    scale = np.hypot(m[..., 0], m[..., 1])
    return scale if cols.size == S else _interpolate_columns(scale, cols, S)
