"""Intrinsic calibration from board detections, with outlier rejection and uncertainties.

`calibrate` turns the corners `detect.detect_board` found in several views of one board
into a `Camera`, in three steps:

1. *Screening*: views without a detection, with fewer than `min_corners` corners, with
   all their corners on one line of the board, or whose corners admit no homography are
   skipped, each with its reason. ChArUco views keep their own object points (partial
   boards are fine).
2. *Fitting*: the intrinsic matrix is initialised with ``cv2.initCameraMatrix2D`` from the
   best-populated views, then refined with ``cv2.calibrateCameraExtended`` (models
   ``"opencv"`` and ``"pinhole"``) or ``cv2.fisheye.calibrate`` (``"fisheye"``).
3. *Outlier rejection*, repeated until nothing changes: views whose median corner
   residual is far above the others' (robust threshold: median + k * 1.4826 * MAD over the
   views, at least 1.5 x the median) are removed first; once the views are stable, single
   corners whose residual exceeds k sigma (sigma estimated robustly from all residuals)
   are removed. Gross outliers go first (only those within a factor 2 of the worst in a
   round), so a corrupt view cannot drag good views over the threshold with it. Every
   removal is recorded with its reason.

Conventions
-----------
- Pixels: OpenCV's; pixel (0, 0) is the centre of the top-left pixel (camera.py).
- Residual = observed - projected [px]. RMS is OpenCV's: sqrt(mean over corners of
  |residual|^2), overall and per view (``cv2.calibrateCamera``'s return value and
  ``perViewErrors`` use the same definition).
- View poses are ``cam_from_target``: ``p_cam = R(rvec) p_board + tvec`` (cv2.Rodrigues),
  tvec in the board's length unit (frames.py).
- Standard deviations come from the Gauss-Newton covariance at the optimum,
  ``sigma^2 (J^T J)^-1`` with ``sigma^2 = sum |r|^2 / (2 M - P)`` (M corners, P free
  parameters: intrinsics and 6 per view), which is what OpenCV >= 4.8 reports
  (calibrateCameraExtended; Hartley & Zisserman 5.1.3). It is computed here for every
  model from the analytic Jacobians of ``cv2.projectPoints`` / ``cv2.fisheye.projectPoints``,
  with the poses eliminated by a Schur complement, so the fisheye model (for which OpenCV
  reports none) gets them too. They describe noise only: a lens model that does not fit
  makes them optimistic (as mrcal warns for lean models).

Example
-------
>>> import numpy as np
>>> from pencilcal.toolkit.board.spec import board_from_dict
>>> from pencilcal.toolkit.camera.model import Camera
>>> board = board_from_dict({"type": "chessboard", "squares": [9, 6], "square": 25.0})
>>> truth = Camera("opencv", 640, 480, [[530.0, 0, 320.0], [0, 530.0, 240.0], [0, 0, 1]],
...                [-0.25, 0.08, 0.0, 0.0, 0.0])
>>> dets = synthetic_detections(truth, board, views=12, noise_px=0.2, seed=1)
>>> res = calibrate(dets, board, (640, 480))
>>> bool(abs(res.camera.fx - 530.0) < 4 * res.std_intrinsics["fx"]), len(res.std_intrinsics)
(True, 9)
>>> round(res.rms_px, 1), sum(res.used)
(0.3, 12)
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass, field

import numpy as np

from pencilcal.toolkit.camera.intrinsics import META_KEY as COV_META_KEY, IntrinsicsCovariance, \
    model_intrinsic_names
from pencilcal.toolkit.camera.model import Camera
from pencilcal.toolkit.board.bundle import WARP_NAMES, Layout, camera_parts, corner_views, covariance, \
    fit_pose, penalty_normal, refine, theta_of, view_residuals, warp_basis
from pencilcal.toolkit.board.corner_noise import fit_corner_noise, variance_factor
from pencilcal.toolkit.board import image_field
from pencilcal.toolkit.board.print_errors import covariance_term, fit_print_errors, intrinsic_gain, view_gains
from pencilcal.toolkit.board.detect import BoardDetection
from pencilcal.toolkit.board.calibration_file import SYMMETRIC_KEY
from pencilcal.toolkit.board.model_choice import CANDIDATES, SPLINED, choose_model, choose_twist, chosen_score, \
    splined_start
from pencilcal.toolkit.camera.splined import is_splined, splined_config
from pencilcal.toolkit.board.synthetic import synthetic_detections
from pencilcal.toolkit.errors import EstimationError, InputError

__all__ = ["CalibrationResult", "calibrate", "calibrate_images", "detect_views", "intrinsic_names",
           "synthetic_detections", "MODELS", "AUTO"]

#: Lens models `calibrate` fits, and the coefficient counts each takes (default first).
MODELS = {"opencv": (5, 4, 8, 12, 14), "pinhole": (0,), "fisheye": (4,)}
#: The model name that asks `calibrate` to choose the lens model on held-out views.
AUTO = "auto"

# a view is never rejected as an outlier while its median residual is within this factor
# of the median view's: real data sets have views that are legitimately noisier (blur, tilt)
_VIEW_RATIO_FLOOR = 1.5
# 1.4826 * MAD estimates a Gaussian sigma
_MAD_SCALE = 1.4826
# the median of |r|^2 / s^2 for a 2-D Gaussian with per-axis sigma s is 2 ln 2
_CHI2_2_MEDIAN = 2.0 * math.log(2.0)
# model-then-weighted-fit passes of the joint corner-noise fit (`_reweighted`)
_REWEIGHT_PASSES = 1


def intrinsic_names(model, coefficients=None):
    """Names of the intrinsic parameters, in the order of `Camera` (K entries, then dist).

    >>> intrinsic_names("opencv", 5)
    ['fx', 'fy', 'cx', 'cy', 'k1', 'k2', 'p1', 'p2', 'k3']
    >>> intrinsic_names("fisheye")
    ['fx', 'fy', 'cx', 'cy', 'k1', 'k2', 'k3', 'k4']
    """
    return model_intrinsic_names(model, _coefficient_count(model, coefficients))


def _coefficient_count(model, coefficients):
    if model not in MODELS:
        raise InputError(f"unknown calibration model {model!r}; expected one of {', '.join(MODELS)}")
    if coefficients is None:
        return MODELS[model][0]
    if isinstance(coefficients, bool) or not isinstance(coefficients, (int, np.integer)) \
            or int(coefficients) not in MODELS[model]:
        allowed = ", ".join(str(c) for c in sorted(MODELS[model]))
        raise InputError(f"the {model} model takes {allowed} distortion coefficients, got {coefficients!r}")
    return int(coefficients)


@dataclass
class CalibrationResult:
    """What `calibrate` found, view by view. Lists are aligned with the input detections.

    Attributes
    ----------
    camera : Camera
        The calibrated camera; ``camera.meta`` holds ``rms_px``, ``std_intrinsics``,
        ``views_used``, ``views_total``, ``corners_used``, ``calibration`` (model, flags).
    rms_px : float
        sqrt(mean |residual|^2) over the corners used [px] (OpenCV's definition).
    per_view_rms : list of float or None
        The same per view; None for views not used.
    std_intrinsics : dict
        1-sigma of each intrinsic parameter, named as `intrinsic_names` (fx, fy, cx, cy
        [px], then the distortion coefficients [unitless]).
    cov_intrinsics : IntrinsicsCovariance or None
        Their full covariance (P, P) in the same order (rows of held parameters zero; with
        the aspect ratio held, fx's row is the ratio times fy's); also in ``camera.meta``
        as ``cov_intrinsics`` (``{"names", "cov"}``).
    corner_noise : CornerNoise or None
        The correlated corner-error model fitted to the final residuals
        (`toolkit.board.corner_noise`), with ``corner_noise=True``; also in ``camera.meta``.
    std_extrinsics : list of dict or None
        Per used view ``{"rvec": (3,) [rad], "tvec": (3,) [board unit]}``.
    view_poses : list of (rvec, tvec) or None
        Per used view, ``cam_from_target`` (p_cam = R(rvec) p_board + tvec).
    used : list of bool
        Whether each view contributed to the final fit.
    rejected : list of dict
        Every view or corner left out, in the order decided: ``{"view": i, "stage":
        "skipped" | "outlier", "reason": str}``, with ``"corner": id`` and
        ``"residual_px"`` for single corners, ``"rms_px"`` for rejected views.
    residuals : list of (K, 2) ndarray or None
        Per used view, observed - projected [px] for *every* detected corner of the view
        (rejected corners included, with the final parameters); None for views not used.
    corner_used : list of (K,) bool ndarray or None
        Which of a used view's corners entered the final fit.
    model, coefficients, flags : str, int, list of str
        The lens model, its coefficient count and the OpenCV flags of the final fit.
    rounds : int
        Number of fits run (1 + the rounds that rejected something).
    warp : dict or None
        With ``warp=True``: the board's warp ``{"names", "value" (2,), "std" (2,), "cov"}``
        [board unit] (`toolkit.board.bundle`); also ``camera.meta["board_warp"]``.
    model_choice : ModelChoice or None
        With ``model="auto"``: every candidate's held-out score and why one was chosen.
    checks : CalibrationChecks or None
        The checks and the verdict, where `validation.calibration_run.calibrate_checked`
        made the result (what `pencilcal calibrate` and `pencilcal.calibrate` run).
    layout, solution, covariance : bundle.Layout, bundle.Solution, bundle.Covariance
        The final problem, its optimum (over the used views, in their order) and the
        covariance (intrinsics, warp, poses, each view's white noise level).
    weights : list of (K_i,) ndarray or None
        With ``corner_noise=True``: each used corner's weight in the final fit (solution
        order), the inverse of its heteroscedastic factor under the corner-noise model
        (`noise_weights`), scaled to a mean of 1 over the corners.
    print_errors : PrintErrors or None
        With ``corner_noise=True``: the printed board's own corner offsets, shared by all
        views (`toolkit.board.print_errors`), measured on the residuals; where kept, their
        share is in ``covariance``'s intrinsics and warp blocks (not in the poses').
    image_field : ImageField or None
        With ``corner_noise=True``: the part of the correlated corner error that is fixed in
        the image, the same in every view (`toolkit.board.image_field`), measured on the
        residuals; where kept, it is one term of ``covariance``'s intrinsics and warp
        blocks instead of each view's own noise.
    """

    camera: Camera
    rms_px: float
    per_view_rms: list
    std_intrinsics: dict
    std_extrinsics: list
    view_poses: list
    used: list
    rejected: list
    residuals: list
    corner_used: list
    model: str
    coefficients: int
    flags: list = field(default_factory=list)
    rounds: int = 1
    cov_intrinsics: IntrinsicsCovariance | None = None
    corner_noise: object = None
    warp: dict | None = None
    model_choice: object = None
    layout: object = None
    solution: object = None
    covariance: object = None
    checks: object = None
    weights: list | None = None
    print_errors: object = None
    image_field: object = None

    @property
    def views_used(self) -> int:
        return int(sum(self.used))

    @property
    def corners_used(self) -> int:
        return int(sum(int(m.sum()) for m in self.corner_used if m is not None))

    def to_dict(self, names=None):
        """The calibration's record (calib.json without the command's own keys): the camera,
        the model (and how it was chosen), RMS, the intrinsics' sigmas and covariance, the
        corner-noise model, the board's warp, counts, each view's report (`view_report`,
        named by `names`), every rejection, and with ``checks`` the verdict, the
        cross-validation, the projection uncertainty map, the views' geometry and coverage."""
        from pencilcal.toolkit.camera.formats import camera_to_dict

        n = len(self.used)
        views = [self.view_report(i, None if names is None else names[i]) for i in range(n)]
        rec = {"model": self.model, "coefficients": self.coefficients, "flags": list(self.flags),
               "rms_px": self.rms_px, "std_intrinsics": dict(self.std_intrinsics),
               "cov_intrinsics": None if self.cov_intrinsics is None else self.cov_intrinsics.to_dict(),
               "corner_noise": None if self.corner_noise is None else self.corner_noise.to_dict(),
               "covariance_model": None if self.covariance is None else self.covariance.model,
               "fit_weights": "uniform" if self.weights is None else "corner_noise",
               "board_warp": self.warp,
               "board_corners": None if self.print_errors is None else self.print_errors.to_dict(),
               "image_field": None if self.image_field is None else self.image_field.to_dict(),
               "model_choice": None if self.model_choice is None else self.model_choice.to_dict(),
               "camera": camera_to_dict(self.camera),
               "counts": {"views": n, "views_skipped": sum(1 for r in self.rejected if r["stage"] == "skipped"),
                          "views_rejected": sum(1 for r in self.rejected
                                                if r["stage"] == "outlier" and "corner" not in r),
                          "views_used": self.views_used,
                          "corners_rejected": sum(1 for r in self.rejected if "corner" in r),
                          "corners_used": self.corners_used},
               "views": views, "rejected": [dict(r) for r in self.rejected]}
        if self.checks is not None:
            rec.update(self.checks.to_dict())
        return rec

    def view_report(self, index, name=None):
        """JSON-ready summary of one view: name, used, rms, pose and its std, rejections."""
        rec = {"view": index}
        if name is not None:
            rec["image"] = name
        rec["used"] = bool(self.used[index])
        rec["rms_px"] = self.per_view_rms[index]
        if self.used[index]:
            rvec, tvec = self.view_poses[index]
            rec["corners_used"] = int(self.corner_used[index].sum())
            rec["rvec"] = rvec.tolist()
            rec["tvec"] = tvec.tolist()
            rec["std_rvec"] = self.std_extrinsics[index]["rvec"].tolist()
            rec["std_tvec"] = self.std_extrinsics[index]["tvec"].tolist()
            rec["max_residual_px"] = float(np.max(np.linalg.norm(self.residuals[index], axis=1)))
        reasons = [r["reason"] for r in self.rejected if r["view"] == index and "corner" not in r]
        if reasons:
            rec["reason"] = reasons[-1]
        corners = [{"corner": r["corner"], "residual_px": r["residual_px"], "reason": r["reason"]}
                   for r in self.rejected if r["view"] == index and "corner" in r]
        if corners:
            rec["rejected_corners"] = corners
        return rec


# ------------------------------------------------------------------------ screening
def _screen(det, obj_all, min_corners, image_size):
    """(obj, img, None) for a usable view, or (None, None, reason)."""
    import cv2

    if det is None or det.count == 0:
        return None, None, "no corners detected"
    if det.image_size is not None and tuple(det.image_size) != tuple(image_size):
        raise InputError(f"a detection is from a {det.image_size[0]}x{det.image_size[1]} image but the "
                         f"calibration is for {image_size[0]}x{image_size[1]}")
    ids = np.asarray(det.ids, int).ravel()
    img = np.asarray(det.corners, float).reshape(-1, 2)
    if ids.size != img.shape[0]:
        raise InputError(f"a detection has {ids.size} ids but {img.shape[0]} corners")
    if ids.size and (ids.min() < 0 or ids.max() >= obj_all.shape[0]):
        raise InputError(f"a detection has corner ids outside 0..{obj_all.shape[0] - 1}; wrong board file?")
    if np.unique(ids).size != ids.size:
        raise InputError("a detection lists the same corner id twice")
    if not np.all(np.isfinite(img)):
        raise InputError("a detection has non-finite corner coordinates")
    if ids.size < min_corners:
        return None, None, f"only {ids.size} corners (need at least {min_corners})"
    obj = obj_all[ids]
    centred = obj[:, :2] - obj[:, :2].mean(0)
    s = np.linalg.svd(centred, compute_uv=False)
    if s[1] <= 1e-9 * s[0]:
        return None, None, "corners are collinear (all on one line of the board)"
    H, _ = cv2.findHomography(obj[:, :2], img, 0)
    if H is None or not np.all(np.isfinite(H)):
        return None, None, "degenerate corner layout (no homography from the board to the image)"
    return obj, img, None


# ------------------------------------------------------------------------ fitting
def _opencv_flags(model, n_coef, fix_aspect, fix_principal_point, zero_tangent):
    import cv2

    flags = cv2.CALIB_USE_INTRINSIC_GUESS
    names = ["CALIB_USE_INTRINSIC_GUESS"]

    def add(name):
        nonlocal flags
        flags |= getattr(cv2, name)
        names.append(name)

    if model == "fisheye":
        for name in ("CALIB_RECOMPUTE_EXTRINSIC", "CALIB_FIX_SKEW"):
            add(name)
        if fix_principal_point:
            add("CALIB_FIX_PRINCIPAL_POINT")
        return flags, names
    if fix_aspect:
        add("CALIB_FIX_ASPECT_RATIO")
    if fix_principal_point:
        add("CALIB_FIX_PRINCIPAL_POINT")
    if model == "pinhole":
        for name in ("CALIB_FIX_K1", "CALIB_FIX_K2", "CALIB_FIX_K3", "CALIB_ZERO_TANGENT_DIST"):
            add(name)
        return flags, names
    if n_coef == 4:
        add("CALIB_FIX_K3")
    if n_coef >= 8:
        add("CALIB_RATIONAL_MODEL")
    if n_coef >= 12:
        add("CALIB_THIN_PRISM_MODEL")
    if n_coef >= 14:
        add("CALIB_TILTED_MODEL")
    if zero_tangent:
        add("CALIB_ZERO_TANGENT_DIST")
    return flags, names


def _initial_K(objs, imgs, image_size, fix_aspect):
    """K from cv2.initCameraMatrix2D over the best-populated views (homographies of views
    with a handful of corners are poor and would spoil the linear solve)."""
    import cv2

    w, h = image_size
    counts = np.array([o.shape[0] for o in objs])
    order = np.argsort(-counts, kind="stable")
    good = [i for i in order if counts[i] >= 0.5 * counts.max()]
    if len(good) < 3:
        good = list(order[: max(3, len(good))])
    o = [objs[i].astype(np.float32).reshape(-1, 1, 3) for i in good]
    p = [imgs[i].astype(np.float32).reshape(-1, 1, 2) for i in good]
    try:
        K = cv2.initCameraMatrix2D(o, p, (int(w), int(h)), 1.0 if fix_aspect else 0.0)
    except cv2.error:
        K = None
    ok = K is not None and np.all(np.isfinite(K)) and 0.05 * max(w, h) < K[0, 0] < 100 * max(w, h) \
        and 0.05 * max(w, h) < K[1, 1] < 100 * max(w, h)
    if not ok:
        # no usable homography: a ~53 degree field of view and the image centre
        f = float(max(w, h))
        K = np.array([[f, 0.0, (w - 1) / 2.0], [0.0, f, (h - 1) / 2.0], [0.0, 0.0, 1.0]])
    K = np.array(K, float)
    if fix_aspect:
        K[0, 0] = K[1, 1] = 0.5 * (K[0, 0] + K[1, 1])
    return K


def _one_line(e):
    """The informative part of an OpenCV error: "... error: (-215:...) message in function 'f'"."""
    text = str(e).strip().splitlines()
    line = next((t.strip() for t in text if t.strip()), type(e).__name__)
    m = re.search(r"error: \(-?\d+:[^)]*\) (.*)", line)
    return m.group(1) if m else line


def _fit(model, n_coef, objs, imgs, image_size, K0, flags):
    """One solve. Returns K, dist (model length), rvecs (V, 3), tvecs (V, 3)."""
    import cv2

    size = (int(image_size[0]), int(image_size[1]))
    # OpenCV's default is 30 iterations; rich models (rational, tilted) need more to settle
    criteria = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 100, float(np.finfo(float).eps))
    try:
        if model == "fisheye":
            # OpenCV 5's fisheye.calibrate wants each view as a (1, N, 3) / (1, N, 2) row;
            # the (N, 1, 3) column other calib functions take fails in arithm_op
            o = [x.reshape(1, -1, 3).astype(np.float64) for x in objs]
            p = [x.reshape(1, -1, 2).astype(np.float64) for x in imgs]
            try:
                _, K, D, rv, tv = cv2.fisheye.calibrate(o, p, size, K0.copy(), np.zeros(4), flags=flags,
                                                        criteria=criteria)
            except cv2.error:
                # OpenCV's own initialisation (f = max(w, h) / pi) suits very wide lenses
                _, K, D, rv, tv = cv2.fisheye.calibrate(o, p, size, np.eye(3), np.zeros(4),
                                                        flags=flags & ~cv2.CALIB_USE_INTRINSIC_GUESS,
                                                        criteria=criteria)
            dist = np.asarray(D, float).ravel()[:4]
        else:
            o = [x.reshape(-1, 1, 3).astype(np.float32) for x in objs]
            p = [x.reshape(-1, 1, 2).astype(np.float32) for x in imgs]
            n_pass = 5 if model == "pinhole" or n_coef == 4 else n_coef
            out = cv2.calibrateCameraExtended(o, p, size, K0.copy(), np.zeros(n_pass), flags=flags,
                                              criteria=criteria)
            K, D, rv, tv = out[1], out[2], out[3], out[4]
            dist = np.asarray(D, float).ravel()[: (0 if model == "pinhole" else n_coef)]
    except cv2.error as e:
        raise EstimationError(f"the calibration solve failed: {_one_line(e)}") from None
    K = np.array(K, float)
    K[0, 1] = 0.0
    rvecs = np.array([np.asarray(r, float).ravel() for r in rv])
    tvecs = np.array([np.asarray(t, float).ravel() for t in tv])
    if not (np.all(np.isfinite(K)) and np.all(np.isfinite(dist)) and K[0, 0] > 0 and K[1, 1] > 0):
        raise EstimationError("the calibration solve diverged (non-finite or negative focal length)")
    return K, dist, rvecs, tvecs


# ---------------------------------------------------------------------- the driver
def _single_threaded(fn):
    """Run OpenCV single-threaded inside `fn`: its multithreaded calibration reduces in a
    varying order and differs between runs in the last digits; one thread is
    bit-reproducible (and no slower here)."""
    import functools

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        import cv2

        n = cv2.getNumThreads()
        cv2.setNumThreads(1)
        try:
            return fn(*args, **kwargs)
        finally:
            cv2.setNumThreads(n)

    return wrapper


@_single_threaded
def calibrate(detections, board, image_size, model="opencv", coefficients=None, *, fix_aspect=False,
              fix_principal_point=False, zero_tangent=False, min_corners=6, min_views=3,
              outlier_view_sigma=4.0, outlier_corner_sigma=5.0, max_rounds=20, corner_noise=False, warp=False,
              candidates=CANDIDATES, twist=False):
    """Calibrate one camera's intrinsics from board detections in several views.

    Parameters
    ----------
    detections : sequence of BoardDetection or None
        One per view (None: nothing detected). Corners in raw pixels, OpenCV convention.
    board : Board
        The board seen (boards.py); its object points are in its length unit.
    image_size : (width, height)
        [px]; every detection must come from an image of this size.
    model : {"opencv", "pinhole", "fisheye", "splined", "auto"} or a splined model's name
        Lens model (camera.py). ``"pinhole"`` fits no distortion at all. ``"auto"``: the
        views are screened and outliers rejected with opencv's 5 coefficients, then the
        `candidates` are compared on held-out views and the one chosen is fitted
        (`toolkit.board.model_choice`; ``model_choice`` on the result says why).
        ``"splined"``: screened the same way, then mrcal's splined stereographic model on
        a grid covering the image, started from the opencv fit (`model_choice.
        splined_start`); ``"splined_stereographic_order=3_Nx=.._Ny=.._fov_x_deg=.."``: on
        that grid.
    coefficients : int, optional
        opencv: 4 (k1 k2 p1 p2), 5 (+ k3, the default), 8 (rational k4..k6), 12 (thin
        prism s1..s4), 14 (tilted sensor); fisheye: 4; pinhole: 0.
    fix_aspect : bool
        Hold fx = fy (CALIB_FIX_ASPECT_RATIO with ratio 1). Not available for fisheye.
    fix_principal_point : bool
        Hold (cx, cy) at the initial estimate (the image centre from initCameraMatrix2D).
    zero_tangent : bool
        opencv: hold p1 = p2 = 0.
    min_corners : int
        Views with fewer corners are skipped (a ChArUco view may show part of the board).
    min_views : int
        Fewer usable views is an EstimationError; outlier rejection never goes below it.
    outlier_view_sigma : float or None
        Views whose median corner residual exceeds median + k * 1.4826 * MAD over the
        views (and 1.5 x the median) are rejected. None or 0 turns view rejection off.
    outlier_corner_sigma : float or None
        Single corners with |residual| > k * sigma are rejected; sigma (per axis) is
        estimated robustly, sqrt(median |r|^2 / (2 ln 2)). None or 0 turns it off.
    max_rounds : int
        At most this many fits (rejection stops at the last one).
    corner_noise : bool
        Also fit the correlated corner-error model to the final residuals
        (`toolkit.board.corner_noise.fit_corner_noise`; a second on a few thousand
        corners), and give the intrinsics the covariance it implies (`bundle.covariance`:
        each view's own noise level and the correlated part, not one white level).
    candidates : sequence of (model, coefficients)
        The models ``"auto"`` compares (`model_choice.CANDIDATES`: all of them).
    warp : bool
        Also estimate the board's warp (`bundle`: two parabolas along the board, mrcal's
        calobject_warp), in the final solve; ``warp`` on the result and ``board_warp`` in
        the camera's statistics.
    twist : bool or "auto"
        With `warp`, the board's twist as a third shape (`bundle.warp_basis`: a saddle,
        +-warp_twist at the grid's corners), which two parabolas do not hold; ``"auto"``:
        where held-out views say so (`model_choice.choose_twist`, its record in
        ``warp["twist_choice"]``).

    Returns
    -------
    CalibrationResult

    Raises
    ------
    InputError
        Invalid options, or detections that do not belong to this board / image size.
    EstimationError
        Too few usable views or corners, or a solve that fails; the message says why.

    Example
    -------
    >>> from pencilcal.toolkit.board.spec import board_from_dict
    >>> board = board_from_dict({"type": "charuco", "squares": [7, 5], "square": 30.0,
    ...                          "marker": 22.0, "dictionary": "DICT_4X4_50"})
    >>> truth = Camera("fisheye", 1280, 720, [[600.0, 0, 640.0], [0, 600.0, 360.0], [0, 0, 1]],
    ...                [0.05, -0.02, 0.01, -0.003])
    >>> dets = synthetic_detections(truth, board, views=10, noise_px=0.1, seed=3)
    >>> res = calibrate(dets, board, (1280, 720), model="fisheye")
    >>> res.camera.model, bool(abs(res.camera.fx - 600.0) < 1.0), sorted(res.std_intrinsics)[:3]
    ('fisheye', True, ['cx', 'cy', 'fx'])
    """
    auto = model == AUTO
    spline = None
    if model == SPLINED or is_splined(model):
        if fix_aspect or zero_tangent:
            raise InputError("fix_aspect and zero_tangent do not apply to the splined model")
        spline = SPLINED if model == SPLINED else splined_config(model)
    if auto or spline is not None:
        model, coefficients = "opencv", None
    n_coef = _coefficient_count(model, coefficients)
    image_size = _check_options(model, fix_aspect, zero_tangent, image_size, min_corners, min_views)
    if not (twist is True or twist is False or twist == "auto"):
        raise InputError(f"twist must be True, False or 'auto', got {twist!r}")
    detections = list(detections)
    for d in detections:
        if d is not None and not isinstance(d, BoardDetection):
            raise InputError(f"detections must be BoardDetection or None, got {type(d).__name__}")
    obj_all = board.object_points()
    n_views = len(detections)
    rejected = []
    objs, imgs = [None] * n_views, [None] * n_views
    for i, det in enumerate(detections):
        o, p, reason = _screen(det, obj_all, int(min_corners), image_size)
        if reason is not None:
            rejected.append({"view": i, "stage": "skipped", "reason": reason})
        objs[i], imgs[i] = o, p
    usable = [i for i in range(n_views) if objs[i] is not None]
    if len(usable) < min_views:
        raise EstimationError(_too_few_views(len(usable), min_views, n_views, rejected))
    layout = Layout(model, n_coef, bool(fix_aspect), bool(fix_principal_point), bool(zero_tangent), warp=False)
    rejection = (outlier_view_sigma, outlier_corner_sigma, int(min_corners), int(min_views), int(max_rounds))
    used, masks, theta, poses, rounds, flag_names = _fit_with_rejection(layout, objs, imgs, usable, image_size,
                                                                        rejection, rejected)
    twist_rec = None
    if warp and twist == "auto":
        lean = Layout(model, n_coef, bool(fix_aspect), bool(fix_principal_point), bool(zero_tangent), warp=True)
        twist_rec = choose_twist(lean, theta, [poses[i] for i in used], [objs[i][masks[i]] for i in used],
                                 [imgs[i][masks[i]] for i in used], board.object_points())
        twist = twist_rec is not None and twist_rec["kept"]
    layout = Layout(model, n_coef, bool(fix_aspect), bool(fix_principal_point), bool(zero_tangent), warp=bool(warp),
                    twist=bool(warp and twist))
    choice, warp0 = None, None
    if auto:
        choice, layout, theta, poses, warp0 = _auto(layout, board, objs, imgs, used, masks, theta, poses,
                                                    candidates, image_size, corner_noise)
        flag_names = _flag_names(layout)
    elif spline is not None:
        K, dist = camera_parts(theta, layout)
        layout, theta = splined_start(layout, K, dist, image_size, config=spline if spline != SPLINED else None)
        flag_names = _flag_names(layout)
    result = _final(layout, board, detections, objs, imgs, used, masks, theta, poses, image_size, corner_noise,
                    rejected, rounds, flag_names, warp0)
    result.model_choice = choice
    if twist_rec is not None and result.warp is not None:
        result.warp["twist_choice"] = twist_rec
    return result


def _flag_names(layout):
    """OpenCV's flags of a lean layout; none for a splined one (pencilcal's own solver)."""
    if is_splined(layout.model):
        return []
    return _opencv_flags(layout.model, layout.n_coef, layout.fix_aspect, layout.fix_principal_point,
                         layout.zero_tangent)[1]


def _auto(layout, board, objs, imgs, used, masks, theta, poses, candidates, image_size, corner_noise=False):
    """`model_choice.choose_model` on the views and corners kept: (the choice, its layout,
    and its fit to start the final solve from: theta, {view: pose}, warp). With
    `corner_noise` the candidates are compared under the weights the final fit will use:
    the corner-noise model fitted to the lean model's residuals (`_reweighted`), and each
    candidate's coefficients are judged determined or not under its covariance with that
    model."""
    obj_all = board.object_points()
    o = [objs[i][masks[i]] for i in used]
    p = [imgs[i][masks[i]] for i in used]
    bases = [warp_basis(obj_all, x, layout.twist) for x in o]
    start = [poses[i] for i in used]
    weights = noise = None
    if corner_noise:
        lean = refine(layout, theta, start, o, p, bases if layout.warp else None)
        _, noise, weights = _reweighted(layout, lean, o, p, bases if layout.warp else None, image_size)
    K, dist = camera_parts(theta, layout)
    choice = choose_model(o, p, bases, K, dist, start,
                          candidates=candidates, warp=layout.warp, fix_aspect=layout.fix_aspect,
                          fix_principal_point=layout.fix_principal_point, zero_tangent=layout.zero_tangent,
                          image_size=image_size, lean=(layout.model, layout.n_coef), weights=weights, noise=noise)
    score = chosen_score(choice)
    sol = score.solution
    chosen = score.layout if score.layout is not None else \
        Layout(choice.model, choice.coefficients, layout.fix_aspect, layout.fix_principal_point,
               layout.zero_tangent and choice.model == "opencv", layout.warp, twist=layout.twist)
    return choice, chosen, sol.theta, {i: (sol.poses[j][0], sol.poses[j][1]) for j, i in enumerate(used)}, sol.warp


def _check_options(model, fix_aspect, zero_tangent, image_size, min_corners, min_views):
    """(w, h) after checking the options (InputError for a bad one)."""
    if model == "fisheye" and fix_aspect:
        raise InputError("fix_aspect is not available for the fisheye model (cv2.fisheye.calibrate "
                         "cannot tie fx to fy)")
    if zero_tangent and model != "opencv":
        raise InputError("zero_tangent applies to the opencv model only")
    try:
        w, h = (int(v) for v in image_size)
    except (TypeError, ValueError):
        raise InputError(f"image_size must be (width, height), got {image_size!r}") from None
    if w <= 0 or h <= 0:
        raise InputError(f"image_size must be positive, got {image_size!r}")
    if int(min_corners) < 4:
        raise InputError(f"min_corners must be at least 4 (a homography needs 4 points), got {min_corners}")
    if int(min_views) < 1:
        raise InputError(f"min_views must be at least 1, got {min_views}")
    return (w, h)


def _fit_with_rejection(layout, objs, imgs, usable, image_size, rejection, rejected):
    """The fit and its outlier rounds: OpenCV's solve first (from initCameraMatrix2D), then
    `bundle.refine` from the last round's parameters after every rejection. Returns (used
    view indices, corner masks, theta (P,), {view: (rvec, tvec)}, rounds, OpenCV flags)."""
    view_k, corner_k, min_corners, min_views, max_rounds = rejection
    model, n_coef = layout.model, layout.n_coef
    masks = {i: np.ones(objs[i].shape[0], bool) for i in usable}
    flags, flag_names = _opencv_flags(model, n_coef, layout.fix_aspect, layout.fix_principal_point,
                                      layout.zero_tangent)
    used = list(usable)
    rounds = 0
    corner_sigma = None
    theta, poses = None, {}
    while True:
        rounds += 1
        if len(used) < min_views:
            raise EstimationError(f"only {len(used)} view(s) left after outlier rejection, need at least {min_views}")
        o = [objs[i][masks[i]] for i in used]
        p = [imgs[i][masks[i]] for i in used]
        _check_counts(model, n_coef, layout.fix_aspect, layout.fix_principal_point, layout.zero_tangent, o)
        if theta is None:
            K0 = _initial_K(o, p, image_size, layout.fix_aspect)
            K, dist, rvecs, tvecs = _fit(model, n_coef, o, p, image_size, K0, flags)
            theta = theta_of(K, dist, layout)
            poses = {i: (rvecs[j], tvecs[j]) for j, i in enumerate(used)}
        else:
            sol = refine(layout, theta, [poses[i] for i in used], o, p)
            theta = sol.theta
            poses = {i: (sol.poses[j][0], sol.poses[j][1]) for j, i in enumerate(used)}
        if rounds >= max_rounds:
            break
        res = view_residuals(layout, _Poses(theta, [poses[i] for i in used]), [objs[i] for i in used],
                             [imgs[i] for i in used])
        norms = {i: np.linalg.norm(r, axis=1) for i, r in zip(used, res)}
        judged = _without_gross_corners(layout, theta, poses, objs, imgs, used, masks, norms, corner_k)
        if _reject_views(used, masks, norms, view_k, min_views, rejected, judged):
            continue
        if corner_k and corner_sigma is None:
            # sigma is estimated once, when the views have settled: re-estimating it after
            # every round would peel off the (heavy) tails of real residuals round by round
            allr = np.concatenate([norms[i][masks[i]] for i in used])
            corner_sigma = math.sqrt(float(np.median(allr ** 2)) / _CHI2_2_MEDIAN)
        if _reject_corners(used, masks, norms, corner_k, corner_sigma, min_corners, rejected):
            continue
        break
    return used, masks, theta, poses, rounds, flag_names


class _Poses:
    """The parts of a `bundle.Solution` that `view_residuals` reads."""

    def __init__(self, theta, poses, warp=None):
        self.theta = theta
        self.poses = [(np.ravel(r), np.ravel(t)) for r, t in poses]
        self.warp = np.zeros(2) if warp is None else warp


def _final(layout, board, detections, objs, imgs, used, masks, theta, poses, image_size, corner_noise, rejected,
           rounds, flag_names, warp0=None):
    """The final solve (with the warp when the layout has it), the covariance under the
    corner errors seen, and the result."""
    obj_all = board.object_points()
    n_views = len(detections)
    o = [objs[i][masks[i]] for i in used]
    p = [imgs[i][masks[i]] for i in used]
    bases = [warp_basis(obj_all, x, layout.twist) for x in o]
    sol = refine(layout, theta, [poses[i] for i in used], o, p, bases, warp=warp0)
    noise, weights = None, None
    if corner_noise:
        sol, noise, weights = _reweighted(layout, sol, o, p, bases, image_size)
    cov = covariance(layout, sol, o, p, bases, noise, weights)
    prints, field = None, None
    if corner_noise:
        cov, prints, field = _with_shared_errors(layout, sol, cov, o, p, bases,
                                                 [_ids(detections[i], masks[i]) for i in used], obj_all.shape[0],
                                                 noise, weights, image_size)
    K, dist = camera_parts(sol.theta, layout)
    names = model_intrinsic_names(layout.model, layout.n_coef)
    sd = np.sqrt(np.clip(np.diag(cov.intrinsics), 0, None))
    std_intr = {n: float(v) for n, v in zip(names, sd)}
    cov_full = IntrinsicsCovariance(tuple(names), cov.intrinsics) if np.all(np.isfinite(cov.intrinsics)) else None
    per_view_rms, residuals, corner_used, std_ext, view_poses = ([None] * n_views for _ in range(5))
    full_res = view_residuals(layout, sol, [objs[i] for i in used], [imgs[i] for i in used],
                              [warp_basis(obj_all, objs[i], layout.twist) for i in used])
    sse, m = 0.0, 0
    for j, i in enumerate(used):
        residuals[i] = full_res[j]
        corner_used[i] = masks[i].copy()
        e2 = float(np.sum(full_res[j][masks[i]] ** 2))
        per_view_rms[i] = math.sqrt(e2 / masks[i].sum())
        sse += e2
        m += int(masks[i].sum())
        s = np.sqrt(np.clip(np.diag(cov.poses[j]), 0, None))
        std_ext[i] = {"rvec": s[:3], "tvec": s[3:]}
        view_poses[i] = (sol.poses[j][0].copy(), sol.poses[j][1].copy())
    rms = math.sqrt(sse / m)
    warp_rec = None
    if layout.warp:
        warp_rec = {"names": list(WARP_NAMES[:layout.n_warp]), "value": sol.warp.tolist(),
                    "std": np.sqrt(np.clip(np.diag(cov.warp), 0, None)).tolist(), "cov": cov.warp.tolist()}
    meta = {"rms_px": rms, "std_intrinsics": std_intr, "views_used": len(used), "views_total": n_views,
            "corners_used": m,
            "calibration": {"model": layout.model, "coefficients": layout.n_coef, "fix_aspect": layout.fix_aspect,
                            "flags": flag_names, "board": board.to_dict(),
                            # how the corners were found: the camera's later poses of the board
                            # detect them so (the corner-noise model was measured on them)
                            SYMMETRIC_KEY: all(detections[i].symmetric for i in used)}}
    if cov_full is not None:
        meta[COV_META_KEY] = cov_full.to_dict()
    if noise is not None:
        meta["corner_noise"] = noise.to_dict()
    if warp_rec is not None:
        meta["board_warp"] = warp_rec
    if prints is not None:
        meta["board_corners"] = prints.to_dict()
    if field is not None:
        meta["image_field"] = field.to_dict()
    camera = Camera(layout.model, image_size[0], image_size[1], K, dist, meta=meta)
    used_set = set(used)
    return CalibrationResult(camera=camera, rms_px=rms, per_view_rms=per_view_rms, std_intrinsics=std_intr,
                             std_extrinsics=std_ext, view_poses=view_poses,
                             used=[i in used_set for i in range(n_views)], rejected=rejected, residuals=residuals,
                             corner_used=corner_used, model=layout.model, coefficients=layout.n_coef,
                             flags=flag_names, rounds=rounds, cov_intrinsics=cov_full, corner_noise=noise,
                             warp=warp_rec, layout=layout, solution=sol, covariance=cov, weights=weights,
                             print_errors=prints, image_field=field)


def _ids(det, mask):
    """A view's used corners' ids (K,)."""
    return np.asarray(det.ids, int).ravel()[np.asarray(mask, bool)]


def _with_shared_errors(layout, sol, cov, o, p, bases, ids, n_corners, noise, weights, image_size):
    """The errors every view shares, measured on the calibration's residuals (weighted by
    the views' levels in `cov`): the printed board's corner offsets (`print_errors`) and the
    correlated error fixed in the image (`image_field`). Where either is kept, the
    covariance again with its share taken out of the views' own noise (`bundle.covariance`'s
    shared and field) and its term (``G diag(var) G^T``, ``G K G^T tau^2``) added to the
    intrinsics, warp and cross blocks. Returns (the covariance, the `PrintErrors`, the
    `ImageField`)."""
    prints, jac, white = fit_print_errors(layout, sol, o, p, bases, ids, n_corners, cov.sigma_w, noise)
    T, prior = layout.transform(sol.theta), penalty_normal(layout, sol.theta)
    field = image_field.fit_image_field(noise, p, jac, white, weights, prior)
    if (prints.kept or field.kept) and np.all(np.isfinite(cov.intrinsics)):
        cov = covariance(layout, sol, o, p, bases, noise, weights, shared=prints if prints.kept else None,
                         field=field if field.kept else None)
        extra = 0.0
        if prints.kept:
            G = intrinsic_gain(view_gains(jac, ids, n_corners, weights), range(len(o)), T, prior)
            extra = extra + covariance_term(G, G, prints)
        if field.kept:
            G = intrinsic_gain(image_field.view_gains(jac, p, image_size, field.length_px, weights), range(len(o)),
                               T, prior)
            extra = extra + image_field.covariance_term(G, G, field, image_size)
        P = cov.intrinsics.shape[0]
        cov.intrinsics = cov.intrinsics + extra[:P, :P]
        if layout.warp:
            cov.warp = cov.warp + extra[P:, P:]
            cov.cross = cov.cross + extra[:P, P:]
    return cov, prints, field


def noise_weights(noise, views):
    """Each corner's weight (K_i,) per CornerView under `noise`: the inverse of its
    heteroscedastic factor (`corner_noise.variance_factor`), scaled to a mean of 1 over all
    corners (so a splined model's penalty keeps its weight against them). The views' own
    levels stay out of the weights (a level estimated from a view's few corners, weighting
    those same corners, predicted held-out views no better on the da Vinci left views and
    moved the RealSense fx by 0.6 sigma; docs/calibration.md); the covariance holds them."""
    d = [variance_factor(noise, v.points, v.scale, v.centre) for v in views]
    m = float(np.mean(np.concatenate(d)))
    return [m / x for x in d]


def _reweighted(layout, sol, o, p, bases, image_size):
    """The corner-noise model and the fit estimated together, by alternating: the model
    fitted to the residuals, then the fit weighted by it (`_REWEIGHT_PASSES` times; a
    second pass moved the da Vinci left fx by 0.003 of its sigma and the shape by 0.07 of
    its sigmas, for 60 % more time). Returns (solution, CornerNoise, weights)."""
    for _ in range(_REWEIGHT_PASSES):
        views = corner_views(layout, sol, o, p, bases)
        noise = fit_corner_noise(views, image_size)
        weights = noise_weights(noise, views)
        sol = refine(layout, sol.theta, sol.poses, o, p, bases, warp=sol.warp, weights=weights)
    return sol, noise, weights


def _too_few_views(n_usable, min_views, n_views, rejected):
    """One line: how many views were usable and why the others were not."""
    reasons = {}
    for r in rejected:
        key = r["reason"].split(" (")[0]
        if key.startswith("only "):
            key = "too few corners"
        reasons[key] = reasons.get(key, 0) + 1
    why = "; ".join(f"{k}: {n}" for k, n in sorted(reasons.items(), key=lambda kv: -kv[1]))
    return (f"only {n_usable} usable view(s) of {n_views}, need at least {min_views}"
            + (f" ({why})" if why else ""))


def _check_counts(model, n_coef, fix_aspect, fix_pp, zero_tan, objs):
    n_intr = (1 if fix_aspect else 2) + (0 if fix_pp else 2)
    if model == "opencv":
        n_intr += n_coef - (2 if zero_tan else 0)
    elif model == "fisheye":
        n_intr += 4
    p = n_intr + 6 * len(objs)
    m = sum(o.shape[0] for o in objs)
    if 2 * m <= p:
        raise EstimationError(f"{m} corners in {len(objs)} views cannot determine {p} parameters "
                              f"({n_intr} intrinsics + 6 per view); add views or use fewer coefficients")


def _without_gross_corners(layout, theta, poses, objs, imgs, used, masks, norms, k):
    """What the view gate judges each view by: ({view: (K,) corners judged}, {view: (K,)
    residual norms [px]}): a view's worst corner left out and its pose fitted again without
    it, one corner at a time, while a corner lies beyond the corner gate's cut (k sigma,
    sigma from every view's median residual) and fewer than half of its corners are out;
    a view left with a corner beyond the cut is judged whole, as before.

    The corner gate comes after the view gate, and a view's few gross corners (ChArUco
    corners beside the da Vinci board's beads, on a board seen at a grazing angle) pull its pose, so that
    its other corners' median residual rises with them: on the da Vinci left views, once the
    corners were refined to their point of symmetry (the median view's residual 0.44 -> 0.20
    px), three views of 11-27 corners with one or two corners off by 3-8 px were rejected
    whole, their other corners 0.14-0.16 px from their projection.
    """
    if not k:
        return masks, norms
    allr = np.concatenate([norms[i][masks[i]] for i in used])
    cut = k * math.sqrt(float(np.median(allr ** 2)) / _CHI2_2_MEDIAN)
    judged, out = dict(masks), dict(norms)
    for i in used:
        keep, r = masks[i].copy(), norms[i]
        while np.max(np.where(keep, r, 0.0)) > cut and 2 * (keep.sum() - 1) > masks[i].sum():
            keep[np.argmax(np.where(keep, r, -1.0))] = False
            _, res = fit_pose(layout, theta, np.zeros(2), poses[i], objs[i], imgs[i], weights=keep.astype(float))
            r = np.linalg.norm(res, axis=1)
        # a view that stays beyond the cut is judged as it is (a bad view, not a few bad corners)
        if not np.array_equal(keep, masks[i]) and np.max(r[keep]) <= cut:
            judged[i], out[i] = keep, r
    return judged, out


def _reject_views(used, masks, norms, k, min_views, rejected, judged=None):
    """Reject views whose median residual is far above the others'. True if any were.
    judged : ({view: (K,) corners}, {view: (K,) norms}) the median is taken over, when not
    (masks, norms) (`_without_gross_corners`)."""
    if not k or len(used) <= min_views:
        return False
    jm, jn = judged if judged is not None else (masks, norms)
    stat = np.array([float(np.median(jn[i][jm[i]])) for i in used])
    med = float(np.median(stat))
    mad = float(np.median(np.abs(stat - med)))
    thr = max(med + k * _MAD_SCALE * mad, _VIEW_RATIO_FLOOR * med)
    worst = float(stat.max())
    if worst <= thr:
        return False
    # gross outliers first: the rest are judged again after the refit
    cut = max(thr, 0.5 * worst)
    order = np.argsort(-stat)
    bad = [j for j in order if stat[j] > cut][: len(used) - min_views]
    if not bad:
        return False
    for j in bad:
        i = used[j]
        rms = float(np.sqrt(np.mean(norms[i][masks[i]] ** 2)))
        rejected.append({"view": i, "stage": "outlier", "rms_px": rms,
                         "reason": f"outlier view: median residual {stat[j]:.3g} px (RMS {rms:.3g} px) is far "
                                   f"above the other views' (threshold {thr:.3g} px, median view {med:.3g} px)"})
    for j in sorted(bad, reverse=True):
        del used[j]
    return True


def _reject_corners(used, masks, norms, k, sigma, min_corners, rejected):
    """Reject single corners with residual > k sigma (sigma per axis). True if any were."""
    if not k or not sigma:
        return False
    allr = np.concatenate([norms[i][masks[i]] for i in used])
    thr = k * sigma
    worst = float(allr.max())
    if worst <= thr:
        return False
    cut = max(thr, 0.5 * worst)
    changed = False
    for i in list(used):
        bad = np.flatnonzero(masks[i] & (norms[i] > cut))
        if bad.size == 0:
            continue
        changed = True
        for c in bad:
            rejected.append({"view": i, "stage": "outlier", "corner": int(c), "residual_px": float(norms[i][c]),
                             "reason": f"outlier corner: residual {norms[i][c]:.3g} px > {k:g} sigma "
                                       f"({thr:.3g} px, sigma {sigma:.3g} px per axis)"})
        masks[i][bad] = False
        left = int(masks[i].sum())
        if left < min_corners:
            used.remove(i)
            rejected.append({"view": i, "stage": "outlier",
                             "reason": f"only {left} corners left after outlier rejection "
                                       f"(need at least {min_corners})"})
    return changed


def detect_views(images, board, symmetric=False):
    """The board's detections in images: (Board, [BoardDetection or None per image], (w, h)).

    images : IMAGES (a path, folder, glob or video, or a list of them) or a sequence of
        (H, W[, 3]) arrays, all the same size; board : Board, or the path of a board file;
        symmetric : ChArUco corners refined to their point of symmetry (`detect_board`).
    Images that cannot be decoded give None.
    """
    from pencilcal.toolkit.board.detect import detect_board
    from pencilcal.toolkit.board.spec import Board, read_board
    from pencilcal.toolkit.io.images import open_images

    board = board if isinstance(board, Board) else read_board(board)
    if isinstance(images, (list, tuple)) and images and isinstance(images[0], np.ndarray):
        frames = list(images)
    else:
        frames = [f.image for f in open_images(images, gray=True)]
    decoded = [im for im in frames if im is not None]
    if not decoded:
        raise InputError("none of the images could be decoded")
    sizes = {(im.shape[1], im.shape[0]) for im in decoded}
    if len(sizes) > 1:
        raise InputError(f"the images differ in size ({sorted(sizes)}); calibrate one camera at one size")
    return board, [None if im is None else detect_board(im, board, symmetric) for im in frames], sizes.pop()


def calibrate_images(images, board, model="opencv", coefficients=None, *, symmetric_corners=False, **options):
    """Calibrate from images: detect the board in each (`detect_views`), then `calibrate`.

    model, coefficients, options : as `calibrate`; symmetric_corners : ChArUco corners
    refined to their point of symmetry (`detect_board`'s ``symmetric``). Returns the `CalibrationResult`; its
    ``camera`` is the calibrated Camera. Views that cannot be decoded are skipped like
    views without the board. (`pencilcal.calibrate` adds the checks and the verdict.)
    """
    board, detections, size = detect_views(images, board, symmetric_corners)
    return calibrate(detections, board, size, model=model, coefficients=coefficients, **options)
