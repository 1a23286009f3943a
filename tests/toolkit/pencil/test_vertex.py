"""The vertex (fulcrum) of a pencil of image lines: exactness, efficiency, robustness, errors.

Simulation used for docs/method.md's reference figures ("The vertex (fulcrum)"): 8 lines with
directions evenly spread over the span, first to last inclusive (np.linspace(0, span, 8));
each segment's centre lies at a distance drawn uniformly from [80, 400] px from the vertex,
independently per line and trial; noise = the line turned about its segment centre by
N(0, sigma_theta) and shifted perpendicular by N(0, sigma_c), sigma_theta = 0.1 deg,
sigma_c = 0.2 px. The figures are sqrt(E[trace CRLB]) over the trials: 0.918 px (30 deg;
ellipse 0.91 x 0.15 px along the bisector), 0.364 px (90 deg), 0.305 px (180 deg).
"""
from __future__ import annotations

import time

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pencilcal.toolkit.errors import EstimationError, InputError
from pencilcal.toolkit.pencil.vertex import (
    intersect_lines,
    lines_through,
    propagate_cov,
    segment_angle_sigma,
    segment_lines,
    vertex_crlb,
)

SIGMA_THETA = np.radians(0.1)
SIGMA_C = 0.2
LENGTH = 60.0  # segment length [px]; the noise model is given per line, so it does not matter


def _segments(vertex, phi, r, length=LENGTH):
    """Segments (..., M, 4) of direction phi (..., M) centred r (..., M) px from vertex."""
    d = np.stack([np.cos(phi), np.sin(phi)], -1)
    centre = np.asarray(vertex, float)[..., None, :] + r[..., None] * d
    return np.concatenate([centre - 0.5 * length * d, centre + 0.5 * length * d], -1)


def _perturb(rng, segments, sigma_theta, sigma_c):
    """Turn each line about its segment centre by N(0, sigma_theta), shift it by N(0, sigma_c)."""
    lines = segment_lines(segments)
    phi = np.arctan2(lines.direction[..., 1], lines.direction[..., 0])
    phi = phi + rng.normal(0.0, sigma_theta, phi.shape)
    d = np.stack([np.cos(phi), np.sin(phi)], -1)
    n = np.stack([-d[..., 1], d[..., 0]], -1)
    centre = lines.centre + rng.normal(0.0, sigma_c, phi.shape)[..., None] * n
    half = 0.5 * lines.length[..., None] * d
    return np.concatenate([centre - half, centre + half], -1)


def _fans(rng, trials, span_deg, m=8, vertex=(640.3, 360.7)):
    """Random-orientation fans: (true, noisy) segments (trials, m, 4), bisector (trials,)."""
    phi0 = rng.uniform(0.0, 2.0 * np.pi, (trials, 1))
    phi = phi0 + np.radians(np.linspace(0.0, span_deg, m))
    r = rng.uniform(80.0, 400.0, (trials, m))
    true = _segments(np.broadcast_to(vertex, (trials, 2)), phi, r)
    return true, _perturb(rng, true, SIGMA_THETA, SIGMA_C), phi0[:, 0] + np.radians(span_deg) / 2


def _outlier_lines(rng, vertex, k, miss_px=10.0):
    """k random segments within 400 px of the vertex whose lines miss it by >= miss_px."""
    out = []
    while len(out) < k:
        c = np.asarray(vertex) + rng.uniform(-400.0, 400.0, 2)
        a = rng.uniform(0.0, np.pi)
        d = np.array([np.cos(a), np.sin(a)])
        if abs(np.array([-d[1], d[0]]) @ (np.asarray(vertex) - c)) >= miss_px:
            out.append(np.concatenate([c - 0.5 * LENGTH * d, c + 0.5 * LENGTH * d]))
    return np.array(out)


# --------------------------------------------------------------------------- helpers


def test_segment_lines_convention():
    L = segment_lines([[0.0, 0.0, 3.0, 4.0], [2.0, 1.0, 2.0, -4.0]])
    np.testing.assert_allclose(np.linalg.norm(L.normal, axis=1), 1.0)
    np.testing.assert_allclose(L.length, [5.0, 5.0])
    np.testing.assert_allclose(L.centre, [[1.5, 2.0], [2.0, -1.5]])
    # both end points lie on a x + b y + c = 0
    for s, n, c in zip([[0.0, 0.0, 3.0, 4.0], [2.0, 1.0, 2.0, -4.0]], L.normal, L.offset):
        assert abs(n @ s[:2] + c) < 1e-12 and abs(n @ s[2:] + c) < 1e-12
    # normal = direction turned by +90 deg
    np.testing.assert_allclose(L.normal, np.stack([-L.direction[:, 1], L.direction[:, 0]], -1))


def test_segment_angle_sigma_matches_endpoint_noise():
    rng = np.random.default_rng(1)
    seg = np.array([10.0, 20.0, 90.0, 80.0])  # L = 100
    sigma = 0.7
    noisy = seg + rng.normal(0.0, sigma, (40000, 4))
    ang = np.arctan2(noisy[:, 3] - noisy[:, 1], noisy[:, 2] - noisy[:, 0])
    expected = float(segment_angle_sigma(seg, sigma))
    assert expected == pytest.approx(np.sqrt(2.0) * sigma / 100.0)
    assert np.std(ang) == pytest.approx(expected, rel=0.03)


def test_propagate_cov_into_normalised_coordinates():
    K = np.array([[800.0, 0.0, 320.0], [0.0, 750.0, 240.0], [0.0, 0.0, 1.0]])
    cov = np.array([[0.8, 0.3], [0.3, 0.2]])
    J = np.linalg.inv(K[:2, :2])
    out = propagate_cov(cov, J)
    np.testing.assert_allclose(out, np.diag([1 / 800, 1 / 750]) @ cov @ np.diag([1 / 800, 1 / 750]))
    stacked = propagate_cov(np.stack([cov, 2 * cov]), J)  # broadcasts over leading dims
    np.testing.assert_allclose(stacked[1], 2 * out)


# --------------------------------------------------------------------------- exactness


def test_noise_free_exact():
    v = np.array([412.25, -37.5])
    phi = np.radians([3.0, 17.0, 41.0, 80.0, 133.0, 200.0])
    segs = _segments(v, phi, np.array([80.0, 120.0, 400.0, 250.0, 95.0, 310.0]))
    for robust in (True, False):
        fit = intersect_lines(segs, SIGMA_THETA, SIGMA_C, robust=robust)
        assert np.max(np.abs(fit.vertex - v)) < 1e-9
        assert fit.inliers.all() and fit.lines_used == 6
        assert np.max(np.abs(fit.residuals)) < 1e-8


@settings(max_examples=60, deadline=None)
@given(
    vx=st.floats(-2000, 2000),
    vy=st.floats(-2000, 2000),
    phi0=st.floats(0, 2 * np.pi),
    gaps=st.lists(st.floats(3.0, 40.0), min_size=1, max_size=11),
    seed=st.integers(0, 2**31 - 1),
)
def test_noise_free_exact_property(vx, vy, phi0, gaps, seed):
    rng = np.random.default_rng(seed)
    v = np.array([vx, vy])
    phi = phi0 + np.radians(np.concatenate([[0.0], np.cumsum(gaps)]))
    phi = phi + np.pi * rng.integers(0, 2, phi.size)  # spokes on either side of the vertex
    segs = _segments(v, phi, rng.uniform(20.0, 1000.0, phi.size))
    fit = intersect_lines(segs)
    assert np.max(np.abs(fit.vertex - v)) < 1e-9
    assert fit.inliers.all()
    # order and segment orientation do not matter
    perm = rng.permutation(phi.size)
    flipped = segs[perm][:, [2, 3, 0, 1]]
    fit2 = intersect_lines(flipped)
    assert np.max(np.abs(fit2.vertex - fit.vertex)) < 1e-9


def test_deterministic_with_sampled_pairs():
    rng = np.random.default_rng(3)
    true, noisy, _ = _fans(rng, 1, 60.0, m=120)
    segs = np.concatenate([noisy[0], _outlier_lines(rng, (640.3, 360.7), 30)])
    a = intersect_lines(segs, SIGMA_THETA, SIGMA_C, max_pairs=200, seed=7)
    b = intersect_lines(segs, SIGMA_THETA, SIGMA_C, max_pairs=200, seed=7)
    np.testing.assert_array_equal(a.vertex, b.vertex)
    np.testing.assert_array_equal(a.inliers, b.inliers)
    assert not a.inliers[120:].any()


def test_two_lines_and_crlb_example():
    v = np.array([5.0, -3.0])
    segs = _segments(v, np.radians([0.0, 90.0]), np.array([150.0, 150.0]), length=100.0)
    fit = intersect_lines(segs, 0.001, 0.2)
    np.testing.assert_allclose(fit.vertex, v, atol=1e-12)
    # sigma_k^2 = 0.04 + 150^2 * 1e-6 px^2 on each axis
    np.testing.assert_allclose(fit.cov, np.eye(2) * 0.0625, atol=1e-12)
    np.testing.assert_allclose(vertex_crlb(v, segs, 0.001, 0.2), fit.cov, atol=1e-12)


# --------------------------------------------------------------------------- efficiency


@pytest.mark.slow
@pytest.mark.parametrize(
    "span_deg, reference", [(30.0, 0.92), (90.0, 0.36), (180.0, 0.31)]
)
def test_monte_carlo_reaches_bound(span_deg, reference):
    rng = np.random.default_rng(2024 + int(span_deg))
    trials = 1000
    true, noisy, bisector = _fans(rng, trials, span_deg)
    v = np.array([640.3, 360.7])
    crlb = vertex_crlb(v, true, SIGMA_THETA, SIGMA_C)  # (trials, 2, 2)
    bound = np.sqrt(np.mean(np.trace(crlb, axis1=1, axis2=2)))
    assert bound == pytest.approx(reference, rel=0.05)  # docs/method.md's figure

    err = np.empty((trials, 2))
    reported = np.empty(trials)
    for t in range(trials):
        fit = intersect_lines(noisy[t], SIGMA_THETA, SIGMA_C)
        err[t] = fit.vertex - v
        reported[t] = np.trace(fit.cov) / np.trace(crlb[t])
    rmse = np.sqrt(np.mean(np.sum(err**2, 1)))
    assert rmse / bound == pytest.approx(1.0, abs=0.10)
    assert np.all(np.abs(np.mean(err, 0)) < 4 * bound / np.sqrt(trials))  # no visible bias
    # the covariance the fit reports is the bound, evaluated at the estimate
    assert np.mean(reported) == pytest.approx(1.0, abs=0.03)

    if span_deg == 30.0:
        # error ellipse in the bisector frame: 0.91 px along the bisector, 0.15 px across
        c, s = np.cos(bisector), np.sin(bisector)
        along = c * err[:, 0] + s * err[:, 1]
        across = -s * err[:, 0] + c * err[:, 1]
        assert np.std(along) == pytest.approx(0.91, rel=0.10)
        assert np.std(across) == pytest.approx(0.15, rel=0.10)
        assert abs(np.corrcoef(along, across)[0, 1]) < 0.1


def test_default_angle_sigma_is_the_endpoint_model():
    """angle_sigma=None with offset_sigma = s/sqrt(2) models end points with sd s."""
    rng = np.random.default_rng(11)
    v = np.array([300.0, 200.0])
    s = 0.5
    trials, m = 400, 8
    phi = rng.uniform(0, 2 * np.pi, (trials, 1)) + np.radians(np.linspace(0, 90, m))
    true = _segments(np.broadcast_to(v, (trials, 2)), phi, rng.uniform(80, 400, (trials, m)), length=100.0)
    noisy = true + rng.normal(0.0, s, true.shape)
    crlb = vertex_crlb(v, true, segment_angle_sigma(true, s), s / np.sqrt(2.0))
    fits = [intersect_lines(noisy[t], offset_sigma=s / np.sqrt(2.0)) for t in range(trials)]
    err = np.array([f.vertex for f in fits]) - v
    ratio = np.sqrt(np.mean(np.sum(err**2, 1))) / np.sqrt(np.mean(np.trace(crlb, axis1=1, axis2=2)))
    assert ratio == pytest.approx(1.0, abs=0.12)


# --------------------------------------------------------------------------- robustness


@pytest.mark.slow
@pytest.mark.parametrize("span_deg", [30.0, 90.0])
def test_outliers_rejected(span_deg):
    """8 pencil lines + 2 random lines (20 % outliers) that miss the vertex by >= 10 px.

    Criterion, over 500 trials: (a) Mahalanobis distance of the error under the clean
    8-line bound, sqrt(e^T CRLB^-1 e), <= 3 in >= 95 % of the trials (98.9 % for an
    efficient estimator on clean data, chi2 with 2 dof; ~98.3 % measured for this one on
    clean data) and < 6 in every trial; (b) both outliers flagged in >= 99.5 % of the
    trials and the inlier set exactly the pencil lines in >= 97 % (at 0.999 confidence a
    clean line is dropped with probability 0.1 %); (c) the estimate equals the fit of the 8
    clean lines alone (1e-6 px) in >= 97 % of the trials: the outliers do not move it.
    Without `robust` the same data give no usable estimate.
    """
    rng = np.random.default_rng(77 + int(span_deg))
    trials = 500
    v = np.array([640.3, 360.7])
    true, noisy, _ = _fans(rng, trials, span_deg)
    crlb = vertex_crlb(v, true, SIGMA_THETA, SIGMA_C)
    maha = np.empty(trials)
    flagged = np.empty(trials, bool)
    exact = np.empty(trials, bool)
    same = np.empty(trials, bool)
    nonrobust_bad = 0
    for t in range(trials):
        segs = np.concatenate([noisy[t], _outlier_lines(rng, v, 2)])
        perm = rng.permutation(10)
        segs, is_outlier = segs[perm], perm >= 8
        fit = intersect_lines(segs, SIGMA_THETA, SIGMA_C)
        e = fit.vertex - v
        maha[t] = np.sqrt(e @ np.linalg.solve(crlb[t], e))
        flagged[t] = not fit.inliers[is_outlier].any()
        exact[t] = np.array_equal(fit.inliers, ~is_outlier)
        clean = intersect_lines(noisy[t], SIGMA_THETA, SIGMA_C)
        same[t] = np.max(np.abs(fit.vertex - clean.vertex)) < 1e-6
        assert np.all(np.abs(fit.residuals[is_outlier]) > 3.29) == flagged[t]
        if t < 100:
            try:
                e = intersect_lines(segs, SIGMA_THETA, SIGMA_C, robust=False).vertex - v
                nonrobust_bad += np.sqrt(e @ np.linalg.solve(crlb[t], e)) > 3
            except EstimationError:
                nonrobust_bad += 1
    assert np.mean(maha <= 3.0) >= 0.95
    assert np.max(maha) < 6.0
    assert np.mean(flagged) >= 0.995
    assert np.mean(exact) >= 0.97
    assert np.mean(same) >= 0.97
    assert nonrobust_bad >= 90


def test_many_lines_with_outliers():
    rng = np.random.default_rng(5)
    v = np.array([640.3, 360.7])
    true, noisy, _ = _fans(rng, 1, 90.0, m=160)
    segs = np.concatenate([noisy[0], _outlier_lines(rng, v, 40)])
    fit = intersect_lines(segs, SIGMA_THETA, SIGMA_C)
    assert not fit.inliers[160:].any()
    assert fit.lines_used >= 157
    e = fit.vertex - v
    assert np.sqrt(e @ np.linalg.solve(vertex_crlb(v, true[0], SIGMA_THETA, SIGMA_C), e)) < 4.0


def test_start_from_known_lines_gives_the_search_s_vertex():
    """`start` (the lines a video's previous frame labelled): over 300 fans of 8 lines with 2
    outliers, the vertex refined from the pencil's lines (an outlier among the given ones in
    a third of the trials: classified again, it is left out, and the search decides) has
    the search's inliers and its vertex to 1e-9 px in every trial where the search found
    the pencil; a line given that the search leaves out (near the gate) is left out too
    where that costs less."""
    rng = np.random.default_rng(11)
    v = np.array([640.3, 360.7])
    _, noisy, _ = _fans(rng, 300, 90.0)
    agree = 0
    for t in range(300):
        segs = np.concatenate([noisy[t], _outlier_lines(rng, v, 2)])
        given = np.r_[np.ones(8, bool), [t % 3 == 0, False]]
        search = intersect_lines(segs, SIGMA_THETA, SIGMA_C)
        seeded = intersect_lines(segs, SIGMA_THETA, SIGMA_C, start=given)
        if np.array_equal(search.inliers, np.r_[np.ones(8, bool), False, False]):
            assert np.array_equal(seeded.inliers, search.inliers)
            assert np.max(np.abs(seeded.vertex - search.vertex)) < 1e-9
            assert np.allclose(seeded.cov, search.cov, rtol=1e-9, atol=0)
            agree += 1
        assert seeded.rival_vertex is None
    assert agree >= 280
    # one line 3 sd off the vertex (a spoke's biased edge): the search leaves it out; so does start
    segs = np.concatenate([noisy[0], _outlier_lines(rng, v, 1, miss_px=3.0 * SIGMA_C)])
    search = intersect_lines(segs, SIGMA_THETA, SIGMA_C)
    seeded = intersect_lines(segs, SIGMA_THETA, SIGMA_C, start=np.ones(9, bool))
    assert np.array_equal(seeded.inliers, search.inliers)
    assert np.max(np.abs(seeded.vertex - search.vertex)) < 1e-9
    # lines given that agree on no point: the search's vertex
    one = intersect_lines(segs, SIGMA_THETA, SIGMA_C, start=np.eye(9, dtype=bool)[0])
    assert np.array_equal(one.inliers, search.inliers) and np.array_equal(one.vertex, search.vertex)


# --------------------------------------------------------------------------- errors


@pytest.mark.parametrize("robust", [True, False])
def test_too_few_lines(robust):
    with pytest.raises(EstimationError, match="at least two"):
        intersect_lines(np.zeros((0, 4)), robust=robust)
    with pytest.raises(EstimationError, match="at least two"):
        intersect_lines([[0.0, 0.0, 10.0, 1.0]], robust=robust)


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_non_finite_input(bad):
    segs = np.array([[0.0, 0.0, 10.0, 0.0], [0.0, 0.0, 0.0, 10.0], [0.0, 0.0, 10.0, 10.0]])
    segs[1, 2] = bad
    with pytest.raises(InputError, match="row 1 is not finite"):
        intersect_lines(segs)


def test_bad_shapes_and_values():
    good = [[0.0, 0.0, 10.0, 0.0], [0.0, 0.0, 0.0, 10.0], [0.0, 0.0, 10.0, 10.0]]
    with pytest.raises(InputError, match="shape"):
        intersect_lines(np.zeros((3, 3)))
    with pytest.raises(InputError, match="shape"):
        intersect_lines([0.0, 0.0, 1.0, 1.0])
    with pytest.raises(InputError, match="zero length"):
        intersect_lines(good + [[5.0, 5.0, 5.0, 5.0]])
    with pytest.raises(InputError, match="offset_sigma"):
        intersect_lines(good, offset_sigma=0.0)
    with pytest.raises(InputError, match="angle_sigma"):
        intersect_lines(good, angle_sigma=-0.1)
    with pytest.raises(InputError, match="angle_sigma"):
        intersect_lines(good, angle_sigma=[0.1, 0.1])
    with pytest.raises(InputError, match="offset_sigma"):
        intersect_lines(good, offset_sigma=np.nan)


@pytest.mark.parametrize("robust", [True, False])
def test_parallel_lines(robust):
    segs = np.array([[0.0, y, 100.0, y] for y in (0.0, 10.0, 25.0, 40.0)])
    with pytest.raises(EstimationError, match="parallel"):
        intersect_lines(segs, SIGMA_THETA, SIGMA_C, robust=robust)
    with pytest.raises(EstimationError, match="parallel"):  # two copies of one line
        intersect_lines(segs[[0, 0]], robust=robust)
    # numerically parallel with exact angles: ill-conditioned, refused
    tilt = np.array([[0.0, y, 100.0, y + 1e-13 * k] for k, y in enumerate((0.0, 10.0, 25.0))])
    with pytest.raises(EstimationError, match="parallel"):
        intersect_lines(tilt, 0.0, SIGMA_C, robust=robust)


@pytest.mark.parametrize("robust", [True, False])
def test_vertex_at_infinity(robust):
    """Lines that converge within their angle noise: the vertex could be anywhere far away."""
    rng = np.random.default_rng(9)
    v = np.array([640.0, 360.0])
    phi = np.radians(np.linspace(0.0, 0.05, 6))  # 0.05 deg fan, sigma_theta = 0.1 deg
    segs = _perturb(rng, _segments(v, phi, np.linspace(100, 400, 6)), SIGMA_THETA, SIGMA_C)
    with pytest.raises(EstimationError, match="infinity"):
        intersect_lines(segs, SIGMA_THETA, SIGMA_C, robust=robust)
    # even noise-free, a fan narrower than its angle noise is refused
    with pytest.raises(EstimationError, match="infinity"):
        intersect_lines(_segments(v, phi, np.linspace(100, 400, 6)), SIGMA_THETA, SIGMA_C, robust=robust)


def test_far_vertex_that_is_determined_is_returned():
    """A 10 deg fan whose vertex lies 3000 px off the segments is far, not at infinity."""
    rng = np.random.default_rng(4)
    v = np.array([-2500.0, 300.0])
    phi = np.radians(np.linspace(-5.0, 5.0, 8))
    true = _segments(v, phi, rng.uniform(2900.0, 3300.0, 8))
    fit = intersect_lines(_perturb(rng, true, SIGMA_THETA, SIGMA_C), SIGMA_THETA, SIGMA_C)
    bound = vertex_crlb(v, true, SIGMA_THETA, SIGMA_C)
    e = fit.vertex - v
    assert np.sqrt(e @ np.linalg.solve(bound, e)) < 4.0
    assert fit.chi2_infinity - fit.chi2 > 10.8


def test_speed():
    rng = np.random.default_rng(6)
    _, noisy, _ = _fans(rng, 1, 90.0, m=8)
    t = time.perf_counter()
    for _ in range(50):
        intersect_lines(noisy[0], SIGMA_THETA, SIGMA_C)
    assert (time.perf_counter() - t) / 50 < 0.01  # ~0.6 ms on a laptop core; generous


def test_lines_through_a_known_point(rng):
    """The test of intersect_lines' inliers against a given point: at the truth, lines with
    the stated noise pass 99.9% of the time (z ~ N(0, 1)); a line 5 sigma off does not;
    the point's own covariance widens the test."""
    v = np.array([300.0, 200.0])
    phi = rng.uniform(0, np.pi, 4000)
    r = rng.uniform(40, 200, 4000)
    segs = _segments(v, phi, r)
    sig = np.sqrt(SIGMA_C**2 + r**2 * SIGMA_THETA**2)  # the perpendicular sd at the vertex
    n = np.stack([-np.sin(phi), np.cos(phi)], -1)
    noisy = segs + np.tile(n * (sig * rng.standard_normal(4000))[:, None], 2)
    z, ok = lines_through(v, noisy, SIGMA_THETA, SIGMA_C)
    assert abs(np.std(z) - 1.0) < 0.05 and 0.997 < ok.mean() <= 1.0
    off = segs[:3] + np.tile(n[:3] * (5.0 * sig[:3])[:, None], 2)
    assert not lines_through(v, off, SIGMA_THETA, SIGMA_C)[1].any()
    cov = np.eye(2) * float(np.max(sig[:3])) ** 2 * 4.0
    assert lines_through(v, off, SIGMA_THETA, SIGMA_C, point_cov=cov)[1].all()


def test_rival_vertex_in_clutter_and_none_for_a_clean_pencil(rng):
    """gain: each line through the vertex adds up to T^2 (10.8). A clean pencil has no rival
    vertex; among random segments alone the best vertex is one of many (rival about as
    well supported), which orient refuses as clutter."""
    _, noisy, _ = _fans(rng, 1, 90.0, m=8)
    fit = intersect_lines(noisy[0], SIGMA_THETA, SIGMA_C)
    assert fit.rival_vertex is None and fit.rival_gain == 0.0 and 8 * 8.0 < fit.gain <= 8 * 10.83
    c = rng.uniform(0, 1000, (300, 2))
    a = rng.uniform(0, np.pi, 300)
    d = np.stack([np.cos(a), np.sin(a)], -1) * rng.uniform(10, 150, 300)[:, None]
    fit = intersect_lines(np.c_[c - d, c + d], offset_sigma=0.3)
    assert fit.rival_vertex is not None and fit.rival_gain > 0.8 * fit.gain
