"""Camera files: exact round trips, every conversion between formats, malformed inputs."""
from __future__ import annotations

import ast
import itertools
import json
import os
import struct

import cv2
import numpy as np
import pycolmap
import pytest

from pencilcal.toolkit.camera.model import Camera
from pencilcal.toolkit.camera.formats import (camera_from_colmap, camera_from_dict, camera_to_colmap,
                                         camera_to_dict, read_camera, write_camera)
from pencilcal.toolkit.errors import InputError

# values with all 53 bits in use, so any loss of precision shows
_r = np.random.default_rng(2024)


def _K(skew=0.0):
    return [[1500.0 + _r.random(), skew, 955.0 + _r.random()], [0.0, 1498.0 + _r.random(), 535.0 + _r.random()],
            [0.0, 0.0, 1.0]]


CAMERAS = {
    "pinhole": Camera("pinhole", 1920, 1080, _K()),
    "opencv4": Camera("opencv", 1920, 1080, _K(), _r.normal(0, 0.05, 4)),
    "opencv5": Camera("opencv", 1920, 1080, _K(), _r.normal(0, 0.05, 5)),
    "opencv8": Camera("opencv", 1920, 1080, _K(), _r.normal(0, 0.05, 8)),
    "opencv12": Camera("opencv", 1920, 1080, _K(), _r.normal(0, 0.01, 12)),
    "opencv14": Camera("opencv", 1920, 1080, _K(), np.r_[_r.normal(0, 0.01, 12), 0.011, -0.007]),
    "fisheye": Camera("fisheye", 1280, 800, _K(), _r.normal(0, 0.01, 4)),
    "skew": Camera("opencv", 1920, 1080, _K(skew=0.75 + _r.random()), _r.normal(0, 0.05, 5)),
}
ALL = set(CAMERAS)
COLMAP_OK = {"pinhole", "opencv4", "opencv5", "opencv8", "fisheye"}
FORMATS = {  # file name -> cameras the format holds exactly
    "cam.json": ALL,
    "cam.yaml": ALL,
    "cam.yml": ALL,
    "cam.xml": ALL,
    "cam.cameramodel": {"pinhole", "opencv4", "opencv5", "opencv8", "opencv12"},
    "cameras.txt": COLMAP_OK,
    "cameras.bin": COLMAP_OK,
    "sparse": COLMAP_OK,
}


def _same(a, b):
    """Equal, and bit-for-bit (equality alone would let -0.0 pass for 0.0)."""
    return a == b and a.K.tobytes() == b.K.tobytes() and a.dist.tobytes() == b.dist.tobytes()


@pytest.mark.parametrize("fname,name", [(f, c) for f in FORMATS for c in sorted(FORMATS[f])])
def test_round_trip_is_exact(tmp_path, fname, name):
    cam = CAMERAS[name]
    p = tmp_path / fname
    write_camera(p, cam)
    back = read_camera(p)
    assert _same(back, cam), (back, cam)


@pytest.mark.parametrize("a,b", list(itertools.product(FORMATS, FORMATS)))
def test_every_conversion_between_formats(tmp_path, a, b):
    names = sorted(FORMATS[a] & FORMATS[b])
    assert names
    for name in names:
        cam = CAMERAS[name]
        pa, pb = tmp_path / f"a_{name}" / a, tmp_path / f"b_{name}" / b
        pa.parent.mkdir()
        pb.parent.mkdir()
        write_camera(pa, cam)
        write_camera(pb, read_camera(pa))
        assert _same(read_camera(pb), cam), (a, b, name)


@pytest.mark.parametrize("fname,name", [(f, c) for f in FORMATS for c in sorted(ALL - FORMATS[f])])
def test_formats_refuse_cameras_they_cannot_hold(tmp_path, fname, name):
    p = tmp_path / fname
    with pytest.raises(InputError) as e:
        write_camera(p, CAMERAS[name])
    msg = str(e.value)
    assert str(p) in msg and "\n" not in msg
    assert any(w in msg for w in ("skew", "fisheye", "coefficients")), msg
    assert not p.exists() and os.listdir(tmp_path) == []  # nothing half-written, no temp files


def test_colmap_principal_point_shift(tmp_path):
    cam = Camera("pinhole", 640, 480, [[500.0, 0, 319.5], [0, 501.0, 239.25], [0, 0, 1]])
    write_camera(tmp_path / "cameras.txt", cam)
    line = [ln for ln in (tmp_path / "cameras.txt").read_text().splitlines() if not ln.startswith("#")][0]
    assert line.split() == ["1", "PINHOLE", "640", "480", "500", "501", "320", "239.75"]
    c = camera_to_colmap(cam)
    assert c.model.name == "PINHOLE" and c.params.tolist() == [500.0, 501.0, 320.0, 239.75]


def test_colmap_shift_across_a_power_of_two_costs_at_most_one_ulp():
    """cx + 0.5 crossing 1024 has one bit less to spare: documented, bounded by 1 ulp."""
    cx = np.nextafter(1023.7, 2000.0)
    cam = Camera("pinhole", 2048, 1536, [[1800.0, 0, cx], [0, 1800.0, 700.1], [0, 0, 1]])
    back = camera_from_colmap(camera_to_colmap(cam))
    assert abs(back.cx - cx) <= np.spacing(cx)
    assert back.cy == cam.cy


def test_colmap_models_map_to_pencilcal(tmp_path):
    lines = ["1 SIMPLE_PINHOLE 640 480 500 320 240", "2 SIMPLE_RADIAL 640 480 500 320 240 -0.1",
             "3 RADIAL 640 480 500 320 240 -0.1 0.02", "4 FULL_OPENCV 640 480 500 501 320 240 0.1 0.2 0.01 0.02 0.3 0 0 0",
             "5 FULL_OPENCV 640 480 500 501 320 240 0.1 0.2 0.01 0.02 0.3 0.4 0 0"]
    p = tmp_path / "cameras.txt"
    p.write_text("# cameras\n" + "\n".join(lines) + "\n")
    got = {i: read_camera(p, camera_id=i) for i in range(1, 6)}
    assert got[1] == Camera("pinhole", 640, 480, [[500, 0, 319.5], [0, 500, 239.5], [0, 0, 1]])
    assert got[2].model == "opencv" and got[2].dist.tolist() == [-0.1, 0, 0, 0]
    assert got[3].dist.tolist() == [-0.1, 0.02, 0, 0]
    assert got[4].dist.tolist() == [0.1, 0.2, 0.01, 0.02, 0.3]  # k4..k6 = 0: the 5-coefficient camera
    assert got[5].dist.size == 8


def test_colmap_several_cameras_need_an_id(tmp_path):
    p = tmp_path / "cameras.txt"
    p.write_text("3 PINHOLE 640 480 500 500 320 240\n7 PINHOLE 800 600 600 600 400 300\n")
    with pytest.raises(InputError, match=r"cameras \[3, 7\]") as e:
        read_camera(p)
    assert str(p) in str(e.value)
    assert read_camera(p, camera_id=7).size == (800, 600)
    with pytest.raises(InputError, match=r"no camera with id 5"):
        read_camera(p, camera_id=5)


def test_colmap_folder_is_a_complete_model(tmp_path):
    cam = CAMERAS["opencv8"]
    write_camera(tmp_path / "sparse", cam)
    rec = pycolmap.Reconstruction()
    rec.read(str(tmp_path / "sparse"))  # pycolmap reads it as a whole model
    assert camera_from_colmap(rec.cameras[1]) == cam
    # a folder with a binary model keeps its format
    b = tmp_path / "bin_model"
    b.mkdir()
    rec.write_binary(str(b))
    write_camera(b, CAMERAS["fisheye"], force=True)
    assert (b / "cameras.bin").is_file() and not (b / "cameras.txt").exists()
    assert read_camera(b) == CAMERAS["fisheye"]


def test_colmap_reader_prefers_binary_like_colmap(tmp_path):
    d = tmp_path / "m"
    d.mkdir()
    write_camera(d / "cameras.txt", CAMERAS["opencv4"])
    write_camera(d / "cameras.bin", CAMERAS["fisheye"])
    assert read_camera(d) == CAMERAS["fisheye"]


# ---------------------------------------------------------------- overwrite and atomicity
@pytest.mark.parametrize("fname", sorted(FORMATS))
def test_existing_outputs_need_force(tmp_path, fname):
    p = tmp_path / fname
    write_camera(p, CAMERAS["opencv4"])
    with pytest.raises(InputError, match="force") as e:
        write_camera(p, CAMERAS["opencv5"])
    assert str(p) in str(e.value)
    assert read_camera(p) == CAMERAS["opencv4"]
    write_camera(p, CAMERAS["opencv5"], force=True)
    assert read_camera(p) == CAMERAS["opencv5"]
    leftovers = [f for f in os.listdir(tmp_path) if f.startswith(".")]
    assert leftovers == []


def test_missing_output_folder(tmp_path):
    for fname in ("cam.json", "cam.yaml", "cam.cameramodel", "cameras.txt", "sparse"):
        with pytest.raises(InputError, match="does not exist"):
            write_camera(tmp_path / "nope" / fname, CAMERAS["pinhole"])


# ---------------------------------------------------------------- meta
META = {"rms_px": 0.2345678901234567, "std_intrinsics": [0.5, 0.25, 1e-07], "views": 42,
        "per_view_rms_px": [[0.1, 0.2], [0.3, 0.4]], "note": "lab 3, lens B", "board": {"square": 5.0, "type": "charuco"}}


@pytest.mark.parametrize("fname", ["cam.json", "cam.yaml", "cam.xml"])
def test_meta_is_carried(tmp_path, fname):
    cam = Camera("opencv", 640, 480, _K(), [0.1, 0.01, 0, 0], meta=META)
    write_camera(tmp_path / fname, cam)
    back = read_camera(tmp_path / fname)
    assert back.meta == META


def test_meta_cannot_shadow_camera_fields(tmp_path):
    cam = Camera("pinhole", 640, 480, _K(), meta={"K": 1})
    for fname in ("cam.json", "cam.yaml"):
        with pytest.raises(InputError, match="collides"):
            write_camera(tmp_path / fname, cam)


def test_dict_form():
    cam = CAMERAS["opencv5"]
    d = camera_to_dict(cam)
    assert list(d)[:5] == ["model", "width", "height", "K", "dist"]
    assert camera_from_dict(json.loads(json.dumps(d))) == cam
    assert camera_from_dict({**d, "rms_px": 0.1}).meta == {"rms_px": 0.1}


# ---------------------------------------------------------------- other writers' files
def test_reads_opencv_sample_and_ros_yaml(tmp_path):
    # cv::FileStorage output of OpenCV's calibration sample: no distortion_model -> opencv
    p = tmp_path / "out_camera_data.yml"
    fs = cv2.FileStorage(str(p), cv2.FILE_STORAGE_WRITE)
    fs.write("nframes", 20)
    fs.write("image_width", 640)
    fs.write("image_height", 480)
    fs.write("camera_matrix", np.array([[500.0, 0, 319.5], [0, 500.0, 239.5], [0, 0, 1]]))
    fs.write("distortion_coefficients", np.array([[-0.1], [0.01], [0.0], [0.0], [0.001]]))
    fs.write("avg_reprojection_error", 0.25)
    fs.release()
    cam = read_camera(p)
    assert cam.model == "opencv" and cam.dist.tolist() == [-0.1, 0.01, 0.0, 0.0, 0.001]
    assert cam.meta == {"nframes": 20, "avg_reprojection_error": 0.25}
    # ROS camera_calibration_parsers YAML (plain YAML, rows/cols/data, plumb_bob)
    p = tmp_path / "ros.yaml"
    p.write_text("image_width: 2448\nimage_height: 2050\ncamera_name: prosilica\n"
                 "camera_matrix:\n  rows: 3\n  cols: 3\n  data: [4827.94, 0, 1223.5, 0, 4835.62, 1024.5, 0, 0, 1]\n"
                 "distortion_model: plumb_bob\n"
                 "distortion_coefficients:\n  rows: 1\n  cols: 5\n  data: [-0.41527, 0.31874, -0.00197, 0.00071, 0]\n")
    cam = read_camera(p)
    assert cam.model == "opencv" and cam.fx == 4827.94 and cam.dist.size == 5 and cam.size == (2448, 2050)
    # OpenCV's fisheye users name it; a file without coefficients is a pinhole
    p = tmp_path / "pin.yaml"
    p.write_text("%YAML:1.0\nimage_width: 64\nimage_height: 48\ncamera_matrix: !!opencv-matrix\n"
                 "   rows: 3\n   cols: 3\n   dt: d\n   data: [ 50., 0., 31.5, 0., 50., 23.5, 0., 0., 1. ]\n")
    assert read_camera(p).model == "pinhole"


def test_reads_a_hand_written_mrcal_model_with_comments_and_legacy_keys(tmp_path):
    p = tmp_path / "m.cameramodel"
    p.write_text("""# generated with mrcal-calibrate-cameras
{ 'lens_model': 'LENSMODEL_OPENCV8',

  # intrinsics are fx,fy,cx,cy,distortion0,distortion1,....
  'intrinsics': [1766.0712405930, 1765.8925266865, 1944.0664501036, 1064.5231421210,
                 2.1648025156, -1.1851581377, -0.0000931342, 0.0007782462,
                 -0.2351910903, 2.4460295029, -0.6697132481, -0.6284355415],
  # extrinsics are rt_fromref
  'extrinsics': [0.1,0,0,0,0,0],
  'imagersize': [3840,2160],
  'valid_intrinsics_region': [[0, 0], [10, 0], [10, 10], [0, 0]],
  'optimization_inputs': b'ignored',
}
""")
    cam = read_camera(p)
    assert cam.model == "opencv" and cam.size == (3840, 2160) and cam.dist.size == 8
    assert cam.K.tolist() == [[1766.0712405930, 0, 1944.0664501036], [0, 1765.8925266865, 1064.5231421210], [0, 0, 1]]
    p.write_text("{'distortion_model': 'DISTORTION_OPENCV4', 'intrinsics': [1, 2, 3, 4, 0.1, 0.2, 0.3, 0.4],"
                 " 'extrinsics': [0]*6 if False else [0, 0, 0, 0, 0, 0], 'imagersize': [8, 6]}")
    with pytest.raises(InputError, match="not a literal"):  # a conditional expression is not a literal
        read_camera(p)
    p.write_text("{'distortion_model': 'DISTORTION_OPENCV4', 'intrinsics': [1, 2, 3, 4, 0.1, 0.2, 0.3, 0.4],"
                 " 'extrinsics': [0, 0, 0, 0, 0, 0], 'imagersize': [8, 6]}")
    assert read_camera(p).dist.tolist() == [0.1, 0.2, 0.3, 0.4]


def test_written_cameramodel_has_mrcal_layout(tmp_path):
    p = tmp_path / "c.cameramodel"
    write_camera(p, CAMERAS["opencv12"])
    text = p.read_text()
    assert text.startswith("#")
    d = ast.literal_eval(text)
    # mrcal's reader requires these keys; extrinsics rt_fromref zero = camera at the reference
    assert set(d) == {"lensmodel", "intrinsics", "extrinsics", "imagersize"}
    assert d["lensmodel"] == "LENSMODEL_OPENCV12" and len(d["intrinsics"]) == 16
    assert d["extrinsics"] == [0.0] * 6 and d["imagersize"] == [1920, 1080]
    cam = CAMERAS["opencv12"]
    assert d["intrinsics"][:4] == [cam.fx, cam.fy, cam.cx, cam.cy]


# ---------------------------------------------------------------- malformed inputs
def _fs_text(K="[ 500., 0., 319.5, 0., 500., 239.5, 0., 0., 1. ]", extra="", width="640"):
    return ("%YAML:1.0\n---\n" + (f"image_width: {width}\n" if width is not None else "") + "image_height: 480\n"
            + (f"camera_matrix: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n   data: {K}\n" if K else "")
            + "distortion_coefficients: !!opencv-matrix\n   rows: 1\n   cols: 4\n   dt: d\n   data: [ 0.1, 0., 0., 0. ]\n"
            + extra)


_GOOD_JSON = {"model": "opencv", "width": 640, "height": 480,
              "K": [[500.0, 0, 319.5], [0, 500.0, 239.5], [0, 0, 1]], "dist": [0.1, 0, 0, 0]}

MALFORMED = {
    "json NaN in K": ("cam.json", json.dumps({**_GOOD_JSON, "K": [[float("nan"), 0, 319.5], [0, 500.0, 239.5], [0, 0, 1]]}), "non-finite"),
    "json missing key": ("cam.json", json.dumps({k: v for k, v in _GOOD_JSON.items() if k != "K"}), "missing key"),
    "json K shape": ("cam.json", json.dumps({**_GOOD_JSON, "K": [1, 2, 3]}), "3x3"),
    "json K strings": ("cam.json", json.dumps({**_GOOD_JSON, "K": [["500", 0, 319.5], [0, 500.0, 239.5], [0, 0, 1]]}), "3x3"),
    "json bad count": ("cam.json", json.dumps({**_GOOD_JSON, "dist": [0.1, 0.2, 0.3]}), "coefficients"),
    "json bad model": ("cam.json", json.dumps({**_GOOD_JSON, "model": "kb8"}), "unknown camera model"),
    "json width": ("cam.json", json.dumps({**_GOOD_JSON, "width": "640"}), "width"),
    "json syntax": ("cam.json", '{"model": "opencv",', "not valid JSON"),
    "json list": ("cam.json", "[1, 2]", "mapping"),
    "yaml NaN in K": ("cam.yaml", _fs_text(K="[ .Nan, 0., 319.5, 0., 500., 239.5, 0., 0., 1. ]"), "non-finite"),
    "yaml missing K": ("cam.yaml", _fs_text(K=None), "camera_matrix"),
    "yaml missing width": ("cam.yaml", _fs_text(width=None), "image_width"),
    "yaml fractional width": ("cam.yaml", _fs_text(width="640.5"), "whole number"),
    "yaml K 2x2": ("cam.yaml", _fs_text().replace("rows: 3\n   cols: 3\n   dt: d\n   data: [ 500., 0., 319.5, 0., 500., 239.5, 0., 0., 1. ]",
                                                  "rows: 2\n   cols: 2\n   dt: d\n   data: [ 500., 0., 0., 500. ]"), "3x3"),
    "yaml bad model": ("cam.yaml", _fs_text(extra="distortion_model: kannala_brandt8\n"), "distortion_model"),
    "yaml garbage": ("cam.yaml", "%YAML:1.0\n---\ncamera_matrix: [ 1, 2\n  : : ]]\n", "FileStorage"),
    "xml truncated": ("cam.xml", '<?xml version="1.0"?>\n<opencv_storage>\n<camera_matrix type_id="opencv-matrix">\n<rows>3</rows>', "FileStorage"),
    "cameramodel bad lens model": ("c.cameramodel", "{'lensmodel': 'LENSMODEL_SPLINED_STEREOGRAPHIC_order=3_Nx=30_Ny=20_fov_x_deg=170', "
                                   "'intrinsics': [1, 1, 1, 1], 'extrinsics': [0, 0, 0, 0, 0, 0], 'imagersize': [8, 6]}",
                                   "LENSMODEL_SPLINED_STEREOGRAPHIC_order=3_Nx=30_Ny=20_fov_x_deg=170"),
    "cameramodel cahvor": ("c.cameramodel", "{'lensmodel': 'LENSMODEL_CAHVOR', 'intrinsics': [1]*9, "
                           "'extrinsics': [0, 0, 0, 0, 0, 0], 'imagersize': [8, 6]}", "not a literal"),
    "cameramodel cahvor literal": ("c.cameramodel", "{'lensmodel': 'LENSMODEL_CAHVOR', 'intrinsics': [1, 1, 1, 1, 0, 0, 0, 0, 0], "
                                   "'extrinsics': [0, 0, 0, 0, 0, 0], 'imagersize': [8, 6]}", "LENSMODEL_CAHVOR"),
    "cameramodel missing intrinsics": ("c.cameramodel", "{'lensmodel': 'LENSMODEL_PINHOLE', 'imagersize': [8, 6]}", "intrinsics"),
    "cameramodel count": ("c.cameramodel", "{'lensmodel': 'LENSMODEL_OPENCV4', 'intrinsics': [1, 1, 1, 1, 0], "
                          "'imagersize': [8, 6]}", "needs 8 intrinsics"),
    "cameramodel inf": ("c.cameramodel", "{'lensmodel': 'LENSMODEL_PINHOLE', 'intrinsics': [1e999, 1, 1, 1], "
                        "'imagersize': [8, 6]}", "non-finite"),
    "cameramodel syntax": ("c.cameramodel", "{'lensmodel': 'LENSMODEL_PINHOLE',, }", "syntax"),
    "cameramodel not a dict": ("c.cameramodel", "[1, 2, 3]", "must be a dict"),
    "cameramodel bool": ("c.cameramodel", "{'lensmodel': 'LENSMODEL_PINHOLE', 'intrinsics': [True, 1, 1, 1], "
                         "'imagersize': [8, 6]}", "intrinsics"),
    "colmap unknown model": ("cameras.txt", "1 FOV 640 480 500 500 320 240 0.1\n", "FOV"),
    "colmap bad model name": ("cameras.txt", "1 NOPE 640 480 500 500 320 240\n", "COLMAP"),
    "colmap param count": ("cameras.txt", "1 PINHOLE 640 480 500 500 320\n", "COLMAP"),
    "colmap zero focal": ("cameras.txt", "1 PINHOLE 640 480 0 500 320 240\n", "fx > 0"),
    "colmap garbage": ("cameras.txt", "hello world\n", "COLMAP"),
    "colmap empty": ("cameras.txt", "# nothing\n", "no cameras"),
}


@pytest.mark.parametrize("case", sorted(MALFORMED))
def test_malformed_files_raise_input_error_with_the_path(tmp_path, case):
    fname, text, expect = MALFORMED[case]
    p = tmp_path / fname
    p.write_text(text)
    with pytest.raises(InputError) as e:
        read_camera(p)
    msg = str(e.value)
    assert msg.startswith(str(p)), msg
    assert "\n" not in msg
    assert expect in msg, msg


def test_cameramodel_expression_is_never_executed(tmp_path):
    marker = tmp_path / "pwned"
    payloads = [
        f"__import__('os').system('touch {marker}')",
        f"{{'lensmodel': 'LENSMODEL_PINHOLE', 'intrinsics': [1, 1, 1, 1], 'imagersize': [8, 6], "
        f"'x': __import__('os').system('touch {marker}')}}",
        f"{{'lensmodel': 'LENSMODEL_PINHOLE', 'intrinsics': [1, 1, 1, 1], 'imagersize': [8, 6], "
        f"'x': open('{marker}', 'w')}}",
        f"(lambda: open('{marker}', 'w'))()",
    ]
    for text in payloads:
        p = tmp_path / "evil.cameramodel"
        p.write_text(text)
        with pytest.raises(InputError, match="is not a literal") as e:
            read_camera(p)
        assert str(e.value).startswith(str(p)) and "\n" not in str(e.value)
        assert not marker.exists()


@pytest.mark.parametrize("cut", [0, 3, 8, 20, 40, 60, -1])
def test_truncated_cameras_bin(tmp_path, cut):
    """pycolmap itself returns zeros for a truncated cameras.bin; we must not."""
    good = tmp_path / "good" / "cameras.bin"
    good.parent.mkdir()
    write_camera(good, CAMERAS["opencv8"])
    data = good.read_bytes()
    p = tmp_path / "cameras.bin"
    p.write_bytes(data[:cut])
    with pytest.raises(InputError, match="cameras") as e:
        read_camera(p)
    assert str(e.value).startswith(str(p))


def test_cameras_bin_with_trailing_bytes_or_huge_count(tmp_path):
    good = tmp_path / "g" / "cameras.bin"
    good.parent.mkdir()
    write_camera(good, CAMERAS["pinhole"])
    data = good.read_bytes()
    p = tmp_path / "cameras.bin"
    p.write_bytes(data + b"\0" * 8)
    with pytest.raises(InputError, match="corrupt"):
        read_camera(p)
    p.write_bytes(struct.pack("<Q", 2**40) + data[8:])
    with pytest.raises(InputError, match="corrupt"):
        read_camera(p)


def test_paths_that_are_not_cameras(tmp_path):
    with pytest.raises(InputError, match="not found"):
        read_camera(tmp_path / "missing.json")
    with pytest.raises(InputError, match="unknown camera file type"):
        read_camera(tmp_path / "cam.ini")
    with pytest.raises(InputError, match="unknown camera file type"):
        write_camera(tmp_path / "cam.ini", CAMERAS["pinhole"])
    (tmp_path / "empty").mkdir()
    with pytest.raises(InputError, match="no COLMAP cameras"):
        read_camera(tmp_path / "empty")
    write_camera(tmp_path / "c.json", CAMERAS["pinhole"])
    with pytest.raises(InputError, match="COLMAP cameras files only"):
        read_camera(tmp_path / "c.json", camera_id=1)
    (tmp_path / "f").write_text("x")
    with pytest.raises(InputError, match="not a folder"):
        write_camera(tmp_path / "f", CAMERAS["pinhole"], force=True)
