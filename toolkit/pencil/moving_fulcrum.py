"""The 3-D fulcrum seen by a camera that moves: every frame's shaft axis carried into one
reference camera by the frame's pose, the translations' scale fitted with the point.

A shaft's 3-D axis (`cylinder.shaft_axis_record`) lives in the camera of its own frame.
Where the camera moves, each frame's pose from the reference frame's camera is measured on
the background (`detect.background_pose`): R_k = R_frame_from_ref and a translation
``lambda t_k`` (t_k = t_frame_from_ref) whose direction and relative size are known but
whose unit is not (monocular motion has no scale): ``lambda`` is the length [mm, the
diameter's unit] of one map unit. A frame's point X goes to ``R_k^T (X - lambda t_k)`` in
the reference camera; with ``c_k = -R_k^T t_k`` (the frame's centre there, map units) the
shafts' metric depths fix lambda: every carried axis, through ``R_k^T A_k + lambda c_k``
along ``R_k^T d_k``, passes through the fulcrum F, so

    minimise over (F, lambda)   sum_k r_k^T S_k^-1 r_k,   r_k = E_k (F - R_k^T A_k - lambda c_k),

with E_k the carried axis's chart rows and S_k its perpendicular covariance at F (as
`cylinder.fulcrum_3d`), from the axis's own chart covariance and the pose's, both carried
to the new chart to first order (`carry_axes`: central differences of the exact chart,
`cylinder.axis_chart`). The solution alternates `cylinder.fulcrum_3d` at a fixed lambda
(its robust start and chi2 gate choose the axes) with Gauss-Newton steps of (F, lambda)
on the axes it keeps; the point's covariance is the (F, F) block of the inverse of the
4 x 4 normal matrix: lambda's uncertainty is in it, multiplied by the used axes' chi2 per
degree of freedom (2 an axis, less 4) where that is above 1: the a-posteriori variance
factor the image lines' fulcrum takes (`sequence_noise`), only ever inflating, as for the
detector's sigmas. On the phantom's frames 1-14 the used axes scatter 1.5-1.6 times (in
variance) what their covariances say, and each one left out is 3.2 in chi2(2) on average
off the fit of the others (none beyond chi2(2)'s 99 %): the edges' and the poses'
covariances are too small together, and no single axis is an outlier. lambda is fixed
only where the translations differ between frames in a way the axes see; with no
translation (a turning camera) it is not fitted and the axes are only turned.

>>> import numpy as np
>>> d = np.array([[1.0, 0, 0], [0, 1, 0], [0.6, 0, 0.8]])
>>> A = np.array([0.0, 0, 100]) - 20 * d                  # three axes through (0, 0, 100)
>>> C = np.broadcast_to(np.diag([1e-6, 1e-6, 0.01, 0.01]), (3, 4, 4))
>>> c = np.array([[0.0, 0, 1], [1, 0, 0], [0, 0, -1]])      # the frames' centres at 5 c: seen from there
>>> R = np.broadcast_to(np.eye(3), (3, 3, 3))
>>> fit = fulcrum_moving(A - 5 * c, d, C, R, -c, np.zeros((3, 6, 6)))   # t_frame_from_ref = -c
>>> np.round(fit.fit.point, 6).tolist(), round(float(fit.scale), 6)
([0.0, 0.0, 100.0], 5.0)
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from pencilcal.toolkit.errors import EstimationError
from pencilcal.toolkit.geometry.frames import normalize, rotation_from_rotvec
from pencilcal.toolkit.pencil.cylinder import Fulcrum3D, axis_chart, axis_frame, fulcrum_3d
from pencilcal.toolkit.pencil.sequence_noise import inflation

__all__ = ["MovingFulcrum", "carry_axes", "fulcrum_moving"]

#: Central differences' steps: chart angles and rotation [rad], chart offsets and the
#: translation (relative to the axis distance, the map unit's size).
_STEP = 1e-6
#: Alternations of the gate and the (F, lambda) steps at most, and their tolerance on lambda.
_ROUNDS, _TOL = 30, 1e-10


@dataclass(frozen=True, eq=False)
class MovingFulcrum:
    """The fulcrum of axes carried into the reference camera (`fulcrum_moving`).

    fit: the `cylinder.Fulcrum3D` (point_cov the (F, F) block with lambda's uncertainty);
    scale: lambda, the length of one map unit (None: no translation, not fitted),
    scale_sigma its sigma; points, directions (N, 3), covs (N, 4, 4): the axes carried at
    that scale; variance_factor: what point_cov and scale_sigma^2 were multiplied by (the
    used axes' chi2 per degree of freedom where above 1)."""

    fit: Fulcrum3D
    scale: float | None
    scale_sigma: float | None
    points: np.ndarray
    directions: np.ndarray
    covs: np.ndarray
    variance_factor: float = 1.0


def carry_axes(points, directions, covs, R, t, pose_cov, scale):
    """Axes carried into the reference camera: (points (N, 3), directions (N, 3), covs
    (N, 4, 4)) of ``R^T (A - scale t)`` along ``R^T d``, each cov the axis's and the pose's
    carried to the new axis's chart (module docstring).

    points, directions: (N, 3) axes in their frames' cameras; covs: (N, 4, 4) their chart
    covariances; R: (N, 3, 3) R_frame_from_ref; t: (N, 3) t_frame_from_ref [map unit];
    pose_cov: (N, 6, 6) of (rotation vector of a left turn of R [rad], t [map unit]);
    scale: lambda.
    """
    A, d = np.asarray(points, float), normalize(directions)
    C, R, t, Sp = (np.asarray(x, float) for x in (covs, R, t, pose_cov))
    E = axis_frame(A, d)                                            # (N, 2, 3)
    p0 = np.einsum("nji,nj->ni", R, A - scale * t)
    d0 = np.einsum("nji,nj->ni", R, d)
    E0 = axis_frame(p0, d0)
    size = np.linalg.norm(A, axis=-1)[:, None] + 1.0

    def chart(x):
        """(N, 4) the chart coordinates of the axes moved by x (N, 10): the four chart
        coordinates of the axis, then the pose's six."""
        P = A + x[:, 2:3] * E[:, 0] + x[:, 3:4] * E[:, 1]
        D = d + x[:, 0:1] * E[:, 0] + x[:, 1:2] * E[:, 1]
        turn = rotation_from_rotvec(x[:, 4:7]) @ R
        q = np.einsum("nji,nj->ni", turn, P - scale * (t + x[:, 7:10]))
        return axis_chart(q, np.einsum("nji,nj->ni", turn, D), p0, d0, E0)

    n = len(A)
    J = np.zeros((n, 4, 10))
    for k in range(10):
        h = _STEP * (size[:, 0] if k in (2, 3) else np.ones(n)) if k < 7 else \
            _STEP * (np.linalg.norm(t, axis=-1) + 1.0)
        e = np.zeros((n, 10))
        e[:, k] = h
        J[:, :, k] = (chart(e) - chart(-e)) / (2.0 * h[:, None])
    out = J[:, :, :4] @ C @ np.swapaxes(J[:, :, :4], 1, 2) + J[:, :, 4:] @ Sp @ np.swapaxes(J[:, :, 4:], 1, 2)
    return p0, d0, 0.5 * (out + np.swapaxes(out, 1, 2))


def _normal(F, P, D, C, t, use):
    """(H (4, 4), g (4,)) of the Gauss-Newton step of (F, lambda): residuals E (F - P) of
    the used axes, weighted by their perpendicular covariance at F; d P / d lambda = t (the
    frames' centres in the reference camera, c_k)."""
    E = axis_frame(P, D)
    dx = F - P
    s = np.sum(dx * D, -1)[:, None, None]
    cross = C[:, :2, 2:]
    S = s * s * C[:, :2, :2] + s * (cross + np.swapaxes(cross, 1, 2)) + C[:, 2:, 2:]
    W = np.linalg.inv(S) * use[:, None, None]
    r = np.einsum("nki,ni->nk", E, dx)
    J = np.concatenate([E, -np.einsum("nki,ni->nk", E, t)[:, :, None]], -1)   # (N, 2, 4)
    H = np.einsum("nki,nkl,nlj->ij", J, W, J)
    g = np.einsum("nki,nkl,nl->i", J, W, r)
    return H, g


def _start(A, d, R, t):
    """The unweighted least-squares (F, lambda) of all axes (the orthogonal distances); R
    (N, 3, 3) R_ref_from_frame, t (N, 3) the frames' centres c_k in the reference camera."""
    P0 = np.einsum("nij,nj->ni", R, A)
    D = np.einsum("nij,nj->ni", R, normalize(d))
    M = np.eye(3) - D[:, :, None] * D[:, None, :]
    H = np.zeros((4, 4))
    g = np.zeros(4)
    H[:3, :3] = M.sum(0)
    Mt = np.einsum("nij,nj->ni", M, t)
    H[:3, 3] = H[3, :3] = -Mt.sum(0)
    H[3, 3] = np.einsum("ni,ni->", t, Mt)
    g[:3] = np.einsum("nij,nj->i", M, P0)
    g[3] = -np.einsum("ni,ni->", Mt, P0)
    try:
        x = np.linalg.solve(H, g)
    except np.linalg.LinAlgError:
        raise EstimationError("the axes and the camera's translations do not fix the fulcrum and the scale") from None
    return x[:3], float(x[3])


def fulcrum_moving(points, directions, covs, R, t, pose_cov, robust=True):
    """The 3-D fulcrum in the reference camera of N axes seen from moving cameras (module
    docstring): points, directions (N, 3), covs (N, 4, 4) in their own frames' cameras (as
    `cylinder.fulcrum_3d` takes them), R (N, 3, 3) R_frame_from_ref, t (N, 3)
    t_frame_from_ref [map unit] and pose_cov (N, 6, 6) each axis's frame's pose
    (`detect.background_pose.FramePose`).
    Returns a `MovingFulcrum`; EstimationError when the axes fix no point or no positive
    scale."""
    A, d, C = np.asarray(points, float), normalize(directions), np.asarray(covs, float)
    R, t, Sp = np.asarray(R, float), np.asarray(t, float), np.asarray(pose_cov, float)
    if not np.any(np.linalg.norm(t, axis=-1) > 0):
        P, D, Cc = carry_axes(A, d, C, R, t, Sp, 1.0)
        fit = fulcrum_3d(P, D, Cc, robust=robust)
        factor = _variance_factor(fit, 3)
        fit = dataclasses.replace(fit, point_cov=fit.point_cov * factor, point_sigma=fit.point_sigma * np.sqrt(factor))
        return MovingFulcrum(fit, None, None, P, D, Cc, factor)
    Rr = np.swapaxes(R, -1, -2)
    c = -np.einsum("nij,nj->ni", Rr, t)                      # the frames' centres in the reference
    F, lam = _start(A, d, Rr, c)
    for _ in range(_ROUNDS):
        if not (np.isfinite(lam) and lam > 0):
            raise EstimationError(f"the camera's translations and the axes give no positive scale ({lam:.3g})")
        P, D, Cc = carry_axes(A, d, C, R, t, Sp, lam)
        fit = fulcrum_3d(P, D, Cc, robust=robust)
        use = np.asarray(fit.inliers, float)
        H, g = _normal(np.asarray(fit.point, float), P, D, Cc, c, use)
        try:
            step = -np.linalg.solve(H, g)
        except np.linalg.LinAlgError:
            raise EstimationError("the axes and the camera's translations do not fix the scale") from None
        lam = lam + step[3]
        if abs(step[3]) <= _TOL * abs(lam):
            break
    P, D, Cc = carry_axes(A, d, C, R, t, Sp, lam)
    fit = fulcrum_3d(P, D, Cc, robust=robust)
    H, _ = _normal(np.asarray(fit.point, float), P, D, Cc, c, np.asarray(fit.inliers, float))
    cov = np.linalg.inv(H)
    if not np.all(np.isfinite(cov)) or not cov[3, 3] > 0:
        raise EstimationError("the axes and the camera's translations do not fix the scale")
    factor = _variance_factor(fit, 4)
    cov = cov * factor
    fit = dataclasses.replace(fit, point_cov=cov[:3, :3], point_sigma=np.sqrt(np.trace(cov[:3, :3])))
    return MovingFulcrum(fit, float(lam), float(np.sqrt(cov[3, 3])), P, D, Cc, factor)


def _variance_factor(fit, params):
    """The a-posteriori variance factor of the fit's axes, only ever above 1: the used
    axes' chi2 over their residuals' degrees of freedom (two an axis, less `params`), 1
    where there are none."""
    used = np.asarray(fit.inliers, bool)
    return inflation(np.sum(np.asarray(fit.chi2)[used]), 2 * int(used.sum()) - params)
