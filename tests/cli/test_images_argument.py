"""IMAGES on the command line: several paths as a shell passes them, in the order given."""
from __future__ import annotations

import json

import cv2
import numpy as np
from click.testing import CliRunner

from pencilcal.cli.main import cli
from pencilcal.toolkit.camera.formats import write_camera
from pencilcal.toolkit.camera.model import Camera


def _setup(tmp_path, names):
    cam = Camera("pinhole", 160, 120, [[150.0, 0, 79.5], [0, 150.0, 59.5], [0, 0, 1]], [])
    write_camera(tmp_path / "camera.json", cam)
    img = np.full((120, 160), 200, np.uint8)
    cv2.line(img, (10, 20), (150, 100), 30, 3)
    paths = []
    for n in names:
        p = tmp_path / n
        p.parent.mkdir(exist_ok=True)
        assert cv2.imwrite(str(p), img)
        paths.append(str(p))
    return paths


def test_a_shell_glob_expands_to_several_arguments(tmp_path):
    paths = _setup(tmp_path, ["left/img10.png", "left/img2.png", "other.png"])
    out = tmp_path / "lines.json"
    # as `pencilcal lines left/*.png other.png` after the shell expanded the glob
    r = CliRunner().invoke(cli, ["lines", *sorted(paths[:2]), paths[2], "--camera", str(tmp_path / "camera.json"),
                                 "-o", str(out), "-q"])
    assert r.exit_code == 0, r.output
    frames = json.loads(out.read_text())["frames"]
    assert [f["image"] for f in frames] == ["img10.png", "img2.png", "other.png"]  # the order given


def test_duplicates_and_a_video_among_images_are_one_line_errors(tmp_path):
    paths = _setup(tmp_path, ["a.png"])
    cam = str(tmp_path / "camera.json")
    r = CliRunner().invoke(cli, ["lines", paths[0], str(tmp_path), "--camera", cam, "-o", str(tmp_path / "o.json")])
    assert r.exit_code == 1 and "given twice" in r.output and len(r.output.strip().splitlines()) == 1
    v = tmp_path / "v.avi"
    w = cv2.VideoWriter(str(v), cv2.VideoWriter_fourcc(*"MJPG"), 5, (160, 120))
    w.write(np.zeros((120, 160, 3), np.uint8))
    w.release()
    r = CliRunner().invoke(cli, ["lines", str(v), paths[0], "--camera", cam, "-o", str(tmp_path / "o.json")])
    assert r.exit_code == 1 and "only IMAGES argument" in r.output
    assert not (tmp_path / "o.json").exists()


def test_help_says_how_images_are_taken():
    for cmd in ("lines", "calibrate", "pnp", "orient", "fulcrum"):
        r = CliRunner().invoke(cli, [cmd, "--help"])
        assert "order given" in " ".join(r.output.split()), cmd
