"""Benchmarks: pencilcal side by side with the bare OpenCV and pycolmap calls, in one process.

Every figure is a ratio measured here and now on the same inputs, never an absolute number
from somewhere else, so it means the same on a laptop and on a 2-core CI machine:

- ``orient_vs_fld_1080p``: image to orientation (decode, spoke detection with FLD, refit,
  vertex, labels, fit) per 1920x1080 frame, over decoding and FLD detection alone on the
  same frames, as `pencilcal orient IMAGES` does it by default (at 1080p the detector runs
  on the half-resolution frame, `detect_bars`' proposal_scale). Lower is better; target
  <= 1.3. ``orient_full_proposals_vs_fld_1080p``: the same with the detector on the
  full-resolution frame (proposal_scale 1), for comparison.
- ``shafts_vs_fld_1080p``: decoding plus instrument-shaft detection (`detect_shafts` with
  the frame set's valid region, detected once beforehand as `pencilcal fulcrum IMAGES`
  does) over decoding plus FLD, per 1920x1080 frame: the 1080p frames of the shared
  laparoscopy set (``../shared/data/real-instruments/laparoscopy-hysterectomy-frames``, or
  under $PENCILCAL_DATA) when present, else rendered 1080p pivot frames (grey, so the edge
  cue); ``shafts_frames`` says which. Target <= 2.0.
- ``pnp_vs_opencv``: `pencilcal pnp`'s work per frame (decode, ChArUco detection, SQPnP with
  LM refinement and covariance) over decoding, CharucoDetector and cv2.solvePnP (SQPNP).
  Target <= 1.1.
- ``sfm_vs_pycolmap``: `pencilcal sfm`'s reconstruction over the bare pycolmap calls
  (extract, match, map) on the same images. Target <= 1.05.
- ``batch_speedup`` (higher is better): batched fits per second over a Python loop of
  single numpy fits; ``fits_per_minute_batched``.
- ``crlb_ratio_tilt20``: Monte Carlo RMSE of the tilt over its Cramer-Rao bound at 20 deg
  of tilt, 8 lines 20 deg apart, 0.1 deg noise (target 0.9-1.1: the estimator is efficient).
- ``single_fit_ms``: one pencil fit (numpy estimator), for latency.

- ``orient_video_vs_decode_fld_1080p``, ``shafts_video_vs_decode_fld_1080p``: a whole
  ``pencilcal orient`` / ``pencilcal fulcrum`` process on a 1080p video over decoding it and
  FLD on every frame (`bench_video`). Targets <= 1.5 and <= 2.0.
- ``shafts_video_point_vs_decode_fld_1080p``: the same ``fulcrum`` process with
  ``--shaft-diameter`` (the 3-D point and its jackknife too), no target.
- ``calibrate_vs_opencv_960x540``: `pencilcal calibrate`'s work (calibration, two halves,
  uncertainty map, verdict) on 50 rendered 960x540 chessboard views over the same decoding
  and detection plus cv2.calibrateCamera (`bench_calibrate`). Target <= 2.0.
- ``orient_motion_*``, ``orient_motion2x_*``, ``shafts_motion_*``: the same on a moving
  camera (a hand-held fan at the speeds of a hand and twice them; a moving instrument over a
  tissue-like texture), both sides whole processes, with the fraction of frames tracked
  (`bench_video`).

Frames are rendered once (toolkit.synth.render, exact truth) and encoded to PNG in memory; both
sides decode them. Each timing is the median over frames of the best of `repeats` runs.
"""
from __future__ import annotations

import time

import numpy as np

__all__ = ["run_bench", "TARGETS", "format_table", "benchmark_batched"]

from pencilcal.validation.bench_calibrate import CALIBRATE_TARGETS, bench_calibrate
from pencilcal.validation.bench_video import (VIDEO_TARGETS, bench_orient_motion, bench_orient_video,
                                              bench_shafts_motion, bench_shafts_video)

TARGETS = {**VIDEO_TARGETS, **CALIBRATE_TARGETS, "orient_vs_fld_1080p": ("<=", 1.3), "shafts_vs_fld_1080p": ("<=", 2.0), "pnp_vs_opencv": ("<=", 1.1), "sfm_vs_pycolmap": ("<=", 1.05),
           "batch_speedup": (">=", 50.0), "fits_per_minute_batched": (">=", 1e6), "crlb_ratio_tilt20": ("in", (0.9, 1.15))}


def _best(fn, repeats):
    best = np.inf
    out = None
    for _ in range(repeats):
        t = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t)
    return best, out


def _encode(images):
    import cv2

    return [cv2.imencode(".png", im)[1] for im in images]


def _decode(buf):
    import cv2

    return cv2.imdecode(buf, cv2.IMREAD_COLOR)


def _frames(scenario, n, size, seed):
    from pencilcal.toolkit.synth.scenarios import make_scenario

    sc = make_scenario(scenario, frames=n, seed=seed, size=size)
    return sc, _encode([sc.render(i) for i in range(n)])


def bench_orient(n=6, repeats=3, seed=0):
    """orient_vs_fld_1080p and per-frame times [ms].

    Frames 2-7 of an 8-frame tilt sweep (0-80 deg: the near-frontal start skipped), or the
    middle `n` of them when n < 6, so that a quick run sees typical tilts, not the grazing
    end where every square of the board beside the fan looks like a bar."""
    import cv2

    from pencilcal.toolkit.detect.lines import lines_record
    from pencilcal.toolkit.pencil.orient import orient_segments
    from pencilcal.toolkit.synth.scenarios import make_scenario

    n = int(np.clip(n, 1, 6))
    sc = make_scenario("tilt-sweep", frames=8, seed=seed, size=(1920, 1080))
    first = 2 + (6 - n) // 2
    bufs = _encode([sc.render(i) for i in range(first, first + n)])
    cam, pencil = sc.camera, sc.sheet.pencil
    fld = cv2.ximgproc.createFastLineDetector()
    t_pc, t_fld, t_full, ok, ok_full = [], [], [], 0, 0

    def ours(buf, scale=None):
        img = _decode(buf)
        rec = lines_record("f", img, cam, "fld", bars=pencil.width is not None, proposal_scale=scale)
        return orient_segments(cam, rec["segments"], pencil, angle_sigma=np.radians(rec["angle_sigma_deg"]),
                               offset_sigma=rec["offset_sigma_px"])

    def bare(buf):
        img = _decode(buf)
        return fld.detect(cv2.cvtColor(img, cv2.COLOR_BGR2GRAY))

    for buf in bufs:
        t, rec = _best(lambda: ours(buf), repeats)
        t_pc.append(t)
        ok += bool(rec.ok)
        t_fld.append(_best(lambda: bare(buf), repeats)[0])
        # the same with the detector on the full-resolution frame (proposal_scale 1)
        t, rec = _best(lambda: ours(buf, 1.0), repeats)
        t_full.append(t)
        ok_full += bool(rec.ok)
    return {"orient_vs_fld_1080p": float(np.median(t_pc) / np.median(t_fld)),
            "orient_ms_1080p": float(np.median(t_pc) * 1e3), "fld_ms_1080p": float(np.median(t_fld) * 1e3),
            "orient_full_proposals_vs_fld_1080p": float(np.median(t_full) / np.median(t_fld)),
            "orient_full_proposals_frames_ok": f"{ok_full}/{len(bufs)}",
            "orient_frames_ok": f"{ok}/{len(bufs)}"}


def _laparoscopy_1080p(n):
    """Up to n encoded 1920x1080 frames of the shared laparoscopy set, or None when it is
    absent (../shared/data beside the checkout, or $PENCILCAL_DATA)."""
    import os
    from pathlib import Path

    root = Path(os.environ.get("PENCILCAL_DATA", Path(__file__).resolve().parents[2] / "shared" / "data"))
    folder = root / "real-instruments" / "laparoscopy-hysterectomy-frames"
    if not folder.is_dir():
        return None
    import cv2

    bufs = []
    for path in sorted(folder.glob("*.jpg")):
        buf = np.fromfile(str(path), np.uint8)
        img = cv2.imdecode(buf, cv2.IMREAD_COLOR)
        if img is not None and img.shape[:2] == (1080, 1920):
            bufs.append(buf)
        if len(bufs) >= n:
            break
    return bufs or None


def bench_shafts(n=16, repeats=3, seed=0):
    """shafts_vs_fld_1080p, per-frame times [ms] and which frames (module docstring)."""
    import cv2

    from pencilcal.toolkit.detect.region.detect import detect_valid_region
    from pencilcal.toolkit.detect.shaft.detector import detect_shafts

    bufs = _laparoscopy_1080p(n)
    if bufs is not None:
        what, camera = f"laparoscopy-hysterectomy-frames ({len(bufs)} real 1920x1080 frames)", None
    else:
        from pencilcal.toolkit.synth.scenarios import make_scenario

        k = int(np.clip(n, 1, 12))
        sc = make_scenario("pivot", frames=k, seed=seed, size=(1920, 1080))
        bufs, camera = _encode([sc.render(i) for i in range(k)]), sc.camera
        what = f"rendered pivot ({k} grey 1920x1080 frames)"
    region = detect_valid_region([_decode(b) for b in bufs])
    fld = cv2.ximgproc.createFastLineDetector()
    t_pc, t_fld, found = [], [], 0

    def ours(buf):
        return detect_shafts(_decode(buf), camera, valid_region=region)

    def bare(buf):
        return fld.detect(cv2.cvtColor(_decode(buf), cv2.COLOR_BGR2GRAY))

    for buf in bufs:
        t, shafts = _best(lambda: ours(buf), repeats)
        t_pc.append(t)
        found += bool(shafts)
        t_fld.append(_best(lambda: bare(buf), repeats)[0])
    return {"shafts_vs_fld_1080p": float(np.median(t_pc) / np.median(t_fld)),
            "shafts_ms_1080p": float(np.median(t_pc) * 1e3), "shafts_fld_ms_1080p": float(np.median(t_fld) * 1e3),
            "shafts_frames": what, "shafts_frames_with_a_shaft": f"{found}/{len(bufs)}"}


def bench_pnp(n=6, repeats=3, seed=0):
    """pnp_vs_opencv and per-frame times [ms]."""
    import cv2

    from pencilcal.toolkit.board.detect import detect_board
    from pencilcal.validation.pnp import estimate_pose

    sc, bufs = _frames("orbit", n, (1280, 720), seed)
    cam, board = sc.camera, sc.sheet.board
    obj = board.object_points()
    det = cv2.aruco.CharucoDetector(board.cv2_board())
    K, dist = np.asarray(cam.K), np.asarray(cam.dist)

    def ours(buf):
        d = detect_board(_decode(buf), board)
        return estimate_pose(obj[d.ids], d.corners, cam, method="sqpnp")

    def bare(buf):
        cc, ci, _, _ = det.detectBoard(cv2.cvtColor(_decode(buf), cv2.COLOR_BGR2GRAY))
        if ci is None or len(ci) < 4:
            return None
        return cv2.solvePnP(obj[ci.ravel()], cc, K, dist, flags=cv2.SOLVEPNP_SQPNP)

    t_pc, t_cv = [], []
    for buf in bufs:
        t_pc.append(_best(lambda: ours(buf), repeats)[0])
        t_cv.append(_best(lambda: bare(buf), repeats)[0])
    return {"pnp_vs_opencv": float(np.median(t_pc) / np.median(t_cv)),
            "pnp_ms": float(np.median(t_pc) * 1e3), "opencv_pnp_ms": float(np.median(t_cv) * 1e3)}


def bench_estimator(trials=2000, seed=0):
    """crlb_ratio_tilt20, single_fit_ms, and the batched throughput."""
    from pencilcal.toolkit.pencil.estimator import crlb, fit_pencil
    from pencilcal.toolkit.geometry.frames import rotation_about_axis
    from pencilcal.toolkit.pencil.spec import image_angles

    rng = np.random.default_rng(seed)
    th = np.radians(np.arange(8) * 20.0)
    sigma = np.radians(0.1)
    z = np.array([0.0, 0.0, 1.0])
    R = (rotation_about_axis(np.tile(z, (trials, 1)), rng.uniform(0, 2 * np.pi, trials))
         @ rotation_about_axis([1.0, 0, 0], np.radians(20.0))
         @ rotation_about_axis(np.tile(z, (trials, 1)), rng.uniform(0, 2 * np.pi, trials)))
    a = image_angles(R, np.zeros(2), th) + sigma * rng.normal(size=(trials, 8))
    t0 = time.perf_counter()
    fit = fit_pencil(a, th, np.zeros(2), sigma=sigma)
    t_batch = time.perf_counter() - t0
    _, b, _ = crlb(R, np.zeros(2), th, sigma)
    ratio = np.sqrt(np.mean((fit.tilt - np.radians(20)) ** 2)) / np.sqrt(np.mean(b**2))
    loop = 200
    t0 = time.perf_counter()
    for i in range(loop):
        fit_pencil(a[i], th, np.zeros(2), sigma=sigma)
    t_single = (time.perf_counter() - t0) / loop
    out = {"crlb_ratio_tilt20": float(ratio), "single_fit_ms": float(t_single * 1e3),
           "numpy_batched_fits_per_s": float(trials / t_batch)}
    try:
        from pencilcal.toolkit.pencil.torch_backend import torch_available

        if torch_available():
            r = benchmark_batched(n=200_000, loop_n=200, numpy_batched_n=20_000)
            out["batch_speedup"] = float(r["speedup_float64_vs_loop"])
            out["fits_per_minute_batched"] = float(r["float64_pencils_per_minute"])
            out["batched_backend"] = f"torch {r.get('torch_version', '')} {r.get('device', '')}".strip()
            return out
    except ImportError:
        pass
    out["batch_speedup"] = float(out["numpy_batched_fits_per_s"] * t_single)
    out["fits_per_minute_batched"] = float(out["numpy_batched_fits_per_s"] * 60)
    out["batched_backend"] = "numpy (torch not installed)"
    return out


def _random_pencils(n, lines, seed):
    """`n` random pencils of `lines` lines for `benchmark_batched`: (a (n, lines) [rad],
    th (lines,) [rad], vertex (n, 2) normalised, sigma [rad])."""
    from pencilcal.toolkit.geometry.frames import rotation_to_z, rotation_about_axis
    from pencilcal.toolkit.pencil.estimator import pencil_jacobian

    rng = np.random.default_rng(seed)
    off = np.radians(rng.uniform(0, 30, n))
    az = rng.uniform(0, 2 * np.pi, n)
    vertex = np.tan(off)[:, None] * np.stack([np.cos(az), np.sin(az)], -1)
    v = np.concatenate([vertex, np.ones((n, 1))], -1)
    z = np.broadcast_to([0.0, 0.0, 1.0], (n, 3))
    R = (np.swapaxes(rotation_to_z(v), -1, -2) @ rotation_about_axis(z, rng.uniform(0, 2 * np.pi, n))
         @ rotation_about_axis(np.broadcast_to([1.0, 0, 0], (n, 3)), np.radians(rng.uniform(5, 80, n)))
         @ rotation_about_axis(z, rng.uniform(0, 2 * np.pi, n)))
    th = np.radians(np.arange(lines) * (160.0 / max(lines - 1, 1)))
    sigma = np.radians(0.1)
    a = pencil_jacobian(R, vertex, th, with_jacobian=False)[0] + sigma * rng.normal(size=(n, lines))
    return a, th, vertex, sigma


def benchmark_batched(n=200_000, lines=8, device="cpu", dtypes=("float64", "float32"), loop_n=300,
                      numpy_batched_n=50_000, chunk=None, workers=None, seed=0, repeats=3):
    """Fits per second: the torch batched path against the numpy estimator.

    Fits `n` random pencils of `lines` lines (tilt 5-80 deg, vertex up to 30 deg off axis,
    0.1 deg noise) with `fit_pencils_torch` for each dtype in `dtypes`, `loop_n` of them
    one by one with `estimator.fit_pencil` (a Python loop over single pencils) and
    `numpy_batched_n` with one batched `estimator.fit_pencil` call. Each time is the best
    of `repeats` runs (a busy machine slows single runs by up to a third).

    Returns a dict: ``torch_<dtype>_fits_per_s``, ``numpy_loop_fits_per_s``,
    ``numpy_batched_fits_per_s``, ``speedup_<dtype>_vs_loop``, ``<dtype>_pencils_per_minute``,
    ``max_rotation_diff_deg_float32`` (float32 against float64 on the same pencils), the
    sizes, the device and the torch thread count. Nothing is asserted.

    Example
    -------
    >>> r = benchmark_batched(n=2000, loop_n=20, numpy_batched_n=2000)   # doctest: +SKIP
    >>> r["speedup_float64_vs_loop"] > 50                                 # doctest: +SKIP
    True
    """
    from pencilcal.toolkit.geometry.frames import rotation_angle
    from pencilcal.toolkit.pencil.estimator import fit_pencil
    from pencilcal.toolkit.pencil.estimator_torch import fit_pencils_torch
    from pencilcal.toolkit.pencil.torch_backend import import_torch, resolve_device

    torch, _ = import_torch()

    dev = resolve_device(device)
    a, th, vertex, sigma = _random_pencils(n, lines, seed)
    out = {"n": int(n), "lines": int(lines), "device": str(dev), "torch_threads": torch.get_num_threads(),
           "torch_version": torch.__version__}

    def sync():
        if dev.type == "cuda":
            torch.cuda.synchronize(dev)

    fits = {}
    for dts in dtypes:
        # warm-up (allocator, kernels), then the timed run on tensors already on the device
        at = torch.as_tensor(a, dtype=getattr(torch, dts), device=dev)
        xt = torch.as_tensor(vertex, dtype=getattr(torch, dts), device=dev)
        tht = torch.as_tensor(th, dtype=getattr(torch, dts), device=dev)
        fit_pencils_torch(at[:4096], tht, xt[:4096], sigma, device=dev, dtype=dts, chunk=chunk, workers=workers)
        sync()
        dt_s = np.inf
        for _ in range(max(1, int(repeats))):
            t0 = time.perf_counter()
            f = fit_pencils_torch(at, tht, xt, sigma, device=dev, dtype=dts, chunk=chunk, workers=workers)
            sync()
            dt_s = min(dt_s, time.perf_counter() - t0)
        fits[dts] = f
        out[f"torch_{dts}_fits_per_s"] = n / dt_s
        out[f"{dts}_pencils_per_minute"] = 60.0 * n / dt_s
        out[f"torch_{dts}_iterations"] = int(f["iterations"])
    t_loop = np.inf
    for _ in range(max(1, int(repeats))):
        t0 = time.perf_counter()
        for i in range(loop_n):
            fit_pencil(a[i], th, vertex[i], sigma=sigma)
        t_loop = min(t_loop, time.perf_counter() - t0)
    out["numpy_loop_fits_per_s"] = loop_n / t_loop
    nb = min(numpy_batched_n, n)
    t_nb = np.inf
    for _ in range(max(1, int(repeats))):
        t0 = time.perf_counter()
        ref = fit_pencil(a[:nb], th, vertex[:nb], sigma=sigma)
        t_nb = min(t_nb, time.perf_counter() - t0)
    out["numpy_batched_fits_per_s"] = nb / t_nb
    for dts in dtypes:
        out[f"speedup_{dts}_vs_loop"] = out[f"torch_{dts}_fits_per_s"] / out["numpy_loop_fits_per_s"]
        out[f"speedup_{dts}_vs_numpy_batched"] = out[f"torch_{dts}_fits_per_s"] / out["numpy_batched_fits_per_s"]
        R = fits[dts]["R_cam_from_target"][:nb].double().cpu().numpy()
        out[f"max_rotation_diff_deg_{dts}_vs_numpy"] = float(np.degrees(rotation_angle(R, ref.R_cam_from_target)).max())
    return out


def bench_sfm(n=12, seed=0, workdir=None, repeats=2):
    """sfm_vs_pycolmap: `reconstruct` over the bare pycolmap calls on the same images.

    The two sides alternate (bare, ours, bare, ours, ...) and each keeps its best wall time,
    so a busy machine hurts both alike; the CPU-time ratio (threads included) is reported
    beside it as ``sfm_vs_pycolmap_cpu``.
    """
    import resource
    import tempfile
    from pathlib import Path

    from pencilcal.validation.sfm import bare_pycolmap, reconstruct

    def cpu():
        r = resource.getrusage(resource.RUSAGE_SELF)
        return r.ru_utime + r.ru_stime

    sc, bufs = _frames("orbit", n, (960, 540), seed)
    wall = {"ours": np.inf, "bare": np.inf}
    cpus = {"ours": np.inf, "bare": np.inf}
    with tempfile.TemporaryDirectory(dir=workdir) as tmp:
        img_dir = Path(tmp) / "images"
        img_dir.mkdir()
        for i, b in enumerate(bufs):
            (img_dir / f"{i:03d}.png").write_bytes(b.tobytes())
        for k in range(repeats):
            for side in ("bare", "ours"):
                work = Path(tmp) / f"{side}{k}"
                t0, c0 = time.perf_counter(), cpu()
                if side == "ours":
                    res = reconstruct(str(img_dir), sc.camera, work, quiet=True)
                    n_ours = res.n_registered
                else:
                    n_bare = bare_pycolmap(img_dir, sc.camera, work)
                wall[side] = min(wall[side], time.perf_counter() - t0)
                cpus[side] = min(cpus[side], cpu() - c0)
    return {"sfm_vs_pycolmap": float(wall["ours"] / wall["bare"]), "sfm_vs_pycolmap_cpu": float(cpus["ours"] / cpus["bare"]),
            "sfm_s": float(wall["ours"]), "pycolmap_s": float(wall["bare"]),
            "sfm_registered": f"{n_ours}/{n}", "pycolmap_registered": f"{n_bare}/{n}"}


def run_bench(quick=False, seed=0, sections=("orient", "shafts", "pnp", "sfm", "estimator"), log=None):
    """Run the benchmarks; returns a flat dict of figures (see the module docstring)."""
    out = {}
    n = 2 if quick else 6
    steps = {
        "orient": lambda: bench_orient(n=n, repeats=2 if quick else 3, seed=seed),
        "shafts": lambda: bench_shafts(n=4 if quick else 16, repeats=2 if quick else 3, seed=seed),
        "pnp": lambda: bench_pnp(n=n, repeats=2 if quick else 3, seed=seed),
        "sfm": lambda: bench_sfm(n=8 if quick else 12, seed=seed, repeats=1 if quick else 2),
        "estimator": lambda: bench_estimator(trials=500 if quick else 2000, seed=seed),
        "orient_video": lambda: bench_orient_video(frames=32 if quick else 64, repeats=1 if quick else 2, seed=seed),
        "shafts_video": lambda: bench_shafts_video(frames=24 if quick else 48, repeats=1 if quick else 2, seed=seed),
        "calibrate": lambda: bench_calibrate(n=50, seed=seed),
        "orient_motion": lambda: bench_orient_motion(frames=48 if quick else 120, repeats=1 if quick else 2, seed=seed),
        "shafts_motion": lambda: bench_shafts_motion(frames=45 if quick else 90, repeats=1 if quick else 2, seed=seed),
    }
    for name in sections:
        if log:
            log(f"bench: {name} ...")
        t0 = time.perf_counter()
        try:
            out.update(steps[name]())
        except ImportError as e:  # an optional dependency missing: say so, keep going
            out[f"{name}_error"] = str(e).splitlines()[0]
        if log:
            log(f"bench: {name} done in {time.perf_counter() - t0:.1f} s")
    out["machine"] = _machine()
    return out


def _machine():
    import os
    import platform

    return {"cpus": os.cpu_count(), "platform": platform.platform(), "python": platform.python_version()}


def format_table(res):
    """The figures as an aligned text table, with the targets and whether they hold."""
    rows = []
    for key, value in res.items():
        if key == "machine" or isinstance(value, dict):
            continue
        target = TARGETS.get(key)
        verdict, tgt = "", ""
        if target and isinstance(value, (int, float)):
            op, lim = target
            if op == "<=":
                ok, tgt = value <= lim, f"<= {lim:g}"
            elif op == ">=":
                ok, tgt = value >= lim, f">= {lim:g}"
            else:
                ok, tgt = lim[0] <= value <= lim[1], f"{lim[0]:g}-{lim[1]:g}"
            verdict = "ok" if ok else "MISSED"
        shown = f"{value:.4g}" if isinstance(value, float) else str(value)
        rows.append((key, shown, tgt, verdict))
    w = [max(len(r[i]) for r in rows + [("figure", "value", "target", "")]) for i in range(4)]
    lines = [f"{'figure':<{w[0]}}  {'value':>{w[1]}}  {'target':<{w[2]}}  {''}"]
    lines += [f"{a:<{w[0]}}  {b:>{w[1]}}  {c:<{w[2]}}  {d}" for a, b, c, d in rows]
    m = res.get("machine", {})
    lines.append(f"({m.get('cpus')} cpus, {m.get('platform')}, python {m.get('python')})")
    return "\n".join(lines)
