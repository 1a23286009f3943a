"""`pencilcal orient IMAGES` finds a fan's spokes whatever they look like, with no width in
the pencil file: thin printed lines and thick bars, dark on light and light on dark (the
light fans are the dark ones' frames with their grey levels turned over). Issue 12 item 4."""
from __future__ import annotations

import json

import cv2
import pytest
from click.testing import CliRunner

from pencilcal.cli.main import cli
from pencilcal.toolkit.camera.formats import write_camera
from pencilcal.toolkit.pencil.spec import Pencil, read_pencil, write_pencil
from pencilcal.toolkit.synth.scenarios import make_scenario
from pencilcal.toolkit.synth.sheet import layout_sheet

FANS = {"thin": dict(spokes=9, width=1.2), "thick": dict(spokes=9, width=4.0, radius=(35.0, 90.0))}


def fan_sequence(d, kind, light, width_in_file):
    """Two frames (tilt 25 and 50 deg) of a 9-spoke fan at 1280x720; returns the truth tilts."""
    sc = make_scenario("tilt-sweep", 3, seed=1, sheet=layout_sheet(**FANS[kind]), size=(1280, 720), max_tilt_deg=50.0)
    (d / "images").mkdir()
    truth = {}
    for i in (1, 2):
        img = sc.render(i, noise=5.0, blur_px=1.5)
        cv2.imwrite(str(d / "images" / sc.frames[i]["image"]), 255 - img if light else img)
        truth[sc.frames[i]["image"]] = sc.frames[i]["tilt_deg"]
    write_camera(d / "camera.json", sc.camera)
    p = sc.sheet.pencil
    write_pencil(d / "pencil.yaml", p if width_in_file else Pencil(p.angles, p.vertex, p.radius, None))
    return truth


def orient_frames(d, *extra):
    out = d / "orientation.json"
    out.unlink(missing_ok=True)
    r = CliRunner().invoke(cli, ["orient", str(d / "images"), "--camera", str(d / "camera.json"), "--pencil",
                                 str(d / "pencil.yaml"), "-o", str(out), "--quiet", *extra])
    return r, (json.loads(out.read_text())["frames"] if out.exists() else [])


@pytest.mark.slow
@pytest.mark.parametrize("kind", sorted(FANS))
@pytest.mark.parametrize("light", [False, True], ids=["dark-on-light", "light-on-dark"])
def test_orient_finds_the_spokes_without_their_width(tmp_path, kind, light):
    truth = fan_sequence(tmp_path, kind, light, width_in_file=False)
    r, frames = orient_frames(tmp_path)
    assert r.exit_code == 0, r.output
    for f in frames:
        assert f["ok"] and f["lines_used"] >= 8, f
        err = f["tilt_deg"] - truth[f["image"]]
        assert abs(err) < 4.0 * f["tilt_sigma_deg"] and abs(err) < 0.3, (f["image"], err, f["tilt_sigma_deg"])


@pytest.mark.slow
def test_with_the_width_the_spokes_are_dark_bars_as_before(tmp_path):
    """The pencil file's width says the spokes are dark bars: on a dark fan the same lines,
    and the same orientations, as without it; plain edge segments only with --edges."""
    truth = fan_sequence(tmp_path, "thin", False, width_in_file=True)
    r, with_width = orient_frames(tmp_path)
    assert r.exit_code == 0, r.output
    assert all(f["ok"] and abs(f["tilt_deg"] - truth[f["image"]]) < 0.3 for f in with_width)
    p = read_pencil(tmp_path / "pencil.yaml")
    write_pencil(tmp_path / "pencil.yaml", Pencil(p.angles, p.vertex, p.radius, None), force=True)
    r, plain = orient_frames(tmp_path)
    assert r.exit_code == 0, r.output
    assert [f["tilt_deg"] for f in plain] == [f["tilt_deg"] for f in with_width]
    r, edges = orient_frames(tmp_path, "--edges")  # each spoke gives two edges: a worse pencil
    assert r.exit_code in (0, 1), r.output
    assert r.exit_code == 1 or [f["tilt_deg"] for f in edges] != [f["tilt_deg"] for f in plain]


@pytest.mark.slow
def test_validate_finds_the_same_fan_lines(tmp_path):
    """validate's FanLines finds the fan's lines as orient IMAGES does: the spokes of a light
    fan without a width, edge segments with edges=True."""
    from pencilcal.toolkit.camera.formats import read_camera
    from pencilcal.validation.validate import FanLines

    fan_sequence(tmp_path, "thick", True, width_in_file=False)
    img = cv2.imread(str(tmp_path / "images" / "002.png"), cv2.IMREAD_UNCHANGED)
    cam = read_camera(tmp_path / "camera.json")
    pen = read_pencil(tmp_path / "pencil.yaml")
    assert len(FanLines(pen)(img, cam, None)["segments"]) >= 9  # the spokes, and a few strips of the board
    assert len(FanLines(pen, edges=True)(img, cam, None)["segments"]) >= 18  # two edges a spoke
