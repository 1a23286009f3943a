"""Calibration as one least-squares problem: intrinsics, every view's pose and the board's warp.

`refine` minimises the sum of squared corner residuals over the free intrinsics, the pose of
every view and, with ``Layout.warp``, two warp parameters of the board, as mrcal's
``calobject_warp`` does: a printed board is not flat, and a sheet that sags or bulges by a
fraction of a millimetre moves the corners of a tilted view by more than their noise. The
board's points are displaced along its normal (board frame z, into the sheet) by::

    dz = warp_x * 4 s (1 - s) + warp_y * 4 t (1 - t)  [+ warp_twist * 4 (s - 1/2) (t - 1/2)]

with s, t in [0, 1] the corner's position across the board's corner grid (`warp_basis`):
two parabolas, zero along the grid's border, ``warp_x`` and ``warp_y`` [board unit] at its
middle; with ``Layout.twist`` a third shape, the saddle of a board twisted about its axes
(zero along the grid's middle lines, ``+-warp_twist`` at its corners), which mrcal's two
parabolas lack: a twisted board seen from different directions looks like a focal length
that changes from view to view. The solver is Levenberg-Marquardt on the normal equations with the poses eliminated
by a Schur complement (one small solve per view), the projection and its Jacobian from
``cv2.projectPoints`` / ``cv2.fisheye.projectPoints``.

`covariance` gives the covariance of the estimate under the corner errors the residuals show
(`toolkit.board.corner_noise`): each view's errors white at that view's own level, plus a
smooth part correlated between neighbouring corners. The estimate is ordinary least squares,
so its covariance is the sandwich ``S^-1 (sum_v A_v^T Sigma_v A_v) S^-1`` with ``A_v`` the
view's Jacobian of the global parameters with its pose projected out and ``S = sum_v
A_v^T A_v`` (the Schur complement). With white errors of one level this is OpenCV's
``sigma^2 (J^T J)^-1``.

Conventions as `toolkit.board.calibrate`: raw pixels, residual = observed - projected,
poses ``cam_from_target`` as (rvec, tvec), tvec and the warp in the board's length unit.

Example
-------
>>> import numpy as np
>>> from pencilcal.toolkit.board.spec import board_from_dict
>>> from pencilcal.toolkit.board.calibrate import synthetic_detections
>>> from pencilcal.toolkit.camera.model import Camera
>>> board = board_from_dict({"type": "chessboard", "squares": [9, 6], "square": 25.0})
>>> cam = Camera("opencv", 640, 480, [[530.0, 0, 320.0], [0, 530.0, 240.0], [0, 0, 1]], [-0.2, 0.05, 0, 0, 0])
>>> dets = synthetic_detections(cam, board, views=8, noise_px=0.1, seed=2, warp=(0.0, 0.4))
>>> objs = [board.object_points()] * 8
>>> bases = [warp_basis(board.object_points(), o) for o in objs]
>>> layout = Layout("opencv", 5)
>>> sol = refine(layout, theta_of(cam.K, cam.dist, layout), dets.truth, objs, [d.corners for d in dets], bases)
>>> cov = covariance(layout, sol, objs, [d.corners for d in dets], bases)
>>> bool(abs(sol.warp[1] - 0.4) < 4 * np.sqrt(cov.warp[1, 1])), sol.warp.shape
(True, (2,))
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from pencilcal.toolkit.camera import splined as _spl
from pencilcal.toolkit.camera.intrinsics import model_intrinsic_names
from pencilcal.toolkit.errors import EstimationError

__all__ = ["Layout", "Solution", "Covariance", "warp_basis", "theta_of", "camera_parts", "refine", "covariance",
           "fit_pose", "view_residuals", "board_scale", "board_jacobian", "view_jacobians", "penalty_normal",
           "WARP_NAMES"]

#: Names of the board's warp parameters [board unit].
WARP_NAMES = ("warp_x", "warp_y", "warp_twist")
# Levenberg-Marquardt: the first damping (relative to the normal matrix's diagonal), the
# largest before giving up, and the relative decrease of the cost that ends the iteration
_LAMBDA0 = 1e-4
_LAMBDA_MAX = 1e10
_REL_TOL = 1e-12
# the least share of a view's white level left to it when the printed board's offsets are
# taken out of it (`covariance`'s shared)
_MIN_OWN_SHARE = 0.1


@dataclass(frozen=True)
class Layout:
    """Which parameters a calibration estimates.

    model : "opencv" | "pinhole" | "fisheye" | a splined model's name; n_coef : its
    distortion coefficient count (0 for pinhole, 2 Nx Ny control points for splined);
    fix_aspect : fx = a fy with a held; fix_principal_point : cx, cy held; zero_tangent :
    opencv p1 = p2 = 0 held; warp : the board's two warp parameters estimated; twist : and
    the board's twist as a third (with ``warp``);
    spline_weight : a splined model's penalty on each control point [px per unit of u]
    (`splined.REGULARIZATION` times the focal length: `splined_layout`).
    """

    model: str
    n_coef: int
    fix_aspect: bool = False
    fix_principal_point: bool = False
    zero_tangent: bool = False
    warp: bool = True
    spline_weight: float = 0.0
    twist: bool = False

    @property
    def n_warp(self):
        """The board's shape parameters estimated: 0, 2 (the parabolas) or 3 (and the twist)."""
        return (3 if self.twist else 2) if self.warp else 0

    @property
    def names(self):
        """The full intrinsic vector's names (fx, fy, cx, cy, coefficients)."""
        return model_intrinsic_names(self.model, self.n_coef)

    def transform(self, theta):
        """T (P, F): the full intrinsics move by ``T @ delta`` for a step ``delta`` of the F
        free ones (fx follows fy with the aspect ratio held)."""
        P = 4 + self.n_coef
        cols = []
        if self.fix_aspect:
            c = np.zeros(P)
            c[0], c[1] = theta[0] / theta[1], 1.0
            cols.append(c)
        else:
            cols += [np.eye(P)[0], np.eye(P)[1]]
        if not self.fix_principal_point:
            cols += [np.eye(P)[2], np.eye(P)[3]]
        for i in range(self.n_coef):
            if not (self.model == "opencv" and self.zero_tangent and i in (2, 3)):
                cols.append(np.eye(P)[4 + i])
        return np.array(cols).T

    @property
    def n_global(self):
        """Free intrinsics plus warp parameters."""
        free = (1 if self.fix_aspect else 2) + (0 if self.fix_principal_point else 2) + self.n_coef
        if self.model == "opencv" and self.zero_tangent:
            free -= 2
        return free + self.n_warp


@dataclass
class Solution:
    """The optimum: theta (P,) full intrinsics, poses (V, 2, 3) (rvec, tvec) per view, warp
    (2,) [board unit] ((3,) with the twist; zeros (2,) when not estimated), the sum of squared residuals [px^2] over
    ``corners`` corners (a splined model's penalty not included), and the iterations run."""

    theta: np.ndarray
    poses: np.ndarray
    warp: np.ndarray
    sse: float
    corners: int
    iterations: int


@dataclass
class Covariance:
    """The estimate's covariance under a corner-error model.

    intrinsics : (P, P) over the full intrinsic vector (held parameters zero rows);
    warp : (W, 2) [board unit^2] (W = 3 with the twist; zeros (2, 2) when not estimated); cross : (P, W) between them;
    poses : (V, 6, 6) each view's (rvec, tvec); sigma_w : (V,) each view's white corner
    noise [px per axis]; model : "white" (one level, OpenCV's) or "views" (each view's level
    and the correlated part).
    """

    intrinsics: np.ndarray
    warp: np.ndarray
    cross: np.ndarray
    poses: np.ndarray
    sigma_w: np.ndarray
    model: str = "white"
    extra: dict = field(default_factory=dict)


def warp_basis(board_points, points, twist=False):
    """(N, 2) the warp's two shapes at `points` (N, 3) of a board whose corners are
    `board_points` (M, 3): ``4 s (1 - s)`` and ``4 t (1 - t)``, s and t the position across
    the corner grid's extent along x and y (0 at the first corner, 1 at the last); with
    `twist` (N, 3), the twist's ``4 (s - 1/2) (t - 1/2)`` as the third.

    >>> b = np.array([[0.0, 0, 0], [10, 0, 0], [0, 20, 0], [10, 20, 0]])
    >>> warp_basis(b, np.array([[5.0, 10, 0], [0, 0, 0]])).tolist()
    [[1.0, 1.0], [0.0, 0.0]]
    >>> warp_basis(b, np.array([[5.0, 10, 0], [0, 0, 0], [10, 0, 0]]), twist=True)[:, 2].tolist()
    [0.0, 1.0, -1.0]
    """
    lo = np.min(board_points[:, :2], 0)
    span = np.maximum(np.ptp(board_points[:, :2], 0), 1e-12)
    s = (np.asarray(points, float)[:, :2] - lo) / span
    out = 4.0 * s * (1.0 - s)
    if twist:
        out = np.c_[out, 4.0 * (s[:, 0] - 0.5) * (s[:, 1] - 0.5)]
    return out


def theta_of(K, dist, layout):
    """The full intrinsic vector (fx, fy, cx, cy, coefficients) of K and dist for `layout`
    (coefficients cut or zero-padded to its count)."""
    d = np.zeros(layout.n_coef)
    src = np.asarray(dist, float).ravel()[:layout.n_coef]
    d[:src.size] = src
    return np.r_[K[0][0], K[1][1], K[0][2], K[1][2], d]


def splined_layout(layout, cfg, theta):
    """The layout of `layout`'s options with the splined model `cfg` (a `SplineConfig`),
    its control points penalised with the weight `splined.REGULARIZATION` x sqrt(fx fy) of
    the intrinsics `theta` to start from."""
    w = _spl.REGULARIZATION * math.sqrt(abs(theta[0] * theta[1]))
    return Layout(cfg.name, cfg.parameters, layout.fix_aspect, layout.fix_principal_point, False, layout.warp, w,
                  layout.twist)


def _regularization(layout, theta, T):
    """The penalty's residuals (R,), observed 0 minus ``w * control points``, and their
    Jacobian in the free parameters (R, F); None for a lean model."""
    if not layout.spline_weight:
        return None
    P = 4 + layout.n_coef
    Jfull = np.zeros((layout.n_coef, P))
    Jfull[:, 4:] = layout.spline_weight * np.eye(layout.n_coef)
    return -layout.spline_weight * np.asarray(theta[4:], float), Jfull @ T


def penalty_normal(layout, theta):
    """The splined model's penalty in the normal equations over the free intrinsics (F, F),
    ``J^T J`` of `_regularization`; None for a lean model."""
    reg = _regularization(layout, theta, layout.transform(theta))
    return None if reg is None else reg[1].T @ reg[1]


def camera_parts(theta, layout):
    """(K (3, 3), dist (n_coef,)) of a full intrinsic vector."""
    K = np.array([[theta[0], 0.0, theta[2]], [0.0, theta[1], theta[3]], [0.0, 0.0, 1.0]])
    return K, np.asarray(theta[4:], float).copy()


def _project(layout, theta, rvec, tvec, obj):
    """Pixels (N, 2), d px / d full intrinsics (2N, P), d px / d (rvec, tvec) (2N, 6)."""
    import cv2

    if _spl.is_splined(layout.model):
        return _project_splined(layout, theta, rvec, tvec, obj)
    K, dist = camera_parts(theta, layout)
    rvec = np.asarray(rvec, float).reshape(3, 1)
    tvec = np.asarray(tvec, float).reshape(3, 1)
    o = np.asarray(obj, np.float64).reshape(-1, 1, 3)
    if layout.model == "fisheye":
        px, J = cv2.fisheye.projectPoints(o, rvec, tvec, K, dist)
        J = np.asarray(J, float)
        return px.reshape(-1, 2), J[:, 0:8], J[:, 8:14]
    px, J = cv2.projectPoints(o, rvec, tvec, K, dist if dist.size else None)
    J = np.asarray(J, float)
    return px.reshape(-1, 2), J[:, 6:10 + layout.n_coef], J[:, 0:6]


def _project_splined(layout, theta, rvec, tvec, obj):
    """`_project` of the splined model: pixels (N, 2), d px / d intrinsics (2N, P), d px /
    d (rvec, tvec) (2N, 6); the control points' columns hold the spline's weights."""
    import cv2

    cfg = _spl.splined_config(layout.model)
    R, dR = cv2.Rodrigues(np.asarray(rvec, float).reshape(3))
    o = np.asarray(obj, float).reshape(-1, 3)
    p = o @ R.T + np.asarray(tvec, float).reshape(3)
    # dR (3, 9): d R.ravel() / d rvec, so dp_i / drvec_k = sum_j dR[k, 3 i + j] o_j
    dp_dr = np.einsum("kij,nj->nik", dR.reshape(3, 3, 3), o)
    u, du_dp = _spl.stereographic(p)
    c, Jc, idx, w = _spl.correction(cfg, theta[4:], u, jac=True)
    f = np.asarray(theta[:2], float)
    N = o.shape[0]
    px = f * (u + c) + np.asarray(theta[2:4], float)
    dq_dp = f[:, None] * ((np.eye(2) + Jc) @ du_dp)                  # (N, 2, 3)
    Jp = np.concatenate([dq_dp @ dp_dr, dq_dp], -1).reshape(2 * N, 6)
    Ji = np.zeros((N, 2, 4 + cfg.parameters))
    Ji[:, 0, 0], Ji[:, 1, 1] = u[:, 0] + c[:, 0], u[:, 1] + c[:, 1]
    Ji[:, 0, 2] = Ji[:, 1, 3] = 1.0
    rows = np.arange(N)[:, None]
    for a in range(2):
        Ji[rows, a, 4 + idx[..., a]] = f[a] * w
    return px, Ji.reshape(2 * N, -1), Jp


def _warped(obj, basis, warp):
    if basis is None or not np.any(warp):
        return obj
    out = np.array(obj, float)
    out[:, 2] += basis @ warp
    return out


def _view(layout, theta, T, pose, obj, img, basis, warp):
    """One view at the current parameters: residuals r (2N,), the Jacobian of the
    *predictions* in the global parameters Jg (2N, G) and in the pose Jp (2N, 6)."""
    import cv2

    px, Ji, Jp = _project(layout, theta, pose[0], pose[1], _warped(obj, basis, warp))
    Jg = Ji @ T
    if layout.warp:
        R = cv2.Rodrigues(np.asarray(pose[0], float))[0]
        dz = Jp[:, 3:6] @ R[:, 2]                   # d px / d (board z), through tvec
        Jg = np.hstack([Jg, dz[:, None] * np.repeat(basis, 2, axis=0)])
    return (np.asarray(img, float) - px).reshape(-1), Jg, Jp


def _weighted(r, Jg, Jp, w):
    """A view's rows times the square root of its corners' weights w (K,) (None: as they are)."""
    if w is None:
        return r, Jg, Jp
    sw = np.repeat(np.sqrt(np.asarray(w, float)), 2)
    return r * sw, Jg * sw[:, None], Jp * sw[:, None]


def board_jacobian(pose, Jp):
    """(K, 2, 2) d pixel / d board (x, y) at each corner, from the pose Jacobian Jp (2K, 6)
    (its tvec columns: a board point moved along board x moves as tvec moved along R's
    first column)."""
    import cv2

    R = cv2.Rodrigues(np.asarray(pose[0], float).reshape(3))[0]
    return Jp.reshape(-1, 2, 6)[:, :, 3:6] @ R[:, :2]


def board_scale(pose, Jp):
    """(K,) the board's local scale at each corner [px per board unit]: sqrt |det| of
    d pixel / d board (x, y) (`board_jacobian`)."""
    return np.sqrt(np.abs(np.linalg.det(board_jacobian(pose, Jp))))


def view_jacobians(layout, solution, objs, imgs, bases=None):
    """Per view at the solution: (residuals observed - projected (K, 2) [px], the
    predictions' Jacobian in the global parameters Jg (2K, G) and in the pose Jp (2K, 6),
    d pixel / d board (x, y) (K, 2, 2)), unweighted."""
    bases = list(bases) if bases is not None else [None] * len(objs)
    T = layout.transform(solution.theta)
    out = []
    for pose, obj, img, basis in zip(solution.poses, objs, imgs, bases):
        r, Jg, Jp = _view(layout, solution.theta, T, pose, obj, img, basis, solution.warp)
        out.append((r.reshape(-1, 2), Jg, Jp, board_jacobian(pose, Jp)))
    return out


def _normal(layout, theta, T, poses, warp, objs, imgs, bases, weights=None):
    """The normal equations' blocks: A (G, G), g (G,), per view B (G, 6), C (6, 6), q (6,),
    and the cost (weighted with `weights`)."""
    G = T.shape[1] + layout.n_warp
    A, g = np.zeros((G, G)), np.zeros(G)
    Bs, Cs, qs = [], [], []
    sse = 0.0
    weights = [None] * len(objs) if weights is None else weights
    for pose, obj, img, basis, w in zip(poses, objs, imgs, bases, weights):
        r, Jg, Jp = _weighted(*_view(layout, theta, T, pose, obj, img, basis, warp), w)
        A += Jg.T @ Jg
        g += Jg.T @ r
        Bs.append(Jg.T @ Jp)
        Cs.append(Jp.T @ Jp)
        qs.append(Jp.T @ r)
        sse += float(r @ r)
    reg = _regularization(layout, theta, T)
    if reg is not None:
        r, J = reg
        A[:J.shape[1], :J.shape[1]] += J.T @ J
        g[:J.shape[1]] += J.T @ r
        sse += float(r @ r)
    return A, g, Bs, Cs, qs, sse


def _step(A, g, Bs, Cs, qs, lam):
    """The damped Gauss-Newton step (global, per view) by the Schur complement."""
    S = A + lam * np.diag(np.diag(A) + 1e-12)
    rhs = g.copy()
    Cinv = []
    for B, C, q in zip(Bs, Cs, qs):
        Ci = np.linalg.inv(C + lam * np.diag(np.diag(C) + 1e-12))
        Cinv.append(Ci)
        S -= B @ Ci @ B.T
        rhs -= B @ (Ci @ q)
    dg = np.linalg.solve(S, rhs)
    return dg, [Ci @ (q - B.T @ dg) for B, Ci, q in zip(Bs, Cinv, qs)]


def refine(layout, theta, poses, objs, imgs, bases=None, warp=None, max_iterations=100, weights=None):
    """Levenberg-Marquardt over the free intrinsics, the poses and the warp.

    Parameters
    ----------
    layout : Layout
    theta : (P,) the full intrinsics to start from (held ones stay).
    poses : (V, 2, 3) or sequence of (rvec, tvec): each view's pose to start from.
    objs, imgs : per view the board points (N_v, 3) [board unit] and their corners (N_v, 2) [px].
    bases : per view `warp_basis` (N_v, 2), (N_v, 3) with ``layout.twist``; needed with ``layout.warp``.
    warp : (2,) or (3,) to start from (zeros; a missing twist starts at 0).
    weights : per view (N_v,) each corner's weight (the inverse of its variance relative
        to the rest; `corner_noise`), or None: ordinary least squares. The solution's sse
        is then the weighted one.

    Returns
    -------
    Solution
        Raises EstimationError when a step cannot be solved (a singular problem).
    """
    theta = np.array(theta, float)
    poses = np.array([np.r_[np.ravel(r), np.ravel(t)] for r, t in poses], float).reshape(-1, 2, 3)
    warp = _warp_start(layout, warp)
    bases = list(bases) if bases is not None else [None] * len(objs)
    if layout.warp and any(b is None for b in bases):
        raise ValueError("the warp needs every view's warp_basis")
    T = layout.transform(theta)
    F = T.shape[1]
    weights = None if weights is None else list(weights)
    blocks = _normal(layout, theta, T, poses, warp, objs, imgs, bases, weights)
    lam = _LAMBDA0
    it = 0
    for it in range(1, int(max_iterations) + 1):
        try:
            dg, dps = _step(*blocks[:5], lam)
        except np.linalg.LinAlgError:
            raise EstimationError("the calibration problem is singular (too few views or corners for this "
                                  "model)") from None
        theta2 = theta + T @ dg[:F]
        warp2 = warp + dg[F:] if layout.warp else warp
        poses2 = poses + np.array(dps).reshape(-1, 2, 3)
        if not (np.all(np.isfinite(theta2)) and theta2[0] > 0 and theta2[1] > 0):
            lam *= 10.0
        else:
            new = _normal(layout, theta2, T, poses2, warp2, objs, imgs, bases, weights)
            if new[5] <= blocks[5]:
                done = blocks[5] - new[5] <= _REL_TOL * max(blocks[5], 1e-300)
                theta, warp, poses, blocks = theta2, warp2, poses2, new
                lam = max(lam / 10.0, 1e-15)
                if done:
                    break
                continue
            lam *= 10.0
        if lam > _LAMBDA_MAX:
            break
    corners = int(sum(np.asarray(o).shape[0] for o in objs))
    reg = _regularization(layout, theta, T)
    # the solution's sse is the corners' alone (the penalty is not a residual of the data)
    sse = float(blocks[5]) - (float(reg[0] @ reg[0]) if reg is not None else 0.0)
    return Solution(theta, poses, warp if layout.warp else np.zeros(2), sse, corners, it)


def _warp_start(layout, warp):
    """The warp to start from: zeros, or `warp` padded with a zero twist where the layout
    estimates one (a start from a fit without it)."""
    n = max(layout.n_warp, 2)
    out = np.zeros(n)
    if warp is not None:
        w = np.asarray(warp, float).reshape(-1)[:n]
        out[:w.size] = w
    return out


def view_residuals(layout, solution, objs, imgs, bases=None):
    """Per view observed - projected (N_v, 2) [px] at the solution."""
    bases = list(bases) if bases is not None else [None] * len(objs)
    out = []
    for pose, obj, img, basis in zip(solution.poses, objs, imgs, bases):
        px = _project(layout, solution.theta, pose[0], pose[1], _warped(obj, basis, solution.warp))[0]
        out.append(np.asarray(img, float) - px)
    return out


def fit_pose(layout, theta, warp, pose, obj, img, basis=None, max_iterations=30, weights=None):
    """One view's pose with the intrinsics and warp held: ((rvec, tvec), residuals (N, 2)
    [px], unweighted). For held-out views (`toolkit.board.model_choice`); weights (N,):
    each corner's weight in the fit (None: 1)."""
    lay = Layout(layout.model, layout.n_coef, warp=False)
    o = _warped(obj, basis, np.asarray(warp, float))
    rvec, tvec = np.array(pose[0], float).ravel(), np.array(pose[1], float).ravel()
    lam = _LAMBDA0
    sw = 1.0 if weights is None else np.repeat(np.sqrt(np.asarray(weights, float)), 2)
    px, _, Jp = _project(lay, theta, rvec, tvec, o)
    r = (np.asarray(img, float) - px).reshape(-1) * sw
    Jp = Jp * (sw if weights is None else sw[:, None])
    cost = float(r @ r)
    for _ in range(int(max_iterations)):
        H = Jp.T @ Jp
        try:
            d = np.linalg.solve(H + lam * np.diag(np.diag(H) + 1e-12), Jp.T @ r)
        except np.linalg.LinAlgError:
            break
        rv2, tv2 = rvec + d[:3], tvec + d[3:]
        px2, _, Jp2 = _project(lay, theta, rv2, tv2, o)
        r2 = (np.asarray(img, float) - px2).reshape(-1) * sw
        Jp2 = Jp2 * (sw if weights is None else sw[:, None])
        c2 = float(r2 @ r2)
        if np.isfinite(c2) and c2 <= cost:
            done = cost - c2 <= _REL_TOL * max(cost, 1e-300)
            rvec, tvec, r, Jp, cost = rv2, tv2, r2, Jp2, c2
            lam = max(lam / 10.0, 1e-15)
            if done:
                break
        else:
            lam *= 10.0
            if lam > _LAMBDA_MAX:
                break
    if weights is not None:
        # the residuals unweighted (a corner of weight 0 included)
        r = (np.asarray(img, float) - _project(lay, theta, rvec, tvec, o)[0]).reshape(-1)
    return (rvec, tvec), r.reshape(-1, 2)


def covariance(layout, solution, objs, imgs, bases=None, noise=None, weights=None, shared=None, field=None):
    """The covariance of `refine`'s estimate.

    noise : None for white corner errors of one level, estimated from all residuals
        (``sum r^2 / (2M - P)``, OpenCV's figure); or a `CornerNoise`: each view's white
        level by REML (`corner_noise.white_variance`), its heteroscedastic shape within the
        view and the correlated part, through the sandwich (the module's docstring).
        `corner_noise.WHITE` gives each view its own white level only.
    weights : the corner weights `refine` was given (None: ordinary least squares); the
        sandwich is that of the weighted estimate, so weights that are not the inverse
        variances still give its true covariance under `noise`.
    shared : the printed board's corner offsets (`print_errors.PrintErrors`) or None. Their
        share of each view's residuals (``A diag(var) A^T`` per corner, A = d pixel / d
        board (x, y)) is taken out of the view's white part in the intrinsics' and warp's
        covariance: the residuals show them as if they were the view's own white noise,
        but they are common to every view and enter that covariance as their own term
        (`print_errors.covariance_term`), not here. The poses' covariance and sigma_w keep
        the whole level (each pose sees the offsets once, as noise of its own).
    field : the correlated error fixed in the image (`image_field.ImageField`) or None.
        Where kept, its share of the correlated part leaves each view's own in the
        intrinsics' and warp's covariance (``c (1 - share)``): it is one error every view
        sees, carried as its own term (`image_field.covariance_term`). The poses' keep the
        whole correlated part.

    Returns a `Covariance`; its intrinsics and warp blocks are inf where the problem is
    singular.
    """
    from pencilcal.toolkit.board.corner_noise import CornerView, kernel, variance_factor, white_variance

    bases = list(bases) if bases is not None else [None] * len(objs)
    weights = [None] * len(objs) if weights is None else list(weights)
    T = layout.transform(solution.theta)
    F = T.shape[1]
    views = []
    S = None
    sse = 0.0
    for pose, obj, img, basis, w in zip(solution.poses, objs, imgs, bases, weights):
        r, Jg, Jp = _view(layout, solution.theta, T, pose, obj, img, basis, solution.warp)
        img = np.asarray(img, float)
        d = np.ones(img.shape[0]) if noise is None else \
            variance_factor(noise, img, board_scale(pose, Jp), solution.theta[2:4])
        # the offsets' variance per corner and image axis, relative to the corner's factor
        share = 0.0 if shared is None else float(np.mean(
            np.einsum("kab,b,kab->ka", board_jacobian(pose, Jp), np.asarray(shared.variance, float),
                      board_jacobian(pose, Jp)) / d[:, None]))
        # the weighted errors' covariance is s2 G (I + c k) G per axis, G = diag(sqrt(w d))
        g = np.sqrt(d if w is None else np.asarray(w, float) * d)
        r, Jg, Jp = _weighted(r, Jg, Jp, w)
        # a corner weighted 0 (set aside) adds nothing: its weighted residual is 0 / 0
        gg = np.repeat(g, 2)
        sse += float(np.sum(np.where(gg > 0, r / np.where(gg > 0, gg, 1.0), 0.0) ** 2))
        C = Jp.T @ Jp
        Ci = np.linalg.pinv(C)
        PJ = Jg - Jp @ (Ci @ (Jp.T @ Jg))               # the pose projected out
        S = Jg.T @ PJ if S is None else S + Jg.T @ PJ
        views.append((r, Jg, Jp, Ci, PJ, img, np.repeat(g, 2), share))
    G = S.shape[0]
    reg = _regularization(layout, solution.theta, T)
    if reg is not None:
        S[:F, :F] += reg[1].T @ reg[1]
    dof = 2 * solution.corners - (G + 6 * len(views))
    if dof <= 0:
        raise EstimationError(f"{solution.corners} corners cannot determine {G + 6 * len(views)} parameters")
    try:
        Si = np.linalg.inv(S)
        if not np.all(np.isfinite(Si)) or np.any(np.diag(Si) <= 0):
            raise np.linalg.LinAlgError
    except np.linalg.LinAlgError:
        Si = np.full((G, G), np.inf)
    s2, mids, sig_e = [], [], []
    own_ratio = 0.0 if noise is None else noise.ratio * (1.0 - (field.share if field is not None and field.kept
                                                                 else 0.0))
    for r, Jg, Jp, Ci, PJ, img, g, share in views:
        K = img.shape[0]
        k = kernel(img, noise.length_px) if noise is not None and noise.ratio > 0 else None
        if noise is None:
            level = sse / dof
        else:
            level = white_variance(CornerView(img, -(r / g).reshape(-1, 2), Jp / g[:, None]), noise, k)
        s2.append(level)
        GP = PJ * g[:, None]
        # the offsets show in the residuals as white errors: they come out of the white
        # part only (a floor: a view they would explain whole keeps a tenth of it), the
        # correlated part stays the level's
        M = max(1.0 - share / level, _MIN_OWN_SHARE) * (GP.T @ GP) if share else GP.T @ GP
        if k is not None:
            P3 = GP.reshape(K, 2, -1)
            M = M + own_ratio * np.einsum("kbp,kbq->pq", P3, np.einsum("kl,lbq->kbq", k, P3))
        mids.append(M)
        sig_e.append(None if k is None else noise.ratio * k)
    if np.all(np.isfinite(Si)):
        meat = sum(v * M for v, M in zip(s2, mids))
        if reg is not None:
            # the penalty read as a prior: its residuals [px] weigh like a corner's, so
            # they carry the corners' mean (weighted) variance; where no corner sees a
            # control point its sigma is then the prior's, and the halves' different
            # pulls towards zero are inside it (without this the sandwich is the
            # penalised estimate's scatter alone, its bias left out)
            var = np.concatenate([v * view[6] ** 2 for v, view in zip(s2, views)])
            meat = meat.copy()
            meat[:F, :F] += float(np.mean(var)) * (reg[1].T @ reg[1])
        Cg = Si @ meat @ Si
        Cg = 0.5 * (Cg + Cg.T)
    else:
        Cg = Si
    cov_poses = []
    for (r, Jg, Jp, Ci, PJ, img, g, _), v, Sigma in zip(views, s2, sig_e):
        B = Jg.T @ Jp
        if not np.all(np.isfinite(Cg)):
            cov_poses.append(np.full((6, 6), np.inf))
            continue
        # dpose = Ci Jp^T e - Ci B^T dg, dg = Si sum PJ^T e; the errors e are G (I + Sigma
        # (x) I_2) G s2 with Sigma the view's correlated part per axis (K, K)
        GJ = Jp * g[:, None]
        GJ_S = GJ if Sigma is None else GJ + np.einsum("kl,lbq->kbq", Sigma, GJ.reshape(-1, 2, 6)).reshape(-1, 6)
        own = v * Ci @ (GJ.T @ GJ_S) @ Ci
        cross = v * Ci @ (GJ_S.T @ (PJ * g[:, None])) @ Si @ B @ Ci
        cp = own - cross - cross.T + Ci @ B.T @ Cg @ B @ Ci
        cov_poses.append(0.5 * (cp + cp.T))
    nw = max(layout.n_warp, 2)
    Ti = np.zeros((T.shape[0] + nw, G))
    Ti[:T.shape[0], :F] = T
    if layout.warp:
        Ti[T.shape[0]:, F:] = np.eye(nw)
    full = Ti @ Cg @ Ti.T if np.all(np.isfinite(Cg)) else np.full((Ti.shape[0],) * 2, np.inf)
    P = T.shape[0]
    return Covariance(0.5 * (full[:P, :P] + full[:P, :P].T), full[P:, P:], full[:P, P:], np.array(cov_poses),
                      np.sqrt(np.array(s2)), "white" if noise is None else "views")


def corner_views(layout, solution, objs, imgs, bases=None):
    """Each view's corners, residuals (projected - observed), pose Jacobian, the board's
    local scale at each corner (`board_scale`) and the principal point at the solution, as
    `corner_noise.CornerView`s (for `corner_noise.fit_corner_noise`)."""
    from pencilcal.toolkit.board.corner_noise import CornerView

    bases = list(bases) if bases is not None else [None] * len(objs)
    T = layout.transform(solution.theta)
    out = []
    for pose, obj, img, basis in zip(solution.poses, objs, imgs, bases):
        r, _, Jp = _view(layout, solution.theta, T, pose, obj, img, basis, solution.warp)
        out.append(CornerView(np.asarray(img, float), -r.reshape(-1, 2), Jp, board_scale(pose, Jp),
                              np.asarray(solution.theta[2:4], float)))
    return out
