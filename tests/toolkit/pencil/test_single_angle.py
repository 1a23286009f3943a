"""Two lines with a known 3D angle (toolkit/pencil/single_angle.py), against exact projection.

The pencil's vertex is on the optical axis (the chapter's aligned setting), the plane is
tilted by gamma about an axis whose image is at psi and whose target-frame angle is th0:
R = Rz(psi) Rx(gamma) Rz(-th0). Image angles come from pencil.image_angles.
"""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from pencilcal.toolkit.geometry.angles import wrap_line
from pencilcal.toolkit.errors import InputError
from pencilcal.toolkit.geometry.frames import rotation_about_axis
from pencilcal.toolkit.pencil.spec import image_angles
from pencilcal.toolkit.pencil.single_angle import SingleAngleResult, image_angle_range, single_angle_tilt

DEG = np.pi / 180.0
SIG = 0.1 * DEG
angle = st.floats(-np.pi, np.pi, allow_nan=False)


def observe(gamma, psi, th0, thetas):
    """Exact image angles of spokes at target angles `thetas` (vertex on the optical axis)."""
    z, x = [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]
    R = rotation_about_axis(z, psi) @ rotation_about_axis(x, gamma) @ rotation_about_axis(z, -th0)
    return image_angles(R, [0.0, 0.0], np.asarray(thetas, float))


def reproduces(c, a1, a2, delta):
    """Does cos(gamma) = c map some pair of lines delta apart onto (a1, a2) from the axis?"""
    t1 = np.arctan2(np.sin(a1), np.cos(a1) * c)  # inverse of tan a = tan t * c
    t2 = np.arctan2(np.sin(a2), np.cos(a2) * c)
    # undoing a compression by c amplifies the rounding of alpha by 1/c (c -> 0: edge-on)
    return abs(wrap_line(t2 - t1 - delta)) < 1e-9 + 1e-14 / c


# ------------------------------------------------------------------------------- on_line
def test_on_line_sd_reference_values():
    """sd(gamma) = sigma (1 + cos^2 g tan^2 theta) / (tan theta sin g): 2.3 / 0.55 / 0.14 deg."""
    want = {5.0: (2.3, 1), 20.0: (0.55, 2), 60.0: (0.14, 2)}
    for g, (ref, digits) in want.items():
        a = observe(g * DEG, 0.0, 0.0, [0.0, 45 * DEG])
        r = single_angle_tilt(a[1] - a[0], 45 * DEG, "on_line", sigma=SIG)
        assert r.status == "unique" and r.axis == "on_line"
        assert abs(r.gamma[0] - g * DEG) < 1e-12
        assert round(np.degrees(r.sigma[0]), digits) == ref
        # the formula is the derivative of acos(tan(alpha)/tan(theta)) times sigma
        h = 1e-7
        gp = single_angle_tilt(a[1] - a[0] + h, 45 * DEG, "on_line").gamma[0]
        gm = single_angle_tilt(a[1] - a[0] - h, 45 * DEG, "on_line").gamma[0]
        assert np.isclose(abs(gp - gm) / (2 * h) * SIG, r.sigma[0], rtol=1e-5)


@settings(max_examples=200, deadline=None)
@given(
    gamma=st.floats(1 * DEG, 85 * DEG),
    psi=angle,
    th0=angle,
    theta=st.floats(5 * DEG, 85 * DEG),
    side=st.sampled_from([-1.0, 1.0]),
    flip=st.booleans(),
)
def test_on_line_recovers_tilt_from_exact_projection(gamma, psi, th0, theta, side, flip):
    theta = side * theta
    a = observe(gamma, psi, th0, [th0, th0 + theta + np.pi * flip])  # the first lies on the axis
    r = single_angle_tilt(a[1] - a[0], theta, "on_line")
    assert r.status == "unique"
    assert abs(r.gamma[0] - gamma) < 1e-9 * DEG
    assert np.isnan(r.sigma[0])  # no sigma given


def test_on_line_inconsistent_and_uninformative():
    r = single_angle_tilt(50 * DEG, 45 * DEG, "on_line", sigma=SIG)
    assert r.status == "inconsistent" and r.gamma == () and r.sigma == () and "> 1" in r.message
    r = single_angle_tilt(-20 * DEG, 45 * DEG, "on_line")
    assert r.status == "inconsistent" and "side" in r.message
    r = single_angle_tilt(90 * DEG, 45 * DEG, "on_line")
    assert r.status == "inconsistent"
    r = single_angle_tilt(45 * DEG, 45 * DEG, "on_line", sigma=SIG)  # frontal: gamma = 0
    assert r.status == "unique" and r.gamma == (0.0,) and np.isinf(r.sigma[0])
    with pytest.raises(InputError, match="on the axis"):
        single_angle_tilt(0.0, np.pi, "on_line")
    with pytest.raises(InputError, match="90 deg"):
        single_angle_tilt(90 * DEG, 90 * DEG, "on_line")
    with pytest.raises(InputError, match="finite"):
        single_angle_tilt(np.nan, 45 * DEG, "on_line")


# --------------------------------------------------------------------------------- known
def test_known_axis_quadratic_two_roots_example():
    """theta_1 = 10 deg, theta_2 = 55 deg from the axis, gamma = 60 deg: 60 or 82.77 deg."""
    psi, th0 = 0.4, 0.3
    a = observe(60 * DEG, psi, th0, th0 + np.radians([10.0, 55.0]))
    r = single_angle_tilt(a - psi, 45 * DEG, "known", sigma=SIG)
    assert r.status == "two_roots" and len(r.gamma) == 2 and len(r.sigma) == 2
    assert abs(r.gamma[0] - 60 * DEG) < 1e-12
    assert np.isclose(np.degrees(r.gamma[1]), 82.7667, atol=1e-4)
    # the second root is a genuine alternative: another offset at 82.77 deg gives the same image
    for g in r.gamma:
        assert reproduces(np.cos(g), *(a - psi), 45 * DEG)
    # the quadratic T c^2 + c (t1 - t2) + T t1 t2 = 0 holds for both roots
    t1, t2 = np.tan(a - psi)
    T = np.tan(45 * DEG)
    for g in r.gamma:
        c = np.cos(g)
        assert abs(T * c * c + c * (t1 - t2) + T * t1 * t2) < 1e-12


def test_known_axis_unique_when_lines_straddle_the_axis():
    psi, th0 = -1.2, 2.0
    a = observe(60 * DEG, psi, th0, th0 + np.radians([-10.0, 35.0]))
    r = single_angle_tilt(a - psi, 45 * DEG, "known", sigma=SIG)
    assert r.status == "unique" and abs(r.gamma[0] - 60 * DEG) < 1e-12
    # sigma: the root's derivative w.r.t. each alpha, combined
    h = 1e-7
    d = []
    for k in range(2):
        e = np.zeros(2)
        e[k] = h
        gp = single_angle_tilt(a - psi + e, 45 * DEG, "known").gamma[0]
        gm = single_angle_tilt(a - psi - e, 45 * DEG, "known").gamma[0]
        d.append((gp - gm) / (2 * h))
    assert np.isclose(SIG * np.hypot(*d), r.sigma[0], rtol=1e-5)


def test_known_axis_inconsistent():
    # symmetric about the axis, 80 deg apart in the image but 30 deg in 3D: a tilt compresses
    r = single_angle_tilt(np.radians([-40.0, 40.0]), 30 * DEG, "known")
    assert r.status == "inconsistent" and "(0, 1]" in r.message and r.gamma == ()
    # no real root at all
    r = single_angle_tilt(np.radians([10.0, 11.0]), 80 * DEG, "known")
    assert r.status == "inconsistent" and "no real root" in r.message
    with pytest.raises(InputError, match="alpha_1, alpha_2"):
        single_angle_tilt(0.3, 30 * DEG, "known")
    with pytest.raises(InputError, match="same 3D direction"):
        single_angle_tilt([0.1, 0.2], np.pi, "known")


@settings(max_examples=200, deadline=None)
@given(
    gamma=st.floats(2 * DEG, 85 * DEG),
    psi=angle,
    th0=angle,
    theta1=st.floats(-85 * DEG, 85 * DEG),
    delta=st.floats(10 * DEG, 170 * DEG),
)
def test_known_axis_truth_is_among_the_roots(gamma, psi, th0, theta1, delta):
    a = observe(gamma, psi, th0, th0 + np.array([theta1, theta1 + delta]))
    al = a - psi
    r = single_angle_tilt(al, delta, "known")
    assert r.status in ("unique", "two_roots")
    assert min(abs(g - gamma) for g in r.gamma) < 1e-6 * DEG
    for g in r.gamma:  # every root reproduces the observation exactly
        assert 0.0 <= g < np.pi / 2 and reproduces(np.cos(g), *al, delta)
    if np.tan(al[0]) * np.tan(al[1]) < 0:  # lines on opposite sides of the axis
        assert r.status == "unique"


# ------------------------------------------------------------------------------- unknown
@settings(max_examples=200, deadline=None)
@given(
    gamma=st.floats(0.0, 85 * DEG),
    psi=angle,
    th0=angle,
    theta1=angle,
    delta=st.floats(5 * DEG, 175 * DEG),
)
def test_unknown_axis_gives_a_lower_bound(gamma, psi, th0, theta1, delta):
    a = observe(gamma, psi, th0, th0 + np.array([theta1, theta1 + delta]))
    r = single_angle_tilt(a, delta, "unknown")  # the pair: its difference is used
    assert r.status == "lower_bound" and len(r.gamma) == 1
    # acos near 1: the rounding of alpha alone moves the bound by ~sqrt(eps / sin alpha)
    # at gamma ~ 0 (1e-7 rad at alpha ~ 170 deg)
    assert r.gamma[0] <= gamma + 1e-6
    lo, hi = image_angle_range(gamma, delta)
    alpha = np.remainder(a[1] - a[0], np.pi)
    assert lo - 1e-12 <= alpha <= hi + 1e-12


@settings(max_examples=100, deadline=None)
@given(gamma=st.floats(1 * DEG, 85 * DEG), psi=angle, th0=angle, delta=st.floats(5 * DEG, 175 * DEG))
def test_unknown_axis_bound_is_attained_at_the_range_ends(gamma, psi, th0, delta):
    """The bound is tight: lines symmetric about the axis or about its perpendicular."""
    lo, hi = image_angle_range(gamma, delta)
    for mid, end in ((0.0, lo), (np.pi / 2, hi)):
        a = observe(gamma, psi, th0, th0 + mid + np.array([-delta / 2, delta / 2]))
        assert abs(wrap_line(a[1] - a[0] - end)) < 1e-12
        r = single_angle_tilt(a[1] - a[0], delta, "unknown")
        assert abs(r.gamma[0] - gamma) < 1e-6 * DEG


def test_unknown_axis_examples_and_sigma():
    r = single_angle_tilt(30 * DEG, 30 * DEG, "unknown", sigma=SIG)
    assert r.status == "lower_bound" and r.gamma == (0.0,) and np.isinf(r.sigma[0])
    r = single_angle_tilt(20 * DEG, 30 * DEG, "unknown", sigma=SIG)
    assert np.isclose(np.degrees(r.gamma[0]), 48.848, atol=1e-3) and "not recoverable" in r.message
    h = 1e-7
    gp = single_angle_tilt(20 * DEG + h, 30 * DEG, "unknown").gamma[0]
    gm = single_angle_tilt(20 * DEG - h, 30 * DEG, "unknown").gamma[0]
    assert np.isclose(abs(gp - gm) / (2 * h) * SIG, r.sigma[0], rtol=1e-5)
    # lines vs directions: (alpha, theta) and (pi - alpha, pi - theta) are the same pair
    r2 = single_angle_tilt(-160 * DEG, -150 * DEG, "unknown")
    assert np.isclose(r2.gamma[0], r.gamma[0], atol=1e-12)
    r = single_angle_tilt(np.pi, 30 * DEG, "unknown")
    assert r.status == "inconsistent" and "coincide" in r.message
    with pytest.raises(InputError, match="same 3D direction"):
        single_angle_tilt(0.2, 0.0, "unknown")


def test_result_type_and_bad_axis():
    r = single_angle_tilt(20 * DEG, 30 * DEG, "on_line")
    assert isinstance(r, SingleAngleResult)
    with pytest.raises(Exception):
        r.status = "unique"  # frozen
    with pytest.raises(InputError, match="axis must be"):
        single_angle_tilt(0.1, 0.2, "sideways")


def test_known_axis_near_frontal_is_not_a_false_unique():
    """Near zero tilt noise can push the right root of the known-axis quadratic past
    cos(gamma) = 1; it must then still count (as gamma = 0), never leaving the far root as
    a confident 'unique' answer (regression)."""
    from pencilcal.toolkit.pencil.single_angle import single_angle_tilt

    rng = np.random.default_rng(4)
    sigma = np.radians(0.05)
    bad = 0
    for _ in range(400):
        g = np.radians(rng.uniform(0.5, 4.0))
        t1 = np.radians(rng.uniform(5, 40))
        delta = np.radians(rng.uniform(20, 60))
        a1 = np.arctan2(np.sin(t1) * np.cos(g), np.cos(t1)) + sigma * rng.normal()
        a2 = np.arctan2(np.sin(t1 + delta) * np.cos(g), np.cos(t1 + delta)) + sigma * rng.normal()
        res = single_angle_tilt((a1, a2), delta, axis="known", sigma=sigma)
        if res.status == "unique" and abs(res.gamma[0] - g) > 10 * max(res.sigma[0], np.radians(0.5)):
            bad += 1
    assert bad == 0
