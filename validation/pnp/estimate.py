"""Board pose estimation: the initialisers, `estimate_pose`, `estimate_all` and `best_method`.

Every initialiser (OpenCV's solvers on undistorted points, or pycolmap's LO-RANSAC on raw
pixels) gives one or more starts; each is refined in raw pixels (`refine`), a planar target
also from the planar twin of the best, and the best kept, with its covariance
(`covariance`). The methods, the planar twin and the degenerate inputs are described in
`pencilcal.validation.pnp`.

Example
-------
>>> import numpy as np
>>> from pencilcal.toolkit.camera.model import Camera
>>> cam = Camera("pinhole", 640, 480, [[500.0, 0, 319.5], [0, 500.0, 239.5], [0, 0, 1]])
>>> X = np.array([[0, 0, 0], [50, 0, 0], [0, 50, 0], [50, 50, 0], [25, 10, 0.0]])
>>> res = estimate_all(X, cam.project(X + [0, 0, 300.0]), cam, methods=("sqpnp", "ippe"))
>>> best_method(res), res["sqpnp"].corners
('sqpnp', 5)
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass
from types import MappingProxyType

import numpy as np

from pencilcal.toolkit.board.calibration_file import board_model, symmetric_corners_of, uncertainty_of
from pencilcal.toolkit.errors import InputError

from .covariance import covariance_from_jacobian, total_covariance
from .refine import levenberg_marquardt, normalized_points, orthonormal, projector, rotation_angle_rad, \
    rotation_from_rotvec
from .result import DEFAULT_METHOD, METHODS, PoseResult

__all__ = ["DEFAULT_MAX_RMS_PX", "MIN_POINTS", "estimate_pose", "estimate_all", "best_method", "board_pose",
           "board_points"]

#: Reprojection RMS [px] above which a pose is rejected as a wrong local minimum.
DEFAULT_MAX_RMS_PX = 5.0
_CV_FLAG_NAMES = MappingProxyType({"iterative": "SOLVEPNP_ITERATIVE", "sqpnp": "SOLVEPNP_SQPNP",
                                   "ippe": "SOLVEPNP_IPPE", "epnp": "SOLVEPNP_EPNP"})
#: Fewest points each method takes here (iterative: on a plane; 6 off a plane).
MIN_POINTS = MappingProxyType({"iterative": 4, "sqpnp": 4, "ippe": 4, "epnp": 4, "colmap": 4})
_ITERATIVE_NONPLANAR_MIN = 6
# OpenCV's planarity test (isPlanarObjectPoints / findExtrinsicCameraParams2): the smallest
# eigenvalue of the centred scatter matrix below 1e-3 times the middle one.
_PLANAR_RATIO = 1e-3
# relative singular values below which points count as collinear
_COLLINEAR_TOL = 1e-9
_IMAGE_COLLINEAR_TOL = 1e-7
# a planar twin whose start reprojects this many times worse (RMS) than the best pose is
# ruled out without refinement (see _candidates)
_TWIN_RULED_OUT = 10.0


# ------------------------------------------------------------------- initialisers
def _fail(method, error, corners=0, t0=None):
    """The result of an estimate that gave no pose: `error` says why (one line)."""
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
            out.append((rotation_from_rotvec(rv), tv))
    return out


def _colmap_solution(X, obs, camera, seed=0):
    """Pose from pycolmap.estimate_and_refine_absolute_pose on raw pixels (+0.5 px)."""
    from pencilcal.toolkit.camera.formats import camera_to_colmap
    from pencilcal.validation.sfm.glog import import_pycolmap

    pycolmap = import_pycolmap()

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
    """An initialiser failed; its message is the result's error."""


def _check_arrays(object_points, image_points, method, corner_sigma_px):
    """X (K, 3), u (K, 2) as float arrays; InputError for wrong shapes, method or sigma."""
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
                  corner_sigma_px=None, max_rms_px=DEFAULT_MAX_RMS_PX, seed=0, *, corner_noise="camera",
                  intrinsics_cov="camera", board_warp=None):
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
    corner_noise : CornerNoise, "camera" or None
        Correlated corner errors (`toolkit.board.corner_noise`) for ``cov_total``;
        "camera" (default): the model the camera file's statistics carry (``corner_noise``,
        written by `pencilcal calibrate`), if any.
    intrinsics_cov : (P, P) array_like, IntrinsicsCovariance, "camera" or None
        Covariance of the camera's intrinsics (`toolkit.camera.intrinsics`) for
        ``cov_total``; "camera" (default): the one the camera file carries
        (``cov_intrinsics``), if any. With either, ``cov_total`` (6, 6) holds the corner term
        of that model and the intrinsics' (`covariance.total_covariance`); ``cov`` stays
        the white corner-noise covariance.
    board_warp : (basis (K, W), cov (W, W)), optional
        The board's warp the object points carry (W = 2, or 3 with the board's twist), per point, and its covariance
        (`toolkit.board.calibration_file.board_model`, which `board_pose` uses): ``cov_total``
        then holds the warp's term too.

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
    if board_warp is not None and (np.ndim(board_warp[0]) != 2 or np.shape(board_warp[0])[0] != X.shape[0]
                                   or np.shape(board_warp[0])[1] not in (2, 3)):
        raise InputError(f"the board warp's basis must be ({X.shape[0]}, 2), or ({X.shape[0]}, 3) with the twist, "
                         f"got {np.shape(board_warp[0])}")
    if max_rms_px is not None and not (np.isfinite(max_rms_px) and max_rms_px > 0):
        raise InputError(f"the RMS limit must be a positive number of pixels, got {max_rms_px!r}")
    n = X.shape[0]
    problem, scatter, xy = _input_problem(X, u, camera, method)
    if problem:
        return _fail(method, problem, n, t0)
    try:
        starts, extra = _method_poses(method, X, u, xy, camera, seed)
    except (_MethodFailed, InputError) as e:
        return _fail(method, str(e), n, t0)
    if not starts:
        return _fail(method, f"{method} returned no pose", n, t0)
    project = projector(camera, X, u)
    candidates = _candidates(project, X, starts, scatter, refine)
    if not candidates:
        return _fail(method, f"{method} found no pose with every point in front of the camera", n, t0)
    chosen = _chosen(candidates)
    R, t = chosen.R, chosen.t
    if refine:
        R = orthonormal(R)
    alt_rms, alt_angle = _runner_up(R, candidates, chosen)
    if max_rms_px is not None and chosen.rms > max_rms_px:
        return _fail(method, f"{method} gave a pose with reprojection RMS {chosen.rms:.2f} px > "
                             f"{max_rms_px:g} px: a wrong local minimum, or a camera that does not fit these images",
                     n, t0)
    try:
        cov, sigma, r = _covariance_at(project, chosen, R, t, corner_sigma_px)
        total = _total_at(project, chosen, R, t, camera, X, u, cov, corner_noise, intrinsics_cov, board_warp)
    except ArithmeticError as e:
        return _fail(method, str(e), n, t0)
    return PoseResult(
        ok=True, method=method, R_cam_from_target=R, t_cam_from_target=t, reproj_rms_px=chosen.rms,
        residuals_px=r, cov=cov, sigma_px=sigma,
        sigma_from=None if sigma is None else ("given" if corner_sigma_px is not None else "residuals"),
        corners=n, refined=bool(refine), lm_iterations=int(chosen.its),
        refine_change_deg=math.degrees(rotation_angle_rad(chosen.raw[0], R)) if refine else None,
        refine_change=float(np.linalg.norm(t - chosen.raw[1])) if refine else None,
        flipped=bool(chosen.flipped), alternative_rms_px=alt_rms, alternative_angle_deg=alt_angle, extra=extra,
        time_s=time.perf_counter() - t0, **total,
    )


def board_pose(image, camera, board, method=DEFAULT_METHOD, **options):
    """The pose of a calibration board in one image: detect its corners, then `estimate_pose`.

    image : (H, W[, 3]) array (raw, as the camera took it); camera : Camera;
    board : Board (toolkit.board.spec); method and options : as `estimate_pose`. ChArUco
    corners are refined to their point of symmetry where the camera's calibration refined
    them so (`calibration_file.symmetric_corners_of`).
    Returns a PoseResult (R_cam_from_target, t_cam_from_target in the board's length unit,
    cov 6x6); ``ok`` is false with `error` when too few corners are found.
    """
    from pencilcal.toolkit.board.detect import detect_board

    det = detect_board(image, board, symmetric_corners_of(camera))
    X, warp = board_points(board, camera, det.ids)
    return estimate_pose(X, det.corners, camera, method=method, board_warp=warp, **options)


def board_points(board, camera, ids):
    """The corners `ids` (K,) of `board` as `camera`'s calibration measured them, for
    `estimate_pose`: (object points (K, 3) [board unit], its ``board_warp`` keyword: (basis
    (K, 2), cov (2, 2)) or None). With the warp of this board in the camera's statistics
    (`toolkit.board.calibration_file.board_model`) the points carry it and the pose's
    ``cov_total`` its sigma; otherwise the nominal points and None.

    >>> from pencilcal.toolkit.board.spec import board_from_dict
    >>> from pencilcal.toolkit.camera.model import Camera
    >>> b = board_from_dict({"type": "chessboard", "squares": [3, 2], "square": 10.0})
    >>> cam = Camera("pinhole", 640, 480, [[500.0, 0, 320], [0, 500.0, 240], [0, 0, 1]])
    >>> X, warp = board_points(b, cam, [1, 4])
    >>> X.tolist(), warp
    ([[10.0, 0.0, 0.0], [10.0, 10.0, 0.0]], None)
    """
    X, basis, cov = board_model(board, camera)
    ids = np.asarray(ids, int).ravel()
    return X[ids], (None if basis is None or cov is None else (basis[ids], cov))


# ------------------------------------------------------------------ estimate_pose's steps
def _input_problem(X, u, camera, method):
    """(reason, scatter, xy): why these points cannot give a pose by `method` (None when
    they can), the object points' `_scatter` and the undistorted normalised image points
    xy (K, 2) (None past a problem)."""
    n = X.shape[0]
    if not (np.all(np.isfinite(X)) and np.all(np.isfinite(u))):
        return "the object or image points contain NaN or inf", None, None
    scatter = _scatter(X) if n >= MIN_POINTS[method] else None
    problem = _geometry_problem(X, method, None if scatter is None else scatter[1])
    if problem:
        return problem, scatter, None
    xy = normalized_points(camera, u)
    bad = ~np.all(np.isfinite(xy), axis=1)
    if np.any(bad):
        return (f"{int(bad.sum())} image point(s) cannot be undistorted (outside the lens "
                "model's invertible part, or 90 degrees or more off the axis)"), scatter, None
    s = np.linalg.svd(xy - xy.mean(0), compute_uv=False)
    if s[0] == 0 or s[1] <= _IMAGE_COLLINEAR_TOL * s[0]:
        return ("the image points lie on one line (a plane seen edge-on?): the pose is "
                "not determined"), scatter, None
    return None, scatter, xy


def _method_poses(method, X, u, xy, camera, seed):
    """(starts, extra): the method's own poses, a list of (R (3, 3), t (3,)), and its
    method-specific facts. Raises _MethodFailed or InputError."""
    if method == "colmap":
        return _colmap_solution(X, u, camera, seed)
    return _opencv_solutions(method, X, xy, camera), {}


@dataclass(eq=False)
class _Candidate:
    """One refined (or, unrefined, ruled-out) start: its RMS [px], pose, LM iterations, the
    method's own pose it descends from (raw: (R, t)), whether it is the planar twin of that
    pose, and the residuals (K, 2) and Jacobian (2K, 6, None when unrefined) at the pose."""

    rms: float
    R: np.ndarray
    t: np.ndarray
    its: int
    raw: tuple
    flipped: bool
    r: np.ndarray
    J: np.ndarray | None


def _candidate(project, R0, t_start, parent=None, refine=True):
    """The `_Candidate` from one start (refined unless not `refine`), or None when the start
    or the refined pose has points behind the camera or a non-finite RMS."""
    with np.errstate(all="ignore"):
        if refine:
            R, t, its, r, J = levenberg_marquardt(project, R0, t_start)
            if r is None:
                return None
        else:
            R, t, its, J = np.asarray(R0, float), np.asarray(t_start, float), 0, None
            r, _, front = project(R, t, jacobian=False)
            if not front.all():
                return None
    rr = r.ravel()
    rms = math.sqrt(float(rr @ rr) / r.shape[0])
    if not math.isfinite(rms):
        return None
    raw = (R0, t_start) if parent is None else parent.raw
    return _Candidate(rms, R, t, its, raw, parent is not None, r, J)


def _candidates(project, X, starts, scatter, refine):
    """Every start refined, best (lowest RMS) first; for a planar target also the planar
    twin of the best. Empty when no start keeps every point in front of the camera."""
    candidates = [c for c in (_candidate(project, R0, t_, refine=refine) for R0, t_ in starts) if c is not None]
    if not candidates:
        return candidates
    candidates.sort(key=lambda c: c.rms)
    if refine and _is_planar(X, scatter[1]):
        # the planar twin: refine also from the mirror image of the best pose about the
        # line of sight, so a method that returned the wrong one of a planar target's two
        # near-solutions is corrected, and the twin's RMS is recorded. A twin whose start
        # reprojects more than _TWIN_RULED_OUT times worse than the pose is ruled out as it
        # is, unrefined: in 12 600 trials (random views of random boards, 0.05-1 px noise,
        # pinhole, opencv and fisheye lenses; SQPnP, IPPE and EPnP poses) none of the 603
        # twins that refined to the better pose (all EPnP's) started more than 1.9 times
        # worse, while 87 % of the others started more than 10 times worse.
        twin = _planar_twin(X, candidates[0].R, candidates[0].t, normal=scatter[2][2])
        c = _candidate(project, *twin, parent=candidates[0], refine=False)
        if c is not None and c.rms <= _TWIN_RULED_OUT * candidates[0].rms:
            c = _candidate(project, *twin, parent=candidates[0])
        if c is not None:
            candidates.append(c)
            candidates.sort(key=lambda c: c.rms)
    return candidates


def _chosen(candidates):
    """The candidate that represents the method: the best, and among starts that converged
    to the same pose (IPPE's pair often does once refined) the one the refinement moved
    least, so refine_change_deg describes the method."""
    best = candidates[0]
    same = [c for c in candidates if c.rms <= best.rms * (1 + 1e-9) + 1e-12
            and rotation_angle_rad(best.R, c.R) < 1e-8]
    if len(same) == 1:
        return same[0]
    return min(same, key=lambda c: (c.flipped, rotation_angle_rad(c.raw[0], c.R)))


def _runner_up(R, candidates, chosen):
    """(RMS [px], angle from R [deg]) of the runner-up: the best other candidate whose pose
    really differs, else the best other start; (None, None) when there is none."""
    others = [c for c in candidates if c is not chosen]
    alt, alt_angle = None, None
    for c in others:
        a = rotation_angle_rad(R, c.R)
        if a > 1e-8:
            alt, alt_angle = c, a
            break
    if alt is None and others:
        alt, alt_angle = others[0], rotation_angle_rad(R, others[0].R)
    if alt is None:
        return None, None
    return alt.rms, math.degrees(alt_angle)


def _covariance_at(project, chosen, R, t, corner_sigma_px):
    """(cov (6, 6), sigma [px], residuals (K, 2) [px]) at the chosen pose, from the
    refinement's last Jacobian (R is orthonormalised since by ~1e-16, which changes
    nothing here); cov and sigma None where sigma is not finite (3 corners or fewer).
    Raises ArithmeticError when the pose is not determined."""
    r, J = chosen.r, chosen.J
    if J is None:
        with np.errstate(all="ignore"):
            r, J, _ = project(R, t)
    cov, sigma = covariance_from_jacobian(J, r, corner_sigma_px)
    if not math.isfinite(sigma):
        cov, sigma = None, None
    return cov, sigma, r


def _resolve_total(camera, corner_noise, intrinsics_cov):
    """(CornerNoise or None, (P, P) array or None): "camera" resolved from the camera file's
    statistics (`toolkit.board.calibration_file.uncertainty_of`)."""
    if isinstance(corner_noise, str) or isinstance(intrinsics_cov, str):
        for v in (corner_noise, intrinsics_cov):
            if isinstance(v, str) and v != "camera":
                raise InputError(f"expected 'camera', None or a value, got {v!r}")
        cov, noise = uncertainty_of(camera)
        corner_noise = noise if isinstance(corner_noise, str) else corner_noise
        intrinsics_cov = cov if isinstance(intrinsics_cov, str) else intrinsics_cov
    if hasattr(intrinsics_cov, "for_camera"):
        intrinsics_cov = intrinsics_cov.for_camera(camera)
    return corner_noise, intrinsics_cov


def _total_at(project, chosen, R, t, camera, X, u, cov, corner_noise, intrinsics_cov, board_warp=None):
    """The `PoseResult` keywords of the total covariance (`covariance.total_covariance`):
    none without a corner-noise model, intrinsics' covariance or warp covariance, or
    without `cov`."""
    corner_noise, intrinsics_cov = _resolve_total(camera, corner_noise, intrinsics_cov)
    warp_cov = None if board_warp is None else board_warp[1]
    if cov is None or (corner_noise is None and intrinsics_cov is None and warp_cov is None):
        return {}
    r, J = chosen.r, chosen.J
    if J is None:
        with np.errstate(all="ignore"):
            r, J, _ = project(R, t)
    total, correlated, G = total_covariance(camera, X, u, R, t, J, r, corner_noise, intrinsics_cov, board_warp)
    return {"cov_total": total, "correlated_corners_used": correlated, "intrinsics_used": G is not None,
            "intrinsics_sensitivity": G}


def estimate_all(object_points, image_points, camera, methods=METHODS, refine=True, corner_sigma_px=None,
                 max_rms_px=DEFAULT_MAX_RMS_PX, seed=0, **total):
    """Run `estimate_pose` with every method in `methods`.

    total: `corner_noise` and `intrinsics_cov`, as `estimate_pose`.

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
    return {m: estimate_pose(object_points, image_points, camera, m, refine, corner_sigma_px, max_rms_px, seed,
                             **total)
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


