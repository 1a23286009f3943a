"""`pencilcal simulate`: the output folder contract, atomicity and refusals."""
from __future__ import annotations

import json
import os

import cv2
import numpy as np
import pytest
from click.testing import CliRunner

from pencilcal.cli.simulate import simulate
from pencilcal.toolkit.board.spec import read_board
from pencilcal.toolkit.camera.model import Camera
from pencilcal.toolkit.camera.formats import read_camera, write_camera
from pencilcal.toolkit.errors import InputError
from pencilcal.toolkit.pencil.spec import read_pencil

SMALL = ["--size", "320x240"]


def invoke(*args):
    return CliRunner().invoke(simulate, [str(a) for a in args])


def test_pivot_writes_the_contract(tmp_path):
    out = tmp_path / "seq"
    r = invoke(out, "--scenario", "pivot", "--frames", 3, "--seed", 5, *SMALL, "-q")
    assert r.exit_code == 0, r.output
    assert sorted(os.listdir(out)) == ["angles.csv", "board.yaml", "camera.json", "camera.yaml", "images",
                                       "pencil.yaml", "truth.json"]
    assert sorted(os.listdir(out / "images")) == ["000.png", "001.png", "002.png"]
    img = cv2.imread(str(out / "images" / "001.png"), cv2.IMREAD_UNCHANGED)
    assert img.shape == (240, 320) and img.dtype == np.uint8
    truth = json.loads((out / "truth.json").read_text())
    cam = read_camera(out / "camera.json")
    assert cam == read_camera(out / "camera.yaml")
    assert (cam.width, cam.height, cam.model) == (320, 240, "opencv")
    assert truth["camera"]["K"] == cam.K.tolist()
    board, pencil = read_board(out / "board.yaml"), read_pencil(out / "pencil.yaml")
    assert board.to_dict() == truth["board"]
    assert pencil.vertex.tolist() == truth["pencil"]["vertex"] and pencil.width == 1.0
    assert [f["image"] for f in truth["frames"]] == ["000.png", "001.png", "002.png"]
    rows = (out / "angles.csv").read_text().splitlines()
    assert rows[0] == "image,angle_deg" and len(rows) == 4
    for f, row in zip(truth["frames"], rows[1:]):
        for key in ("R_cam_from_target", "t_cam_from_target", "normal", "vertex_px", "tilt_deg"):
            assert key in f
        R = np.asarray(f["R_cam_from_target"])
        assert np.allclose(f["normal"], R[:, 2])
        name, angle = row.split(",")
        assert name == f["image"] and float(angle) == f["angle_deg"]
        # vertex_px is the fulcrum's image, exactly as the camera file projects it
        assert np.allclose(cam.project(np.asarray(f["fulcrum_cam"])), f["vertex_px"], atol=1e-9)
    assert truth["render"]["noise"] == 5.0 and truth["render"]["blur_px"] == 1.5
    # nothing else left behind in the parent folder
    assert sorted(os.listdir(tmp_path)) == ["seq"]


def test_tilt_sweep_options_and_same_seed_same_images(tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    for out in (a, b):
        r = invoke(out, "--scenario", "tilt-sweep", "--frames", 2, "--axis", 30, "--max-tilt", 60, "--model",
                   "fisheye", "--noise", 1.5, "--blur", 0.3, *SMALL, "-q")
        assert r.exit_code == 0, r.output
    ta = json.loads((a / "truth.json").read_text())
    assert [f["tilt_deg"] for f in ta["frames"]] == [0.0, 60.0]
    assert ta["frames"][1]["axis_deg"] == 30.0 and ta["camera"]["model"] == "fisheye"
    assert not (a / "angles.csv").exists()
    for name in ("000.png", "001.png"):
        assert (a / "images" / name).read_bytes() == (b / "images" / name).read_bytes()


def test_custom_camera_and_color(tmp_path):
    cam = Camera("pinhole", 300, 200, [[230.0, 0, 149.5], [0, 230.0, 99.5], [0, 0, 1]])
    write_camera(tmp_path / "cam.yaml", cam)
    r = invoke(tmp_path / "o", "--scenario", "orbit", "--frames", 2, "--camera", tmp_path / "cam.yaml", "--color",
               "-q")
    assert r.exit_code == 0, r.output
    assert read_camera(tmp_path / "o" / "camera.json") == cam
    assert cv2.imread(str(tmp_path / "o" / "images" / "000.png"), cv2.IMREAD_UNCHANGED).shape == (200, 300, 3)


def test_refuses_a_non_empty_folder_and_force_replaces_an_earlier_output(tmp_path):
    out = tmp_path / "seq"
    assert invoke(out, "--scenario", "tilt-sweep", "--frames", 1, *SMALL, "-q").exit_code == 0
    before = (out / "truth.json").read_text()
    r = invoke(out, "--scenario", "tilt-sweep", "--frames", 2, *SMALL, "-q")
    assert r.exit_code == 1
    assert r.output.count("\n") == 1 and "not empty" in r.output and "--force" in r.output
    assert (out / "truth.json").read_text() == before
    r = invoke(out, "--scenario", "tilt-sweep", "--frames", 2, *SMALL, "-q", "--force")
    assert r.exit_code == 0, r.output
    assert len(os.listdir(out / "images")) == 2
    assert sorted(os.listdir(tmp_path)) == ["seq"]
    # an empty folder is fine without --force
    (tmp_path / "empty").mkdir()
    assert invoke(tmp_path / "empty", "--scenario", "tilt-sweep", "--frames", 1, *SMALL, "-q").exit_code == 0
    # a folder that is not a simulate output is never replaced
    other = tmp_path / "mine"
    other.mkdir()
    (other / "notes.txt").write_text("keep")
    r = invoke(other, "--scenario", "orbit", "--frames", 1, *SMALL, "-q", "--force")
    assert r.exit_code == 1 and "not replacing" in r.output
    assert (other / "notes.txt").read_text() == "keep"
    r = invoke(tmp_path / "missing" / "seq", "--scenario", "orbit", "--frames", 1, *SMALL, "-q")
    assert r.exit_code == 1 and "does not exist" in r.output


def test_a_failed_run_leaves_nothing(tmp_path, monkeypatch):
    from pencilcal.toolkit.synth import scenarios as scenes

    real = scenes.Scenario.render

    def flaky(self, i, **kw):
        if i == 1:
            raise InputError("simulated failure")
        return real(self, i, **kw)

    monkeypatch.setattr(scenes.Scenario, "render", flaky)
    r = invoke(tmp_path / "seq", "--scenario", "orbit", "--frames", 3, *SMALL, "-q")
    assert r.exit_code == 1 and "simulated failure" in r.output
    assert os.listdir(tmp_path) == []
    # a failure while replacing keeps the earlier output
    monkeypatch.setattr(scenes.Scenario, "render", real)
    assert invoke(tmp_path / "seq", "--scenario", "orbit", "--frames", 1, *SMALL, "-q").exit_code == 0
    before = (tmp_path / "seq" / "truth.json").read_text()
    monkeypatch.setattr(scenes.Scenario, "render", flaky)
    r = invoke(tmp_path / "seq", "--scenario", "orbit", "--frames", 3, *SMALL, "-q", "--force")
    assert r.exit_code == 1
    assert (tmp_path / "seq" / "truth.json").read_text() == before
    assert sorted(os.listdir(tmp_path)) == ["seq"]


@pytest.mark.parametrize("args,message", [
    (["--scenario", "orbit", "--size", "12"], "WxH"),
    (["--scenario", "spin"], "spin"),
    (["--scenario", "orbit", "--frames", "0"], "frames"),
    (["--scenario", "orbit", "--noise", "-1"], "noise"),
])
def test_usage_errors_exit_2(tmp_path, args, message):
    r = invoke(tmp_path / "x", *args)
    assert r.exit_code == 2 and message in r.output
    assert not (tmp_path / "x").exists()


def test_help_has_an_example():
    r = invoke("--help")
    assert r.exit_code == 0 and "Example" in r.output and "pencilcal simulate" in r.output
