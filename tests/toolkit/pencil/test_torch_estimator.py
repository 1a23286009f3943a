"""The torch batched estimator against the numpy one, and its message when torch is missing."""
from __future__ import annotations

import sys

import numpy as np
import pytest

from pencilcal.toolkit.pencil import estimator_torch as te
from pencilcal.toolkit.pencil import torch_backend as tb
from pencilcal.toolkit.geometry.angles import wrap_line
from pencilcal.toolkit.errors import EstimationError, InputError
from pencilcal.toolkit.pencil.estimator import PencilFit, fit_pencil
from pencilcal.toolkit.geometry.frames import angle_between, rotation_angle
from pencilcal.toolkit.pencil.spec import image_angles
from tests.toolkit.pencil.test_estimator import pose

HAVE_TORCH = tb.torch_available()
needs_torch = pytest.mark.skipif(not HAVE_TORCH, reason='torch/kornia not installed (pip install -e ".[torch]")')
DEG = np.pi / 180


def random_pencils(rng, T, N=8, off_max=40.0, tilt=(5.0, 80.0), noise=0.1 * DEG):
    off = np.radians(rng.uniform(0, off_max, T))
    az = rng.uniform(0, 2 * np.pi, T)
    vertex = np.tan(off)[:, None] * np.stack([np.cos(az), np.sin(az)], -1)
    R = pose(vertex, np.radians(rng.uniform(*tilt, T)), rng.uniform(0, 2 * np.pi, T), rng.uniform(0, 2 * np.pi, T))
    th = np.radians(np.arange(N) * 20.0)
    a = image_angles(R, vertex, th) + noise * rng.normal(size=(T, N))
    return a, th, vertex, R


def closer_error(fit, R):
    return np.minimum(rotation_angle(fit["R_cam_from_target"], R), rotation_angle(fit["R_twin"], R))


@needs_torch
class TestAgreement:
    def test_wrap_line_is_the_same_rule(self, rng):
        import torch

        x = np.concatenate([rng.uniform(-20, 20, 1000), [0.0, np.pi / 2, -np.pi / 2, np.pi, -np.pi, 3 * np.pi / 2]])
        got = te.wrap_line_torch(torch.as_tensor(x)).numpy()
        np.testing.assert_array_equal(got, wrap_line(x))

    def test_agrees_with_numpy(self, rng):
        """Noise, missing lines (weight 0, NaN angle), per-line sigma, vertex off axis: the
        rotation agrees to 1e-6 deg, every other field to ~1e-6 relative."""
        T = 600
        a, th, vertex, _ = random_pencils(rng, T)
        w = (rng.random(a.shape) > 0.2).astype(float)
        w[:, :3] = 1.0
        a[w == 0] = np.nan
        sigma = np.radians(rng.uniform(0.05, 0.3, a.shape))
        ref = fit_pencil(a, th, vertex, sigma=sigma, weights=w)
        got = te.fit_pencils_torch(a, th, vertex, sigma, weights=w, output="numpy")
        d = np.degrees(rotation_angle(ref.R_cam_from_target, got["R_cam_from_target"]))
        assert d.max() < 1e-6, d.max()
        assert np.degrees(rotation_angle(ref.R_twin, got["R_twin"])).max() < 1e-6
        for k in ("tilt", "tilt_sigma", "normal_sigma", "chi2", "chi2_frontal", "rms"):
            np.testing.assert_allclose(got[k], getattr(ref, k), rtol=1e-6, atol=1e-12, err_msg=k)
        # cov against the scale of each matrix: its small off-diagonal entries move with the
        # ~1e-8 rad where numpy's LM stops, like every other entry
        scale = np.abs(ref.cov).max(axis=(-1, -2), keepdims=True)
        assert (np.abs(got["cov"] - ref.cov) / scale).max() < 1e-6
        np.testing.assert_allclose(got["residuals"], ref.residuals, atol=1e-8)  # rad; 1e-6 deg
        np.testing.assert_array_equal(got["detectable"], ref.detectable)
        np.testing.assert_array_equal(got["lines_used"], ref.lines_used)
        assert got["converged"].all() and got["ok"].all() and got["ambiguous"].all()

    def test_written_out_rotation_update_is_kornias(self, rng):
        """The LM's rotation update (Rodrigues written out on (B,) tensors, exact at zero
        through torch.sinc) against kornia's axis_angle_to_rotation_matrix: the same
        rotation to rounding, from 1e-12 rad to pi."""
        import kornia
        import torch

        s = rng.normal(size=(400, 3))
        s *= (10.0 ** rng.uniform(-12, np.log10(np.pi), 400) / np.linalg.norm(s, axis=1))[:, None]
        s[0] = 0.0
        c = rng.normal(size=(400, 3))
        st, ct = torch.as_tensor(s), torch.as_tensor(c)
        got = torch.stack(te._rotate(torch, tuple(st.T), tuple(ct.T)), -1)
        R = kornia.geometry.conversions.axis_angle_to_rotation_matrix(st)
        want = (R @ ct[:, :, None])[:, :, 0]
        assert torch.allclose(got, want, rtol=0, atol=1e-14 * 10)

    def test_noise_free_three_lines_exact(self, rng):
        T = 300
        a, _, vertex, R = random_pencils(rng, T, N=3, noise=0.0)
        th = np.radians(np.cumsum(rng.uniform(20, 100, (T, 3)), -1))
        a = image_angles(R, vertex, th)
        fit = te.fit_pencils_torch(a, th, vertex, output="numpy")
        assert np.degrees(closer_error(fit, R)).max() < 1e-8

    def test_vertex_covariance_and_unoriented(self, rng):
        T = 200
        a, th, vertex, R = random_pencils(rng, T)
        cov_x = np.diag([0.002, 0.001]) ** 2
        ref = fit_pencil(a, th, vertex, sigma=0.1 * DEG, vertex_cov=cov_x)
        got = te.fit_pencils_torch(a, th, vertex, 0.1 * DEG, vertex_cov=cov_x, output="numpy")
        np.testing.assert_allclose(got["tilt_sigma"], ref.tilt_sigma, rtol=1e-6)
        np.testing.assert_allclose(got["normal_sigma"], ref.normal_sigma, rtol=1e-6)
        # lines given either way round: the normal still agrees (closer twin)
        flip = a + np.pi * rng.integers(0, 2, a.shape)
        ref = fit_pencil(flip, th, vertex, sigma=0.1 * DEG, oriented=False)
        got = te.fit_pencils_torch(flip, th, vertex, 0.1 * DEG, oriented=False, output="numpy")
        n = got["normal"]
        err = np.minimum(angle_between(n, ref.normal), angle_between(n, ref.normal_twin))
        assert np.degrees(err).max() < 1e-6

    def test_float32_is_good_enough_for_planning(self, rng):
        a, th, vertex, _ = random_pencils(rng, 500, tilt=(10.0, 80.0))
        f64 = te.fit_pencils_torch(a, th, vertex, 0.1 * DEG, output="numpy")
        f32 = te.fit_pencils_torch(a, th, vertex, 0.1 * DEG, output="numpy", dtype="float32")
        d = rotation_angle(f64["R_cam_from_target"], f32["R_cam_from_target"].astype(float))
        assert np.all(d < 0.02 * f64["normal_sigma"])  # 2% of the statistical error
        assert f32["R_cam_from_target"].dtype == np.float32

    def test_batch_shapes_and_tensor_io(self, rng):
        import torch

        a, th, vertex, _ = random_pencils(rng, 6)
        fit = te.fit_pencils_torch(a.reshape(2, 3, 8), th, vertex.reshape(2, 3, 2))
        assert fit["R_cam_from_target"].shape == (2, 3, 3, 3) and fit["tilt"].shape == (2, 3)
        assert isinstance(fit["tilt"], torch.Tensor) and fit["tilt"].dtype == torch.float64
        pf = te.to_pencil_fit(fit)
        assert isinstance(pf, PencilFit) and pf.normal.shape == (2, 3, 3)
        # chunks and worker threads do not change the answer
        a, th, vertex, _ = random_pencils(rng, 300)
        one = te.fit_pencils_torch(a, th, vertex, output="numpy")
        many = te.fit_pencils_torch(a, th, vertex, output="numpy", chunk=37, workers=2)
        np.testing.assert_allclose(one["R_cam_from_target"], many["R_cam_from_target"], atol=1e-10)

    def test_converged_judged_per_pencil(self, rng):
        """Garbage pencils iterate to max_iter; the good ones beside them still report
        converged (numpy's batched loop keeps raising their damping and says False)."""
        a, th, vertex, _ = random_pencils(rng, 400, off_max=0.0, tilt=(40.0, 40.0))
        a[:40] = rng.uniform(-np.pi, np.pi, (40, 8))
        fit = te.fit_pencils_torch(a, th, vertex, output="numpy")
        assert fit["iterations"] == 30
        assert fit["converged"][40:].all()
        assert fit["iterations_per_pencil"][40:].max() < 30

    def test_errors_as_numpy_or_masked(self):
        th = [0.0, 0.4, 0.8]
        with pytest.raises(EstimationError, match="three"):
            te.fit_pencils_torch([0.1, 0.5], [0.0, 0.4], [0.0, 0.0])
        with pytest.raises(InputError, match="finite"):
            te.fit_pencils_torch([0.1, np.nan, 0.9], th, [0.0, 0.0])
        with pytest.raises(InputError, match="sigma"):
            te.fit_pencils_torch([0.1, 0.5, 0.9], th, [0.0, 0.0], sigma=0.0)
        with pytest.raises(EstimationError, match="distinct directions"):
            te.fit_pencils_torch([0.3, 0.3, 0.3 + np.pi], th, [0.0, 0.0])
        with pytest.raises(EstimationError, match="infinity"):
            te.fit_pencils_torch([0.1, 0.5, 0.9], th, [1e9, 0.0])
        # strict=False: the bad pencils are marked, the good one is fitted
        a = np.array([[0.1, 0.5, 0.9], [0.3, 0.3, 0.3 + np.pi], [0.1, np.nan, 0.9], [0.1, 0.5, 0.9]])
        x = np.array([[0.0, 0.0], [0.0, 0.0], [0.0, 0.0], [1e9, 0.0]])
        fit = te.fit_pencils_torch(a, th, x, strict=False, output="numpy")
        assert fit["ok"].tolist() == [True, False, False, False]
        assert np.isfinite(fit["tilt"][0]) and np.isnan(fit["tilt"][1:]).all()
        assert not fit["detectable"][1:].any()


def test_without_torch_the_message_says_how_to_install(monkeypatch):
    monkeypatch.setitem(sys.modules, "torch", None)  # import torch now raises ImportError
    assert not tb.torch_available()
    with pytest.raises(ImportError) as e:
        te.fit_pencils_torch([[0.1, 0.5, 0.9]], [0.0, 0.4, 0.8], [[0.0, 0.0]])
    assert isinstance(e.value, InputError)
    msg = str(e.value)
    assert "\n" not in msg and 'pip install torch==2.13.0 && pip install -e ".[torch]"' in msg
