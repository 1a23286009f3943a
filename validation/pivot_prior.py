"""The fulcrum prior's angle search scored frame by frame on rendered pivots.

On a `validation.pivot_renders` sequence the fulcrum and every frame's axis are known. Each
frame of one eye is detected through the true fulcrum's image (`detect_shafts(...,
axis_prior=...)`, the prior's sd the port's play seen at its depth, `prior_of`) and its
shaft, if any, scored against the frame's true axis image (`truth_axis`): *found* within
`ANGLE_DEG` and max(`OFFSET_PX`, half the shaft's width) at the middle of its visible
stretch, otherwise *false*; a frame without a found shaft is *missed*. A found shaft more
than `OFF_AXIS_PX` off the axis is listed: that tolerance lets a band beside the axis (a
highlight along the shaft) pass. This is the figure
that `fulcrum --fulcrum-prior` rests on, measured without the estimation of the prior.

    python -m pencilcal.validation.pivot_prior --seeds 2656:2666 --out DIR [--eye left]

writes the sequences that are not yet under DIR (`pivot_renders.write_sequence`), scores them
and prints one line per seed (found, false, the missed, false and off-axis frames) and the totals;
``prior_scores_left.json`` (or ``_right``) under DIR holds the frames' records.

Example
-------
>>> s = draw_sequence(2600, frames=2)
>>> ln, c, w = truth_axis(s, 0)
>>> bool(abs(ln[:2] @ c + ln[2]) < 1e-9 and 10.0 < w < 200.0)
True
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

from pencilcal.toolkit.detect.shaft.mask import MaskAxis
from pencilcal.toolkit.detect.shaft.prior import AxisPrior
from pencilcal.validation.fulcrum_pivots import pivot_camera
from pencilcal.validation.metrics import seed_list
from pencilcal.validation.pivot_renders import (DIAMETER_MM, PLAY_SD_MM, draw_sequence, eye_axis, eye_pose, in_view,
                                                write_sequence)
from pencilcal.validation.shaft_score import Tolerance, detection_line, score_frame

__all__ = ["ANGLE_DEG", "OFFSET_PX", "OFF_AXIS_PX", "truth_axis", "prior_of", "score_sequence", "main"]

#: A shaft through the prior finds the instrument within this angle [deg] of its axis ...
ANGLE_DEG = 4.0
#: ... and max(this, half its width) [px] of the axis at the middle of its visible stretch.
OFFSET_PX = 15.0


def truth_axis(scene, i, eye=0):
    """(line (3,) with a^2 + b^2 = 1, its point (2,), the shaft's width there [px]) of frame i's
    axis image in one eye (ideal px = raw px: the camera is a pinhole; the axis and what the
    eye sees of it as the renders have them, `pivot_renders.eye_axis`, `pivot_renders.in_view`):
    the point the middle of the shaft's visible stretch, port to tip."""
    cam = pivot_camera()
    A, d = eye_axis(scene, i, eye)
    X = A + np.linspace(0.0, scene["frames"][i]["L"], 400)[:, None] * d
    p = _pixels(cam, X)
    k = np.flatnonzero(in_view(X, p, (cam.width, cam.height), 0.0))
    if k.size == 0:
        k = np.arange(X.shape[0])
    mid = k[k.size // 2]
    ln, _ = detection_line(np.r_[p[0], p[-1]])
    c = p[mid] - (ln[:2] @ p[mid] + ln[2]) * ln[:2]
    return ln, c, float(cam.K[0, 0] * DIAMETER_MM / X[mid, 2])


def prior_of(scene, eye=0):
    """The `AxisPrior` of the true fulcrum's image in one eye (`pivot_renders.eye_pose`): its sd
    the port's play (`PLAY_SD_MM`) at the port's depth [px] per axis."""
    cam = pivot_camera()
    R, t = eye_pose(scene, eye)
    F = R @ scene["fulcrum"] + t
    sd = cam.K[0, 0] * PLAY_SD_MM / F[2]
    return AxisPrior.from_point(_pixels(cam, F[None])[0], np.eye(2) * sd**2)


def _pixels(cam, X):
    """(N, 2) pixels of the points X (N, 3) [mm, an eye's frame] by the pinhole's K, (K X) / z:
    the form these scores were measured with. `Camera.project` (x / z through K, as the renders
    project) differs from it in the last bits (up to 4e-13 px), which moves the prior's point
    and so the detections' own last bits; kept so that the figures stay those measured."""
    p = (cam.K @ X.T).T
    return p[:, :2] / p[:, 2:]


def score_sequence(folder, scene, eye=0, frames=None, detect=None):
    """Per frame of a written sequence (`pivot_renders.write_sequence`) of the scene, a dict
    {frame, found, false, angle_err_deg, offset_err_px} of the shafts detected through the
    true fulcrum's image (module docstring). frames: the frame indices (default all);
    detect: ``detect(image, camera, prior) -> shafts`` (default `detect_shafts`)."""
    import cv2

    from pencilcal.toolkit.detect.shaft.detector import detect_shafts

    detect = detect or (lambda img, cam, p: detect_shafts(img, cam, axis_prior=p))
    cam, prior = pivot_camera(), prior_of(scene, eye)
    out = []
    for i in range(len(scene["frames"])) if frames is None else frames:
        img = cv2.imread(str(Path(folder) / ("left", "right")[eye] / f"frame_{i:03d}.jpg"), cv2.IMREAD_COLOR)
        ln, c, w = truth_axis(scene, i, eye)
        ref = MaskAxis(line=ln, point=c, kind="shaft", width_px=w, length_px=0.0, elongation=0.0, edges=None, area=0)
        dets = [{"midline": np.asarray(s.ideal_midline, float).ravel().tolist(), "score": s.score}
                for s in detect(img, cam, prior)]
        fs = score_frame(dets, [ref], Tolerance(angle_deg=ANGLE_DEG, offset_px=max(OFFSET_PX, 0.5 * w)))
        out.append({"frame": int(i), "found": fs.found, "false": fs.false,
                    "angle_err_deg": fs.angle_err_deg[0] if fs.found else None,
                    "offset_err_px": fs.offset_err_px[0] if fs.found else None})
    return out


#: A found shaft this far [px] off the true axis is flagged: within the tolerance, but a
#: band of the shaft beside its axis (a highlight along it), not its silhouette.
OFF_AXIS_PX = 3.0


def _line(seed, rows):
    """One seed's line of the table: found, false, the frames missed, false, found off the axis."""
    miss = [r["frame"] for r in rows if not r["found"]]
    false = [r["frame"] for r in rows if r["false"]]
    off = [r["frame"] for r in rows if r["found"] and r["offset_err_px"] > OFF_AXIS_PX]
    return (f"{seed:<6d} found {sum(r['found'] for r in rows):3d}/{len(rows):<3d} false {sum(r['false'] for r in rows):2d}"
            f"  missed {miss}  false at {false}  off the axis (> {OFF_AXIS_PX:g} px) at {off}")


def main(argv=None):
    """Write (where missing), score and tabulate seeded sequences (module docstring)."""
    import argparse

    ap = argparse.ArgumentParser(prog="python -m pencilcal.validation.pivot_prior", description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=seed_list, default="2656:2666", help="A:B (seeds A to B-1) or a,b,c")
    ap.add_argument("--frames", type=int, default=50)
    ap.add_argument("--eye", default="left", choices=("left", "right"))
    ap.add_argument("--out", required=True, help="folder for the sequences and prior_scores.json")
    a = ap.parse_args(argv)
    out, eye = Path(a.out), ("left", "right").index(a.eye)
    res = {}
    for seed in a.seeds:
        folder = out / f"seq{seed}"
        scene = draw_sequence(seed, a.frames)
        if not (folder / "truth.json").exists():
            write_sequence(scene, folder)
        res[seed] = score_sequence(folder, scene, eye)
        print(_line(seed, res[seed]), flush=True)
    allrows = [r for rows in res.values() for r in rows]
    print(f"total  found {sum(r['found'] for r in allrows)}/{len(allrows)} false {sum(r['false'] for r in allrows)}")
    tmp = out / f"prior_scores_{a.eye}.json.tmp"
    tmp.write_text(json.dumps({str(k): v for k, v in res.items()}, indent=1))
    tmp.replace(out / f"prior_scores_{a.eye}.json")


if __name__ == "__main__":
    main(sys.argv[1:])
