"""The harder hand-held video scored against its truth: `pencilcal orient VIDEO` frame by frame.

Each seed's video is rendered by `bench_video.hard_handheld_frames` (a phone or webcam in a
hand: blur, a rolling shutter read out over 0.6 of a frame, JPEG, auto exposure, a hand over
the fan; docs/live.md, "A harder hand-held video"), written as 1080p MJPEG with its camera
and pencil files, and run as a user runs it (``pencilcal orient VIDEO --camera ... --pencil
... --jsonl OUT``: tracked, one worker), as a process of its own. The camera file states no readout
unless one is given (``--readout R``: as the camera file's ``readout``; ``unknown``, the
default: none, so each moved frame's sigmas are widened for a readout anywhere in 0-1).

Per seed, of the frames with an orientation: wrong (the tilt more than 1 deg off the truth,
or more than 3 of its sigmas), right (the others), within 1, 2 and 3 sigma, the median tilt
sigma, within 0.5 deg, more than 1 deg off, and the largest error [deg]. A frame's truth is
the pose at the middle of the exposure of the row through the fan's vertex.

    python -m pencilcal.validation.hard_video --seeds 1:2 [--readout R|unknown] [--videos DIR]

``--videos DIR`` keeps each seed's rendered video in DIR/hard<seed>/ (v.avi, camera.json,
pencil.yaml, truth.json) and uses it again when it is there (a 1080p seed takes minutes to
render); ``--frames`` (default 120), ``--size WxH`` (default 1920x1080).

Example
-------
>>> rec = [{"ok": True, "tilt_deg": 20.3, "tilt_sigma_deg": 0.2}, {"ok": True, "tilt_deg": 21.5, "tilt_sigma_deg": 1.0},
...        {"ok": False}]
>>> s = score(rec, [20.0, 20.0, 20.0])
>>> s["oriented"], s["right"], s["wrong"], s["within_sigma"]
(2, 1, 1, [0.0, 1.0, 1.0])
"""
from __future__ import annotations

import json
import sys
import tempfile
from pathlib import Path

import numpy as np

from pencilcal.toolkit.errors import InputError
from pencilcal.validation.metrics import seed_list

__all__ = ["score", "render_seed", "run_seed", "format_row", "main", "WRONG_DEG", "WRONG_SIGMAS"]

#: A frame is wrong when its tilt is more than this far off [deg] ...
WRONG_DEG = 1.0
#: ... or more than this many of its tilt sigmas off.
WRONG_SIGMAS = 3.0


def score(records, tilts):
    """The figures of one video (module docstring) from its ``--jsonl`` records (one per frame,
    in order: ``ok``, ``tilt_deg``, ``tilt_sigma_deg``) and the true tilts [deg] (same length).

    Returns a dict: frames, oriented, right, wrong, beyond_3_sigma, within_sigma (the
    fractions within 1, 2, 3 sigma of the oriented frames), median_sigma_deg,
    within_0p5_deg, over_1_deg, largest_error_deg, wrong_frames (their indices)."""
    truth = np.asarray(tilts, float)
    if len(records) != len(truth):
        raise InputError(f"hard video: {len(records)} orientation records for {len(truth)} frames")
    ok = np.array([bool(r.get("ok")) for r in records])
    t = np.array([r["tilt_deg"] if o else np.nan for r, o in zip(records, ok)], float)
    s = np.array([r.get("tilt_sigma_deg", np.nan) if o else np.nan for r, o in zip(records, ok)], float)
    e = np.abs(t - truth)
    with np.errstate(invalid="ignore"):
        wrong = ok & ((e > WRONG_DEG) | (e > WRONG_SIGMAS * s))
        within = [float(np.mean(e[ok] <= k * s[ok])) if ok.any() else float("nan") for k in (1, 2, 3)]
        return {"frames": int(len(truth)), "oriented": int(ok.sum()), "right": int(np.sum(ok & ~wrong)),
                "wrong": int(wrong.sum()), "beyond_3_sigma": int(np.sum(ok & (e > WRONG_SIGMAS * s))),
                "within_sigma": within, "median_sigma_deg": float(np.nanmedian(s)) if ok.any() else float("nan"),
                "within_0p5_deg": int(np.sum(ok & (e <= 0.5))), "over_1_deg": int(np.sum(ok & (e > WRONG_DEG))),
                "largest_error_deg": float(np.nanmax(e)) if ok.any() else float("nan"),
                "wrong_frames": np.flatnonzero(wrong).tolist()}


def render_seed(seed, folder, frames=120, size=(1920, 1080)):
    """Render seed's hard hand-held video into `folder` (v.avi MJPEG, camera.json, pencil.yaml,
    truth.json: ``tilts`` [deg] and per-frame ``info``) unless it holds that video already
    (the same number of frames). Returns the folder."""
    d = Path(folder)
    names = ("v.avi", "camera.json", "pencil.yaml", "truth.json")
    if all((d / n).exists() for n in names) and len(json.loads((d / "truth.json").read_text())["tilts"]) == frames:
        return d
    from pencilcal.toolkit.camera.formats import write_camera
    from pencilcal.toolkit.pencil.spec import write_pencil
    from pencilcal.validation.bench_video import hard_handheld_frames, write_video

    d.mkdir(parents=True, exist_ok=True)
    cam, pencil, images, tilts, info = hard_handheld_frames(frames, seed=seed, size=size)
    write_camera(d / "camera.json", cam)
    write_pencil(d / "pencil.yaml", pencil)
    write_video(d / "v.avi", images, fourcc="MJPG")
    (d / "truth.json").write_text(json.dumps({"tilts": tilts, "info": info}))
    return d


def run_seed(folder, readout=None, workdir=None):
    """score() of ``pencilcal orient`` on the video in `folder` (`render_seed`'s layout), run as
    a process of its own (``python -m pencilcal.cli.main``, this interpreter); readout: None
    (not known: the camera file's, none in a rendered one) or the rows' readout over the
    frame interval (0-1), as ``--readout`` gives it."""
    import subprocess

    d = Path(folder)
    with tempfile.TemporaryDirectory(dir=workdir) as tmp:
        out, jsonl = Path(tmp) / "o.json", Path(tmp) / "o.jsonl"
        args = ["orient", str(d / "v.avi"), "--camera", str(d / "camera.json"), "--pencil", str(d / "pencil.yaml"),
                "-o", str(out), "--jsonl", str(jsonl), "--force", "-q"]
        if readout is not None:
            args += ["--readout", str(readout)]
        r = subprocess.run([sys.executable, "-m", "pencilcal.cli.main", *args], capture_output=True, text=True)
        # exit 1 with the records written: no frame gave an orientation (the records say so)
        if r.returncode not in (0, 1) or not jsonl.exists():
            raise RuntimeError(f"hard video: `pencilcal orient` on {d} failed (exit {r.returncode}): "
                               f"{r.stderr.strip()[-300:]}")
        records = [json.loads(line) for line in jsonl.read_text().splitlines() if line.strip()]
    return score(records, json.loads((d / "truth.json").read_text())["tilts"])


def format_row(seed, s):
    """One seed's figures as a line of text."""
    w1, w2, w3 = (100 * v for v in s["within_sigma"])
    return (f"seed {seed}: {s['oriented']}/{s['frames']} with an orientation, right {s['right']}, wrong {s['wrong']} "
            f"(beyond 3 sigma {s['beyond_3_sigma']}, more than 1 deg off {s['over_1_deg']}), within 1/2/3 sigma "
            f"{w1:.0f}/{w2:.0f}/{w3:.0f} %, median tilt sigma {s['median_sigma_deg']:.3f} deg, within 0.5 deg "
            f"{s['within_0p5_deg']}, largest error {s['largest_error_deg']:.2f} deg")


def _readout(text):
    if text == "unknown":
        return None
    try:
        r = float(text)
    except ValueError:
        r = -1.0
    if not 0.0 <= r <= 1.0:
        raise InputError(f"--readout: a number from 0 to 1 or 'unknown', got {text!r}")
    return r


def main(argv=None):
    """Render (or reuse), orient and score each seed (module docstring)."""
    import argparse

    ap = argparse.ArgumentParser(prog="python -m pencilcal.validation.hard_video", description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=seed_list, default="1:2", help="A:B (seeds A to B-1) or a,b,c")
    ap.add_argument("--readout", default="unknown", help="the readout orient is told (0-1), or 'unknown' (default)")
    ap.add_argument("--videos", default=None, help="a folder keeping each seed's video (hard<seed>/), reused")
    ap.add_argument("--frames", type=int, default=120)
    ap.add_argument("--size", default="1920x1080", help="WxH")
    ap.add_argument("--out", default=None, help="a JSON file for the rows")
    a = ap.parse_args(argv)
    readout = _readout(a.readout)
    size = tuple(int(v) for v in a.size.lower().split("x"))
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        base = Path(a.videos) if a.videos else Path(tmp)
        for seed in a.seeds:
            d = render_seed(seed, base / f"hard{seed}", a.frames, size)
            s = run_seed(d, readout)
            rows.append(dict(s, seed=seed, readout=a.readout))
            print(format_row(seed, s), flush=True)
    if a.out:
        Path(a.out).write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
