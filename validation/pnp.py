"""Board pose from corner correspondences (PnP), refined in raw pixels, with covariance.

`estimate_pose` finds the pose of a target (a calibration board) from its known corner
positions and their raw (distorted) pixels with one of several initialisers, then refines
it by Levenberg-Marquardt on the reprojection error in raw pixels under the camera's full
lens model, and reports the reprojection residuals and the 6x6 pose covariance.

Methods
-------
``"iterative"``
    OpenCV's SOLVEPNP_ITERATIVE (homography or DLT start, then its own LM). Needs 4 points
    on a plane, 6 otherwise (OpenCV's DLT; its planarity test is used here too).
``"sqpnp"`` (default)
    OpenCV's SOLVEPNP_SQPNP (globally optimal algebraic solver). 4 points or more here
    (OpenCV accepts 3, which leave up to 4 poses).
``"ippe"``
    OpenCV's SOLVEPNP_IPPE, planar targets only; it returns the two poses that explain a
    planar target. Both are refined; the one with the lower RMS is kept and the other's
    RMS and angle are recorded (``alternative_rms_px``, ``alternative_angle_deg``).
``"epnp"``
    OpenCV's SOLVEPNP_EPNP. 4 points or more. On planar targets OpenCV's EPnP is
    unreliable (opencv/opencv#22351): on 5 of the 28 real RealSense ChArUco frames, and on
    ~13 % of random synthetic views, it returns a pose 80-145 deg off that refines to the
    wrong planar twin (RMS 17-38 px on the real frames); the twin check below corrects it
    (``flipped``).
``"colmap"``
    pycolmap.estimate_and_refine_absolute_pose: LO-RANSAC (P3P, EPnP local optimisation)
    and COLMAP's own Ceres refinement with a Cauchy loss, with the camera converted by
    `camera_io.camera_to_colmap` (principal point + 0.5 px) and the image points shifted
    by the same + 0.5 px into COLMAP's pixel convention. The camera must be a model COLMAP
    has (no skew, no thin-prism/tilt coefficients).

Every OpenCV method runs on *undistorted* points: the raw pixels are undistorted exactly
by `Camera.normalized_from_pixels` (opencv, fisheye or pinhole) and handed to OpenCV as
ideal pinhole pixels ``(fx x + cx, fy y + cy)`` with no distortion coefficients. So every
lens model is handled alike, including fisheye lenses that cv2.solvePnP cannot take.
All solutions a method returns are refined (``refine=True``) and the best kept. For a
planar target the refinement also starts from the *planar twin* of that pose (its mirror
image about the line of sight, the other near-solution every planar pose has) and keeps
whichever fits better, so a method that returned the wrong twin is corrected (``flipped``)
and the twin's RMS is recorded (``alternative_rms_px``): EPnP returns the wrong twin on
about one planar view in eight. A twin whose start already reprojects more than 10 times
worse (RMS) than the pose is ruled out there, unrefined, and that start's RMS is recorded
(refining it could only lower it; no twin that refined to the better pose ever started
more than 1.9 times worse in 12 600 trials, see `estimate_pose`). This skips the twin's
refinement on most views, where perspective resolves the twin clearly.

Refinement and covariance
-------------------------
The refinement minimises ``sum_k |project(R X_k + t) - u_k|^2`` over the pose with
``project`` = `Camera.project` (raw pixels, full distortion), by Levenberg-Marquardt on
the parameters ``(delta, dt)``::

    R <- expm(skew(delta)) @ R        (left perturbation, in the camera frame; frames.py)
    t <- t + dt                       (t = t_cam_from_target, target length unit)

with the analytic Jacobian (lens Jacobian from `Camera.jacobian_pixels_from_normalized`).

``cov`` (6x6) is the covariance of the error of the estimate in these same coordinates,
rotation first: the true pose is ``R_true = expm(skew(d_rot)) @ R_hat`` and
``t_true = t_hat + d_t`` with ``(d_rot, d_t) ~ N(0, cov)``; d_rot is a rotation vector
in radians about the *camera* axes, d_t is in the length unit of the object points. It
is ``sigma^2 (J^T J)^-1`` at the optimum, with ``sigma`` the corner noise (px): given
(``corner_sigma_px``), or estimated from the residuals as
``sqrt(sum r^2 / (2 K - 6))`` (K corners). The translation block is *not* an SE(3)
(``exp(xi) T``) perturbation: rotation and translation are perturbed independently.
(COLMAP reports its covariance on the quaternion tangent, whose rotation block is a
quarter of ours at sigma = 1 px; see `colmap_covariance_to_pencilcal`.) The covariance
is local: it does not cover the planar twin, whose distance in RMS (`alternative_rms_px`
against `reproj_rms_px`) says how clearly the twin is ruled out.

It assumes independent corner errors. On real frames they need not be (blur, compression and
interlaced fields can correlate neighbouring corners), and what they share mostly moves the
pose, which no per-frame residual can show: on the da Vinci stereo pair the relative
rotation of the two cameras scatters by about as much as the covariances say, but only 31 %
of the frames fall inside their 68 % region (docs/experiments.md). Read PnP sigmas on real
frames as about 1.5 times too small.

Degenerate input never gives a pose: fewer points than the method needs, NaN/inf,
collinear object points, image points on one line (a plane seen edge-on), a pose with
points behind the camera, a numerically singular normal matrix, or a pose whose
reprojection RMS exceeds `max_rms_px` (a wrong local minimum) give ``ok=False`` and an
``error`` that says why.

Example
-------
>>> import numpy as np
>>> from pencilcal.toolkit.camera.model import Camera
>>> from pencilcal.toolkit.geometry.frames import rotation_about_axis
>>> cam = Camera("opencv", 1280, 720, [[900.0, 0, 639.5], [0, 900.0, 359.5], [0, 0, 1]],
...              [-0.2, 0.05, 0.0, 0.0])
>>> j, i = np.mgrid[1:5, 1:7]
>>> X = np.stack([i.ravel() * 30.0, j.ravel() * 30.0, np.zeros(24)], -1)   # mm
>>> R = rotation_about_axis([1.0, 0.2, 0.0], np.radians(30))
>>> t = np.array([-100.0, -70.0, 500.0])
>>> u = cam.project(X @ R.T + t)
>>> res = estimate_pose(X, u, cam, method="sqpnp", corner_sigma_px=0.2)
>>> res.ok, bool(np.allclose(res.R_cam_from_target, R, atol=1e-9)), res.cov.shape
(True, True, (6, 6))
>>> bool(res.reproj_rms_px < 1e-6)
True
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from pencilcal.toolkit.errors import InputError
from pencilcal.toolkit.io.files import load_frames, write_json
from pencilcal.toolkit.geometry.frames import rotvec_from_rotation

__all__ = [
    "METHODS",
    "DEFAULT_METHOD",
    "DEFAULT_MAX_RMS_PX",
    "PoseResult",
    "estimate_pose",
    "estimate_all",
    "best_method",
    "refine_pose",
    "pose_covariance",
    "colmap_covariance_to_pencilcal",
    "frame_record",
    "empty_frame_record",
    "write_poses",
    "read_poses",
    "POSE_KEYS",
    "COV_CONVENTION",
]

#: Estimation methods, in the order `estimate_all` runs them.
METHODS = ("sqpnp", "ippe", "iterative", "epnp", "colmap")
DEFAULT_METHOD = "sqpnp"
#: Reprojection RMS [px] above which a pose is rejected as a wrong local minimum.
DEFAULT_MAX_RMS_PX = 5.0
_CV_FLAG_NAMES = {"iterative": "SOLVEPNP_ITERATIVE", "sqpnp": "SOLVEPNP_SQPNP",
                  "ippe": "SOLVEPNP_IPPE", "epnp": "SOLVEPNP_EPNP"}
#: Fewest points each method takes here (iterative: on a plane; 6 off a plane).
MIN_POINTS = {"iterative": 4, "sqpnp": 4, "ippe": 4, "epnp": 4, "colmap": 4}
_ITERATIVE_NONPLANAR_MIN = 6
# OpenCV's planarity test (isPlanarObjectPoints / findExtrinsicCameraParams2): the smallest
# eigenvalue of the centred scatter matrix below 1e-3 times the middle one.
_PLANAR_RATIO = 1e-3
# relative singular values below which points count as collinear
_COLLINEAR_TOL = 1e-9
_IMAGE_COLLINEAR_TOL = 1e-7
# a planar twin whose start reprojects this many times worse (RMS) than the best pose is
# ruled out without refinement (see estimate_pose)
_TWIN_RULED_OUT = 10.0
# smallest eigenvalue of the Jacobi-scaled normal matrix, relative to the largest, below
# which the pose is numerically undetermined
_SINGULAR_TOL = 1e-13

#: The keys INTERFACES.md promises in every poses.json frame.
POSE_KEYS = ("image", "ok", "method", "R_cam_from_target", "t_cam_from_target", "rvec", "tvec",
             "reproj_rms_px", "corners", "cov")

#: One-line statement of the covariance convention, written into poses.json.
COV_CONVENTION = ("cov is 6x6 over (d_rot, d_t): R_true = expm(skew(d_rot)) @ R_cam_from_target "
                  "(rotation vector in rad about the camera axes, left perturbation), "
                  "t_true = t_cam_from_target + d_t (target length unit)")


@dataclass
class PoseResult:
    """One pose estimate of a target in a camera.

    Attributes
    ----------
    ok : bool
        False when no pose was found; then `error` says why and the pose fields are None.
    method : str
        One of `METHODS`.
    error : str or None
        Why there is no pose (one line).
    R_cam_from_target : (3, 3) ndarray or None
        Rotation, ``p_cam = R p_target + t``.
    t_cam_from_target : (3,) ndarray or None
        Translation [length unit of the object points].
    reproj_rms_px : float or None
        RMS of the per-corner reprojection error ``sqrt(mean |r_k|^2)`` [px].
    residuals_px : (K, 2) ndarray or None
        ``projected - observed`` raw pixels per corner, in the input order.
    cov : (6, 6) ndarray or None
        Covariance of (d_rot [rad], d_t [length]), rotation first; see the module doc.
    sigma_px : float or None
        Corner noise behind `cov` [px].
    sigma_from : {"given", "residuals"} or None
    corners : int
        Number of correspondences used.
    refined : bool
        Whether the LM refinement in raw pixels ran.
    lm_iterations : int
    refine_change_deg, refine_change : float or None
        How far the refinement moved the method's own pose: rotation [deg] and
        translation [length unit].
    flipped : bool
        True when the pose came from the planar twin of the method's own pose, i.e. the
        method returned the wrong one of a planar target's two near-solutions.
    alternative_rms_px, alternative_angle_deg : float or None
        The runner-up: IPPE's other solution, or (refined, planar targets) the planar
        twin; its RMS [px] and rotation angle from the chosen pose [deg]. An angle near 0
        means both converged to the same pose: no ambiguity left. A twin ruled out at its
        start (more than 10 times the pose's RMS) is reported there, unrefined.
    extra : dict
        Method-specific facts (``colmap_inliers``).
    time_s : float
        Wall time of the estimate [s].
    """

    ok: bool
    method: str
    error: str | None = None
    R_cam_from_target: np.ndarray | None = None
    t_cam_from_target: np.ndarray | None = None
    reproj_rms_px: float | None = None
    residuals_px: np.ndarray | None = None
    cov: np.ndarray | None = None
    sigma_px: float | None = None
    sigma_from: str | None = None
    corners: int = 0
    refined: bool = False
    lm_iterations: int = 0
    refine_change_deg: float | None = None
    refine_change: float | None = None
    flipped: bool = False
    alternative_rms_px: float | None = None
    alternative_angle_deg: float | None = None
    extra: dict = field(default_factory=dict)
    time_s: float = 0.0

    @property
    def rvec(self):
        """(3,) rotation vector of R_cam_from_target [rad], as cv2.Rodrigues; None if not ok."""
        return None if self.R_cam_from_target is None else rotvec_from_rotation(self.R_cam_from_target)

    @property
    def tvec(self):
        """(3,) = t_cam_from_target (OpenCV's name); None if not ok."""
        return None if self.t_cam_from_target is None else self.t_cam_from_target.copy()

    @property
    def normal(self):
        """(3,) target z axis in the camera frame, R[:, 2] (points away from the camera)."""
        return None if self.R_cam_from_target is None else self.R_cam_from_target[:, 2].copy()

    @property
    def distance(self):
        """|t_cam_from_target|: distance of the target origin [length unit]."""
        return None if self.t_cam_from_target is None else float(np.linalg.norm(self.t_cam_from_target))

    @property
    def rotation_sigma_deg(self):
        """(3,) standard deviations of d_rot about the camera x, y, z axes [deg]."""
        return None if self.cov is None else np.degrees(np.sqrt(np.maximum(np.diag(self.cov)[:3], 0.0)))

    @property
    def translation_sigma(self):
        """(3,) standard deviations of t_cam_from_target along camera x, y, z [length unit]."""
        return None if self.cov is None else np.sqrt(np.maximum(np.diag(self.cov)[3:], 0.0))

    @property
    def normal_sigma_deg(self):
        """RMS angular error of `normal` [deg]: sqrt(trace(P C_rot P)), P = I - n n^T."""
        if self.cov is None:
            return None
        n = self.R_cam_from_target[:, 2]
        P = np.eye(3) - np.outer(n, n)
        return float(np.degrees(np.sqrt(max(np.trace(P @ self.cov[:3, :3] @ P), 0.0))))

    def to_dict(self, residuals=True):
        """JSON-ready record of this estimate (numpy arrays are converted on writing).

        Keys: ok, error, method, corners, R_cam_from_target, t_cam_from_target, rvec, tvec,
        normal, distance, reproj_rms_px, cov, sigma_px, sigma_from, rotation_sigma_deg,
        translation_sigma, normal_sigma_deg, alternative_rms_px, alternative_angle_deg,
        refined, refine_change_deg, refine_change, lm_iterations, extra keys, and with
        `residuals` also residuals_px.
        """
        d = {
            "ok": bool(self.ok), "error": self.error, "method": self.method, "corners": int(self.corners),
            "R_cam_from_target": self.R_cam_from_target, "t_cam_from_target": self.t_cam_from_target,
            "rvec": self.rvec, "tvec": self.tvec, "normal": self.normal, "distance": self.distance,
            "reproj_rms_px": self.reproj_rms_px, "cov": self.cov, "sigma_px": self.sigma_px,
            "sigma_from": self.sigma_from, "rotation_sigma_deg": self.rotation_sigma_deg,
            "translation_sigma": self.translation_sigma, "normal_sigma_deg": self.normal_sigma_deg,
            "flipped": bool(self.flipped), "alternative_rms_px": self.alternative_rms_px,
            "alternative_angle_deg": self.alternative_angle_deg,
            "refined": bool(self.refined), "refine_change_deg": self.refine_change_deg,
            "refine_change": self.refine_change, "lm_iterations": int(self.lm_iterations),
        }
        d.update(self.extra)
        if residuals:
            d["residuals_px"] = self.residuals_px
        return d


# ------------------------------------------------------------------------- projection
_ZERO3 = np.zeros(3)


def _cv_intrinsics(camera):
    """(K, dist) for cv2.projectPoints where it computes exactly `camera`'s model (opencv
    or pinhole without skew: OpenCV drops K[0, 1]), else None (fisheye, skew)."""
    K = camera.K
    if camera.model == "fisheye" or K[0, 1] != 0.0:
        return None
    return np.ascontiguousarray(K, float), (np.ascontiguousarray(camera.dist, float) if camera.dist.size else None)


def _projector(camera, X, obs):
    """f(R, t, jacobian=True) -> (r, J, front) for fixed correspondences X (K, 3), obs (K, 2).

    r (K, 2): projected - observed raw pixels, NaN where a point is not in front of the
    camera; J (2K, 6): d r / d (delta, dt), rows (u, v) per corner (or None); front (K,).
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


def _residuals(camera, X, obs, R, t, jacobian=True):
    """Residuals projected - observed (K, 2) and the Jacobian (2K, 6) in (d_rot, d_t).

    Returns (r, J, in_front); r is NaN where a point is not in front of the camera.
    """
    return _projector(camera, X, obs)(np.asarray(R, float), np.asarray(t, float), jacobian)


# Undistortion by cv2.undistortPoints, accepted where the lens model maps the result back
# onto the pixel to this (normalised, distorted) tolerance, as Camera.normalized_from_pixels
# accepts its own, and the model is invertible from the centre out to it (det J > 0 on
# these fractions of the way: Camera's fold test).
_UNDISTORT_TOL = 1e-11
_FOLD_FRACTIONS = np.linspace(0.0, 1.0, 9)[1:]
_UNDISTORT_CRITERIA = (3, 100, 1e-12)  # cv2.TERM_CRITERIA_COUNT + EPS, iterations, px


def _normalized(camera, u):
    """Undistorted normalised coordinates (K, 2) of raw pixels u (K, 2), NaN where they
    cannot be undistorted: `Camera.normalized_from_pixels`, or for the opencv model
    without sensor tilt or skew the same roots from OpenCV's iteration, checked."""
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


def _rotation_from_rotvec(v):
    """Rodrigues' formula (cv2.Rodrigues) for one (3,) rotation vector."""
    import cv2

    return cv2.Rodrigues(np.ascontiguousarray(v, float))[0]


def _angle(R_a, R_b):
    """Geodesic angle [rad] between two rotations (frames.rotation_angle for one pair)."""
    M = (R_a.T @ R_b).tolist()
    # the antisymmetric part keeps precision for tiny angles where acos(trace) does not
    s = 0.5 * math.sqrt((M[2][1] - M[1][2]) ** 2 + (M[0][2] - M[2][0]) ** 2 + (M[1][0] - M[0][1]) ** 2)
    return math.atan2(s, 0.5 * (M[0][0] + M[1][1] + M[2][2] - 1.0))


# relative cost decrease below which the refinement has converged
_LM_TOL = 1e-12


def _lm(project, R, t, max_iterations=100):
    """Levenberg-Marquardt from (R, t) with ``project`` from `_projector`.

    Returns (R, t, iterations, r, J): the residuals and Jacobian at the returned pose, or
    r = J = None where the start has points behind the camera (R, t returned unchanged).
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
                R_new = _rotation_from_rotvec(rot) @ R
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


def _orthonormal(R):
    """The nearest rotation: keeps R exactly orthonormal after many small updates."""
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
    R, t, it, r, _ = _lm(_projector(camera, X, obs), R, t, max_iterations)
    if r is None:
        return R, t, 0
    return _orthonormal(R), t, it


def _covariance(J, r, corner_sigma_px=None):
    """cov, sigma from the Jacobian (2K, 6) and residuals (K, 2) at the optimum; see
    `pose_covariance`."""
    from pencilcal.toolkit.errors import EstimationError

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
    from pencilcal.toolkit.errors import EstimationError

    X = np.asarray(object_points, float)
    obs = np.asarray(image_points, float)
    with np.errstate(all="ignore"):
        r, J, front = _residuals(camera, X, obs, R, t)
    if not np.all(front):
        raise EstimationError("some corners are behind the camera in this pose")
    cov, sigma = _covariance(J, r, corner_sigma_px)
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


# ------------------------------------------------------------------- initialisers
def _fail(method, error, corners=0, t0=None):
    return PoseResult(ok=False, method=method, error=error, corners=int(corners),
                      time_s=0.0 if t0 is None else time.perf_counter() - t0)


def _opencv_solutions(method, X, xy, camera):
    """Poses from cv2.solvePnPGeneric on undistorted points xy (normalised), as (R, t) list."""
    import cv2

    flag = getattr(cv2, _CV_FLAG_NAMES[method])
    # ideal pinhole pixels with the camera's focal lengths keep OpenCV's pixel-scaled
    # thresholds meaningful; no skew (OpenCV's PnP ignores it) and no distortion
    K = camera.K
    fx, fy, cx, cy = float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2])
    Kp = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    ideal = np.ascontiguousarray((xy * (fx, fy) + (cx, cy)).reshape(-1, 1, 2))
    obj = np.ascontiguousarray(X.reshape(-1, 1, 3))
    try:
        n, rvecs, tvecs, _ = cv2.solvePnPGeneric(obj, ideal, Kp, None, flags=flag)
    except cv2.error as e:
        lines = [ln.strip() for ln in str(e).splitlines() if ln.strip()]
        msg = next((ln.lstrip("> ") for ln in lines[1:] if ln.startswith(">")), lines[0] if lines else "failed")
        raise _MethodFailed(f"OpenCV {_CV_FLAG_NAMES[method]} failed: {msg}") from None
    out = []
    for i in range(int(n)):
        rv = np.asarray(rvecs[i], float).reshape(3)
        tv = np.asarray(tvecs[i], float).reshape(3)
        if np.all(np.isfinite(rv)) and np.all(np.isfinite(tv)):
            out.append((_rotation_from_rotvec(rv), tv))
    return out


def _colmap_solution(X, obs, camera, seed=0):
    """Pose from pycolmap.estimate_and_refine_absolute_pose on raw pixels (+0.5 px)."""
    import pycolmap

    from pencilcal.toolkit.camera.formats import camera_to_colmap

    cc = camera_to_colmap(camera, source="colmap method")  # InputError for models COLMAP lacks
    est = pycolmap.AbsolutePoseEstimationOptions()
    est.ransac.random_seed = int(seed)
    ref = pycolmap.AbsolutePoseRefinementOptions()
    ref.gradient_tolerance = 1e-10
    ref.max_num_iterations = 100
    try:
        ans = pycolmap.estimate_and_refine_absolute_pose(
            np.ascontiguousarray(obs + 0.5), np.ascontiguousarray(X), cc, est, ref)
    except Exception as e:  # pycolmap raises ValueError/RuntimeError with C++ check text
        text = str(e).strip()
        raise _MethodFailed(f"pycolmap failed: {text.splitlines()[0] if text else type(e).__name__}") from None
    if ans is None or not ans.get("success", True):
        raise _MethodFailed("pycolmap found no pose (LO-RANSAC failed)")
    cfw = ans["cam_from_world"]
    R = np.asarray(cfw.rotation.matrix(), float)
    t = np.asarray(cfw.translation, float).reshape(3)
    return [(R, t)], {"colmap_inliers": int(ans["num_inliers"])}


class _MethodFailed(Exception):
    pass


# -------------------------------------------------------------------------- public
def _check_arrays(object_points, image_points, method, corner_sigma_px):
    if method not in METHODS:
        raise InputError(f"unknown PnP method {method!r}; expected one of {', '.join(METHODS)}")
    try:
        X = np.array(object_points, dtype=float)
        u = np.array(image_points, dtype=float)
    except (TypeError, ValueError):
        raise InputError("object and image points must be arrays of numbers") from None
    if X.ndim != 2 or X.shape[1] != 3:
        raise InputError(f"object points must have shape (K, 3), got {X.shape}")
    if u.ndim != 2 or u.shape[1] != 2:
        raise InputError(f"image points must have shape (K, 2), got {u.shape}")
    if X.shape[0] != u.shape[0]:
        raise InputError(f"{X.shape[0]} object points but {u.shape[0]} image points")
    if corner_sigma_px is not None:
        s = corner_sigma_px
        if isinstance(s, bool) or not isinstance(s, (int, float, np.floating, np.integer)) \
                or not np.isfinite(s) or s <= 0:
            raise InputError(f"corner sigma must be a positive number of pixels, got {s!r}")
    return X, u


def _scatter(X):
    """Centroid, singular values and right singular vectors of the centred points."""
    c = X.mean(0)
    _, s, Vt = np.linalg.svd(X - c, full_matrices=False)
    return c, s, Vt


def _is_planar(X, s=None):
    """OpenCV's planarity test: smallest scatter eigenvalue below 1e-3 of the middle one."""
    if s is None:
        s = np.linalg.svd(X - X.mean(0), compute_uv=False)
    return bool(s[2] ** 2 < _PLANAR_RATIO * s[1] ** 2)


def _planar_twin(X, R, t, normal=None):
    """The other near-solution of a planar target: the pose mirrored about the line of sight.

    Under weak perspective a plane and its mirror image in the plane perpendicular to the
    line of sight d (to the target's centroid c) project alike. With M = I - 2 d d^T (in the
    camera frame) and S = I - 2 m m^T the reflection in the target's own plane (normal m),
    the twin R' = M R S is a rotation with R' (X - c) = M R (X - c) for every target point;
    the centroid stays in place. It is a start for the refinement, not a solution.
    normal: the plane's normal m where known. Returns (R', t').
    """
    c = X.mean(0)
    m = np.linalg.svd(X - c)[2][2] if normal is None else normal
    c_cam = R @ c + t
    d = c_cam / math.sqrt(c_cam @ c_cam)
    RS = R - 2.0 * np.outer(R @ m, m)  # R S
    R2 = RS - 2.0 * np.outer(d, d @ RS)  # M R S
    return R2, c_cam - R2 @ c


def _geometry_problem(X, method, s=None):
    """A one-line reason why these object points cannot give a pose by `method`, or None.

    s: the singular values of the centred points where known."""
    n = X.shape[0]
    need = MIN_POINTS[method]
    if n < need:
        return f"{method} needs at least {need} points, got {n}"
    if s is None:
        s = np.linalg.svd(X - X.mean(0), compute_uv=False)
    if s[0] == 0 or s[1] <= _COLLINEAR_TOL * s[0]:
        return "the object points are collinear (or coincide): the pose is not determined"
    planar = s[2] ** 2 < _PLANAR_RATIO * s[1] ** 2
    if method == "ippe" and not planar:
        return "ippe needs coplanar object points; these are not (use sqpnp or epnp)"
    if method == "iterative" and not planar and n < _ITERATIVE_NONPLANAR_MIN:
        return (f"iterative needs at least {_ITERATIVE_NONPLANAR_MIN} points off a plane "
                f"(OpenCV's DLT start), got {n}")
    return None


def estimate_pose(object_points, image_points, camera, method=DEFAULT_METHOD, refine=True,
                  corner_sigma_px=None, max_rms_px=DEFAULT_MAX_RMS_PX, seed=0):
    """Pose of a target from K point correspondences, refined in raw pixels, with covariance.

    Parameters
    ----------
    object_points : (K, 3) array_like
        Points in the target frame [length unit, e.g. mm], e.g. ``Board.object_points()[ids]``.
    image_points : (K, 2) array_like
        Their observed raw (distorted) pixels [px, OpenCV convention: (0, 0) is the centre
        of the top-left pixel].
    camera : Camera
        Intrinsics (pinhole, opencv or fisheye).
    method : {"sqpnp", "ippe", "iterative", "epnp", "colmap"}
        Initialiser; see the module doc.
    refine : bool
        Levenberg-Marquardt on the raw-pixel reprojection error (default), from every pose
        the method returns and, for planar targets, from the planar twin of the best.
        Without it the method's own pose is reported (the covariance is then only
        approximate).
    corner_sigma_px : float, optional
        Corner noise [px] for the covariance; default: estimated from the residuals with
        2K - 6 degrees of freedom.
    max_rms_px : float or None
        A pose whose reprojection RMS exceeds this [px] is not returned (``ok=False``): it
        is a wrong local minimum or the camera does not fit the images (or corners are
        mislabelled). None: no limit.
    seed : int
        RANSAC seed of the colmap method (results are reproducible).

    Returns
    -------
    PoseResult
        ``ok=False`` with `error` for degenerate input (fewer points than the method needs,
        NaN/inf, collinear object points, image points on a line, no solution in front of
        the camera, a numerically undetermined pose) and for a pose that does not explain
        the corners (RMS above `max_rms_px`).

    Raises
    ------
    InputError
        For arrays of the wrong shape, an unknown method or a bad sigma.

    Example
    -------
    >>> import numpy as np
    >>> from pencilcal.toolkit.camera.model import Camera
    >>> cam = Camera("pinhole", 640, 480, [[500.0, 0, 319.5], [0, 500.0, 239.5], [0, 0, 1]])
    >>> X = np.array([[0, 0, 0], [50, 0, 0], [0, 50, 0], [50, 50, 0], [25, 10, 0.0]])
    >>> res = estimate_pose(X, cam.project(X + [0, 0, 300.0]), cam, method="ippe")
    >>> res.ok, (np.round(res.t_cam_from_target, 6) + 0.0).tolist()
    (True, [0.0, 0.0, 300.0])
    >>> estimate_pose(X[:3], cam.project(X[:3] + [0, 0, 300.0]), cam).error
    'sqpnp needs at least 4 points, got 3'
    """
    t0 = time.perf_counter()
    X, u = _check_arrays(object_points, image_points, method, corner_sigma_px)
    if max_rms_px is not None and not (np.isfinite(max_rms_px) and max_rms_px > 0):
        raise InputError(f"the RMS limit must be a positive number of pixels, got {max_rms_px!r}")
    n = X.shape[0]
    if not (np.all(np.isfinite(X)) and np.all(np.isfinite(u))):
        return _fail(method, "the object or image points contain NaN or inf", n, t0)
    scatter = _scatter(X) if n >= MIN_POINTS[method] else None
    problem = _geometry_problem(X, method, None if scatter is None else scatter[1])
    if problem:
        return _fail(method, problem, n, t0)
    xy = _normalized(camera, u)
    bad = ~np.all(np.isfinite(xy), axis=1)
    if np.any(bad):
        return _fail(method, f"{int(bad.sum())} image point(s) cannot be undistorted (outside the lens "
                             "model's invertible part, or 90 degrees or more off the axis)", n, t0)
    s = np.linalg.svd(xy - xy.mean(0), compute_uv=False)
    if s[0] == 0 or s[1] <= _IMAGE_COLLINEAR_TOL * s[0]:
        return _fail(method, "the image points lie on one line (a plane seen edge-on?): the pose is "
                             "not determined", n, t0)
    extra = {}
    try:
        if method == "colmap":
            sols, extra = _colmap_solution(X, u, camera, seed)
        else:
            sols = _opencv_solutions(method, X, xy, camera)
    except (_MethodFailed, InputError) as e:
        return _fail(method, str(e), n, t0)
    if not sols:
        return _fail(method, f"{method} returned no pose", n, t0)
    project = _projector(camera, X, u)

    def candidate(R0, t_start, parent=None, refine=refine):
        with np.errstate(all="ignore"):
            if refine:
                R, t, its, r, J = _lm(project, R0, t_start)
                if r is None:
                    return None
            else:
                R, t, its, J = np.asarray(R0, float), np.asarray(t_start, float), 0, None
                r, _, front = project(R, t, jacobian=False)
                if not front.all():
                    return None
        rr = r.ravel()
        rms = math.sqrt(float(rr @ rr) / n)
        if not math.isfinite(rms):
            return None
        # raw: the method's own pose this candidate descends from
        raw = (R0, t_start) if parent is None else parent["raw"]
        return {"rms": rms, "R": R, "t": t, "its": its, "raw": raw, "flipped": parent is not None,
                "r": r, "J": J}

    candidates = [c for c in (candidate(R0, t_) for R0, t_ in sols) if c is not None]
    if not candidates:
        return _fail(method, f"{method} found no pose with every point in front of the camera", n, t0)
    candidates.sort(key=lambda c: c["rms"])
    if refine and _is_planar(X, scatter[1]):
        # the planar twin: refine also from the mirror image of the best pose about the
        # line of sight, so a method that returned the wrong one of a planar target's two
        # near-solutions is corrected, and the twin's RMS is recorded. A twin whose start
        # reprojects more than _TWIN_RULED_OUT times worse than the pose is ruled out as it
        # is, unrefined: in 12 600 trials (random views of random boards, 0.05-1 px noise,
        # pinhole, opencv and fisheye lenses; SQPnP, IPPE and EPnP poses) none of the 603
        # twins that refined to the better pose (all EPnP's) started more than 1.9 times
        # worse, while 87 % of the others started more than 10 times worse.
        twin = _planar_twin(X, candidates[0]["R"], candidates[0]["t"], normal=scatter[2][2])
        c = candidate(*twin, parent=candidates[0], refine=False)
        if c is not None and c["rms"] <= _TWIN_RULED_OUT * candidates[0]["rms"]:
            c = candidate(*twin, parent=candidates[0])
        if c is not None:
            candidates.append(c)
            candidates.sort(key=lambda c: c["rms"])
    # starts that converged to the same pose (IPPE's pair often does once refined): keep
    # the one the refinement moved least, so refine_change_deg describes the method
    best = candidates[0]
    same = [c for c in candidates if c["rms"] <= best["rms"] * (1 + 1e-9) + 1e-12
            and _angle(best["R"], c["R"]) < 1e-8]
    chosen = same[0] if len(same) == 1 else \
        min(same, key=lambda c: (c["flipped"], _angle(c["raw"][0], c["R"])))
    R, t = chosen["R"], chosen["t"]
    if refine:
        R = _orthonormal(R)
    # the runner-up: the best other pose that is really different, else the best other start
    others = [c for c in candidates if c is not chosen]
    alt, alt_angle = None, None
    for c in others:
        a = _angle(R, c["R"])
        if a > 1e-8:
            alt, alt_angle = c, a
            break
    if alt is None and others:
        alt, alt_angle = others[0], _angle(R, others[0]["R"])
    alt_rms = None if alt is None else alt["rms"]
    alt_angle = None if alt is None else math.degrees(alt_angle)
    if max_rms_px is not None and chosen["rms"] > max_rms_px:
        return _fail(method, f"{method} gave a pose with reprojection RMS {chosen['rms']:.2f} px > "
                             f"{max_rms_px:g} px: a wrong local minimum, or a camera that does not fit these images",
                     n, t0)
    # the covariance from the Jacobian at the optimum (the refinement's last one: R is
    # orthonormalised since by ~1e-16, which changes nothing here)
    r, J = chosen["r"], chosen["J"]
    if J is None:
        with np.errstate(all="ignore"):
            r, J, _ = project(R, t)
    try:
        cov, sigma = _covariance(J, r, corner_sigma_px)
    except ArithmeticError as e:
        return _fail(method, str(e), n, t0)
    if not math.isfinite(sigma):
        cov, sigma = None, None
    return PoseResult(
        ok=True, method=method, R_cam_from_target=R, t_cam_from_target=t, reproj_rms_px=chosen["rms"],
        residuals_px=r, cov=cov, sigma_px=sigma,
        sigma_from=None if sigma is None else ("given" if corner_sigma_px is not None else "residuals"),
        corners=n, refined=bool(refine), lm_iterations=int(chosen["its"]),
        refine_change_deg=math.degrees(_angle(chosen["raw"][0], R)) if refine else None,
        refine_change=float(np.linalg.norm(t - chosen["raw"][1])) if refine else None,
        flipped=bool(chosen["flipped"]), alternative_rms_px=alt_rms, alternative_angle_deg=alt_angle, extra=extra,
        time_s=time.perf_counter() - t0,
    )


def estimate_all(object_points, image_points, camera, methods=METHODS, refine=True, corner_sigma_px=None,
                 max_rms_px=DEFAULT_MAX_RMS_PX, seed=0):
    """Run `estimate_pose` with every method in `methods`.

    Returns
    -------
    dict
        method name -> PoseResult, in the order of `methods`.

    Example
    -------
    >>> import numpy as np
    >>> from pencilcal.toolkit.camera.model import Camera
    >>> cam = Camera("pinhole", 640, 480, [[500.0, 0, 319.5], [0, 500.0, 239.5], [0, 0, 1]])
    >>> X = np.array([[0, 0, 0], [50, 0, 0], [0, 50, 0], [50, 50, 0], [25, 10, 0.0]])
    >>> res = estimate_all(X, cam.project(X + [0, 0, 300.0]), cam)
    >>> [(m, r.ok) for m, r in res.items()]
    [('sqpnp', True), ('ippe', True), ('iterative', True), ('epnp', True), ('colmap', True)]
    """
    for m in methods:
        if m not in METHODS:
            raise InputError(f"unknown PnP method {m!r}; expected one of {', '.join(METHODS)}")
    return {m: estimate_pose(object_points, image_points, camera, m, refine, corner_sigma_px, max_rms_px, seed)
            for m in methods}


def best_method(results, prefer=DEFAULT_METHOD, tol_px=1e-6):
    """The method whose pose represents a frame: `prefer` unless another ok method reached
    a reprojection RMS lower by more than `tol_px` (a different, better minimum), then
    the lowest. None when no method is ok.

    results: dict name -> PoseResult (as `estimate_all` returns).
    """
    ok = {m: r for m, r in results.items() if r.ok}
    if not ok:
        return None
    lowest = min(ok, key=lambda m: ok[m].reproj_rms_px)
    if prefer in ok and ok[prefer].reproj_rms_px <= ok[lowest].reproj_rms_px + tol_px:
        return prefer
    return lowest


# -------------------------------------------------------------------- poses.json
_RECORD_KEYS = ("ok", "error", "method", "corners", "R_cam_from_target", "t_cam_from_target", "rvec", "tvec",
                "normal", "distance", "reproj_rms_px", "cov", "sigma_px", "sigma_from", "rotation_sigma_deg",
                "translation_sigma", "normal_sigma_deg", "flipped", "alternative_rms_px", "alternative_angle_deg",
                "refined", "refine_change_deg", "refine_change", "lm_iterations", "residuals_px")


def empty_frame_record(image, error, method=DEFAULT_METHOD, corners=0, ids=None):
    """A poses.json frame with no pose: ``ok`` false, `error`, every pose key None."""
    rec = {"image": str(image)}
    rec.update({k: None for k in _RECORD_KEYS})
    rec.update(ok=False, error=str(error), method=method, corners=int(corners), refined=False, lm_iterations=0)
    rec["ids"] = None if ids is None else np.asarray(ids, int).tolist()
    return rec


def frame_record(image, result, ids=None, methods=None):
    """One poses.json frame.

    Parameters
    ----------
    image : str
        Image (file) name.
    result : PoseResult
        The pose that represents the frame; its keys are at the frame level, so the
        INTERFACES.md keys (image, ok, method, R_cam_from_target, t_cam_from_target, rvec,
        tvec, reproj_rms_px, corners, cov) are always there (None when not ok).
    ids : (K,) array_like of int, optional
        Corner ids of the correspondences, in the order of ``residuals_px``.
    methods : dict name -> PoseResult, optional
        With --method all: every method's result, written under ``"methods"`` (without the
        per-corner residuals); `result` is then normally ``methods[best_method(methods)]``.

    Returns
    -------
    dict
    """
    rec = {"image": str(image)}
    rec.update(result.to_dict())
    rec["ids"] = None if ids is None else np.asarray(ids, int).tolist()
    if methods is not None:
        rec["methods"] = {m: r.to_dict(residuals=False) for m, r in methods.items()}
    return rec


def write_poses(path, frames, force=False, **meta):
    """Write poses.json atomically: ``{**meta, "cov_convention": ..., "frames": frames}``.

    frames: list of dicts from `frame_record` / `empty_frame_record`. Raises InputError if
    `path` exists and not `force`.
    """
    for i, f in enumerate(frames):
        missing = [k for k in POSE_KEYS if k not in f]
        if missing:
            raise InputError(f"poses frame {i} lacks {missing}")
    out = dict(meta)
    out["cov_convention"] = COV_CONVENTION
    out["frames"] = list(frames)
    write_json(path, out, force=force)


_ARRAY_SHAPES = {"R_cam_from_target": (3, 3), "t_cam_from_target": (3,), "rvec": (3,), "tvec": (3,),
                 "normal": (3,), "cov": (6, 6), "rotation_sigma_deg": (3,), "translation_sigma": (3,)}


def _frame_arrays(f, where):
    out = dict(f)
    for k, shape in _ARRAY_SHAPES.items():
        v = f.get(k)
        if v is None:
            continue
        try:
            a = np.array(v, dtype=float)
        except (TypeError, ValueError):
            raise InputError(f"{where}: '{k}' must be numbers") from None
        if a.shape != shape:
            raise InputError(f"{where}: '{k}' must have shape {shape}, got {a.shape}")
        out[k] = a
    if f.get("residuals_px") is not None:
        a = np.array(f["residuals_px"], dtype=float)
        if a.ndim != 2 or a.shape[1] != 2:
            raise InputError(f"{where}: 'residuals_px' must be K x 2")
        out["residuals_px"] = a
    if f.get("ids") is not None:
        out["ids"] = np.array(f["ids"], dtype=int)
    return out


def read_poses(path):
    """Read a poses.json (pencilcal pnp) with its pose arrays as numpy arrays.

    Returns the file's object with ``frames`` a list of dicts whose R_cam_from_target
    (3, 3), t_cam_from_target, rvec, tvec, normal (3,), cov (6, 6), residuals_px (K, 2)
    and ids (K,) are ndarrays (None where the file has null); the per-method records under
    ``methods`` likewise. InputError with a one-line reason for anything malformed: every
    frame needs the INTERFACES.md keys, and an ok frame a finite rotation and translation.

    Example
    -------
    >>> import os, tempfile
    >>> p = os.path.join(tempfile.mkdtemp(), "poses.json")
    >>> write_poses(p, [empty_frame_record("a.png", "no board")], camera="cam.yaml")
    >>> d = read_poses(p)
    >>> d["camera"], d["frames"][0]["ok"], d["frames"][0]["error"]
    ('cam.yaml', False, 'no board')
    """
    data, frames = load_frames(path, "poses file", POSE_KEYS)
    out = []
    for f, where in frames:
        if not isinstance(f["ok"], bool):
            raise InputError(f"{where}: 'ok' must be true or false")
        g = _frame_arrays(f, where)
        if g["ok"]:
            for k in ("R_cam_from_target", "t_cam_from_target"):
                if g.get(k) is None or not np.all(np.isfinite(g[k])):
                    raise InputError(f"{where}: an ok frame needs a finite '{k}'")
        if isinstance(f.get("methods"), dict):
            g["methods"] = {m: _frame_arrays(r, f"{where}: method {m}") if isinstance(r, dict) else r
                            for m, r in f["methods"].items()}
        out.append(g)
    res = dict(data)
    res["frames"] = out
    return res
