"""`pencilcal fulcrum --stabilize`: a rendered pivot (simulate's port view over a printed
sheet, 960x540, colour, noise 3, blur 1.5 px) whose camera turns 3 deg about its own
centre after the sixth frame, the pivot never moving."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest
from click.testing import CliRunner

from pencilcal.cli.main import cli
from pencilcal.toolkit.camera.formats import write_camera
from pencilcal.toolkit.geometry.frames import rotation_about_axis
from pencilcal.toolkit.synth.scenarios import make_scenario

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def sequence(tmp_path_factory):
    """(folder with images/ and cam.json, the exact fulcrum image of frames 6-11)."""
    import cv2

    tmp = tmp_path_factory.mktemp("turned")
    sc = make_scenario("pivot", 12, seed=5, size=(960, 540), port_view=100.0, shaft_radius=4.0, tip=100.0,
                       height=60.0, angle_range_deg=(55.0, 125.0))
    Q = rotation_about_axis(np.array([0.6, 0.8, 0.0]), math.radians(3.0))
    for fr in sc.frames[6:]:
        fr["R_cam_from_target"], fr["t_cam_from_target"] = Q @ fr["R_cam_from_target"], Q @ fr["t_cam_from_target"]
    (tmp / "images").mkdir()
    for i, fr in enumerate(sc.frames):
        cv2.imwrite(str(tmp / "images" / fr["image"]), sc.render(i, color=True, noise=3.0, blur_px=1.5, lighting=0.3))
    write_camera(tmp / "cam.json", sc.camera)
    return tmp, sc.camera.project(Q @ sc.frames[0]["fulcrum_cam"])


def _chi2(doc, truth):
    """chi2 (2 dof) of fulcrum.json's image of the fulcrum against the exact one."""
    e = np.asarray(doc["vertex_px"]) - truth
    return float(e @ np.linalg.solve(np.asarray(doc["vertex_cov_px2"]), e))


def _run(*args):
    return CliRunner().invoke(cli, [str(a) for a in args])


def test_stabilize_takes_the_turn_out(sequence):
    """Without --stabilize the fulcrum is far from either half's (chi2 above 100); with it the
    lines are one epoch whose fulcrum is the reference (middle) frame's within 3 sigma, and
    fulcrum.json's ``stabilize`` says per frame the homography used and its residual."""
    tmp, truth = sequence
    r = _run("fulcrum", tmp / "images", "--camera", tmp / "cam.json", "-o", tmp / "plain.json", "-q")
    assert r.exit_code == 0, r.output
    plain = json.loads((tmp / "plain.json").read_text())
    assert _chi2(plain, truth) > 100.0  # measured: 40 px off, chi2 859 (the other half's lines outvoted)
    r = _run("fulcrum", tmp / "images", "--camera", tmp / "cam.json", "--stabilize", "-o", tmp / "f.json", "-q")
    assert r.exit_code == 0, r.output
    doc = json.loads((tmp / "f.json").read_text())
    st = doc["stabilize"]
    assert st["model"] == "homography" and st["reference"] == "006.png" and st["frames_measured"] == 12
    assert len(st["frames"]) == 12 and all(f["ok"] and f["rms_px"] < 1.0 and f["inliers"] >= 100 for f in st["frames"])
    assert np.shape(st["frames"][0]["H_ref_from_frame"]) == (3, 3) and np.shape(st["frames"][0]["H_cov"]) == (8, 8)
    assert doc["epoch_test"]["epochs"] == 1
    assert _chi2(doc, truth) < 11.8  # chi2(2) at 3 sigma's 99.73 %; measured: 0.54 px off, chi2 0.15


def test_stabilize_needs_the_frames(sequence, tmp_path):
    """--stabilize measures the motion on the images: with --lines it is a usage error."""
    tmp, _ = sequence
    (tmp_path / "l.json").write_text("{}")
    r = _run("fulcrum", "--lines", tmp_path / "l.json", "--camera", tmp / "cam.json", "--stabilize", "-o",
             tmp_path / "f.json")
    assert r.exit_code == 2 and "--stabilize measures the camera's motion on IMAGES" in r.output
