"""The pencil as a 1-D projective map (toolkit/geometry/projective.py), against exact projection."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from pencilcal.toolkit.geometry import projective as P
from pencilcal.toolkit.geometry.angles import wrap_angle, wrap_line
from pencilcal.toolkit.errors import EstimationError, InputError
from pencilcal.toolkit.geometry.frames import rotation_about_axis, rotation_to_z
from pencilcal.toolkit.pencil.spec import image_angles, spoke_directions

DEG = np.pi / 180.0
angle = st.floats(-np.pi, np.pi, allow_nan=False)


def make_pose(off, off_dir, tilt, az, spin):
    x = np.tan(off) * np.array([np.cos(off_dir), np.sin(off_dir)])
    v = np.array([x[0], x[1], 1.0]) / np.hypot(np.hypot(x[0], x[1]), 1.0)
    tilt_axis = np.array([np.cos(az), np.sin(az), 0.0])
    R = rotation_to_z(v).T @ rotation_about_axis(tilt_axis, tilt) @ rotation_about_axis([0.0, 0.0, 1.0], spin)
    return x, R


poses = st.builds(
    make_pose,
    off=st.floats(0.0, 40 * DEG),
    off_dir=angle,
    tilt=st.floats(0.0, 70 * DEG),
    az=angle,
    spin=angle,
)


@st.composite
def spokes(draw, n_min=4, n_max=8):
    """Distinct lines: gaps of 15 deg or more within 170 deg; each spoke possibly reversed."""
    n = draw(st.integers(n_min, n_max))
    start = draw(angle)
    gaps = draw(st.lists(st.floats(15 * DEG, 170 * DEG / (n - 1)), min_size=n - 1, max_size=n - 1))
    flips = draw(st.lists(st.booleans(), min_size=n, max_size=n))
    perm = draw(st.permutations(range(n)))
    th = start + np.concatenate([[0.0], np.cumsum(gaps)]) + np.pi * np.array(flips)
    return wrap_angle(th[list(perm)])


cameras = st.builds(
    lambda fx, aspect, skew, cx, cy: np.array([[fx, skew, cx], [0.0, fx * aspect, cy], [0.0, 0.0, 1.0]]),
    fx=st.floats(500.0, 3000.0),
    aspect=st.floats(0.5, 2.0).filter(lambda a: abs(a - 1.0) > 0.01),
    skew=st.floats(-50.0, 50.0),
    cx=st.floats(0.0, 1000.0),
    cy=st.floats(0.0, 1000.0),
)


def pixel_angles(K, R, x, th, depth=5.0, length=4.0):
    """Image angles in raw pixels of an undistorted camera K, from projected 3D points.

    The angle comes from the difference of two projected pixel positions, so it carries
    their rounding (~1e-16 of the pixel coordinates): long spokes keep that below 1e-14.
    """
    P0 = depth * np.array([x[0], x[1], 1.0])
    d = spoke_directions(R, th)
    tips = P0 + length * d
    p0 = K @ P0
    p0 = p0[:2] / p0[2]
    pt = tips @ K.T
    pt = pt[:, :2] / pt[:, 2:]
    return np.arctan2(pt[:, 1] - p0[1], pt[:, 0] - p0[0])


def _rel(a, b):
    return abs(a - b) / max(abs(a), abs(b))


@settings(max_examples=200, deadline=None)
@given(pose=poses, th=spokes(4, 4), K=cameras, turns=st.lists(st.booleans(), min_size=4, max_size=4))
def test_cross_ratio_invariant_under_projection_and_intrinsics(pose, th, K, turns):
    x, R = pose
    cr3d = P.cross_ratio(*th)
    a = image_angles(R, x, th)
    apx = pixel_angles(K, R, x, th)
    assert _rel(P.cross_ratio(*a), cr3d) < 1e-13
    assert _rel(P.cross_ratio(*apx), cr3d) < 1e-13  # no intrinsics needed
    # period pi: lines or directions give the same value
    a_turned = a + np.pi * np.array(turns)
    assert _rel(P.cross_ratio(*a_turned), cr3d) < 1e-13


@settings(max_examples=200, deadline=None)
@given(pose=poses, th=spokes(4, 8))
def test_predict_from_three_lines_is_exact(pose, th):
    x, R = pose
    a = image_angles(R, x, th)
    pred = P.predict_line_angles(a[:3], th[:3], th[3:])
    assert np.max(np.abs(wrap_angle(pred - a[3:]))) < 1e-9 * DEG  # oriented directions


@settings(max_examples=100, deadline=None)
@given(pose=poses, th=spokes(4, 8), K=cameras)
def test_predict_from_three_lines_in_pixels_without_intrinsics(pose, th, K):
    x, R = pose
    apx = pixel_angles(K, R, x, th)
    pred = P.predict_line_angles(apx[:3], th[:3], th[3:])
    assert np.max(np.abs(wrap_angle(pred - apx[3:]))) < 1e-9 * DEG


@settings(max_examples=150, deadline=None)
@given(pose=poses, th=spokes(4, 8), turns=st.lists(st.booleans(), min_size=8, max_size=8))
def test_dlt_with_four_or_more_lines_is_consistent(pose, th, turns):
    """N >= 4 noise-free lines: the DLT has a 1-D null space and gives the pose's H."""
    x, R = pose
    a = image_angles(R, x, th)
    H = P.pencil_homography(a, th)
    Ht = P.homography_from_pose(R, x)
    Ht = Ht / np.linalg.norm(Ht)
    assert np.allclose(H, Ht, atol=1e-12)  # same sign: oriented inputs give an oriented H
    assert np.max(np.abs(wrap_angle(P.apply_pencil_homography(H, th) - a))) < 1e-11
    # unoriented lines: the same map up to sign, same lines
    lines = a + np.pi * np.array(turns[: th.size])
    H2 = P.pencil_homography(lines, th)
    assert min(np.abs(H2 - Ht).max(), np.abs(H2 + Ht).max()) < 1e-12
    assert np.max(np.abs(wrap_line(P.apply_pencil_homography(H2, th) - lines))) < 1e-11


def test_dlt_detects_inconsistent_fourth_line_and_weights():
    x, R = make_pose(25 * DEG, 0.4, 50 * DEG, 1.0, 0.3)
    th = np.radians([0.0, 30.0, 70.0, 110.0, 150.0])
    a = image_angles(R, x, th)
    bad = a.copy()
    bad[4] += 5 * DEG
    H = P.pencil_homography(bad, th)
    assert np.max(np.abs(wrap_line(P.apply_pencil_homography(H, th) - bad))) > 0.1 * DEG
    H0 = P.pencil_homography(bad, th, weights=[1, 1, 1, 1, 0])
    assert np.max(np.abs(wrap_angle(P.apply_pencil_homography(H0, th[:4]) - a[:4]))) < 1e-12


def test_batched_equals_one_by_one():
    rng = np.random.default_rng(2)
    th = np.radians([0.0, 35.0, 80.0, 120.0, 160.0])
    poses_ = [make_pose(*rng.uniform([0, -3, 0, -3, -3], [0.6, 3, 1.2, 3, 3])) for _ in range(6)]
    a = np.stack([image_angles(R, x, th) for x, R in poses_])
    H = P.pencil_homography(a, th)  # spoke angles broadcast against (6, 5)
    assert H.shape == (6, 2, 2)
    for k in range(6):
        assert np.allclose(H[k], P.pencil_homography(a[k], th), atol=1e-13)
    pred = P.predict_line_angles(a[:, :3], th[:3], th[3:])
    assert pred.shape == (6, 2)
    assert np.max(np.abs(wrap_angle(pred - a[:, 3:]))) < 1e-12


def test_cross_ratio_convention():
    # (l1, l2; l3, l4) = sin(a1-a3) sin(a2-a4) / (sin(a1-a4) sin(a2-a3))
    a = np.radians([0.0, 30.0, 60.0, 90.0])
    assert np.isclose(P.cross_ratio(*a), 1.5, rtol=1e-15)
    # equals the cross-ratio of the points where the lines cut the transversal y = 1
    t = 1.0 / np.tan(np.radians([10.0, 40.0, 75.0, 130.0]))  # x of each cut
    pts = (t[0] - t[2]) * (t[1] - t[3]) / ((t[0] - t[3]) * (t[1] - t[2]))
    assert np.isclose(P.cross_ratio(*np.radians([10.0, 40.0, 75.0, 130.0])), pts, rtol=1e-13)
    assert abs(P.cross_ratio(0.0, 0.5, 1.0, np.pi)) > 1e12  # lines 1 and 4 coincide


def test_degenerate_input_raises():
    th = np.radians([0.0, 40.0, 80.0])
    a = np.radians([5.0, 30.0, 70.0])
    with pytest.raises(EstimationError, match="distinct"):  # two identical lines
        P.predict_line_angles([a[0], a[0], a[2]], [th[0], th[0], th[2]], [1.0])
    with pytest.raises(EstimationError, match="distinct"):  # the same line, once reversed
        P.pencil_homography([a[0], a[0] + np.pi, a[2]], [th[0], th[0] + np.pi, th[2]])
    with pytest.raises(EstimationError, match="singular"):  # two spokes on one image line
        P.pencil_homography([a[0], a[0], a[2]], th)
    with pytest.raises(EstimationError, match="viewing ray"):  # all spokes on one image line
        P.pencil_homography([0.3, 0.3, 0.3 + np.pi, 0.3], [0.0, 0.5, 1.0, 2.0])
    with pytest.raises(EstimationError, match="at least three"):
        P.pencil_homography(a[:2], th[:2])
    with pytest.raises(InputError, match="NaN"):
        P.predict_line_angles([a[0], np.nan, a[2]], th, [1.0])
    with pytest.raises(InputError, match="NaN"):
        P.predict_line_angles(a, th, [np.nan])
    with pytest.raises(InputError, match="broadcast"):
        P.pencil_homography(a, th[:2])
    with pytest.raises(InputError, match="weights"):
        P.pencil_homography(a, th, weights=[1.0, -1.0, 1.0])


def test_line_through_and_line_meet_give_the_crossing_of_two_segments_lines():
    rng = np.random.default_rng(4)
    for _ in range(50):
        a0, a1, b0, b1 = rng.uniform(-100.0, 100.0, (4, 2))
        v = P.line_meet(P.line_through(a0, a1), P.line_through(b0, b1))
        x = v[:2] / v[2]
        # the point lies on both lines: x = a0 + s (a1 - a0) = b0 + r (b1 - b0)
        s, r = np.linalg.solve(np.c_[a1 - a0, b0 - b1], b0 - a0)
        assert np.allclose(x, a0 + s * (a1 - a0), atol=1e-8 * (1 + np.abs(x).max()))
    # parallel lines meet at infinity, in their direction
    v = P.line_meet(P.line_through([0.0, 0.0], [2.0, 1.0]), P.line_through([0.0, 3.0], [4.0, 5.0]))
    assert v[2] == 0.0 and abs(v[0] * 1.0 - v[1] * 2.0) < 1e-12
    # batched: (..., 2) points give (..., 3) lines, the same as one at a time
    p, q = rng.normal(size=(2, 5, 3, 2))
    L = P.line_through(p, q)
    assert L.shape == (5, 3, 3) and np.array_equal(L[2, 1], P.line_through(p[2, 1], q[2, 1]))
