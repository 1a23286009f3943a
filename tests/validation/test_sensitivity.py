"""Planning maps: they reproduce docs/method.md's table, read the curves sensibly and are
reproducible; the numpy fallback gives the same numbers as the torch path."""
from __future__ import annotations

import numpy as np
import pytest

from pencilcal.toolkit.pencil import torch_backend as te
from pencilcal.toolkit.errors import InputError
from pencilcal.validation import sensitivity as sens

HAVE_TORCH = te.torch_available()


class TestRanges:
    def test_specs(self):
        assert sens.parse_range("0:80:20").tolist() == [0, 20, 40, 60, 80]
        assert sens.parse_range("0:10:3").tolist() == [0, 3, 6, 9]
        assert sens.parse_range("20,5,10,5").tolist() == [5, 10, 20]
        assert sens.parse_range("0:4:2,10").tolist() == [0, 2, 4, 10]
        assert sens.parse_range("0.1:0.3:0.1").tolist() == [0.1, 0.2, 0.3]
        assert sens.parse_range(7).tolist() == [7.0]

    @pytest.mark.parametrize("spec", ["", "a:b", "0:10", "10:0:1", "0:10:0", "0:10:-1", "1,nan"])
    def test_bad_specs(self, spec):
        with pytest.raises(InputError):
            sens.parse_range(spec, "--tilts")

    def test_setup_checks(self):
        with pytest.raises(InputError, match="three spokes"):
            sens.Setup(spokes=2)
        with pytest.raises(InputError, match="distinct line directions"):
            sens.Setup(spokes=4, step_deg=90.0)  # 0, 90, 180, 270: two lines
        with pytest.raises(InputError, match="noise"):
            sens.Setup(sigma_deg=0.0)


class TestGeometryTable:
    def test_monte_carlo_reaches_the_bound_at_20_deg(self):
        """docs/method.md: sigma 0.1 deg, 8 lines 20 deg apart: at 20 deg of tilt the bound is
        0.28 deg (tilt) and 0.40 deg (normal) and the estimator reaches it, on axis and
        20 deg off axis."""
        m = sens.tilt_offaxis_map(sens.Setup(), tilts_deg=[20.0], offaxis_deg=[0.0, 20.0], trials=1500, seed=3)
        np.testing.assert_allclose(m["crb"]["tilt_deg"][:, 0], 0.28, rtol=0.02)
        np.testing.assert_allclose(m["crb"]["normal_deg"][:, 0], 0.40, rtol=0.02)
        assert np.all((m["ratio_tilt"] >= 0.9) & (m["ratio_tilt"] <= 1.15)), m["ratio_tilt"]
        assert np.all((m["ratio_normal"] >= 0.9) & (m["ratio_normal"] <= 1.15)), m["ratio_normal"]
        assert np.all(m["mc"]["detect_rate"] > 0.99)
        assert np.all(m["mc"]["tilt_p95_deg"] > m["mc"]["tilt_median_deg"])

    def test_bound_scales_with_noise_and_is_infinite_at_zero_tilt(self):
        th = sens.Setup().spoke_angles()
        t, n = sens.crb_cells([0.0, 20.0, 20.0], 0.0, th, [0.1, 0.1, 0.2])
        assert np.isinf(t[0]) and np.isinf(n[0])
        assert t[2] == pytest.approx(2 * t[1], rel=1e-9) and n[2] == pytest.approx(2 * n[1], rel=1e-9)

    @pytest.mark.skipif(not HAVE_TORCH, reason='torch/kornia not installed (pip install -e ".[torch]")')
    def test_numpy_fallback_gives_the_same_numbers(self):
        kw = dict(tilts_deg="5,15,40", offaxis_deg="0,30", trials=200, seed=5)
        a = sens.tilt_offaxis_map(sens.Setup(), backend="torch", **kw)
        b = sens.tilt_offaxis_map(sens.Setup(), backend="numpy", **kw)
        for k in a["mc"]:
            np.testing.assert_allclose(a["mc"][k], b["mc"][k], atol=1e-6, err_msg=k)


class TestReadingCurves:
    def test_min_tilt_definition(self):
        t = [0, 10, 20, 30, 40]
        # a bump at 30 deg: the accuracy must *stay* reached, so the answer is after it
        v = [5.0, 0.8, 0.9, 1.2, 0.5]
        assert sens.min_tilt_for_accuracy(t, v, 1.0) == pytest.approx(30 + 10 * 0.2 / 0.7)
        assert sens.min_tilt_for_accuracy(t, v, 10.0) == 0.0  # reached on the whole grid
        assert np.isnan(sens.min_tilt_for_accuracy(t, v, 0.1))  # never reached
        assert np.isnan(sens.min_tilt_for_accuracy(t, [5, 4, 3, 2, np.nan], 2.5))

    def test_min_tilt_monotone_in_accuracy(self, rng):
        """A looser accuracy never asks for more tilt: on a real Monte Carlo curve and on
        random bumpy curves."""
        m = sens.tilt_offaxis_map(sens.Setup(), tilts_deg="0:80:4", offaxis_deg=[0.0], trials=300, seed=2)
        acc = np.geomspace(0.05, 5.0, 40)
        for curve in (m["mc"]["normal_rmse_deg"][0], m["mc"]["tilt_rmse_deg"][0], m["crb"]["normal_deg"][0]):
            got = np.array([sens.min_tilt_for_accuracy(m["tilts_deg"], curve, x) for x in acc])
            fin = got[np.isfinite(got)]
            assert np.all(np.diff(fin) <= 1e-12)
            assert np.all(np.isfinite(got[np.argmax(np.isfinite(got)):]))  # once reached, always
        t = np.arange(0, 81, 2.0)
        for _ in range(50):
            curve = np.exp(rng.normal(size=t.size).cumsum() * 0.3 - t / 20)
            got = [float(sens.min_tilt_for_accuracy(t, curve, x)) for x in acc]
            fin = np.array([g for g in got if np.isfinite(g)])
            assert np.all(np.diff(fin) <= 1e-12)

    def test_detection_crossings(self):
        t = [0, 2, 4, 6]
        r = np.array([[0.0, 0.2, 0.6, 1.0], [0.95, 1.0, 1.0, 1.0], [0.0, 0.0, 0.1, 0.3]])
        got = sens.detection_crossings(t, r)
        np.testing.assert_allclose(got[0], [2 + 2 * 0.75, 4 + 2 * 0.75])
        np.testing.assert_allclose(got[1], [0.0, 0.0])
        assert np.isnan(got[2]).all()


class TestDetectionThreshold:
    def test_measured_threshold_near_two_sqrt_sigma(self):
        """The 50% detection tilt sits near (a little above) the noise-level rule
        2 sqrt(sigma), and grows as sqrt(sigma): x2 for sigma x4."""
        m = sens.noise_map(sens.Setup(), sigmas_deg="0.1,0.4", tilts_deg="0:20:0.5", trials=600, seed=4)
        det = m["detection"]
        np.testing.assert_allclose(det["rule_deg"], [4.787, 9.575], rtol=1e-3)
        ratio = det["rate50_deg"] / det["rule_deg"]
        assert np.all((ratio > 1.0) & (ratio < 1.6)), ratio
        assert det["rate50_deg"][1] / det["rate50_deg"][0] == pytest.approx(2.0, rel=0.15)
        assert np.all(det["rate90_deg"] > det["rate50_deg"])
        # a frontal pencil is flagged at about the test's 1% level
        assert np.all(m["mc"]["detect_rate"][:, 0] < 0.04)


class TestMaps:
    def test_spokes_spacing(self):
        m = sens.spokes_spacing_map(sens.Setup(), spokes="3,4,8", steps_deg="10,20,90", tilts_deg="0:80:5",
                                    accuracy_deg=1.0, trials=150, seed=1)
        mt = m["min_tilt_deg"]["crb_normal"]
        assert mt.shape == (3, 3)
        assert np.isnan(mt[1, 2])  # 4 spokes 90 deg apart: only two line directions
        assert np.isfinite(mt[2, 1]) and mt[2, 1] < mt[0, 1]  # more spokes: less tilt needed
        ref = m["at_tilt_ref"]["mc_normal_rmse_deg"]
        assert ref[2, 1] < ref[0, 1] and ref[0, 1] < ref[0, 0]  # ... and a wider spread too
        assert m["curves"]["detect_rate"].shape == (3, 3, 17)

    def test_reproducible(self):
        kw = dict(tilts_deg="10,30", offaxis_deg=[10.0], trials=100)
        a = sens.tilt_offaxis_map(sens.Setup(), seed=7, **kw)
        b = sens.tilt_offaxis_map(sens.Setup(), seed=7, **kw)
        c = sens.tilt_offaxis_map(sens.Setup(), seed=8, **kw)
        np.testing.assert_array_equal(a["mc"]["normal_rmse_deg"], b["mc"]["normal_rmse_deg"])
        assert not np.array_equal(a["mc"]["normal_rmse_deg"], c["mc"]["normal_rmse_deg"])

    def test_plan_and_heatmaps(self, tmp_path):
        res = sens.plan(sens.Setup(), tilts_deg="0:60:10", offaxis_deg="0,20", trials=60, accuracy_deg=1.0,
                        maps=("tilt-offaxis", "noise", "spokes-spacing"), spokes_grid="4,8", steps_grid="20,40",
                        sigmas_grid="0.1,0.3", seed=0)
        ans = res["answer"]
        assert len(ans["per_offaxis"]) == 2 and np.isfinite(ans["min_tilt_deg"])
        assert ans["min_tilt_deg"] == max(p["mc_normal_rmse_deg"] for p in ans["per_offaxis"])
        assert "from a tilt of" in ans["text"]
        assert res["detection"]["rule_2sqrt_sigma_deg"] == pytest.approx(4.787, rel=1e-3)
        paths = sens.write_heatmaps(res, str(tmp_path / "p"))
        assert [p.rsplit("_", 1)[-1] for p in paths] == ["tilt-offaxis.png", "spokes-spacing.png", "noise.png"]
        for p in paths:
            with open(p, "rb") as f:
                assert f.read(8) == b"\x89PNG\r\n\x1a\n"
        with pytest.raises(InputError, match="already exists"):
            sens.write_heatmaps(res, str(tmp_path / "p"))

    def test_answer_below_the_grid_says_so(self):
        res = sens.plan(sens.Setup(), tilts_deg="20,40", offaxis_deg="0", trials=50, accuracy_deg=5.0)
        assert res["answer"]["below_grid"] and res["answer"]["min_tilt_deg"] == 20.0
        assert "extend --tilts downwards" in res["answer"]["text"]

    def test_bound_only(self):
        res = sens.plan(sens.Setup(), tilts_deg="0:60:10", offaxis_deg="0", trials=0, accuracy_deg=0.5)
        assert res["maps"]["tilt_offaxis"]["mc"] is None
        assert "Cramer-Rao" in res["answer"]["metric"]
        assert "measured" not in res["detection"]
