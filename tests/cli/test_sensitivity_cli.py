"""`pencilcal sensitivity`: the JSON and PNGs, the no-torch note, exit codes and messages."""
from __future__ import annotations

import json
import sys

import numpy as np
import pytest
from click.testing import CliRunner

from pencilcal.cli.sensitivity import sensitivity
from pencilcal.toolkit.pencil import torch_backend as te

FAST = ["--tilts", "0:60:10", "--offaxis", "0,20", "--trials", "80"]
NOTE = 'pip install -e ".[torch]" makes this much faster'


def invoke(*args):
    return CliRunner().invoke(sensitivity, [str(a) for a in args])


@pytest.fixture
def no_torch(monkeypatch):
    """Simulate an install without the [torch] extra: importing torch/kornia fails."""
    monkeypatch.setitem(sys.modules, "torch", None)
    monkeypatch.setitem(sys.modules, "kornia", None)
    assert not te.torch_available()


def test_happy_path_writes_json_and_heatmaps(tmp_path):
    out = tmp_path / "s.json"
    r = invoke("-o", out, *FAST, "--map", "all", "--spokes-grid", "4,8", "--step-grid", "20,40",
               "--sigma-grid", "0.1,0.3", "--accuracy", "0.5", "--png", tmp_path / "plan")
    assert r.exit_code == 0, r.output
    d = json.loads(out.read_text())
    assert set(d) >= {"setup", "backend", "answer", "detection", "maps"}
    assert set(d["maps"]) == {"tilt_offaxis", "spokes_spacing", "noise"}
    m = d["maps"]["tilt_offaxis"]
    assert m["tilts_deg"] == [0, 10, 20, 30, 40, 50, 60] and m["offaxis_deg"] == [0, 20]
    assert np.array(m["crb"]["normal_deg"]).shape == (2, 7) and m["crb"]["normal_deg"][0][0] is None  # inf
    assert np.array(m["mc"]["normal_rmse_deg"]).shape == (2, 7)
    assert d["answer"]["accuracy_deg"] == 0.5 and d["answer"]["min_tilt_deg"] > 5
    assert d["detection"]["rule_2sqrt_sigma_deg"] == pytest.approx(4.787, rel=1e-3)
    assert len(d["png"]) == 3
    for name in ("tilt-offaxis", "spokes-spacing", "noise"):
        assert (tmp_path / f"plan_{name}.png").stat().st_size > 1000
    assert "from a tilt of" in r.stderr


def test_offaxis_in_pixels_uses_the_focal_length(tmp_path):
    out = tmp_path / "s.json"
    r = invoke("-o", out, "--tilts", "20,40", "--offaxis", "0,800px", "--focal", "800", "--trials", "0", "-q")
    assert r.exit_code == 0, r.output
    m = json.loads(out.read_text())["maps"]["tilt_offaxis"]
    assert m["offaxis_deg"] == pytest.approx([0.0, 45.0]) and m["offaxis_px"] == pytest.approx([0.0, 800.0])


def test_without_torch_numpy_path_and_one_note(tmp_path, no_torch):
    out = tmp_path / "s.json"
    r = invoke("-o", out, *FAST)
    assert r.exit_code == 0, r.output
    assert r.stderr.count(NOTE) == 1
    assert json.loads(out.read_text())["backend"]["name"] == "numpy"


def test_without_torch_cuda_is_a_one_line_error(tmp_path, no_torch):
    r = invoke("-o", tmp_path / "s.json", *FAST, "--device", "cuda")
    assert r.exit_code == 1
    lines = [ln for ln in r.output.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("pencilcal: error:")
    assert 'pip install torch==2.13.0 && pip install -e ".[torch]"' in lines[0]
    assert not (tmp_path / "s.json").exists()


@pytest.mark.skipif(not te.torch_available(), reason='torch/kornia not installed (pip install -e ".[torch]")')
def test_cuda_without_gpu_is_a_one_line_error(tmp_path):
    import torch

    if torch.cuda.is_available():
        pytest.skip("a GPU is present")
    r = invoke("-o", tmp_path / "s.json", *FAST, "--device", "cuda")
    assert r.exit_code == 1
    lines = [ln for ln in r.output.splitlines() if ln.strip()]
    assert len(lines) == 1 and "--device cpu" in lines[0]


def test_no_overwrite_without_force(tmp_path):
    out = tmp_path / "s.json"
    out.write_text("keep me")
    r = invoke("-o", out, *FAST, "-q")
    assert r.exit_code == 1 and "already exists" in r.output and out.read_text() == "keep me"
    out2 = tmp_path / "t.json"
    (tmp_path / "p_tilt-offaxis.png").write_text("keep me")
    r = invoke("-o", out2, *FAST, "-q", "--png", tmp_path / "p")
    assert r.exit_code == 1 and "p_tilt-offaxis.png" in r.output and not out2.exists()
    assert invoke("-o", out, *FAST, "-q", "--force").exit_code == 0


@pytest.mark.parametrize("args,message", [
    (["--tilts", "0:80"], "--tilts"),
    (["--tilts", "0:95:5"], "--tilts"),
    (["--map", "noise", "--sigma-grid", "0,0.1"], "--sigma-grid"),
    (["--offaxis", "a,b"], "--offaxis"),
    (["--spokes", "2"], "three spokes"),
    (["--spokes", "4", "--step-deg", "90"], "distinct line directions"),
])
def test_bad_values_are_one_line_exit_1(tmp_path, args, message):
    r = invoke("-o", tmp_path / "s.json", "--trials", "0", *args)
    assert r.exit_code == 1, r.output
    lines = [ln for ln in r.output.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("pencilcal: error:") and message in lines[0]
    assert "Traceback" not in r.output


def test_usage_errors_exit_2(tmp_path):
    assert invoke("-o", tmp_path / "s.json", "--trials", "-1").exit_code == 2
    assert invoke("-o", tmp_path / "s.json", "--map", "bogus").exit_code == 2
    assert invoke("--trials", "5").exit_code == 2  # no -o


def test_help_has_an_example():
    r = invoke("--help")
    assert r.exit_code == 0 and "Example" in r.output and "pencilcal sensitivity -o" in r.output
