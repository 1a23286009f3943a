"""A printed sheet's bend, an error every spoke of a radial target shares.

A sheet of paper is rarely flat: curled along one direction it lifts its spokes off the
plane by an amount that grows with the square of their distance from the vertex. Each
edge's image is then the image of a curve, which its straight line fits at an angle a
little off the plane's pencil, and every spoke is turned by the same bend: an error the
lines' own noise does not include, and that does not shrink as more spokes are used.

Model: the sheet tangent to the target plane at the vertex, lifted along the plane's normal
by z = (b1 u^2 + 2 b2 u v + b3 v^2) / 2 at target point (u, v) (lengths in units of the
vertex's depth, so that b is the curvature times that depth). `bend_response` gives each
line's angle change per unit b (the line fitted through the lifted points over its extent,
and the vertex the lines meet at moved with them). The bend is a random effect:
b ~ N(0, tau^2 S) with S the shape of a cylinder's bend in a direction drawn uniformly
(`CYLINDER_SHAPE`), tau^2 estimated from the lines' residuals (what of them the bend
explains beyond what their noise does: `bend_covariance`). The fit itself is unchanged; its
rotation's covariance gains the bend's share, tau^2 M S M^T (M: the fit's response to b).
On a flat sheet the estimate is 0 (95 % of the time) and the sigmas stay as they were.

What misfit is left once the bend's fit is taken out is the lines' own errors being larger
than their sds say: its chi2 per degree of freedom (the lines less the turn's 3 and the
bend's 3), where over one, scales the lines' error variances (`bend_covariance`'s scale), and
the bend is told from the noise so widened (lines that scatter twice their sds show a bend's
chi2 four times chance on a flat sheet).
"""
from __future__ import annotations

import numpy as np

from pencilcal.toolkit.geometry.angles import wrap_line
from pencilcal.toolkit.geometry.conic import fit_ellipse
from pencilcal.toolkit.geometry.quantiles import chi2_isf
from pencilcal.toolkit.pencil.circle import conic_normal
from pencilcal.toolkit.pencil.estimator import pencil_jacobian

__all__ = ["CYLINDER_SHAPE", "BEND_SAMPLES", "BEND_CHANCE", "bend_response", "bend_covariance",
           "circle_bend_response"]

#: E[b b^T] of a cylindrical bend of unit curvature about an axis in a direction drawn
#: uniformly in the plane: b = (c^2, c s, s^2) with (c, s) the bend's direction.
CYLINDER_SHAPE = np.array([[3 / 8, 0.0, 1 / 8], [0.0, 1 / 8, 0.0], [1 / 8, 0.0, 3 / 8]])
#: Points along each line at which the lifted sheet is imaged (the line fitted through them).
BEND_SAMPLES = 9
#: The bend's chi2 (3 dof) that the lines' noise alone reaches in 5 % of flat sheets: only
#: what the residuals show beyond it counts as a bend (flat sheets keep their sigmas 95 %
#: of the time; chosen on rendered photographs, docs/uncertainty.md).
BEND_CHANCE = float(chi2_isf(0.05, 3))


def bend_response(R_cam_from_target, vertex, p1, p2, angle_sigma, offset_sigma, samples=BEND_SAMPLES):
    """How a bend of the sheet moves each line and the vertex they meet at.

    R_cam_from_target: (3, 3) the fitted plane; vertex: (2,) normalised; p1, p2: (K, 2) the
    lines' end points (normalised); angle_sigma (K,) [rad], offset_sigma (K,) [normalised]:
    the lines' sds, which weigh them in the vertex's intersection.

    Returns (G (K, 3): each line's angle change [rad] per unit bend b (module docstring),
    X (2, 3): the lines' weighted intersection's move per unit b [normalised]).
    """
    R = np.asarray(R_cam_from_target, float)
    x = np.asarray(vertex, float)
    n = R[:, 2]
    V = np.append(x, 1.0)  # the vertex at unit depth
    s = np.linspace(0.0, 1.0, samples)
    p = p1[:, None] + s[None, :, None] * (p2 - p1)[:, None]  # (K, S, 2)
    ray = np.concatenate([p, np.ones(p.shape[:-1] + (1,))], -1)
    P = ((n @ V) / (ray @ n))[..., None] * ray  # where each ray meets the plane
    u, v = np.moveaxis((P - V) @ R[:, :2], -1, 0)
    basis = np.stack([0.5 * u * u, u * v, 0.5 * v * v], -1)  # (K, S, 3) lift per unit b
    d = (p2 - p1) / np.hypot(*(p2 - p1).T)[:, None]
    nrm = np.stack([-d[:, 1], d[:, 0]], 1)
    # a point lifted by z along n images d(P[:2] / P[2]) = (n[:2] - p n[2]) z / P[2] away
    across = np.einsum("ksj,kj->ks", (n[:2] - p * n[2]) / P[..., 2:3], nrm)[..., None] * basis  # (K, S, 3)
    along = np.einsum("ksj,kj->ks", p - p.mean(1, keepdims=True), d)
    G = np.einsum("ks,ksj->kj", along, across) / np.sum(along**2, 1)[:, None]  # the fitted line's turn
    # each line's move across itself where it passes the vertex, and the intersection's move
    at_vertex = np.einsum("kj,kj->k", x - p.mean(1), d)
    shift = across.mean(1) + G * at_vertex[:, None]
    w = 1.0 / (np.asarray(offset_sigma, float) ** 2 + (at_vertex * np.asarray(angle_sigma, float)) ** 2)
    A = np.einsum("k,ki,kj->ij", w, nrm, nrm)
    X = np.linalg.solve(A, np.einsum("k,ki,kj->ij", w, nrm, shift))
    return G, X


def bend_covariance(R_cam_from_target, vertex, spoke_angles, angles, sigma, p1, p2, offset_sigma,
                    sigma_error=None):
    """The rotation's covariance from the sheet's bend, estimated from the lines' residuals.

    R_cam_from_target: (3, 3) the fit; vertex: (2,) normalised; spoke_angles, angles,
    sigma: (K,) [rad] the lines' target angles, image angles (normalised) and the sds the
    fit weighted them by; p1, p2: (K, 2) their end points (normalised); offset_sigma: (K,)
    [normalised]; sigma_error: (K,) [rad] or None, the sds of the lines' errors where wider
    than sigma (`pencil_covariance`'s).

    The bend the residuals show, b_hat (3,), has under the lines' noise alone a covariance
    V (the bend's directions that a turn of the plane absorbs are poorly seen: V is wide
    there); its chi2 q = b_hat^T V^-1 b_hat is chi-square(3) on a flat sheet. The bend's
    variance beyond what that noise explains, tau^2 = max(0, q - BEND_CHANCE) / tr(V^-1 S)
    (the method of moments for b_hat ~ N(0, V + tau^2 S), E q = 3 + tau^2 tr(V^-1 S), with
    the noise's 95 % quantile in place of its mean), is carried into the rotation through
    the fit's response to b, M = H^-1 J^T W G: the normal's spread over bends of that size
    in any direction.

    The misfit the bend leaves, the residuals less the bend's fit to them (G_p b_hat), has
    chi2 on K - 6 degrees of freedom: per degree of freedom it is the factor by which the
    lines' errors exceed their sds, every line alike (scale, at least 1; to multiply the
    variances of sigma_error). The bend is told from that noise: q / scale against the
    chance quantile, and V scale times wider (tau^2 = max(0, q / scale - BEND_CHANCE) scale /
    tr(V^-1 S)); q itself is reported against the lines' own sds.

    Returns (cov (3, 3) [rad^2] to add to the rotation's covariance (left perturbation),
    q, tau2, scale, M (3, 3): the rotation's move per unit b, cov = tau2 M S M^T). Zeros, q
    None and scale 1 where the lines cannot tell a bend (fewer than 7 lines, or a bend no
    turn of theirs tells from a tilt).
    """
    R = np.asarray(R_cam_from_target, float)
    x = np.asarray(vertex, float)
    a = np.asarray(angles, float)
    s = np.asarray(sigma, float)
    se = s if sigma_error is None else np.asarray(sigma_error, float)
    if a.size < 7:  # 3 for the turn, 3 for the bend, one to tell them from noise
        return np.zeros((3, 3)), None, 0.0, 1.0, np.zeros((3, 3))
    alpha, J, Jx = pencil_jacobian(R, x, np.asarray(spoke_angles, float))
    r = wrap_line(a - alpha)  # residuals, the line's direction either way
    G, X = bend_response(R, x, p1, p2, s, offset_sigma)
    G = G - Jx @ X  # the residual's change: the line turned, the prediction moved with the vertex
    w = 1.0 / s**2
    HiJW = np.linalg.solve(J.T @ (J * w[:, None]), J.T * w)  # the fit's turn per residual (3, K)
    Gp = G - J @ (HiJW @ G)  # what of the bend the fit leaves in the residuals
    we = 1.0 / se**2
    F = Gp.T @ (Gp * we[:, None])
    if np.linalg.cond(F) > 1e12:
        return np.zeros((3, 3)), None, 0.0, 1.0, np.zeros((3, 3))
    A = np.linalg.solve(F, Gp.T * we)  # b_hat = A r
    AP = A - (A @ J) @ HiJW  # the residual maker applied first: the noise b_hat sees
    V = (AP * se**2) @ AP.T
    b = A @ r
    # the misfit the bend's fit leaves: the lines' errors wider than their sds (every line
    # alike), the noise the bend is then told from
    scale = max(1.0, float(np.sum(((r - Gp @ b) / se) ** 2)) / (a.size - 6))
    q = float(b @ np.linalg.solve(V, b))
    tau2 = max(0.0, q / scale - BEND_CHANCE) * scale / float(np.trace(np.linalg.solve(V, CYLINDER_SHAPE)))
    M = HiJW @ G
    return tau2 * M @ CYLINDER_SHAPE @ M.T, q, tau2, scale, M


def circle_bend_response(R_cam_from_target, vertex, radii, weights=None, samples=72, h=1e-3):
    """How a bend of the sheet moves the circles' normal (the poles' polars of their images,
    `circle.conic_normal`): a bend lifts a circle about the vertex by rho^2 / 2 (b1 c^2 +
    2 b2 c s + b3 s^2), a lift that varies twice round it, and its image is the ellipse of a
    circle on a plane tilted otherwise, where the lines' normal, spokes all round, hardly moves.

    R_cam_from_target: (3, 3) the fitted plane; vertex: (2,) normalised; radii: (C,) the
    circles' radii on the plane [units of the vertex's depth]; weights: (C,) or None, how
    much each circle counts in their normal (equal without). Each circle's image is fitted
    flat and lifted by +-h per component of b (`samples` points, no noise).

    Returns (3, 3): the circles' normal's change (camera frame) per unit b.
    """
    R = np.asarray(R_cam_from_target, float)
    x = np.asarray(vertex, float)
    n = R[:, 2]
    rho = np.asarray(radii, float).reshape(-1)
    w = np.ones(rho.size) if weights is None else np.asarray(weights, float).reshape(-1)
    phi = np.linspace(0.0, 2 * np.pi, samples, endpoint=False)
    out = np.zeros((3, 3))
    for r, wc in zip(rho, w / w.sum()):
        u, v = r * np.cos(phi), r * np.sin(phi)
        flat = np.append(x, 1.0)[:, None] + R[:, :2] @ np.stack([u, v])  # (3, S)
        for j, lift in enumerate((0.5 * u * u, u * v, 0.5 * v * v)):
            moved = []
            for sgn in (1.0, -1.0):
                P = flat + np.outer(n, sgn * h * lift)
                m = conic_normal(fit_ellipse((P[:2] / P[2]).T).conic, x)[0]
                moved.append(m if m @ n > 0 else -m)
            out[:, j] += wc * (moved[0] - moved[1]) / (2 * h)
    return out
