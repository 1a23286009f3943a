"""The exact angular-variation estimator: pencil orientation from image line angles.

Given the image of the vertex and the image angles of N >= 3 spokes whose in-plane angles
theta_k are known in the target frame, recover R_cam_from_target (3 degrees of freedom:
the plane normal and the in-plane rotation), its twin, and their uncertainty.

Method (docs/method.md, "The exact estimator")
----------------------------------------------
1. Closed-form start. Rotate virtually so the vertex ray v_d becomes the optical axis
   (frames.rotation_to_z). There the spoke directions image as
   ``(cos b_k, sin b_k) ~ A (cos theta_k, sin theta_k)`` with A the top-left 2x2 block of
   the virtual rotation, A = R(psi) diag(1, cos gamma) R(theta0). A comes from a DLT, its
   signed SVD gives cos(gamma) = s2 / s1, and the rotation is completed in closed form.
2. Levenberg-Marquardt on wrapped image-angle residuals (period pi, lines), weighted by
   1/sigma_k^2: maximum likelihood for Gaussian angle noise. The rotation is updated by
   left perturbations in the camera frame, ``R <- expm(skew(delta)) R``.
3. Covariance of delta from the Jacobian, (J^T W J)^-1, with the vertex covariance carried
   in through the sensitivity of the solution to the vertex (first order).
4. ``detectable``: a likelihood-ratio test of the fit against the best *frontal* pencil
   (normal along v_d, one free in-plane angle). Near zero tilt the image angles change
   only as gamma^2 / 4, so the test is regular in (gamma^2 cos 2psi, gamma^2 sin 2psi) and
   the statistic is chi-square with 2 degrees of freedom; the default level is 1%.
5. The twin ``R' = Rot(v_d, pi) R Rot(z, pi)`` reproduces every image line and every
   oriented spoke direction exactly, so the data alone never separate it from R. Both are
   returned; `choose_by_prior` and `metric_twin_costs` use extra information.

All angles are radians, image angles are in *normalised* camera coordinates (z = 1 plane,
after undistortion), and every function broadcasts over leading batch dimensions, so N
pencils are fitted at once.

Example
-------
>>> import numpy as np
>>> from pencilcal.toolkit.geometry.frames import rotation_from_rotvec, rotation_angle
>>> from pencilcal.toolkit.pencil.spec import image_angles
>>> R_true = rotation_from_rotvec([0.5, -0.2, 0.1])
>>> theta = np.radians([0.0, 20, 40, 60, 80, 100, 120, 140])
>>> vertex = np.array([0.1, -0.05])                    # normalised image of the vertex
>>> a = image_angles(R_true, vertex, theta)
>>> fit = fit_pencil(a, theta, vertex, sigma=np.radians(0.1))
>>> err = min(rotation_angle(fit.R_cam_from_target, R_true), rotation_angle(fit.R_twin, R_true))
>>> bool(np.degrees(err) < 1e-8), bool(fit.detectable)
(True, True)
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from pencilcal.toolkit.geometry.angles import wrap_line
from pencilcal.toolkit.errors import EstimationError, InputError
from pencilcal.toolkit.pencil.defaults import CHI2_2_DETECTION, MAX_VERTEX, MIN_COS
from pencilcal.toolkit.geometry.frames import twin_rotation

__all__ = [
    "PencilFit",
    "fit_pencil",
    "closed_form_start",
    "refine_pencil",
    "pencil_jacobian",
    "pencil_covariance",
    "crlb",
    "frontal_fit",
    "max_angular_change",
    "detection_threshold",
    "choose_by_prior",
    "swap_twins",
    "check_vertex",
]

# Up to this many lines a single pencil is fitted on Python floats (toolkit/pencil/scalar.py).
_SINGLE_MAX_LINES = 64


@dataclass(frozen=True)
class PencilFit:
    """Result of `fit_pencil`; every field has the batch shape (...) in front.

    R_cam_from_target: (..., 3, 3) the solution; `normal` is its third column.
    R_twin: (..., 3, 3) the other rotation that reproduces the same image exactly.
    normal, normal_twin: (..., 3) unit, pointing away from the camera.
    ray: (..., 3) unit viewing ray of the vertex.
    tilt: (...) [rad] angle between normal and ray (0 = pencil faces the camera); the same
        for both twins.
    tilt_sigma, normal_sigma: (...) [rad] one-sigma tilt error; RMS angle of the normal
        error (sqrt of the trace of its 2x2 covariance), both including the vertex
        covariance when one was given.
    cov: (..., 3, 3) [rad^2] covariance of the left perturbation of R in the camera frame.
    residuals: (..., N) [rad] wrapped line residuals a_k - alpha_k (0 where weight is 0).
    rms: (...) [rad] weighted RMS residual; chi2: (...) sum of (residual/sigma)^2.
    chi2_frontal: (...) chi2 of the best frontal pencil; detectable: (...) bool, the
        likelihood-ratio test chi2_frontal - chi2 > chi2_2(1 - DETECTION_LEVEL) (defaults.py), with sigma
        inflated by the residual RMS when the lines scatter more than sigma says.
    lines_used: (...) int, lines with non-zero weight.
    converged: (...) bool; iterations: int.
    ambiguous: (...) bool, True until a twin is chosen with extra information.
    resolved_by: str or None, what chose between the twins ("prior", "radius", ...).
    """

    R_cam_from_target: np.ndarray
    R_twin: np.ndarray
    normal: np.ndarray
    normal_twin: np.ndarray
    ray: np.ndarray
    tilt: np.ndarray
    tilt_sigma: np.ndarray
    normal_sigma: np.ndarray
    cov: np.ndarray
    residuals: np.ndarray
    rms: np.ndarray
    chi2: np.ndarray
    chi2_frontal: np.ndarray
    detectable: np.ndarray
    lines_used: np.ndarray
    converged: np.ndarray
    iterations: int
    ambiguous: np.ndarray
    resolved_by: str | None = None

    def _with_residuals(self, keep):
        """The residuals spread back over all N input lines (0 where the weight was 0)."""
        if keep.all():
            return self
        full = np.zeros(keep.shape)
        full[keep] = self.residuals
        return replace(self, residuals=full)


# ----------------------------------------------------------------------------------------
# model and Jacobian


def _unit_dirs(spoke_angles):
    return np.stack([np.cos(spoke_angles), np.sin(spoke_angles)], -1)


def _cross(a, b):
    # np.cross moves axes around; for (..., 3) arrays this is several times faster
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    out = np.empty(np.broadcast_shapes(a.shape, b.shape))
    out[..., 0] = a1 * b2 - a2 * b1
    out[..., 1] = a2 * b0 - a0 * b2
    out[..., 2] = a0 * b1 - a1 * b0
    return out


def _spoke_matrix(ct, st):
    """(B, 2, N) stack of spoke cosines and sines, the right factor of `_model`."""
    return np.stack(np.broadcast_arrays(ct, st), -2)


def _model(R, x, C, with_jacobian=True):
    """Core of `pencil_jacobian` with the spokes precomputed.

    R: (B, 3, 3); x: (B, 2); C: (B, 2, N) or (2, N) spoke cosines and sines (`_spoke_matrix`).
    """
    D = R[..., :, :2] @ C  # camera-frame spoke directions as columns, (B, 3, N)
    dx, dy, dz = D[:, 0], D[:, 1], D[:, 2]
    x0, x1 = x[:, 0, None], x[:, 1, None]
    wx = dx - x0 * dz
    wy = dy - x1 * dz
    alpha = np.arctan2(wy, wx)
    if not with_jacobian:
        return alpha, None, None
    inv = 1.0 / (wx * wx + wy * wy)
    gx, gy = -wy * inv, wx * inv  # d alpha / d w
    # u = P^T g with P = [[1, 0, -x], [0, 1, -y]] = d w / d d
    u2 = -(gx * x0 + gy * x1)
    # d d / d delta = -[d]x  =>  d alpha / d delta = -u^T [d]x = -(u x d) = d x u
    J_rot = np.empty(alpha.shape + (3,))
    J_rot[..., 0] = dy * u2 - dz * gy
    J_rot[..., 1] = dz * gx - dx * u2
    J_rot[..., 2] = dx * gy - dy * gx
    J_vertex = np.empty(alpha.shape + (2,))
    J_vertex[..., 0] = -dz * gx
    J_vertex[..., 1] = -dz * gy
    return alpha, J_rot, J_vertex


def pencil_jacobian(R_cam_from_target, vertex, spoke_angles, with_jacobian=True):
    """Exact image angles of the spokes and their derivatives.

    R_cam_from_target: (..., 3, 3); vertex: (..., 2) normalised image of the vertex;
    spoke_angles: (..., N) [rad]. Returns

    alpha: (..., N) [rad] image angles (oriented, period 2*pi);
    J_rot: (..., N, 3) d alpha / d delta for the left perturbation R <- expm([delta]x) R;
    J_vertex: (..., N, 2) d alpha / d vertex (normalised coordinates).
    With ``with_jacobian=False`` only alpha is computed (J_rot, J_vertex are None).
    """
    R = np.asarray(R_cam_from_target, float)
    x = np.asarray(vertex, float)
    th = np.asarray(spoke_angles, float)
    batch = np.broadcast_shapes(R.shape[:-2], x.shape[:-1], th.shape[:-1])
    N = th.shape[-1]
    R = np.broadcast_to(R, batch + (3, 3)).reshape(-1, 3, 3)
    x = np.broadcast_to(x, batch + (2,)).reshape(-1, 2)
    th = np.broadcast_to(th, batch + (N,)).reshape(-1, N)
    alpha, J, Jx = _model(R, x, _spoke_matrix(np.cos(th), np.sin(th)), with_jacobian)
    if not with_jacobian:
        return alpha.reshape(batch + (N,)), None, None
    return alpha.reshape(batch + (N,)), J.reshape(batch + (N, 3)), Jx.reshape(batch + (N, 2))


def _rotvec_small(r):
    # Rodrigues for (B, 3), written out: this sits in the LM loop.
    # a = sin(t)/t and b = (1 - cos t)/t^2 = 2 sin^2(t/2)/t^2 are exact down to t = 1e-150
    # without branches (below that the step is zero to double precision anyway).
    t = np.maximum(np.sqrt((r * r).sum(-1)), 1e-150)
    a = np.sin(t) / t
    h = np.sin(0.5 * t)
    b = 2.0 * h * h / (t * t)
    x, y, z = r[..., 0], r[..., 1], r[..., 2]
    bx, by, bz = b * x, b * y, b * z
    ax, ay, az = a * x, a * y, a * z
    out = np.empty(r.shape[:-1] + (3, 3))
    out[..., 0, 0] = 1.0 - by * y - bz * z
    out[..., 1, 1] = 1.0 - bx * x - bz * z
    out[..., 2, 2] = 1.0 - bx * x - by * y
    out[..., 0, 1] = bx * y - az
    out[..., 1, 0] = bx * y + az
    out[..., 0, 2] = bx * z + ay
    out[..., 2, 0] = bx * z - ay
    out[..., 1, 2] = by * z - ax
    out[..., 2, 1] = by * z + ax
    return out


def _virtual_rotation(x):
    """Q with Q (x, y, 1) ~ (0, 0, 1) for normalised vertices x: (B, 2) -> (B, 3, 3).

    The same rotation as frames.rotation_to_z (about v x z), written out for speed.
    """
    n = np.sqrt(1.0 + x[..., 0] ** 2 + x[..., 1] ** 2)
    vx, vy, c = x[..., 0] / n, x[..., 1] / n, 1.0 / n
    # Rodrigues for the rotation taking v to z: I + [k]x + [k]x^2 / (1 + c), k = v x z
    kx, ky = vy, -vx
    f = 1.0 / (1.0 + c)
    Q = np.empty(x.shape[:-1] + (3, 3))
    Q[..., 0, 0] = 1.0 - f * ky * ky
    Q[..., 0, 1] = f * kx * ky
    Q[..., 0, 2] = ky
    Q[..., 1, 0] = f * kx * ky
    Q[..., 1, 1] = 1.0 - f * kx * kx
    Q[..., 1, 2] = -kx
    Q[..., 2, 0] = -ky
    Q[..., 2, 1] = kx
    Q[..., 2, 2] = c
    return Q


def _residuals(a, alpha):
    return wrap_line(a - alpha)


# ----------------------------------------------------------------------------------------
# closed-form start


def _zxz(phi, cos_g, sin_g, theta):
    """Rz(phi) Rx(gamma) Rz(theta) for (B,) arrays, written out (no matmuls)."""
    cp, sp, ct, st = np.cos(phi), np.sin(phi), np.cos(theta), np.sin(theta)
    out = np.empty(phi.shape + (3, 3))
    out[..., 0, 0] = cp * ct - sp * cos_g * st
    out[..., 0, 1] = -cp * st - sp * cos_g * ct
    out[..., 0, 2] = sp * sin_g
    out[..., 1, 0] = sp * ct + cp * cos_g * st
    out[..., 1, 1] = -sp * st + cp * cos_g * ct
    out[..., 1, 2] = -cp * sin_g
    out[..., 2, 0] = sin_g * st
    out[..., 2, 1] = sin_g * ct
    out[..., 2, 2] = cos_g
    return out


def _virtual_line_dirs(Q, ca, sa):
    # a line through the vertex with direction (cos a, sin a) is the image of the 3D line
    # through P0 with direction (cos a, sin a, 0); the virtual camera sees Q of that
    bx = Q[..., 0, 0, None] * ca + Q[..., 0, 1, None] * sa
    by = Q[..., 1, 0, None] * ca + Q[..., 1, 1, None] * sa
    return bx, by


def _closed_form(bx, by, ct, st, w, Q, oriented, twin=True):
    """DLT of A in (cos b, sin b) ~ A (cos theta, sin theta), then its signed SVD."""
    nb = np.sqrt(bx * bx + by * by)
    cb, sb = bx / nb, by / nb
    sw = np.sqrt(w)
    rows = np.stack([sb * ct, sb * st, -cb * ct, -cb * st], -1) * sw[..., None]
    M = np.matmul(np.swapaxes(rows, -1, -2), rows)
    evals, evecs = np.linalg.eigh(M)
    # a unique pencil needs a one-dimensional null space; three or more lines that share
    # one direction (or two directions only) leave two
    # (relative 1e-12: rounding leaves ~1e-16 of the largest eigenvalue in a true null space)
    if np.any(evals[..., 1] <= 1e-12 * evals[..., 3]):
        raise EstimationError("the lines do not determine a pencil: fewer than three distinct directions")
    h = evecs[..., :, 0]
    a, b, c, d = h[..., 0], h[..., 1], h[..., 2], h[..., 3]
    if oriented:
        # the spoke directions (vertex -> tip) must agree with the line directions
        agree = np.sum(w * ((a[..., None] * ct + b[..., None] * st) * cb + (c[..., None] * ct + d[..., None] * st) * sb), -1)
        sgn = np.where(agree < 0, -1.0, 1.0)
        a, b, c, d = a * sgn, b * sgn, c * sgn, d * sgn
    # analytic signed SVD A = Rot(phi) diag(s1, s2) Rot(theta0), s1 >= |s2|, sign(s2) = sign(det A)
    E, F, G, H = (a + d) / 2, (a - d) / 2, (c + b) / 2, (c - b) / 2
    q, r = np.hypot(E, H), np.hypot(F, G)
    a1, a2 = np.arctan2(G, F), np.arctan2(H, E)
    theta0, phi = (a2 - a1) / 2, (a2 + a1) / 2
    # cos(gamma) = s2/s1; a negative s2 (mirror image) is noise near edge-on: clamp
    cos_g = np.clip((q - r) / np.maximum(q + r, 1e-300), MIN_COS, 1.0)
    sin_g = np.sqrt(1.0 - cos_g * cos_g)
    Qt = np.swapaxes(Q, -1, -2)
    R = Qt @ _zxz(phi, cos_g, sin_g, theta0)
    return R, (Qt @ _zxz(phi, cos_g, -sin_g, theta0) if twin else None)


def closed_form_start(line_angles, spoke_angles, vertex, weights=None, oriented=True):
    """Closed-form rotation from >= 3 lines by a DLT in the virtual camera (module doc, step 1).

    line_angles, spoke_angles: (..., N) [rad]; vertex: (..., 2) normalised; weights:
    (..., N) or None. In the virtual camera looking along the vertex ray,
    (cos b_k, sin b_k) ~ A (cos theta_k, sin theta_k) with A = R(psi) diag(1, cos gamma)
    R(theta0); A comes from the DLT and its signed SVD. With `oriented`, the sign of A is
    chosen so that spoke directions (vertex -> tip) agree with the line directions;
    otherwise the in-plane rotation is defined only up to 180 deg.

    Returns (R, R_twin): (..., 3, 3) each, exact for noise-free data.
    """
    a = np.asarray(line_angles, float)
    th = np.asarray(spoke_angles, float)
    x = np.asarray(vertex, float)
    shape = np.broadcast_shapes(a.shape, th.shape, x.shape[:-1] + (1,))
    a, th = np.broadcast_to(a, shape), np.broadcast_to(th, shape)
    x = np.broadcast_to(x, shape[:-1] + (2,))
    w = np.ones(shape) if weights is None else np.broadcast_to(np.asarray(weights, float), shape)
    Q = _virtual_rotation(x)
    bx, by = _virtual_line_dirs(Q, np.cos(a), np.sin(a))
    return _closed_form(bx, by, np.cos(th), np.sin(th), w, Q, oriented)


# ----------------------------------------------------------------------------------------
# refinement


def refine_pencil(R0, line_angles, spoke_angles, vertex, weights, max_iter=30, tol=1e-9, _C=None):
    """Levenberg-Marquardt on wrapped, weighted line-angle residuals.

    R0: (B, 3, 3) start; line_angles, spoke_angles, weights: (B, N); vertex: (B, 2).
    Stops when the step is below `tol` [rad] or the cost no longer decreases.
    Returns (R, cost, converged, iterations, (J_rot, J_vertex, r)) with cost = sum w r^2
    per pencil, the Jacobians of `pencil_jacobian` at R and the weighted residuals r.
    """
    R = np.array(R0, float)
    a = np.asarray(line_angles, float)
    th = np.asarray(spoke_angles, float)
    x = np.asarray(vertex, float)
    sw = np.sqrt(np.asarray(weights, float))
    C = _spoke_matrix(np.cos(th), np.sin(th)) if _C is None else _C
    alpha, J, Jx = _model(R, x, C)
    r = sw * wrap_line(a - alpha)
    cost = (r * r).sum(-1)
    lam = np.full(cost.shape, 1e-4)
    active = np.ones(cost.shape, bool)
    eye = np.eye(3)
    it = 0
    for it in range(1, max_iter + 1):
        Jw = J * sw[..., None]
        JwT = Jw.transpose(0, 2, 1)
        H = JwT @ Jw
        # residual r = a - alpha and d r / d delta = -J, so the GN step solves H step = J^T r
        g = JwT @ r[..., None]
        # Marquardt scaling of the diagonal, plus a floor for exactly unobservable
        # directions (zero tilt), so the damped system is never singular
        floor = 1e-12 * (H[:, 0, 0] + H[:, 1, 1] + H[:, 2, 2]) + 1e-300
        Hd = H * (1.0 + lam[:, None, None] * eye) + (lam * floor)[:, None, None] * eye
        step = np.linalg.solve(Hd, g)[..., 0]
        if not active.all():
            step[~active] = 0.0
        R_new = _rotvec_small(step) @ R
        alpha_n, J_n, Jx_n = _model(R_new, x, C)
        r_n = sw * wrap_line(a - alpha_n)
        cost_n = (r_n * r_n).sum(-1)
        better = (cost_n <= cost) & active
        if better.all():
            R, J, Jx, r = R_new, J_n, Jx_n, r_n
        else:
            R = np.where(better[:, None, None], R_new, R)
            J = np.where(better[:, None, None], J_n, J)
            Jx = np.where(better[:, None, None], Jx_n, Jx)
            r = np.where(better[:, None], r_n, r)
        small = (step * step).sum(-1) < tol * tol
        stalled = better & ((cost - cost_n) <= 1e-14 * cost)
        cost = np.minimum(cost, cost_n) * better + cost * ~better
        # only pencils still iterating change their damping: a stopped pencil must not be
        # pushed past the divergence limit by its neighbours' iterations
        lam = np.where(active, lam * (10.0 - 9.9 * better), lam)
        active &= ~(small | stalled | (lam > 1e10))
        if not active.any():
            break
    return R, cost, lam <= 1e10, it, (J, Jx, r)


# ----------------------------------------------------------------------------------------
# uncertainty


def _covariance(R, x, J, Jx, w, vertex_cov, w_error=None, shared_cov=None):
    """Covariance, tilt sigma and normal sigma from the Jacobians at R (see pencil_covariance;
    w_error: the inverse variances of the angles' errors where not the weights w; shared_cov:
    the rotation's covariance from errors all lines share, added)."""
    JT = np.swapaxes(J, -1, -2)
    H = JT @ (J * w[..., None])
    # At zero tilt the tilt directions are unobservable to first order: a tiny ridge keeps
    # the inverse finite (and huge) instead of singular.
    ridge = (1e-14 * np.trace(H, axis1=-2, axis2=-1))[..., None, None] * np.eye(3)
    H_inv = np.linalg.inv(H + ridge)
    cov_rot = H_inv  # the rotation's covariance where the weights w are the inverse variances ...
    if w_error is not None:
        # ... else the fit weighted by w, its angles' errors of variance 1 / w_error: the solution
        # moves by H^-1 J^T W r, whose covariance is H^-1 J^T W C W J H^-1 (H^-1 where C = W^-1)
        cov_rot = H_inv @ (JT @ (J * (w * w / w_error)[..., None])) @ H_inv
    n = R[..., :, 2]
    nv = np.sqrt(1.0 + x[..., 0] ** 2 + x[..., 1] ** 2)
    v = np.concatenate([x, np.ones(x.shape[:-1] + (1,))], -1) / nv[..., None]
    # tilt gamma = acos(n . v): d gamma / d delta = -(n x v) / sin(gamma)
    nxv = _cross(n, v)
    sin_raw = np.sqrt(np.sum(nxv * nxv, -1))
    sin_g = np.maximum(sin_raw, 1e-12)
    g_rot = -nxv / sin_g[..., None]
    var_tilt = np.einsum("...i,...ij,...j->...", g_rot, cov_rot, g_rot)
    # at exactly zero tilt the tilt's direction is undefined and, to first order, the
    # angles do not see it at all: the bound is infinite, not the zero the gradient gives
    var_tilt = np.where(sin_raw < 1e-9, np.inf, var_tilt)
    cov = cov_rot
    if vertex_cov is not None:
        Cx = np.asarray(vertex_cov, float)
        # sensitivity of the solution to the vertex: with r = a - alpha, d r/d delta = -J and
        # d r/d x = -Jx, the solution moves by G dx with G = -H^-1 J^T W Jx
        G = -H_inv @ (JT @ (Jx * w[..., None]))  # the fit's own response, whatever its angles' errors
        cov = cov + G @ Cx @ np.swapaxes(G, -1, -2)
        # the tilt also moves with the ray itself: d v_hat / d x = (I - v v^T)[:, :2] / |v|
        P = (np.eye(3) - v[..., :, None] * v[..., None, :])[..., :, :2] / nv[..., None, None]
        g_x = np.einsum("...i,...ij->...j", g_rot, G) - np.einsum("...i,...ij->...j", n, P) / sin_g[..., None]
        var_tilt = var_tilt + np.einsum("...i,...ij,...j->...", g_x, Cx, g_x)
    if shared_cov is not None:  # an error the lines share, whatever the vertex
        S = np.asarray(shared_cov, float)
        cov = cov + S
        var_tilt = var_tilt + np.einsum("...i,...ij,...j->...", g_rot, S, g_rot)
    # the normal moves by delta x n: covariance P cov P with P = I - n n^T
    Pn = np.eye(3) - n[..., :, None] * n[..., None, :]
    var_normal = np.trace(Pn @ cov @ Pn, axis1=-2, axis2=-1)
    return cov, np.sqrt(np.maximum(var_tilt, 0.0)), np.sqrt(np.maximum(var_normal, 0.0))


def pencil_covariance(R_cam_from_target, vertex, spoke_angles, sigma, vertex_cov=None, weights_mask=None,
                      sigma_error=None, shared_cov=None):
    """First-order covariance of the orientation at R, given angle noise and vertex noise.

    R_cam_from_target: (..., 3, 3); vertex: (..., 2) normalised; spoke_angles: (..., N);
    sigma: (..., N) or scalar [rad], the standard deviation of each image line angle in
    normalised coordinates; vertex_cov: (..., 2, 2) covariance of the normalised vertex or
    None (vertex exact); weights_mask: (..., N) bool of lines used (default all);
    sigma_error: None or like sigma [rad], the sd of each angle's error where it is not the
    sigma the fit weighted it by (errors the weights leave out): the covariance of the fit
    weighted by 1 / sigma^2 under errors of these sds (H^-1 J^T W C W J H^-1), the same as
    without it where sigma_error equals sigma.
    shared_cov: None or (..., 3, 3) [rad^2] the rotation's covariance (left perturbation)
    from an error all the lines share, which their own sds leave out (a printed sheet's
    bend: `bend.bend_covariance`), added before the tilt and normal are taken from it.

    Returns (cov, tilt_sigma, normal_sigma): cov (..., 3, 3) [rad^2] of the left rotation
    perturbation; tilt_sigma (...) [rad]; normal_sigma (...) [rad], the RMS angle of the
    normal error (sqrt of the trace of the normal's covariance). Evaluated at the true
    rotation this is the Cramer-Rao bound (see `crlb`). The vertex is treated as
    independent of the line angles (it comes mostly from the lines' offsets).
    """
    R = np.asarray(R_cam_from_target, float)
    x = np.asarray(vertex, float)
    _, J, Jx = pencil_jacobian(R, x, spoke_angles)
    w = 1.0 / np.broadcast_to(np.asarray(sigma, float), J.shape[:-1]) ** 2
    if weights_mask is not None:
        w = np.where(weights_mask, w, 0.0)
    w_err = None if sigma_error is None else 1.0 / np.broadcast_to(np.asarray(sigma_error, float), J.shape[:-1]) ** 2
    return _covariance(R, np.broadcast_to(x, J.shape[:-2] + (2,)), J, Jx, w, vertex_cov, w_err, shared_cov)


def crlb(R_cam_from_target, vertex, spoke_angles, sigma, vertex_cov=None):
    """Cramer-Rao bound of the orientation for Gaussian angle noise `sigma` [rad].

    The same computation as `pencil_covariance`, evaluated at the true pose. Returns
    (cov, tilt_sigma, normal_sigma) with the shapes documented there.

    Example: 8 spokes 20 deg apart, sigma = 0.1 deg, tilt 20 deg on the optical axis:
    >>> import numpy as np
    >>> from pencilcal.toolkit.geometry.frames import rotation_about_axis
    >>> R = rotation_about_axis([1.0, 0, 0], np.radians(20))
    >>> _, s_tilt, _ = crlb(R, [0.0, 0.0], np.radians(np.arange(8) * 20.0), np.radians(0.1))
    >>> 0.1 < float(np.degrees(s_tilt)) < 0.6
    True
    """
    return pencil_covariance(R_cam_from_target, vertex, spoke_angles, sigma, vertex_cov)


# ----------------------------------------------------------------------------------------
# frontal model and detection


def _frontal(a, th, C, x, w, Q, bx, by):
    """Frontal fit on prepared arrays; see `frontal_fit`."""
    b = np.arctan2(by, bx)
    # d b / d a = det(L) / |L t|^2 with L = Q[:2, :2], det(L) = Q[2, 2]: the virtual image
    # stretches angles by this gain, so the weights there are w / gain^2
    gain2 = (Q[..., 2, 2, None] / (bx * bx + by * by)) ** 2
    wv = w / gain2
    e = 2.0 * (b - th)  # lines: period pi
    phi = 0.5 * np.arctan2((wv * np.sin(e)).sum(-1), (wv * np.cos(e)).sum(-1))
    Qt = Q.transpose(0, 2, 1) if Q.ndim == 3 else np.swapaxes(Q, -1, -2)
    vhat = Qt[..., :, 2]
    sw = np.sqrt(w)

    def rot(phi):
        Rz = np.zeros(phi.shape + (3, 3))
        c, s = np.cos(phi), np.sin(phi)
        Rz[..., 0, 0] = c
        Rz[..., 0, 1] = -s
        Rz[..., 1, 0] = s
        Rz[..., 1, 1] = c
        Rz[..., 2, 2] = 1.0
        return Qt @ Rz

    alpha, J, _ = _model(rot(phi), x, C)
    r = sw * wrap_line(a - alpha)
    # rotating about the ray is the left perturbation delta = phi * v_hat: one GN step
    j = sw * (J @ vhat[..., None])[..., 0]
    phi = phi + (j * r).sum(-1) / np.maximum((j * j).sum(-1), 1e-300)
    R = rot(phi)
    alpha, _, _ = _model(R, x, C, with_jacobian=False)
    r = sw * wrap_line(a - alpha)
    return R, (r * r).sum(-1)


def frontal_fit(line_angles, spoke_angles, vertex, weights):
    """Best pencil with the normal along the vertex ray (tilt 0), one free in-plane angle.

    line_angles, spoke_angles, weights: (..., N); vertex: (..., 2). In the virtual camera
    that looks along the ray a frontal pencil images exactly as b_k = theta_k + phi, so phi
    is a weighted circular mean there (weights carried through d b / d a); one Gauss-Newton
    step on the real residuals polishes it. Returns (R_frontal (..., 3, 3), chi2 (...)),
    chi2 = sum w r^2 evaluated exactly at R_frontal.
    """
    a = np.asarray(line_angles, float)
    th = np.asarray(spoke_angles, float)
    x = np.asarray(vertex, float)
    w = np.asarray(weights, float)
    Q = _virtual_rotation(x)
    ca, sa = np.cos(a), np.sin(a)
    bx, by = _virtual_line_dirs(Q, ca, sa)
    return _frontal(a, th, _spoke_matrix(np.cos(th), np.sin(th)), x, w, Q, bx, by)


def max_angular_change(tilt):
    """Largest change of an image angle that a tilt produces: atan(1/sqrt(cos g)) - atan(sqrt(cos g)).

    tilt: (...) [rad] -> (...) [rad]; about tilt^2 / 4 for small tilts (0.44 deg at 10 deg).
    """
    c = np.sqrt(np.cos(np.asarray(tilt, float)))
    return np.arctan(1.0 / c) - np.arctan(c)


def detection_threshold(sigma):
    """Tilt [rad] at which the largest angular change equals the angle noise: ~2 sqrt(sigma).

    sigma: (...) [rad]. Solves max_angular_change(g) = sigma exactly (the 2 sqrt(sigma)
    rule of docs/method.md is its small-angle form: 4.8 deg for sigma = 0.1 deg).
    """
    s = np.asarray(sigma, float)
    g = 2.0 * np.sqrt(s)
    for _ in range(30):  # Newton on f(g) = max_angular_change(g) - sigma
        c = np.sqrt(np.cos(g))
        # f'(g) = sin g / (c (1 + c^2)), c = sqrt(cos g): quadratic convergence, a few steps
        step = (np.arctan(1.0 / c) - np.arctan(c) - s) * c * (1.0 + c * c) / np.sin(g)
        new = np.clip(g - step, 1e-9, np.pi / 2 - 1e-9)
        done = np.all(np.abs(new - g) <= 1e-12 * new)  # f itself is known to ~1e-10 of sigma
        g = new
        if done:
            break
    return g


# ----------------------------------------------------------------------------------------
# the whole fit


def check_vertex(vertex):
    """EstimationError when a normalised vertex (..., 2) is at infinity (> 89 deg off axis)."""
    if np.any(np.hypot(np.asarray(vertex, float)[..., 0], np.asarray(vertex, float)[..., 1]) > MAX_VERTEX):
        raise EstimationError("the vertex is at infinity (the lines are parallel in the image)")


def _as_batch(line_angles, spoke_angles, vertex, sigma, weights):
    a = np.asarray(line_angles, float)
    th = np.asarray(spoke_angles, float)
    x = np.asarray(vertex, float)
    if weights is None and a.ndim == 1 and th.shape == a.shape and x.shape == (2,) and np.ndim(sigma) == 0:
        # one pencil, all lines used: the common call, without the broadcasting machinery
        s0 = float(sigma)
        if not (np.isfinite(a).all() and np.isfinite(th).all() and np.isfinite(x).all() and np.isfinite(s0)):
            raise InputError("line angles, spoke angles, sigma and vertex must be finite (NaN or inf given)")
        if not s0 > 0:
            raise InputError("sigma must be positive")
        N = a.size
        return (a[None], th[None], x[None], np.full((1, N), s0), np.full((1, N), 1.0 / (s0 * s0)),
                np.ones((1, N), bool), ())
    if a.ndim == 0 or x.ndim == 0 or x.shape[-1] != 2:
        raise InputError("line angles must be (..., N) and the vertex (..., 2)")
    batch = np.broadcast_shapes(a.shape[:-1], th.shape[:-1], x.shape[:-1])
    N = np.broadcast_shapes(a.shape[-1:], th.shape[-1:])[0]
    a = np.broadcast_to(a, batch + (N,)).reshape(-1, N)
    th = np.broadcast_to(th, batch + (N,)).reshape(-1, N)
    x = np.broadcast_to(x, batch + (2,)).reshape(-1, 2)
    s = np.broadcast_to(np.asarray(sigma, float), batch + (N,)).reshape(-1, N)
    if weights is None:
        m = np.ones(a.shape, bool)
    else:
        m = np.broadcast_to(np.asarray(weights) > 0, batch + (N,)).reshape(-1, N)
    # only the lines in use have to be finite: a missing spoke may be NaN
    ok = np.isfinite(np.where(m, a + th + s, 0.0)).all() and np.isfinite(x).all()
    if not ok:
        raise InputError("line angles, spoke angles, sigma and vertex must be finite (NaN or inf given)")
    if np.any(m & ~(s > 0)):
        raise InputError("sigma must be positive")
    w = np.where(m, 1.0 / np.where(m, s, 1.0) ** 2, 0.0)
    a = np.where(m, a, 0.0)
    th = np.where(m, th, 0.0)
    return a, th, x, s, w, m, batch


def fit_pencil(line_angles, spoke_angles, vertex, sigma=np.radians(0.1), vertex_cov=None,
               weights=None, oriented=True, max_iter=30):
    """Fit the orientation of one or many pencils (the exact estimator, the default).

    line_angles: (..., N) [rad] image angles in normalised coordinates, line k labelled
        with spoke k; oriented (vertex -> tip) when `oriented`, else any of a, a + pi.
    spoke_angles: (..., N) [rad] theta_k in the target frame.
    vertex: (..., 2) normalised image of the vertex.
    sigma: scalar or (..., N) [rad] standard deviation of each line angle.
    vertex_cov: (..., 2, 2) covariance of the normalised vertex, or None.
    weights: (..., N) mask; lines with weight 0 are ignored (missing spokes).

    Returns a `PencilFit` with batch shape (...). The first solution is the twin whose
    normal is closer to the optical axis (a deterministic order; `ambiguous` is True).
    Raises EstimationError when a pencil has fewer than three lines.
    """
    a, th, x, s, w, m, batch = _as_batch(line_angles, spoke_angles, vertex, sigma, weights)
    used = m.sum(-1)
    if np.any(used < 3):
        raise EstimationError(f"a pencil needs at least three lines, got {int(used.min())}")
    check_vertex(x)
    if batch == () and a.shape[-1] <= _SINGLE_MAX_LINES:
        # one pencil: the same arithmetic on Python floats is several times faster than
        # hundreds of tiny numpy calls (toolkit/pencil/scalar.py, held equal by the tests)
        from pencilcal.toolkit.pencil.scalar import fit_one

        keep = m[0]
        try:
            return PencilFit(**fit_one(a[0][keep].tolist(), th[0][keep].tolist(), x[0], s[0][keep].tolist(), oriented,
                                       max_iter, 1e-9, vertex_cov, MIN_COS, CHI2_2_DETECTION))._with_residuals(keep)
        except ValueError:
            raise EstimationError("the lines do not determine a pencil: fewer than three distinct directions") from None
    ct, st = np.cos(th), np.sin(th)
    C = _spoke_matrix(ct, st)
    Q = _virtual_rotation(x)
    bx, by = _virtual_line_dirs(Q, np.cos(a), np.sin(a))
    R0, _ = _closed_form(bx, by, ct, st, w, Q, oriented, twin=False)
    R, cost, conv, iters, (J, Jx, r) = refine_pencil(R0, a, th, x, w, max_iter=max_iter, _C=C)
    v = Q[:, 2, :]  # unit ray: Q maps it to z, so it is Q's last row
    Rt = twin_rotation(R, v)
    # deterministic order: the normal closer to the optical axis first
    swap = Rt[:, 2, 2] > R[:, 2, 2]
    if swap.any():
        R, Rt = np.where(swap[:, None, None], Rt, R), np.where(swap[:, None, None], R, Rt)
        _, J2, Jx2 = _model(R, x, C)
        J, Jx = np.where(swap[:, None, None], J2, J), np.where(swap[:, None, None], Jx2, Jx)
    # the twin images every line identically, so the residuals hold for either order
    res = np.where(m, r / np.where(m, np.sqrt(w), 1.0), 0.0)
    Cx = None if vertex_cov is None else np.broadcast_to(np.asarray(vertex_cov, float), batch + (2, 2)).reshape(-1, 2, 2)
    cov, s_tilt, s_norm = _covariance(R, x, J, Jx, w, Cx)
    _, chi2_0 = _frontal(a, th, C, x, w, Q, bx, by)
    dof = used - 3
    # if the lines scatter more than sigma says, test against the inflated noise
    inflate = np.where(dof > 0, np.maximum(1.0, cost / np.maximum(dof, 1)), 1.0)
    detectable = (chi2_0 - cost) / inflate > CHI2_2_DETECTION
    tilt = np.arccos(np.clip(np.einsum("bi,bi->b", R[:, :, 2], v), -1.0, 1.0))
    rms = np.sqrt(np.sum(w * res * res, -1) / np.sum(w, -1))

    def out(arr, tail=()):
        return np.asarray(arr).reshape(batch + tail)

    return PencilFit(
        R_cam_from_target=out(R, (3, 3)),
        R_twin=out(Rt, (3, 3)),
        normal=out(R[:, :, 2], (3,)),
        normal_twin=out(Rt[:, :, 2], (3,)),
        ray=out(v, (3,)),
        tilt=out(tilt),
        tilt_sigma=out(s_tilt),
        normal_sigma=out(s_norm),
        cov=out(cov, (3, 3)),
        residuals=out(res, (res.shape[-1],)),
        rms=out(rms),
        chi2=out(cost),
        chi2_frontal=out(chi2_0),
        detectable=out(detectable),
        lines_used=out(used),
        converged=out(conv),
        iterations=iters,
        ambiguous=out(np.ones(detectable.shape, bool)),
    )


# ----------------------------------------------------------------------------------------
# twins


def swap_twins(fit, which, spoke_angles, vertex, sigma, vertex_cov=None, weights=None, resolved_by=None):
    """Return `fit` with the twin made the solution where `which` is true, re-evaluating
    the covariance at the new solution. which: (...) bool. Marks them not ambiguous when
    `resolved_by` is given."""
    which = np.asarray(which, bool)
    R = np.where(which[..., None, None], fit.R_twin, fit.R_cam_from_target)
    Rt = np.where(which[..., None, None], fit.R_cam_from_target, fit.R_twin)
    mask = None if weights is None else np.asarray(weights) > 0
    cov, s_tilt, s_norm = pencil_covariance(R, vertex, spoke_angles, sigma, vertex_cov, mask)
    amb = fit.ambiguous if resolved_by is None else np.zeros_like(fit.ambiguous)
    return replace(
        fit, R_cam_from_target=R, R_twin=Rt, normal=R[..., :, 2], normal_twin=Rt[..., :, 2],
        cov=cov, tilt_sigma=s_tilt, normal_sigma=s_norm, ambiguous=amb,
        resolved_by=resolved_by if resolved_by is not None else fit.resolved_by,
    )


def choose_by_prior(R, R_twin, R_prior):
    """True where the twin is closer to a prior rotation than R (a board pose, the previous
    frame). (..., 3, 3) each -> (...) bool."""
    from pencilcal.toolkit.geometry.frames import rotation_angle

    return rotation_angle(R_twin, R_prior) < rotation_angle(R, R_prior)
