"""The exact estimator: noise-free exactness, twins, efficiency against the Cramer-Rao bound."""
from __future__ import annotations

import numpy as np
import pytest

from pencilcal.toolkit.errors import EstimationError, InputError
from pencilcal.toolkit.pencil.estimator import (
    choose_by_prior,
    crlb,
    detection_threshold,
    fit_pencil,
    max_angular_change,
    pencil_covariance,
    pencil_jacobian,
    swap_twins,
)
from pencilcal.toolkit.geometry.frames import (
    angle_between,
    normalize,
    rotation_about_axis,
    rotation_angle,
    rotation_to_z,
    twin_rotation,
)
from pencilcal.toolkit.pencil.spec import image_angles

DEG = np.pi / 180
Z = np.array([0.0, 0.0, 1.0])


def pose(vertex, tilt, psi, theta0):
    """R_cam_from_target with the given tilt against the vertex ray (docs/method.md's
    parametrisation: virtual camera along the ray, then Rz(psi) Rx(tilt) Rz(theta0))."""
    v = normalize(np.concatenate([np.asarray(vertex, float), np.ones(np.shape(vertex)[:-1] + (1,))], -1))
    Qt = np.swapaxes(rotation_to_z(v), -1, -2)
    n = np.broadcast_shapes(np.shape(psi), np.shape(theta0), np.shape(tilt))
    rz = lambda a: rotation_about_axis(np.broadcast_to(Z, n + (3,)), np.broadcast_to(a, n))
    rx = rotation_about_axis(np.broadcast_to([1.0, 0, 0], n + (3,)), np.broadcast_to(tilt, n))
    return Qt @ rz(psi) @ rx @ rz(theta0)


def closer_error(fit, R):
    return np.minimum(rotation_angle(fit.R_cam_from_target, R), rotation_angle(fit.R_twin, R))


class TestNoiseFree:
    def test_three_lines_exact(self, rng):
        """Three lines determine the pencil exactly (to 1e-8 deg), for well-posed fans: spokes
        at least 20 deg apart, tilt 5-80 deg, vertex up to 40 deg off the optical axis."""
        T = 500
        off = np.radians(rng.uniform(0, 40, T))
        az = rng.uniform(0, 2 * np.pi, T)
        vertex = np.tan(off)[:, None] * np.stack([np.cos(az), np.sin(az)], -1)
        R = pose(vertex, np.radians(rng.uniform(5, 80, T)), rng.uniform(0, 2 * np.pi, T), rng.uniform(0, 2 * np.pi, T))
        gaps = rng.uniform(20, 100, (T, 3))
        th = np.radians(np.cumsum(gaps, -1) + rng.uniform(0, 360, (T, 1)))
        a = image_angles(R, vertex, th)
        fit = fit_pencil(a, th, vertex)
        err = np.degrees(closer_error(fit, R))
        assert err.max() < 1e-8
        assert np.all(fit.converged)

    def test_twin_fits_exactly_as_well(self, rng):
        """The twin reproduces every image line and every oriented spoke direction."""
        T = 200
        vertex = rng.uniform(-0.4, 0.4, (T, 2))
        R = pose(vertex, np.radians(rng.uniform(5, 80, T)), rng.uniform(0, 6.3, T), rng.uniform(0, 6.3, T))
        th = np.radians(np.arange(6) * 25.0)
        a = image_angles(R, vertex, th)
        fit = fit_pencil(a, th, vertex)
        a1 = image_angles(fit.R_cam_from_target, vertex, th)
        a2 = image_angles(fit.R_twin, vertex, th)
        np.testing.assert_allclose(np.angle(np.exp(1j * (a1 - a))), 0, atol=1e-10)
        np.testing.assert_allclose(np.angle(np.exp(1j * (a2 - a))), 0, atol=1e-10)
        # the twins are 2 tilt apart and share the tilt
        sep = angle_between(fit.normal, fit.normal_twin)
        np.testing.assert_allclose(sep, 2 * fit.tilt, atol=1e-9)
        np.testing.assert_allclose(fit.R_twin, twin_rotation(fit.R_cam_from_target, fit.ray), atol=1e-12)

    def test_normal_points_away(self, rng):
        T = 100
        vertex = rng.uniform(-0.5, 0.5, (T, 2))
        R = pose(vertex, np.radians(rng.uniform(5, 85, T)), rng.uniform(0, 6.3, T), rng.uniform(0, 6.3, T))
        th = np.radians([0.0, 40, 90, 150])
        fit = fit_pencil(image_angles(R, vertex, th), th, vertex)
        assert np.all(np.sum(fit.normal * fit.ray, -1) > 0)
        assert np.all(np.sum(fit.normal_twin * fit.ray, -1) > 0)
        np.testing.assert_allclose(np.cos(fit.tilt), np.sum(fit.normal * fit.ray, -1), atol=1e-12)

    def test_unoriented_lines(self, rng):
        """Lines given with arbitrary direction (a or a + pi) still give the normal."""
        T = 100
        vertex = rng.uniform(-0.3, 0.3, (T, 2))
        R = pose(vertex, np.radians(rng.uniform(10, 70, T)), rng.uniform(0, 6.3, T), rng.uniform(0, 6.3, T))
        th = np.radians(np.arange(5) * 30.0)
        a = image_angles(R, vertex, th) + np.pi * rng.integers(0, 2, (T, 5))
        fit = fit_pencil(a, th, vertex, oriented=False)
        n = R[..., :, 2]
        err = np.minimum(angle_between(fit.normal, n), angle_between(fit.normal_twin, n))
        assert np.degrees(err).max() < 1e-8

    def test_batched_equals_loop(self, rng):
        vertex = rng.uniform(-0.3, 0.3, (5, 2))
        R = pose(vertex, np.radians([10, 20, 30, 40, 50.0]), rng.uniform(0, 6.3, 5), rng.uniform(0, 6.3, 5))
        th = np.radians(np.arange(8) * 20.0)
        a = image_angles(R, vertex, th) + 0.002 * rng.normal(size=(5, 8))
        batch = fit_pencil(a, th, vertex)
        for i in range(5):
            one = fit_pencil(a[i], th, vertex[i])
            np.testing.assert_allclose(one.R_cam_from_target, batch.R_cam_from_target[i], atol=1e-9)
            np.testing.assert_allclose(one.tilt_sigma, batch.tilt_sigma[i], rtol=1e-6)

    def test_convergence_is_per_pencil(self, rng):
        """Good pencils batched with slow ones still report converged (regression)."""
        vertex = rng.uniform(-0.3, 0.3, (60, 2))
        R = pose(vertex, np.radians(rng.uniform(10, 70, 60)), rng.uniform(0, 6.3, 60), rng.uniform(0, 6.3, 60))
        th = np.radians(np.arange(8) * 20.0)
        a = image_angles(R, vertex, th) + 0.002 * rng.normal(size=(60, 8))
        a[:10] = rng.uniform(-np.pi, np.pi, (10, 8))  # garbage: slow, maybe not converging
        fit = fit_pencil(a, th, vertex)
        assert fit.converged[10:].all()
        alone = fit_pencil(a[10:], th, vertex[10:])
        np.testing.assert_allclose(fit.R_cam_from_target[10:], alone.R_cam_from_target, atol=1e-8)

    def test_missing_lines_by_weight(self, rng):
        vertex = np.array([0.1, 0.2])
        R = pose(vertex, np.radians(30), 0.3, 1.0)
        th = np.radians(np.arange(8) * 20.0)
        a = image_angles(R, vertex, th)
        a[[1, 5]] = np.nan  # missing spokes may be NaN when their weight is zero
        w = np.ones(8)
        w[[1, 5]] = 0
        fit = fit_pencil(a, th, vertex, weights=w)
        assert int(fit.lines_used) == 6
        assert np.degrees(closer_error(fit, R)) < 1e-8


class TestStatistics:
    """Seeded Monte Carlo, 1000+ trials per point, against docs/method.md's reference table."""

    SIGMA = 0.1 * DEG
    TH = np.radians(np.arange(8) * 20.0)

    def run(self, rng, tilt_deg, off_deg, T=1500):
        vertex = np.array([np.tan(np.radians(off_deg)), 0.0])
        R = pose(vertex, np.radians(tilt_deg), rng.uniform(0, 2 * np.pi, T), rng.uniform(0, 2 * np.pi, T))
        a = image_angles(R, vertex, self.TH) + self.SIGMA * rng.normal(size=(T, 8))
        fit = fit_pencil(a, self.TH, vertex, sigma=self.SIGMA)
        _, bound_tilt, bound_normal = crlb(R, vertex, self.TH, self.SIGMA)
        return R, fit, bound_tilt, bound_normal

    @pytest.mark.parametrize("off", [0.0, 20.0])
    @pytest.mark.parametrize("tilt", [10, 20, 40, 60])
    def test_efficiency_and_coverage(self, rng, tilt, off):
        R, fit, bound_tilt, bound_normal = self.run(rng, tilt, off)
        err = fit.tilt - np.radians(tilt)
        ratio = np.sqrt(np.mean(err**2)) / np.sqrt(np.mean(bound_tilt**2))
        assert 0.9 <= ratio <= 1.15, ratio
        n = R[..., :, 2]
        nerr = np.minimum(angle_between(fit.normal, n), angle_between(fit.normal_twin, n))
        nratio = np.sqrt(np.mean(nerr**2)) / np.sqrt(np.mean(bound_normal**2))
        assert 0.9 <= nratio <= 1.15, nratio
        # reported sigmas mean what they say: 68% +- 5% of tilt errors within one sigma
        cover = np.mean(np.abs(err) < fit.tilt_sigma)
        assert 0.63 <= cover <= 0.73, cover
        assert fit.detectable.mean() > 0.99

    def test_reference_bounds(self):
        """The bound itself matches docs/method.md's table (averaged over in-plane angles)."""
        table = {5: 1.16, 10: 0.58, 20: 0.28, 40: 0.123, 60: 0.063}
        psi, th0 = np.meshgrid(np.linspace(0, np.pi, 60, endpoint=False), np.linspace(0, 2 * np.pi, 60, endpoint=False))
        for g, ref in table.items():
            R = pose(np.zeros(2), np.radians(g), psi.ravel(), th0.ravel())
            _, b, _ = crlb(R, np.zeros(2), self.TH, self.SIGMA)
            assert np.degrees(np.sqrt(np.mean(b**2))) == pytest.approx(ref, rel=0.02)

    def test_frontal_not_detectable(self, rng):
        """A frontal pencil: median tilt ~3.75 deg, flagged not detectable in >= 90% of trials."""
        T = 1500
        R = pose(np.zeros(2), 0.0, rng.uniform(0, 2 * np.pi, T), 0.0)
        a = image_angles(R, np.zeros(2), self.TH) + self.SIGMA * rng.normal(size=(T, 8))
        fit = fit_pencil(a, self.TH, np.zeros(2), sigma=self.SIGMA)
        assert fit.detectable.mean() <= 0.10
        assert np.degrees(np.median(fit.tilt)) == pytest.approx(3.75, abs=0.25)
        assert np.degrees(np.percentile(fit.tilt, 95)) == pytest.approx(5.3, abs=0.4)

    def test_few_lines_cost_a_lot(self, rng):
        """4 lines 10 deg apart at tilt 30 deg: ~2.3 deg RMSE, against ~0.16 deg for 12 lines."""
        T = 1500
        out = {}
        for name, th in (("few", np.radians([0.0, 10, 20, 30])), ("many", np.radians(np.arange(12) * 15.0))):
            R = pose(np.zeros(2), np.radians(30), rng.uniform(0, 2 * np.pi, T), rng.uniform(0, 2 * np.pi, T))
            a = image_angles(R, np.zeros(2), th) + self.SIGMA * rng.normal(size=(T, th.size))
            fit = fit_pencil(a, th, np.zeros(2), sigma=self.SIGMA)
            out[name] = np.degrees(np.sqrt(np.mean((fit.tilt - np.radians(30)) ** 2)))
        assert out["few"] > 10 * out["many"]
        assert 0.1 < out["many"] < 0.25


class TestVertexUncertainty:
    def test_vertex_covariance_is_carried(self, rng):
        """With a noisy vertex the reported sigma grows and still covers the errors."""
        T = 1500
        sigma = 0.1 * DEG
        th = np.radians(np.arange(8) * 20.0)
        vertex = np.array([0.2, -0.1])
        cov_x = np.diag([0.002, 0.001]) ** 2  # normalised units, ~2 px at f = 1000
        R = pose(vertex, np.radians(30), rng.uniform(0, 6.3, T), rng.uniform(0, 6.3, T))
        a = image_angles(R, vertex, th) + sigma * rng.normal(size=(T, 8))
        noisy_vertex = vertex + rng.multivariate_normal(np.zeros(2), cov_x, T)
        fit0 = fit_pencil(a, th, noisy_vertex, sigma=sigma)
        fit = fit_pencil(a, th, noisy_vertex, sigma=sigma, vertex_cov=cov_x)
        assert np.all(fit.tilt_sigma > fit0.tilt_sigma)
        err = fit.tilt - np.radians(30)
        assert 0.62 <= np.mean(np.abs(err) < fit.tilt_sigma) <= 0.74


class TestJacobian:
    def test_against_finite_differences(self, rng):
        from pencilcal.toolkit.geometry.frames import rotation_from_rotvec

        vertex = np.array([0.15, -0.2])
        R = pose(vertex, np.radians(35), 0.4, 1.1)
        th = np.radians([0.0, 30, 70, 120])
        a, J, Jx = pencil_jacobian(R, vertex, th)
        h = 1e-7
        for i in range(3):
            e = np.zeros(3)
            e[i] = h
            ap, _, _ = pencil_jacobian(rotation_from_rotvec(e) @ R, vertex, th)
            am, _, _ = pencil_jacobian(rotation_from_rotvec(-e) @ R, vertex, th)
            np.testing.assert_allclose((ap - am) / (2 * h), J[:, i], atol=1e-7)
        for i in range(2):
            e = np.zeros(2)
            e[i] = h
            ap, _, _ = pencil_jacobian(R, vertex + e, th)
            am, _, _ = pencil_jacobian(R, vertex - e, th)
            np.testing.assert_allclose((ap - am) / (2 * h), Jx[:, i], atol=1e-6)


class TestThresholds:
    def test_max_angular_change(self):
        """docs/method.md: 0.018 deg at 2 deg, 0.11 at 5, 0.44 at 10, 1.78 at 20."""
        got = np.degrees(max_angular_change(np.radians([2.0, 5, 10, 20])))
        np.testing.assert_allclose(got, [0.018, 0.11, 0.44, 1.78], rtol=0.05)

    def test_detection_threshold(self):
        """It equals sigma where ~2 sqrt(sigma): 4.8 deg at sigma = 0.1 deg."""
        g = detection_threshold(np.radians(0.1))
        assert np.degrees(g) == pytest.approx(4.8, abs=0.1)
        assert max_angular_change(g) == pytest.approx(np.radians(0.1), rel=1e-6)


class TestTwinChoice:
    def test_prior_picks_the_right_twin(self, rng):
        vertex = np.array([0.1, 0.05])
        th = np.radians(np.arange(8) * 20.0)
        R = pose(vertex, np.radians(25), 0.7, 0.2)
        fit = fit_pencil(image_angles(R, vertex, th), th, vertex)
        prior = rotation_about_axis(rng.normal(size=3), np.radians(3)) @ R  # a board pose 3 deg off
        which = choose_by_prior(fit.R_cam_from_target, fit.R_twin, prior)
        chosen = swap_twins(fit, which, th, vertex, np.radians(0.1), resolved_by="prior")
        assert np.degrees(rotation_angle(chosen.R_cam_from_target, R)) < 1e-8
        assert not chosen.ambiguous and chosen.resolved_by == "prior"


class TestBadInput:
    def test_fewer_than_three_lines(self):
        with pytest.raises(EstimationError, match="three"):
            fit_pencil([0.1, 0.5], [0.0, 0.4], [0.0, 0.0])

    def test_nan_and_inf(self):
        with pytest.raises(InputError, match="finite"):
            fit_pencil([0.1, np.nan, 0.9], [0.0, 0.4, 0.8], [0.0, 0.0])
        with pytest.raises(InputError, match="finite"):
            fit_pencil([0.1, 0.5, 0.9], [0.0, 0.4, 0.8], [np.inf, 0.0])

    @pytest.mark.parametrize("a", [[0.3, 0.3, 0.3 + np.pi], [0.3, 0.3 + 1e-15, 0.3 - 1e-15, 0.3 + np.pi]])
    def test_parallel_lines(self, a):
        """Lines that all share one image direction do not determine a pencil. (Two lines
        along one direction and a third elsewhere do: an edge-on pencil with one spoke on
        the viewing ray.)"""
        with pytest.raises(EstimationError, match="distinct directions"):
            fit_pencil(a, np.radians([0.0, 40, 80, 120])[: len(a)], [0.05, -0.02])

    def test_vertex_at_infinity(self):
        with pytest.raises(EstimationError, match="infinity"):
            fit_pencil([0.1, 0.5, 0.9], [0.0, 0.4, 0.8], [1e9, 0.0])

    def test_bad_sigma(self):
        with pytest.raises(InputError, match="sigma"):
            fit_pencil([0.1, 0.5, 0.9], [0.0, 0.4, 0.8], [0.0, 0.0], sigma=0.0)


class TestSinglePencilPath:
    """One pencil is fitted on Python floats (toolkit/pencil/scalar.py); it must agree with the
    batched numpy path on every field."""

    def test_agrees_with_batched(self, rng):
        for trial in range(60):
            N = int(rng.integers(3, 13))
            vertex = rng.uniform(-0.5, 0.5, 2)
            R = pose(vertex, np.radians(rng.uniform(0, 80)), rng.uniform(0, 6.3), rng.uniform(0, 6.3))
            th = np.sort(rng.uniform(0, 2 * np.pi, N))
            a = image_angles(R, vertex, th) + np.radians(0.1) * rng.normal(size=N)
            s = np.radians(rng.uniform(0.05, 0.3, N))
            cov = np.diag(rng.uniform(1e-7, 1e-5, 2)) if trial % 2 else None
            one = fit_pencil(a, th, vertex, sigma=s, vertex_cov=cov)
            two = fit_pencil(a[None], th, vertex[None], sigma=s[None], vertex_cov=None if cov is None else cov[None])
            for field in ("R_cam_from_target", "R_twin", "tilt", "tilt_sigma", "normal_sigma", "cov", "residuals",
                          "rms", "chi2", "chi2_frontal"):
                np.testing.assert_allclose(getattr(one, field), getattr(two, field)[0], rtol=1e-6, atol=1e-9,
                                           err_msg=field)
            assert bool(one.detectable) == bool(two.detectable[0])

    def test_missing_lines_and_degenerate(self):
        th = np.radians([0.0, 30, 60, 90, 120])
        a = np.radians([1.0, 31, 62, 88, 121])
        w = np.array([1, 1, 0, 1, 1])
        one = fit_pencil(a, th, [0.0, 0.0], weights=w)
        two = fit_pencil(a[None], th, np.zeros((1, 2)), weights=w[None])
        np.testing.assert_allclose(one.residuals, two.residuals[0], atol=1e-12)
        assert one.residuals[2] == 0 and int(one.lines_used) == 4
        with pytest.raises(EstimationError, match="distinct directions"):
            fit_pencil([0.3, 0.3, 0.3], [0.0, 0.4, 0.8], [0.0, 0.0])


class TestErrorsWiderThanWeights:
    def test_sigma_error_covers_the_weighted_fits_errors(self, rng):
        """Lines weighted by sigma whose errors are wider on the short ones (sds 0.05 deg
        weighted, 0.05-0.5 deg drawn: a star's near edges turned by what they share): the
        fit's own covariance leaves out most of the error, the covariance under sigma_error
        covers it (68 +- 5 % of the tilt errors within one sigma), and sigma_error = sigma
        is the fit's own."""
        T = 1500
        th = np.radians(np.arange(12) * 30.0)
        sigma = np.full(12, 0.05 * DEG)
        wide = sigma * np.array([10.0, 1, 1, 6, 1, 1, 10, 1, 1, 6, 1, 1])
        R = pose(np.zeros(2), np.radians(35), rng.uniform(0, 6.3, T), rng.uniform(0, 6.3, T))
        a = image_angles(R, np.zeros(2), th) + wide * rng.normal(size=(T, 12))
        fit = fit_pencil(a, th, np.zeros(2), sigma=sigma)
        err = np.abs(fit.tilt - np.radians(35))
        _, s_tilt, s_norm = pencil_covariance(fit.R_cam_from_target, np.zeros(2), th, sigma, sigma_error=wide)
        assert np.mean(err < fit.tilt_sigma) < 0.4
        assert 0.63 <= np.mean(err < s_tilt) <= 0.73
        assert np.all(s_norm > fit.normal_sigma)
        same = pencil_covariance(fit.R_cam_from_target, np.zeros(2), th, sigma, sigma_error=sigma)
        np.testing.assert_allclose(same[1], fit.tilt_sigma, rtol=1e-9)

    def test_the_vertex_term_is_the_fits_own_response_whatever_the_errors(self):
        """Errors k times the weights' sds on every line widen the lines' part of the
        covariance by k^2 and leave the vertex's part as it was: the fit's response to the
        vertex is H^-1 J^T W Jx, the weights', not the errors' (it was scaled by k^2, its
        variance by k^4: a dartboard whose lines scatter 5.8 times their sds read 1.35 deg for
        0.30)."""
        th = np.radians(np.arange(12) * 30.0)
        sigma = np.full(12, 0.05 * DEG)
        R = pose(np.array([0.05, -0.03]), np.radians(35), 0.4, 1.1)
        x = np.array([0.05, -0.03])
        Cx = np.diag([4e-6, 1e-6])
        k = 3.0
        lines = pencil_covariance(R, x, th, sigma)[0]
        both = pencil_covariance(R, x, th, sigma, vertex_cov=Cx)[0]
        wide = pencil_covariance(R, x, th, sigma, vertex_cov=Cx, sigma_error=k * sigma)[0]
        np.testing.assert_allclose(wide, k * k * lines + (both - lines), rtol=1e-9, atol=1e-18)
