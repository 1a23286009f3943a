"""What the intrinsics' uncertainty does to a pencil's orientation and vertex (first order).

A pencil's lines are measured in raw pixels; the intrinsics turn them into normalised
lines (undistortion), and those give the vertex and the orientation. With the intrinsics
``theta`` uncertain (covariance C, `toolkit.camera.intrinsics`), every estimate y moves by
``G d_theta``: the line angles a and the vertex x by ``A = da/dtheta`` and
``X = dx/dtheta`` (central differences of the undistortion, each parameter stepped by
1e-3 of its own sigma; the vertex re-intersected from the same lines, or, when it was
given in raw pixels, undistorted again), and the fit, a weighted least-squares problem at
its optimum, by the implicit function theorem::

    d_rot = H^-1 J^T W (A - Jx X) d_theta          H = J^T W J

with J = d alpha / d delta and Jx = d alpha / dx the pencil's Jacobians at the estimate
(`estimator.pencil_jacobian`). The tilt (angle between the normal and the vertex ray)
moves with both d_rot and dx. The totals add ``G C G^T`` to the noise-only variances:
``tilt_sigma_total_deg``, ``normal_sigma_total_deg`` and ``vertex_cov_total_px2`` (raw
pixels, through the perturbed lens too).

Example
-------
>>> import numpy as np
>>> from pencilcal.toolkit.camera.model import Camera
>>> cam = Camera("opencv", 640, 480, [[500.0, 0, 319.5], [0, 500.0, 239.5], [0, 0, 1]], [-0.1, 0.01, 0, 0])
>>> steps = intrinsics_steps(np.diag([1.0, 1.0, 4.0, 4.0, 1e-4, 1e-6, 0, 0]))
>>> [j for j, _ in steps]
[0, 1, 2, 3, 4, 5]
"""
from __future__ import annotations

import numpy as np

from pencilcal.toolkit.camera.intrinsics import (camera_intrinsics_covariance, intrinsic_names, intrinsics_vector,
                                                 propagate, with_intrinsics)
from pencilcal.toolkit.errors import InputError
from pencilcal.toolkit.geometry.frames import rotation_from_rotvec
from pencilcal.toolkit.pencil.estimator import pencil_jacobian
from pencilcal.toolkit.pencil.vertex import intersect_lines

__all__ = ["intrinsics_steps", "perturbed_cameras", "line_sensitivity", "orientation_sensitivity", "tilt_of",
           "total_terms", "vertex_cov_total_px2", "resolve_intrinsics_cov", "orientation_totals",
           "ray_sigma_total_deg"]

# each intrinsic parameter is stepped by this fraction of its own sigma
_STEP_OF_SIGMA = 1e-3


def intrinsics_steps(cov):
    """[(j, h_j)]: the parameters with a positive variance in cov (P, P) and their steps,
    1e-3 of their sigma (held parameters, of zero variance, move nothing)."""
    sd = np.sqrt(np.clip(np.diag(np.asarray(cov, float)), 0.0, None))
    return [(j, _STEP_OF_SIGMA * float(s)) for j, s in enumerate(sd) if s > 0]


def perturbed_cameras(camera, steps):
    """[(j, h, camera_plus, camera_minus)] for `intrinsics_steps`' steps."""
    th = intrinsics_vector(camera)
    out = []
    for j, h in steps:
        e = np.zeros_like(th)
        e[j] = h
        out.append((j, h, with_intrinsics(camera, th + e), with_intrinsics(camera, th - e)))
    return out


def _normalised_angles(camera, segments, away):
    """Angles [rad] (K,) of raw segments (K, 4) in normalised coordinates, pointing along
    ``away`` (K,) of +-1 (from the first end point to the second, or back)."""
    p = camera.normalized_from_pixels(np.asarray(segments, float).reshape(-1, 2)).reshape(-1, 4)
    d = (p[:, 2:] - p[:, :2]) * np.asarray(away, float)[:, None]
    return np.arctan2(d[:, 1], d[:, 0])


def _vertex_of(camera, K_ref, through, st, sc, vertex_px):
    """The normalised vertex (2,) under `camera`: `vertex_px` undistorted, or the plain
    (not robust) intersection of the lines `through` (raw, (M, 4)) mapped to ideal pixels
    with the reference K_ref (so the sigmas st [rad], sc [px] keep their meaning)."""
    if vertex_px is not None:
        return camera.normalized_from_pixels(np.asarray(vertex_px, float))
    p = camera.normalized_from_pixels(np.asarray(through, float).reshape(-1, 2))
    ideal = (p @ K_ref[:2, :2].T + K_ref[:2, 2]).reshape(-1, 4)
    v = intersect_lines(ideal, angle_sigma=st, offset_sigma=sc, robust=False).vertex
    Kinv = np.linalg.inv(K_ref)
    return Kinv[:2, :2] @ v + Kinv[:2, 2]


def line_sensitivity(camera, cov, segments, away, through=None, st=None, sc=None, vertex_px=None):
    """(A (K, P), X (2, P)): d(line angle)/d(theta) [rad per unit] of the fitted segments and
    d(normalised vertex)/d(theta), by central differences.

    camera; cov (P, P): the intrinsics' covariance (which parameters move, and by how
    little); segments (K, 4) raw px: the lines of the fit, ``away`` (K,) +-1 their
    orientation; the vertex is `vertex_px` (raw px) undistorted when given, else the
    intersection of ``through`` (M, 4) raw px with angle sd st (M,) [rad] and offset sd
    sc (M,) [ideal px]. Columns of parameters that do not move are zero.
    """
    P = 4 + camera.dist.size
    seg = np.asarray(segments, float).reshape(-1, 4)
    A = np.zeros((seg.shape[0], P))
    X = np.zeros((2, P))
    K_ref = np.asarray(camera.K, float)
    for j, h, cp, cm in perturbed_cameras(camera, intrinsics_steps(cov)):
        da = _normalised_angles(cp, seg, away) - _normalised_angles(cm, seg, away)
        A[:, j] = np.angle(np.exp(1j * da)) / (2.0 * h)
        X[:, j] = (_vertex_of(cp, K_ref, through, st, sc, vertex_px)
                   - _vertex_of(cm, K_ref, through, st, sc, vertex_px)) / (2.0 * h)
    return A, X


def tilt_of(R, x):
    """Tilt [rad]: angle between the normal R[:, 2] (3, 3) and the ray of the vertex x (2,)."""
    v = np.r_[np.asarray(x, float), 1.0]
    return float(np.arccos(np.clip(R[:, 2] @ v / np.linalg.norm(v), -1.0, 1.0)))


def orientation_sensitivity(R, x, spoke_angles, sigma, A, X):
    """G_rot (3, P) and g_tilt (P,): d(rotation)/d(theta) [rad, left perturbation] and
    d(tilt)/d(theta) [rad] of a pencil fit at (R (3, 3), normalised vertex x (2,)), from
    its lines' spoke angles (K,) [rad], angle sd sigma (K,) [rad] and `line_sensitivity`'s
    A (K, P), X (2, P)."""
    _, J, Jx = pencil_jacobian(R, x, spoke_angles)
    w = 1.0 / np.asarray(sigma, float) ** 2
    H = J.T @ (J * w[:, None])
    G = np.linalg.solve(H, J.T @ (w[:, None] * (A - Jx @ X)))
    g = np.zeros(A.shape[1])
    for j in np.flatnonzero(np.any(G != 0, 0) | np.any(X != 0, 0)):
        # the tilt along this column, by a symmetric step of the linear map
        s = 1e-6 / max(float(np.linalg.norm(G[:, j])) + float(np.linalg.norm(X[:, j])), 1e-300)
        tp = tilt_of(rotation_from_rotvec(s * G[:, j]) @ R, x + s * X[:, j])
        tm = tilt_of(rotation_from_rotvec(-s * G[:, j]) @ R, x - s * X[:, j])
        g[j] = (tp - tm) / (2.0 * s)
    return G, g


def total_terms(camera, cov, R, x, G_rot, g_tilt, X, cov_rot, tilt_sigma_deg, vertex_cov_px2=None):
    """The orientation record's total keys: ``tilt_sigma_total_deg``, ``normal_sigma_total_deg``
    [deg], ``vertex_cov_total_px2`` (2, 2) [px^2] (None where the record has no raw vertex)
    and ``intrinsics_used`` (True).

    camera; cov (P, P) the intrinsics' covariance; R (3, 3), x (2,) the estimate; G_rot,
    g_tilt, X from `orientation_sensitivity` / `line_sensitivity`; cov_rot (3, 3) [rad^2] the
    noise-only rotation covariance; tilt_sigma_deg its tilt sigma; vertex_cov_px2 (2, 2) the
    noise-only raw vertex covariance or None.
    """
    C = np.asarray(cov, float)
    n = R[:, 2]
    Pn = np.eye(3) - np.outer(n, n)
    rot = np.asarray(cov_rot, float) + propagate(G_rot, C)
    var_tilt = np.radians(tilt_sigma_deg) ** 2 + float(g_tilt @ C @ g_tilt)
    out = {"tilt_sigma_total_deg": float(np.degrees(np.sqrt(max(var_tilt, 0.0)))),
           "normal_sigma_total_deg": float(np.degrees(np.sqrt(max(np.trace(Pn @ rot @ Pn), 0.0)))),
           "vertex_cov_total_px2": None, "intrinsics_used": True}
    if vertex_cov_px2 is not None:
        out["vertex_cov_total_px2"] = vertex_cov_total_px2(camera, C, x, X, vertex_cov_px2)
    return out


def vertex_cov_total_px2(camera, cov, x, X, vertex_cov_px2):
    """(2, 2) [px^2]: a raw vertex's noise-only covariance `vertex_cov_px2` plus the
    intrinsics' term; the raw vertex moves with its normalised position x (2,) (by X
    (2, P) per unit of theta) and with the lens that images it."""
    C = np.asarray(cov, float)
    Gv = np.zeros((2, C.shape[0]))
    for j, h, cp, cm in perturbed_cameras(camera, intrinsics_steps(C)):
        Gv[:, j] = (cp.pixels_from_normalized(x + h * X[:, j]) - cm.pixels_from_normalized(x - h * X[:, j])) / (2 * h)
    return np.asarray(vertex_cov_px2, float) + propagate(Gv, C)


def resolve_intrinsics_cov(camera, intrinsics_cov):
    """The intrinsics' covariance (P, P) to propagate, or None: ``"camera"`` takes the one
    the camera file's statistics carry (none: None), None none, else an
    `IntrinsicsCovariance` or a (P, P) array in `intrinsic_names` order."""
    if intrinsics_cov is None:
        return None
    if isinstance(intrinsics_cov, str):
        if intrinsics_cov != "camera":
            raise InputError(f"intrinsics_cov must be 'camera', None, or a covariance; got {intrinsics_cov!r}")
        c = camera_intrinsics_covariance(camera)
        return None if c is None else c.cov
    if hasattr(intrinsics_cov, "for_camera"):
        return intrinsics_cov.for_camera(camera)
    C = np.asarray(intrinsics_cov, float)
    P = len(intrinsic_names(camera))
    if C.shape != (P, P):
        raise InputError(f"the intrinsics' covariance must be {P} x {P} for this camera, got shape {C.shape}")
    return C


def _away(camera, segments, angles):
    """+-1 per raw segment (K, 4): whether the fit's line angle (K,) [rad] runs from its first
    end point to its second (+1) or back."""
    d = _normalised_angles(camera, segments, np.ones(len(angles))) - np.asarray(angles, float)
    return np.where(np.cos(d) >= 0, 1.0, -1.0)


def orientation_totals(camera, cov, R, x, cov_rot, tilt_sigma_deg, vertex_cov_px2, segments, angles, spoke_angles,
                       sigma, through=None, st=None, sc=None, vertex_px=None):
    """The total keys of one orientation (`total_terms`) from its fit and lines.

    camera; cov (P, P) the intrinsics' covariance; R (3, 3), x (2,) normalised vertex,
    cov_rot (3, 3) [rad^2], tilt_sigma_deg, vertex_cov_px2 (2, 2) or None: the estimate
    and its noise-only uncertainty; segments (K, 4) raw px, angles (K,) [rad], spoke_angles
    (K,) [rad], sigma (K,) [rad]: the lines of the fit (normalised angles and sds); the
    vertex as in `line_sensitivity` (through (M, 4), st, sc, or vertex_px).
    """
    away = _away(camera, segments, angles)
    A, X = line_sensitivity(camera, cov, segments, away, through, st, sc, vertex_px)
    G, g = orientation_sensitivity(R, x, spoke_angles, sigma, A, X)
    return total_terms(camera, cov, R, x, G, g, X, cov_rot, tilt_sigma_deg, vertex_cov_px2)


def ray_sigma_total_deg(camera, cov, x, cov_x, through, st, sc):
    """(ray sigma with the intrinsics [deg], X (2, P)): the RMS angle of the unit ray of a
    vertex x (2,) intersected from raw lines `through` (M, 4) (sds st [rad], sc [px]), with
    noise-only normalised covariance cov_x (2, 2), plus the intrinsics' term."""
    seg = np.asarray(through, float).reshape(-1, 4)
    _, X = line_sensitivity(camera, cov, seg[:1], np.ones(1), seg, st, sc)
    v = np.r_[np.asarray(x, float), 1.0]
    P = (np.eye(3) - np.outer(v, v) / (v @ v))[:, :2] / np.linalg.norm(v)
    total = np.asarray(cov_x, float) + propagate(X, np.asarray(cov, float))
    return float(np.degrees(np.sqrt(max(np.trace(P @ total @ P.T), 0.0)))), X
