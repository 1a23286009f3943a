"""Reprojection in raw pixels and the Levenberg-Marquardt refinement of a board pose.

`projector` gives the residuals ``projected - observed`` (K, 2) [px] of K fixed
correspondences and their Jacobian (2K, 6) in the pose parameters ``(delta, dt)``
(``R <- expm(skew(delta)) @ R``, a left perturbation in the camera frame [rad];
``t <- t + dt`` [length unit]), under the camera's full lens model;
`levenberg_marquardt` minimises their sum of squares; `refine_pose` is the public entry.
`normalized_points` undistorts raw pixels for the initialisers. The conventions are the
package's (`pencilcal.validation.pnp`).

Example
-------
>>> import numpy as np
>>> from pencilcal.toolkit.camera.model import Camera
>>> cam = Camera("pinhole", 640, 480, [[500.0, 0, 319.5], [0, 500.0, 239.5], [0, 0, 1]])
>>> X = np.array([[0, 0, 0], [50, 0, 0], [0, 50, 0], [50, 50, 0.0]])
>>> r, J, front = residuals(cam, X, cam.project(X + [0, 0, 300.0]), np.eye(3), [0, 0, 300.0])
>>> r.shape, J.shape, bool(front.all()), bool(np.abs(r).max() < 1e-9)
((4, 2), (8, 6), True, True)
"""
from __future__ import annotations

import math

import numpy as np

__all__ = ["projector", "residuals", "normalized_points", "rotation_from_rotvec", "rotation_angle_rad",
           "levenberg_marquardt", "orthonormal", "refine_pose"]

# rvec = tvec = 0 for cv2.projectPoints on camera-frame points (read-only)
_ZERO3 = np.zeros(3)
_ZERO3.flags.writeable = False


def _cv_intrinsics(camera):
    """(K, dist) for cv2.projectPoints where it computes exactly `camera`'s model (opencv
    or pinhole without skew: OpenCV drops K[0, 1]), else None (fisheye, skew)."""
    K = camera.K
    if camera.model == "fisheye" or K[0, 1] != 0.0:
        return None
    return np.ascontiguousarray(K, float), (np.ascontiguousarray(camera.dist, float) if camera.dist.size else None)


def projector(camera, X, obs):
    """The reprojection of fixed correspondences as a function of the pose.

    Parameters
    ----------
    camera : Camera
    X : (K, 3) array_like
        Target-frame points [length unit].
    obs : (K, 2) array_like
        Their observed raw pixels [px].

    Returns
    -------
    project : callable
        ``project(R (3, 3), t (3,), jacobian=True) -> (r, J, front)``: r (K, 2) projected -
        observed raw pixels [px], NaN where a point is not in front of the camera; J (2K, 6)
        d r / d (delta [rad], dt [length unit]), rows (u, v) per corner (None without
        `jacobian`); front (K,) bool.

    For the opencv and pinhole models (no skew) the projection and its point Jacobian
    come from one cv2.projectPoints call on the camera-frame points, the same model in
    C++; otherwise from `Camera.pixels_from_normalized` / `jacobian_pixels_from_normalized`.
    """
    import cv2

    X = np.ascontiguousarray(X, float)
    obs = np.asarray(obs, float)
    n = X.shape[0]
    cv = _cv_intrinsics(camera)

    def assemble(RX, A):
        # d p / d delta = -skew(R X) (left perturbation), so the rotation row of a pixel
        # row a = d pixel / d p is a @ -skew(RX) = cross(RX, a); d p / d t = I
        V = np.repeat(RX, 2, axis=0)
        J = np.empty((2 * n, 6))
        J[:, 0] = V[:, 1] * A[:, 2] - V[:, 2] * A[:, 1]
        J[:, 1] = V[:, 2] * A[:, 0] - V[:, 0] * A[:, 2]
        J[:, 2] = V[:, 0] * A[:, 1] - V[:, 1] * A[:, 0]
        J[:, 3:] = A
        return J

    if cv is not None:
        Kc, dist = cv

        def project(R, t, jacobian=True):
            p = X @ R.T + t
            front = p[:, 2] > 0
            # the camera-frame points with rvec = tvec = 0: the tvec columns are d pixel / d p,
            # the rvec columns (Rodrigues at 0) d pixel / d delta for p <- expm(skew(delta)) p,
            # i.e. -A skew(p); the rotation of R alone moves R X = p - t: -A skew(p - t)
            img, jac = cv2.projectPoints(p, _ZERO3, _ZERO3, Kc, dist)
            r = img.reshape(n, 2) - obs
            J = None
            if jacobian:
                J = np.empty((2 * n, 6))
                A = jac[:, 3:6]
                J[:, 3:] = A
                J[:, :3] = jac[:, :3] + A @ np.array([[0.0, -t[2], t[1]], [t[2], 0.0, -t[0]], [-t[1], t[0], 0.0]])
            if not front.all():  # OpenCV mirrors points behind the camera into the image
                r[~front] = np.nan
                if J is not None:
                    J.reshape(n, 2, 6)[~front] = np.nan
            return r, J, front
        return project

    def project(R, t, jacobian=True):
        RX = X @ R.T
        p = RX + t
        z = p[:, 2]
        front = z > 0
        zs = np.where(front, z, np.nan)
        xy = p[:, :2] / zs[:, None]
        r = camera.pixels_from_normalized(xy) - obs
        if not jacobian:
            return r, None, front
        Jl = camera.jacobian_pixels_from_normalized(xy)  # (K, 2, 2)
        inv_z = (1.0 / zs)[:, None]
        A = np.empty((n, 2, 3))  # d pixel / d p = Jl @ d xy / d p
        A[:, :, :2] = Jl * inv_z[:, :, None]
        A[:, :, 2] = -(Jl[:, :, 0] * xy[:, :1] + Jl[:, :, 1] * xy[:, 1:]) * inv_z
        return r, assemble(RX, A.reshape(2 * n, 3)), front
    return project


def residuals(camera, X, obs, R, t, jacobian=True):
    """Residuals projected - observed (K, 2) [px] and the Jacobian (2K, 6) in (d_rot, d_t).

    camera, X (K, 3), obs (K, 2): as `projector`; R (3, 3), t (3,): the pose. Returns
    (r, J, in_front): r is NaN where a point is not in front of the camera; J is None
    without `jacobian`; in_front (K,) bool.
    """
    return projector(camera, X, obs)(np.asarray(R, float), np.asarray(t, float), jacobian)


# Undistortion by cv2.undistortPoints, accepted where the lens model maps the result back
# onto the pixel to this (normalised, distorted) tolerance, as Camera.normalized_from_pixels
# accepts its own, and the model is invertible from the centre out to it (det J > 0 on
# these fractions of the way: Camera's fold test).
_UNDISTORT_TOL = 1e-11
_FOLD_FRACTIONS = np.linspace(0.0, 1.0, 9)[1:]
_FOLD_FRACTIONS.flags.writeable = False
_UNDISTORT_CRITERIA = (3, 100, 1e-12)  # cv2.TERM_CRITERIA_COUNT + EPS, iterations, px


def normalized_points(camera, u):
    """Undistorted normalised coordinates (K, 2) of raw pixels u (K, 2) [px], NaN where they
    cannot be undistorted: `Camera.normalized_from_pixels`, or for the opencv model
    without sensor tilt or skew the same roots from OpenCV's iteration, checked.

    Example
    -------
    >>> import numpy as np
    >>> from pencilcal.toolkit.camera.model import Camera
    >>> cam = Camera("pinhole", 640, 480, [[500.0, 0, 319.5], [0, 500.0, 239.5], [0, 0, 1]])
    >>> normalized_points(cam, np.array([[319.5, 239.5], [819.5, 239.5]])).tolist()
    [[0.0, 0.0], [1.0, 0.0]]
    """
    import cv2

    cv = _cv_intrinsics(camera)
    if cv is not None and camera.model == "opencv" and camera.dist.size < 14:
        Kc, dist = cv
        n = u.shape[0]
        with np.errstate(all="ignore"):
            xy = cv2.undistortPoints(np.ascontiguousarray(u.reshape(-1, 1, 2)), Kc, dist, None, None, None,
                                     _UNDISTORT_CRITERIA).reshape(n, 2)
            if np.all(np.isfinite(xy)):
                # back to pixels, and the Jacobian along the way from the centre to each root
                frac = _FOLD_FRACTIONS[:, None, None] * xy
                pts = np.concatenate([np.concatenate([xy, frac.reshape(-1, 2)]), np.ones((n * 9, 1))], 1)
                img, jac = cv2.projectPoints(pts, _ZERO3, _ZERO3, Kc, dist)
                img = img.reshape(-1, 2)
                fx, fy = Kc[0, 0], Kc[1, 1]
                err = np.hypot((img[:n, 0] - u[:, 0]) / fx, (img[:n, 1] - u[:, 1]) / fy)
                scale = 1.0 + np.hypot((u[:, 0] - Kc[0, 2]) / fx, (u[:, 1] - Kc[1, 2]) / fy)
                A = jac[2 * n:, 3:5].reshape(-1, 2, 2)  # d pixel / d (x, y) at z = 1
                det = A[:, 0, 0] * A[:, 1, 1] - A[:, 0, 1] * A[:, 1, 0]
                if np.all(err <= _UNDISTORT_TOL * scale) and np.all(det > 0):
                    return xy
    with np.errstate(all="ignore"):
        return camera.normalized_from_pixels(u)


def rotation_from_rotvec(v):
    """Rodrigues' formula (cv2.Rodrigues): the (3, 3) rotation of one (3,) rotation vector [rad]."""
    import cv2

    return cv2.Rodrigues(np.ascontiguousarray(v, float))[0]


def rotation_angle_rad(R_a, R_b):
    """Geodesic angle [rad] between two (3, 3) rotations (frames.rotation_angle for one pair,
    in plain floats: the estimator compares many pairs one at a time).

    >>> import numpy as np
    >>> round(rotation_angle_rad(np.eye(3), rotation_from_rotvec([0.0, 0.0, 0.5])), 12)
    0.5
    """
    M = (R_a.T @ R_b).tolist()
    # the antisymmetric part keeps precision for tiny angles where acos(trace) does not
    s = 0.5 * math.sqrt((M[2][1] - M[1][2]) ** 2 + (M[0][2] - M[2][0]) ** 2 + (M[1][0] - M[0][1]) ** 2)
    return math.atan2(s, 0.5 * (M[0][0] + M[1][1] + M[2][2] - 1.0))


# relative cost decrease below which the refinement has converged
_LM_TOL = 1e-12


def levenberg_marquardt(project, R, t, max_iterations=100):
    """Levenberg-Marquardt from (R (3, 3), t (3,)) with ``project`` from `projector`.

    Returns (R, t, iterations, r, J): the residuals (K, 2) [px] and Jacobian (2K, 6) at the
    returned pose, or r = J = None where the start has points behind the camera (R, t
    returned unchanged). R is not re-orthonormalised (`orthonormal`).
    """
    import cv2

    R = np.array(R, float)
    t = np.array(t, float)
    with np.errstate(all="ignore"):
        r, J, front = project(R, t)
        if not front.all() or not np.isfinite(r).all() or not np.isfinite(J).all():
            return R, t, 0, None, None
        rv = r.ravel()
        cost = float(rv @ rv)
        lam = 1e-6
        it = 0
        for it in range(1, max_iterations + 1):
            H = J.T @ J
            g = J.T @ rv
            mg = -g.reshape(6, 1)
            dH = H.diagonal() + 1e-300
            tiny = 1e-24 * (1.0 + math.sqrt(t @ t)) ** 2
            accepted = False
            while lam < 1e12:
                ok, step = cv2.solve(H + np.diag(lam * dH), mg)
                if not ok:
                    lam *= 10.0
                    continue
                step = step.ravel()
                # stop once a step changes the pose by ~1e-12 (relative) or lowers the cost
                # by 1e-12 of itself: far below any uncertainty the corners allow. A step
                # the Gauss-Newton model says lowers the cost by less is the last one tried
                # (taken if it does not raise the cost): near the optimum the model is exact,
                # and raising the damping further could only shrink it.
                rot, tr = step[:3], step[3:]
                if rot @ rot < 1e-24 and tr @ tr < tiny:
                    break
                last = -float(g @ step) - 0.5 * float(step @ H @ step) <= _LM_TOL * cost
                R_new = rotation_from_rotvec(rot) @ R
                t_new = t + tr
                r_new, J_new, front_new = project(R_new, t_new)
                rv_new = r_new.ravel()
                cost_new = float(rv_new @ rv_new) if front_new.all() else np.inf
                if cost_new <= cost and np.isfinite(J_new).all():  # False for NaN/inf
                    accepted = True
                    break
                if last:
                    break
                lam *= 10.0
            if not accepted:
                break
            done = cost - cost_new <= _LM_TOL * cost
            R, t, r, rv, J, cost = R_new, t_new, r_new, rv_new, J_new, cost_new
            lam = max(lam * 0.1, 1e-12)
            if done:
                break
    return R, t, it, r, J


def orthonormal(R):
    """The nearest rotation (3, 3) to R (3, 3): keeps R exactly orthonormal after many small updates."""
    E = R.T @ R - np.eye(3)
    if np.abs(E).max() < 1e-9:
        # polar factor to second order: R (I + E)^(-1/2) = R (I - E / 2 + O(E^2))
        return R - 0.5 * (R @ E)
    U, _, Vt = np.linalg.svd(R)
    if np.linalg.det(U @ Vt) < 0:
        U[:, 2] = -U[:, 2]
    return U @ Vt


def refine_pose(camera, object_points, image_points, R, t, max_iterations=100):
    """Levenberg-Marquardt on the raw-pixel reprojection error under the full lens model.

    Parameters
    ----------
    camera : Camera
    object_points : (K, 3) array_like
        Target-frame points [length unit].
    image_points : (K, 2) array_like
        Observed raw pixels [px, OpenCV convention].
    R, t : (3, 3), (3,) array_like
        Starting R_cam_from_target and t_cam_from_target.
    max_iterations : int

    Returns
    -------
    R, t, iterations : (3, 3) ndarray, (3,) ndarray, int
        The refined pose. Never raises: a start with points behind the camera is returned
        unchanged (the caller checks).

    Example
    -------
    >>> import numpy as np
    >>> from pencilcal.toolkit.camera.model import Camera
    >>> cam = Camera("pinhole", 640, 480, [[500.0, 0, 319.5], [0, 500.0, 239.5], [0, 0, 1]])
    >>> X = np.array([[0, 0, 0], [50, 0, 0], [0, 50, 0], [50, 50, 0], [25, 10, 0.0]])
    >>> u = cam.project(X + [0, 0, 300.0])
    >>> R, t, _ = refine_pose(cam, X, u, np.eye(3), np.array([2.0, -1.0, 310.0]))
    >>> (np.round(t, 9) + 0.0).tolist()
    [0.0, 0.0, 300.0]
    """
    X = np.asarray(object_points, float)
    obs = np.asarray(image_points, float)
    R, t, it, r, _ = levenberg_marquardt(projector(camera, X, obs), R, t, max_iterations)
    if r is None:
        return R, t, 0
    return orthonormal(R), t, it


