"""A shaft's 3-D axis from both eyes of a calibrated stereo pair, and the fulcrum of such axes.

Each silhouette edge of a shaft back-projects to a plane through its camera's centre that
touches the cylinder: with two eyes a shaft gives four such planes. Every one is parallel
to the axis and at the radius r from it, eight conditions on five unknowns (the axis's four
degrees of freedom and r), so the axis and the radius follow from the silhouettes alone, by
least squares, with no fulcrum ray and, if need be, no known diameter: the baseline fixes
the depth where one eye has only the band's width.

`stereo_axis` fits them in the left camera frame. It starts from the planes (the direction
orthogonal to the four normals, then the point and r linear in the plane equations) and
minimises the edges' image residuals: per eye and edge, the angle between the measured edge
and the cylinder's silhouette line (`cylinder.project_cylinder`) and the measured segment
centre's distance from that line, whitened by the edge's 2x2 covariance of (angle
[rad], offset [px]) (`shaft.axis.Midline.edge_cov`, `cylinder.shaft_axis`'s convention).
Unknowns: the axis in the chart of `pencil.cylinder` (theta_u, theta_w, s_u, s_w) about
the start, and r; with a known diameter a prior on r (its sd given). The covariance is
``(J^T J)^-1`` of the whitened residuals, and ``rig_jacobian = -(J^T J)^-1 J^T J_rig``
says how the axis moves with an error of the rig (its rotation vector and translation).
The rig is one for all the shafts of a sequence: `stereo_fulcrum_axes` solves the fulcrum
together with the rig's error, under its prior, not axis by axis (where its effect would
count as independent and average away).

`match_shafts` pairs the shafts of the two eyes of a frame by the chi2 of their joint fit,
gated at the edges' own noise over a sequence (`match_factor`, in `matched_axes`);
`stereo_fulcrum_axes` is the fulcrum of the stereo axes (`cylinder.fulcrum_3d`), each axis
weighed by its covariance at its own estimate (on pivots like a da Vinci endoscope's the
point leans less towards the camera than with each covariance evaluated at the line through
the point: docs/method.md).

Conventions as `pencil.cylinder`: OpenCV camera frames, lengths in the rig's unit (mm),
``p_right = R_right_from_left p_left + t_right_from_left``, undistorted pixels of each eye's
K; edge segments ``[x1, y1, x2, y2]``.

Example
-------
>>> import numpy as np
>>> from pencilcal.toolkit.pencil.cylinder import project_cylinder
>>> K = np.array([[600.0, 0, 320], [0, 600, 240], [0, 0, 1]])
>>> R, t = np.eye(3), np.array([-5.0, 0, 0])                 # right eye 5 mm to the right
>>> A, d = np.array([0.0, 5, 80]), np.array([1.0, 0.2, 0.3])
>>> def edges(K, A, d):
...     ls = project_cylinder(K, A, d, 4.0).lines
...     return np.array([[0.0, -l[2] / l[1], 640.0, -(l[2] + 640 * l[0]) / l[1]] for l in ls])
>>> cov = np.broadcast_to(np.diag([1e-6, 0.01]), (2, 2, 2))
>>> ax = stereo_axis(K, edges(K, A, d), cov, K, edges(K, R @ A + t, R @ d), cov, R, t)
>>> round(float(ax.radius), 6), np.round(ax.axis_point, 4).tolist()
(4.0, [-22.1239, 0.5752, 73.3628])
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from pencilcal.toolkit.camera.stereo import pair_frames
from pencilcal.toolkit.errors import EstimationError, InputError
from pencilcal.toolkit.geometry.frames import normalize, rotation_from_rotvec
from pencilcal.toolkit.geometry.projective import line_through
from pencilcal.toolkit.geometry.quantiles import chi2_isf
from pencilcal.toolkit.pencil.cylinder import (GATE_CONFIDENCE, Fulcrum3D, axis_frame, axis_offsets, fulcrum_3d,
                                               offset_chi2, project_cylinder, silhouette_planes)
from pencilcal.toolkit.pencil.sequence_noise import MAX_RUNS, MIN_DOF

__all__ = ["StereoAxis", "AxesFulcrum", "stereo_axis", "match_shafts", "stereo_fulcrum_axes", "stereo_axes_from_frames",
           "matched_axes"]

_STEP = 1e-6  # central-difference step of the Jacobians (chart units, mm, rad)
_RADIUS_PRIOR_REL = 1e-3  # a known diameter's radius prior: its sd relative to the radius
_MIN_FACTOR = 1e-6  # the least factor on the edges' covariances (their fits' chi2 of exact edges is ~0)


@dataclass(frozen=True, eq=False)
class StereoAxis:
    """A shaft's axis from both eyes (`stereo_axis`), left camera frame.

    axis_point (3,) [length]: the axis's point closest to the left camera centre;
    axis_direction (3,) unit, d_z > 0; axis_cov (4, 4): covariance of the chart
    (theta_u, theta_w [rad], s_u, s_w [length]) about it (`pencil.cylinder`), the edges'
    noise only; axis_frame (2, 3): the chart's (u, w); radius [length] and radius_sigma;
    cov (5, 5): the chart's and r's covariance; rig_jacobian (5, 6): d (chart, r) / d (rig
    rotation vector [rad], translation [length]), for the rig's covariance; chi2: the
    whitened residuals' sum of squares, dof its expected value at the stated noise: 8 - 5,
    plus with a radius prior that prior's leverage ``radius_sigma^2 / prior_sd^2`` (1 where
    the prior fixes the radius, 0 where the edges fix it far better). Not a whole 1: the
    prior's value, a known diameter, is not drawn anew with each shaft, so its term holds
    noise only in the share by which it fixes r (edges drawn at their covariances: mean
    chi2 3.08 at 0.0001 px where the prior's leverage is 0, 4.08 at 0.1 px where it is 0.97;
    `_fits_factor` read their noise at 0.7 of the truth with a whole dof for it).
    """

    axis_point: np.ndarray
    axis_direction: np.ndarray
    axis_cov: np.ndarray
    axis_frame: np.ndarray
    radius: float
    radius_sigma: float
    cov: np.ndarray
    rig_jacobian: np.ndarray
    rig_information: np.ndarray
    rig_vector: np.ndarray
    chi2: float
    dof: float


def _canon(d):
    d = normalize(d)
    return -d if (d[2] < 0 or (d[2] == 0 and (d[1] < 0 or (d[1] == 0 and d[0] < 0)))) else d


def _line_of(chart, A, d, frame):
    """(point, direction) of the line at chart coordinates (4,) about (A, d, frame)."""
    u, w = frame
    return A + chart[2] * u + chart[3] * w, normalize(d + chart[0] * u + chart[1] * w)


def _edge_terms(edges):
    """(centre (2, 2), angle (2,)) of two edge segments (2, 4) [px]."""
    e = np.asarray(edges, float)
    c = 0.5 * (e[:, :2] + e[:, 2:])
    return c, np.arctan2(e[:, 3] - e[:, 1], e[:, 2] - e[:, 0])


def _whiteners(covs):
    """(2, 2, 2) the inverse Cholesky factors of two edges' (angle, offset) covariances."""
    covs = np.asarray(covs, float).reshape(2, 2, 2)
    try:
        return np.stack([np.linalg.inv(np.linalg.cholesky(c)) for c in covs])
    except np.linalg.LinAlgError:
        raise InputError("stereo_axis: an edge covariance is not positive definite") from None


def _residuals_eye(K, A, d, r, centre, angle, Wh, order):
    """Whitened residuals (4,) of one eye's two edges against the cylinder's silhouette
    lines, the lines taken in the given order (2,)."""
    lines = project_cylinder(K, A, d, r).lines[list(order)]
    out = []
    for k in range(2):
        a, b, c = lines[k]
        ang = np.arctan2(a, -b)  # the direction (-b, a)... of the line, mod pi
        dphi = (ang - angle[k] + 0.5 * np.pi) % np.pi - 0.5 * np.pi
        nu = np.array([-np.sin(angle[k]), np.cos(angle[k])])
        # the measured centre's distance from the line, along the measured normal
        off = -(a * centre[k, 0] + b * centre[k, 1] + c) / (a * nu[0] + b * nu[1])
        out.append(Wh[k] @ np.array([dphi, off]))
    return np.concatenate(out)


def _order(K, A, d, r, centre):
    """Which silhouette line (of `project_cylinder`) each measured edge is: (2,)."""
    lines = project_cylinder(K, A, d, r).lines
    dist = np.abs(lines[:, :2] @ centre.T + lines[:, 2:3])  # (line, edge)
    return (0, 1) if dist[0, 0] + dist[1, 1] <= dist[1, 0] + dist[0, 1] else (1, 0)


def _planes(K, edges, R=None, t=None):
    """The oriented tangent planes (2, 3) normals and (2,) offsets of one eye's edges, in
    the left frame: ``n . X = n . C`` (C the eye's centre)."""
    e = np.asarray(edges, float)
    h = line_through(e[:, :2], e[:, 2:])
    inside = np.linalg.inv(K) @ np.r_[0.25 * (e[0, :2] + e[0, 2:] + e[1, :2] + e[1, 2:]), 1.0]
    n = silhouette_planes(h @ K, inside[:2] / inside[2])
    if R is None:
        return n, np.zeros(2)
    n = n @ R  # R^T n: right-frame normals into the left frame
    C = -R.T @ t
    return n, n @ C


def _start(K_l, edges_l, K_r, edges_r, R, t, radius):
    """(A, d, r): the axis and radius from the four planes, linear (module docstring)."""
    n1, o1 = _planes(K_l, edges_l)
    n2, o2 = _planes(K_r, edges_r, R, t)
    N = np.concatenate([n1, n2])
    off = np.concatenate([o1, o2])
    d = _canon(np.linalg.svd(N)[2][-1])
    # n_i . A - r = n_i . C_i, A . d = 0
    M = np.zeros((5, 4))
    M[:4, :3] = N
    M[:4, 3] = -1.0
    M[4, :3] = d
    rhs = np.r_[off, 0.0]
    if radius is not None:
        sol, *_ = np.linalg.lstsq(M[:, :3], rhs + np.r_[np.full(4, radius), 0.0], rcond=None)
        return sol, d, float(radius)
    sol, *_ = np.linalg.lstsq(M, rhs, rcond=None)
    if not sol[3] > 0:
        raise EstimationError("stereo_axis: the four silhouette planes bound no cylinder")
    return sol[:3], d, float(sol[3])


@dataclass(frozen=True, eq=False)
class _Problem:
    """One shaft's stereo measurements, as `stereo_axis` whitens them: each eye's camera
    matrix, edge centres (2, 2) [px], angles (2,) [rad], whiteners (2, 2, 2) and which
    silhouette line each edge is (2,); the rig; the radius prior (value, sd) or None."""

    K_l: np.ndarray
    K_r: np.ndarray
    centre_l: np.ndarray
    angle_l: np.ndarray
    white_l: np.ndarray
    order_l: tuple
    centre_r: np.ndarray
    angle_r: np.ndarray
    white_r: np.ndarray
    order_r: tuple
    R: np.ndarray
    t: np.ndarray
    prior: tuple | None


def _residuals(prob, p, A, d, frame, R=None, t=None):
    """Whitened residuals (8,) or (9,) of a `_Problem` for the line at chart coordinates p[:4]
    about (A, d, frame) with radius p[4], under the rig (R, t) (default the problem's)."""
    R = prob.R if R is None else R
    t = prob.t if t is None else t
    P, D = _line_of(p[:4], A, d, frame)
    r = p[4]
    if not r > 0:
        raise EstimationError("stereo_axis: the fit left the cylinder (radius <= 0)")
    try:
        res = [_residuals_eye(prob.K_l, P, D, r, prob.centre_l, prob.angle_l, prob.white_l, prob.order_l),
               _residuals_eye(prob.K_r, R @ P + t, R @ D, r, prob.centre_r, prob.angle_r, prob.white_r, prob.order_r)]
    except InputError:  # a camera centre inside the cylinder: these edges bound none
        raise EstimationError("stereo_axis: the edges bound no cylinder clear of both cameras") from None
    if prob.prior is not None:
        res.append([(r - prob.prior[0]) / prob.prior[1]])
    return np.concatenate(res)


def _jacobian(prob, A, d, r):
    """(f0, J (n, 5)) of a `_Problem`: its residuals at the line (A, d) with radius r and
    their Jacobian in the line's chart (`axis_frame(A, d)`) and r, by central differences."""
    frame = axis_frame(A, d)
    p0 = np.r_[np.zeros(4), r]
    return _residuals(prob, p0, A, d, frame), _jac(lambda p: _residuals(prob, p, A, d, frame), p0, 5)


def _jac(f, p, n):
    return np.stack([(f(p + h) - f(p - h)) / (2 * _STEP) for h in np.eye(n) * _STEP], -1)


def stereo_axis(K_left, edges_left, cov_left, K_right, edges_right, cov_right, R_right_from_left, t_right_from_left,
                *, radius=None, radius_sigma=None, iterations=20):
    """A shaft's 3-D axis and radius from its silhouette edges in both eyes (module docstring).

    K_left, K_right: (3, 3) each eye's camera matrix of its undistorted pixels;
    edges_left, edges_right: (2, 4) each eye's two edge segments [undistorted px];
    cov_left, cov_right: (2, 2, 2) per edge the covariance of its (angle [rad], offset [px])
    about the segment's centre; R_right_from_left (3, 3), t_right_from_left (3,) [length]:
    the rig; radius [length], radius_sigma [length]: a prior on the radius (the shaft's
    known diameter over two, and how well it is known; radius_sigma None with a radius: 1e-3
    of it). Returns a `StereoAxis`; EstimationError when the edges bound no cylinder.
    """
    K_l, K_r = np.asarray(K_left, float), np.asarray(K_right, float)
    R, t = np.asarray(R_right_from_left, float), np.asarray(t_right_from_left, float)
    el, er = np.asarray(edges_left, float).reshape(2, 4), np.asarray(edges_right, float).reshape(2, 4)
    cl, al = _edge_terms(el)
    cr, ar = _edge_terms(er)
    Wl, Wr = _whiteners(cov_left), _whiteners(cov_right)
    A0, d0, r0 = _start(K_l, el, K_r, er, R, t, radius)
    prior = None
    if radius is not None:
        prior = (float(radius), float(_RADIUS_PRIOR_REL * radius if radius_sigma is None else radius_sigma))
    try:
        ord_l, ord_r = _order(K_l, A0, d0, r0, cl), _order(K_r, R @ A0 + t, R @ d0, r0, cr)
    except InputError:
        raise EstimationError("stereo_axis: the edges bound no cylinder clear of both cameras") from None
    prob = _Problem(K_l, K_r, cl, al, Wl, ord_l, cr, ar, Wr, ord_r, R, t, prior)

    A, d, r = A0, d0, r0
    for _ in range(iterations):  # Gauss-Newton, the chart re-centred on the estimate each step
        f0, J = _jacobian(prob, A, d, r)
        step = np.linalg.lstsq(J, -f0, rcond=None)[0]
        P, D = _line_of(step[:4], A, d, axis_frame(A, d))
        A, d, r = P - (P @ D) * D, _canon(D), r + step[4]
        if np.max(np.abs(step)) < 1e-10:
            break
    frame = axis_frame(A, d)
    p0 = np.r_[np.zeros(4), r]
    f0, J = _jacobian(prob, A, d, r)
    cov = np.linalg.inv(J.T @ J)

    def rig_res(q):
        Rq = rotation_from_rotvec(q[:3]) @ R
        return _residuals(prob, p0, A, d, frame, Rq, t + q[3:])

    J_rig = _jac(rig_res, np.zeros(6), 6)
    A_rig = J_rig - J @ (cov @ (J.T @ J_rig))
    return StereoAxis(axis_point=A, axis_direction=d, axis_cov=cov[:4, :4], axis_frame=frame, radius=float(r),
                      radius_sigma=float(np.sqrt(cov[4, 4])), cov=cov, rig_jacobian=-cov @ J.T @ J_rig,
                      rig_information=A_rig.T @ A_rig, rig_vector=A_rig.T @ f0, chi2=float(f0 @ f0),
                      dof=3.0 + (0.0 if prior is None else float(min(cov[4, 4] / prior[1] ** 2, 1.0))))


def _candidates(K_left, left, K_right, right, R_right_from_left, t_right_from_left, **kw):
    """[(chi2, i, j, StereoAxis)] of every left shaft i with every right shaft j whose joint
    fit (`stereo_axis`) converges; arguments as `match_shafts`'s."""
    cands = []
    for i, (el, cl) in enumerate(left):
        for j, (er, cr) in enumerate(right):
            try:
                ax = stereo_axis(K_left, el, cl, K_right, er, cr, R_right_from_left, t_right_from_left, **kw)
            except (EstimationError, np.linalg.LinAlgError):
                continue
            cands.append((ax.chi2, i, j, ax))
    return cands


def _greedy(cands, confidence=None, factor=1.0):
    """[(i, j, StereoAxis)]: the candidates by increasing chi2, each shaft in at most one
    pair, those beyond ``factor * chi2.ppf(confidence, dof)`` left out (none with
    confidence None)."""
    out, used_l, used_r = [], set(), set()
    for c2, i, j, ax in sorted(cands, key=lambda c: c[0]):
        if confidence is not None and c2 > factor * chi2_isf(1.0 - confidence, ax.dof):
            continue
        if i not in used_l and j not in used_r:
            out.append((i, j, ax))
            used_l.add(i)
            used_r.add(j)
    return out


def match_shafts(K_left, left, K_right, right, R_right_from_left, t_right_from_left, *, confidence=GATE_CONFIDENCE,
                 factor=1.0, **kw):
    """Pairs of one frame's shafts seen by the two eyes: [(i, j, StereoAxis)], each left
    shaft i with at most one right shaft j, by the least chi2 of their joint fit
    (`stereo_axis`) under its gate (``factor * chi2.ppf(confidence, dof)``), greedily.

    left, right: lists of (edges (2, 4) [px], edge covariance (2, 2, 2)); factor: the
    edges' variance over their stated covariances (>= 1; a sequence's: `match_factor`);
    kw: the radius prior of `stereo_axis`."""
    return _greedy(_candidates(K_left, left, K_right, right, R_right_from_left, t_right_from_left, **kw),
                   confidence, factor)


def match_factor(frame_candidates):
    """The factor k >= 1 by which a sequence's edges are noisier than their covariances
    state, read from its frames' most consistent pairs: per frame the pairs of least chi2
    (`_greedy` without a gate), then the median over them of their joint fit's chi2 over the
    median of chi2(dof). The median, not the mean, so that a minority of wrong pairs (a shaft
    that one eye alone sees, paired with another) does not move it; the pairs' chi2 also
    holds the rig's calibration error, which every pair shares. 1 where the pairs pool
    fewer than `MIN_DOF` degrees of freedom, as `sequence_noise`.

    frame_candidates: per frame `_candidates`' list.

    >>> class Ax: dof, chi2 = 4, 4 * float(chi2_isf(0.5, 4))
    >>> class Bad: dof, chi2 = 4, 1e4
    >>> round(match_factor([[(Ax.chi2, 0, 0, Ax())]] * 3 + [[(Bad.chi2, 0, 0, Bad())]] * 2), 6)
    4.0
    """
    pairs = [ax for cands in frame_candidates for _, _, ax in _greedy(cands)]
    if sum(ax.dof for ax in pairs) < MIN_DOF:
        return 1.0
    return max(1.0, float(np.median([ax.chi2 / chi2_isf(0.5, ax.dof) for ax in pairs])))


@dataclass(frozen=True, eq=False)
class AxesFulcrum:
    """The fulcrum of stereo axes (`stereo_fulcrum_axes`), left camera frame: point (3,)
    [length] and point_cov (3, 3) (the edges' noise and, with its covariance, the rig's),
    point_sigma sqrt(trace); fit: the `cylinder.Fulcrum3D` of the axes alone (which axes
    were used, their chi2); rig_used: whether the rig's covariance was in the fit;
    play: the variance [length^2] per direction of the axes' offsets from one point beyond
    their covariances (`_axes_with_noise`), in point_cov; 0 where they scatter no more;
    factor: the factor (>= 1) on the axes' own covariances, in point_cov."""

    point: np.ndarray
    point_cov: np.ndarray
    point_sigma: float
    fit: Fulcrum3D
    rig_used: bool
    play: float = 0.0
    factor: float = 1.0


def _with_rig(x, axes, use, rig_cov, covs=None, iterations=10, factor=1.0):
    """(point (3,), covariance (3, 3)) of the fulcrum with the rig's error as an unknown
    common to every axis, under its prior: each used axis moves by its rig Jacobian times
    the rig's error delta (6,), and x and delta minimise the axes' weighted offsets, their
    own fits' residuals as delta changes them (`StereoAxis.rig_information`) and
    ``delta^T C_rig^-1 delta`` (a rig error that one axis would take for its own noise is
    seen in all of them together). covs: (N, 4, 4) the axes' chart covariances with the
    play in them (`_axes_with_noise`), default their own; factor: the factor k on the
    edges' covariances (`_axes_with_noise`), which whitens the fits' residuals by it too."""
    Cinv = np.linalg.pinv(rig_cov)
    covs = [a.axis_cov for a in axes] if covs is None else covs
    for _ in range(iterations):
        H = np.zeros((9, 9))
        g = np.zeros(9)
        for a, u, ac in zip(axes, use, covs):
            if not u:
                continue
            E = a.axis_frame
            t = float(a.axis_direction @ (x - a.axis_point))
            M = np.array([[t, 0.0, 1.0, 0.0], [0.0, t, 0.0, 1.0]])
            Sinv = np.linalg.inv(M @ ac @ M.T)
            B = np.hstack([E, -M @ a.rig_jacobian[:4]])  # d offset / d (x, delta)
            H += B.T @ Sinv @ B
            g += B.T @ Sinv @ (E @ a.axis_point)
            # the axis's own residuals: where the eyes disagree, the rig is off
            H[3:, 3:] += a.rig_information / factor
            g[3:] -= a.rig_vector / factor
        H[3:, 3:] += Cinv
        z = np.linalg.solve(H, g)
        done = np.max(np.abs(z[:3] - x)) < 1e-9
        x = z[:3]
        if done:
            break
    cov = np.linalg.inv(H)[:3, :3]
    return x, 0.5 * (cov + cov.T)


def _play(P, D, C, E, x):
    """A first variance s2 [length^2] (>= 0) per direction of an isotropic offset of each axis
    from the point x: the one that brings the median of every axis's chi2 (2 dof) to its own
    median, outliers and all (r, S the offset and its covariance, `cylinder.axis_offsets`),
    by bisection; 0 where the axes scatter no more than their covariances say. A start the
    gate of too small a noise cannot bias (`_axes_with_noise`)."""
    r, S, _ = axis_offsets(x, P, D, E, C)

    def over(s2):
        return np.median(offset_chi2(r, S + s2 * np.eye(2))) > 2.0 * np.log(2.0)
    if not over(0.0):
        return 0.0
    lo, hi = 0.0, float(np.max(np.sum(r * r, -1))) + 1e-12
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if over(mid) else (lo, mid)
    return hi


def _factor_and_play(r, S, start, iterations=100, factor=None):
    """(k >= 1, s2 >= 0) maximising the likelihood of the offsets r (N, 2) under covariances
    ``M = k S + s2 I`` (S: (N, 2, 2)): a factor on the axes' own covariances (edges noisier
    than said: mostly along each axis's depth, where a stereo axis is least precise) and an
    isotropic play; start: the first s2; factor: k where it is known (the axes' own fits,
    `_fits_factor`; below 1 too), only s2 fitted then. Fisher scoring on (k, s2), the linear variance
    components of M: the score ``g_j = 1/2 sum (r^T M^-1 A_j M^-1 r - tr(M^-1 A_j))`` and the
    expected information ``F_ij = 1/2 sum tr(M^-1 A_i M^-1 A_j)`` with A = (S, I), a
    component held at its bound while its score points past it.

    >>> S = np.broadcast_to(np.diag([0.01, 0.04]), (4, 2, 2))
    >>> r = np.array([[0.2, 0.4], [-0.2, -0.4], [0.2, -0.4], [-0.2, 0.4]])   # twice the sd: k = 4
    >>> [round(float(v), 6) for v in _factor_and_play(r, S, 0.0)]
    [4.0, 0.0]
    >>> [round(float(v), 6) for v in _factor_and_play(r, S, 0.0, factor=1.0)]   # k held: play
    [1.0, 0.059514]
    """
    k, s2 = (1.0 if factor is None else float(factor)), max(float(start), 0.0)
    eye = np.eye(2)
    for _ in range(iterations):
        Mi = np.linalg.inv(k * S + s2 * eye)
        u = np.einsum("nij,nj->ni", Mi, r)
        MS = Mi @ S
        g = 0.5 * np.array([np.sum(np.einsum("ni,nij,nj->n", u, S, u) - np.trace(MS, axis1=1, axis2=2)),
                            np.sum(np.sum(u * u, -1) - np.trace(Mi, axis1=1, axis2=2))])
        F = 0.5 * np.array([[np.sum(MS * np.swapaxes(MS, 1, 2)), np.sum(MS * np.swapaxes(Mi, 1, 2))],
                            [0.0, np.sum(Mi * np.swapaxes(Mi, 1, 2))]])
        F[1, 0] = F[0, 1]
        # a component at its bound whose score points past it stays there; a given k stays
        free = [factor is None and not (k <= 1.0 and g[0] < 0.0), not (s2 <= 0.0 and g[1] < 0.0)]
        step = np.zeros(2)
        idx = [j for j in range(2) if free[j]]
        if idx:
            step[idx] = np.linalg.solve(F[np.ix_(idx, idx)], g[idx])
        new_k = k if factor is not None else max(1.0, k + step[0])
        new_s2 = max(0.0, s2 + step[1])
        done = abs(new_k - k) <= 1e-9 * k and abs(new_s2 - s2) <= 1e-9 * max(s2, 1e-12)
        k, s2 = new_k, new_s2
        if done:
            break
    return k, s2


def _fits_factor(fits, used):
    """The factor k on the edges' covariances that the used axes' own fits read: their
    whitened residuals' chi2 over its degrees of freedom (each fit's 8 edge terms, less the
    5 of its axis and radius, plus the radius prior's leverage: `StereoAxis.dof`), the part
    that one error of the rig common to them all explains taken out first (its least squares
    over them, its rank taken from the dof). fits: (chi2 (N,), dof (N,), rig_information (N, 6, 6), rig_vector
    (N, 6)) of the axes (`StereoAxis`); used: (N,) bool.

    The residuals are the edges' noise alone: the port's play moves an axis, not its edges'
    fit, and the gate on the axes' offsets does not truncate them, so k is read without the
    play and without the gate's bias (the offsets alone read k = 3.3-3.4 for a true 4 on
    edge-level pivots, these 3.9-4.0). k below 1 is kept: the edges' covariances hold the
    detector's error floor (`shaft.axis.EDGE_FLOOR_PX`), which on clean edges is far above
    their scatter (rendered pivots: k 0.003-0.25, their axes' errors against the truth
    0.003-0.09 of their covariances, median), and covariances that large hide the port's
    play from the offsets (`_axes_with_noise`). At least 1 unless the fits pool `MIN_DOF`
    degrees of freedom or more and their chi2 lies below its lower 1 % point (the stated
    noise rejected); then at least `_MIN_FACTOR`.

    >>> fits = (np.array([8.0, 8.0]), np.array([4.0, 4.0]), np.zeros((2, 6, 6)), np.zeros((2, 6)))
    >>> _fits_factor(fits, np.array([True, True]))
    2.0
    """
    c2, dof, info, vec = fits
    v = np.sum(vec[used], 0)
    z, _, rank, _ = np.linalg.lstsq(np.sum(info[used], 0), v, rcond=1e-10)
    left = float(np.sum(dof[used])) - float(rank)
    c2_left = float(np.sum(c2[used]) - v @ z)
    k = c2_left / max(left, 1.0)
    # below 1 only where the fits reject the stated noise (their chi2 under its lower 1 %
    # point, at least `MIN_DOF` dof): a k a little below 1 by chance would read a play where
    # the axes meet
    if left < MIN_DOF or c2_left >= chi2_isf(GATE_CONFIDENCE, left):
        return max(1.0, k)
    return max(_MIN_FACTOR, k)


#: The mean chi-square (2 dof) of an axis the 99 % gate keeps: ``(2 - (c + 2) e^(-c/2)) / 0.99``
#: at its threshold c; the kept axes' chi-square sum is held to this per axis, less 3.
_KEPT_CHI2 = 1.907


def _axes_with_noise(P, D, C, E, robust, runs=MAX_RUNS, fits=None):
    """(Fulcrum3D, chart covariances (N, 4, 4) with the noise in them, play s2 [length^2],
    factor k) of the stereo axes: where the axes scatter about the point more than their
    covariances say, their covariances become ``k C + s2 I`` (on the position): k >= 1 a
    factor on their own (edges noisier than said), s2 an isotropic play (an instrument that
    does not pivot about one point exactly: the port's play). s2 starts from the median of
    every axis's chi2 (`_play`: a gate set for too small a noise keeps only the few axes that
    happen to pass close, and their scatter would say there is none; where it is 0 the axes
    keep their covariances), then k and s2 on the gate's inliers, the fit again with them,
    until they change by less than 10 % (at most `runs` runs). With the axes' own fits
    (fits: `_fits_factor`'s) k is what their residuals read and s2 alone is fitted to the
    offsets, by maximum likelihood, then raised until the inliers' chi2 is that of a gated
    sample (`_KEPT_CHI2` per axis, less 3: likelihood alone reads a truncated scatter too
    small); without them k and s2 both by maximum likelihood on the offsets
    (`_factor_and_play`), both scaled up to that chi2, only inflating, as the monocular
    point's variance factor (`fulcrum._point_with_noise`). Where the fits read k below 1
    (edges whose covariances hold the detector's error floor scatter far less than it
    says), k is theirs from the start (the play's first s2 read at ``k C``) and serves only
    to read the play, which at the stated covariances hid in them (rendered pivots:
    the play read 0 on 11 of 16, its true sd 0.35 mm; docs/method.md), and the axes keep
    their stated covariances plus the play, ``C + s2 I``."""
    lift = np.zeros((4, 4))
    lift[2, 2] = lift[3, 3] = 1.0
    try:
        fit = fulcrum_3d(P, D, C, robust, axis_frames=E)
    except EstimationError:
        # the gate at the stated covariances keeps fewer than two axes where they scatter far
        # beyond them (edges three times noisier than stated and the port's play: 4 in 40
        # pivots of 8 axes): the first point is then only the start of the play, so every axis
        # is taken, and the gate is applied once the noise is in the covariances
        fit = None
    x = np.asarray((fulcrum_3d(P, D, C, False, axis_frames=E) if fit is None else fit).point, float)
    k = 1.0
    if fits is not None:
        # the edges' noise as their own fits read it, before the play is read: covariances that
        # hold the detector's error floor (far above clean edges' scatter) would take the play in
        # (above 1 the factor is read on the gate's inliers below, as it was)
        k = min(1.0, _fits_factor(fits, np.ones(len(P), bool) if fit is None else np.asarray(fit.inliers, bool)))
    s2 = _play(P, D, k * C, E, x)
    if s2 == 0.0 and fit is not None:  # the axes' median meets its own: no scatter beyond them
        return fit, C, 0.0, 1.0  # (a k below 1 only reads the play: none here)
    fit = fulcrum_3d(P, D, k * C + s2 * lift, robust, axis_frames=E)
    for _ in range(runs):
        used = np.asarray(fit.inliers, bool)
        if 2 * used.sum() <= 3:
            break
        r, S, _ = axis_offsets(np.asarray(fit.point, float), P, D, E, C)
        k_new, s2_new = _factor_and_play(r[used], S[used], s2,
                                         factor=None if fits is None else _fits_factor(fits, used))
        done = abs(k_new - k) <= 0.1 * k and abs(s2_new - s2) <= 0.1 * max(s2, 1e-12)
        k, s2 = k_new, s2_new
        fit = fulcrum_3d(P, D, k * C + s2 * lift, robust, axis_frames=E)
        if done:
            break
    used = np.asarray(fit.inliers, bool)
    r, S, _ = axis_offsets(np.asarray(fit.point, float), P, D, E, C)
    target = max(_KEPT_CHI2 * used.sum() - 3.0, 1.0)

    def chi2(k, s2):
        return float(np.sum(offset_chi2(r[used], k * S[used] + s2 * np.eye(2))))
    c = max(1.0, chi2(k, s2) / target)
    if fits is None:
        k, s2 = k * c, s2 * c
    elif c > 1.0:  # k is the fits'; the play alone takes the rest (bisection: chi2 falls with s2)
        lo, hi = s2, s2 + float(np.max(np.sum(r[used] ** 2, -1))) + 1e-12
        for _ in range(60):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if chi2(k, mid) > target else (lo, mid)
        s2 = hi
    # below 1 the fits' factor only reads the play: the axes keep their stated covariances,
    # since the fits do not see an error that moves an axis's four edges together (a shaded
    # limb's bias: on the rendered pivots the axes' errors against the truth are 3-10 times
    # the variance their fits read)
    k = max(k, 1.0)
    fit = fulcrum_3d(P, D, k * C + s2 * lift, robust, axis_frames=E)
    return fit, k * C + s2 * lift, s2, k


def stereo_fulcrum_axes(axes, rig_cov=None, robust=True):
    """The fulcrum (`AxesFulcrum`, left camera frame) of stereo axes (`StereoAxis`, at least
    two), with the rig's covariance if given.

    The axes are gated and weighted as `cylinder.fulcrum_3d` does, each by its own
    covariance (at its own estimate), and where they scatter
    about the point more than their covariances say, their covariances take a factor and
    each axis's position an isotropic play variance, both fitted from that scatter
    (`_axes_with_noise`: only inflating, as the monocular 3-D fulcrum's variance factor;
    the factor is the one the axes' own fits' residuals read, `_fits_factor`). rig_cov: (6, 6) the rig's covariance (rotation vector
    [rad], translation [length]; ``R = exp(w) R0``, ``t = t0 + dt``) or None. The rig is one
    for every axis, so its error moves them all at once: with its covariance the point is
    solved together with that error, under its prior (`_with_rig`, the gate's axes, their
    covariances with the factor and the play, their fits' residuals with the factor), and
    its covariance is the point's marginal, the edges' noise and the rig's both in it.
    EstimationError (one line, saying so) where fewer than two axes meet near one point even
    with their scatter in their covariances.
    """
    if len(axes) < 2:
        raise EstimationError(f"the stereo fulcrum needs two axes, got {len(axes)}")
    P = np.stack([a.axis_point for a in axes])
    D = np.stack([a.axis_direction for a in axes])
    C = np.stack([a.axis_cov for a in axes])
    E = np.stack([a.axis_frame for a in axes])
    fits = (np.array([a.chi2 for a in axes], float), np.array([a.dof for a in axes], float),
            np.stack([a.rig_information for a in axes]), np.stack([a.rig_vector for a in axes]))
    try:
        # each axis weighed at its own estimate: evaluated at the lines through the point
        # instead, the point leant further towards the camera (docs/method.md)
        fit, C_noise, play, factor = _axes_with_noise(P, D, C, E, robust, fits=fits)
    except EstimationError as e:
        raise EstimationError(f"fewer than two of the {len(axes)} stereo axes meet near one "
                              f"point, even with their scatter taken into their covariances ({e})") from None
    C = C_noise
    if rig_cov is None:
        return AxesFulcrum(fit.point, fit.point_cov, float(fit.point_sigma), fit, False, play, factor)
    rig_cov = np.asarray(rig_cov, float)
    if rig_cov.shape != (6, 6) or not np.all(np.isfinite(rig_cov)):
        raise InputError(f"the rig's covariance must be a finite 6x6 matrix (rotation vector, translation), "
                         f"got shape {rig_cov.shape}")
    x, cov = _with_rig(np.asarray(fit.point, float), axes, np.asarray(fit.inliers, bool), rig_cov, C, factor=factor)
    return AxesFulcrum(x, cov, float(np.sqrt(np.trace(cov))), fit, True, play, factor)


def _frame_pairs(frames_left, frames_right):
    """Index pairs of the two eyes' lines.json frames by their image names
    (`camera.stereo.pair_frames`: by stem, in order only where the names say nothing)."""
    return pair_frames([f.get("image") for f in frames_left], [f.get("image") for f in frames_right])


def _measured(camera, frame):
    """[(edges (2, 4) [undistorted px], edge_cov (2, 2, 2))] of a frame's shafts that carry
    them, and the index of each in the frame's shafts."""
    out, index = [], []
    for k, sh in enumerate(frame.get("shafts") or []):
        if sh.get("edges") is None or sh.get("edge_cov") is None:
            continue
        e = np.asarray(camera.undistort_pixels(np.asarray(sh["edges"], float).reshape(-1, 2)), float).reshape(2, 4)
        if np.all(np.isfinite(e)):
            out.append((e, np.asarray(sh["edge_cov"], float).reshape(2, 2, 2)))
            index.append(k)
    return out, index


def stereo_axes_from_frames(camera_left, frames_left, camera_right, frames_right, rig, diameter=None, width_sd=0.0):
    """fulcrum.json's ``stereo.axes`` record: each frame's shafts matched between the eyes
    (`match_shafts`), their stereo axes (`stereo_axis`; with the diameter a prior on the
    radius, 1e-3 of it) and the fulcrum of those (`stereo_fulcrum_axes`, with the rig's
    covariance when the stereo file has one).

    camera_left, camera_right: each eye's `Camera`; frames_left, frames_right: lines.json
    frames whose shafts carry ``edges`` [raw px] and ``edge_cov`` (`pencilcal lines
    --shaft`), paired by image name or order; rig: the `camera.stereo.StereoRig`;
    diameter: the shafts' diameter in the rig's unit, or None (the radius from the
    baseline); width_sd: with the diameter, the relative sd of the band width's error that
    the sequence shares (`fulcrum.FulcrumPoint.width_sd`, the left view's): the radius's
    prior sets the axes' depth partly by the diameter (on an endoscope's 5 mm baseline
    almost wholly), and a width error reads every shaft that much wider or narrower at once,
    as a diameter off by it would; point_cov gains ``width_sd^2 s s^T`` (``point_cov_width``),
    s the point's derivative by the diameter's relative error (`_diameter_sensitivity`).
    Returns a dict: point, point_cov, point_sigma [rig unit], play_sigma (the
    sd [rig unit] per direction of the axes' offsets from one point beyond their
    covariances, in point_cov: `stereo_fulcrum_axes`), noise_factor (the factor on the axes'
    own covariances, in point_cov), rig_used, frames
    (paired), axes (matched), axes_used, outliers ([{"image", "left", "right"}]), radius
    and radius_sigma (the matched axes' weighted mean). EstimationError with fewer than two
    matched axes.
    """
    axes, owners, pairs = matched_axes(camera_left, frames_left, camera_right, frames_right, rig, diameter)
    owners = [{k: o[k] for k in ("image", "left", "right")} for o in owners]
    if len(axes) < 2:
        raise EstimationError(f"fewer than two shafts matched between the eyes ({len(axes)} in {pairs} frame "
                              "pairs): check the stereo file and that both views' shafts were measured")
    res = stereo_fulcrum_axes(axes, rig.cov)
    r = np.array([a.radius for a in axes])
    w = 1.0 / np.maximum(np.array([a.radius_sigma for a in axes]) ** 2, 1e-300)
    inl = np.asarray(res.fit.inliers, bool)
    x = np.asarray(res.point, float)
    width_cov = np.zeros((3, 3))
    if diameter is not None and width_sd > 0:
        sens = _diameter_sensitivity(axes, 0.5 * float(diameter), rig.cov, x)
        width_cov = float(width_sd) ** 2 * np.outer(sens, sens)
    cov = np.asarray(res.point_cov, float) + width_cov
    return {"point": x.tolist(), "point_cov": cov.tolist(), "point_sigma": float(np.sqrt(np.trace(cov))),
            "point_cov_width": width_cov.tolist(), "play_sigma": float(np.sqrt(res.play)),
            "noise_factor": float(res.factor),
            "rig_used": bool(res.rig_used), "frames": pairs,
            "axes": len(axes), "axes_used": int(inl.sum()),
            "outliers": [o for o, k in zip(owners, inl) if not k],
            "radius": float(np.sum(w * r) / np.sum(w)), "radius_sigma": float(np.sqrt(1.0 / np.sum(w)))}


def _diameter_sensitivity(axes, radius, rig_cov, point, step=1e-3):
    """(3,) [length] the axes' fulcrum's derivative by a relative error of the diameter their
    radius's prior holds (each axis fitted with it, `stereo_axis`): per axis the linearised
    fit moves its chart by ``cov[:4, 4] / sd^2`` per unit of the prior's radius (the
    posterior mean's response to a Gaussian prior's mean), every axis at once by `step` of
    the prior's radius [length]; the fulcrum of the moved axes (`stereo_fulcrum_axes`), less `point`, over
    `step`."""
    moved = []
    for a in axes:
        prior_sd = _RADIUS_PRIOR_REL * radius  # the prior `stereo_axis` gave it
        chart = np.asarray(a.cov, float)[:4, 4] / prior_sd**2 * (step * radius)
        P, D = _line_of(chart, a.axis_point, a.axis_direction, a.axis_frame)
        D = _canon(D)
        P = P - (P @ D) * D
        moved.append(dataclasses.replace(a, axis_point=P, axis_direction=D, axis_frame=axis_frame(P, D)))
    return (np.asarray(stereo_fulcrum_axes(moved, rig_cov).point, float) - np.asarray(point, float)) / step


def matched_axes(camera_left, frames_left, camera_right, frames_right, rig, diameter=None):
    """(axes, owners, frame pairs): every frame's shafts matched between the eyes
    (`match_shafts`) and their `StereoAxis` (left camera frame; with the diameter a prior on
    the radius, 1e-3 of it); owners: per axis {"image", "frame" (the left frame's index),
    "left", "right" (the matched shafts' indices among those with edges and edge_cov, as
    ``stereo.axes.outliers`` names them), "left_shaft" (its index in the left frame's
    shafts)}; frame pairs: how many. Arguments as
    `stereo_axes_from_frames`'s."""
    R, t = rig.R_right_from_left, rig.t_right_from_left
    Kl, Kr = np.asarray(camera_left.K, float), np.asarray(camera_right.K, float)
    prior = {} if diameter is None else {"radius": 0.5 * float(diameter)}
    axes, owners = [], []
    pairs = _frame_pairs(frames_left, frames_right)
    cands, ats = [], []
    for i, j in pairs:
        (left, at), (right, _) = _measured(camera_left, frames_left[i]), _measured(camera_right, frames_right[j])
        cands.append(_candidates(Kl, left, Kr, right, R, t, **prior))
        ats.append(at)
    # the gate at the edges' own noise (`match_factor`): at their stated covariances alone it
    # drops the true pairs of edges noisier than said (half of them at twice the sd)
    k = match_factor(cands)
    for (i, _), c, at in zip(pairs, cands, ats):
        for a, b, ax in _greedy(c, GATE_CONFIDENCE, k):
            axes.append(ax)
            owners.append({"image": frames_left[i].get("image"), "frame": i, "left": a, "right": b,
                           "left_shaft": at[a]})
    return axes, owners, len(pairs)


def axes_with_noise(points, directions, covs, frames, robust=True):
    """(Fulcrum3D, chart covariances (N, 4, 4) with the noise in them, play s2 [length^2],
    factor k) of 3-D axes with no fits of their own (one eye's: `fulcrum._point_with_noise`):
    points, directions (N, 3), covs (N, 4, 4), frames (N, 2, 3) as `cylinder.fulcrum_3d`
    takes them; k and s2 both by maximum likelihood on the gate's offsets, as
    `_axes_with_noise` without the fits."""
    return _axes_with_noise(points, directions, covs, frames, robust)
