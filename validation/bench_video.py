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
  Target <= 2.0. ``shafts_video_point_vs_decode_fld_1080p``: the same process with
  ``--shaft-diameter`` (every shaft's 3-D axis, the 3-D fulcrum and its jackknife over
  frames, one 3-D point per frame left out, on top; ``shafts_video_point_found`` says
  whether it found the point), no target.

Beside each ratio: the process's seconds, the floor's, and from the --jsonl stream of the
orient process its start-up (until the first frame's record) and its per-frame time after
that (``orient_video_ms_per_frame``), over the floor's per frame
(``orient_video_steady_vs_decode_fld``): how much of the ratio is start-up.

On a moving camera (`bench_orient_motion`, `bench_shafts_motion`), both sides whole
processes (the floor a Python process that imports OpenCV, decodes the video and runs FLD
on every frame), best of `repeats`:

- ``orient_motion_vs_decode_fld_1080p``, ``orient_motion_overlay_vs_decode_fld_1080p``: a
  1920x1080 MJPEG video of the printed fan seen by a hand-held camera (the ``handheld``
  scenario: the fan's centre up to 8 px a frame, its in-plane angle 3 deg and its tilt 1 deg
  a frame, lens k1 -0.2, a plain backdrop, blur 1 px), ``orient VIDEO`` without and with
  ``--overlay OUT.mp4`` (and ``--jsonl``; the overlay at its default half size, and at full
  size, ``--overlay-scale 1``, in ``orient_motion_overlay_full_*``). Targets <= 1.5 with
  the overlay; beside them the fraction of frames whose bars were tracked
  (``orient_motion_tracked``, target >= 0.9) and of frames with the tilt within 0.5 deg of
  the truth (``orient_motion_tilt_within_0p5``, >= 0.95). Each run's CPU seconds (all its
  threads, least of the runs) over the floor's: ``*_cpu_vs_decode_fld`` (with other jobs on
  the machine, what the run cost rather than how the machine was shared).
- ``orient_motion2x_overlay_vs_decode_fld_1080p``: the same path at twice the speed (every
  other frame of a path twice as long), with the overlay: target <= 2.0 and no frame lost
  (``orient_motion2x_frames_lost``).
- ``shafts_motion_vs_decode_fld_1080p``: ``fulcrum VIDEO`` on a 1920x1080 colour MJPEG video
  of an instrument pivoting back and forth (up to ~3.7 deg a frame) over a textured,
  tissue-like backdrop, seen from near its port (the pivot scenario's ``port_view``): target
  <= 2.0, with the fraction of frames whose shafts were tracked (``shafts_motion_tracked``,
  >= 0.9); ``shafts_motion_lines_vs_decode_fld_1080p``: ``lines VIDEO --shaft --no-segments``
  on the same video (the shafts alone, tracked), target <= 2.0
  (``shafts_motion_lines_tracked``).
"""
from __future__ import annotations

import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

__all__ = ["bench_orient_video", "bench_shafts_video", "bench_orient_motion", "bench_shafts_motion", "VIDEO_TARGETS",
           "handheld_frames", "moving_shaft_frames"]

VIDEO_TARGETS = {"orient_video_vs_decode_fld_1080p": ("<=", 1.5), "shafts_video_vs_decode_fld_1080p": ("<=", 2.0),
                 "orient_motion_overlay_vs_decode_fld_1080p": ("<=", 1.5), "orient_motion_tracked": (">=", 0.9),
                 "orient_motion_tilt_within_0p5": (">=", 0.95),
                 "orient_motion2x_overlay_vs_decode_fld_1080p": ("<=", 2.0), "orient_motion2x_frames_lost": ("<=", 0),
                 "shafts_motion_vs_decode_fld_1080p": ("<=", 2.0), "shafts_motion_tracked": (">=", 0.9),
                 "shafts_motion_lines_vs_decode_fld_1080p": ("<=", 2.0), "shafts_motion_lines_tracked": (">=", 0.9)}

# decoding a video and FLD on every frame, as a process of its own (the floor of the motion
# benchmarks: both sides pay a Python process's start-up)
_FLOOR = """import sys, cv2
fld = cv2.ximgproc.createFastLineDetector()
cap = cv2.VideoCapture(sys.argv[1])
while True:
    ok, img = cap.read()
    if not ok:
        break
    fld.detect(cv2.cvtColor(img, cv2.COLOR_BGR2GRAY))
"""


def _write_video(path, images, fps=30.0, fourcc="mp4v"):
    import cv2

    h, w = images[0].shape[:2]
    out = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*fourcc), fps, (w, h))
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


def _children_cpu():
    """CPU seconds (user + system) of this process's finished children so far."""
    import resource

    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def _process(args, repeats, cpu=None):
    """(best wall seconds, start-up seconds to the first jsonl line, per-frame seconds after
    it) of ``python -m pencilcal.cli.main ARGS --jsonl -``; the least CPU seconds of the
    runs (all its threads: with other jobs on the machine the wall time says how the
    machine was shared, the CPU time what the run cost) appended to `cpu` when given."""
    best, least = (np.inf, np.nan, np.nan), np.inf
    for _ in range(repeats):
        c0, t0 = _children_cpu(), time.perf_counter()
        p = subprocess.Popen([sys.executable, "-m", "pencilcal.cli.main", *args, "--jsonl", "-"],
                             stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
        stamps = [time.perf_counter() - t0 for _ in p.stdout]
        p.wait()
        wall = time.perf_counter() - t0
        least = min(least, _children_cpu() - c0)
        if p.returncode != 0:
            raise RuntimeError(f"bench: `pencilcal {' '.join(args[:2])} ...` failed (exit {p.returncode})")
        if wall < best[0]:
            per = (stamps[-1] - stamps[0]) / (len(stamps) - 1) if len(stamps) > 1 else np.nan
            best = (wall, stamps[0] if stamps else np.nan, per)
    if cpu is not None:
        cpu.append(least)
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
        t = _process_wall(args, repeats)
        # the same with the shafts' diameter: every shaft's 3-D axis, the 3-D fulcrum and its
        # jackknife over frames (one 3-D point per frame left out) on top
        t_point = _process_wall(args + ["--shaft-diameter", str(sc.options["shaft_diameter"])], repeats)
        import json

        has_point = json.loads((d / "f.json").read_text()).get("point") is not None
        floor, n = _floor(d / "pivot.mp4", repeats)
    return {"shafts_video_vs_decode_fld_1080p": float(t / floor), "shafts_video_s": float(t),
            "shafts_decode_fld_video_s": float(floor), "shafts_video_frames": n,
            "shafts_video_point_vs_decode_fld_1080p": float(t_point / floor), "shafts_video_point_s": float(t_point),
            "shafts_video_point_found": bool(has_point)}


def _process_wall(args, repeats):
    """Best wall seconds of a `pencilcal` process with `args` over `repeats` runs."""
    t = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        r = subprocess.run([sys.executable, "-m", "pencilcal.cli.main", *args], capture_output=True)
        t.append(time.perf_counter() - t0)
        if r.returncode != 0:
            raise RuntimeError(f"bench: `pencilcal {args[0]}` failed: {r.stderr.decode(errors='replace')[-200:]}")
    return min(t)


def _floor_process(video, repeats, cpu=None):
    """Best wall seconds of a process decoding `video` with FLD on every frame (`_FLOOR`);
    its least CPU seconds appended to `cpu` when given."""
    best, least = np.inf, np.inf
    for _ in range(repeats):
        c0, t0 = _children_cpu(), time.perf_counter()
        r = subprocess.run([sys.executable, "-c", _FLOOR, str(video)], capture_output=True)
        best = min(best, time.perf_counter() - t0)
        least = min(least, _children_cpu() - c0)
        if r.returncode != 0:
            raise RuntimeError(f"bench: the decode + FLD floor failed: {r.stderr.decode(errors='replace')[-200:]}")
    if cpu is not None:
        cpu.append(least)
    return best


def handheld_frames(frames, seed=0, size=(1920, 1080)):
    """(camera, pencil, images, tilts, images2x, tilts2x): `frames` frames of the printed fan
    seen by a hand-held camera (module docstring), and as many of the same path at twice the
    speed (every other frame of a path twice as long); the true tilt of each [deg]."""
    from pencilcal.toolkit.camera.model import Camera
    from pencilcal.toolkit.synth.scenarios import default_camera, make_scenario

    c = default_camera("opencv", size)
    cam = Camera("opencv", c.width, c.height, c.K, [-0.2, 0.05, 0.0, 0.0, 0.0])
    sc = make_scenario("handheld", frames=2 * frames, seed=seed, camera=cam, distance=250.0)
    want = sorted(set(range(frames)) | set(range(0, 2 * frames, 2)))
    img = {i: sc.render(i, background="plain", blur_px=1.0) for i in want}
    tilt = [f["tilt_deg"] for f in sc.frames]
    slow, fast = list(range(frames)), list(range(0, 2 * frames, 2))
    return (cam, sc.sheet.pencil, [img[i] for i in slow], [tilt[i] for i in slow], [img[i] for i in fast],
            [tilt[i] for i in fast])


def _orient_run(d, video, overlay, repeats, cpu):
    """(best wall seconds, start-up, seconds a frame, orientation.json) of ``orient VIDEO``
    (with ``--overlay``, at its default size, when `overlay` is True; at full size when it
    is "full"); its CPU seconds appended to `cpu`."""
    import json

    args = ["orient", str(video), "--camera", str(d / "camera.json"), "--pencil", str(d / "pencil.yaml"), "-o",
            str(d / "o.json"), "--force", "-q"] + (["--overlay", str(d / "overlay.mp4")] if overlay else []) \
        + (["--overlay-scale", "1"] if overlay == "full" else [])
    wall, startup, per = _process(args, repeats, cpu)
    return wall, startup, per, json.loads((d / "o.json").read_text())


def _motion_figures(prefix, data, tilts):
    """Tracked, within-0.5-deg and lost frames of an orientation.json against the truth."""
    fr = data["frames"]
    ok = [f["ok"] for f in fr]
    err = np.array([abs(f["tilt_deg"] - t) if f["ok"] else np.inf for f, t in zip(fr, tilts)])
    return {f"{prefix}_frames": len(fr), f"{prefix}_tracked": data.get("bars_tracked", 0) / len(fr),
            f"{prefix}_tilt_within_0p5": float(np.mean(err <= 0.5)), f"{prefix}_frames_lost": len(fr) - sum(ok)}


def bench_orient_motion(frames=120, repeats=2, seed=0, workdir=None):
    """orient_motion_* and orient_motion2x_* (module docstring)."""
    from pencilcal.toolkit.camera.formats import write_camera
    from pencilcal.toolkit.pencil.spec import write_pencil

    cam, pencil, slow, tilt, fast, tilt2 = handheld_frames(frames, seed)
    out = {}
    with tempfile.TemporaryDirectory(dir=workdir) as tmp:
        d = Path(tmp)
        write_camera(d / "camera.json", cam)
        write_pencil(d / "pencil.yaml", pencil)
        for name, images, truth, runs in (("orient_motion", slow, tilt, (False, "full", True)),
                                          ("orient_motion2x", fast, tilt2, (True,))):
            video = d / f"{name}.avi"
            _write_video(video, images, fourcc="MJPG")
            cpu = []
            floor = _floor_process(video, repeats, cpu)
            out[f"{name}_decode_fld_s"] = float(floor)
            for overlay in runs:
                key = name + {False: "", True: "_overlay", "full": "_overlay_full"}[overlay]
                wall, startup, per, data = _orient_run(d, video, overlay, repeats, cpu)
                out.update({f"{key}_vs_decode_fld_1080p": float(wall / floor), f"{key}_s": float(wall),
                            f"{key}_cpu_vs_decode_fld": float(cpu[-1] / cpu[0]),
                            f"{key}_startup_s": float(startup), f"{key}_ms_per_frame": float(per * 1e3)})
            out.update(_motion_figures(name, data, truth))
    return out


def moving_shaft_frames(frames, seed=0, size=(1920, 1080), period=60):
    """(camera, images): `frames` colour frames of an instrument pivoting back and forth (its
    angle 90 +- 35 deg, a sine of `period` frames) seen from near its port, over the table's
    textured backdrop only (the fulcrum below the printed sheet, out of view)."""
    from pencilcal.toolkit.synth.render import render_scene
    from pencilcal.toolkit.synth.scenarios import make_scenario

    fine = max(8 * frames, 720)  # the pivot angles fine enough that the sine stays smooth
    sc = make_scenario("pivot", frames=fine, seed=seed, size=size, fulcrum=(40.0, 320.0), port_view=150.0,
                       height=40.0, tilt_deg=30.0, angle_range_deg=(55.0, 125.0))
    f0 = sc.frames[0]
    scene = render_scene(sc.camera, f0["R_cam_from_target"], f0["t_cam_from_target"], sc.sheet,
                         background=sc.backdrop, color=True)
    t = np.arange(frames)
    idx = np.round((fine - 1) * (0.5 + 0.5 * np.sin(2 * np.pi * t / period))).astype(int)
    img = {i: sc.render(int(i), color=True, scene=scene, blur_px=1.0) for i in np.unique(idx)}
    return sc.camera, [img[i] for i in idx]


def bench_shafts_motion(frames=90, repeats=2, seed=0, workdir=None):
    """shafts_motion_* (module docstring)."""
    import json

    from pencilcal.toolkit.camera.formats import write_camera

    cam, images = moving_shaft_frames(frames, seed)
    with tempfile.TemporaryDirectory(dir=workdir) as tmp:
        d = Path(tmp)
        video = d / "instrument.avi"
        _write_video(video, images, fourcc="MJPG")
        write_camera(d / "camera.json", cam)
        args = ["fulcrum", str(video), "--camera", str(d / "camera.json"), "-o", str(d / "f.json"), "--force", "-q"]
        wall, startup, per = _process(args, repeats)
        lines_args = ["lines", str(video), "--camera", str(d / "camera.json"), "--shaft", "--no-segments",
                      "-o", str(d / "l.json"), "--force", "-q"]
        lines_wall = _process(lines_args, repeats)[0]
        floor = _floor_process(video, repeats)
        data = json.loads((d / "f.json").read_text())
        lines_data = json.loads((d / "l.json").read_text())
    n = len(images)
    return {"shafts_motion_vs_decode_fld_1080p": float(wall / floor), "shafts_motion_s": float(wall),
            "shafts_motion_decode_fld_s": float(floor), "shafts_motion_frames": n,
            "shafts_motion_tracked": data.get("frames_tracked", 0) / n, "shafts_motion_startup_s": float(startup),
            "shafts_motion_lines_vs_decode_fld_1080p": float(lines_wall / floor),
            "shafts_motion_lines_s": float(lines_wall),
            "shafts_motion_lines_tracked": lines_data.get("frames_tracked", 0) / n}
