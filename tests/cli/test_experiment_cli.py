"""`pencilcal experiment`: outputs, figures, exit codes and messages.

The inputs are validation files made without images (experiments.synthetic_validation:
exact poses, Gaussian line noise, the exact estimator's fits), so these run in seconds;
tests/validation/test_experiments.py runs the experiments on rendered frames.
"""
from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

from pencilcal.cli.experiment import experiment
from pencilcal.toolkit.io.files import write_json
from pencilcal.validation.experiments import synthetic_validation

PNG = b"\x89PNG\r\n\x1a\n"
FIGURES = {"single-angle": ["single-angle"], "distribution": ["distribution-angles", "distribution-spacing"],
           "threshold": ["threshold"]}


@pytest.fixture(scope="module")
def sweep(tmp_path_factory):
    """A tilt sweep 0-60 deg about a spoke (axis 30 deg), with frames near zero tilt."""
    d = tmp_path_factory.mktemp("experiment_cli")
    tilts = np.r_[np.repeat(np.arange(0.0, 8.0, 0.5), 3), np.arange(8.0, 61.0, 4.0)]
    write_json(d / "v.json", synthetic_validation(tilts, sigma_deg=0.05, axis_deg=30.0, offaxis_deg=10.0, seed=3))
    return d / "v.json"


@pytest.fixture(scope="module")
def tilted_only(tmp_path_factory):
    """Only large tilts (as the real da Vinci frames): no threshold can be measured."""
    d = tmp_path_factory.mktemp("experiment_cli_tilted")
    write_json(d / "v.json", synthetic_validation(np.arange(20.0, 61.0, 5.0), sigma_deg=0.05, seed=1))
    return d / "v.json"


def invoke(*args):
    return CliRunner().invoke(experiment, [str(a) for a in args])


def one_error_line(r):
    lines = [ln for ln in r.output.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("pencilcal: error:"), r.output
    assert "Traceback" not in r.output
    return lines[0]


@pytest.mark.parametrize("name", ["single-angle", "distribution", "threshold"])
def test_happy_path_writes_json_and_figures(sweep, tmp_path, name):
    out = tmp_path / "out.json"
    extra = ["--bootstrap", "200", "--trials", "50"] if name == "threshold" else []
    r = invoke(name, sweep, "-o", out, "--png", tmp_path / "fig", *extra)
    assert r.exit_code == 0, r.output
    assert f"pencilcal experiment {name}:" in r.stderr and str(out) in r.stderr
    assert "warning" not in r.output
    res = json.loads(out.read_text())
    assert res["experiment"] == name and res["status"] == "ok" and res["input"] == str(sweep)
    assert res["reference"] == "truth" and res["frames_used"] > 20
    want = [str(tmp_path / f"fig_{f}.png") for f in FIGURES[name]]
    assert res["figures"] == want
    for p in want:
        assert open(p, "rb").read(8) == PNG
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temporary files left


def test_results_carry_the_numbers(sweep, tmp_path):
    r = invoke("single-angle", sweep, "-o", tmp_path / "s.json", "--pairs", "all", "-q")
    assert r.exit_code == 0 and r.output == ""  # --quiet: nothing on success
    s = json.loads((tmp_path / "s.json").read_text())
    assert s["pairs"] == "all" and s["on_line"]["status"] == "ok"
    assert s["on_line"]["unique"]["count"] > 50 and s["theory"]["curves"]
    r = invoke("distribution", sweep, "-o", tmp_path / "d.json", "--strides", "1,2", "-q")
    assert r.exit_code == 0, r.output
    d = json.loads((tmp_path / "d.json").read_text())
    assert [row["stride"] for row in d["spacing"]["strides"]] == [1, 2]
    r = invoke("threshold", sweep, "-o", tmp_path / "t.json", "--bootstrap", "200", "--trials", "50", "--seed", "3")
    assert r.exit_code == 0, r.output
    t = json.loads((tmp_path / "t.json").read_text())
    assert t["detection"]["status"] == "ok"
    assert 0.7 < t["detection"]["tilt50_deg"] / t["theory"]["two_sqrt_sigma_deg"] < 1.6
    assert "50% detectable at" in r.stderr and "2 sqrt(sigma)" in r.stderr


def test_insufficient_data_exits_0_and_says_so(tilted_only, tmp_path):
    out = tmp_path / "t.json"
    r = invoke("threshold", tilted_only, "-o", out, "--png", tmp_path / "f", "--bootstrap", "100", "--trials", "50")
    assert r.exit_code == 0, r.output
    warnings = [ln for ln in r.stderr.splitlines() if ln.startswith("pencilcal: warning: threshold:")]
    assert len(warnings) == 3 and all("insufficient data" in w for w in warnings)
    t = json.loads(out.read_text())
    assert t["status"] == "insufficient data" and "smallest reference tilt" in t["reason"]
    assert t["detection"]["upper_bound_deg"] == pytest.approx(20.0)
    assert (tmp_path / "f_threshold.png").read_bytes()[:8] == PNG
    # single-angle: the axis (0 deg) has no spoke on it; the other cases run
    r = invoke("single-angle", tilted_only, "-o", tmp_path / "s.json")
    assert r.exit_code == 0 and "on_line: insufficient data" in r.stderr
    assert json.loads((tmp_path / "s.json").read_text())["status"] == "partial"


def test_no_overwrite_without_force(sweep, tmp_path):
    out = tmp_path / "d.json"
    assert invoke("distribution", sweep, "-o", out, "-q").exit_code == 0
    before = out.read_text()
    r = invoke("distribution", sweep, "-o", out)
    assert r.exit_code == 1 and "already exists" in one_error_line(r) and "--force" in r.output
    assert out.read_text() == before
    (tmp_path / "p_single-angle.png").write_bytes(b"x")
    r = invoke("single-angle", sweep, "-o", tmp_path / "s.json", "--png", tmp_path / "p")
    assert r.exit_code == 1 and "p_single-angle.png: already exists" in one_error_line(r)
    assert not (tmp_path / "s.json").exists()  # refused before any work
    assert invoke("single-angle", sweep, "-o", tmp_path / "s.json", "--png", tmp_path / "p", "--force", "-q").exit_code == 0
    assert (tmp_path / "p_single-angle.png").read_bytes()[:8] == PNG


def test_bad_input_is_one_line_exit_1(sweep, tmp_path):
    r = invoke("threshold", tmp_path / "missing.json", "-o", tmp_path / "o.json")
    assert r.exit_code == 1 and "validation file not found" in one_error_line(r)
    bad = tmp_path / "bad.json"
    bad.write_text("{oops")
    r = invoke("single-angle", bad, "-o", tmp_path / "o.json")
    assert r.exit_code == 1 and "not valid JSON" in one_error_line(r)
    bad.write_text(json.dumps({"frames": [], "summary": {}}))
    r = invoke("distribution", bad, "-o", tmp_path / "o.json")
    assert r.exit_code == 1 and "not a validation file" in one_error_line(r)
    # a validation file without the exact model's lines (validate --models general)
    v = json.loads(sweep.read_text())
    for f in v["frames"]:
        del f["orient"]["exact"]["lines"]
    bad.write_text(json.dumps(v))
    r = invoke("distribution", bad, "-o", tmp_path / "o.json")
    assert r.exit_code == 1 and "no frame has both the exact model's lines" in one_error_line(r)
    r = invoke("single-angle", sweep, "-o", tmp_path / "nofolder" / "o.json")
    assert r.exit_code == 1 and "does not exist" in one_error_line(r)
    assert not (tmp_path / "o.json").exists()


def test_usage_errors_exit_2(sweep, tmp_path):
    assert invoke("distribution", sweep, "-o", tmp_path / "o.json", "--strides", "0,2").exit_code == 2
    assert invoke("distribution", sweep, "-o", tmp_path / "o.json", "--strides", "a").exit_code == 2
    assert invoke("single-angle", sweep, "-o", tmp_path / "o.json", "--pairs", "some").exit_code == 2
    assert invoke("threshold", sweep).exit_code == 2  # no -o
    assert invoke("nonsense", sweep, "-o", tmp_path / "o.json").exit_code == 2


def test_help_has_examples():
    r = invoke("--help")
    assert r.exit_code == 0 and "Example" in r.output
    for name in ("single-angle", "distribution", "threshold"):
        assert name in r.output
        h = invoke(name, "--help")
        assert h.exit_code == 0 and "Example" in h.output and f"pencilcal experiment {name}" in h.output
