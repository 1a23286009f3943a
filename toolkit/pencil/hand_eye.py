"""The camera-to-robot transform (hand-eye) and the remote centre of motion from a pivot
whose tool poses the robot reports.

Per frame the camera sees the shaft's 3-D axis (`cylinder.shaft_axis`, the diameter known)
and the robot's kinematics give the same axis in its base frame (the tool frame's z axis
through its origin, `io.tool_poses`). The rigid transform that carries the base frame's
lines onto the camera's is a registration of lines:

1. closed form: each set's directions oriented alike (towards their principal direction),
   the rotation by Kabsch (SVD) of the directions, the translation by least squares of the
   base lines' points onto the camera lines; both relative orientations are tried (a line
   has no sign);
2. Gauss-Newton over the rotation (a left perturbation) and the translation: per frame the
   base line, carried into the camera frame, in the 4 chart coordinates of the camera's
   axis (`cylinder.axis_chart`: two angles [rad], two offsets [mm]) weighted by that
   axis's covariance plus the kinematics' own (isotropic ``sigma_deg``, ``sigma_mm`` at
   the tool origin, carried along the line), with a chi2 gate (4 dof) on the frames;
3. the covariance of the transform, the inverse of the normal equations, raised by the fit's
   chi2 per degree of freedom where it is significantly above 1 (the axes' sigmas too
   small).

For a pure pivot every axis passes the fulcrum: the rotation comes from the directions and
the translation from the fulcrum itself, so the directions must spread
(`MIN_AXIS_SPREAD_DEG`) and three frames are the fewest (`MIN_FRAMES`). A fan in one plane
is symmetric under a half turn about the plane's normal through the fulcrum: the two
solutions fit alike, and the side of the fulcrum the tool origin (the tip) lies on against
the side of the band's end where the tool ends in the image decides between them.

The remote centre of motion in the base frame is the point nearest the base frame's axes
(`cylinder.fulcrum_3d`, weighted by the kinematics' sigmas, or by the scatter of the axes
about it where the file gives none); carried into the camera frame it is compared with the
camera's own fulcrum of the same axes, the difference's covariance holding that both come
from the same axes (first order: each estimate's gain on each axis).

Conventions: ``p_cam = R_cam_from_base p_base + t_cam_from_base`` (frames.py), lengths in mm
(the shaft diameter's unit), covariances of a transform of (w [rad], t [mm]) with
``R = exp(skew(w)) R_hat`` (as a stereo file's ``cov_right_from_left``).

Example
-------
>>> rng = np.random.default_rng(0)
>>> d = normalize(rng.normal(size=(6, 3)) * [0.3, 0.3, 0.1] + [0, 0, 1])
>>> F = np.array([10.0, -5, 100])
>>> R, t = rotation_from_rotvec([0.1, -0.2, 0.3]), np.array([5.0, 50, -20])
>>> cov = np.broadcast_to(np.diag([1e-6, 1e-6, 0.01, 0.01]), (6, 4, 4))
>>> base_d = d @ R                                   # R^T d: the axes in the base frame
>>> base_p = (F + 90 * d - t) @ R                    # the tool origins, 90 mm past F
>>> he = hand_eye_from_axes(F - 20 * d, d, cov, base_p, base_d)
>>> bool(np.allclose(he.R_cam_from_base, R)), np.round(he.t_cam_from_base, 9).tolist()
(True, [5.0, 50.0, -20.0])
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pencilcal.toolkit.errors import EstimationError, InputError
from pencilcal.toolkit.geometry.frames import (normalize, project_to_rotation, rotation_from_rotvec, rotvec_from_rotation,
                                              skew)
from pencilcal.toolkit.geometry.quantiles import chi2_isf, chi2_sf
from pencilcal.toolkit.pencil.cylinder import (GATE_CONFIDENCE, axis_chart, axis_frame, fulcrum_3d, shaft_axis_record,
                                               shared_difference_chi2)

__all__ = ["MIN_FRAMES", "MIN_AXIS_SPREAD_DEG", "HandEye", "RobotCalibration", "hand_eye_from_axes", "robot_fulcrum",
           "fulcrum_agreement", "invert_transform", "robot_from_frames"]

#: The fewest frames paired (an axis and a pose) for a hand-eye with a check (4 N - 6 dof).
MIN_FRAMES = 3
#: The least spread of the axes' directions [deg] (RMS about their mean): below it the
#: rotation about them is not fixed (all axes parallel).
MIN_AXIS_SPREAD_DEG = 1.0

_ROUNDS = 10            # most refits of the inlier set (stable after two or three)
_MAX_ITER = 30          # Gauss-Newton iterations
_STEP_ROT = 1e-7        # central-difference steps [rad], and [mm] per mm of |t|
_STEP_T = 1e-6
_MEDIAN_CHI2_4 = 3.3567  # median of chi2 with 4 dof: the robust scale of the gate


@dataclass(frozen=True, eq=False)
class HandEye:
    """The camera-to-robot transform from paired axes (`hand_eye_from_axes`); N frames.

    R_cam_from_base (3, 3), t_cam_from_base (3,) [mm]; cov (6, 6): of (w [rad], t [mm]),
    ``R = exp(skew(w)) R_hat``, inflated by `variance_factor`. chi2: (N,) each frame's
    normalised squared residual (4 dof, covariances not inflated); angle_deg (N,), offset
    (N,) [mm]: the base axis carried into the camera frame against the camera's, the angle
    between them and their distance at the camera axis's reference point; inliers: (N,)
    the frames used; dof: 4 n - 6; chi2_dof: their chi2 sum over dof; variance_factor: 1,
    or chi2_dof where that is significantly above 1 (99 %); twin_chi2: the chi2 sum of the
    best transform with the other relative orientation of the lines; twin_by: "fit" (its
    chi2 is far worse) or "sides" (a fan in one plane: decided by the side of the fulcrum
    the tool origins lie on); twin_vote: for "sides", the mean over the used frames of +1
    where the tool origin and the part of the shaft the camera sees lie on the same side of
    the fulcrum, -1 where not (1: all agree; near 0: the fulcrum is in view and the sides do
    not decide), else NaN; gain (N, 6, 4): the transform's first-order change per unit
    change of each camera axis's chart coordinates (`fulcrum_agreement`), zero for frames
    left out; kin_cov (N, 4, 4): the kinematics' covariance in each camera axis's chart.
    """

    R_cam_from_base: np.ndarray
    t_cam_from_base: np.ndarray
    cov: np.ndarray
    chi2: np.ndarray
    angle_deg: np.ndarray
    offset: np.ndarray
    inliers: np.ndarray
    dof: int
    chi2_dof: float
    variance_factor: float
    twin_chi2: float
    twin_by: str
    twin_vote: float
    gain: np.ndarray
    kin_cov: np.ndarray

    @property
    def rotation_sigma_deg(self) -> float:
        """RMS error of the rotation [deg]: sqrt of the trace of its 3x3 block."""
        return float(np.degrees(np.sqrt(np.trace(self.cov[:3, :3]))))

    @property
    def translation_sigma(self) -> float:
        """RMS error of the translation [mm]: sqrt of the trace of its 3x3 block."""
        return float(np.sqrt(np.trace(self.cov[3:, 3:])))


def invert_transform(R, t, cov):
    """(R_b_from_a, t_b_from_a, its 6x6 covariance) of ``p_a = R p_b + t`` with cov of
    (w, t), ``R = exp(skew(w)) R_hat``: the inverse's (w', t') = J (w, t) with
    ``w' = -R^T w``, ``t' = -R^T skew(t) w - R^T t``.

    >>> R, t, c = invert_transform(np.eye(3), np.array([1.0, 0, 0]), np.eye(6))
    >>> t.tolist(), np.round(np.diag(c), 9).tolist()
    ([-1.0, 0.0, 0.0], [1.0, 1.0, 1.0, 1.0, 2.0, 2.0])
    """
    R, t = np.asarray(R, float), np.asarray(t, float)
    J = np.zeros((6, 6))
    J[:3, :3] = -R.T
    J[3:, :3] = -R.T @ skew(t)
    J[3:, 3:] = -R.T
    return R.T, -R.T @ t, J @ np.asarray(cov, float) @ J.T


def _principal(d):
    """(N, 3) unit directions turned towards their principal direction (one hemisphere)."""
    m = np.linalg.eigh(np.einsum("ni,nj->ij", d, d))[1][:, -1]
    return d * np.where(d @ m < 0, -1.0, 1.0)[:, None]


def _spread_deg(d):
    """RMS angle [deg] of unoriented directions (N, 3) about their principal direction."""
    w = np.linalg.eigvalsh(np.einsum("ni,nj->ij", d, d) / len(d))
    return float(np.degrees(np.arcsin(np.sqrt(np.clip(w[0] + w[1], 0.0, 1.0)))))


def _translation(R, cam_p, cam_d, base_p, use):
    """t minimising the distances of R b + t from the camera lines (used frames)."""
    P = (np.eye(3) - cam_d[:, :, None] * cam_d[:, None, :])[use]
    r = (cam_p - base_p @ R.T)[use]
    H = P.sum(0)
    if np.linalg.cond(H) > 1e12:
        raise EstimationError("the axes do not fix the translation (fewer than two crossing axes)")
    return np.linalg.solve(H, np.einsum("nij,nj->i", P, r))


def _iso_cov(sig_a, sig_p):
    """(N, 4, 4) the chart covariance of lines with isotropic errors: angle sig_a (N,) [rad]
    in both angles, offset sig_p (N,) [mm] in both offsets."""
    K = np.zeros((len(sig_a), 4, 4))
    K[:, 0, 0] = K[:, 1, 1] = np.asarray(sig_a, float) ** 2
    K[:, 2, 2] = K[:, 3, 3] = np.asarray(sig_p, float) ** 2
    return K


def _kin_cov(R, t, cam_p, cam_d, frames, base_p, base_d, sig_a, sig_p):
    """(N, 4, 4) the kinematics' isotropic covariance (angle sig_a [rad], offset sig_p [mm]
    at the tool origin) in each camera axis's chart, and (N, 4, 4) M: the map from the base
    line's own chart (`cylinder.axis_frame` at the tool origin) to the camera's."""
    Eb = axis_frame(base_p, base_d)
    e = base_d @ R.T
    F = np.einsum("nki,ij,nlj->nkl", frames, R, Eb)                    # (N, 2, 2)
    sign = np.where(np.sum(e * cam_d, -1) < 0, -1.0, 1.0)[:, None, None]
    tau = np.sum(((cam_p - t) @ R - base_p) * base_d, -1)[:, None, None]
    M = np.zeros((len(cam_p), 4, 4))
    M[:, :2, :2] = sign * F
    M[:, 2:, :2] = tau * F
    M[:, 2:, 2:] = F
    K = _iso_cov(sig_a, sig_p)
    return M @ K @ np.swapaxes(M, -1, -2), M


def _charts(R, t, cam_p, cam_d, frames, base_p, base_d):
    """(..., N, 4) the base lines carried into the camera frame by R (..., 3, 3), t (..., 3)
    in the camera axes' charts."""
    R, t = np.asarray(R, float), np.asarray(t, float)[..., None, :]
    return axis_chart(np.einsum("...ij,nj->...ni", R, base_p) + t, np.einsum("...ij,nj->...ni", R, base_d),
                      cam_p, cam_d, frames)


def _jacobian(R, t, lines):
    """(N, 4, 6) d chart / d (w, t) by central differences (w a left perturbation)."""
    h = np.r_[np.full(3, _STEP_ROT), np.full(3, _STEP_T * (1.0 + float(np.linalg.norm(t))))]
    q = np.concatenate([np.diag(h), -np.diag(h)])                         # (12, 6)
    c = _charts(rotation_from_rotvec(q[:, :3]) @ R, t + q[:, 3:], *lines)  # (12, N, 4)
    return np.moveaxis((c[:6] - c[6:]) / (2.0 * h[:, None, None]), 0, -1)


def _gauss_newton(R, t, lines, Linv, use):
    """(R, t, A (N, 4, 6) the whitened Jacobian) minimising the used frames' whitened charts:
    Gauss-Newton, each step halved until the cost falls (a poor start, the wrong relative
    orientation, does not run away)."""

    def cost(R, t):
        r = np.einsum("nij,nj->ni", Linv, _charts(R, t, *lines))[use]
        return float(np.sum(r * r)), r

    c, r = cost(R, t)
    for _ in range(_MAX_ITER):
        A = np.einsum("nij,njk->nik", Linv, _jacobian(R, t, lines))
        step = -np.linalg.lstsq(A[use].reshape(-1, 6), r.reshape(-1), rcond=None)[0]
        for _ in range(20):
            R1, t1 = rotation_from_rotvec(step[:3]) @ R, t + step[3:]
            c1, r1 = cost(R1, t1)
            if c1 <= c:
                break
            step = 0.5 * step
        else:
            break
        done = c - c1 <= 1e-10 * (1.0 + c)
        R, t, c, r = R1, t1, c1, r1
        if done:
            break
    A = np.einsum("nij,njk->nik", Linv, _jacobian(R, t, lines))
    return R, t, A


def _fit(R, t, lines, cam_cov, kin, confidence):
    """(R, t, chi2 (N,), inliers, A, Linv, kin_cov) of the robust weighted fit from (R, t)."""
    n = len(cam_cov)
    use = np.ones(n, bool)
    gate = chi2_isf(1.0 - confidence, 4)
    for k in range(_ROUNDS):
        K, _ = _kin_cov(R, t, *lines, *kin)
        Linv = np.linalg.inv(np.linalg.cholesky(cam_cov + K))
        R, t, A = _gauss_newton(R, t, lines, Linv, use)
        K, _ = _kin_cov(R, t, *lines, *kin)
        Linv = np.linalg.inv(np.linalg.cholesky(cam_cov + K))
        r = np.einsum("nij,nj->ni", Linv, _charts(R, t, *lines))
        c2 = np.sum(r * r, -1)
        # gated on the chi2 over its robust scale: axes whose sigmas are all too small alike
        # keep their frames; a frame far off the others' scatter goes
        scale = max(1.0, float(np.median(c2[use])) / _MEDIAN_CHI2_4)
        gated = c2 / scale < gate
        if gated.sum() < MIN_FRAMES:
            raise EstimationError(f"the hand-eye: fewer than {MIN_FRAMES} frames pass the chi2 gate "
                                  f"({int(gated.sum())} of {n})")
        if np.array_equal(gated, use) or k == _ROUNDS - 1:
            break
        use = gated
    return R, t, c2, use, A, Linv, K


def _side_vote(R, t, cam_p, cam_d, cam_sides, base_p, use):
    """Mean sign, over the used frames, of the tool origin (carried into the camera frame)
    and the camera's side point lying on the same side of the fulcrum along each axis."""
    F = fulcrum_3d(cam_p[use], cam_d[use], np.broadcast_to(np.diag([0.0, 0.0, 1.0, 1.0]), (int(use.sum()), 4, 4)),
                   robust=False).point
    tool = base_p @ R.T + t
    a = np.sum((cam_sides - F) * cam_d, -1)
    b = np.sum((tool - F) * cam_d, -1)
    return float(np.mean(np.sign(a * b)[use]))


def _check_axes(cam_p, cam_d, cam_cov, base_p, base_d):
    n = len(cam_p)
    if not (cam_d.shape == base_d.shape == cam_p.shape == base_p.shape == (n, 3) and cam_cov.shape == (n, 4, 4)):
        raise InputError("hand_eye_from_axes: points and directions must be (N, 3), covariances (N, 4, 4)")
    if n < MIN_FRAMES:
        raise EstimationError(f"the hand-eye needs {MIN_FRAMES} frames at least with both a shaft axis and a tool "
                              f"pose, got {n}")
    for name, d in (("camera", cam_d), ("robot", base_d)):
        s = _spread_deg(d)
        if s < MIN_AXIS_SPREAD_DEG:
            raise EstimationError(f"the hand-eye: the {name}'s axes are all parallel (spread {s:.2g} deg, under "
                                  f"{MIN_AXIS_SPREAD_DEG:g}): the rotation about them is not fixed; pivot the tool")


def hand_eye_from_axes(cam_points, cam_directions, cam_covs, base_points, base_directions, *, sigma_deg=0.0,
                       sigma_mm=0.0, cam_sides=None, confidence=GATE_CONFIDENCE):
    """The transform carrying the robot base frame onto the camera frame from N paired axes.

    cam_points: (N, 3) [mm] each camera axis's chart reference (its point closest to the
        camera centre, `cylinder.ShaftAxis.axis_point`); cam_directions: (N, 3);
        cam_covs: (N, 4, 4) their chart covariances (`cylinder.ShaftAxis.axis_cov`).
    base_points: (N, 3) [mm] the tool origins in the base frame; base_directions: (N, 3) the
        shaft's axis there (either sign: lines).
    sigma_deg, sigma_mm: scalars or (N,): the kinematics' isotropic error of each axis,
        angle [deg] and offset [mm] at the tool origin (0: exact).
    cam_sides: (N, 3) a point of each camera axis on the tip's side of the fulcrum
        (`robot_from_frames`: where the band ends in the image, away from its border), for
        the twin of a fan in one plane (module docstring); default cam_points.
    confidence: of the chi2 gate on the frames (4 dof).

    Returns a `HandEye`. EstimationError with fewer than `MIN_FRAMES` frames, axes all
    parallel (`MIN_AXIS_SPREAD_DEG`), or too few frames through the gate.
    """
    cam_p, cam_d = np.asarray(cam_points, float), normalize(cam_directions)
    base_p, base_d = np.asarray(base_points, float), normalize(base_directions)
    cam_cov = np.asarray(cam_covs, float)
    _check_axes(cam_p, cam_d, cam_cov, base_p, base_d)
    n = len(cam_p)
    kin = (np.broadcast_to(np.radians(np.asarray(sigma_deg, float)), (n,)),
           np.broadcast_to(np.asarray(sigma_mm, float), (n,)))
    sides = cam_p if cam_sides is None else np.asarray(cam_sides, float)
    lines = (cam_p, cam_d, axis_frame(cam_p, cam_d), base_p, base_d)
    fits = []
    for s in (1.0, -1.0):
        # Kabsch: the rotation minimising sum |cam - R base|^2 is the one nearest sum cam base^T
        R0 = project_to_rotation((s * _principal(cam_d)).T @ _principal(base_d))
        t0 = _translation(R0, cam_p, cam_d, base_p, np.ones(n, bool))
        try:
            fits.append(_fit(R0, t0, lines, cam_cov, kin, confidence))
        except EstimationError as e:
            fits.append(e)
    if all(isinstance(f, EstimationError) for f in fits):
        raise fits[0]
    cost = [np.inf if isinstance(f, EstimationError) else float(np.sum(f[2][f[3]])) for f in fits]
    order = np.argsort(cost)
    twin_by, vote = "fit", float("nan")
    if cost[order[1]] - cost[order[0]] < chi2_isf(1.0 - confidence, 3):
        votes = [-np.inf if isinstance(f, EstimationError) else _side_vote(f[0], f[1], cam_p, cam_d, sides, base_p,
                                                                             f[3]) for f in fits]
        order = np.argsort([-v for v in votes])
        twin_by, vote = "sides", float(votes[order[0]])
    R, t, c2, use, A, Linv, K = fits[order[0]]
    dof = 4 * int(use.sum()) - 6
    chi2_dof = float(np.sum(c2[use]) / dof) if dof > 0 else float("nan")
    factor = 1.0
    if dof > 0 and np.sum(c2[use]) > chi2_isf(1.0 - confidence, dof):
        factor = chi2_dof
    Au = np.where(use[:, None, None], A, 0.0)
    N_inv = np.linalg.inv(np.einsum("nki,nkj->ij", Au, Au))
    gain = np.einsum("ij,nkj,nkl->nil", N_inv, Au, Linv)          # (N, 6, 4)
    mapped = base_d @ R.T
    charts = _charts(R, t, *lines)
    return HandEye(R_cam_from_base=R, t_cam_from_base=t, cov=N_inv * factor, chi2=c2,
                   angle_deg=np.degrees(np.arctan2(np.linalg.norm(np.cross(mapped, cam_d), axis=-1),
                                                    np.abs(np.sum(mapped * cam_d, -1)))),
                   offset=np.linalg.norm(charts[:, 2:], axis=-1), inliers=use, dof=dof, chi2_dof=chi2_dof,
                   variance_factor=factor, twin_chi2=cost[order[1]], twin_by=twin_by, twin_vote=vote, gain=gain,
                   kin_cov=K)


def robot_fulcrum(base_points, base_directions, sigma_deg=0.0, sigma_mm=0.0):
    """The remote centre of motion: the point nearest the base frame's axes, and its covariance.

    base_points: (N, 3) [mm] the tool origins; base_directions: (N, 3); sigma_deg,
    sigma_mm: scalars or (N,) the kinematics' isotropic error of each axis (angle [deg],
    offset at the tool origin [mm]). With sigma_mm > 0 the axes are weighted by them
    (`cylinder.fulcrum_3d`, no outlier search); with both 0 the axes are taken alike and
    the covariance is scaled by their scatter about the point (the squared distances' sum
    over 2 N - 3).

    Returns (point (3,), cov (3, 3), distances (N,) [mm], ``"sigmas"`` or ``"scatter"``).

    >>> d = normalize([[1.0, 0, 1], [-1, 0, 1], [0, 1, 1]])
    >>> p, c, dist, how = robot_fulcrum([5.0, 0, 0] + 10 * d, d)
    >>> (np.round(p, 9) + 0.0).tolist(), how
    ([5.0, 0.0, 0.0], 'scatter')
    """
    P, D = np.asarray(base_points, float), normalize(base_directions)
    n = len(P)
    sa = np.broadcast_to(np.radians(np.asarray(sigma_deg, float)), (n,))
    sp = np.broadcast_to(np.asarray(sigma_mm, float), (n,))
    weighted = bool(np.all(sp > 0))
    covs = _iso_cov(sa, sp) if weighted else _iso_cov(np.zeros(n), np.ones(n))
    fit = fulcrum_3d(P, D, covs, robust=False)
    cov = np.asarray(fit.point_cov, float)
    if not weighted:
        cov = cov * float(np.sum(fit.distances ** 2)) / max(2 * n - 3, 1)
    return np.asarray(fit.point, float), cov, np.asarray(fit.distances, float), "sigmas" if weighted else "scatter"


def _point_gain(F, points, dirs, covs):
    """(N, 3, 4) the first-order change of the weighted point nearest the lines (F, as
    `cylinder.fulcrum_3d` fits it) per unit change of each line's chart coordinates, and its
    covariance (3, 3)."""
    E = axis_frame(points, dirs)
    t = np.sum((F - points) * dirs, -1)
    G = np.concatenate([t[:, None, None] * np.eye(2), np.broadcast_to(np.eye(2), (len(t), 2, 2))], -1)
    W = np.linalg.inv(G @ covs @ np.swapaxes(G, -1, -2))
    H = np.einsum("nki,nkl,nlj->ij", E, W, E)
    Hinv = np.linalg.inv(H)
    return np.einsum("ij,nkj,nkl,nlm->nim", Hinv, E, W, G), Hinv


def fulcrum_agreement(he, cam_points, cam_directions, cam_covs, base_points, base_directions, robot,
                      sigma_deg=0.0, sigma_mm=0.0, confidence=GATE_CONFIDENCE):
    """The camera's fulcrum of the paired axes against the robot's carried into the camera frame.

    he: the `HandEye`; the axes as `hand_eye_from_axes` took them; robot: (point, cov, ...)
    of `robot_fulcrum` (base frame). The camera's fulcrum is the weighted point nearest the
    frames' camera axes the hand-eye used (`cylinder.fulcrum_3d`, covariances times the
    hand-eye's variance factor). Both are, to first order, linear in the same axes' errors
    (the gains of each estimate); the difference's covariance sums, per axis, (camera gain -
    transform gain) C (.)^T, the kinematics' term where they have sigmas, and otherwise the
    robot fulcrum's own covariance. Its components under `cylinder.SHARED_FLOOR` of the
    variance they would have for independent estimates are the same in both (for a pivot
    the translation is fixed by the fulcrum: mostly two of three) and are left out of the
    test, whose dof counts the others. Returns a dict: camera_point, camera_cov,
    robot_point_cam (the robot's carried over), robot_cov_cam, difference [mm], distance,
    difference_cov, chi2, dof, p_value, consistent (chi2 within its `confidence` quantile).
    """
    use = np.asarray(he.inliers)
    cp, cd = np.asarray(cam_points, float)[use], normalize(cam_directions)[use]
    cc = np.asarray(cam_covs, float)[use] * he.variance_factor
    fit = fulcrum_3d(cp, cd, cc, robust=False)
    F = np.asarray(fit.point, float)
    B, F_cov = _point_gain(F, cp, cd, cc)
    R, t = he.R_cam_from_base, he.t_cam_from_base
    Fb, Fb_cov = np.asarray(robot[0], float), np.asarray(robot[1], float)
    Fr = R @ Fb + t
    D = np.concatenate([-skew(R @ Fb), np.eye(3)], -1)                  # d Fr / d (w, t)
    Q = he.gain[use]
    X = B - np.einsum("ij,njk->nik", D, Q)
    cov = np.einsum("nij,njk,nlk->il", X, cc, X)
    n = len(use)
    sa = np.radians(np.broadcast_to(np.asarray(sigma_deg, float), (n,)))[use]
    sp = np.broadcast_to(np.asarray(sigma_mm, float), (n,))[use]
    if robot[3] == "sigmas":
        # the kinematics' errors move both the transform (through the frames' residuals)
        # and the robot's fulcrum: one term, per axis, of their joint gain
        bp, bd = np.asarray(base_points, float)[use], normalize(base_directions)[use]
        _, M = _kin_cov(R, t, cp, cd, axis_frame(cp, cd), bp, bd, sa, sp)
        Kb = _iso_cov(sa, sp)
        Bb, _ = _point_gain(Fb, bp, bd, Kb)
        Y = np.einsum("ij,njk,nkl->nil", D, Q, M) - np.einsum("ij,njk->nik", R, Bb)
        cov = cov + np.einsum("nij,njk,nlk->il", Y, Kb, Y)
    else:
        cov = cov + R @ Fb_cov @ R.T
    diff = F - Fr
    robot_cov = D @ he.cov @ D.T + R @ Fb_cov @ R.T
    # the components the shared axes make the same in both (for a pivot the transform's
    # translation is fixed by the fulcrum itself) are left out of the test
    c2, dof = shared_difference_chi2(diff, cov, F_cov + robot_cov)
    c2, dof = float(c2), int(dof)
    thr = chi2_isf(1.0 - confidence, dof) if dof else 0.0
    return {"camera_point": F.tolist(), "camera_cov": F_cov.tolist(), "robot_point_cam": Fr.tolist(),
            "robot_cov_cam": robot_cov.tolist(), "difference": diff.tolist(), "distance": float(np.linalg.norm(diff)),
            "difference_cov": cov.tolist(), "chi2": c2, "dof": dof,
            "p_value": float(chi2_sf(c2, dof)) if dof else 1.0,
            "consistent": bool(c2 <= thr)}


@dataclass(frozen=True, eq=False)
class RobotCalibration:
    """A pivot's hand-eye and remote centre of motion (`robot_from_frames`).

    hand_eye: the `HandEye`; robot: `robot_fulcrum`'s (point, cov, distances, how) over the
    frames the hand-eye used (base frame); agreement: `fulcrum_agreement`'s dict; images:
    (N,) the frames paired (an axis and a pose); rows: (N,) their kinematics file lines;
    source: the kinematics file; tool_axis: (3,) the shaft's axis in the tool frame;
    unpaired: frames with a pose but no shaft axis; no_pose: frames with an axis-bearing
    shaft but no pose; lens_cov: (6, 6) the intrinsics' term of the transform's covariance
    (`robot_from_frames`), or None.
    """

    hand_eye: HandEye
    robot: tuple
    agreement: dict
    images: list
    rows: list
    source: str
    tool_axis: np.ndarray
    unpaired: int
    no_pose: int
    lens_cov: np.ndarray | None = None

    def to_dict(self) -> dict:
        """fulcrum.json's ``robot`` record (docs/formats.md)."""
        he = self.hand_eye
        R_b, t_b, cov_b = invert_transform(he.R_cam_from_base, he.t_cam_from_base, he.cov)
        point, cov, dist, how = self.robot
        used = np.asarray(he.inliers)
        return {
            "kinematics": self.source, "tool_axis": np.asarray(self.tool_axis, float).tolist(),
            "frames_paired": len(self.images), "frames_used": int(used.sum()),
            "frames_without_axis": self.unpaired, "frames_without_pose": self.no_pose,
            "R_cam_from_base": he.R_cam_from_base.tolist(), "t_cam_from_base_mm": he.t_cam_from_base.tolist(),
            "cov_cam_from_base": he.cov.tolist(),
            "R_base_from_cam": R_b.tolist(), "t_base_from_cam_mm": t_b.tolist(), "cov_base_from_cam": cov_b.tolist(),
            "rotation_sigma_deg": he.rotation_sigma_deg, "translation_sigma_mm": he.translation_sigma,
            "chi2": float(np.sum(he.chi2[used])), "dof": he.dof, "chi2_dof": he.chi2_dof,
            "variance_factor": he.variance_factor, "twin_chi2": he.twin_chi2, "twin_by": he.twin_by,
            "twin_vote": None if np.isnan(he.twin_vote) else he.twin_vote,
            "residuals": [{"image": im, "line": int(r), "chi2": float(c), "angle_deg": float(a), "offset_mm": float(o),
                           "used": bool(u)}
                          for im, r, c, a, o, u in zip(self.images, self.rows, he.chi2, he.angle_deg, he.offset, used)],
            "fulcrum_base_mm": point.tolist(), "fulcrum_base_cov_mm2": cov.tolist(),
            "fulcrum_base_sigma_mm": float(np.sqrt(np.trace(cov))), "fulcrum_base_cov_from": how,
            "fulcrum_base_rms_distance_mm": float(np.sqrt(np.mean(dist ** 2))),
            "agreement": self.agreement,
            **self._totals(),
        }

    def _totals(self):
        """cov_cam_from_base_total (the intrinsics' term added), its sigmas, intrinsics_used."""
        if self.lens_cov is None:
            return {"intrinsics_used": False}
        total = self.hand_eye.cov + self.lens_cov
        return {"intrinsics_used": True, "cov_cam_from_base_total": total.tolist(),
                "rotation_sigma_total_deg": float(np.degrees(np.sqrt(np.trace(total[:3, :3])))),
                "translation_sigma_total_mm": float(np.sqrt(np.trace(total[3:, 3:])))}


def _side_point(camera, edges_raw, point, direction):
    """The point of an axis nearest the viewing ray through the band's end farther from the
    image border (the tip's end: the band enters across the border or from the port, and
    ends where the tool does), or None when the lens model cannot undistort the edges."""
    e = np.asarray(edges_raw, float).reshape(2, 2, 2)
    if np.sum((e[0, 0] - e[1, 0]) ** 2) > np.sum((e[0, 0] - e[1, 1]) ** 2):
        e[1] = e[1, ::-1]                                            # pair each end of one edge with the other's
    ends = 0.5 * (e[0] + e[1])                                       # (2, 2) the band's two ends [raw px]
    border = np.minimum.reduce([ends[:, 0], ends[:, 1], camera.width - 1 - ends[:, 0], camera.height - 1 - ends[:, 1]])
    end = ends[int(np.argmax(border))]
    ideal = np.asarray(camera.undistort_pixels(end[None]), float).reshape(2)
    if not np.all(np.isfinite(ideal)):
        return None
    ray = normalize(np.linalg.solve(np.asarray(camera.K, float), [ideal[0], ideal[1], 1.0]))
    d = normalize(direction)
    b = float(ray @ d)
    den = 1.0 - b * b
    if den < 1e-12:
        return None
    s = (float(ray @ point) - b * float(d @ point)) / den        # along the ray
    return point + d * (b * s - float(d @ point))


def _mono_candidates(camera, frames, diameter):
    """{frame index: [(axis record, raw edges, edge_cov)]}: each frame's shafts' 3-D axes from
    one view (`cylinder.shaft_axis_record`)."""
    out = {}
    for i, fr in enumerate(frames):
        for sh in (fr.get("shafts") or []) if fr.get("ok", True) else []:
            if sh.get("edges") is None or sh.get("edge_cov") is None:
                continue
            try:
                out.setdefault(i, []).append((shaft_axis_record(camera, sh["edges"], sh["edge_cov"], diameter),
                                              sh["edges"], sh["edge_cov"]))
            except (EstimationError, InputError):
                continue
    return out


def _stereo_candidates(camera, frames, stereo, diameter):
    """{frame index: [(axis record, left raw edges, None)]}: each frame's shafts matched
    between the eyes, their axes from both (`stereo_axes.matched_axes`; left camera frame;
    no edge_cov: the lens term is for one view)."""
    from pencilcal.toolkit.pencil.stereo_axes import matched_axes

    camera_right, frames_right, rig = stereo
    axes, owners, _ = matched_axes(camera, frames, camera_right, frames_right, rig, diameter)
    out = {}
    for ax, o in zip(axes, owners):
        rec = {"axis_point": ax.axis_point, "axis_direction": ax.axis_direction, "axis_cov": ax.axis_cov}
        out.setdefault(o["frame"], []).append((rec, frames[o["frame"]]["shafts"][o["left_shaft"]]["edges"], None))
    return out


def _frame_axes(camera, frames, index, candidates, near):
    """Per paired frame (image, axis record, side point, its pose row, (edges, edge_cov)): of the frame's
    candidate axes the one that passes nearest `near` (the camera's fulcrum, or None: the
    first), and the count of frames with a pose and no such axis."""
    out, missing = [], 0
    for i, (fr, k) in enumerate(zip(frames, index)):
        if k < 0:
            continue
        best = None
        for ax, edges, edge_cov in candidates.get(i, ()):
            p, d = np.asarray(ax["axis_point"], float), np.asarray(ax["axis_direction"], float)
            dist = 0.0 if near is None else float(np.linalg.norm(np.cross(np.asarray(near) - p, d)))
            if best is None or dist < best[0]:
                best = (dist, ax, edges, edge_cov)
        side = None if best is None else _side_point(camera, best[2], np.asarray(best[1]["axis_point"], float),
                                                      np.asarray(best[1]["axis_direction"], float))
        if best is None or side is None:
            missing += 1
            continue
        out.append((fr.get("image"), best[1], side, int(k), (best[2], best[3])))
    return out, missing


def _lens_cov(camera, C, he, measured, diameter, base_p, base_d, kin):
    """(6, 6) the intrinsics' term of the transform's covariance, or None: every intrinsic
    parameter with a variance stepped by 1e-3 of its sigma either way
    (`lens_uncertainty.perturbed_cameras`), each used frame's axis found again through the
    stepped lens and the transform refitted to them from the estimate with the same
    weights and frames; the central differences G (6, P) give ``G C G^T``. One lens for
    every frame: its error moves all the axes together, so this term does not shrink with
    more frames. measured: per paired frame (edges [raw px], edge_cov)."""
    from pencilcal.toolkit.camera.intrinsics import propagate
    from pencilcal.toolkit.pencil.lens_uncertainty import intrinsics_steps, perturbed_cameras

    steps = intrinsics_steps(C)
    use = np.asarray(he.inliers)
    if not steps:
        return None

    def transform(cam):
        axes = [shaft_axis_record(cam, e, c, diameter) for e, c in measured]
        cp = np.array([a["axis_point"] for a in axes], float)
        cd = normalize(np.array([a["axis_direction"] for a in axes], float))
        cc = np.array([a["axis_cov"] for a in axes], float)
        lines = (cp, cd, axis_frame(cp, cd), base_p, base_d)
        K, _ = _kin_cov(he.R_cam_from_base, he.t_cam_from_base, *lines, *kin)
        Linv = np.linalg.inv(np.linalg.cholesky(cc + K))
        return _gauss_newton(he.R_cam_from_base, he.t_cam_from_base, lines, Linv, use)[:2]

    G = np.zeros((6, C.shape[0]))
    try:
        for j, h, plus, minus in perturbed_cameras(camera, steps):
            (Rp, tp), (Rm, tm) = transform(plus), transform(minus)
            G[:3, j] = rotvec_from_rotation(Rp @ Rm.T) / (2.0 * h)
            G[3:, j] = (tp - tm) / (2.0 * h)
    except (EstimationError, InputError, np.linalg.LinAlgError):
        return None
    return propagate(G, C)


def robot_from_frames(camera, frames, poses, diameter, *, tool_axis=(0.0, 0.0, 1.0), near=None, first=0,
                      stereo=None, intrinsics_cov="camera", confidence=GATE_CONFIDENCE):
    """The hand-eye and the remote centre of motion of a pivot with the robot's tool poses.

    camera: the `Camera` of the frames; frames: lines.json frames whose shafts carry
    ``edges`` and ``edge_cov`` (`pencilcal lines --shaft`); poses: `io.tool_poses.ToolPoses`
    (matched by image name or frame index); diameter: the shaft's [mm]; tool_axis: the
    shaft's axis in the tool frame (default z); near: (3,) the camera's 3-D fulcrum, to
    choose the shaft of a frame with several (the one whose axis passes nearest), or None;
    first: the sequence index of frames[0] (a pivot epoch's frames, for a file of frame
    indices); stereo: (camera_right, frames_right, `camera.stereo.StereoRig`) or None: then
    the axes are triangulated from both eyes' silhouettes (`stereo_axes.matched_axes`, the
    diameter a prior on the radius; the rig's error is not in their covariance), in the left
    camera frame; intrinsics_cov: as `fulcrum.fulcrum_from_frames` ("camera": the camera
    file's, if it carries one): then, for one view, also the transform's intrinsics term
    (`RobotCalibration.lens_cov`).

    Per paired frame the shaft's 3-D axis (`cylinder.shaft_axis_record`) and the pose's axis
    go to `hand_eye_from_axes`, the used frames' tool axes to `robot_fulcrum`, and both
    fulcrums to `fulcrum_agreement`. Returns a `RobotCalibration`; EstimationError (naming
    the kinematics file) when the frames do not fix them.
    """
    index = poses.index([f.get("image") for f in frames], first)
    if not np.any(index >= 0):
        raise EstimationError(f"{poses.source}: no frame has a tool pose (images named as in the frames, or frame "
                              "indices from 0)")
    candidates = (_mono_candidates(camera, frames, diameter) if stereo is None
                  else _stereo_candidates(camera, frames, stereo, diameter))
    paired, missing = _frame_axes(camera, frames, index, candidates, near)
    no_pose = sum(1 for f, k in zip(frames, index) if k < 0 and f.get("shafts"))
    rows = np.array([p[3] for p in paired], int)
    base_p, base_d = poses.axes(tool_axis)
    base_p, base_d = base_p[rows] if len(rows) else base_p[:0], base_d[rows] if len(rows) else base_d[:0]
    sd, sm = poses.sigma_deg[rows] if len(rows) else 0.0, poses.sigma_mm[rows] if len(rows) else 0.0
    cam = [np.array([a[k] for _, a, *_ in paired], float).reshape(-1, *s)
           for k, s in (("axis_point", (3,)), ("axis_direction", (3,)), ("axis_cov", (4, 4)))]
    sides = np.array([s for _, _, s, *_ in paired], float).reshape(-1, 3)
    try:
        he = hand_eye_from_axes(*cam, base_p, base_d, sigma_deg=sd, sigma_mm=sm, cam_sides=sides,
                                confidence=confidence)
        use = np.asarray(he.inliers)
        robot = robot_fulcrum(base_p[use], base_d[use], np.asarray(sd)[use] if np.ndim(sd) else sd,
                              np.asarray(sm)[use] if np.ndim(sm) else sm)
        agreement = fulcrum_agreement(he, *cam, base_p, base_d, robot, sd, sm, confidence)
    except EstimationError as e:
        raise EstimationError(f"{poses.source}: {e}") from None
    from pencilcal.toolkit.pencil.lens_uncertainty import resolve_intrinsics_cov

    C = resolve_intrinsics_cov(camera, intrinsics_cov)
    lens = None
    if C is not None and stereo is None:
        kin = (np.broadcast_to(np.radians(np.asarray(sd, float)), (len(rows),)),
               np.broadcast_to(np.asarray(sm, float), (len(rows),)))
        lens = _lens_cov(camera, C, he, [p[4] for p in paired], diameter, base_p, base_d, kin)
    return RobotCalibration(hand_eye=he, robot=robot, agreement=agreement, images=[im for im, *_ in paired],
                            rows=[int(poses.rows[k]) for k in rows], source=poses.source,
                            tool_axis=normalize(tool_axis), unpaired=missing, no_pose=no_pose, lens_cov=lens)
