"""`pencilcal convert`: exact round trips between every pair of formats, refusals, fits."""
from __future__ import annotations

import itertools
import re
from pathlib import Path

import numpy as np
import pycolmap
import pytest
from click.testing import CliRunner

from pencilcal.cli.convert import convert
from pencilcal.toolkit.camera.convert import projection_difference
from pencilcal.toolkit.camera.formats import read_camera, write_camera
from pencilcal.toolkit.camera.model import Camera

CORPUS = Path(__file__).resolve().parents[1] / "corpus"
# all 53 bits in use, so any loss of precision shows; cx + 0.5 crosses no power of two
_r = np.random.default_rng(7)
_K = [[400.0 + _r.random(), 0.0, 160.0 + _r.random()], [0.0, 400.0 + _r.random(), 120.0 + _r.random()],
      [0.0, 0.0, 1.0]]
CAMERAS = {
    "pinhole": Camera("pinhole", 320, 240, _K),
    "opencv5": Camera("opencv", 320, 240, _K, _r.normal(0, 0.03, 5)),
    "fisheye": Camera("fisheye", 320, 240, _K, _r.normal(0, 0.01, 4)),
}
FORMATS = {"cam.json": set(CAMERAS), "cam.yaml": set(CAMERAS), "cam.xml": set(CAMERAS),
           "cam.cameramodel": {"pinhole", "opencv5"}, "cameras.txt": set(CAMERAS), "cameras.bin": set(CAMERAS),
           "sparse": set(CAMERAS)}
OPENCV12 = Camera("opencv", 640, 480, [[612.37, 0.0, 321.19], [0.0, 611.83, 238.71], [0.0, 0.0, 1.0]],
                  [-0.28, 0.09, 0.0007, -0.0004, -0.012, 0.02, 0.004, 0.001, 0.003, -0.001, 0.002, 0.0008])


def invoke(*args):
    return CliRunner().invoke(convert, [str(a) for a in args])


def _printed_px(output, key="largest reprojection difference over the image"):
    m = re.search(re.escape(key) + r" ([-+.\deinf]+) px", output)
    assert m, output
    return float(m.group(1))


def _same(a, b):
    """Equal, and bit-for-bit (equality alone would let -0.0 pass for 0.0)."""
    return a == b and a.K.tobytes() == b.K.tobytes() and a.dist.tobytes() == b.dist.tobytes()


def _round_trip(tmp_path, name, a, b):
    """Convert camera `name` written as format `a` to format `b`: exact, and says so."""
    cam = CAMERAS[name]
    src, out = tmp_path / f"{name}_{a}_{b}" / a, tmp_path / f"{name}_{a}_{b}" / "out" / b
    out.parent.mkdir(parents=True)
    write_camera(src, cam)
    r = invoke(src, "-o", out)
    assert r.exit_code == 0, r.output
    assert _same(read_camera(out), cam), (a, b, name)
    assert _printed_px(r.output) < 1e-8, r.output
    assert f"{src} -> {out}: " in r.output and r.output.count("\n") == 1


@pytest.mark.parametrize("a,b", list(itertools.product(FORMATS, FORMATS)))
def test_every_pair_of_formats_round_trips_exactly(tmp_path, a, b):
    _round_trip(tmp_path, "opencv5", a, b)


@pytest.mark.parametrize("name,fmt", [(n, f) for n in ("pinhole", "fisheye") for f in FORMATS if n in FORMATS[f]])
def test_pinhole_and_fisheye_round_trip_exactly(tmp_path, name, fmt):
    _round_trip(tmp_path, name, "cam.json", fmt)
    if fmt != "cam.json":
        _round_trip(tmp_path, name, fmt, "cam.json")


def test_colmap_round_trip_is_exact_and_shifts_the_principal_point(tmp_path):
    cam = CAMERAS["opencv5"]
    write_camera(tmp_path / "cam.json", cam)
    assert invoke(tmp_path / "cam.json", "-o", tmp_path / "cameras.txt").exit_code == 0
    line = [ln for ln in (tmp_path / "cameras.txt").read_text().splitlines() if not ln.startswith("#")][0].split()
    assert line[:4] == ["1", "FULL_OPENCV", "320", "240"]
    fx, fy, cx, cy = (float(v) for v in line[4:8])
    assert (fx, fy, cx, cy) == (cam.fx, cam.fy, cam.cx + 0.5, cam.cy + 0.5)
    assert [float(v) for v in line[8:]] == cam.dist.tolist() + [0.0, 0.0, 0.0]
    r = invoke(tmp_path / "cameras.txt", "-o", tmp_path / "back.json")
    assert r.exit_code == 0, r.output
    assert _same(read_camera(tmp_path / "back.json"), cam)


def test_refusal_names_the_file_what_it_cannot_hold_and_the_difference(tmp_path):
    write_camera(tmp_path / "cam12.json", OPENCV12)
    out = tmp_path / "cameras.txt"
    r = invoke(tmp_path / "cam12.json", "-o", out)
    assert r.exit_code == 1 and not out.exists()
    lines = r.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"pencilcal: error: {out}: COLMAP has no camera model for 12")
    assert "as opencv with 8 coefficients it would differ by up to 1.26 px over the image" in lines[0]
    assert "--approximate" in lines[0]


def test_approximate_fits_12_coefficients_into_colmap(tmp_path):
    write_camera(tmp_path / "cam12.json", OPENCV12)
    out = tmp_path / "cameras.txt"
    r = invoke(tmp_path / "cam12.json", "-o", out, "--approximate")
    assert r.exit_code == 0, r.output
    back = read_camera(out)
    d = projection_difference(OPENCV12, back)
    shown_max = _printed_px(r.output, "max")
    shown_rms = _printed_px(r.output, "RMS")
    assert shown_max == pytest.approx(d.max_px, rel=1e-2) and shown_rms == pytest.approx(d.rms_px, rel=1e-2)
    assert "12 opencv coefficients" in r.output and "fitted opencv with 5 coefficients" in r.output
    assert 0.01 < d.max_px < 0.75 and d.rms_px < 0.18  # measured 0.718 px, RMS 0.170 px


def test_approximate_fits_a_fisheye_into_mrcal(tmp_path):
    cam = Camera("fisheye", 320, 240, [[150.0, 0, 159.5], [0, 150.0, 119.5], [0, 0, 1]], [0.03, -0.01, 0.002, -0.0005])
    write_camera(tmp_path / "fish.yaml", cam)
    out = tmp_path / "fish.cameramodel"
    r = invoke(tmp_path / "fish.yaml", "-o", out)
    assert r.exit_code == 1 and "fisheye" in r.output and "--approximate writes the best-fitting opencv" in r.output
    r = invoke(tmp_path / "fish.yaml", "-o", out, "--approximate")
    assert r.exit_code == 0, r.output
    assert read_camera(out).model == "opencv"
    assert _printed_px(r.output, "max") < 0.003  # measured 0.0026 px: 74 deg off the axis at the corners


def test_terms_that_are_zero_are_dropped_without_approximate(tmp_path):
    cam = Camera("opencv", 640, 480, OPENCV12.K, np.r_[OPENCV12.dist[:8], 0.0, 0.0, 0.0, 0.0])
    write_camera(tmp_path / "cam.json", cam)
    r = invoke(tmp_path / "cam.json", "-o", tmp_path / "cameras.bin")
    assert r.exit_code == 0, r.output
    assert "12 opencv coefficients" in r.output and "written as opencv with 8 coefficients" in r.output
    assert _printed_px(r.output) < 1e-8
    assert read_camera(tmp_path / "cameras.bin").dist.tolist() == OPENCV12.dist[:8].tolist()


def test_never_overwrites_without_force(tmp_path):
    write_camera(tmp_path / "cam.json", CAMERAS["opencv5"])
    out = tmp_path / "cam.yaml"
    out.write_text("keep me\n")
    r = invoke(tmp_path / "cam.json", "-o", out)
    assert r.exit_code == 1 and "already exists; pass --force" in r.output
    assert out.read_text() == "keep me\n"
    r = invoke(tmp_path / "cam.json", "-o", out, "--force")
    assert r.exit_code == 0, r.output
    assert _same(read_camera(out), CAMERAS["opencv5"])


def test_an_existing_model_folder_needs_force(tmp_path):
    write_camera(tmp_path / "cam.json", CAMERAS["pinhole"])
    write_camera(tmp_path / "sparse", CAMERAS["opencv5"])
    assert invoke(tmp_path / "cam.json", "-o", tmp_path / "sparse").exit_code == 1
    r = invoke(tmp_path / "cam.json", "-o", tmp_path / "sparse", "--force")
    assert r.exit_code == 0, r.output
    assert _same(read_camera(tmp_path / "sparse"), CAMERAS["pinhole"])


@pytest.mark.parametrize("name,what", [("camera_missing_key.json", "missing key(s) ['K']"),
                                       ("camera_nan.yaml", "non-finite"),
                                       ("evil.cameramodel", "is not a literal"),
                                       ("absent.json", "camera file not found")])
def test_a_bad_input_file_is_one_line_and_exit_1(tmp_path, name, what):
    r = invoke(CORPUS / name, "-o", tmp_path / "out.json")
    lines = r.output.strip().splitlines()
    assert r.exit_code == 1 and len(lines) == 1, r.output
    assert lines[0].startswith(f"pencilcal: error: {CORPUS / name}") and what in lines[0]
    assert not (tmp_path / "out.json").exists()


def test_unknown_output_extension(tmp_path):
    write_camera(tmp_path / "cam.json", CAMERAS["pinhole"])
    r = invoke(tmp_path / "cam.json", "-o", tmp_path / "cam.txtx")
    assert r.exit_code == 1 and "unknown camera file type '.txtx'" in r.output


def test_camera_id_picks_one_of_several_colmap_cameras(tmp_path):
    rec = pycolmap.Reconstruction()
    for i, (w, h) in ((3, (640, 480)), (7, (800, 600))):
        rec.add_camera(pycolmap.Camera(model="PINHOLE", width=w, height=h, params=[500.0, 501.0, w / 2, h / 2],
                                       camera_id=i))
    rec.write_text(str(tmp_path))
    cams = tmp_path / "cameras.txt"
    r = invoke(cams, "-o", tmp_path / "cam.json")
    assert r.exit_code == 1 and "holds cameras [3, 7]; choose one with a camera id (--camera-id)" in r.output
    r = invoke(cams, "--camera-id", 7, "-o", tmp_path / "cam.json")
    assert r.exit_code == 0, r.output
    got = read_camera(tmp_path / "cam.json")
    assert got.size == (800, 600) and (got.cx, got.cy) == (399.5, 299.5)


def test_help_has_an_example():
    r = invoke("--help")
    assert r.exit_code == 0 and "pencilcal convert camera.json -o cameras.txt" in r.output
