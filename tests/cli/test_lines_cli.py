"""`pencilcal lines`: the lines.json contract, --bars, --shaft, exit codes and messages."""
from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from click.testing import CliRunner

from pencilcal.cli.lines import lines
from pencilcal.toolkit.camera.model import Camera
from pencilcal.toolkit.camera.formats import write_camera
from pencilcal.toolkit.io.lines_file import read_lines
from pencilcal.toolkit.pencil.orient import orient_segments
from tests.toolkit.detect.scenes import fan_scene, line_errors
from tests.toolkit.detect.shaft.test_detector import render_shaft, shaft_from


def invoke(*args):
    return CliRunner().invoke(lines, [str(a) for a in args])


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    """Two frames of a fan (640x480, mild distortion), a camera file, the truth."""
    d = tmp_path_factory.mktemp("lines")
    cam = Camera("opencv", 640, 480, [[800.0, 0, 319.5], [0, 800.0, 239.5], [0, 0, 1]], [-0.1, 0.02, 0, 0, 0])
    write_camera(d / "camera.json", cam)
    (d / "frames").mkdir()
    rng = np.random.default_rng(7)
    truth = {}
    for i in range(2):
        img, pen, R, t, ideal = fan_scene(cam, rng, tilt_deg=25 + 10 * i, depth=230.0, pixel=(320, 240))
        cv2.imwrite(str(d / "frames" / f"{i:03d}.png"), img)
        truth[f"{i:03d}.png"] = (R, ideal)
    return d, cam, pen, truth


def test_bars_happy_path(scene):
    d, cam, pen, truth = scene
    out = d / "bars.json"
    r = invoke(d / "frames", "--camera", d / "camera.json", "--bars", "--detector", "fld", "-o", out, "--quiet")
    assert r.exit_code == 0, r.output
    frames = read_lines(out)
    assert [f["image"] for f in frames] == ["000.png", "001.png"]
    raw = json.loads(out.read_text())
    assert raw["detector"] == "fld" and raw["mode"] == "bars"
    for fr in frames:
        assert fr["ok"] and fr["segments"].shape == (8, 4)
        assert fr["angle_sigma_deg"].shape == (8,) and np.all(fr["angle_sigma_deg"] > 0)
        R, ideal = truth[fr["image"]]
        found = cam.undistort_pixels(fr["segments"].reshape(-1, 2)).reshape(-1, 4)
        assert all(np.abs(e[1]).max() < 0.15 for e in line_errors(found, ideal))
        # the file feeds orient directly, with the per-segment sigmas
        rec = orient_segments(cam, fr["segments"], pen, angle_sigma=np.radians(fr["angle_sigma_deg"]))
        assert rec.ok and rec.lines_used == 8
        err = min(np.degrees(np.arccos(np.clip(np.asarray(n) @ R[:, 2], -1, 1)))
                  for n in (rec.normal, rec.normal_twin))
        assert err < 0.3


def test_edges_mode_gives_two_edges_per_bar(scene):
    d, cam, pen, truth = scene
    out = d / "edges.json"
    r = invoke(d / "frames" / "000.png", "--camera", d / "camera.json", "-o", out, "-q", "--min-length", 40)
    assert r.exit_code == 0, r.output
    fr = read_lines(out)[0]
    assert fr["segments"].shape[0] == 16  # two long edges per bar (the caps are short)
    assert "shafts" not in fr


def test_shaft_option(tmp_path):
    cam = Camera("opencv", 640, 480, [[420.0, 0, 319.5], [0, 420.0, 239.5], [0, 0, 1]], [-0.25, 0.07, 0, 0, 0])
    write_camera(tmp_path / "camera.yaml", cam)
    rng = np.random.default_rng(1)
    img = render_shaft(cam, [shaft_from([-30.0, 14.0, 22.0], [2.0, -4.0, 85.0])], rng)
    (tmp_path / "v").mkdir()
    cv2.imwrite(str(tmp_path / "v" / "a.png"), img)
    r = invoke(tmp_path / "v", "--camera", tmp_path / "camera.yaml", "--shaft", "-o", tmp_path / "l.json", "-q")
    assert r.exit_code == 0, r.output
    fr = read_lines(tmp_path / "l.json")[0]
    assert len(fr["shafts"]) == 1
    sh = fr["shafts"][0]
    # the sigma holds the measured edge floor (EDGE_FLOOR_PX at either end of each edge), so even
    # a clean render's shaft is not surer than about floor / seen length
    assert sh["midline"].shape == (4,) and sh["width_px"] > 40 and 0.05 < sh["angle_sigma_deg"] < 1.0
    assert fr["segments"].shape[0] >= 2  # the shaft's own edges among them

    # --no-segments: the same shafts alone (a live shaft video does not pay for the segments)
    r = invoke(tmp_path / "v", "--camera", tmp_path / "camera.yaml", "--shaft", "--no-segments",
               "-o", tmp_path / "s.json", "-q")
    assert r.exit_code == 0, r.output
    alone = read_lines(tmp_path / "s.json")[0]
    assert alone["segments"].shape == (0, 4) and len(alone["shafts"]) == 1
    np.testing.assert_array_equal(alone["shafts"][0]["midline"], sh["midline"])
    r = invoke(tmp_path / "v", "--camera", tmp_path / "camera.yaml", "--no-segments", "-o", tmp_path / "x.json")
    assert r.exit_code == 2 and "--no-segments" in r.output and "only with --shaft" in r.output


def test_undecodable_frame_is_a_warning(scene, tmp_path):
    d, cam, pen, truth = scene
    frames = tmp_path / "f"
    frames.mkdir()
    (frames / "000.png").write_bytes((d / "frames" / "000.png").read_bytes())
    (frames / "001.png").write_bytes(b"\x89PNG broken")
    r = invoke(frames, "--camera", d / "camera.json", "--bars", "-o", tmp_path / "o.json", "-q")
    assert r.exit_code == 0, r.output
    assert "001.png" in r.output and "warning" in r.output
    fr = read_lines(tmp_path / "o.json")
    assert fr[0]["ok"] and not fr[1]["ok"] and fr[1]["segments"].shape == (0, 4)


def test_wrong_image_size_is_one_line_exit_1(scene, tmp_path):
    d, cam, pen, truth = scene
    (tmp_path / "small").mkdir()
    cv2.imwrite(str(tmp_path / "small" / "x.png"), np.zeros((240, 320), np.uint8))
    r = invoke(tmp_path / "small", "--camera", d / "camera.json", "-o", tmp_path / "o.json", "-q")
    assert r.exit_code == 1
    assert r.output.strip().count("\n") == 0 and "320x240" in r.output and "640x480" in r.output
    assert not (tmp_path / "o.json").exists()


def test_empty_folder_and_existing_output(scene, tmp_path):
    d, cam, pen, truth = scene
    (tmp_path / "empty").mkdir()
    r = invoke(tmp_path / "empty", "--camera", d / "camera.json", "-o", tmp_path / "o.json")
    assert r.exit_code == 1 and "no images" in r.output
    (tmp_path / "o.json").write_text("keep")
    r = invoke(d / "frames", "--camera", d / "camera.json", "-o", tmp_path / "o.json", "-q")
    assert r.exit_code == 1 and "already exists" in r.output
    assert (tmp_path / "o.json").read_text() == "keep"


@pytest.mark.parametrize("args,hint", [
    (["--detector", "hough"], "detector"),
    (["--min-length", "0"], "--min-length"),
    (["--bar-width", "5", "2", "--bars"], "--bar-width"),
    (["--bar-width", "2", "5"], "--bar-width"),
])
def test_usage_errors_exit_2(scene, tmp_path, args, hint):
    d, cam, pen, truth = scene
    r = invoke(d / "frames", "--camera", d / "camera.json", "-o", tmp_path / "o.json", *args)
    assert r.exit_code == 2 and hint in r.output


def test_help_has_an_example():
    r = invoke("--help")
    assert r.exit_code == 0
    assert "Example" in r.output and "--bars" in r.output and "--shaft" in r.output


def test_lines_shaft_edge_model_limb(tmp_path):
    """--edge-model limb: the shaded shaft's band as wide as it is (docs/method.md, the limb
    model); only with --shaft."""
    from pencilcal.toolkit.synth.shaded import MATERIALS, render_shaded_shaft

    cam = Camera("pinhole", 640, 480, [[520.0, 0, 319.5], [0, 520.0, 239.5], [0, 0, 1]])
    write_camera(tmp_path / "camera.json", cam)
    img, truth = render_shaded_shaft(cam, [0, 0, 120], [1.0, 0.35, 0.5], 4.0, MATERIALS["glossy"],
                                     background=(0.35, 0.3, 0.5), blur_px=1.0, noise=1.5, rng=3)
    (tmp_path / "frames").mkdir()
    cv2.imwrite(str(tmp_path / "frames" / "0.png"), img)
    r = invoke(tmp_path / "frames", "--camera", tmp_path / "camera.json", "--shaft", "--edge-model", "limb",
               "-o", tmp_path / "l.json", "-q")
    assert r.exit_code == 0, r.output
    data = json.loads((tmp_path / "l.json").read_text())
    assert data["edge_model"] == "limb"
    sh = read_lines(tmp_path / "l.json")[0]["shafts"][0]
    mid = np.asarray(sh["midline"], float)
    assert abs(sh["width_px"] / truth.width_at(0.5 * (mid[:2] + mid[2:])) - 1) < 0.003
    r = invoke(tmp_path / "frames", "--camera", tmp_path / "camera.json", "--edge-model", "limb",
               "-o", tmp_path / "m.json")
    assert r.exit_code == 2 and "--edge-model" in r.output


def test_lines_shaft_parts(tmp_path):
    """--parts: a stubby grey jaw entering from the border (110 px wide, 140 long: under the
    cues' 1.25 widths at the border, no shaft for them; over a region's least length of one
    width) gets an axis (cue pixels, its kind written); only with --shaft."""
    from tests.toolkit.detect.shaft.test_parts import _frame

    write_camera(tmp_path / "camera.json", Camera("pinhole", 640, 480, [[640.0, 0, 319.5], [0, 640.0, 239.5], [0, 0, 1]]))
    (tmp_path / "frames").mkdir()
    cv2.imwrite(str(tmp_path / "frames" / "0.png"), _frame([[0, 170], [140, 185], [140, 295], [0, 290]]))
    r = invoke(tmp_path / "frames", "--camera", tmp_path / "camera.json", "--shaft", "--parts", "-o",
               tmp_path / "l.json", "-q")
    assert r.exit_code == 0, r.output
    data = json.loads((tmp_path / "l.json").read_text())
    assert data["parts"] is True
    shafts = read_lines(tmp_path / "l.json")[0]["shafts"]
    got = [s for s in shafts if s["cue"] == "pixels"]
    assert len(got) == 1 and got[0]["kind"] in ("shaft", "part")
    assert all("kind" in s for s in shafts)
    r = invoke(tmp_path / "frames", "--camera", tmp_path / "camera.json", "--parts", "-o", tmp_path / "m.json")
    assert r.exit_code == 2 and "--parts" in r.output
