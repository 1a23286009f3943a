"""The book chapter's forward models (eqs. 6-9) in atan2 form, their fits, and ellipse facts.

docs/method.md ("The chapter's models") restates the chapter; this module fixes the
conventions it leaves unsaid so that its general model *equals* exact projection (pencil.image_angles) to ~1e-12 deg.

Geometry (camera frame: x right, y down, z forward; image angle = atan2(dv, du) in
normalised coordinates; spoke k along (cos theta_k, sin theta_k, 0) in the target frame;
n = R_cam_from_target[:, 2] points away from the camera; v_d = unit(x_d, y_d, 1) is the
viewing ray of the vertex imaged at x_d). Let T be the plane through v_d orthogonal to it
(the plane tangent to the viewing sphere at v_d). A spoke d through the vertex images as

    w = d_xy - x_d d_z  =  (d - (d_z / v_dz) v_d)_xy

i.e. the image direction is the projection of d *along v_d* onto the image plane. Both the
pencil plane and the image plane therefore map to T by orthogonal projection along v_d,
which keeps lengths along the line where each plane meets T and scales the perpendicular
ones by the cosine of the angle between the planes. That gives the chapter's two steps:

1. pencil plane -> T:  tilt gamma_r, cos(gamma_r) = n . v_d (atan2 form below);
   axis u_r = unit(v_d x n) (in both planes); theta_r = angle of the spoke from u_r,
   positive about +n (right-handed), i.e. theta_r = theta_k - theta_offset with
   theta_offset the target-frame angle of u_r. Its projection in T makes the angle
   phi = atan2(sin theta_r cos gamma_r, cos theta_r) with u_r, positive about +v_d.
2. T -> image plane: tilt gamma_i, cos(gamma_i) = v_d . z; axis u_i = unit(z x v_d) (it
   lies in the image plane, with image angle psi_i); theta_i = image angle from u_i,
   positive about +z (the image-angle sense, atan2(dv, du)). With delta the SIGNED angle
   from u_r to u_i about +v_d, the angle from u_i in T is phi - delta, and
   theta_i = atan2(sin(phi - delta), cos(phi - delta) cos gamma_i),
   i.e. tan theta_i = tan(phi - delta) / cos(gamma_i)   (the chapter's eqs. 7-9 combined).
   The image angle of the spoke is a = psi_i + theta_i.

Both maps preserve orientation (cos gamma_i > 0 always; cos gamma_r > 0 when the pencil
faces the camera), so the atan2 form reproduces *oriented* spoke directions, and stays
exact for gamma_r >= 90 deg (pencil seen from behind) too. Turning delta's sign gives
errors up to ~90 deg; dropping step 2 (`shortcut=True`) errs by up to
atan(1/sqrt(cos gamma_i)) - atan(sqrt(cos gamma_i)) (1.78 deg at 20 deg off axis).

Degenerate cases (explicit conventions; the angles stay exact):
- vertex on the optical axis (x_d = 0): gamma_i = 0 and u_i := camera +x (psi_i = 0);
- frontal pencil (n parallel to v_d, |v_d x n| <= 1e-14): u_r := u_i (delta = 0).

The *aligned* model (eq. 6) is step 1 alone with v_d = z: exact when the vertex is on the
optical axis, wrong elsewhere when its tilt is measured from the image plane
(`image_angles_aligned`).

Everything is radians. Forward models broadcast over leading dimensions; the fits take a
single problem, (N,) angles.

Example
-------
>>> import numpy as np
>>> from pencilcal.toolkit.pencil.spec import image_angles
>>> from pencilcal.toolkit.geometry.frames import rotation_from_rotvec, rotation_angle
>>> R = rotation_from_rotvec([0.5, -0.3, 0.2])
>>> th = np.radians(np.arange(0, 180, 20))
>>> exact = image_angles(R, [0.3, -0.2], th)
>>> bool(np.allclose(image_angles_general(R, [0.3, -0.2], th), exact, atol=1e-13))
True
>>> fit = fit_general(exact, th, [0.3, -0.2])
>>> err = [rotation_angle(fit[k], R) for k in ("R_cam_from_target", "R_cam_from_target_twin")]
>>> bool(min(err) < 1e-12)
True
"""
from __future__ import annotations

import numpy as np
from scipy.optimize import least_squares

from pencilcal.toolkit.geometry.angles import wrap_angle, wrap_line
from pencilcal.toolkit.errors import EstimationError, InputError
from pencilcal.toolkit.geometry.frames import normalize, rotation_about_axis
from pencilcal.toolkit.geometry.projective import pencil_homography

__all__ = [
    "aligned_angles",
    "general_angles",
    "viewing_ray",
    "general_parameters",
    "rotation_from_general",
    "image_angles_general",
    "aligned_parameters",
    "rotation_from_aligned",
    "image_angles_aligned",
    "fit_aligned",
    "fit_general",
    "perspective_circle_eccentricity",
    "projected_circle_ellipse",
]

# Below _TINY the axis z x v_d (or z x n) is undefined (vertex exactly on the optical axis,
# normal exactly along z): the documented convention applies. Those cross products are
# formed from exact components, so above it they are accurate to rounding. v_d x n is
# formed by subtraction: below _FRONTAL its direction is rounding noise.
_TINY = 1e-300
_FRONTAL = 1e-14
_LSQ_TOL = dict(xtol=1e-15, ftol=1e-15, gtol=1e-15)


# --------------------------------------------------------------------------- forward models
def aligned_angles(theta, gamma):
    """Eq. 6 in atan2 form: alpha = atan2(sin theta cos gamma, cos theta).

    tan(alpha) = tan(theta) cos(gamma), with theta (in the tilted plane) and alpha (in the
    reference plane) both measured from the rotation axis, positive in the same sense.
    Orientation-preserving for |gamma| < 90 deg; no singularity at theta = 90 deg.
    theta, gamma: broadcastable [rad]. Returns their broadcast shape [rad].

    >>> import numpy as np
    >>> round(float(np.degrees(aligned_angles(np.radians(90.0), np.radians(60.0)))), 12)
    90.0
    >>> round(float(np.degrees(aligned_angles(np.radians(45.0), np.radians(60.0)))), 9)
    26.565051177
    """
    theta = np.asarray(theta, dtype=float)
    return np.arctan2(np.sin(theta) * np.cos(gamma), np.cos(theta))


def general_angles(theta_r, gamma_r, delta, gamma_i, shortcut=False):
    """Chapter eqs. 7-9 in atan2 form: image angle theta_i from the image axis u_i.

        phi     = atan2(sin theta_r cos gamma_r, cos theta_r)        (pencil plane -> T)
        theta_i = atan2(sin(phi - delta), cos(phi - delta) cos gamma_i)     (T -> image)

    theta_r: spoke angle from u_r, positive about +n; gamma_r: tilt of the pencil against
    T (the plane orthogonal to the vertex ray); delta: signed angle from u_r to u_i about
    +v_d; gamma_i: angle between the vertex ray and the optical axis. All [rad],
    broadcastable. With ``shortcut=True`` the gamma_i step is dropped
    (theta_i = phi - delta): the chapter read literally, wrong off-axis (for demos/tests).
    Returns theta_i [rad], in (-pi, pi].
    """
    phi = aligned_angles(theta_r, gamma_r)
    x = phi - np.asarray(delta, dtype=float)
    if shortcut:
        return wrap_angle(x)
    return np.arctan2(np.sin(x), np.cos(x) * np.cos(gamma_i))


def viewing_ray(vertex):
    """Unit viewing ray v_d = unit(x, y, 1) of a vertex in normalised image coordinates.

    vertex: (..., 2). Returns (..., 3).
    """
    x = np.asarray(vertex, dtype=float)
    return normalize(np.concatenate([x, np.ones(x.shape[:-1] + (1,))], -1))


def _image_axis(vertex):
    """gamma_i, u_i (..., 3) and psi_i for vertices (..., 2) (u_i := +x on the axis)."""
    x = np.asarray(vertex, dtype=float)
    h = np.hypot(x[..., 0], x[..., 1])
    ok = h > _TINY
    hs = np.where(ok, h, 1.0)
    u = np.stack([np.where(ok, -x[..., 1] / hs, 1.0), np.where(ok, x[..., 0] / hs, 0.0), np.zeros_like(h)], -1)
    gamma_i = np.arctan2(h, 1.0)  # angle between (x, y, 1) and z
    psi_i = np.arctan2(u[..., 1], u[..., 0])
    return gamma_i, u, psi_i


def general_parameters(R_cam_from_target, vertex):
    """The chapter's parameters of a pose, with the conventions of this module.

    R_cam_from_target: (..., 3, 3); vertex: (..., 2) normalised image of the vertex.
    Returns a dict of arrays (shapes (...) unless noted), angles in radians:

    - ``ray`` (..., 3): v_d;  ``normal`` (..., 3): n = R[:, 2];
    - ``gamma_i``: angle between v_d and the optical axis (image plane vs T);
    - ``axis_image`` (..., 3): u_i = unit(z x v_d) (camera +x if the vertex is on the axis);
    - ``psi_i``: image angle of u_i;
    - ``gamma_r``: angle between n and v_d (pencil plane vs T; the tilt reported as
      ``tilt_deg``), in [0, pi]; > pi/2 means the pencil is seen from behind;
    - ``axis_pencil`` (..., 3): u_r = unit(v_d x n) (u_i if the pencil is frontal);
    - ``theta_offset``: target-frame angle of u_r, so theta_r = theta_k - theta_offset;
    - ``delta``: signed angle from u_r to u_i about +v_d, in (-pi, pi].

    Then ``image_angles(R, vertex, th) == psi_i + general_angles(th - theta_offset,
    gamma_r, delta, gamma_i)`` (wrapped), and ``rotation_from_general(vertex, gamma_r,
    delta, theta_offset)`` gives R back.
    """
    R = np.asarray(R_cam_from_target, dtype=float)
    x = np.asarray(vertex, dtype=float)
    v = viewing_ray(x)
    n = R[..., :, 2]
    gamma_i, u_i, psi_i = _image_axis(x)
    c = np.cross(v, n)
    c = c - np.sum(c * v, -1, keepdims=True) * v  # exactly in T even when n ~ v (rounding)
    s = np.linalg.norm(c, axis=-1)
    gamma_r = np.arctan2(s, np.sum(n * v, -1))
    # below _FRONTAL the direction of v x n is rounding noise: frontal convention u_r := u_i
    # (the angles do not depend on u_r to O(gamma_r^2); the pose to O(gamma_r))
    ok = (s > _FRONTAL)[..., None]
    u_r = np.where(ok, c / np.where(ok, s[..., None], 1.0), u_i)
    ut = np.einsum("...ji,...j->...i", R, u_r)  # R^T u_r, in the target plane
    theta_offset = np.arctan2(ut[..., 1], ut[..., 0])
    delta = np.arctan2(np.sum(np.cross(u_r, u_i) * v, -1), np.sum(u_r * u_i, -1))
    return {
        "ray": v,
        "normal": n,
        "gamma_i": gamma_i,
        "axis_image": u_i,
        "psi_i": psi_i,
        "gamma_r": gamma_r,
        "axis_pencil": u_r,
        "theta_offset": theta_offset,
        "delta": delta,
    }


def _rz(angle):
    return rotation_about_axis(np.array([0.0, 0.0, 1.0]), np.asarray(angle, dtype=float))


def rotation_from_general(vertex, gamma_r, delta, theta_offset):
    """R_cam_from_target from the chapter's parameters (inverse of `general_parameters`).

    vertex: (..., 2); gamma_r, delta, theta_offset: (...) [rad]. u_r = Rot(v_d, -delta) u_i,
    n = Rot(u_r, gamma_r) v_d, and R maps the target direction at theta_offset to u_r and
    target z to n. gamma_r -> -gamma_r gives the twin (frames.twin_rotation about v_d),
    which images every spoke identically. Returns (..., 3, 3).
    """
    x = np.asarray(vertex, dtype=float)
    v = viewing_ray(x)
    _, u_i, _ = _image_axis(x)
    u_r = np.einsum("...ij,...j->...i", rotation_about_axis(v, -np.asarray(delta, dtype=float)), u_i)
    n = np.einsum("...ij,...j->...i", rotation_about_axis(u_r, np.asarray(gamma_r, dtype=float)), v)
    B = np.stack([u_r, np.cross(n, u_r), n], -1)
    return B @ _rz(-np.asarray(theta_offset, dtype=float))


def image_angles_general(R_cam_from_target, vertex, angles, shortcut=False):
    """Image angles from the chapter's general model (eqs. 7-9) at the parameters of a pose.

    R_cam_from_target: (..., 3, 3); vertex: (..., 2) normalised; angles: (..., N) [rad].
    Returns (..., N) [rad], oriented, equal to pencil.image_angles to ~1e-12 deg.
    ``shortcut=True`` drops the gamma_i step (the error is at most
    ``estimator.max_angular_change(gamma_i)``, 1.78 deg at 20 deg off axis).
    """
    p = general_parameters(R_cam_from_target, vertex)
    th = np.asarray(angles, dtype=float)
    e = (lambda k: p[k][..., None])
    ti = general_angles(th - e("theta_offset"), e("gamma_r"), e("delta"), e("gamma_i"), shortcut)
    return wrap_angle(e("psi_i") + ti)


def aligned_parameters(R_cam_from_target):
    """Parameters of eq. 6 applied directly in the image (tilt measured from the image plane).

    R_cam_from_target: (..., 3, 3). Returns a dict: ``gamma`` = angle between n and the
    optical axis, ``axis`` (..., 3) = unit(z x n) (camera +x if n is along z), ``psi`` its
    image angle, ``theta_offset`` its target-frame angle. Exact only when the vertex lies
    on the optical axis.
    """
    R = np.asarray(R_cam_from_target, dtype=float)
    n = R[..., :, 2]
    h = np.hypot(n[..., 0], n[..., 1])
    ok = h > _TINY
    hs = np.where(ok, h, 1.0)
    u = np.stack([np.where(ok, -n[..., 1] / hs, 1.0), np.where(ok, n[..., 0] / hs, 0.0), np.zeros_like(h)], -1)
    ut = np.einsum("...ji,...j->...i", R, u)
    return {
        "gamma": np.arctan2(h, n[..., 2]),
        "axis": u,
        "psi": np.arctan2(u[..., 1], u[..., 0]),
        "theta_offset": np.arctan2(ut[..., 1], ut[..., 0]),
    }


def rotation_from_aligned(gamma, psi, theta_offset):
    """R = Rz(psi) Rx(gamma) Rz(-theta_offset): the aligned model's pose (vertex on the axis).

    gamma, psi, theta_offset: (...) [rad]. -gamma gives the twin
    Rot(z, pi) R Rot(z, pi). Returns (..., 3, 3).
    """
    g = np.asarray(gamma, dtype=float)
    rx = rotation_about_axis(np.array([1.0, 0.0, 0.0]), g)
    return _rz(psi) @ rx @ _rz(-np.asarray(theta_offset, dtype=float))


def image_angles_aligned(R_cam_from_target, angles):
    """Eq. 6 applied in the image with the tilt measured from the image plane.

    a_k = psi + aligned_angles(theta_k - theta_offset, gamma) with `aligned_parameters`.
    It ignores where the vertex is: exact for a vertex on the optical axis, wrong off axis
    (3.6 deg for a pencil facing a vertex 20 deg off axis, up to 19.7 deg at 40 deg tilt;
    see tests). R: (..., 3, 3); angles: (..., N) [rad]. Returns (..., N) [rad].
    """
    p = aligned_parameters(R_cam_from_target)
    th = np.asarray(angles, dtype=float)
    return wrap_angle(p["psi"][..., None] + aligned_angles(th - p["theta_offset"][..., None], p["gamma"][..., None]))


# --------------------------------------------------------------------------------- fitting
def _check_fit_input(line_angles, spoke_angles, weights, name):
    a = np.asarray(line_angles, dtype=float)
    th = np.asarray(spoke_angles, dtype=float)
    if a.ndim != 1 or th.shape != a.shape:
        raise InputError(f"{name}: line and spoke angles must be two 1-D arrays of the same length, got {a.shape} and {th.shape}")
    if not (np.all(np.isfinite(a)) and np.all(np.isfinite(th))):
        raise InputError(f"{name}: line or spoke angles contain NaN or infinity")
    if a.size < 3:
        raise EstimationError(f"{name}: needs at least three lines, got {a.size}")
    if weights is None:
        w = np.ones_like(a)
    else:
        w = np.asarray(weights, dtype=float)
        if w.shape != a.shape or not np.all(np.isfinite(w)) or np.any(w < 0):
            raise InputError(f"{name}: weights must be {a.shape[0]} finite values >= 0")
    return a, th, w


def _decompose(H):
    """H ~ Rot(A) diag(1, c) Rot(-B) with proper rotations; returns (gamma, A, B), c = cos gamma."""
    U, s, Vt = np.linalg.svd(H)
    s = s.copy()
    if np.linalg.det(U) < 0:
        U[:, 1] *= -1.0
        s[1] *= -1.0
    if np.linalg.det(Vt) < 0:
        Vt[1, :] *= -1.0
        s[1] *= -1.0
    c = np.clip(s[1] / s[0], -1.0, 1.0)
    return float(np.arccos(c)), float(np.arctan2(U[1, 0], U[0, 0])), float(-np.arctan2(Vt[1, 0], Vt[0, 0]))


def _lsq(fun, x0, sw):
    res = least_squares(lambda p: sw * wrap_line(fun(p)), np.asarray(x0, float), method="lm", **_LSQ_TOL)
    return res


def _fit_summary(a, pred, resid, res):
    """Keys shared by the fit results: predictions, residuals, solver status."""
    return {
        "predicted": wrap_angle(pred),
        "residuals": resid,
        "rms": float(np.sqrt(np.mean(resid**2))),
        "oriented_consistent": bool(np.all(np.abs(wrap_angle(a - pred)) < np.pi / 2)),
        "success": bool(res.success),
        "nfev": int(res.nfev),
    }


def fit_aligned(line_angles, spoke_angles, weights=None):
    """Fit eq. 6 directly in the image: a_k = psi + aligned_angles(theta_k - theta_offset, gamma).

    This is the chapter's aligned-centre model with the tilt measured from the image plane,
    i.e. as if the vertex were on the optical axis (exact there, biased elsewhere; use
    `fit_general` or the exact estimator off axis).

    line_angles: (N,) image angles [rad] (lines or oriented directions), N >= 3;
    spoke_angles: (N,) 3D angles theta_k [rad]; weights: (N,) e.g. 1/sigma_k^2.
    Start: DLT of the 1-D homography, H ~ Rot(psi) diag(1, cos gamma) Rot(-theta_offset)
    (exact for noise-free data, so the fit is global); refined by Levenberg-Marquardt on
    wrapped line residuals (period pi).

    Returns a dict (radians):
    ``gamma`` in [0, pi] (its sign is not observable: ``gamma_sign_ambiguous`` is True and
    the two signs are the two twins), ``psi``, ``theta_offset``,
    ``R_cam_from_target`` = Rz(psi) Rx(gamma) Rz(-theta_offset) (vertex on the optical
    axis), ``R_cam_from_target_twin`` (gamma -> -gamma), ``normal``, ``normal_twin``,
    ``residuals`` (N,) = wrap_line(observed - predicted), ``rms``, ``predicted`` (N,)
    oriented, ``oriented_consistent`` (every |oriented residual| < 90 deg: the inputs look
    like oriented directions and R reproduces them; otherwise R and R Rz(pi) fit equally),
    ``choice`` (why the primary is primary), ``success``, ``nfev``, ``model``.

    >>> import numpy as np
    >>> th = np.radians([0, 40, 80, 120])
    >>> a = 0.3 + aligned_angles(th - 0.2, np.radians(35))
    >>> round(float(np.degrees(fit_aligned(a, th)["gamma"])), 9)
    35.0
    """
    a, th, w = _check_fit_input(line_angles, spoke_angles, weights, "fit_aligned")
    g0, psi0, t00 = _decompose(pencil_homography(a, th, w))

    def model(p):
        return p[1] + aligned_angles(th - p[2], p[0])

    res = _lsq(lambda p: model(p) - a, [g0, psi0, t00], np.sqrt(w))
    g, psi, t0 = res.x
    gamma = float(np.arccos(np.clip(np.cos(g), -1.0, 1.0)))
    pred = model([gamma, psi, t0])
    if np.sum(w * np.cos(pred - a)) < 0:  # oriented branch: turn the in-plane offset by pi
        t0 += np.pi
        pred = model([gamma, psi, t0])
    psi, t0 = float(wrap_angle(psi)), float(wrap_angle(t0))
    R = rotation_from_aligned(gamma, psi, t0)
    Rt = rotation_from_aligned(-gamma, psi, t0)
    resid = wrap_line(a - pred)
    return {
        "model": "aligned",
        "gamma": gamma,
        "gamma_sign_ambiguous": True,
        "psi": psi,
        "theta_offset": t0,
        "R_cam_from_target": R,
        "R_cam_from_target_twin": Rt,
        "normal": R[:, 2],
        "normal_twin": Rt[:, 2],
        "choice": "arbitrary: line angles cannot tell the twins apart; primary has gamma >= 0 in Rz(psi) Rx(gamma) Rz(-theta_offset)",
        **_fit_summary(a, pred, resid, res),
    }


def fit_general(line_angles, spoke_angles, vertex, weights=None):
    """Fit the chapter's general model (eqs. 7-9) with the vertex image known.

    Unknowns: gamma_r (tilt against the vertex ray), delta (signed angle from u_r to u_i
    about v_d; fitted, never assumed) and theta_offset (in-plane offset); gamma_i and u_i
    follow from the vertex. line_angles, spoke_angles: (N,) [rad], N >= 3;
    vertex: (2,) normalised image coordinates; weights: (N,) e.g. 1/sigma_k^2.

    Start: undo the gamma_i step (phi'_k = atan2(sin(a_k - psi_i) cos gamma_i,
    cos(a_k - psi_i)), the angles in the plane T orthogonal to the ray), then the DLT of
    phi' ~ Rot(-delta) diag(1, cos gamma_r) Rot(-theta_offset) theta: exact for noise-free
    data, so the fit converges globally. Refined by Levenberg-Marquardt on wrapped line
    residuals of the full model.

    Returns a dict (radians): ``gamma_r``, ``delta``, ``theta_offset`` (of the primary),
    ``gamma_i``, ``psi_i``, ``ray``, ``R_cam_from_target`` and ``R_cam_from_target_twin``
    (= Rot(v_d, pi) R Rot(z, pi), gamma_r -> -gamma_r), ``normal``, ``normal_twin``,
    ``parameters`` and ``parameters_twin`` (`general_parameters` of both), ``choice``
    (the primary is the twin whose normal is closer to the optical axis: an arbitrary,
    deterministic rule, since the lines cannot tell them apart), ``predicted``,
    ``residuals`` = wrap_line(observed - predicted), ``rms``, ``oriented_consistent``,
    ``success``, ``nfev``, ``model``.
    """
    a, th, w = _check_fit_input(line_angles, spoke_angles, weights, "fit_general")
    x = np.asarray(vertex, dtype=float)
    if x.shape != (2,) or not np.all(np.isfinite(x)):
        raise InputError(f"fit_general: vertex must be 2 finite normalised coordinates, got {vertex!r}")
    gamma_i, _, psi_i = _image_axis(x)
    gamma_i, psi_i = float(gamma_i), float(psi_i)
    phi_t = aligned_angles(a - psi_i, gamma_i)  # inverse of the T -> image step
    g0, A0, B0 = _decompose(pencil_homography(phi_t, th, w))

    def model(p):
        return psi_i + general_angles(th - p[2], p[0], p[1], gamma_i)

    res = _lsq(lambda p: model(p) - a, [g0, -A0, B0], np.sqrt(w))
    g, d, t0 = res.x
    gamma = float(np.arccos(np.clip(np.cos(g), -1.0, 1.0)))
    pred = model([gamma, d, t0])
    if np.sum(w * np.cos(pred - a)) < 0:
        t0 += np.pi
        pred = model([gamma, d, t0])
    R1 = rotation_from_general(x, gamma, d, t0)
    R2 = rotation_from_general(x, -gamma, d, t0)
    if R2[2, 2] > R1[2, 2]:
        R1, R2 = R2, R1
    p1 = general_parameters(R1, x)
    p2 = general_parameters(R2, x)
    resid = wrap_line(a - pred)
    return {
        "model": "general",
        "gamma_r": float(p1["gamma_r"]),
        "delta": float(p1["delta"]),
        "theta_offset": float(p1["theta_offset"]),
        "gamma_i": gamma_i,
        "psi_i": psi_i,
        "ray": p1["ray"],
        "R_cam_from_target": R1,
        "R_cam_from_target_twin": R2,
        "normal": R1[:, 2],
        "normal_twin": R2[:, 2],
        "parameters": p1,
        "parameters_twin": p2,
        "choice": "arbitrary: line angles cannot tell the twins apart; primary is the normal closer to the optical axis",
        **_fit_summary(a, pred, resid, res),
    }


# -------------------------------------------------------------------------------- ellipses
def perspective_circle_eccentricity(gamma, rho):
    """Eccentricity of the image of a circle centred on the optical axis, full perspective.

    e = sin(g) sqrt((1 - rho^2) / (1 - rho^2 sin^2 g)), rho = radius / depth of the centre,
    g = tilt of the circle's plane against the image plane. Weak perspective (rho -> 0)
    gives the chapter's e = sin(g). gamma, rho: broadcastable. rho = 0.5, g = 45 deg: 0.655.

    >>> import numpy as np
    >>> round(float(perspective_circle_eccentricity(np.radians(45.0), 0.5)), 3)
    0.655
    """
    s = np.sin(np.asarray(gamma, dtype=float))
    r2 = np.asarray(rho, dtype=float) ** 2
    return s * np.sqrt((1.0 - r2) / (1.0 - r2 * s * s))


def projected_circle_ellipse(center, normal, radius, K=None):
    """Exact image of a 3D circle: conic matrix, eccentricity, centre, axes.

    center: (..., 3) camera-frame centre P0 of the circle; normal: (..., 3) its plane's
    normal; radius: (...). K: optional 3x3 camera matrix (pixels; without it, normalised
    coordinates). The circle s^2 + t^2 = r^2 in an orthonormal in-plane basis (e1, e2)
    maps to the image by the plane homography G = [e1 e2 P0]; its image conic is
    C = G^-T diag(1, 1, -r^2) G^-1 (x^T C x = 0 for homogeneous image points x), then
    K^-T C K^-1 in pixels. Requires the whole circle in front of the camera (an ellipse).

    Returns a dict: ``conic`` (..., 3, 3) (unit Frobenius norm, 2x2 block positive
    definite), ``center`` (..., 2) ellipse centre = -M^-1 b, ``semi_axes`` (..., 2)
    (major, minor), ``major_angle`` (...) image angle of the major axis,
    ``eccentricity`` (...) = sqrt(1 - (minor/major)^2), ``vertex_image`` (..., 2) image of
    P0 (differs from ``center`` under perspective).
    """
    P0 = np.asarray(center, dtype=float)
    n = normalize(normal)
    r = np.asarray(radius, dtype=float)
    helper = np.where(np.abs(n[..., :1]) < 0.9, np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0]))
    e1 = normalize(np.cross(n, helper))
    e2 = np.cross(n, e1)
    G = np.stack([e1, e2, P0], -1)
    if K is not None:
        G = np.asarray(K, dtype=float) @ G
    if np.any(np.abs(np.linalg.det(G)) <= 1e-12 * np.linalg.norm(P0, axis=-1) * (1.0 if K is None else abs(np.linalg.det(K)))):
        raise EstimationError("projected_circle_ellipse: the circle's plane passes through the camera centre (it images as a line)")
    Gi = np.linalg.inv(G)
    Cc = np.zeros(np.shape(r) + (3, 3))
    Cc[..., 0, 0] = 1.0
    Cc[..., 1, 1] = 1.0
    Cc[..., 2, 2] = -(r**2)
    C = np.swapaxes(Gi, -1, -2) @ Cc @ Gi
    C = 0.5 * (C + np.swapaxes(C, -1, -2))
    M = C[..., :2, :2]
    sgn = np.where(np.linalg.det(M) > 0, np.sign(M[..., 0, 0]), np.nan)
    if np.any(np.isnan(sgn)):
        raise EstimationError("projected_circle_ellipse: the image of the circle is not an ellipse (circle crosses the camera's plane)")
    C = C * (sgn / np.linalg.norm(C, axis=(-2, -1)))[..., None, None]
    M = C[..., :2, :2]
    b = C[..., :2, 2]
    xc = -np.linalg.solve(M, b[..., None])[..., 0]
    f = C[..., 2, 2] + np.sum(b * xc, -1)  # value of the conic at the centre (< 0 inside)
    lam, vec = np.linalg.eigh(M)  # ascending: lam[0] -> major axis
    semi = np.sqrt(-f[..., None] / lam)
    major = vec[..., :, 0]
    pv = P0 if K is None else np.einsum("ij,...j->...i", np.asarray(K, dtype=float), P0)
    return {
        "conic": C,
        "center": xc,
        "semi_axes": semi,
        "major_angle": np.arctan2(major[..., 1], major[..., 0]),
        "eccentricity": np.sqrt(1.0 - lam[..., 0] / lam[..., 1]),
        "vertex_image": pv[..., :2] / pv[..., 2:3],
    }
