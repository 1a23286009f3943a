"""--mask and the valid region of the detecting commands: lines.json's `valid_region`, no
lines on a field stop's edge, mask files (PNG, JSON, a lines.json) and their errors."""
from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from click.testing import CliRunner

from pencilcal.cli.lines import lines
from pencilcal.cli.orient import orient
from pencilcal.toolkit.camera.formats import write_camera
from pencilcal.toolkit.camera.model import Camera
from pencilcal.toolkit.io.lines_file import read_lines
from tests.toolkit.detect.region.test_valid import FIELD, field_with_shaft


@pytest.fixture(scope="module")
def field(tmp_path_factory):
    """Two 640x480 frames of a circular field with a shaft entering it, and a pinhole camera."""
    d = tmp_path_factory.mktemp("mask")
    (d / "frames").mkdir()
    for i in range(2):
        cv2.imwrite(str(d / "frames" / f"{i:03d}.png"), field_with_shaft(seed=i))
    write_camera(d / "camera.json", Camera("pinhole", 640, 480, [[640.0, 0, 319.5], [0, 640.0, 239.5], [0, 0, 1]]))
    return d


def run_lines(d, out, *extra):
    r = CliRunner().invoke(lines, [str(d / "frames"), "--camera", str(d / "camera.json"), "-o", str(out), "--quiet",
                                   *map(str, extra)])
    return r, (json.loads(out.read_text()) if r.exit_code == 0 else None)


def test_lines_detects_and_writes_the_region(field):
    r, doc = run_lines(field, field / "lines.json")
    assert r.exit_code == 0, r.output
    cx, cy, r50 = FIELD
    c = doc["valid_region"]["circle"]
    assert list(doc) == ["detector", "mode", "camera", "valid_region", "frames"]
    assert np.hypot(c[0] - cx, c[1] - cy) < 1.0 and r50 - 8.0 < c[2] < r50
    assert all("valid_region" not in f for f in doc["frames"])  # once, for the sequence
    for f in read_lines(field / "lines.json"):
        seg = f["segments"]
        assert len(seg) >= 2
        mid = 0.5 * (seg[:, :2] + seg[:, 2:])
        assert np.all(np.hypot(mid[:, 0] - cx, mid[:, 1] - cy) < r50 - 4.0)  # none on the field's edge


def test_mask_png_json_and_a_lines_file(field):
    m = np.zeros((480, 640), np.uint8)
    cv2.circle(m, (320, 240), 150, 255, -1)
    cv2.imwrite(str(field / "mask.png"), m)
    r, doc = run_lines(field, field / "png.json", "--mask", field / "mask.png")
    assert r.exit_code == 0, r.output
    poly = np.array(doc["valid_region"]["polygon"])
    assert np.all(np.hypot(poly[:, 0] - 320, poly[:, 1] - 240) < 152)
    for f in read_lines(field / "png.json"):
        ends = f["segments"].reshape(-1, 2)
        assert np.all(np.hypot(ends[:, 0] - 320, ends[:, 1] - 240) <= 151)
    (field / "circle.yaml").write_text("circle: [320, 240, 180]\n")
    r, doc = run_lines(field, field / "yaml.json", "--mask", field / "circle.yaml")
    assert r.exit_code == 0, r.output
    assert doc["valid_region"] == {"circle": [320.0, 240.0, 180.0]}
    # a lines.json's own region serves as a mask
    r, doc2 = run_lines(field, field / "again.json", "--mask", field / "yaml.json")
    assert r.exit_code == 0, r.output
    assert doc2["valid_region"] == doc["valid_region"] and doc2["frames"] == doc["frames"]


@pytest.mark.parametrize("content, message", [
    (None, "mask is 10x10, the images are 640x480"),
    ('{"circle": [1, 2]}', "circle must have 3 numbers"),
    ('{"circle": [-900, -900, 5]}', "contains no pixel"),
    ("{circle", "not valid JSON"),
])
def test_bad_masks_are_one_line_errors(field, content, message):
    if content is None:
        path = field / "small.png"
        cv2.imwrite(str(path), np.full((10, 10), 255, np.uint8))
    else:
        path = field / "bad.json"
        path.write_text(content)
    r, _ = run_lines(field, field / "bad_out.json", "--mask", path)
    assert r.exit_code == 1
    line = r.output.strip()
    assert "\n" not in line and path.name in line and message in line, line
    assert not (field / "bad_out.json").exists()


def test_mask_and_edges_need_images(field):
    r = CliRunner().invoke(orient, ["--lines", str(field / "lines.json"), "--camera", str(field / "camera.json"),
                                    "--pencil", "x.yaml", "-o", str(field / "o.json"), "--mask", "m.png"])
    assert r.exit_code == 2 and "--mask" in r.output
