"""The chapter's models (toolkit/pencil/chapter.py) against exact projection (pencil.image_angles).

Poses are built here independently of chapter.py: a vertex at `off` from the optical axis,
a normal at `tilt` from the vertex ray (turned about it by `az`), and an in-plane `spin`.
"""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from pencilcal.toolkit.pencil import chapter as C
from pencilcal.toolkit.geometry.angles import wrap_angle, wrap_line
from pencilcal.toolkit.errors import EstimationError, InputError
from pencilcal.toolkit.pencil.estimator import max_angular_change
from pencilcal.toolkit.geometry.frames import (
    angle_between,
    rotation_about_axis,
    rotation_angle,
    rotation_to_z,
    twin_rotation,
)
from pencilcal.toolkit.pencil.spec import image_angles

DEG = np.pi / 180.0
TOL_MODEL = 1e-9 * DEG  # the general model equals exact projection
TOL_FIT = 1e-8 * DEG  # noise-free fits recover the truth


def make_pose(off, off_dir, tilt, az, spin):
    """(vertex (2,), R_cam_from_target) with the vertex `off` rad off axis, n at `tilt` from the ray."""
    x = np.tan(off) * np.array([np.cos(off_dir), np.sin(off_dir)])
    v = np.array([x[0], x[1], 1.0]) / np.hypot(np.hypot(x[0], x[1]), 1.0)
    to_ray = rotation_to_z(v).T  # maps camera z onto v
    tilt_axis = np.array([np.cos(az), np.sin(az), 0.0])
    R = to_ray @ rotation_about_axis(tilt_axis, tilt) @ rotation_about_axis([0.0, 0.0, 1.0], spin)
    return x, R


angle = st.floats(-np.pi, np.pi, allow_nan=False)
poses = st.builds(
    make_pose,
    off=st.floats(0.0, 40 * DEG),
    off_dir=angle,
    tilt=st.floats(0.0, 80 * DEG),
    az=angle,
    spin=angle,
)


def spoke_set(n_min=3, n_max=8, gap_min=10 * DEG):
    """Spokes with distinct lines: gaps >= gap_min within 170 deg, each possibly reversed."""

    @st.composite
    def build(draw):
        n = draw(st.integers(n_min, n_max))
        start = draw(angle)
        gmax = 170 * DEG / (n - 1)
        gaps = draw(st.lists(st.floats(gap_min, gmax), min_size=n - 1, max_size=n - 1))
        flips = draw(st.lists(st.booleans(), min_size=n, max_size=n))
        th = start + np.concatenate([[0.0], np.cumsum(gaps)]) + np.pi * np.array(flips)
        return wrap_angle(th)

    return build()


# ------------------------------------------------------------------- forward models: exact
@settings(max_examples=300, deadline=None)
@given(pose=poses, th=st.lists(angle, min_size=1, max_size=12))
def test_general_model_equals_exact_projection(pose, th):
    x, R = pose
    th = np.array(th)
    err = wrap_angle(C.image_angles_general(R, x, th) - image_angles(R, x, th))
    assert np.max(np.abs(err)) < TOL_MODEL  # oriented directions, not only lines


@settings(max_examples=200, deadline=None)
@given(pose=poses, th=st.lists(angle, min_size=1, max_size=8))
def test_general_model_composition_and_parameters(pose, th):
    """psi_i + general_angles(theta - theta_offset, gamma_r, delta, gamma_i), spelled out."""
    x, R = pose
    th = np.array(th)
    p = C.general_parameters(R, x)
    v = p["ray"]
    n = R[:, 2]
    # the conventions of docs/method.md
    assert np.isclose(np.cos(p["gamma_i"]), v[2], atol=1e-14)
    assert np.isclose(np.cos(p["gamma_r"]), n @ v, atol=1e-14)
    u_i, u_r = p["axis_image"], p["axis_pencil"]
    if p["gamma_i"] > 1e-3:
        assert np.allclose(u_i, np.cross([0, 0, 1.0], v) / np.sin(p["gamma_i"]), atol=1e-12)
    if p["gamma_r"] > 1e-3:
        assert np.allclose(u_r, np.cross(v, n) / np.sin(p["gamma_r"]), atol=1e-12)
    assert np.isclose(wrap_angle(p["psi_i"] - np.arctan2(u_i[1], u_i[0])), 0.0, atol=1e-14)
    # delta: angle from u_r to u_i about +v_d
    assert np.allclose(rotation_about_axis(v, p["delta"]) @ u_r, u_i, atol=1e-12)
    # theta_offset: the target direction that R maps onto u_r
    c, s = np.cos(p["theta_offset"]), np.sin(p["theta_offset"])
    assert np.allclose(R @ [c, s, 0.0], u_r, atol=1e-12)
    model = p["psi_i"] + C.general_angles(th - p["theta_offset"], p["gamma_r"], p["delta"], p["gamma_i"])
    assert np.max(np.abs(wrap_angle(model - image_angles(R, x, th)))) < TOL_MODEL
    # the tilt against the ray is the one the pose was built with
    assert np.isclose(p["gamma_r"], np.arccos(np.clip(n @ v, -1, 1)), atol=1e-7)


def test_chapter_tan_form_equals_atan2_form():
    """docs/method.md's eq.: tan(theta_i) = (tan(theta_r) cos(gamma_r) - tan(delta)) /
    (cos(gamma_i) (1 + tan(theta_r) cos(gamma_r) tan(delta))), away from its singularities."""
    rng = np.random.default_rng(1)
    tr, gr, d, gi = rng.uniform([-1.5, 0.0, -1.5, 0.0], [1.5, 1.4, 1.5, 0.7], (4000, 4)).T
    num = np.tan(tr) * np.cos(gr) - np.tan(d)
    den = np.cos(gi) * (1 + np.tan(tr) * np.cos(gr) * np.tan(d))
    ok = (np.abs(den) > 1e-3) & (np.abs(np.cos(tr)) > 1e-3) & (np.abs(np.cos(d)) > 1e-3)
    lit = np.arctan(num[ok] / den[ok])
    assert np.max(np.abs(wrap_line(C.general_angles(tr, gr, d, gi)[ok] - lit))) < 1e-11


@settings(max_examples=200, deadline=None)
@given(pose=poses)
def test_parameters_round_trip_and_twin(pose):
    x, R = pose
    p = C.general_parameters(R, x)
    R2 = C.rotation_from_general(x, p["gamma_r"], p["delta"], p["theta_offset"])
    assert rotation_angle(R, R2) < 1e-12
    twin = C.rotation_from_general(x, -p["gamma_r"], p["delta"], p["theta_offset"])
    assert rotation_angle(twin, twin_rotation(R, p["ray"])) < 1e-12
    th = np.linspace(-np.pi, np.pi, 13)
    assert np.max(np.abs(wrap_angle(image_angles(twin, x, th) - image_angles(R, x, th)))) < 1e-12


@settings(max_examples=200, deadline=None)
@given(
    tilt=st.floats(0.0, 80 * DEG),
    az=angle,
    spin=angle,
    th=st.lists(angle, min_size=1, max_size=12),
)
def test_aligned_model_exact_on_axis(tilt, az, spin, th):
    """Eq. 6 (atan2 form) is exact for a vertex on the optical axis, at any depth."""
    x, R = make_pose(0.0, 0.0, tilt, az, spin)
    th = np.array(th)
    exact = image_angles(R, x, th)
    assert np.max(np.abs(wrap_angle(C.image_angles_aligned(R, th) - exact))) < TOL_MODEL
    p = C.aligned_parameters(R)
    assert np.isclose(p["gamma"], tilt, atol=1e-9)
    model = p["psi"] + C.aligned_angles(th - p["theta_offset"], p["gamma"])
    assert np.max(np.abs(wrap_angle(model - exact))) < TOL_MODEL
    Rb = C.rotation_from_aligned(p["gamma"], p["psi"], p["theta_offset"])
    assert rotation_angle(Rb, R) < 1e-12 or rotation_angle(twin_rotation(Rb, [0, 0, 1.0]), R) < 1e-12


def test_aligned_angles_atan2_form_has_no_tan_singularity():
    g = 50 * DEG
    th = np.array([89.999999, 90.0, 90.000001, 270.0, -90.0]) * DEG
    a = C.aligned_angles(th, g)
    assert np.allclose(wrap_angle(a[1:4:2] - np.array([90.0, -90.0]) * DEG), 0.0, atol=1e-15)
    assert np.isclose(a[1], 90 * DEG) and np.all(np.diff(a[:3]) > 0)
    # tan(alpha) = tan(theta) cos(gamma) away from 90 deg
    t = np.radians([-80.0, -30.0, 10.0, 60.0])
    assert np.allclose(np.tan(C.aligned_angles(t, g)), np.tan(t) * np.cos(g), rtol=1e-13)


def test_degenerate_conventions_are_exact():
    th = np.linspace(-np.pi, np.pi, 25)
    # vertex on the optical axis: u_i := +x, gamma_i = 0
    x0, R = make_pose(0.0, 0.0, 35 * DEG, 0.4, 1.1)
    p = C.general_parameters(R, x0)
    assert p["gamma_i"] == 0.0 and p["psi_i"] == 0.0 and np.allclose(p["axis_image"], [1, 0, 0])
    assert np.max(np.abs(wrap_angle(C.image_angles_general(R, x0, th) - image_angles(R, x0, th)))) < TOL_MODEL
    # frontal pencil (n = v_d): u_r := u_i, delta = 0
    x, R = make_pose(25 * DEG, 2.0, 0.0, 0.0, 0.7)
    p = C.general_parameters(R, x)
    assert p["gamma_r"] < 1e-15 and p["delta"] == 0.0 and np.allclose(p["axis_pencil"], p["axis_image"])
    assert np.max(np.abs(wrap_angle(C.image_angles_general(R, x, th) - image_angles(R, x, th)))) < TOL_MODEL
    # both at once: the identity pose
    assert np.max(np.abs(wrap_angle(C.image_angles_general(np.eye(3), x0, th) - th))) < 1e-15
    # pencil seen from behind (n . v_d < 0) and edge-on: the atan2 form stays exact
    for tilt in (90 * DEG, 120 * DEG, 179 * DEG):
        x, R = make_pose(30 * DEG, 0.3, tilt, 1.0, 0.2)
        assert np.max(np.abs(wrap_line(C.image_angles_general(R, x, th) - image_angles(R, x, th)))) < TOL_MODEL


def test_forward_models_broadcast():
    rng = np.random.default_rng(3)
    poses_ = [make_pose(*rng.uniform([0, -3, 0, -3, -3], [0.6, 3, 1.3, 3, 3])) for _ in range(5)]
    x = np.stack([p[0] for p in poses_])
    R = np.stack([p[1] for p in poses_])
    th = rng.uniform(-np.pi, np.pi, (5, 7))
    assert C.image_angles_general(R, x, th).shape == (5, 7)
    assert np.max(np.abs(wrap_angle(C.image_angles_general(R, x, th) - image_angles(R, x, th)))) < TOL_MODEL
    p = C.general_parameters(R, x)
    assert p["gamma_r"].shape == (5,) and p["axis_pencil"].shape == (5, 3)
    R2 = C.rotation_from_general(x, p["gamma_r"], p["delta"], p["theta_offset"])
    assert np.max(rotation_angle(R, R2)) < 1e-12
    assert C.image_angles_aligned(R, th).shape == (5, 7)


def test_delta_sign_matters():
    """With delta's sign turned (angle from u_i to u_r) the model errs by up to ~90 deg."""
    rng = np.random.default_rng(7)
    th = np.radians(np.arange(0.0, 180.0, 1.0))
    worst = 0.0
    for _ in range(200):
        x, R = make_pose(rng.uniform(5, 40) * DEG, rng.uniform(-np.pi, np.pi), rng.uniform(10, 80) * DEG,
                         rng.uniform(-np.pi, np.pi), rng.uniform(-np.pi, np.pi))
        p = C.general_parameters(R, x)
        wrong = p["psi_i"] + C.general_angles(th - p["theta_offset"], p["gamma_r"], -p["delta"], p["gamma_i"])
        worst = max(worst, np.max(np.abs(wrap_line(wrong - image_angles(R, x, th)))))
    assert worst > 85 * DEG


# ----------------------------------------------------------------- the shortcuts' errors
def test_dropping_gamma_i_step_errs_by_1p78_deg_at_20_deg_off_axis():
    """Dropping the T -> image step (theta_i = phi - delta) at a vertex 20 deg off axis.

    The exact step is tan(theta_i) = tan(phi - delta) / cos(gamma_i): an affine stretch by
    1/cos(gamma_i) across u_i. Its largest angle change, at tan(x) = sqrt(cos g), is
    atan(1/sqrt(cos g)) - atan(sqrt(cos g)) = 1.78 deg for g = 20 deg, whatever the pose
    (phi - delta sweeps every angle as the spokes go round). The full model: no error.
    """
    expected = np.degrees(np.arctan(1 / np.sqrt(np.cos(20 * DEG))) - np.arctan(np.sqrt(np.cos(20 * DEG))))
    assert round(expected, 2) == 1.78
    assert np.isclose(np.degrees(max_angular_change(20 * DEG)), expected, rtol=1e-14)
    rng = np.random.default_rng(11)
    th = np.radians(np.arange(0.0, 360.0, 0.02))
    for _ in range(6):
        x, R = make_pose(20 * DEG, rng.uniform(-np.pi, np.pi), rng.uniform(0, 80) * DEG,
                         rng.uniform(-np.pi, np.pi), rng.uniform(-np.pi, np.pi))
        exact = image_angles(R, x, th)
        short = np.degrees(np.max(np.abs(wrap_angle(C.image_angles_general(R, x, th, shortcut=True) - exact))))
        assert abs(short - expected) < 2e-4, short
        full = np.max(np.abs(wrap_angle(C.image_angles_general(R, x, th) - exact)))
        assert full < TOL_MODEL


def _aligned_image_plane_worst(tilt, off=20 * DEG, axis_step=2.0, spoke_step=0.05):
    """Worst error [deg] of eq. 6 with the tilt from the image plane, over tilt axes and spokes."""
    x = np.array([np.tan(off), 0.0])
    axes = np.radians(np.arange(-180.0, 180.0, axis_step))
    th = np.radians(np.arange(0.0, 180.0, spoke_step))
    k = axes.size
    R = C.rotation_from_general(np.broadcast_to(x, (k, 2)), np.full(k, tilt), axes, np.zeros(k))
    ths = np.broadcast_to(th, (k, th.size))
    exact = image_angles(R, x, ths)
    err = np.abs(wrap_line(C.image_angles_aligned(R, ths) - exact))
    full = np.abs(wrap_angle(C.image_angles_general(R, x, ths) - exact))
    return np.degrees(err.max(-1)), np.degrees(full.max())


def test_aligned_model_with_image_plane_tilt_errs_3p6_to_20_deg():
    """Eq. 6 applied with the tilt measured from the image plane, vertex 20 deg off axis.

    Setup that reproduces docs/method.md's "3.6-20 deg": the pencil tilted by gamma_r from
    the vertex ray (the tilt the estimators report), gamma_r from 0 to 40 deg; for each
    tilt the error is the worst over every tilt-axis direction in the plane orthogonal to
    the ray and over all spoke directions (0.05 deg steps).

    - gamma_r = 0 (pencil facing the vertex): the image plane is tilted 20 deg from the
      pencil, eq. 6 compresses by cos 20 deg where the truth stretches by 1/cos 20 deg
      across the same axis: error atan(1/c) - atan(c) = 90 - 2 atan(cos 20 deg) = 3.56 deg,
      for every axis;
    - the worst case grows monotonically with the tilt: 6.4, 9.9, 14.1 deg at 10, 20, 30 deg
      and 19.65 deg at 40 deg (20.3 deg at 41 deg, 23.2 deg at 45 deg).
    The best axis does better (0 when the tilt turns the pencil parallel to the image
    plane, gamma_r = 20 deg), so "3.6-20" is the worst case over 0-40 deg of tilt.
    The full general model has no error in the same poses.
    """
    tilts = np.radians([0.0, 10.0, 20.0, 30.0, 40.0])
    worst = []
    for t in tilts:
        err, full = _aligned_image_plane_worst(t)
        worst.append(err.max())
        assert full < 1e-9
        if t == 0.0:  # the same for every axis direction
            assert np.ptp(err) < 1e-9
    c = np.cos(20 * DEG)
    assert abs(worst[0] - np.degrees(np.arctan(1 / c) - np.arctan(c))) < 1e-4
    assert abs(worst[0] - 3.56) < 0.01
    assert np.all(np.diff(worst) > 2.0)
    assert 19.55 < worst[-1] < 19.75  # refined grids give 19.654
    assert np.allclose(worst[1:4], [6.41, 9.86, 14.11], atol=0.02)
    # and the same model is exact with the vertex on the optical axis
    err0, _ = _aligned_image_plane_worst(40 * DEG, off=0.0, axis_step=15.0)
    assert err0.max() < 1e-9


# ---------------------------------------------------------------------------------- fits
def _closer(fit, R):
    return min(rotation_angle(fit["R_cam_from_target"], R), rotation_angle(fit["R_cam_from_target_twin"], R))


@settings(max_examples=150, deadline=None)
@given(
    off=st.floats(0.0, 40 * DEG),
    off_dir=angle,
    tilt=st.floats(1 * DEG, 80 * DEG),
    az=angle,
    spin=angle,
    th=spoke_set(),
)
def test_fit_general_recovers_truth_noise_free(off, off_dir, tilt, az, spin, th):
    x, R = make_pose(off, off_dir, tilt, az, spin)
    a = image_angles(R, x, th)
    fit = C.fit_general(a, th, x)
    assert _closer(fit, R) < TOL_FIT
    assert fit["rms"] < 1e-12 and fit["oriented_consistent"]
    assert np.isclose(fit["gamma_r"], tilt, atol=1e-9)
    assert rotation_angle(fit["R_cam_from_target_twin"], twin_rotation(fit["R_cam_from_target"], fit["ray"])) < 1e-12
    assert fit["R_cam_from_target"][2, 2] >= fit["R_cam_from_target_twin"][2, 2]
    # chapter parameters of the closer twin match the truth's
    p_true = C.general_parameters(R, x)
    p = fit["parameters"] if rotation_angle(fit["R_cam_from_target"], R) < TOL_FIT else fit["parameters_twin"]
    assert abs(wrap_angle(p["delta"] - p_true["delta"])) < 1e-6
    assert np.allclose(wrap_angle(fit["predicted"] - a), 0.0, atol=1e-11)


@settings(max_examples=150, deadline=None)
@given(tilt=st.floats(1 * DEG, 80 * DEG), az=angle, spin=angle, th=spoke_set())
def test_fit_aligned_recovers_truth_on_axis(tilt, az, spin, th):
    x, R = make_pose(0.0, 0.0, tilt, az, spin)
    a = image_angles(R, x, th)
    fit = C.fit_aligned(a, th)
    assert _closer(fit, R) < TOL_FIT
    assert np.isclose(fit["gamma"], tilt, atol=1e-9) and fit["gamma_sign_ambiguous"]
    assert fit["rms"] < 1e-12
    assert rotation_angle(fit["R_cam_from_target_twin"], twin_rotation(fit["R_cam_from_target"], [0, 0, 1.0])) < 1e-12


def test_fit_with_unoriented_lines_recovers_normal():
    """Lines (period pi) fix the normal up to the twin; R only up to R Rz(pi)."""
    rng = np.random.default_rng(5)
    th = np.radians([0.0, 25.0, 50.0, 80.0, 120.0, 150.0])
    for _ in range(20):
        x, R = make_pose(rng.uniform(0, 40) * DEG, rng.uniform(-3, 3), rng.uniform(5, 80) * DEG,
                         rng.uniform(-3, 3), rng.uniform(-3, 3))
        a = image_angles(R, x, th) + np.pi * rng.integers(0, 2, th.size)
        fit = C.fit_general(a, th, x)
        assert fit["rms"] < 1e-12
        n = R[:, 2]
        assert min(angle_between(fit["normal"], n), angle_between(fit["normal_twin"], n)) < 1e-12
        Rz = np.diag([-1.0, -1.0, 1.0])
        cands = [fit["R_cam_from_target"], fit["R_cam_from_target_twin"]]
        assert min(min(rotation_angle(Q, R), rotation_angle(Q @ Rz, R)) for Q in cands) < TOL_FIT


def test_fit_weights_and_noise():
    rng = np.random.default_rng(9)
    x, R = make_pose(20 * DEG, 0.7, 35 * DEG, 1.2, -0.4)
    th = np.radians(np.arange(0.0, 160.0, 20.0))
    a = image_angles(R, x, th)
    # a gross outlier with zero weight does not move the exact solution
    bad = a.copy()
    bad[3] += 7 * DEG
    w = np.ones_like(a)
    w[3] = 0.0
    fit = C.fit_general(bad, th, x, weights=w)
    assert _closer(fit, R) < TOL_FIT
    assert np.isclose(abs(fit["residuals"][3]), 7 * DEG, atol=1e-9)
    # with 0.1 deg noise the rms residual is of the noise's order and the normal is close
    sig = 0.1 * DEG
    noisy = a + rng.normal(0, sig, a.size)
    fit = C.fit_general(noisy, th, x, weights=np.full(a.size, 1 / sig**2))
    assert fit["success"] and 0.2 * sig < fit["rms"] < 2 * sig
    assert _closer(fit, R) < 3 * DEG
    # Off axis the aligned model still reproduces the lines exactly (any 1-D homography with
    # det > 0 is Rot(psi) diag(1, cos g) Rot(-theta_offset): 3 DOF either way), but the pose
    # it returns is wrong; the general model's is right.
    fa = C.fit_aligned(a, th)
    assert fa["rms"] < 1e-12
    assert _closer(fa, R) > 5 * DEG
    assert _closer(C.fit_general(a, th, x), R) < TOL_FIT


def test_fit_input_errors():
    th = np.radians([0.0, 40.0, 80.0])
    with pytest.raises(EstimationError, match="at least three"):
        C.fit_general(th[:2], th[:2], [0.1, 0.0])
    with pytest.raises(EstimationError, match="at least three"):
        C.fit_aligned(th[:2], th[:2])
    with pytest.raises(InputError, match="NaN"):
        C.fit_aligned([0.0, np.nan, 1.0], th)
    with pytest.raises(InputError, match="vertex"):
        C.fit_general(th, th, [np.nan, 0.0])
    with pytest.raises(InputError, match="same length"):
        C.fit_general(th, th[:2], [0.0, 0.0])
    with pytest.raises(EstimationError, match="distinct"):
        C.fit_aligned([0.1, 0.1, 0.5], [0.0, 0.0, 1.0])


# ------------------------------------------------------------------------------ ellipses
def test_perspective_ellipse_eccentricity_and_centre():
    """A circle of radius R centred on the optical axis at depth z0, its plane tilted by g.

    Geometry: P0 = (0, 0, z0), normal n = (0, sin g, cos g) (tilted about the camera x
    axis), rho = R / z0. Exact eccentricity from the conic matrix vs the closed form
    e = sin g sqrt((1 - rho^2) / (1 - rho^2 sin^2 g)); rho = 0.5, g = 45 deg -> 0.655, not
    sin 45 deg = 0.707. The ellipse is symmetric about the image y axis; its y extremes are
    the images of P0 +- R (0, cos g, -sin g), so its centre is at
    y_c = rho^2 sin g cos g / (1 - rho^2 sin^2 g) (= 1/7 for the example), not at the image
    of P0 (the origin).
    """
    z0 = 2.0
    g, rho = 45 * DEG, 0.5
    P0 = np.array([0.0, 0.0, z0])
    n = np.array([0.0, np.sin(g), np.cos(g)])
    e = C.projected_circle_ellipse(P0, n, rho * z0)
    assert round(float(e["eccentricity"]), 3) == 0.655
    assert abs(e["eccentricity"] - np.sin(g)) > 0.05  # the weak-perspective value is wrong
    assert np.isclose(C.perspective_circle_eccentricity(g, rho), e["eccentricity"], rtol=1e-12)
    assert np.allclose(e["vertex_image"], [0.0, 0.0])
    assert np.allclose(e["center"], [0.0, 1.0 / 7.0], atol=1e-14)
    # the projected circle lies on the conic, and its y extremes give the centre
    t = np.linspace(0, 2 * np.pi, 721)
    e1, e2 = np.array([1.0, 0, 0]), np.cross(n, [1.0, 0, 0])
    P = P0 + rho * z0 * (np.cos(t)[:, None] * e1 + np.sin(t)[:, None] * e2)
    xh = P / P[:, 2:]
    assert np.max(np.abs(np.einsum("ni,ij,nj->n", xh, e["conic"], xh))) < 1e-14
    assert np.isclose((xh[:, 1].max() + xh[:, 1].min()) / 2, e["center"][1], atol=1e-5)
    # the closed forms over a grid, and the weak-perspective limit
    for gd in (5.0, 30.0, 60.0, 85.0):
        for r in (1e-4, 0.2, 0.5, 0.9):
            gg = gd * DEG
            nn = np.array([0.0, np.sin(gg), np.cos(gg)])
            el = C.projected_circle_ellipse(P0, nn, r * z0)
            assert np.isclose(el["eccentricity"], C.perspective_circle_eccentricity(gg, r), rtol=1e-9, atol=1e-12)
            yc = r**2 * np.sin(gg) * np.cos(gg) / (1 - r**2 * np.sin(gg) ** 2)
            assert np.allclose(el["center"], [0.0, yc], atol=1e-12)
    assert np.isclose(C.perspective_circle_eccentricity(g, 1e-6), np.sin(g), rtol=1e-10)
    # in pixels the conic is K^-T C K^-1 (same point set)
    K = np.array([[800.0, 2.0, 320.0], [0.0, 760.0, 240.0], [0.0, 0.0, 1.0]])
    ep = C.projected_circle_ellipse(P0, n, rho * z0, K=K)
    px = xh @ K.T
    assert np.max(np.abs(np.einsum("ni,ij,nj->n", px, ep["conic"], px) / np.sum(px**2, 1))) < 1e-13
    # a circle reaching behind the camera has no ellipse image; a plane through the camera
    # centre has no image at all
    with pytest.raises(EstimationError, match="not an ellipse"):
        C.projected_circle_ellipse(P0, [0.0, np.sin(80 * DEG), np.cos(80 * DEG)], 3 * z0)
    with pytest.raises(EstimationError, match="camera centre"):
        C.projected_circle_ellipse(P0, [1.0, 0, 0], 0.5)
