"""The hard hand-held video (`bench_video.hard_handheld_frames`): seeded, and as hard as promised."""
from __future__ import annotations

import json

import numpy as np

from pencilcal.validation.bench_video import hard_handheld_frames


def test_hard_video_is_seeded_frame_by_frame():
    # a frame rendered alone is the same frame as in the whole video (the draws of the frames
    # skipped are still made), and another seed is another video
    cam, pencil, full, tilts, info = hard_handheld_frames(3, seed=5, size=(480, 270))
    _, _, one, tilts1, info1 = hard_handheld_frames(3, seed=5, size=(480, 270), only={2})
    assert one[0] is None and np.array_equal(one[2], full[2])
    assert tilts1 == tilts and info1 == info
    other = hard_handheld_frames(3, seed=6, size=(480, 270), only={2})[2][2]
    assert not np.array_equal(other, full[2])
    assert full[2].shape == (270, 480) and full[2].dtype == np.uint8


def test_hard_video_has_what_it_promises():
    # over 120 frames: 2-3x swings, a hand, auto-exposure steps, defocus drift, JPEG 50-75
    _, _, images, tilts, info = hard_handheld_frames(120, seed=1, size=(480, 270), only=set())
    speed = np.array([f["speed"] for f in info])
    gain = np.array([f["exposure"] for f in info])
    blur = np.array([f["blur_px"] for f in info])
    q = np.array([f["jpeg_quality"] for f in info])
    assert all(im is None for im in images) and len(tilts) == 120
    assert np.any((speed >= 2.0) & (speed <= 3.0)) and np.mean(speed > 1.0) < 0.4
    assert sum(f["hand"] is not None for f in info) >= 4
    assert np.ptp(gain) > 0.05 and np.all((blur >= 1.0 - 1e-9) & (blur <= 2.5 + 1e-9)) and np.ptp(blur) > 0.5
    assert np.all((q >= 50) & (q <= 75)) and 150.0 <= info[0]["distance_mm"] <= 400.0
    assert 3.0 <= info[0]["noise"] <= 6.0 and 0.5 <= info[0]["exposure_time"] <= 1.0
    assert 5.0 < min(tilts) and max(tilts) < 65.0


def test_a_known_readout_undoes_the_rolling_shutter(tmp_path):
    # three frames of a steady turn (seed 1, 53-55): the rows read out over 0.6 of a frame
    # shear the fan by ~2 deg of tilt at a sigma of 0.1-0.2 deg; told the readout, the
    # later frames' edges are moved back by their motion since the previous frame
    import cv2
    from click.testing import CliRunner

    from pencilcal.cli.main import cli
    from pencilcal.toolkit.camera.formats import write_camera
    from pencilcal.toolkit.pencil.spec import write_pencil

    idx = [53, 54, 55]
    cam, pencil, images, tilts, _ = hard_handheld_frames(56, seed=1, only=set(idx))
    frames = tmp_path / "frames"
    frames.mkdir()
    for i in idx:
        cv2.imwrite(str(frames / f"f{i:03d}.png"), images[i])
    write_camera(tmp_path / "camera.json", cam)
    write_pencil(tmp_path / "pencil.yaml", pencil)

    def errors(*extra):
        out = tmp_path / f"o{'_'.join(extra)}.json"
        r = CliRunner().invoke(cli, ["orient", str(frames), "--camera", str(tmp_path / "camera.json"), "--pencil",
                                     str(tmp_path / "pencil.yaml"), "-o", str(out), "--endpoint-sigma", "0.5",
                                     "-q", *extra])
        assert r.exit_code == 0, r.output
        recs = json.loads(out.read_text())["frames"]
        return np.array([abs(f["tilt_deg"] - tilts[i]) for f, i in zip(recs, idx)]), \
            np.array([f["tilt_sigma_deg"] for f in recs])

    e0, s0 = errors("--readout", "0")
    e1, s1 = errors("--readout", "0.6")
    assert np.all(e0[1:] > 1.0) and np.all(e0[1:] > 3 * s0[1:])  # the shear: wrong far beyond the sigmas
    assert np.all(e1[1:] < 0.5) and np.all(e1[1:] < 3 * s1[1:])
    assert e1[0] == e0[0]  # the first frame has no motion to go by
    # told nothing: the same estimates as a global shutter's, the later frames' sigmas
    # widened to cover the shear, the first frame's kept
    e2, s2 = errors()
    assert np.array_equal(e2, e0) and s2[0] == s0[0]
    assert np.all(e2[1:] < 3 * s2[1:]) and np.all(s2[1:] < 5 * e2[1:])


def test_the_scores_count_wrong_frames_by_degrees_and_sigmas():
    from pencilcal.validation.hard_video import score

    recs = [{"ok": True, "tilt_deg": 20.05, "tilt_sigma_deg": 0.1},  # 0.5 sigma: right
            {"ok": True, "tilt_deg": 20.5, "tilt_sigma_deg": 0.1},  # 5 sigma: wrong
            {"ok": True, "tilt_deg": 22.0, "tilt_sigma_deg": 1.0},  # 2 deg off, 2 sigma: wrong
            {"ok": True, "tilt_deg": 19.75, "tilt_sigma_deg": 0.1},  # 2.5 sigma: right
            {"ok": False}]
    s = score(recs, [20.0] * 5)
    assert (s["frames"], s["oriented"], s["right"], s["wrong"]) == (5, 4, 2, 2)
    assert s["wrong_frames"] == [1, 2] and s["beyond_3_sigma"] == 1 and s["over_1_deg"] == 1
    assert s["within_sigma"] == [0.25, 0.5, 0.75] and s["within_0p5_deg"] == 3
    assert abs(s["largest_error_deg"] - 2.0) < 1e-9


def test_the_runner_renders_orients_and_scores_a_short_video(tmp_path, capsys):
    # four small frames of seed 3, rendered once into the videos folder and used again
    from pencilcal.validation.hard_video import main

    args = ["--seeds", "3", "--frames", "4", "--size", "960x540", "--videos", str(tmp_path), "--out",
            str(tmp_path / "rows.json")]
    assert main(args) == 0
    d = tmp_path / "hard3"
    assert all((d / n).exists() for n in ("v.avi", "camera.json", "pencil.yaml", "truth.json"))
    rows = json.loads((tmp_path / "rows.json").read_text())
    assert rows[0]["seed"] == 3 and rows[0]["frames"] == 4
    assert rows[0]["right"] + rows[0]["wrong"] == rows[0]["oriented"]
    assert "seed 3:" in capsys.readouterr().out
    stamp = (d / "v.avi").stat().st_mtime_ns
    assert main(args + ["--readout", "0"]) == 0
    assert (d / "v.avi").stat().st_mtime_ns == stamp
