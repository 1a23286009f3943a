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
"""
from __future__ import annotations

import numpy as np

from pencilcal.toolkit.geometry.angles import wrap_line
from pencilcal.toolkit.geometry.quantiles import chi2_isf
from pencilcal.toolkit.pencil.estimator import pencil_jacobian

__all__ = ["CYLINDER_SHAPE", "BEND_SAMPLES", "BEND_CHANCE", "bend_response", "bend_covariance"]

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

    Returns (cov (3, 3) [rad^2] to add to the rotation's covariance (left perturbation),
    q, tau2). Zeros where the lines cannot tell a bend (fewer than 7 lines).
    """
    R = np.asarray(R_cam_from_target, float)
    x = np.asarray(vertex, float)
    a = np.asarray(angles, float)
    s = np.asarray(sigma, float)
    se = s if sigma_error is None else np.asarray(sigma_error, float)
    if a.size < 7:  # 3 for the turn, 3 for the bend, one to tell them from noise
        return np.zeros((3, 3)), 0.0, 0.0
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
        return np.zeros((3, 3)), 0.0, 0.0
    A = np.linalg.solve(F, Gp.T * we)  # b_hat = A r
    AP = A - (A @ J) @ HiJW  # the residual maker applied first: the noise b_hat sees
    V = (AP * se**2) @ AP.T
    b = A @ r
    q = float(b @ np.linalg.solve(V, b))
    tau2 = max(0.0, q - BEND_CHANCE) / float(np.trace(np.linalg.solve(V, CYLINDER_SHAPE)))
    M = HiJW @ G
    return tau2 * M @ CYLINDER_SHAPE @ M.T, q, tau2
