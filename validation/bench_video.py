"""Benchmarks on video: a whole `pencilcal` process against the floor of decoding the same
video and running OpenCV's FLD on every frame.

- ``orient_video_vs_decode_fld_1080p``: the wall time of ``pencilcal orient VIDEO`` (a
  separate process: start-up and imports, the valid region, every frame, the output file)
  over decoding the same 1920x1080 video with cv2.VideoCapture plus
  cv2.ximgproc FastLineDetector on every frame, in this process (best of `repeats`).
  Target <= 1.5. The video is a tilt sweep rendered over a few degrees (8 frames played
  forwards and back), as a hand-held target moves between frames at 30 fps.
- ``shafts_video_vs_decode_fld_1080p``: the same for ``pencilcal fulcrum VIDEO`` (instrument
  shafts in every frame, the fulcrum at the end) on a rendered 1080p pivot sequence.
  Target <= 2.0.

Beside each ratio: the process's seconds, the floor's, and from the --jsonl stream of the
orient process its start-up (until the first frame's record) and its per-frame time after
that (``orient_video_ms_per_frame``), over the floor's per frame
(``orient_video_steady_vs_decode_fld``): how much of the ratio is start-up.
"""
from __future__ import annotations

import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

__all__ = ["bench_orient_video", "bench_shafts_video", "VIDEO_TARGETS"]

VIDEO_TARGETS = {"orient_video_vs_decode_fld_1080p": ("<=", 1.5), "shafts_video_vs_decode_fld_1080p": ("<=", 2.0)}


def _write_video(path, images, fps=30.0):
    import cv2

    h, w = images[0].shape[:2]
    out = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), fps, (w, h))
    for im in images:
        out.write(im if im.ndim == 3 else cv2.cvtColor(im, cv2.COLOR_GRAY2BGR))
    out.release()


def _ping_pong(images, frames):
    """`frames` frames going forwards and back over `images`."""
    cycle = list(images) + list(images[-2:0:-1])
    return [cycle[i % len(cycle)] for i in range(frames)]


def _floor(video, repeats):
    """Seconds to decode `video` and run FLD on every frame (best of `repeats`), frames."""
    import cv2

    fld = cv2.ximgproc.createFastLineDetector()
    best, n = np.inf, 0
    for _ in range(repeats):
        t0 = time.perf_counter()
        cap = cv2.VideoCapture(str(video))
        n = 0
        while True:
            ok, img = cap.read()
            if not ok:
                break
            fld.detect(cv2.cvtColor(img, cv2.COLOR_BGR2GRAY))
            n += 1
        cap.release()
        best = min(best, time.perf_counter() - t0)
    return best, n


def _process(args, repeats):
    """(best wall seconds, start-up seconds to the first jsonl line, per-frame seconds after
    it) of ``python -m pencilcal.cli.main ARGS --jsonl -``."""
    best = (np.inf, np.nan, np.nan)
    for _ in range(repeats):
        t0 = time.perf_counter()
        p = subprocess.Popen([sys.executable, "-m", "pencilcal.cli.main", *args, "--jsonl", "-"],
                             stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
        stamps = [time.perf_counter() - t0 for _ in p.stdout]
        p.wait()
        wall = time.perf_counter() - t0
        if p.returncode != 0:
            raise RuntimeError(f"bench: `pencilcal {' '.join(args[:2])} ...` failed (exit {p.returncode})")
        if wall < best[0]:
            per = (stamps[-1] - stamps[0]) / (len(stamps) - 1) if len(stamps) > 1 else np.nan
            best = (wall, stamps[0] if stamps else np.nan, per)
    return best


def bench_orient_video(frames=64, repeats=2, seed=0, workdir=None):
    """orient_video_vs_decode_fld_1080p and its parts (module docstring)."""
    from pencilcal.toolkit.camera.formats import write_camera
    from pencilcal.toolkit.pencil.spec import write_pencil
    from pencilcal.toolkit.synth.scenarios import make_scenario

    sc = make_scenario("tilt-sweep", frames=40, seed=seed, size=(1920, 1080))
    images = [sc.render(i) for i in range(12, 20)]  # 30-40 deg, 2 deg a frame
    with tempfile.TemporaryDirectory(dir=workdir) as tmp:
        d = Path(tmp)
        _write_video(d / "sweep.mp4", _ping_pong(images, frames))
        write_camera(d / "camera.json", sc.camera)
        write_pencil(d / "pencil.yaml", sc.sheet.pencil)
        args = ["orient", str(d / "sweep.mp4"), "--camera", str(d / "camera.json"), "--pencil",
                str(d / "pencil.yaml"), "-o", str(d / "o.json"), "--force", "-q"]
        wall, startup, per = _process(args, repeats)
        floor, n = _floor(d / "sweep.mp4", repeats)
        import json

        data = json.loads((d / "o.json").read_text())
    ok = sum(f["ok"] for f in data["frames"])
    return {"orient_video_vs_decode_fld_1080p": float(wall / floor), "orient_video_s": float(wall),
            "decode_fld_video_s": float(floor), "orient_video_frames": n,
            "orient_video_startup_s": float(startup), "orient_video_ms_per_frame": float(per * 1e3),
            "orient_video_steady_vs_decode_fld": float(per / (floor / n)),
            "orient_video_frames_ok": f"{ok}/{len(data['frames'])}",
            "orient_video_frames_tracked": f"{data.get('frames_tracked', 0)}/{len(data['frames'])}",
            "orient_video_bars_tracked": f"{data.get('bars_tracked', 0)}/{len(data['frames'])}"}


def bench_shafts_video(frames=48, repeats=2, seed=0, workdir=None):
    """shafts_video_vs_decode_fld_1080p and its parts (module docstring)."""
    from pencilcal.toolkit.camera.formats import write_camera
    from pencilcal.toolkit.synth.scenarios import make_scenario

    sc = make_scenario("pivot", frames=8, seed=seed, size=(1920, 1080))
    images = [sc.render(i) for i in range(8)]
    with tempfile.TemporaryDirectory(dir=workdir) as tmp:
        d = Path(tmp)
        _write_video(d / "pivot.mp4", _ping_pong(images, frames))
        write_camera(d / "camera.json", sc.camera)
        args = ["fulcrum", str(d / "pivot.mp4"), "--camera", str(d / "camera.json"), "-o", str(d / "f.json"),
                "--force", "-q"]
        t = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            r = subprocess.run([sys.executable, "-m", "pencilcal.cli.main", *args], capture_output=True)
            t.append(time.perf_counter() - t0)
            if r.returncode != 0:
                raise RuntimeError(f"bench: `pencilcal fulcrum` failed: {r.stderr.decode(errors='replace')[-200:]}")
        floor, n = _floor(d / "pivot.mp4", repeats)
    return {"shafts_video_vs_decode_fld_1080p": float(min(t) / floor), "shafts_video_s": float(min(t)),
            "shafts_decode_fld_video_s": float(floor), "shafts_video_frames": n}
