"""The calibration page: residuals per view, where the corners fell, sigmas, advice."""
from __future__ import annotations

import html
import json
import re

import numpy as np
from click.testing import CliRunner

from pencilcal.cli.main import cli
from pencilcal.validation.calibration_report import build_calibration_report, coverage_advice, coverage_grid


def test_coverage_grid_counts_each_corner_once_in_its_cell():
    corners = [np.array([[-0.5, -0.5], [639.4, 479.4], [320.0, 240.0]]), np.zeros((0, 2))]
    g = coverage_grid(corners, (640, 480), cells=(4, 4))
    c = np.array(g["counts"])
    assert c.sum() == 3 and c[0, 0] == 1 and c[3, 3] == 1 and c[2, 2] == 1


def test_the_advice_names_the_empty_parts():
    full = {"counts": np.ones((9, 16), int).tolist()}
    assert "no region needs more views" in coverage_advice(full)
    left_missing = np.ones((9, 16), int)
    left_missing[:, :5] = 0
    text = coverage_advice({"counts": left_missing.tolist()})
    assert "left edge" in text and "top-left corner" in text and "right edge" not in text
    middle = np.zeros((9, 16), int)
    middle[3:6, 5:11] = 20
    assert "Only the middle" in coverage_advice({"counts": middle.tolist()})


def test_calibrate_writes_the_page(tmp_path):
    sim = tmp_path / "sim"
    r = CliRunner().invoke(cli, ["simulate", str(sim), "--scenario", "orbit", "--frames", "8", "--size", "640x360",
                                 "-q"])
    assert r.exit_code == 0, r.output
    for report in ("calib.html", "calib.json"):
        r = CliRunner().invoke(cli, ["calibrate", str(sim / "images"), "--board", str(sim / "board.yaml"),
                                     "-o", str(tmp_path / f"{report}.yaml"), "--report", str(tmp_path / report), "-q"])
        assert r.exit_code == 0, r.output
    page = (tmp_path / "calib.html").read_text()
    rec = json.loads((tmp_path / "calib.json").read_text())
    assert sum(map(sum, rec["coverage"]["counts"])) == rec["counts"]["corners_used"]
    rep = build_calibration_report(rec)
    # the answer first: the verdict, the uncertainty map, the cross-validation, the advice
    assert [s.id for s in rep.sections][:4] == ["verdict", "uncertainty", "cross-validation", "advice"]
    verdict = rec["verdict"]
    assert verdict["status"] in ("usable", "usable within this region", "not usable")
    assert page.index(html.escape(verdict["headline"])) < page.index('<section id="uncertainty">')
    cv = rec["cross_validation"]
    maps = 4 if "odd_even" in cv else 3        # uncertainty, [difference], per-view residuals, coverage
    assert page.startswith("<!DOCTYPE html>") and len(re.findall(r"data:image/png;base64,", page)) == maps
    for words in ("Per-view residuals", "Coverage of the image", "Intrinsics and their sigmas", "What to add",
                  "worst direction's standard deviation [px]"):
        assert html.escape(words) in page
    if "odd_even" in cv:
        assert "odd and the even views calibrated apart" in page and "projection difference" in page
    else:
        assert "could not be calibrated apart" in page
