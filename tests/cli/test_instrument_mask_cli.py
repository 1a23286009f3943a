"""--instrument-mask MASKS on `lines --shaft`, `fulcrum` and `validate`: the shafts are the
masked instruments' axes refined on the image; the masks' pairing and file errors are one
line, exit 1; nothing is overwritten without --force."""
from __future__ import annotations

import json
import shutil

import cv2
import numpy as np
import pytest
from click.testing import CliRunner

from pencilcal.cli.main import cli
from pencilcal.toolkit.synth.folder import write_sequence
from pencilcal.toolkit.synth.scenarios import make_scenario

FRAMES = 4


@pytest.fixture(scope="module")
def pivot(tmp_path_factory):
    """A simulate pivot folder (colour, 960x540, a 25 px shaft) and masks/ beside its images:
    each instrument's exact coverage drawn a pixel wide on one side, as a network might."""
    d = tmp_path_factory.mktemp("maskcli")
    sc = make_scenario("pivot", FRAMES, seed=3, size=(960, 540), shaft_radius=4.0, distance=250.0)
    write_sequence(d / "sim", sc, color=True)
    (d / "masks").mkdir()
    for i, fr in enumerate(sc.frames):
        m = (sc.instrument_coverage(i) >= 0.5).astype(np.uint8) * 255
        m[1:] |= m[:-1]
        cv2.imwrite(str(d / "masks" / fr["image"]), m)
    return d


def _run(*args):
    return CliRunner().invoke(cli, [str(a) for a in args])


def _lines(d, out, *extra):
    return _run("lines", d / "sim" / "images", "--camera", d / "sim" / "camera.json", "--shaft",
                "--instrument-mask", d / "masks", "-o", out, "-q", *extra)


def _one_line_error(r, *words):
    assert r.exit_code == 1, r.output
    lines = [ln for ln in r.output.strip().splitlines() if ln.startswith("pencilcal: error:")]
    assert len(lines) == 1 and all(w in lines[0] for w in words), r.output


def test_lines_writes_the_masks_shafts(pivot, tmp_path):
    r = _lines(pivot, tmp_path / "l.json", "--shaft-diameter", 8)
    assert r.exit_code == 0, r.output
    doc = json.loads((tmp_path / "l.json").read_text())
    assert doc["instrument_mask"] == str(pivot / "masks")
    for f in doc["frames"]:
        (sh,) = f["shafts"]
        assert sh["cue"] == "mask" and sh["kind"] == "shaft" and sh["mask_agrees"] is True
        assert sh["edge_from"] == ["image", "image"] and len(sh["mask_offset_px"]) == 2
        assert sh["instrument"] == 0 and "axis_direction" in sh and "mask_warning" not in sh
    truth = json.loads((pivot / "sim" / "truth.json").read_text())
    # the 3-D axis from the refined edges: the diameter fixes the depth
    for f, t in zip(doc["frames"], truth["frames"]):
        a, b = np.asarray(f["shafts"][0]["axis_direction"]), np.asarray(t["axis_direction_cam"])
        assert np.degrees(np.arccos(min(1.0, abs(float(a @ b))))) < 1.5


def test_a_disagreeing_mask_is_warned_about(pivot, tmp_path):
    d = tmp_path / "wide"
    shutil.copytree(pivot / "masks", d)
    p = sorted(d.iterdir())[0]
    m = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
    cv2.imwrite(str(p), cv2.dilate(m, np.ones((15, 15), np.uint8)))  # 7 px wide all round
    r = _run("lines", pivot / "sim" / "images", "--camera", pivot / "sim" / "camera.json", "--shaft",
             "--instrument-mask", d, "-o", tmp_path / "l.json", "-q")
    assert r.exit_code == 0, r.output
    assert f"pencilcal: warning: {p.name}: instrument 0:" in r.output and "the mask's edge used" in r.output
    sh = json.loads((tmp_path / "l.json").read_text())["frames"][0]["shafts"][0]
    assert sh["mask_agrees"] is False and "mask" in sh["edge_from"]


def test_mask_file_errors_are_one_line(pivot, tmp_path):
    bad = tmp_path / "bad"
    shutil.copytree(pivot / "masks", bad)
    first = sorted(bad.iterdir())[0]
    first.write_bytes(b"not a png")
    _one_line_error(_lines(pivot, tmp_path / "a.json", "--instrument-mask", bad), first.name, "cannot decode the mask")
    small = tmp_path / "small"
    shutil.copytree(pivot / "masks", small)
    p = sorted(small.iterdir())[1]
    cv2.imwrite(str(p), np.zeros((270, 480), np.uint8))
    _one_line_error(_lines(pivot, tmp_path / "b.json", "--instrument-mask", small), p.name,
                    "the mask is 480x270 but its frame is 960x540")
    few = tmp_path / "few"
    few.mkdir()
    for k in range(2):
        shutil.copy(sorted((pivot / "masks").iterdir())[k], few / f"other_{k}.png")
    _one_line_error(_lines(pivot, tmp_path / "c.json", "--instrument-mask", few), "2 mask(s) for 4 frame(s)",
                    "000.png")
    assert not any((tmp_path / n).exists() for n in ("a.json", "b.json", "c.json"))


def test_usage_and_no_overwrite(pivot, tmp_path):
    r = _run("lines", pivot / "sim" / "images", "--camera", pivot / "sim" / "camera.json", "--instrument-mask",
             pivot / "masks", "-o", tmp_path / "x.json")
    assert r.exit_code == 2 and "only with --shaft" in r.output
    r = _run("lines", pivot / "sim" / "images", "--camera", pivot / "sim" / "camera.json", "--shaft",
             "--mask-label", "3", "-o", tmp_path / "x.json")
    assert r.exit_code == 2 and "go with --instrument-mask" in r.output
    out = tmp_path / "l.json"
    out.write_text("mine")
    _one_line_error(_lines(pivot, out), "l.json")
    assert out.read_text() == "mine"
    assert _lines(pivot, out, "--force").exit_code == 0 and out.read_text() != "mine"


def test_fulcrum_and_validate_take_the_masks(pivot, tmp_path):
    r = _run("fulcrum", pivot / "sim" / "images", "--camera", pivot / "sim" / "camera.json", "--instrument-mask",
             pivot / "masks", "--mask-label", "255", "--shaft-diameter", 8, "-o", tmp_path / "f.json", "-q")
    assert r.exit_code == 0, r.output
    f = json.loads((tmp_path / "f.json").read_text())
    truth = json.loads((pivot / "sim" / "truth.json").read_text())
    assert f["instrument_mask"] == str(pivot / "masks") and f["lines_used"] == FRAMES and "frames_tracked" not in f
    assert np.linalg.norm(np.asarray(f["point"]) - truth["pivot"]["fulcrum_cam"]) < 5.0  # mm, from 4 frames
    r = _run("validate", pivot / "sim", "--instrument-mask", pivot / "masks", "--methods", "ippe", "--models", "exact",
             "-o", tmp_path / "v.json", "-q")
    assert r.exit_code == 0, r.output
    v = json.loads((tmp_path / "v.json").read_text())
    assert v["fulcrum"]["instrument_mask"] == str(pivot / "masks")
    r = _run("fulcrum", "--lines", tmp_path / "f.json", "--camera", pivot / "sim" / "camera.json",
             "--instrument-mask", pivot / "masks", "-o", tmp_path / "g.json")
    assert r.exit_code == 2 and "--instrument-mask" in r.output
