"""`pencilcal demo`: one command from nothing to a validation report."""
from __future__ import annotations

import json
import re

import numpy as np
import pytest
from click.testing import CliRunner

from pencilcal.cli.main import cli


@pytest.mark.slow
def test_demo_writes_a_report_and_every_file_it_used(tmp_path):
    from tests.validation.report.figure_rules import linted_figures

    out = tmp_path / "demo"
    with linted_figures() as problems:  # every figure of both reports legible, labelled, legends off the data
        r = CliRunner().invoke(cli, ["demo", "-o", str(out), "--frames", "8", "--no-sfm", "-q"])
    assert problems == []
    assert r.exit_code == 0, r.output
    # with --quiet the absolute paths alone, on standard output
    assert r.stdout.splitlines() == [str(out / "report.html"), str(out / "pivot-report.html")]
    assert (out / "report.html").read_text().startswith("<!DOCTYPE html>")
    # the pivoting instrument: its fulcrum against the truth, in its own report, which opens
    # with it; the fan's twin resolved in every frame (the spoke radii, then continuity)
    page = (out / "pivot-report.html").read_text()
    assert '<p class="verdict good" id="verdict"><b>PASS</b>fulcrum of the pivoting instrument: the 3-D point' in page
    assert "2. Fulcrum of the pivoting instrument" in page
    twin = json.loads((out / "pivot-validation.json").read_text())["summary"]["orient:exact"]["twin"]
    assert twin == {"right": 12}, twin
    fulcrum = json.loads((out / "pivot-validation.json").read_text())["fulcrum"]
    truth = fulcrum["truth"]
    assert truth["vertex_error_px"] < 1.0
    # the 3-D point within its own covariance, and within 3 % of its distance: the rendered
    # shaft's shaded limbs widen its 16-24 px band by ~2 %, so every axis and the point come
    # out ~2 % near (docs/method.md, seeds 0-4: 1.4-2.3 %)
    assert truth["point_p_value"] > 0.01
    assert truth["point_error_norm"] < 0.03 * float(np.linalg.norm(truth["fulcrum_cam"]))
    data = json.loads((out / "validation.json").read_text())
    assert len(data["frames"]) == 8 and sum(f["ok"] for f in data["frames"]) >= 6
    for f in ("truth.json", "camera.json", "board.yaml", "pencil.yaml"):
        assert (out / "sequence" / f).is_file()
    # each report's first screen (1280x900, headless Chromium) shows its verdict with the
    # headline figure and its unit
    from tests.validation.report.browser import CHROMIUM, first_screen

    if CHROMIUM.exists():
        for name, figure in (("report", r"median error \d[\d.]* deg, sigma \d[\d.]* deg"),
                             ("pivot-report", r"the 3-D point \([-\d., ]+\) mm in the camera frame, sigma [\d.]+ mm")):
            verdict, problems = first_screen(out / f"{name}.html", tmp_path, tmp_path / f"{name}-first-screen.png")
            assert problems == [] and re.search(figure, verdict), (name, verdict, problems)
    # an earlier demo is replaced only with --force; a folder of other files never
    r = CliRunner().invoke(cli, ["demo", "-o", str(out), "--frames", "6", "--no-sfm", "-q"])
    assert r.exit_code == 1 and "--force" in r.output
    other = tmp_path / "mine"
    other.mkdir()
    (other / "thesis.tex").write_text("keep")
    r = CliRunner().invoke(cli, ["demo", "-o", str(other), "--force", "-q"])
    assert r.exit_code == 1 and "not replacing" in r.output and (other / "thesis.tex").read_text() == "keep"


def test_the_default_folder_is_outside_a_checkout(tmp_path):
    """In a git checkout (the source's own, say) the demo writes to the temporary folder, so
    that a clone never fills with untracked files; elsewhere to ./pencilcal-demo. The
    repository ignores pencilcal-demo/ besides."""
    import subprocess
    import tempfile
    from pathlib import Path

    from pencilcal.cli.demo import default_folder

    plain = tmp_path / "work"
    (plain / "deep").mkdir(parents=True)
    assert default_folder(plain / "deep") == (plain / "deep" / "pencilcal-demo").resolve()
    clone = tmp_path / "clone"
    (clone / ".git").mkdir(parents=True)
    (clone / "docs").mkdir()
    assert default_folder(clone / "docs") == Path(tempfile.gettempdir()) / "pencilcal-demo"
    repo = Path(__file__).resolve().parents[2]
    if (repo / ".git").exists():
        r = subprocess.run(["git", "-C", str(repo), "check-ignore", "-q", "pencilcal-demo/report.html"])
        assert r.returncode == 0, ".gitignore does not ignore the demo's folder"
