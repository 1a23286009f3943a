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
>>> lin = linearity(cam, C, q)          # the pixel is linear in fx, fy, cx, cy: the sigmas hold
>>> round(lin["predicted_rms_px"], 2), bool(lin["departure_share"] < 0.01)
(0.34, True)
"""
from __future__ import annotations

import math

import numpy as np

from pencilcal.toolkit.camera.intrinsics import jacobian_pixels_wrt_intrinsics, with_intrinsics, intrinsics_vector

__all__ = ["rotation_jacobian", "projection_sensitivity", "projection_uncertainty", "projection_difference",
           "worst_sigma", "linearity", "LINEAR_DEPARTURE"]

#: The most the projection may depart from its linearisation over the intrinsics' one-sigma
#: ellipsoid, as a share of the projection uncertainty that linearisation predicts
#: (`linearity`), for that uncertainty to be read as the calibration's: a one-sigma step
#: then moves the projection by at most sqrt(1 + 0.83^2) = 1.3 x the linear figure, the
#: factor by which two calibrations' difference may exceed its prediction and still agree.
LINEAR_DEPARTURE = math.sqrt(1.3 ** 2 - 1.0)


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
    xy, ok = _rays(camera_a, pixels)
    ref = None
    if region is not None:
        xr, okr = _rays(camera_a, region)
        ref = (xr[okr], np.asarray(region, float).reshape(-1, 2)[okr])
    return _aligned_difference(camera_b, xy, ok, np.asarray(pixels, float).reshape(-1, 2), ref, iterations)


def _aligned_difference(camera_b, xy, ok, pixels, ref, iterations=3):
    """`projection_difference` from the rays xy (N, 2) (ok (N,): found) of `pixels` (N, 2);
    ref : (the region's rays (M, 2), its pixels (M, 2)) or None for no rotation."""
    import cv2

    v = np.concatenate([xy, np.ones(xy.shape[:-1] + (1,))], -1)
    R = np.eye(3)
    if ref is not None:
        vr = np.concatenate([ref[0], np.ones((ref[0].shape[0], 1))], -1)
        target = ref[1]
        for _ in range(int(iterations)):
            p = vr @ R.T
            d = camera_b.project(p) - target
            J = rotation_jacobian(camera_b, p[:, :2] / p[:, 2:3])
            good = np.all(np.isfinite(d), -1)
            w = np.linalg.lstsq(J[good].reshape(-1, 3), -d[good].reshape(-1), rcond=None)[0]
            R = cv2.Rodrigues(w)[0] @ R
    out = np.full(xy.shape, np.nan)
    out[ok] = camera_b.project(v[ok] @ R.T) - pixels[ok]
    return out

def linearity(camera, cov, region):
    """Does the projection stay linear in the intrinsics over their uncertainty? Every
    projection uncertainty here (and the two halves' predicted difference) is the first-order
    response ``A_q C A_q^T``; it describes the calibration only while a one-sigma change of
    the intrinsics moves the projection as ``A_q`` says. A lens model whose coefficients the
    views do not determine (OpenCV's rational model, whose numerator and denominator can
    grow together by thousands) has sigmas that reach far past that range, and its
    linearised uncertainty is then meaningless, large or small.

    The intrinsics are stepped by +-1 sigma along each principal axis of the projection's
    response (the right singular vectors of ``A L`` over `region`, ``L L^T = cov``); at each
    step the camera's projection of the region's rays, up to the aligning rotation
    (`projection_difference`), is compared with the linear ``A L z``.

    camera : the calibrated `Camera`; cov : (P, P) its intrinsics' covariance; region :
    (M, 2) the pixels the views cover [px].

    Returns ``{"predicted_rms_px": sqrt(mean tr A C A^T) over the region, "departure_rms_px":
    the RMS over the region and the 2 P steps of exact minus linear, summed over the axes
    like the prediction, "departure_share": their ratio (inf where a step's rays are
    lost)}``.
    """
    region = np.asarray(region, float).reshape(-1, 2)
    A = projection_sensitivity(camera, region, region)
    xy, found = _rays(camera, region)
    ok = found & np.all(np.isfinite(A), (-1, -2))
    A, region, xy = A[ok], region[ok], xy[ok]
    ref = (xy, region)
    w, V = np.linalg.eigh(0.5 * (np.asarray(cov, float) + np.asarray(cov, float).T))
    L = V * np.sqrt(np.clip(w, 0.0, None))
    M = (A @ L).reshape(-1, L.shape[1])
    Z = np.linalg.svd(M, full_matrices=False)[2]                      # (P, P) whitened axes
    theta = intrinsics_vector(camera)
    pred2 = float(np.sum(M * M)) / max(region.shape[0], 1)
    dep2 = 0.0
    for z in Z:
        step = L @ z
        lin = (A @ step).reshape(-1, 2)
        for sign in (1.0, -1.0):
            exact = _aligned_difference(with_intrinsics(camera, theta + sign * step), xy, np.ones(len(xy), bool),
                                        region, ref)
            if not np.all(np.isfinite(exact)):
                return {"predicted_rms_px": float(np.sqrt(pred2)), "departure_rms_px": float("inf"),
                        "departure_share": float("inf")}
            dep2 += 0.5 * float(np.sum((exact - sign * lin) ** 2)) / region.shape[0]
    pred = float(np.sqrt(pred2))
    return {"predicted_rms_px": pred, "departure_rms_px": float(np.sqrt(dep2)),
            "departure_share": float(np.sqrt(dep2)) / pred if pred > 0 else float("inf")}
