"""Two lines with a known 3D angle: what the chapter's single-angle test can and cannot say.

Model (the chapter's eq. 6, aligned centre): a plane tilted by gamma about an axis in it
maps a line at angle theta from the axis to an image line at alpha from the image of the
axis, tan(alpha) = tan(theta) cos(gamma) (chapter.aligned_angles). It is exact under full
perspective when the vertex is on the optical axis. Off axis, first move every image angle
a into the plane orthogonal to the vertex ray, ``psi_i + chapter.aligned_angles(a - psi_i,
gamma_i)`` (chapter.general_parameters gives psi_i and gamma_i), and gamma below is then
the tilt against the ray.

Three situations (docs/method.md, "Two lines with a known angle"):

- ``axis="on_line"``: the image of the tilt axis is known and one line lies on it. alpha
  is the image angle of the other line from it, theta its 3D angle from the axis.
  cos(gamma) = tan(alpha) / tan(theta), with
  sd(gamma) = sigma (1 + cos^2 g tan^2 theta) / (tan theta sin g)  -> status "unique".
- ``axis="known"``: the axis image is known, neither line is on it, the in-plane offset
  is unknown. alpha = (alpha_1, alpha_2) from the axis image, theta = theta_2 - theta_1.
  With c = cos(gamma), t_j = tan(alpha_j), T = tan(theta): tan(theta_j) = t_j / c and
  tan(theta_2 - theta_1) = T give
      T c^2 + c (t_1 - t_2) + T t_1 t_2 = 0
  (solved in the trig-regular form sin(T) cos a1 cos a2 c^2 + cos(T) sin(a1 - a2) c
  + sin(T) sin a1 sin a2 = 0). Both roots in (0, 1] can be admissible: status
  "two_roots" (both returned) or "unique" (always when the lines straddle the axis: the
  product of the roots is t_1 t_2 < 0). c = 0 (edge-on; the spurious root when a line lies
  on the axis) is never admissible.
- ``axis="unknown"``: alpha = image angle between the lines, theta = their 3D angle. For a
  tilt gamma the image angle ranges, over the unknown offset, over
  [2 atan(cos g tan(theta/2)), 2 atan(tan(theta/2) / cos g)] (lines symmetric about the
  axis, resp. about its perpendicular), so the observation only says
      cos(gamma) <= min(r, 1/r),  r = tan(alpha/2) / tan(theta/2)
  -> status "lower_bound" with gamma_min = acos(min(r, 1/r)); any tilt up to 90 deg fits.

Measurements no tilt can produce give status "inconsistent" with the reason, never a
number. Angles are radians, lines (period pi): alpha and theta are reduced modulo pi, and
must be measured in the same rotation sense (image angles atan2(dv, du), 3D angles about
the normal pointing away from the camera; the map preserves orientation).

Example
-------
>>> import numpy as np
>>> r = single_angle_tilt(np.arctan(np.cos(np.radians(20))), np.radians(45), "on_line", sigma=np.radians(0.1))
>>> r.status, round(float(np.degrees(r.gamma[0])), 9), round(float(np.degrees(r.sigma[0])), 2)
('unique', 20.0, 0.55)
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pencilcal.toolkit.geometry.angles import wrap_line
from pencilcal.toolkit.errors import InputError

__all__ = ["SingleAngleResult", "single_angle_tilt", "image_angle_range"]

_EPS = 1e-12
# roots cos(gamma) below this (tilt within 6e-8 deg of 90) are the edge-on root c = 0
_EDGE_ON = 1e-9


@dataclass(frozen=True)
class SingleAngleResult:
    """Outcome of `single_angle_tilt`.

    status: "unique" | "two_roots" | "lower_bound" | "inconsistent".
    gamma: tilt values [rad]: one ("unique"), two ascending ("two_roots"), the lower bound
        ("lower_bound"; any tilt from it up to pi/2 fits), none ("inconsistent").
    sigma: standard deviation of each gamma value [rad] from the angle noise `sigma` given
        (NaN when none was given, inf where the tilt is not locally determined).
    message: one line saying what was found, or why no tilt fits.
    axis: the case that was solved ("on_line", "known", "unknown").
    """

    status: str
    gamma: tuple
    sigma: tuple
    message: str
    axis: str


def image_angle_range(gamma, theta):
    """Range of the image angle between two lines theta apart, over the unknown offset.

    gamma: tilt [rad]; theta: 3D angle between the lines [rad], in (0, pi). Returns
    (low, high) [rad] = (2 atan(cos g tan(theta/2)), 2 atan(tan(theta/2) / cos g)):
    lines symmetric about the tilt axis, resp. about its perpendicular. Broadcasts.
    """
    c = np.cos(np.asarray(gamma, dtype=float))
    t = np.tan(np.asarray(theta, dtype=float) / 2.0)
    return 2.0 * np.arctan(c * t), 2.0 * np.arctan2(t, c)


def _finite(name, *vals):
    for v in vals:
        if not np.isfinite(v):
            raise InputError(f"single_angle_tilt: {name} must be finite, got {v!r}")


def _result(status, gammas, sigmas, message, axis):
    return SingleAngleResult(status, tuple(float(g) for g in gammas), tuple(float(s) for s in sigmas), message, axis)


def _deg(x):
    return f"{np.degrees(x):.4g} deg"


def single_angle_tilt(alpha, theta, axis="on_line", sigma=None):
    """Tilt of a plane from two of its lines with a known 3D angle (chapter's single-angle test).

    alpha: "on_line": image angle of the second line from the axis line [rad];
        "known": (alpha_1, alpha_2), image angles of both lines from the axis image [rad];
        "unknown": image angle from line 1 to line 2 [rad] (or the pair (a_1, a_2) of their
        image angles, whose difference is used).
    theta: "on_line": 3D angle of the second line from the axis; "known" and "unknown":
        3D angle from line 1 to line 2 [rad].
    axis: "on_line" | "known" | "unknown" (module docstring).
    sigma: standard deviation of each alpha value [rad] (optional).
    Returns a SingleAngleResult; raises InputError for non-finite input or a configuration
    that carries no tilt information (second line on the axis or perpendicular to it, two
    lines with the same 3D direction).

    >>> import numpy as np
    >>> single_angle_tilt(np.radians(50), np.radians(45), "on_line").status
    'inconsistent'
    >>> r = single_angle_tilt(np.radians(20), np.radians(30), "unknown")
    >>> r.status, round(float(np.degrees(r.gamma[0])), 3)
    ('lower_bound', 48.848)
    """
    s = np.nan if sigma is None else float(sigma)
    if axis == "on_line":
        return _on_line(float(alpha), float(theta), s)
    if axis == "known":
        a = np.asarray(alpha, dtype=float).reshape(-1)
        if a.shape != (2,):
            raise InputError("single_angle_tilt: axis='known' needs alpha = (alpha_1, alpha_2)")
        return _known(float(a[0]), float(a[1]), float(theta), s)
    if axis == "unknown":
        a = np.asarray(alpha, dtype=float).reshape(-1)
        if a.shape == (2,):
            a = a[1:] - a[:1]
        if a.shape != (1,):
            raise InputError("single_angle_tilt: axis='unknown' needs alpha as one angle or a pair")
        return _unknown(float(a[0]), float(theta), s)
    raise InputError(f"single_angle_tilt: axis must be 'on_line', 'known' or 'unknown', got {axis!r}")


def _on_line(alpha, theta, sigma):
    _finite("alpha and theta", alpha, theta)
    a, t = float(wrap_line(alpha)), float(wrap_line(theta))
    if abs(np.sin(t)) < _EPS:
        raise InputError("single_angle_tilt: theta = 0 mod 180 deg: the second line lies on the axis and carries no tilt information")
    if abs(np.cos(t)) < _EPS:
        raise InputError("single_angle_tilt: theta = 90 deg from the axis: its image is at 90 deg for every tilt, no tilt information")
    if abs(np.cos(a)) < _EPS:
        return _result("inconsistent", (), (), f"alpha = 90 deg from the axis needs theta = 90 deg, got theta = {_deg(t)}", "on_line")
    c = np.sin(a) * np.cos(t) / (np.cos(a) * np.sin(t))  # tan(alpha) / tan(theta)
    if c <= 0.0:
        return _result("inconsistent", (), (), f"tan(alpha)/tan(theta) = {c:.6g} <= 0: alpha ({_deg(a)}) is not on the same side of the axis as theta ({_deg(t)})", "on_line")
    if c > 1.0 + _EPS:
        return _result("inconsistent", (), (), f"tan(alpha)/tan(theta) = {c:.6g} > 1: the image angle is larger than the 3D angle, a tilt only compresses it", "on_line")
    c = min(c, 1.0)
    g = float(np.arccos(c))
    tt = abs(np.tan(t))
    sd = sigma * (1.0 + c * c * tt * tt) / (tt * np.sin(g)) if g > 0 else (np.inf if np.isfinite(sigma) else np.nan)
    return _result("unique", (g,), (sd,), f"cos(gamma) = tan(alpha)/tan(theta) = {c:.9g}, gamma = {_deg(g)} (sign unknown)", "on_line")


def _known(a1, a2, delta, sigma):
    _finite("alpha and theta", a1, a2, delta)
    a1, a2, d = float(wrap_line(a1)), float(wrap_line(a2)), float(wrap_line(delta))
    if abs(np.sin(d)) < _EPS:
        raise InputError("single_angle_tilt: theta = 0 mod 180 deg: the two lines have the same 3D direction")
    sd_, cd = np.sin(d), np.cos(d)
    A = sd_ * np.cos(a1) * np.cos(a2)
    B = cd * np.sin(a1 - a2)
    C = sd_ * np.sin(a1) * np.sin(a2)
    if abs(A) < _EPS * max(abs(B), abs(C), 1e-300):
        roots = np.array([-C / B]) if abs(B) > 0 else np.array([])
    else:
        disc = B * B - 4.0 * A * C
        if disc < -_EPS * max(B * B, abs(4.0 * A * C)):
            return _result("inconsistent", (), (), f"the quadratic in cos(gamma) has no real root (discriminant {disc:.3g}): no tilt reproduces both angles", "known")
        q = -0.5 * (B + np.copysign(np.sqrt(max(disc, 0.0)), B if B != 0 else 1.0))
        roots = np.array([q / A, C / q]) if q != 0 else np.array([0.0, 0.0])
    def sd_c(c):
        # sd of a root from the angle noise: dc = -(dF/da1 da1 + dF/da2 da2) / (dF/dc)
        Fc = 2.0 * A * c + B
        Fa1 = -sd_ * np.sin(a1) * np.cos(a2) * c * c + cd * np.cos(a1 - a2) * c + sd_ * np.cos(a1) * np.sin(a2)
        Fa2 = -sd_ * np.cos(a1) * np.sin(a2) * c * c - cd * np.cos(a1 - a2) * c + sd_ * np.sin(a1) * np.cos(a2)
        return sigma * np.hypot(Fa1, Fa2) / abs(Fc) if (np.isfinite(sigma) and Fc != 0.0) else 0.0

    # c <= _EDGE_ON is the edge-on root c = 0 (a line on the axis gives it) up to rounding.
    # Near zero tilt, noise can push the right root past c = 1: within three of its sds it
    # is still the frontal solution (gamma = 0), not a reason to trust the other root alone.
    adm = sorted({float(min(c, 1.0)) for c in roots if _EDGE_ON < c <= 1.0 + max(1e-9, 3.0 * sd_c(c))})
    if len(adm) == 2 and abs(adm[0] - adm[1]) < 1e-12:
        adm = adm[:1]
    if not adm:
        return _result("inconsistent", (), (), f"no root of the quadratic in cos(gamma) lies in (0, 1] (roots {np.round(roots, 6).tolist()})", "known")
    gammas, sds = [], []
    for c in sorted(adm, reverse=True):  # ascending gamma
        g = float(np.arccos(c))
        Fc = 2.0 * A * c + B
        Fa1 = -sd_ * np.sin(a1) * np.cos(a2) * c * c + cd * np.cos(a1 - a2) * c + sd_ * np.cos(a1) * np.sin(a2)
        Fa2 = -sd_ * np.cos(a1) * np.sin(a2) * c * c - cd * np.cos(a1 - a2) * c + sd_ * np.sin(a1) * np.cos(a2)
        if not np.isfinite(sigma):
            sdg = np.nan
        elif g == 0.0 or Fc == 0.0:
            sdg = np.inf
        else:
            sdg = sigma * np.hypot(Fa1, Fa2) / abs(Fc) / np.sin(g)
        gammas.append(g)
        sds.append(sdg)
    if len(gammas) == 2:
        msg = f"two tilts fit: {_deg(gammas[0])} and {_deg(gammas[1])}; a third line or a prior must choose"
        return _result("two_roots", gammas, sds, msg, "known")
    return _result("unique", gammas, sds, f"one admissible root: gamma = {_deg(gammas[0])} (sign unknown)", "known")


def _unknown(alpha, delta, sigma):
    _finite("alpha and theta", alpha, delta)
    # line angles reduced into (0, pi]
    a = float(wrap_line(alpha - np.pi / 2.0)) + np.pi / 2.0
    d = float(wrap_line(delta - np.pi / 2.0)) + np.pi / 2.0
    if min(d, np.pi - d) < _EPS:
        raise InputError("single_angle_tilt: theta = 0 mod 180 deg: the two lines have the same 3D direction")
    if min(a, np.pi - a) < _EPS:
        return _result("inconsistent", (), (), "the two lines coincide in the image: only a pencil plane containing the viewing ray (tilt 90 deg) does that", "unknown")
    r = np.tan(a / 2.0) / np.tan(d / 2.0)
    m = min(r, 1.0 / r)
    g = float(np.arccos(m))
    if not np.isfinite(sigma):
        sdg = np.nan
    elif g == 0.0:
        sdg = np.inf
    else:
        dr = 0.5 / np.cos(a / 2.0) ** 2 / np.tan(d / 2.0)
        dm = dr if r < 1.0 else -dr / (r * r)
        sdg = sigma * abs(dm) / np.sin(g)
    msg = (f"axis unknown: the tilt is not recoverable, only bounded: gamma >= {_deg(g)} "
           f"(any tilt from there up to 90 deg reproduces the image angle {_deg(a)})")
    return _result("lower_bound", (g,), (sdg,), msg, "unknown")
