"""The bad-input corpus (tests/corpus/cases.yaml): every case ends in a clear message and
the documented exit code; nothing already on disk is overwritten by a failing run, and a
failing run leaves nothing that looks like a result."""
from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import pytest
import yaml
from click.testing import CliRunner

from pencilcal.cli.main import cli

CORPUS = Path(__file__).resolve().parents[1] / "corpus"
CASES = yaml.safe_load((CORPUS / "cases.yaml").read_text())


def _make_corpus():
    """tests/corpus/make_corpus.py, whose generators make the inputs too big (or too many)
    to keep in the repository."""
    spec = importlib.util.spec_from_file_location("make_corpus", CORPUS / "make_corpus.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _args(case, out):
    """The case's command line: corpus files and generated inputs (made in out's folder)
    by their paths."""
    made = _make_corpus().generate(case["generate"], out.parent) if case.get("generate") else {}
    args = [str(made[a]) if a in made else str(CORPUS / a) if (CORPUS / a).exists() and not a.startswith("-") else a
            for a in case["args"]]
    return args + ["-o", str(out), "-q"]


def _lines(output):
    return [ln for ln in output.splitlines() if ln.strip()]


@pytest.mark.parametrize("case", CASES, ids=[c["name"] for c in CASES])
def test_case(case, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # where a rogue .cameramodel would write its marker
    out = tmp_path / "out.json"
    r = CliRunner().invoke(cli, _args(case, out))
    assert r.exit_code == case["exit"], r.output
    assert "Traceback" not in r.output
    lines = _lines(r.output)
    for word in case.get("warnings", []):
        assert any("warning" in ln and word in ln for ln in lines), (word, r.output)
    if case["exit"] == 1:
        assert lines and lines[-1].startswith("pencilcal: error:"), r.output
        for word in case["message"]:
            assert word in lines[-1], (word, lines[-1])
        assert not out.exists()
    else:
        frames = json.loads(out.read_text())["frames"]
        for name in case.get("not_ok", []):
            f = [fr for fr in frames if fr["image"] == name]
            assert len(f) == 1 and f[0]["ok"] is False and f[0]["error"], name
    checks = case.get("checks", [])
    if "not_executed" in checks:
        assert not (tmp_path / "PWNED_BY_CAMERAMODEL").exists()
    if "frontal_not_detectable" in checks:
        f = json.loads(out.read_text())["frames"][0]
        assert f["ok"] is True and f["detectable"] is False and f["tilt_deg"] < 10
    if "clean_ok" in checks:  # the frame without clutter beside the refused ones: estimated, unflagged
        f = [fr for fr in json.loads(out.read_text())["frames"] if fr["image"] == "clean.png"][0]
        assert f["ok"] is True and f["lines_used"] == 8 and not f["normal_ambiguous"], f
    if "first_segment_rejected" in checks:
        f = json.loads(out.read_text())["frames"][0]
        assert f["ok"] is True and f["spokes"][0] == -1 and f["lines_used"] == 7, f


@pytest.mark.parametrize("case", [c for c in CASES if c["exit"] == 1], ids=lambda c: c["name"])
def test_failing_run_keeps_what_is_on_disk(case, tmp_path, monkeypatch):
    """Even with --force, a run that fails leaves an existing output as it was."""
    monkeypatch.chdir(tmp_path)
    out = tmp_path / "out.json"
    out.write_text("keep me\n")
    r = CliRunner().invoke(cli, _args(case, out) + ["--force"])
    assert r.exit_code == 1, r.output
    assert out.read_text() == "keep me\n"


def test_existing_output_needs_force(tmp_path):
    out = tmp_path / "out.json"
    out.write_text("keep me\n")
    r = CliRunner().invoke(cli, ["lines", str(CORPUS / "frames"), "--camera", str(CORPUS / "camera.json"), "-o", str(out), "-q"])
    assert r.exit_code == 1 and "--force" in r.output and out.read_text() == "keep me\n"


def test_calibrate_failure_leaves_no_partial_outputs(tmp_path):
    """Too few views: neither the camera, nor the report, nor the corner cache appears."""
    outs = [tmp_path / "cam.yaml", tmp_path / "calib.json", tmp_path / "corners.vnl"]
    r = CliRunner().invoke(cli, ["calibrate", str(CORPUS / "frames"), "--board", str(CORPUS / "board.yaml"),
                                 "-o", str(outs[0]), "--report", str(outs[1]), "--corners", str(outs[2]), "-q"])
    assert r.exit_code == 1 and "Traceback" not in r.output
    assert not any(p.exists() for p in outs)
