"""`import pencilcal`: the public API offers what docs/api.md says, and its examples run."""
from __future__ import annotations

import re
from pathlib import Path

import pytest

import pencilcal

DOC = Path(__file__).resolve().parents[1] / "docs" / "api.md"
BLOCKS = re.findall(r"```python\n(.*?)```", DOC.read_text(), re.S)


def test_the_api_names():
    for name in ("__version__", "read_camera", "write_camera", "Camera", "fit_pencil", "orient_segments",
                 "detect_lines", "detect_shafts", "fulcrum", "hand_eye", "calibrate", "board_pose"):
        assert hasattr(pencilcal, name), name
    assert set(pencilcal.__all__) <= set(dir(pencilcal))


@pytest.mark.parametrize("code", BLOCKS, ids=[f"block{i}" for i in range(len(BLOCKS))])
def test_docs_api_examples_run(code, capsys):
    exec(compile(code, str(DOC), "exec"), {})


def test_the_examples_say_what_they_show(capsys):
    """The orientation example's tilt is within its sigmas of the truth, the calibration's
    focal length within 1%, the fulcrum on its true ray."""
    ns = {}
    exec(compile(BLOCKS[2], str(DOC), "exec"), ns)
    o, truth = ns["o"], ns["truth"]
    assert abs(o.tilt_deg - truth["tilt_deg"]) < 4 * o.tilt_sigma_deg + 0.05
    ns = {}
    exec(compile(BLOCKS[4], str(DOC), "exec"), ns)
    assert abs(ns["result"].camera.fx / ns["sc"].camera.fx - 1) < 0.01 and ns["error"] < 0.2
