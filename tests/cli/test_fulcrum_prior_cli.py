"""`pencilcal fulcrum --fulcrum-prior`, the epochs in fulcrum.json, and `lines --shaft
--fulcrum-prior`: on a rendered pivot sequence with a camera move (pivot_frames.py)."""
from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

from pencilcal.cli.main import cli
from pencilcal.toolkit.camera.formats import write_camera

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def sequence(tmp_path_factory):
    """(folder with images/ and cam.json, scenario): 16 frames, the camera turned after 8."""
    import cv2

    from tests.toolkit.detect.shaft.pivot_frames import pivot_frames

    tmp = tmp_path_factory.mktemp("pivot")
    sc, imgs = pivot_frames(1, frames=16, epochs=2)
    (tmp / "images").mkdir()
    for fr, im in zip(sc.frames, imgs):
        cv2.imwrite(str(tmp / "images" / fr["image"]), im)
    write_camera(tmp / "cam.json", sc.camera)
    return tmp, sc


def _run(*args):
    return CliRunner().invoke(cli, [str(a) for a in args])


def test_fulcrum_auto_prior_and_epochs(sequence):
    """The epochs where the camera moved, each with its fulcrum (near the truth's image) and
    prior; every frame at most one shaft; the prior file read back by lines and fulcrum."""
    tmp, sc = sequence
    r = _run("fulcrum", tmp / "images", "--camera", tmp / "cam.json", "--fulcrum-prior", "auto", "-o", tmp / "f.json",
             "--jsonl", tmp / "f.jsonl", "-q")
    assert r.exit_code == 0, r.output
    assert "the fulcrum moved: 2 pivot epochs" in r.output
    doc = json.loads((tmp / "f.json").read_text())
    assert doc["fulcrum_prior"] == "auto" and set(doc["axis_prior"]) == {"point", "cov", "widths_px"}
    test = doc["epoch_test"]
    assert test["epochs"] == 2 and [c["index"] for c in test["change_points"]] == [8]
    assert {"statistic", "dof", "p_value", "p_corrected", "positions", "vertices_ideal_px", "last_image_before",
            "first_image_after"} <= set(test["change_points"][0])
    for e, truth in zip(doc["epochs"], sc.extra["epochs"]):
        assert (e["first"], e["last"]) == (truth["first"], truth["last"])
        assert e["images"] == [f["image"] for f in sc.frames[e["first"]:e["last"] + 1]]
        assert np.linalg.norm(np.asarray(e["vertex_px"]) - truth["fulcrum_px"]) < 5.0
        assert "axis_prior" in e and "jackknife" in e
    shafts = [json.loads(line)["shafts"] for line in (tmp / "f.jsonl").read_text().splitlines()]
    assert all(len(s) <= 1 for s in shafts) and sum(len(s) for s in shafts) >= 15

    r = _run("lines", tmp / "images", "--camera", tmp / "cam.json", "--shaft", "--fulcrum-prior", tmp / "f.json",
             "-o", tmp / "lines.json", "-q")
    assert r.exit_code == 0, r.output
    lines = json.loads((tmp / "lines.json").read_text())
    assert lines["fulcrum_prior"] == str(tmp / "f.json")
    assert all(len(f["shafts"]) <= 1 for f in lines["frames"]) and sum(len(f["shafts"]) for f in lines["frames"]) >= 15

    r = _run("fulcrum", tmp / "images", "--camera", tmp / "cam.json", "--fulcrum-prior", tmp / "f.json", "-o",
             tmp / "g.json", "-q")
    assert r.exit_code == 0, r.output
    assert json.loads((tmp / "g.json").read_text())["epoch_test"]["epochs"] == 2


def test_fulcrum_prior_errors(sequence, tmp_path):
    tmp, _ = sequence
    (tmp_path / "lines.json").write_text(json.dumps({"frames": []}))
    r = _run("fulcrum", "--lines", tmp_path / "lines.json", "--camera", tmp / "cam.json", "--fulcrum-prior", "auto",
             "-o", tmp_path / "x.json")
    assert r.exit_code == 2 and "--fulcrum-prior" in r.output
    r = _run("lines", tmp / "images", "--camera", tmp / "cam.json", "--fulcrum-prior", tmp_path / "lines.json",
             "-o", tmp_path / "x.json")
    assert r.exit_code == 2 and "only with --shaft" in r.output
    (tmp_path / "bad.json").write_text(json.dumps({"vertex_px": [1, 2]}))
    r = _run("lines", tmp / "images", "--camera", tmp / "cam.json", "--shaft", "--fulcrum-prior",
             tmp_path / "bad.json", "-o", tmp_path / "x.json")
    assert r.exit_code == 1 and "bad.json: no fulcrum prior" in r.output and len(r.output.strip().splitlines()) == 1
    r = _run("fulcrum", "--source", "0", "--camera", tmp / "cam.json", "--fulcrum-prior", "auto", "-o",
             tmp_path / "x.json")
    assert r.exit_code == 2 and "reads the frames twice" in r.output
