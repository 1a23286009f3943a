"""`pencilcal score`: shafts scored against instrument masks (score.json, the contact sheet),
its inputs checked, and on a real masked source the same figures as the protocol's table."""
from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from click.testing import CliRunner

from pencilcal.cli.score import score


def invoke(*args):
    return CliRunner().invoke(score, [str(a) for a in args])


def _frame(rng, band):
    """A 640x360 frame of pink tissue with a grey shaft from the left border (band: its
    polygon), and its mask."""
    img = np.zeros((360, 640, 3), np.uint8)
    img[:] = (70, 90, 180)
    cv2.fillConvexPoly(img, band, (95, 95, 95))
    img = cv2.GaussianBlur(np.clip(img + rng.normal(0, 3, img.shape), 0, 255).astype(np.uint8), (0, 0), 1.0)
    mask = np.zeros((360, 640), np.uint8)
    cv2.fillConvexPoly(mask, band, 255)
    return img, mask


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    d = tmp_path_factory.mktemp("score")
    (d / "frames").mkdir()
    (d / "masks").mkdir()
    rng = np.random.default_rng(3)
    bands = [np.array([[0, 150], [400, 165], [400, 205], [0, 220]]), np.array([[0, 60], [420, 110], [410, 150], [0, 120]])]
    for i, band in enumerate(bands):
        img, mask = _frame(rng, band)
        cv2.imwrite(str(d / "frames" / f"f{i}.png"), img)
        cv2.imwrite(str(d / "masks" / f"f{i}.png"), mask)
    # a second instrument drawn only in the mask of f1: missed
    m = cv2.imread(str(d / "masks" / "f1.png"), cv2.IMREAD_GRAYSCALE)
    cv2.fillConvexPoly(m, np.array([[640, 250], [300, 280], [300, 310], [640, 300]]), 255)
    cv2.imwrite(str(d / "masks" / "f1.png"), m)
    return d


def test_scores_and_sheet(scene):
    d = scene
    out, sheet = d / "score.json", d / "sheet.html"
    r = invoke(d / "frames", "--masks", d / "masks", "-o", out, "--sheet", sheet)
    assert r.exit_code == 0, r.output
    data = json.loads(out.read_text())
    s = data["summary"]
    assert (s["instruments"], s["found"], s["false"]) == (3, 2, 0)
    f0, f1 = data["frames"]
    assert f0["image"] == "f0.png" and f0["found"] == 1 and f0["matches"][0]["angle_err_deg"] < 0.5
    assert f1["missed"] == 1 and len(f1["references"]) == 2
    assert "found 2 of 3 instruments" in r.output and str(out.resolve()) in r.output
    html = sheet.read_text()
    assert html.startswith("<!DOCTYPE html>") and html.count("<figure>") == 2 and "found 2 of 3" in html


def test_lines_file_scored(scene, tmp_path):
    d = scene
    lines = tmp_path / "lines.json"
    lines.write_text(json.dumps({"frames": [
        {"image": "f0.png", "ok": True, "segments": [], "shafts": [{"midline": [0, 185, 400, 185], "score": 1.0}]},
        {"image": "f1.png", "ok": True, "segments": [], "shafts": [{"midline": [0, 20, 600, 330], "score": 1.0}]}]}))
    out = tmp_path / "s.json"
    r = invoke(d / "frames", "--masks", d / "masks", "--lines", lines, "-o", out, "--quiet")
    assert r.exit_code == 0, r.output
    s = json.loads(out.read_text())["summary"]
    assert (s["found"], s["false"]) == (1, 1)


def test_bad_inputs(scene, tmp_path):
    d = scene
    out = tmp_path / "s.json"
    # masks that pair with no frame
    (tmp_path / "m").mkdir()
    cv2.imwrite(str(tmp_path / "m" / "x.png"), np.zeros((360, 640), np.uint8))
    r = invoke(d / "frames", "--masks", tmp_path / "m", "-o", out)
    assert r.exit_code == 1 and "mask" in r.output and len(r.output.strip().splitlines()) == 1
    # a mask of the wrong size, named
    (tmp_path / "w").mkdir()
    for i in range(2):
        cv2.imwrite(str(tmp_path / "w" / f"f{i}.png"), np.zeros((100, 100), np.uint8))
    r = invoke(d / "frames", "--masks", tmp_path / "w", "-o", out)
    assert r.exit_code == 1 and "f0.png" in r.output and "100x100" in r.output
    # an existing output without --force
    out.write_text("keep")
    r = invoke(d / "frames", "--masks", d / "masks", "-o", out)
    assert r.exit_code == 1 and out.read_text() == "keep"
    # --lines gives the shafts: no camera or valid-region mask for detecting them
    r = invoke(d / "frames", "--masks", d / "masks", "--lines", out, "--mask", out, "-o", tmp_path / "t.json")
    assert r.exit_code == 2


@pytest.mark.slow
def test_real_source_as_the_protocol(tmp_path):
    """The command on cholec (instance masks) gives the figures of the protocol's table at the
    detector's defaults (tests/validation/test_shaft_protocol.py)."""
    from tests.conftest import data_dir

    root = data_dir("real-instruments") / "cholec-instance-masks"
    out = tmp_path / "s.json"
    r = invoke(root / "frames", "--masks", root / "masks_inst", "--mask-instances", "-o", out, "--quiet")
    assert r.exit_code == 0, r.output
    s = json.loads(out.read_text())["summary"]
    assert s["instruments"] == 23 and s["found"] >= 4 and s["false_per_frame"] <= 0.5
