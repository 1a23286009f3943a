"""The chapter's experiments (validation/experiments/).

Image-free checks first: with noise-free lines every experiment recovers the reference
exactly (vertex 20 deg off axis, so the move into the plane orthogonal to the vertex ray is
exercised), the single-angle sd is the chapter's formula, and on hundreds of frames near
zero tilt the threshold experiment reproduces docs/method.md's figures. Then a small rendered
tilt sweep (`pencilcal simulate` + `pencilcal validate`, ~11 s) through all three.
"""
from __future__ import annotations

import json
import math

import numpy as np
import pytest
from click.testing import CliRunner

from pencilcal.toolkit.pencil.chapter import aligned_angles
from pencilcal.toolkit.errors import EstimationError, InputError
from pencilcal.toolkit.io.files import write_json
from pencilcal.toolkit.pencil.single_angle import single_angle_tilt
from pencilcal.validation import experiments as ex
from pencilcal.validation.experiments.detection import _crossing


# ------------------------------------------------------------------ image-free checks
def test_sd_on_line_is_the_chapter_formula_with_geometry_numbers():
    # docs/method.md: 2.3 deg at 5 deg, 0.55 at 20, 0.14 at 60 (theta 45 deg, sigma 0.1 deg)
    sd = np.degrees(ex.sd_on_line(np.radians([5.0, 20.0, 60.0]), math.radians(45), math.radians(0.1)))
    assert np.allclose(sd, [2.3, 0.55, 0.14], rtol=0.04)
    for g, th in ((10.0, 20.0), (35.0, 60.0), (70.0, 80.0)):
        a = math.atan(math.tan(math.radians(th)) * math.cos(math.radians(g)))
        r = single_angle_tilt(a, math.radians(th), "on_line", sigma=math.radians(0.1))
        assert r.sigma[0] == pytest.approx(float(ex.sd_on_line(math.radians(g), math.radians(th), math.radians(0.1))),
                                           rel=1e-9)
    assert np.isinf(ex.sd_on_line(0.0, 0.5, 0.001))


@pytest.fixture(scope="module")
def exact_offaxis():
    """Noise-free lines, tilt axis on a spoke (30 deg), vertex 20 deg off the optical axis."""
    return ex.synthetic_validation(np.arange(0.0, 80.0, 5.0), sigma_deg=1e-9, axis_deg=30.0, offaxis_deg=20.0)


def test_noise_free_single_angle_is_exact_off_axis(exact_offaxis):
    r = ex.single_angle(exact_offaxis)
    assert r["status"] == "ok" and r["sequence_axis_deg"] == pytest.approx(30.0, abs=1e-6)
    on = [p for p in r["on_line"]["pairs"] if p["reference_tilt_deg"] >= 5.0]
    assert on and all(p["status"] == "unique" for p in on)
    assert max(abs(p["error_deg"][0]) for p in on) < 1e-5
    assert {p["spokes"][0] for p in on} == {5}  # the spoke at 30 deg is the axis
    # known axis: one of the returned roots is the reference (two roots are both reported)
    kn = [p for p in r["known"]["pairs"] if p["reference_tilt_deg"] >= 5.0]
    assert {p["status"] for p in kn} <= {"unique", "two_roots"}
    assert max(min(abs(e) for e in p["error_deg"]) for p in kn) < 1e-5
    for p in kn:
        assert len(p["gamma_deg"]) == len(p["error_deg"]) == (2 if p["status"] == "two_roots" else 1)
    # unknown axis: only a bound, and it holds (at zero tilt acos turns 1e-9 of noise into 5e-4 deg)
    un = r["unknown"]["pairs"]
    assert {p["status"] for p in un} == {"lower_bound"}
    assert all(p["error_deg"] == [] and p["bound_minus_reference_deg"] <= 1e-3 for p in un)


def test_noise_free_distribution_is_exact_off_axis(exact_offaxis):
    r = ex.distribution(exact_offaxis, strides=(1, 2, 3))
    a = r["angles"]
    assert a["residual_max_abs_deg"] < 1e-6
    for ln in a["lines"]:
        th, g = math.radians(ln["theta_from_axis_deg"]), math.radians(ln["reference_tilt_deg"])
        # the angular variation is the chapter's eq. 6 in the plane orthogonal to the ray
        assert ln["variation_predicted_deg"] == pytest.approx(math.degrees(aligned_angles(th, g) - th), abs=1e-9)
        assert ln["variation_measured_deg"] == pytest.approx(ln["variation_predicted_deg"], abs=1e-6)
    fits = [f for f in r["spacing"]["fits"] if f["reference_tilt_deg"] >= 5.0]
    assert fits and max(f["normal_error_closer_deg"] for f in fits) < 1e-5
    assert [s["spacing_deg"] for s in r["spacing"]["strides"]] == pytest.approx([20.0, 40.0, 60.0])


@pytest.fixture(scope="module")
def near_zero():
    """300 frames from 0 to 8 deg of tilt, 8 spokes, sigma 0.1 deg (docs/method.md's set-up)."""
    v = ex.synthetic_validation(np.repeat(np.arange(0.0, 8.01, 0.25), 9)[:300], sigma_deg=0.1, seed=4)
    return ex.threshold(v, n_boot=300, trials=300, seed=1)


def test_threshold_reproduces_the_detection_rule(near_zero):
    r = near_zero
    th = r["theory"]
    assert th["two_sqrt_sigma_deg"] == pytest.approx(4.79, abs=0.01)
    assert th["detection_threshold_deg"] == pytest.approx(th["two_sqrt_sigma_deg"], rel=0.01)
    d = r["detection"]
    assert r["status"] == "ok" and d["status"] == "ok"
    # the likelihood-ratio test needs a little more than "change = sigma"
    assert 0.9 < d["tilt50_deg"] / th["two_sqrt_sigma_deg"] < 1.4
    assert d["interval_deg"][0] <= d["tilt50_deg"] <= d["interval_deg"][1]
    assert abs(d["tilt50_deg"] - th["predicted_detect50_deg"]) < 0.6
    n = r["noise_level"]
    assert n["status"] == "ok" and abs(n["tilt50_deg"] - th["predicted_noise50_deg"]) < 0.8


def test_threshold_reproduces_the_frontal_noise_floor(near_zero):
    f = near_zero["frontal"]
    assert f["status"] == "ok" and f["count"] >= 50
    assert f["geometry"]["median_deg"] == pytest.approx(3.75, rel=1e-6)  # sigma is exactly 0.1 deg
    assert f["monte_carlo"]["median_deg"] == pytest.approx(3.75, rel=0.1)
    assert f["monte_carlo"]["p95_deg"] == pytest.approx(5.3, rel=0.15)
    assert f["measured_median_deg"] == pytest.approx(3.75, rel=0.25)
    assert f["detectable"] <= 0.1 * f["count"]


def test_insufficient_data_is_said_not_invented():
    v = ex.synthetic_validation(np.arange(20.0, 61.0, 10.0), sigma_deg=0.05, axis_deg=0.0, seed=2)
    t = ex.threshold(v, n_boot=100, trials=50)
    assert t["status"] == "insufficient data" and "reason" in t
    for k in ("detection", "noise_level", "frontal"):
        assert t[k]["status"] == "insufficient data" and t[k]["reason"]
        assert "tilt50_deg" not in t[k]
    assert t["detection"]["upper_bound_deg"] == pytest.approx(20.0)
    s = ex.single_angle(v)  # axis 0 deg: no spoke of the +-70 deg fan lies on it
    assert s["status"] == "partial" and s["on_line"]["status"] == "insufficient data"
    assert "tilt axis" in s["on_line"]["reason"] and s["known"]["status"] == "ok"


def test_frames_without_labels_or_lines_are_skipped_with_reasons():
    v = ex.synthetic_validation([10.0, 20.0, 30.0], sigma_deg=0.05)
    v["frames"][0]["orient"]["exact"]["labels_ambiguous"] = True
    del v["frames"][1]["orient"]["exact"]["lines"]
    frames, skipped = ex.usable_frames(v)
    assert [f.image for f in frames] == ["0002.png"]
    assert "labels ambiguous" in skipped[0]["reason"] and "lines" in skipped[1]["reason"]
    del v["frames"][2]["R_ref"]
    with pytest.raises(EstimationError, match="no frame"):
        ex.distribution(v)


def test_load_validation_refuses_other_files(tmp_path):
    with pytest.raises(InputError, match="not found"):
        ex.load_validation(tmp_path / "none.json")
    p = tmp_path / "bad.json"
    p.write_text("{not json")
    with pytest.raises(InputError, match="not valid JSON"):
        ex.load_validation(p)
    p.write_text(json.dumps({"frames": []}))
    with pytest.raises(InputError, match="not a validation file"):
        ex.load_validation(p)
    p.write_text(json.dumps([1, 2]))
    with pytest.raises(InputError, match="not a validation file"):
        ex.load_validation(p)


def test_crossing_of_separated_and_noisy_indicators():
    c, br = _crossing([0, 1, 2, 3, 4, 5], [0, 0, 0, 1, 1, 1])
    assert c == pytest.approx(2.5) and br == (2.0, 3.0)
    c, br = _crossing([0, 1, 2, 3, 4, 5], [0, 1, 0, 1, 1, 1])  # pooled: 0, .5, .5, 1
    assert 0.0 < c <= 2.0
    assert _crossing([1, 2, 3], [1, 1, 1]) == (None, None)


# ---------------------------------------------------------- a rendered tilt sweep
@pytest.fixture(scope="module")
def sweep(tmp_path_factory):
    """21 frames 0-60 deg about an axis through a spoke (--axis 30), 640x360, validated."""
    from pencilcal.cli.simulate import simulate
    from pencilcal.cli.validate import validate

    d = tmp_path_factory.mktemp("experiments")
    r = CliRunner().invoke(simulate, [str(d / "ts"), "--scenario", "tilt-sweep", "--frames", "21", "--seed", "3",
                                      "--size", "640x360", "--axis", "30", "--max-tilt", "60", "-q"])
    assert r.exit_code == 0, r.output
    r = CliRunner().invoke(validate, [str(d / "ts"), "--models", "exact", "--methods", "sqpnp", "-o",
                                      str(d / "v.json"), "-q"])
    assert r.exit_code == 0, r.output
    return ex.load_validation(d / "v.json")


def test_sweep_single_angle_errors_match_their_sd_and_the_curve(sweep):
    r = ex.single_angle(sweep)
    on = r["on_line"]
    assert on["status"] == "ok" and on["counts"]["unique"] >= 60
    u = on["unique"]["above"]
    assert u["count"] >= 50
    assert 0.6 < u["z_rms"] < 1.8 and 0.35 < u["z_median_abs"] < 1.1
    # binned RMS error against the chapter's curve at the bin centre, sigma_alpha measured
    sa = math.radians(r["theory"]["sigma_alpha_deg"])
    pairs = [p for p in on["pairs"] if p["status"] == "unique" and p["reference_tilt_deg"] >= 10]
    for lo in (10, 30, 50):
        sel = [p for p in pairs if lo <= p["reference_tilt_deg"] < lo + 20]
        err = math.sqrt(np.mean([p["error_deg"][0] ** 2 for p in sel]))
        sd = math.sqrt(np.mean([math.degrees(float(ex.sd_on_line(math.radians(p["reference_tilt_deg"]),
                                                                  math.radians(p["theta_deg"]), sa))) ** 2
                                for p in sel]))
        assert 0.35 < err / sd < 2.5, (lo, err, sd)
    # every status is counted; none is turned into a number it does not have
    for case in ("on_line", "known", "unknown"):
        s = r[case]
        assert sum(s["counts"].values()) == len(s["pairs"])
        for p in s["pairs"]:
            if p["status"] in ("inconsistent", "no information"):
                assert p["gamma_deg"] == [] and p["error_deg"] == []
    assert set(r["unknown"]["counts"]) == {"lower_bound"}


def test_sweep_distribution_matches_projection_and_the_bound(sweep):
    r = ex.distribution(sweep, strides=(1, 2, 3))
    a = r["angles"]
    assert a["count"] >= 100
    assert 0.7 < a["z_rms"] < 1.5 and a["z_within_3"] > 0.97
    assert a["residual_rms_deg"] < 4 * r["sigma_line_deg"]
    # the angular change grows with the tilt as the exact model says
    mv = sorted(a["max_variation"], key=lambda m: m["reference_tilt_deg"])
    big = [m for m in mv if m["reference_tilt_deg"] >= 20]
    assert all(abs(m["max_variation_measured_deg"] - m["max_variation_predicted_deg"]) < 1.0 for m in big)
    assert all(m["max_variation_predicted_deg"] <= m["max_angular_change_deg"] + 1e-9 for m in mv)
    rows = {s["stride"]: s for s in r["spacing"]["strides"]}
    assert [rows[m]["spacing_deg"] for m in (1, 2, 3)] == pytest.approx([20.0, 40.0, 60.0])
    # sparser subsets: larger error, larger bound; errors of the bound's order
    assert rows[1]["normal_error_median_deg"] < rows[3]["normal_error_median_deg"]
    assert rows[1]["normal_crlb_rms_deg"] < rows[2]["normal_crlb_rms_deg"] < rows[3]["normal_crlb_rms_deg"]
    for m in (1, 2, 3):
        assert 0.4 < rows[m]["normal_ratio"] < 2.5, rows[m]
        assert 0.4 < rows[m]["tilt_ratio"] < 2.5, rows[m]


def test_sweep_threshold_near_two_sqrt_sigma(sweep, tmp_path):
    r = ex.threshold(sweep, n_boot=300, trials=100)
    th = r["theory"]
    assert th["two_sqrt_sigma_deg"] == pytest.approx(math.degrees(2 * math.sqrt(math.radians(r["sigma_line_deg"]))))
    d = r["detection"]
    assert d["status"] == "ok"
    assert 0.5 < d["tilt50_deg"] / th["two_sqrt_sigma_deg"] < 2.5
    assert r["frontal"]["status"] == "ok" and r["frontal"]["count"] >= 1
    # JSON-ready and the figures render
    write_json(tmp_path / "t.json", r)
    paths = ex.write_figures(r, str(tmp_path / "fig"))
    assert [p.rsplit("/", 1)[-1] for p in paths] == ["fig_threshold.png"]
    assert (tmp_path / "fig_threshold.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
