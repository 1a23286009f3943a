"""The covariance of a board pose from the reprojection Jacobian, and COLMAP's converted.

``cov`` (6, 6) is the covariance of the error of the estimate in the refinement's own
coordinates, rotation first: the true pose is ``R_true = expm(skew(d_rot)) @ R_hat`` and
``t_true = t_hat + d_t`` with ``(d_rot, d_t) ~ N(0, cov)``; d_rot [rad] is a rotation
vector about the *camera* axes, d_t is in the length unit of the object points. It is
``sigma^2 (J^T J)^-1`` at the optimum, with ``sigma`` the corner noise [px], given or
estimated from the residuals as ``sqrt(sum r^2 / (2 K - 6))`` (K corners). See
`pencilcal.validation.pnp` for what it covers and what it does not.

Example
-------
>>> import numpy as np
>>> from pencilcal.toolkit.camera.model import Camera
>>> cam = Camera("pinhole", 640, 480, [[500.0, 0, 319.5], [0, 500.0, 239.5], [0, 0, 1]])
>>> X = np.array([[0, 0, 0], [50, 0, 0], [0, 50, 0], [50, 50, 0], [25, 10, 0.0]])
>>> cov, sigma, r = pose_covariance(cam, X, cam.project(X + [0, 0, 300.0]), np.eye(3), [0, 0, 300.0], 0.5)
>>> cov.shape, sigma, bool(np.all(np.linalg.eigvalsh(cov) > 0))
((6, 6), 0.5, True)
"""
from __future__ import annotations

import math

import numpy as np

from pencilcal.toolkit.board.corner_noise import correlated_covariance
from pencilcal.toolkit.camera.intrinsics import jacobian_pixels_wrt_intrinsics, propagate
from pencilcal.toolkit.errors import EstimationError

from .refine import residuals

__all__ = ["covariance_from_jacobian", "pose_covariance", "colmap_covariance_to_pencilcal",
           "pose_intrinsics_sensitivity", "pose_warp_sensitivity", "total_covariance"]

# smallest eigenvalue of the Jacobi-scaled normal matrix, relative to the largest, below
# which the pose is numerically undetermined
_SINGULAR_TOL = 1e-13


def covariance_from_jacobian(J, r, corner_sigma_px=None):
    """(cov (6, 6), sigma [px]) from the Jacobian J (2K, 6) and residuals r (K, 2) [px] at
    the optimum; corner_sigma_px: the corner noise [px], default from the residuals (NaN
    sigma with 3 corners or fewer). See `pose_covariance`.

    Raises EstimationError (an ArithmeticError) when the pose is not determined.
    """
    if not np.all(np.isfinite(J)):
        raise EstimationError("some corners are behind the camera in this pose")
    import cv2

    H = J.T @ J
    d = np.sqrt(H.diagonal())
    if not np.all(d > 0):
        raise EstimationError("the pose is not determined by these points (a parameter has no effect)")
    dd = np.outer(d, d)
    # the Jacobi-scaled normal matrix: its eigenvalues (descending) say whether the pose is
    # determined, and give its inverse
    _, w, V = cv2.eigen(H / dd)
    w = w.ravel()
    if not w[-1] > _SINGULAR_TOL * w[0]:
        raise EstimationError("the pose is not determined by these points (degenerate geometry: "
                              f"normal matrix condition {w[0] / max(w[-1], 1e-300):.1e})")
    Hinv = ((V.T / w) @ V) / dd
    Hinv = 0.5 * (Hinv + Hinv.T)
    if corner_sigma_px is None:
        dof = 2 * r.shape[0] - 6
        rr = r.ravel()
        sigma = math.sqrt(float(rr @ rr) / dof) if dof > 0 else float("nan")
    else:
        sigma = float(corner_sigma_px)
    return sigma * sigma * Hinv, sigma


def pose_covariance(camera, object_points, image_points, R, t, corner_sigma_px=None):
    """Covariance (6x6, rotation first) of a pose from the reprojection Jacobian.

    Parameters
    ----------
    camera, object_points (K, 3), image_points (K, 2), R (3, 3), t (3,)
        As `refine_pose`; the pose should be the least-squares optimum.
    corner_sigma_px : float, optional
        Corner noise [px]; default: from the residuals, sqrt(sum r^2 / (2K - 6)).

    Returns
    -------
    cov : (6, 6) ndarray
        Of (d_rot [rad], d_t [length]); see the module doc for the convention.
    sigma : float
        The corner noise used [px].
    residuals : (K, 2) ndarray
        projected - observed [px].

    Raises
    ------
    ArithmeticError (EstimationError)
        When the normal matrix is numerically singular (the pose is not determined).
    """
    X = np.asarray(object_points, float)
    obs = np.asarray(image_points, float)
    with np.errstate(all="ignore"):
        r, J, front = residuals(camera, X, obs, R, t)
    if not np.all(front):
        raise EstimationError("some corners are behind the camera in this pose")
    cov, sigma = covariance_from_jacobian(J, r, corner_sigma_px)
    return cov, sigma, r


def colmap_covariance_to_pencilcal(cov_colmap, sigma_px=1.0):
    """Convert COLMAP's RefineAbsolutePose covariance to this module's convention.

    COLMAP (estimators/pose.cc) reports ``ceres::Covariance`` in the tangent space of the
    Eigen quaternion manifold and the translation, assuming 1 px residuals. Ceres'
    quaternion tangent ``delta`` applies ``q(delta) * q`` with ``q(delta) = [cos|delta|,
    sin|delta| delta/|delta|]``, a rotation by 2|delta|: the rotation vector is 2 delta,
    a left perturbation in the camera frame as here. So the rotation block is scaled by 4,
    the cross blocks by 2, and everything by sigma_px^2.

    cov_colmap: (6, 6). Returns (6, 6).
    """
    S = np.diag([2.0, 2.0, 2.0, 1.0, 1.0, 1.0])
    return float(sigma_px) ** 2 * S @ np.asarray(cov_colmap, float) @ S




def pose_intrinsics_sensitivity(camera, object_points, R, t, J):
    """G (6, P) = d(pose) / d(intrinsics) at a least-squares optimum (implicit function theorem).

    At the optimum J^T r = 0; moving the intrinsics by d_theta moves the residuals by
    J_theta d_theta, and the pose by ``G d_theta`` with ``G = -(J^T J)^-1 J^T J_theta``
    (Gauss-Newton: the residuals' own curvature is left out, as in the covariance).

    camera; object_points (K, 3) [length]; R (3, 3), t (3,): the pose; J (2K, 6): the
    residuals' pose Jacobian there (`refine.residuals`). Columns in the order of
    `toolkit.camera.intrinsics.intrinsic_names`; rows (d_rot [rad], d_t [length]).
    """
    p = np.asarray(object_points, float) @ np.asarray(R, float).T + np.asarray(t, float)
    Jt = jacobian_pixels_wrt_intrinsics(camera, p[:, :2] / p[:, 2:3]).reshape(2 * p.shape[0], -1)
    return -np.linalg.solve(J.T @ J, J.T @ Jt)


def pose_warp_sensitivity(camera, object_points, image_points, R, t, J, basis):
    """G (6, W) = d(pose) / d(board warp) at a least-squares optimum, as
    `pose_intrinsics_sensitivity`: each corner lifted off the board's plane by ``basis``
    (K, W) [d z / d warp, `toolkit.board.bundle.warp_basis`; W = 3 with the twist], the residuals' change by
    central differences (the projection is smooth; the warp moves corners by a fraction of
    a millimetre). Rows (d_rot [rad], d_t [length]), columns (warp_x, warp_y[, warp_twist])."""
    X = np.asarray(object_points, float)
    basis = np.asarray(basis, float)
    h = 1e-3 * max(float(np.ptp(X[:, :2])), 1e-9)
    cols = []
    for k in range(basis.shape[1]):
        dz = np.zeros_like(X)
        dz[:, 2] = h * basis[:, k]
        rp = residuals(camera, X + dz, image_points, R, t)[0].reshape(-1)
        rm = residuals(camera, X - dz, image_points, R, t)[0].reshape(-1)
        cols.append((rp - rm) / (2.0 * h))
    return -np.linalg.solve(J.T @ J, J.T @ np.stack(cols, 1))


def total_covariance(camera, object_points, image_points, R, t, J, r, corner_noise=None, intrinsics_cov=None,
                     board_warp=None):
    """The pose's covariance with every term this package models, and what it holds.

    Parameters
    ----------
    camera, object_points (K, 3), image_points (K, 2), R (3, 3), t (3,)
        As `pose_covariance`, at the optimum.
    J : (2K, 6) ndarray
        The residuals' pose Jacobian there; r : (K, 2) the residuals [px].
    corner_noise : CornerNoise, optional
        Correlated corner errors (`toolkit.board.corner_noise`): the corner term becomes the
        sandwich covariance of that model with the view's own white level; None (or a
        ratio of 0): white errors, ``sigma^2 (J^T J)^-1`` with sigma from the residuals.
    intrinsics_cov : (P, P) array_like, optional
        Covariance of the camera's intrinsics (`intrinsic_names` order): adds
        ``G C G^T`` (`pose_intrinsics_sensitivity`).
    board_warp : (basis (K, 2), cov (2, 2)), optional
        The board's warp the object points carry (`toolkit.board.calibration_file.
        board_model`) and its covariance: adds its term (`pose_warp_sensitivity`).

    Returns
    -------
    cov : (6, 6) ndarray
        Same convention as the corner-noise covariance (rotation first, rad and length).
    correlated : bool
        Whether it holds the correlated corner term.
    G : (6, P) ndarray or None
        `pose_intrinsics_sensitivity` when it holds the intrinsics' term.
    """
    correlated = corner_noise is not None and corner_noise.ratio > 0
    if correlated:
        cov, _ = correlated_covariance(J, r, image_points, corner_noise)
    else:
        cov, _ = covariance_from_jacobian(J, r)
    G = None
    if intrinsics_cov is not None:
        G = pose_intrinsics_sensitivity(camera, object_points, R, t, J)
        cov = cov + propagate(G, intrinsics_cov)
    if board_warp is not None and board_warp[1] is not None:
        Gw = pose_warp_sensitivity(camera, object_points, image_points, R, t, J, board_warp[0])
        cov = cov + Gw @ np.asarray(board_warp[1], float) @ Gw.T
    return cov, correlated, G
