"""How well a calibration knows where a ray lands in the image, and how two calibrations differ.

The projection uncertainty at a pixel q is the scatter of the pixel at which the camera
puts the ray it sees at q, when the intrinsics vary as their covariance C says: to first
order ``A_q C A_q^T`` (2 x 2) [px^2], ``A_q`` = d pixel / d intrinsics at the fixed ray
(`intrinsics.jacobian_pixels_wrt_intrinsics`). Its size is given as mrcal-show-projection-
uncertainty gives it: the worst direction's standard deviation, ``sqrt`` of the larger
eigenvalue [px].

Part of any intrinsics error is indistinguishable from turning the camera: a principal
point off by a pixel, with every board pose turned by 1/f rad, fits the corners as well.
The board poses of a calibration absorb that part, and so does any later pose or extrinsic
calibration made with the camera; mrcal compares calibrations after fitting the rotation
between them for this reason. With ``region`` given, that common rotation, fitted by least
squares over the region's pixels, is taken out: ``A_q - R_q W`` with ``R_q`` = d pixel / d
rotation of the ray and ``W`` the rotation's least-squares response over the region.
`projection_difference` does the same to two calibrations: the rays of one through
`pixels`, turned by the rotation that best aligns the two over the region, are projected by
the other.

Example
-------
>>> import numpy as np
>>> from pencilcal.toolkit.camera.model import Camera
>>> cam = Camera("opencv", 640, 480, [[500.0, 0, 319.5], [0, 500.0, 239.5], [0, 0, 1]], [-0.1, 0.01, 0, 0])
>>> C = np.diag([1.0, 1.0, 4.0, 4.0, 0, 0, 0, 0])      # fx, fy, cx, cy [px^2]
>>> q = np.array([[319.5, 239.5], [600.0, 440.0]])
>>> projection_uncertainty(cam, C, q)[0].round(2).tolist()         # the centre: the principal point's 2 px
[2.0, 2.08]
>>> projection_uncertainty(cam, C, q, region=q)[0].round(2).tolist()   # a rotation takes it out
[0.39, 0.3]
>>> other = Camera("opencv", 640, 480, [[500.0, 0, 321.5], [0, 500.0, 239.5], [0, 0, 1]], [-0.1, 0.01, 0, 0])
>>> float(np.abs(projection_difference(cam, other, q)).max()), round(float(np.abs(projection_difference(cam, other, q, q)).max()), 2)
(2.0, 0.19)
"""
from __future__ import annotations

import numpy as np

from pencilcal.toolkit.camera.intrinsics import jacobian_pixels_wrt_intrinsics

__all__ = ["rotation_jacobian", "projection_sensitivity", "projection_uncertainty", "projection_difference",
           "worst_sigma"]


def rotation_jacobian(camera, xy):
    """(N, 2, 3): d pixel / d omega of the ray through normalised points xy (N, 2) turned
    by a small rotation exp([omega]_x) in the camera frame."""
    xy = np.asarray(xy, float)
    v = np.concatenate([xy, np.ones(xy.shape[:-1] + (1,))], -1)
    # d(R v)/d omega = -[v]_x ; d xy / d p at z = 1: [[1, 0, -x], [0, 1, -y]]
    Vx = np.zeros(v.shape[:-1] + (3, 3))
    Vx[..., 0, 1], Vx[..., 0, 2] = v[..., 2], -v[..., 1]
    Vx[..., 1, 0], Vx[..., 1, 2] = -v[..., 2], v[..., 0]
    Vx[..., 2, 0], Vx[..., 2, 1] = v[..., 1], -v[..., 0]
    D = np.zeros(v.shape[:-1] + (2, 3))
    D[..., 0, 0] = D[..., 1, 1] = 1.0
    D[..., 0, 2], D[..., 1, 2] = -xy[..., 0], -xy[..., 1]
    return camera.jacobian_pixels_from_normalized(xy) @ D @ Vx


def _rays(camera, pixels):
    xy = camera.normalized_from_pixels(np.asarray(pixels, float).reshape(-1, 2))
    return xy, np.all(np.isfinite(xy), -1)


def projection_sensitivity(camera, pixels, region=None):
    """A (N, 2, P): d pixel / d intrinsics of the fixed rays through `pixels` (N, 2), with
    the common rotation fitted over `region` (M, 2) taken out when given. NaN rows where a
    pixel does not undistort."""
    xy, ok = _rays(camera, pixels)
    A = np.full(xy.shape[:-1] + (2, 4 + camera.dist.size), np.nan)
    A[ok] = jacobian_pixels_wrt_intrinsics(camera, xy[ok])
    if region is None:
        return A
    xr, okr = _rays(camera, region)
    Ar = jacobian_pixels_wrt_intrinsics(camera, xr[okr]).reshape(-1, A.shape[-1])
    Rr = rotation_jacobian(camera, xr[okr]).reshape(-1, 3)
    W = np.linalg.lstsq(Rr, Ar, rcond=None)[0]                       # (3, P)
    A[ok] -= rotation_jacobian(camera, xy[ok]) @ W
    return A


def worst_sigma(cov2):
    """sqrt of the larger eigenvalue of 2 x 2 covariances (..., 2, 2) [px]."""
    a, b, c = cov2[..., 0, 0], cov2[..., 0, 1], cov2[..., 1, 1]
    return np.sqrt(np.maximum(0.5 * (a + c) + np.sqrt(0.25 * (a - c) ** 2 + b * b), 0.0))


def projection_uncertainty(camera, cov, pixels, region=None):
    """(sigma (N,) [px], cov2 (N, 2, 2) [px^2]): the projection uncertainty at `pixels`
    (N, 2) under the intrinsics' covariance `cov` (P, P), the worst direction's standard
    deviation and the full 2 x 2; up to the rotation fitted over `region` when given."""
    A = projection_sensitivity(camera, pixels, region)
    C = A @ np.asarray(cov, float) @ np.swapaxes(A, -1, -2)
    C = 0.5 * (C + np.swapaxes(C, -1, -2))
    return worst_sigma(C), C


def projection_difference(camera_a, camera_b, pixels, region=None, iterations=3):
    """(N, 2) [px]: where camera_b puts the rays camera_a sees at `pixels` (N, 2), minus
    those pixels; with `region` (M, 2) the rays are first turned by the rotation that best
    aligns the two cameras over the region's pixels (Gauss-Newton, least squares). NaN
    where a ray is not found."""
    import cv2

    xy, ok = _rays(camera_a, pixels)
    v = np.concatenate([xy, np.ones(xy.shape[:-1] + (1,))], -1)
    R = np.eye(3)
    if region is not None:
        xr, okr = _rays(camera_a, region)
        vr = np.concatenate([xr[okr], np.ones((int(okr.sum()), 1))], -1)
        target = np.asarray(region, float).reshape(-1, 2)[okr]
        for _ in range(int(iterations)):
            p = vr @ R.T
            d = camera_b.project(p) - target
            J = rotation_jacobian(camera_b, p[:, :2] / p[:, 2:3])
            good = np.all(np.isfinite(d), -1)
            w = np.linalg.lstsq(J[good].reshape(-1, 3), -d[good].reshape(-1), rcond=None)[0]
            R = cv2.Rodrigues(w)[0] @ R
    out = np.full(xy.shape, np.nan)
    out[ok] = camera_b.project(v[ok] @ R.T) - np.asarray(pixels, float).reshape(-1, 2)[ok]
    return out
