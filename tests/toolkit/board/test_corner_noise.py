"""Correlated corner errors: the REML fit recovers a simulated model, and the sandwich
covariance of a pose matches its Monte Carlo scatter under such errors."""
from __future__ import annotations

import numpy as np
import pytest

from pencilcal.toolkit.board.corner_noise import WHITE, CornerNoise, CornerView, correlated_covariance, \
    fit_corner_noise, kernel
from pencilcal.toolkit.camera.model import Camera
from pencilcal.toolkit.errors import InputError
from pencilcal.toolkit.geometry.frames import rotation_about_axis
from pencilcal.validation.pnp import estimate_pose, refine_pose
from pencilcal.validation.pnp.refine import residuals

CAM = Camera("opencv", 720, 576, [[830.0, 0, 360.0], [0, 900.0, 288.0], [0, 0, 1]], [-0.3, 0.4, 0.0, 0.0])
J_, I_ = np.mgrid[0:10, 0:14]
BOARD = np.stack([I_.ravel() * 5.0, J_.ravel() * 5.0, np.zeros(I_.size)], -1)  # mm


def _view(rng):
    R = rotation_about_axis(rng.normal(size=3), np.radians(rng.uniform(10, 40)))
    t = np.array([rng.uniform(-10, 10) - 32, rng.uniform(-8, 8) - 22, rng.uniform(90, 130)])
    return R, t


def _noisy(u, rng, sigma, noise):
    """Corner errors of the model: white sigma plus sigma^2 c k(l), per axis."""
    S = sigma**2 * (np.eye(len(u)) + noise.ratio * kernel(u, noise.length_px))
    L = np.linalg.cholesky(S + 1e-12 * np.eye(len(u)))
    return u + (L @ rng.normal(size=(len(u), 2)))


def _views(noise, n, seed, sigma=0.3):
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        R, t = _view(rng)
        u = CAM.project(BOARD @ R.T + t)
        obs = _noisy(u, rng, sigma, noise)
        R1, t1, _ = refine_pose(CAM, BOARD, obs, R, t)
        r, J, _ = residuals(CAM, BOARD, obs, R1, t1)
        out.append(CornerView(obs, r, J))
    return out


def test_fit_recovers_a_correlated_model():
    truth = CornerNoise(0.3, 150.0)
    fit = fit_corner_noise(_views(truth, 40, seed=1), CAM.size)
    assert fit.log_likelihood_gain > 10
    assert 0.5 * truth.ratio < fit.ratio < 2.0 * truth.ratio
    assert 0.6 * truth.length_px < fit.length_px < 1.6 * truth.length_px


def test_white_errors_give_no_correlated_part():
    fit = fit_corner_noise(_views(WHITE, 30, seed=2), CAM.size)
    assert fit.ratio < 0.02 and fit.log_likelihood_gain < 3.0


def test_sandwich_matches_the_scatter_under_correlated_errors():
    """Poses from corners with correlated errors scatter as the sandwich says (and far
    more than the white-noise covariance says)."""
    noise = CornerNoise(0.3, 150.0)
    rng = np.random.default_rng(3)
    R, t = _view(rng)
    u = CAM.project(BOARD @ R.T + t)
    devs, covs, white = [], [], []
    for _ in range(300):
        obs = _noisy(u, rng, 0.3, noise)
        res = estimate_pose(BOARD, obs, CAM, corner_noise=noise, intrinsics_cov=None)
        devs.append(np.r_[np.linalg.norm(res.R_cam_from_target - R) / np.sqrt(2), res.t_cam_from_target - t])
        covs.append(res.cov_total)
        white.append(res.cov)
    d = np.array(devs)[:, 1:]
    emp = np.cov(d.T)
    pred = np.mean(covs, 0)[3:, 3:]
    ratio = np.sqrt(np.trace(emp) / np.trace(pred))
    assert 0.85 < ratio < 1.18, ratio
    assert np.trace(np.mean(white, 0)[3:, 3:]) < 0.5 * np.trace(pred)


def test_covariance_reduces_to_white_without_correlation():
    views = _views(WHITE, 1, seed=4)
    v = views[0]
    cov, s = correlated_covariance(v.jacobian, v.residuals, v.points, CornerNoise(0.0, 100.0))
    H = v.jacobian.T @ v.jacobian
    rr = v.residuals.ravel()
    np.testing.assert_allclose(cov, (rr @ rr) / (rr.size - 6) * np.linalg.inv(H), rtol=1e-9)


def test_records_round_trip_and_are_checked():
    n = CornerNoise(0.2, 180.0, 40, 4000, 30.0)
    assert CornerNoise.from_dict(n.to_dict()) == n
    with pytest.raises(InputError, match="ratio"):
        CornerNoise(-1.0, 10.0)
    with pytest.raises(InputError, match="corner_noise"):
        CornerNoise.from_dict({"kernel": "matern"}, "cam.json")
