"""Conics in the plane: an ellipse fitted to points, its distances and its uncertainty.

A conic is a symmetric 3x3 matrix C with ``x^T C x = 0`` for its points x = (u, v, 1): the
image of a circle is one (an ellipse, in undistorted pixels or normalised coordinates).
`fit_ellipse` is the direct least-squares ellipse (Fitzgibbon, Pilu and Fisher 1999, in the
numerically stable form of Halir and Flusser 1998) on centred, scaled points, refined by
Gauss-Newton on the Sampson distances (the first-order geometric distance of each point from
the conic); its covariance comes from the refinement's Jacobian and the points' scatter about
the fit (a-posteriori). Conics are defined up to scale: C is returned with unit Frobenius
norm and its covariance (6, 6) over the vector `conic_vector(C)` = (a, b, c, d, e, f) of
``a u^2 + b u v + c v^2 + d u + e v + f``, singular along C itself (the scale).

Example
-------
>>> t = np.linspace(0, 2 * np.pi, 40, endpoint=False)
>>> pts = np.stack([100 + 30 * np.cos(t), 50 + 20 * np.sin(t)], -1)
>>> fit = fit_ellipse(pts)
>>> np.round(ellipse_parameters(fit.conic)[:2], 6).tolist(), float(np.max(np.abs(fit.residuals))) < 1e-9
([[100.0, 50.0], [30.0, 20.0]], True)
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from pencilcal.toolkit.errors import EstimationError

__all__ = ["EllipseFit", "fit_ellipse", "conic_vector", "conic_matrix", "sampson_distances", "ellipse_parameters"]


class EllipseFit(NamedTuple):
    """An ellipse fitted to K points.

    conic: (3, 3) unit-norm symmetric matrix; cov: (6, 6) covariance of `conic_vector`
    (a-posteriori, from the points' scatter); residuals: (K,) Sampson distances of the
    points [their unit], signed; rms: their RMS (with K - 5 degrees of freedom).
    """

    conic: np.ndarray
    cov: np.ndarray
    residuals: np.ndarray
    rms: float


def conic_vector(C):
    """(..., 6) (a, b, c, d, e, f) of conics C (..., 3, 3): a u^2 + b uv + c v^2 + d u + e v + f."""
    C = np.asarray(C, float)
    return np.stack([C[..., 0, 0], 2 * C[..., 0, 1], C[..., 1, 1], 2 * C[..., 0, 2], 2 * C[..., 1, 2], C[..., 2, 2]], -1)


def conic_matrix(q):
    """(..., 3, 3) symmetric conic matrices of vectors q (..., 6) (`conic_vector`'s inverse)."""
    q = np.asarray(q, float)
    a, b, c, d, e, f = (q[..., i] for i in range(6))
    return np.stack([np.stack([a, b / 2, d / 2], -1), np.stack([b / 2, c, e / 2], -1),
                     np.stack([d / 2, e / 2, f], -1)], -2)


def _design(p):
    """(K, 6) rows (u^2, uv, v^2, u, v, 1) of points p (K, 2)."""
    u, v = p[:, 0], p[:, 1]
    return np.stack([u * u, u * v, v * v, u, v, np.ones_like(u)], -1)


def sampson_distances(C, points):
    """Signed first-order geometric distances (K,) of points (K, 2) from the conic C (3, 3):
    x^T C x / |gradient|, the gradient 2 (C x)[:2]."""
    p = np.asarray(points, float)
    x = np.concatenate([p, np.ones((p.shape[0], 1))], -1)
    Cx = x @ np.asarray(C, float)
    return np.sum(Cx * x, -1) / (2.0 * np.maximum(np.hypot(Cx[:, 0], Cx[:, 1]), 1e-300))


def _direct_ellipse(p):
    """The direct least-squares ellipse through points p (K, 2) (already centred and
    scaled), Halir and Flusser's form: the conic vector (6,), or None."""
    D = _design(p)
    D1, D2 = D[:, :3], D[:, 3:]
    S1, S2, S3 = D1.T @ D1, D1.T @ D2, D2.T @ D2
    try:
        T = -np.linalg.solve(S3, S2.T)
    except np.linalg.LinAlgError:
        return None
    M = S1 + S2 @ T
    M = np.array([M[2] / 2, -M[1], M[0] / 2])
    w, V = np.linalg.eig(M)
    V = np.real(V)
    cond = 4 * V[0] * V[2] - V[1] ** 2  # > 0 for the ellipse
    ok = np.flatnonzero(cond > 0)
    if ok.size == 0:
        return None
    a1 = V[:, ok[np.argmin(np.abs(np.real(w[ok])))]]
    return np.r_[a1, T @ a1]


def fit_ellipse(points, iterations=10):
    """The ellipse through points (K, 2), K >= 6: direct fit, then Gauss-Newton on the
    Sampson distances; an `EllipseFit`. EstimationError when the points fit no ellipse.
    """
    p = np.asarray(points, float).reshape(-1, 2)
    if p.shape[0] < 6:
        raise EstimationError(f"an ellipse needs at least 6 points, got {p.shape[0]}")
    # centred and scaled: the design matrix is then well conditioned
    m = p.mean(0)
    s = np.sqrt(2.0) / max(float(np.mean(np.hypot(*(p - m).T))), 1e-300)
    A = np.array([[s, 0, -s * m[0]], [0, s, -s * m[1]], [0, 0, 1.0]])  # x_n = A x
    pn = (p - m) * s
    q = _direct_ellipse(pn)
    if q is None:
        raise EstimationError("the points fit no ellipse")
    q /= np.linalg.norm(q)
    for _ in range(iterations):
        r, J = _sampson_jacobian(q, pn)
        # minimise |r|^2 over q on the sphere |q| = 1: a step in the tangent space
        P = np.eye(6) - np.outer(q, q)
        JP = J @ P
        step = -np.linalg.lstsq(JP, r, rcond=None)[0]
        q = q + P @ step
        q /= np.linalg.norm(q)
        if np.linalg.norm(P @ step) < 1e-12:
            break
    r, J = _sampson_jacobian(q, pn)
    Cn = conic_matrix(q)
    if 4 * Cn[0, 0] * Cn[1, 1] - (2 * Cn[0, 1]) ** 2 <= 0:
        raise EstimationError("the points fit no ellipse")
    dof = max(p.shape[0] - 5, 1)
    var = float(np.sum(r * r)) / dof
    P = np.eye(6) - np.outer(q, q)
    JP = J @ P
    cov_n = var * np.linalg.pinv(JP.T @ JP, rcond=1e-12, hermitian=True)
    # back to the points' own frame: C = A^T Cn A, a linear map of the vector q
    C = A.T @ Cn @ A
    L = np.stack([conic_vector(A.T @ conic_matrix(e) @ A) for e in np.eye(6)], -1)  # (6, 6)
    norm = np.linalg.norm(C)
    Cq = conic_vector(C) / norm
    # the unit-norm conic's Jacobian: (I - c c^T / |c|^2) / |c| with c = L q
    c = L @ q
    Jn = (np.eye(6) - np.outer(c, c) / (c @ c)) / np.linalg.norm(C) @ L
    cov = Jn @ cov_n @ Jn.T
    # the Sampson distances in the points' own unit
    res = sampson_distances(C / norm, p)
    return EllipseFit(conic_matrix(Cq), 0.5 * (cov + cov.T), res, float(np.sqrt(np.sum(res * res) / dof)))


def _sampson_jacobian(q, p):
    """Sampson distances r (K,) of points p (K, 2) from the conic vector q (6,) and their
    Jacobian (K, 6) by q."""
    D = _design(p)
    a, b, c, d, e, f = q
    u, v = p[:, 0], p[:, 1]
    gu, gv = 2 * a * u + b * v + d, b * u + 2 * c * v + e
    g = np.maximum(np.hypot(gu, gv), 1e-300)
    alg = D @ q
    r = alg / g
    # d g / d q: gu depends on (a, b, d) as (2u, v, 1), gv on (b, c, e) as (u, 2v, 1)
    dgu = np.stack([2 * u, v, np.zeros_like(u), np.ones_like(u), np.zeros_like(u), np.zeros_like(u)], -1)
    dgv = np.stack([np.zeros_like(u), u, 2 * v, np.zeros_like(u), np.ones_like(u), np.zeros_like(u)], -1)
    dg = (gu[:, None] * dgu + gv[:, None] * dgv) / g[:, None]
    J = D / g[:, None] - (alg / g**2)[:, None] * dg
    return r, J


def ellipse_parameters(C):
    """(centre (2,), semi-axes (2,) major first, angle [rad] of the major axis) of an
    ellipse's conic C (3, 3)."""
    C = np.asarray(C, float)
    A2 = C[:2, :2]
    centre = -np.linalg.solve(A2, C[:2, 2])
    k = -(centre @ C[:2, 2] + C[2, 2])
    w, V = np.linalg.eigh(A2 / k)
    axes = 1.0 / np.sqrt(np.maximum(w, 1e-300))
    major = int(np.argmax(axes))
    return centre, np.sort(axes)[::-1], float(np.arctan2(V[1, major], V[0, major]))
