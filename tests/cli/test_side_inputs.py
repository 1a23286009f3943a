"""Side files and odd inputs are checked up front: a prior that matches nothing or is no
rotation, an angles file listing an image twice, a video without frames."""
from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from click.testing import CliRunner

from pencilcal.cli.main import cli
from pencilcal.toolkit.errors import InputError
from pencilcal.toolkit.pencil.fulcrum import read_angles

EX = Path(__file__).resolve().parents[2] / "examples" / "orient"


def _orient(tmp_path, prior):
    p = tmp_path / "prior.json"
    p.write_text(json.dumps({"frames": prior}))
    return CliRunner().invoke(cli, ["orient", "--lines", str(EX / "lines.json"), "--camera", str(EX / "camera.yaml"),
                                    "--pencil", str(EX / "pencil.yaml"), "--prior", str(p),
                                    "-o", str(tmp_path / "o.json"), "-q"])


def test_a_prior_that_matches_no_frame_is_refused(tmp_path):
    r = _orient(tmp_path, [{"image": "nope.png", "R_cam_from_target": np.eye(3).tolist()}])
    assert r.exit_code == 1 and "none of its 1 image names" in r.output
    assert not (tmp_path / "o.json").exists()


def test_a_prior_that_is_no_rotation_is_refused(tmp_path):
    r = _orient(tmp_path, [{"image": "000.png", "R_cam_from_target": (2 * np.eye(3)).tolist()}])
    assert r.exit_code == 1 and "not a rotation" in r.output
    r = _orient(tmp_path, [{"image": "000.png", "R_cam_from_target": np.diag([1.0, 1, -1]).tolist()}])
    assert r.exit_code == 1 and "not a rotation" in r.output


def test_a_matching_prior_is_used(tmp_path):
    truth = json.loads((EX / "truth.json").read_text())["frames"][0]
    r = _orient(tmp_path, [{"image": truth["image"], "R_cam_from_target": truth["R_cam_from_target"]}])
    assert r.exit_code == 0, r.output
    frames = json.loads((tmp_path / "o.json").read_text())["frames"]
    assert frames[0]["resolved_by"] == "prior"


def test_an_angles_file_listing_an_image_twice_is_refused(tmp_path):
    p = tmp_path / "angles.csv"
    p.write_text("image,angle_deg\na.png,1\nb.png,2\na.png,3\n")
    with pytest.raises(InputError, match="listed twice"):
        read_angles(p, ["a.png", "b.png"])


def test_a_video_without_frames_is_refused(tmp_path):
    v = tmp_path / "empty.avi"
    w = cv2.VideoWriter(str(v), cv2.VideoWriter_fourcc(*"MJPG"), 5, (32, 24))
    w.release()
    cam = tmp_path / "camera.json"
    cam.write_text(json.dumps({"model": "pinhole", "width": 32, "height": 24,
                               "K": [[30, 0, 15.5], [0, 30, 11.5], [0, 0, 1]], "dist": []}))
    r = CliRunner().invoke(cli, ["lines", str(v), "--camera", str(cam), "-o", str(tmp_path / "o.json")])
    assert r.exit_code == 1 and ("holds no frames" in r.output or "cannot open" in r.output), r.output
