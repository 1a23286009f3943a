"""Plots a reviewer can trust, in every report the tests make: legible at 900 px, every
axis labelled with its unit, legends outside the data, no plot of a single value
(figure_rules.py); and the rules themselves catch what they are for."""
from __future__ import annotations

import copy
import json
import shutil

import numpy as np
import pytest
from click.testing import CliRunner

from pencilcal.toolkit.io.files import to_jsonable
from pencilcal.validation.report import build_report
from pencilcal.validation.report.figures import axes_text, new_figure, png_bytes, tilt_axis
from tests.conftest import data_dir

from .figure_rules import figure_problems, linted_figures
from .helpers import synthetic


def test_the_rules_catch_what_they_are_for():
    fig = new_figure(figsize=(11, 4))
    ax = fig.subplots()
    ax.plot([1.0, 1.0, 1.0], [0.1, 0.2, 0.3], "o", label="every frame at one tilt")
    ax.plot([0.5, 1.5], [0.0, 0.0], label="flat on the axis")
    ax.set_ylim(0.0, 0.4)
    ax.set_xlabel("tilt")
    ax.legend(fontsize=6, loc="upper left")
    problems = " / ".join(figure_problems(fig))
    for what in ("11.0 in wide", "text under 8.0 pt", "label 'tilt' has no unit", "y axis", "has no label",
                 "lies over a plot", "lies on the edge of its axes"):
        assert what in problems, what
    fig = new_figure(figsize=(6, 3))
    ax = fig.subplots()
    ax.plot([3.0, 3.0], [1.0, 2.0], "o")
    ax.set_xlabel("reference tilt [deg]")
    ax.set_ylabel("error [deg]")
    assert "single value on its x axis" in " / ".join(figure_problems(fig))


@pytest.fixture(scope="module")
def plan():
    from pencilcal.validation.sensitivity import Setup, plan

    return json.loads(json.dumps(to_jsonable(plan(
        Setup(), tilts_deg="0:60:15", offaxis_deg="0,20", trials=20, accuracy_deg=0.5, seed=1, backend="numpy",
        maps=("tilt-offaxis", "spokes-spacing", "noise"), spokes_grid="3,8", steps_grid="10,20",
        sigmas_grid="0.05,0.1"))))


@pytest.mark.parametrize("kind", [dict(sfm=True, calibration=True), dict(truth=False), dict(grid=True),
                                  dict(n=3, failing=False)], ids=["truth-sfm-calibration", "pnp", "grid", "three"])
def test_every_figure_of_the_validation_report_is_trusted(tmp_path, plan, kind):
    data = synthetic(tmp_path, **kind)
    with linted_figures() as problems:
        report = build_report(data, sensitivity=plan, samples=2)
    assert problems == []
    plots = [b for s in report.sections for b in s.blocks if hasattr(b, "png")]
    assert len(plots) >= 7
    # every plot says what its axes show (their units checked above); frames drawn on are images
    for p in plots:
        assert p.axes == "image" or ("x: " in p.axes and "(none)" not in p.axes), (p.alt, p.axes)


def test_a_fixed_camera_plots_against_the_frame(tmp_path):
    """Every frame at one reference tilt (a pivot: the camera fixed): the errors are drawn
    against the frame, not piled on one tilt, and the caption says why."""
    data = synthetic(tmp_path, n=8, failing=False)
    for fr in data["frames"]:
        fr["reference_tilt_deg"] = 33.7
    xs, label = tilt_axis(data)
    assert label == "frame (every frame at a reference tilt of 33.7 deg)" and sorted(xs.values()) == list(range(8))
    with linted_figures() as problems:
        report = build_report(copy.deepcopy(data), samples=0)
    assert problems == []
    plot = next(b for b in next(s for s in report.sections if s.id == "plots").blocks if hasattr(b, "png"))
    assert "the errors are drawn against the frame" in plot.caption and "x: frame (every frame" in plot.axes


def test_axes_text_reads_the_axes():
    fig = new_figure(figsize=(4, 3))
    ax1, ax2 = fig.subplots(1, 2)
    ax1.plot([0, 1], [0, 1])
    ax1.set_xlabel("tilt [deg]")
    ax2.imshow(np.zeros((4, 4)))
    ax2.set_xticks([])
    ax2.set_yticks([])
    png_bytes(fig)  # drawn, as a report draws it
    assert axes_text(fig) == "x: tilt [deg]; y: (none) | image"


@pytest.mark.skipif(not data_dir("opencv-stereo-chessboard").is_dir(), reason="OpenCV's sample chessboard not found")
def test_the_calibration_report_figures_are_trusted(tmp_path):
    from pencilcal.cli.main import cli

    (tmp_path / "images").mkdir()
    for f in sorted(data_dir("opencv-stereo-chessboard").glob("left*.jpg"))[:8]:
        shutil.copy(f, tmp_path / "images" / f.name)
    (tmp_path / "board.yaml").write_text("type: chessboard\nsquares: [9, 6]\nsquare: 25.0\n")
    with linted_figures() as problems:
        r = CliRunner().invoke(cli, ["calibrate", str(tmp_path / "images"), "--board", str(tmp_path / "board.yaml"),
                                     "-o", str(tmp_path / "c.json"), "--report", str(tmp_path / "r.html"), "-q"])
    assert r.exit_code == 0, r.output
    assert problems == [] and (tmp_path / "r.html").is_file()
