"""validation/sfm/: pycolmap reconstruction with fixed intrinsics against exact truth.

The orbit scenario (toolkit/synth/scenarios.py) renders a textured table with boxes around the
printed sheet, with the exact R_cam_from_target per frame. At 640x360, 14 frames and 2048
SIFT features per image every frame registers and the rotations agree with the truth to
0.03-0.07 deg (mean) / 0.05-0.11 deg (worst frame) over scenario seeds 0-7; the asserts
leave room (< 0.2 deg worst, < 0.1 deg mean).
"""
from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from pencilcal.toolkit.camera.formats import camera_from_colmap, camera_to_colmap, write_camera
from pencilcal.toolkit.errors import EstimationError, InputError
from pencilcal.toolkit.geometry.frames import rotation_angle
from pencilcal.toolkit.synth.scenarios import make_scenario
from pencilcal.validation.align import align_rotations, align_similarity
from pencilcal.validation.sfm import (
    EXHAUSTIVE_MAX_IMAGES,
    SfmResult,
    bare_pycolmap,
    choose_matching,
    colmap_logging,
    import_pycolmap,
    read_sfm_poses,
    reconstruct,
    write_sfm_poses,
)
from pencilcal.validation.sfm import progress as progress_module
from pencilcal.validation.sfm import pipeline as pipeline_module
from pencilcal.validation.sfm.prepare import prepare_frames
from pencilcal.validation.sfm.progress import extract_progress, match_progress, sequential_pair_count

try:  # as the library loads it: glog writes each log line through
    pycolmap = import_pycolmap()
except ImportError:
    pytest.skip("pycolmap is not installed", allow_module_level=True)

N_FRAMES = 14
SIZE = (640, 360)
FEATURES = 2048


@pytest.fixture(scope="module")
def orbit(tmp_path_factory):
    """images/000.png..013.png of the orbit scenario, its camera and truth."""
    d = tmp_path_factory.mktemp("sfm_orbit")
    sc = make_scenario("orbit", frames=N_FRAMES, seed=1, size=SIZE)
    (d / "images").mkdir()
    for i, fr in enumerate(sc.frames):
        cv2.imwrite(str(d / "images" / fr["image"]), sc.render(i))
    write_camera(d / "camera.json", sc.camera)
    return d, sc


@pytest.fixture(scope="module")
def recon(orbit, tmp_path_factory):
    d, sc = orbit
    stages = []
    res = reconstruct(d / "images", sc.camera, tmp_path_factory.mktemp("sfm_work") / "w", max_features=FEATURES,
                      progress=lambda s, done, total: stages.append((s, done, total)))
    return res, stages


def test_all_frames_registered(recon):
    res, _ = recon
    assert isinstance(res, SfmResult)
    assert res.n_frames == N_FRAMES
    assert res.n_registered == N_FRAMES
    assert res.registered.all()
    assert res.n_models == 1 and res.warnings == []
    assert res.matching == "exhaustive"  # auto with 14 images
    assert res.n_points3D > 1000
    assert 0 < res.mean_reprojection_error_px < 1.0
    assert [f.image for f in res.frames] == [f"{i:03d}.png" for i in range(N_FRAMES)]
    assert all(f.colmap_name == f.image and f.num_features > 500 and f.num_points3D > 100 for f in res.frames)


def test_rotations_match_truth(recon, orbit):
    res, _ = recon
    _, sc = orbit
    names, R_cw = res.rotations()
    R_ct = np.array([sc.frames[int(n[:3])]["R_cam_from_target"] for n in names])
    R_wt, inliers = align_rotations(R_cw, R_ct)
    err = np.degrees(rotation_angle(R_cw @ R_wt, R_ct))
    assert inliers.all()
    assert err.max() < 0.2, err
    assert err.mean() < 0.1, err


def test_centres_match_truth_up_to_similarity(recon, orbit):
    res, _ = recon
    _, sc = orbit
    reg = [f for f in res.frames if f.registered]
    C_w = np.array([f.camera_center for f in reg])
    C_t = np.array([sc.frames[f.index]["camera_center"] for f in reg])
    sim, _ = align_similarity(C_w, C_t)
    resid = np.linalg.norm(sim.apply(C_w) - C_t, axis=1)
    # cameras 340-460 mm away: centres within a couple of millimetres
    assert resid.max() < 3.0, resid


def test_pose_conventions(recon):
    res, _ = recon
    for f in res.frames:
        R, t = f.R_cam_from_world, f.t_cam_from_world
        np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
        assert np.linalg.det(R) == pytest.approx(1.0)
        np.testing.assert_allclose(f.camera_center, -R.T @ t, atol=1e-12)
    # the model in memory holds the same poses (cam_from_world maps world -> camera)
    rec = res.reconstruction
    im = rec.find_image_with_name(res.frames[3].colmap_name)
    X = np.array([0.3, -0.2, 1.5])
    f = res.frames[3]
    np.testing.assert_allclose(im.cam_from_world() * X, f.R_cam_from_world @ X + f.t_cam_from_world, atol=1e-12)


def test_intrinsics_bit_identical(recon, orbit):
    res, _ = recon
    _, sc = orbit
    want = camera_to_colmap(sc.camera)
    assert res.camera_unchanged
    on_disk = pycolmap.Reconstruction(str(res.model_path))
    for rec in (res.reconstruction, on_disk):
        (cam,) = rec.cameras.values()
        assert cam.model.name == want.model.name == "FULL_OPENCV"
        assert np.asarray(cam.params).tobytes() == np.asarray(want.params).tobytes()
        assert camera_from_colmap(cam) == sc.camera
    txt = pycolmap.Reconstruction()
    txt.read_text(str(res.model_path))
    assert np.asarray(next(iter(txt.cameras.values())).params).tobytes() == np.asarray(want.params).tobytes()


def test_output_layout(recon):
    res, _ = recon
    w = res.workdir
    assert res.model_path == w / "sparse" / "0"
    for name in ("cameras", "images", "points3D"):
        assert (res.model_path / f"{name}.bin").is_file()
        assert (res.model_path / f"{name}.txt").is_file()
    assert res.database_path == w / "database.db" and res.database_path.is_file()
    assert (w / "colmap.log").is_file() and "Keeping successful reconstruction" in (w / "colmap.log").read_text()
    assert not (w / "images").exists() and not (w / ".mapper").exists()
    assert str(res.image_path).endswith("images")  # read in place from the input folder
    assert set(res.timings) >= {"prepare", "extract", "match", "map", "write", "total"}


def test_progress_reports_every_stage(recon):
    _, stages = recon
    seen = [s for s, _, _ in stages]
    assert [s for i, s in enumerate(seen) if i == 0 or seen[i - 1] != s] == ["prepare", "extract", "match", "map",
                                                                               "write"]
    for stage in ("prepare", "extract", "match", "map"):
        last = [(d, t) for s, d, t in stages if s == stage][-1]
        assert last[0] == last[1] > 0


def test_poses_json_round_trip(recon, tmp_path):
    res, _ = recon
    p = tmp_path / "poses.json"
    write_sfm_poses(p, res, images="images/")
    raw = json.loads(p.read_text())
    assert raw["registered_count"] == N_FRAMES and raw["matching"] == "exhaustive"
    assert raw["images"] == "images/" and raw["pycolmap_version"] == pycolmap.__version__
    assert raw["camera_unchanged"] is True
    back = read_sfm_poses(p)
    for a, b in zip(res.frames, back["frames"]):
        assert (a.image, a.registered, a.colmap_name) == (b.image, b.registered, b.colmap_name)
        for k in ("R_cam_from_world", "t_cam_from_world", "camera_center"):
            assert np.array_equal(getattr(a, k), getattr(b, k))  # repr floats: exact
    with pytest.raises(InputError):
        write_sfm_poses(p, res)  # exists
    bad = dict(raw)
    bad["frames"] = [{k: v for k, v in raw["frames"][0].items() if k != "R_cam_from_world"}]
    (tmp_path / "bad.json").write_text(json.dumps(bad))
    with pytest.raises(InputError, match="R_cam_from_world"):
        read_sfm_poses(tmp_path / "bad.json")


def test_no_log_on_stderr_and_logging_restored(capfd, tmp_path):
    L = pycolmap.logging
    before = (L.minloglevel, L.alsologtostderr, L.stderrthreshold)
    with colmap_logging(tmp_path / "colmap.log"):
        L.info("pencilcal-test-info")
        L.warning("pencilcal-test-warning")
    out, err = capfd.readouterr()
    assert "pencilcal-test" not in out + err
    assert "pencilcal-test-warning" in (tmp_path / "colmap.log").read_text()
    assert (L.minloglevel, L.alsologtostderr, L.stderrthreshold) == before


def test_bare_pycolmap_baseline_holds_the_camera(orbit, tmp_path):
    """The benchmark's baseline does the same work: same camera, same fixed intrinsics."""
    d, sc = orbit
    sub = _write(tmp_path / "sub", [cv2.imread(str(d / "images" / f"{i:03d}.png"), cv2.IMREAD_GRAYSCALE)
                                    for i in range(5)])
    assert bare_pycolmap(sub, sc.camera, tmp_path / "bare", max_features=1024) == 5
    (cam,) = pycolmap.Reconstruction(str(tmp_path / "bare" / "sparse" / "0")).cameras.values()
    assert np.asarray(cam.params).tobytes() == np.asarray(camera_to_colmap(sc.camera).params).tobytes()


# ----------------------------------------------------------------------------- failures
def _write(folder, images, names=None):
    folder.mkdir(parents=True, exist_ok=True)
    for i, img in enumerate(images):
        cv2.imwrite(str(folder / (names[i] if names else f"{i:03d}.png")), img)
    return folder


def test_textureless_images_fail_in_one_line(orbit, tmp_path):
    _, sc = orbit
    d = _write(tmp_path / "grey", [np.full((SIZE[1], SIZE[0]), 128, np.uint8)] * 4)
    with pytest.raises(EstimationError, match="too few features") as e:
        reconstruct(d, sc.camera, tmp_path / "w")
    assert "\n" not in str(e.value)


def test_one_image_is_an_input_error(orbit, tmp_path):
    d, sc = orbit
    one = _write(tmp_path / "one", [cv2.imread(str(d / "images" / "000.png"), cv2.IMREAD_GRAYSCALE)])
    with pytest.raises(InputError, match="at least 3 images.*got 1 decodable image$"):
        reconstruct(one, sc.camera, tmp_path / "w")
    with pytest.raises(InputError, match="at least 2 images"):
        reconstruct(one, sc.camera, tmp_path / "w2", min_registered=2)


def test_image_size_mismatch_is_an_input_error(orbit, tmp_path):
    _, sc = orbit
    d = _write(tmp_path / "small", [np.zeros((180, 320), np.uint8)] * 3)
    with pytest.raises(InputError, match="320x180 but the camera was calibrated at 640x360"):
        reconstruct(d, sc.camera, tmp_path / "w")


def test_bad_arguments(orbit, tmp_path):
    d, sc = orbit
    with pytest.raises(InputError, match="matching mode"):
        reconstruct(d / "images", sc.camera, tmp_path / "w", matching="vocabtree")
    with pytest.raises(InputError, match="min_registered"):
        reconstruct(d / "images", sc.camera, tmp_path / "w", min_registered=1)
    with pytest.raises(InputError, match="max_features"):
        reconstruct(d / "images", sc.camera, tmp_path / "w", max_features=0)
    used = tmp_path / "used"
    (used / "sparse").mkdir(parents=True)
    with pytest.raises(InputError, match="already holds sparse"):
        reconstruct(d / "images", sc.camera, used)


def test_too_few_registered_is_an_estimation_error(orbit, tmp_path):
    """Three overlapping frames and three unrelated textures: three frames register."""
    d, sc = orbit
    rng = np.random.default_rng(0)
    imgs = [cv2.imread(str(d / "images" / f"{i:03d}.png"), cv2.IMREAD_GRAYSCALE) for i in (4, 5, 6)]
    for _ in range(3):
        noise = cv2.GaussianBlur(rng.uniform(0, 255, (SIZE[1], SIZE[0])).astype(np.uint8), (0, 0), 2.0)
        imgs.append(cv2.normalize(noise, None, 0, 255, cv2.NORM_MINMAX))
    mixed = _write(tmp_path / "mixed", imgs)
    with pytest.raises(EstimationError, match=r"only \d of 6 frames registered") as e:
        reconstruct(mixed, sc.camera, tmp_path / "w", max_features=1024, min_registered=5)
    assert "\n" not in str(e.value)


# ----------------------------------------------------------------------------- frame staging
def test_prepare_names_follow_frame_order_for_sequential(orbit, tmp_path):
    """COLMAP's sequential matcher pairs images in byte order of their names: img2 < img10
    in frame order but not in bytes, so the frames are linked under index-prefixed names."""
    d, sc = orbit
    imgs = [cv2.imread(str(d / "images" / f"{i:03d}.png"), cv2.IMREAD_GRAYSCALE) for i in range(3)]
    src = _write(tmp_path / "odd", imgs, ["img1.png", "img2.png", "img10.png"])
    items, image_path, names, mode, staged = prepare_frames(src, sc.camera, tmp_path / "w", "sequential", 2, None)
    assert mode == "sequential" and staged
    assert [x.name for x in items] == ["img1.png", "img2.png", "img10.png"]
    assert names == sorted(names) == ["000000_img1.png", "000001_img2.png", "000002_img10.png"]
    assert image_path == str(tmp_path / "w" / "images")
    assert all((tmp_path / "w" / "images" / n).resolve() == (src / x.name).resolve() for n, x in zip(names, items))
    # exhaustive matching does not care about order: read in place
    items, image_path, names, _, staged = prepare_frames(src, sc.camera, tmp_path / "w2", "exhaustive", 2, None)
    assert image_path == str(src.resolve()) and names == ["img1.png", "img2.png", "img10.png"] and not staged


def test_prepare_arrays_and_broken_frames(orbit, tmp_path):
    d, sc = orbit
    img = cv2.imread(str(d / "images" / "000.png"), cv2.IMREAD_GRAYSCALE)
    items, image_path, names, mode, staged = prepare_frames([img, img, img], sc.camera, tmp_path / "w", "auto", 3, None)
    assert names == ["000000.png", "000001.png", "000002.png"] and mode == "exhaustive" and staged
    assert all(cv2.imread(str(tmp_path / "w" / "images" / n), cv2.IMREAD_GRAYSCALE).tobytes() == img.tobytes()
               for n in names)
    src = _write(tmp_path / "broken", [img, img, img])
    (src / "003.png").write_bytes(b"\x89PNG\r\n\x1a\n broken")
    items, _, names, _, staged = prepare_frames(src, sc.camera, tmp_path / "w3", "auto", 3, None)
    assert not staged
    assert [x.error is None for x in items] == [True, True, True, False]
    assert names == ["000.png", "001.png", "002.png"]
    # never stage into a folder that exists already (it could hold the input)
    (tmp_path / "w4" / "images").mkdir(parents=True)
    with pytest.raises(InputError, match="exists"):
        prepare_frames([img, img, img], sc.camera, tmp_path / "w4", "auto", 3, None)


def test_matching_choice_and_pair_count():
    assert choose_matching("auto", EXHAUSTIVE_MAX_IMAGES) == "exhaustive"
    assert choose_matching("auto", EXHAUSTIVE_MAX_IMAGES + 1) == "sequential"
    assert choose_matching("sequential", 3) == "sequential"
    with pytest.raises(InputError):
        choose_matching("spatial", 3)
    assert sequential_pair_count(5, 10) == 10
    assert sequential_pair_count(30, 10) == sum(min(10, 29 - i) for i in range(30))
    assert sequential_pair_count(3, 10, 30) == 30
    assert sequential_pair_count(28, 10, 30) + 1 == sequential_pair_count(30, 10)


def _follow(tracker, log, lines):
    """Feed `lines` to a glog-like file one by one (each in two halves) while
    `tracker` follows it; the progress values it reported."""
    import threading
    import time

    tracker.poll_s = 0.005
    seen = []
    done = threading.Event()

    def progress(stage, n, total):
        seen.append((stage, n, total))
        done.set()

    tracker.progress = progress
    with tracker:
        time.sleep(0.03)  # no file yet: nothing to report
        with open(log, "wb", buffering=0) as f:
            for line in lines:
                done.clear()
                f.write(line[: len(line) // 2])
                time.sleep(0.02)  # a half-written line is not read
                f.write(line[len(line) // 2:])
                if b"] Process" in line:  # a progress line: wait until it is reported
                    done.wait(5.0)
    return seen


def test_extraction_progress_follows_colmaps_log(tmp_path):
    """Progress comes from COLMAP's log, never from its database (a second SQLite in the
    process breaks COLMAP's locks on its memory-mapped WAL index: a bus error, seen in CI)."""
    base = tmp_path / "colmap.log."
    lines = [b"I20261201 00:00:00.1 1 sift.cc:764] Creating SIFT CPU feature extractor\n"]
    lines += [f"I20261201 00:00:00.2 1 feature_extraction.cc:270] Processed file [{k}/4]\n".encode() for k in (1, 2, 3)]
    seen = _follow(extract_progress(base, 4, None), tmp_path / "colmap.log.20261201-000000.1", lines)
    assert seen[0] == ("extract", 0, 4) and seen[-1] == ("extract", 4, 4)
    assert [n for _, n, _ in seen[1:-1]] == [1, 2, 3]
    assert "sqlite3" not in vars(progress_module) and "sqlite3" not in vars(pipeline_module)


def test_matching_progress_in_pairs(tmp_path):
    base = tmp_path / "colmap.log."
    seq = [f"I 1 pairing.cc:562] Processing image [{k}/30]\n".encode() for k in range(1, 31)]
    seen = _follow(match_progress(base, "sequential", 30, None), tmp_path / "colmap.log.x", seq)
    total = sequential_pair_count(30, 10)
    assert [n for _, n, _ in seen] == [0] + [sequential_pair_count(k, 10, 30) for k in range(1, 30)] + [total]
    assert {t for _, _, t in seen} == {total}

    blocks = [f"I 1 pairing.cc:214] Processing block [{a}/3, {b}/3]\n".encode() for a in (1, 2, 3) for b in (1, 2, 3)]
    seen = _follow(match_progress(base, "exhaustive", 120, None), tmp_path / "colmap.log.y", blocks)
    total = 120 * 119 // 2
    assert [n for _, n, _ in seen] == [0] + [total * k // 9 for k in range(1, 9)] + [total]
