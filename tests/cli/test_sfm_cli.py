"""`pencilcal sfm`: the output folder contract, exit codes and messages (orbit frames
rendered by toolkit/synth/render.py, as a folder and as a lossless video)."""
from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from click.testing import CliRunner

from pencilcal.cli.sfm import sfm
from pencilcal.toolkit.camera.formats import camera_to_colmap, write_camera
from pencilcal.toolkit.geometry.frames import rotation_angle
from pencilcal.toolkit.synth.scenarios import make_scenario
from pencilcal.validation.align import align_rotations
from pencilcal.validation.sfm import import_pycolmap, read_sfm_poses

try:  # as the library loads it: glog writes each log line through
    pycolmap = import_pycolmap()
except ImportError:
    pytest.skip("pycolmap is not installed", allow_module_level=True)

N = 8
SIZE = (640, 360)


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    """images/000.png..007.png, clip.avi (the same frames, lossless), camera.json, truth."""
    d = tmp_path_factory.mktemp("sfm_cli")
    sc = make_scenario("orbit", frames=N, seed=2, size=SIZE)
    (d / "images").mkdir()
    frames = [sc.render(i) for i in range(N)]
    for fr, img in zip(sc.frames, frames):
        cv2.imwrite(str(d / "images" / fr["image"]), img)
    video = None
    for fourcc in ("FFV1", "MJPG"):
        w = cv2.VideoWriter(str(d / "clip.avi"), cv2.VideoWriter_fourcc(*fourcc), 10, SIZE, isColor=True)
        if w.isOpened():
            for img in frames:
                w.write(cv2.cvtColor(img, cv2.COLOR_GRAY2BGR))
            w.release()
            video = d / "clip.avi"
            break
    write_camera(d / "camera.json", sc.camera)
    return d, sc, video


def invoke(*args):
    return CliRunner().invoke(sfm, [str(a) for a in args])


def one_error_line(r):
    lines = [ln for ln in r.output.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("pencilcal: error:"), r.output
    assert "Traceback" not in r.output
    return lines[0]


def leftovers(folder):
    return [p.name for p in folder.iterdir() if p.name.startswith(".")]


def test_folder_then_video_with_force(scene, tmp_path):
    d, sc, video = scene
    out = tmp_path / "sfm"
    r = invoke(d / "images", "--camera", d / "camera.json", "-o", out, "--max-features", 2048)
    assert r.exit_code == 0, r.output
    assert f"{N}/{N} frames registered" in r.output and "exhaustive matching" in r.output
    for name in ("poses.json", "database.db", "colmap.log", "sparse/0/cameras.bin", "sparse/0/images.bin",
                 "sparse/0/points3D.bin", "sparse/0/cameras.txt", "sparse/0/images.txt", "sparse/0/points3D.txt"):
        assert (out / name).is_file(), name
    assert not (out / "images").exists() and leftovers(tmp_path) == []
    raw = json.loads((out / "poses.json").read_text())
    assert raw["registered_count"] == N and raw["model"] == "sparse/0" and raw["database"] == "database.db"
    assert raw["images"] == str(d / "images") and raw["camera_file"] == str(d / "camera.json")
    assert raw["camera_unchanged"] is True and raw["matching"] == "exhaustive"
    assert set(raw["timings_s"]) >= {"extract", "match", "map", "total"}
    f0 = raw["frames"][0]
    assert f0["image"] == "000.png" and f0["registered"] is True
    assert {"R_cam_from_world", "t_cam_from_world", "camera_center"} <= set(f0)
    poses = read_sfm_poses(out / "poses.json")
    names = [f.image for f in poses["frames"]]
    R_cw = np.array([f.R_cam_from_world for f in poses["frames"]])
    R_ct = np.array([sc.frames[int(n[:3])]["R_cam_from_target"] for n in names])
    R_wt, _ = align_rotations(R_cw, R_ct)
    assert np.degrees(rotation_angle(R_cw @ R_wt, R_ct)).max() < 0.3
    (cam,) = pycolmap.Reconstruction(str(out / "sparse" / "0")).cameras.values()
    assert np.asarray(cam.params).tobytes() == np.asarray(camera_to_colmap(sc.camera).params).tobytes()

    # an existing output: refused without --force, replaced with it
    r = invoke(d / "images", "--camera", d / "camera.json", "-o", out)
    assert r.exit_code == 1 and "already exists" in one_error_line(r) and "--force" in r.output
    if video is None:
        pytest.skip("no video writer in this OpenCV build")
    r = invoke(video, "--camera", d / "camera.json", "-o", out, "--force", "--matching", "sequential",
               "--max-features", 2048, "--keep-frames", "--quiet")
    assert r.exit_code == 0, r.output
    assert r.output == ""  # --quiet: nothing on success
    raw = json.loads((out / "poses.json").read_text())
    assert raw["matching"] == "sequential" and raw["image_path"] == "images"
    assert [f["image"] for f in raw["frames"]] == [f"frame_{i:06d}" for i in range(N)]
    assert raw["registered_count"] >= N - 1
    assert sorted(p.name for p in (out / "images").iterdir()) == [f"frame_{i:06d}.png" for i in range(N)]
    assert leftovers(tmp_path) == []


def test_textureless_frames_fail_in_one_line_and_leave_nothing(scene, tmp_path):
    d, _, _ = scene
    grey = tmp_path / "grey"
    grey.mkdir()
    for i in range(3):
        cv2.imwrite(str(grey / f"{i}.png"), np.full((SIZE[1], SIZE[0]), 90, np.uint8))
    out = tmp_path / "sfm"
    r = invoke(grey, "--camera", d / "camera.json", "-o", out)
    assert r.exit_code == 1 and "too few features" in one_error_line(r)
    assert not out.exists() and leftovers(tmp_path) == []


def test_bad_input(scene, tmp_path):
    d, _, _ = scene
    out = tmp_path / "sfm"
    r = invoke(tmp_path / "nothing", "--camera", d / "camera.json", "-o", out)
    assert r.exit_code == 1 and "no such file or folder" in one_error_line(r)
    small = tmp_path / "small"
    small.mkdir()
    for i in range(3):
        cv2.imwrite(str(small / f"{i}.png"), np.zeros((180, 320), np.uint8))
    r = invoke(small, "--camera", d / "camera.json", "-o", out)
    assert r.exit_code == 1 and "320x180 but the camera was calibrated at 640x360" in one_error_line(r)
    one = tmp_path / "one"
    one.mkdir()
    cv2.imwrite(str(one / "0.png"), cv2.imread(str(d / "images" / "000.png")))
    r = invoke(one, "--camera", d / "camera.json", "-o", out)
    assert r.exit_code == 1 and "at least 3 images" in one_error_line(r)
    r = invoke(d / "images", "--camera", tmp_path / "missing.json", "-o", out)
    assert r.exit_code == 1 and "camera file not found" in one_error_line(r)
    assert not out.exists() and leftovers(tmp_path) == []
    # --force never replaces a folder that is not an sfm output
    other = tmp_path / "other"
    other.mkdir()
    (other / "notes.txt").write_text("mine")
    r = invoke(d / "images", "--camera", d / "camera.json", "-o", other, "--force")
    assert r.exit_code == 1 and "not an sfm output folder" in one_error_line(r)
    assert (other / "notes.txt").read_text() == "mine"
    (tmp_path / "file").write_text("x")
    r = invoke(d / "images", "--camera", d / "camera.json", "-o", tmp_path / "file")
    assert r.exit_code != 0


@pytest.mark.parametrize("args", [["--min-registered", "1"], ["--max-features", "0"], ["--matching", "vocab"]])
def test_usage_errors_exit_2(scene, tmp_path, args):
    d, _, _ = scene
    r = invoke(d / "images", "--camera", d / "camera.json", "-o", tmp_path / "sfm", *args)
    assert r.exit_code == 2, r.output


def test_help_has_an_example():
    r = invoke("--help")
    assert r.exit_code == 0
    assert "Example" in r.output and "pencilcal sfm" in r.output
    for opt in ("--camera", "--camera-id", "--matching", "--max-features", "--min-registered", "--force", "--quiet",
                "--verbose", "--keep-frames"):
        assert opt in r.output
