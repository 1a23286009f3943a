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
           "write_video", "handheld_frames", "hard_handheld_frames", "moving_shaft_frames"]

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


def write_video(path, images, fps=30.0, fourcc="mp4v"):
    """Write `images` ((H, W) grey or (H, W, 3) BGR uint8 each) to `path` as a video of `fps`
    frames a second in the `fourcc` codec ("MJPG": motion JPEG, as a webcam stores it)."""
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
        write_video(d / "sweep.mp4", _ping_pong(images, frames))
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
        write_video(d / "pivot.mp4", _ping_pong(images, frames))
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
            write_video(video, images, fourcc="MJPG")
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
        write_video(video, images, fourcc="MJPG")
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



def _plane_map(camera, R_to, t_to, R_from, t_from, step=16):
    """(map_x, map_y), (H, W) float32 each: for every pixel of the image at pose `to`, where
    the point of the target plane (z = 0) seen there was in the image at pose `from`
    [pixels] (-1e4 where the ray misses the plane); computed on a grid of `step` px and
    interpolated (the field is smooth). Poses R_cam_from_target (3, 3), t (3,) [mm]."""
    import cv2

    W, H = camera.width, camera.height
    gx, gy = np.meshgrid(np.arange(0, W + step, step, dtype=float), np.arange(0, H + step, step, dtype=float))
    ray = camera.rays_from_pixels(np.stack([gx, gy], -1).reshape(-1, 2))
    # the ray's point l * ray on the plane z_target = 0 at pose `to`: (R^T (l ray - t))_z = 0
    lam = (R_to[:, 2] @ t_to) / (ray @ R_to[:, 2])
    X_target = (lam[:, None] * ray - t_to) @ R_to
    src = camera.project(X_target @ R_from.T + t_from)
    bad = ~np.all(np.isfinite(src), -1) | (lam <= 0)
    src = np.where(bad[:, None], -1e4, src).astype(np.float32).reshape(gy.shape + (2,))
    ux, uy = np.meshgrid(np.arange(W, dtype=np.float32) / step, np.arange(H, dtype=np.float32) / step)
    up = cv2.remap(src, ux, uy, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return up[..., 0].copy(), up[..., 1].copy()


def hard_handheld_frames(frames, seed=0, size=(1920, 1080), quality=None, readout=0.6, exposure_time=None, only=None):
    """(camera, pencil, images, tilts, info): `frames` frames of the printed fan seen by a
    hand-held camera as a phone or webcam films it, harder than `handheld_frames` in every
    way the world is: the fan 150-400 mm away and tilted 10-60 deg (drawn per seed), a
    textured table with boxes around it, occasional fast swings (the hand's path run 2-3x
    as fast for 4-8 frames), motion blur over each row's exposure (1/60-1/30 s) and a
    rolling shutter (rows read out over 0.6 of a frame), the exposure stepping by up to
    +-35 % (auto exposure) every 15-40 frames, defocus drifting between 1 and 2.5 px,
    sensor noise 3-6 grey levels, each frame JPEG-compressed at quality 50-75, and now and
    then a hand (a dark blob) over part of the fan for 4-8 frames. Lens k1 -0.2, 30 fps.

    The truth of a frame is the pose at the middle of the exposure of the row through the
    fan's vertex (the rows above and below it were exposed earlier and later: a rolling
    shutter bends the fan itself). Seeded: a seed gives the same video.

    `readout`: the rows' readout over the frame interval (0: a global shutter);
    `exposure_time`: over the frame interval (default drawn in 0.5-1); `only`: the frame
    indices to render (the others None; the same video otherwise).

    Returns the camera, the pencil, the images ((H, W) uint8 each), the true tilt of each
    frame [deg], and `info`: per frame dicts (speed, exposure, blur_px, hand, jpeg quality).
    """
    import cv2

    from pencilcal.toolkit.camera.model import Camera
    from pencilcal.toolkit.synth.render import render_frame, render_scene
    from pencilcal.toolkit.synth.scenarios import default_camera, make_scenario

    rng = np.random.default_rng([int(seed), 2406])
    c = default_camera("opencv", size)
    cam = Camera("opencv", c.width, c.height, c.K, [-0.2, 0.05, 0.0, 0.0, 0.0])
    W, H = cam.width, cam.height
    dist = float(rng.uniform(150.0, 400.0))
    tilt0 = float(rng.uniform(20.0, 50.0))  # the hand's tilt channel swings it ~ +-10 deg
    noise = float(rng.uniform(3.0, 6.0))
    expo = float(rng.uniform(0.5, 1.0))  # exposure time over the frame interval (1/60-1/30 s at 30 fps)
    expo = expo if exposure_time is None else float(exposure_time)
    # the hand's speed along its path: 1, with 2-3x swings of 4-8 frames every 20-45 frames
    speed = np.ones(frames + 2)
    k = int(rng.integers(8, 25))
    while k < frames:
        n = int(rng.integers(4, 9))
        speed[k:k + n] = rng.uniform(2.0, 3.0)
        k += n + int(rng.integers(20, 46))
    s_at = np.concatenate([[0.0], np.cumsum(speed)])  # path position at the start of each frame
    fine = 16  # poses per unit of path: the exposure is sampled between them
    # (the hand's channels take their peak rates over the whole path: never a short one)
    sc = make_scenario("handheld", frames=int(np.ceil(max(s_at[frames + 1], 120.0) * fine)) + 2, seed=seed, camera=cam,
                       distance=dist, tilt_deg=tilt0, speed=1.0 / fine)

    def pose(tau):
        """The pose at time tau [frames] (the path position interpolated from the fine grid)."""
        i = int(np.floor(tau))
        s = s_at[i] + (tau - i) * speed[i]
        f = sc.frames[min(int(round(s * fine)), len(sc.frames) - 1)]
        return f, np.asarray(f["R_cam_from_target"]), np.asarray(f["t_cam_from_target"])

    # auto exposure: steps of up to +-35 % every 15-40 frames, each settling over 3 frames
    gain = np.ones(frames)
    level, k = 1.0, int(rng.integers(15, 41))
    target = np.ones(frames)
    while k < frames:
        level = float(np.clip(level * rng.uniform(0.65, 1.35), 0.6, 1.5))
        target[k:] = level
        k += int(rng.integers(15, 41))
    g = 1.0
    for i in range(frames):
        g += 0.5 * (target[i] - g)
        gain[i] = g
    blur = 1.75 + 0.75 * np.sin(2 * np.pi * np.arange(frames) / rng.uniform(40, 90) + rng.uniform(0, 2 * np.pi))
    # hands: episodes of 4-8 frames, a dark ellipse entering from a side over the fan
    hand = np.zeros(frames, bool)
    k = int(rng.integers(10, 40))
    while k < frames:
        hand[k:k + int(rng.integers(4, 9))] = True
        k += int(rng.integers(30, 60))
    quality = [int(rng.integers(50, 76)) for _ in range(frames)] if quality is None else [int(quality)] * frames
    nsub = 8
    images, tilts, info = [], [], []
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float32)
    for i in range(frames):
        f0, _, _ = pose(i)
        vy = float(np.clip(f0["vertex_px"][1], 0, H - 1))
        t_ref = i + readout * vy / H + expo / 2  # the vertex row's mid exposure
        fr, R0, t0 = pose(t_ref)
        hand_box = None
        if hand[i]:
            # a hand over part of the fan: an ellipse around one spoke's end, dark skin
            sp = np.asarray(fr["spokes_px"], float).reshape(-1, 2)
            sp = sp[np.all(np.isfinite(sp), -1)]
            cx, cy = sp[rng.integers(len(sp))] if len(sp) else (W / 2, H / 2)
            hand_box = [float(cx), float(cy), rng.uniform(0.06, 0.12) * W, rng.uniform(0.05, 0.09) * W,
                        rng.uniform(0, np.pi)]  # centre, half axes [px], angle [rad]
        tilts.append(float(fr["tilt_deg"]))
        info.append({"speed": float(speed[i]), "exposure": float(gain[i]), "blur_px": float(blur[i]),
                     "hand": hand_box, "jpeg_quality": quality[i], "distance_mm": dist, "noise": noise,
                     "exposure_time": expo})
        if only is not None and i not in only:
            images.append(None)
            continue
        scene = render_scene(cam, R0, t0, sc.sheet, background=sc.backdrop)[..., 0].astype(np.float32)
        acc = np.zeros((H, W), np.float32)
        w_row = (np.arange(H, dtype=np.float32) / (H - 1))[:, None]
        for j in range(nsub):
            # row y exposed over [i + readout y / (H - 1), + expo]: the maps at the first and
            # the last row, interpolated between (the pose changes smoothly over a frame)
            u = expo * (j + 0.5) / nsub
            (ax, ay), (bx, by) = (_plane_map(cam, *pose(i + u + readout * r)[1:], R0, t0) for r in (0.0, 1.0))
            mx, my = ax + (bx - ax) * w_row, ay + (by - ay) * w_row
            acc += cv2.remap(scene, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
        lin = acc / nsub
        if hand_box is not None:
            cx, cy, ax_, ay_, ang = hand_box
            dx, dy = xx - cx, yy - cy
            r2 = ((dx * np.cos(ang) + dy * np.sin(ang)) / ax_) ** 2 + ((-dx * np.sin(ang) + dy * np.cos(ang)) / ay_) ** 2
            m = cv2.GaussianBlur(np.clip(1.5 - r2, 0, 1).astype(np.float32), (0, 0), 6)
            lin = lin * (1 - m) + 0.06 * m
        rs = np.random.default_rng([int(seed), 2407, i])
        img = render_frame(cam, R0, t0, sc.sheet, scene=lin[..., None].astype(np.float64), noise=noise,
                           blur_px=float(blur[i]), lighting=0.25, gamma=2.2, exposure=float(gain[i]), rng=rs)
        ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, quality[i]])
        images.append(cv2.imdecode(buf, cv2.IMREAD_GRAYSCALE))
    return cam, sc.sheet.pencil, images, tilts, info
