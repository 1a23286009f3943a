"""`pencilcal pnp`: the poses.json contract, exit codes and messages (frames rendered by toolkit/synth/render.py)."""
from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from click.testing import CliRunner

from pencilcal.cli.pnp import pnp
from pencilcal.toolkit.board.spec import board_from_dict
from pencilcal.toolkit.camera.model import Camera
from pencilcal.toolkit.camera.formats import write_camera
from pencilcal.toolkit.geometry.frames import rotation_about_axis, rotation_angle
from pencilcal.validation.pnp import METHODS, POSE_KEYS
from pencilcal.toolkit.synth.render import render_frame
from pencilcal.toolkit.synth.sheet import layout_sheet

BOARD_YAML = "type: charuco\nsquares: [7, 5]\nsquare: 30.0\nmarker: 22.0\ndictionary: DICT_4X4_50\n"
BOARD = board_from_dict({"type": "charuco", "squares": [7, 5], "square": 30.0, "marker": 22.0,
                         "dictionary": "DICT_4X4_50"})
CAMERA = Camera("opencv", 640, 480, [[600.0, 0, 319.5], [0, 600.0, 239.5], [0, 0, 1]], [-0.05, 0.01, 0.0, 0.0])


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    """images/: 000-002 a board at known poses, 003 corrupt, 004 blank; camera.json, board.yaml."""
    d = tmp_path_factory.mktemp("pnp")
    (d / "images").mkdir()
    write_camera(d / "camera.json", CAMERA)
    (d / "board.yaml").write_text(BOARD_YAML)
    rng = np.random.default_rng(4)
    sheet = layout_sheet(BOARD, paper="a3")
    c = BOARD.object_points().mean(0)
    truth = []
    for k in range(3):
        R = rotation_about_axis([np.cos(2 * k), np.sin(2 * k), 0.0], np.radians(25 + 8 * k))
        t = np.array([10.0 * k, -5.0, 420.0]) - R @ c
        img = render_frame(CAMERA, R, t, sheet, background="plain", noise=1.0, rng=rng)
        cv2.imwrite(str(d / "images" / f"{k:03d}.png"), img)
        truth.append((R, t))
    (d / "images" / "003.png").write_bytes(b"\x89PNG\r\n\x1a\n broken")
    cv2.imwrite(str(d / "images" / "004.png"), np.full((480, 640), 128, np.uint8))
    return d, truth


def invoke(*args):
    return CliRunner().invoke(pnp, [str(a) for a in args])


def run_pnp(d, out, *extra):
    return invoke(d / "images", "--camera", d / "camera.json", "--board", d / "board.yaml", "-o", out, "-q", *extra)


def test_pnp_writes_contract(scene, tmp_path):
    d, truth = scene
    out = tmp_path / "poses.json"
    r = run_pnp(d, out)
    assert r.exit_code == 0, r.output
    data = json.loads(out.read_text())
    assert data["method"] == "sqpnp" and data["camera_model"] == "opencv" and data["image_size"] == [640, 480]
    assert data["board_spec"]["dictionary"] == "DICT_4X4_50" and "cov_convention" in data
    frames = data["frames"]
    assert [f["image"] for f in frames] == ["000.png", "001.png", "002.png", "003.png", "004.png"]
    for f in frames:
        assert all(k in f for k in POSE_KEYS), f
    for f, (R, t) in zip(frames[:3], truth):
        assert f["ok"] and f["method"] == "sqpnp" and f["corners"] == 24 and f["error"] is None
        Rf, tf = np.asarray(f["R_cam_from_target"]), np.asarray(f["t_cam_from_target"])
        assert np.degrees(rotation_angle(Rf, R)) < 1.0 and np.linalg.norm(tf - t) < 3.0  # mm
        # the error is what the covariance in the file says it may be
        e = np.concatenate([cv2.Rodrigues(R @ Rf.T)[0].ravel(), t - tf])
        assert e @ np.linalg.solve(np.asarray(f["cov"]), e) < 30.0
        assert f["reproj_rms_px"] < 0.3 and np.asarray(f["cov"]).shape == (6, 6)
        assert f["ids"] == list(range(24)) and np.asarray(f["residuals_px"]).shape == (24, 2)
        assert np.allclose(f["tvec"], f["t_cam_from_target"]) and np.allclose(
            cv2.Rodrigues(np.asarray(f["rvec"]))[0], f["R_cam_from_target"], atol=1e-12)
    corrupt, blank = frames[3], frames[4]
    assert corrupt["ok"] is False and "decode" in corrupt["error"] and corrupt["R_cam_from_target"] is None
    assert blank["ok"] is False and blank["error"] == "no board corners found" and blank["corners"] == 0
    # each failing frame is one warning line on stderr
    assert "003.png" in r.output and "004.png" in r.output


def test_pnp_method_all(scene, tmp_path):
    d, truth = scene
    out = tmp_path / "poses.json"
    r = run_pnp(d, out, "--method", "all", "--corner-sigma", "0.2")
    assert r.exit_code == 0, r.output
    data = json.loads(out.read_text())
    assert data["method"] == "all" and data["methods"] == list(METHODS) and data["corner_sigma_px"] == 0.2
    f = data["frames"][0]
    assert f["ok"] and f["method"] == "sqpnp" and f["sigma_from"] == "given" and f["sigma_px"] == 0.2
    assert set(f["methods"]) == set(METHODS)
    for m, rec in f["methods"].items():
        assert rec["method"] == m and rec["ok"], rec["error"]
        assert np.degrees(rotation_angle(np.asarray(rec["R_cam_from_target"]),
                                         np.asarray(f["R_cam_from_target"]))) < 1e-4
        assert "residuals_px" not in rec and rec["alternative_rms_px"] is not None
    assert data["frames"][3]["ok"] is False and data["frames"][3]["method"] == "all"


def test_no_overwrite_without_force(scene, tmp_path):
    d, _ = scene
    out = tmp_path / "poses.json"
    out.write_text("keep me")
    r = run_pnp(d, out)
    assert r.exit_code == 1 and "already exists" in r.output and "--force" in r.output
    assert out.read_text() == "keep me"
    assert run_pnp(d, out, "--force").exit_code == 0


def _one_line_error(r, words):
    assert r.exit_code == 1, r.output
    lines = [ln for ln in r.output.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("pencilcal: error:"), r.output
    for w in words:
        assert w in lines[0], lines[0]
    assert "Traceback" not in r.output


def test_image_size_mismatch_is_one_line_exit_1(scene, tmp_path):
    d, _ = scene
    (tmp_path / "imgs").mkdir()
    cv2.imwrite(str(tmp_path / "imgs" / "a.png"), np.zeros((240, 320), np.uint8))
    out = tmp_path / "poses.json"
    r = invoke(tmp_path / "imgs", "--camera", d / "camera.json", "--board", d / "board.yaml", "-o", out, "-q")
    _one_line_error(r, ["320x240", "640x480"])
    assert not out.exists()


def test_empty_folder_is_exit_1(scene, tmp_path):
    d, _ = scene
    (tmp_path / "empty").mkdir()
    r = invoke(tmp_path / "empty", "--camera", d / "camera.json", "--board", d / "board.yaml",
               "-o", tmp_path / "p.json", "-q")
    _one_line_error(r, ["no images"])


def test_unknown_dictionary_is_exit_1(scene, tmp_path):
    d, _ = scene
    (tmp_path / "board.yaml").write_text(BOARD_YAML.replace("DICT_4X4_50", "DICT_4X4_51"))
    r = invoke(d / "images", "--camera", d / "camera.json", "--board", tmp_path / "board.yaml",
               "-o", tmp_path / "p.json", "-q")
    _one_line_error(r, ["unknown ArUco dictionary", "DICT_4X4_51"])


def test_missing_camera_is_exit_1(scene, tmp_path):
    d, _ = scene
    r = invoke(d / "images", "--camera", tmp_path / "nope.json", "--board", d / "board.yaml",
               "-o", tmp_path / "p.json", "-q")
    _one_line_error(r, ["nope.json"])


@pytest.mark.parametrize("args", [
    ["--min-corners", "3"], ["--corner-sigma", "-1"], ["--max-rms", "0"], ["--method", "p3p"],
])
def test_bad_options_are_usage_errors(scene, tmp_path, args):
    d, _ = scene
    r = run_pnp(d, tmp_path / "p.json", *args)
    assert r.exit_code == 2, r.output
    assert not (tmp_path / "p.json").exists()


def test_min_corners_rejects_partial_views(scene, tmp_path):
    """Every frame rejected: the run failed, exit 1 with one line, no output left behind;
    each frame's reason is a warning line."""
    d, _ = scene
    out = tmp_path / "p.json"
    r = run_pnp(d, out, "--min-corners", "30")
    assert r.exit_code == 1 and "no frame gave a pose" in r.output
    assert "only 24 board corners found (--min-corners 30)" in r.output
    assert not out.exists()


def test_help_has_an_example():
    r = invoke("--help")
    assert r.exit_code == 0
    assert "Example" in r.output and "pencilcal pnp" in r.output
    for opt in ("--method", "--camera-id", "--corner-sigma", "--min-corners", "--force", "--quiet"):
        assert opt in r.output


def test_corners_found_as_the_calibration_found_them(scene, tmp_path):
    """A camera calibrated on ChArUco corners refined to their point of symmetry (`calibrate
    --symmetric-corners`, recorded in its statistics) has its board's corners refined so:
    poses.json says so, and on the renders the reprojection RMS falls."""
    d, _ = scene
    meta = {"calibration": {"symmetric_corners": True}}
    write_camera(tmp_path / "sym.json", Camera(CAMERA.model, 640, 480, CAMERA.K, CAMERA.dist, meta=meta))
    rms = {}
    for name, cam in (("plain", d / "camera.json"), ("sym", tmp_path / "sym.json")):
        out = tmp_path / f"poses_{name}.json"
        r = invoke(d / "images", "--camera", cam, "--board", d / "board.yaml", "-o", out, "-q")
        assert r.exit_code == 0, r.output
        data = json.loads(out.read_text())
        assert data["symmetric_corners"] is (name == "sym")
        rms[name] = np.median([f["reproj_rms_px"] for f in data["frames"] if f["ok"]])
    assert rms["sym"] < 0.5 * rms["plain"], rms  # measured 0.070 -> 0.026 px
