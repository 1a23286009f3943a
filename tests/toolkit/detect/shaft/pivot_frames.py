"""Synthetic still-camera pivot sequences as hard as real frames, with exact truth, for the
pivot epochs and the fulcrum prior (test_prior.py, test_epochs_render.py).

`pivot_frames` renders simulate's pivot scenario in its port view (an 8 mm shaft 80-150 mm
from the camera, its port outside the view) with camera epochs (the camera turned 3 deg
between them), colour, over a tissue-like backdrop with pale folds (`synth.tissue`), blur
1.5 px, noise, uneven light and JPEG at quality 80. `truth_axes` gives each frame's shaft
axis in undistorted pixels, `score` the found and false shafts against them.
"""
from __future__ import annotations

import numpy as np

from pencilcal.toolkit.detect.shaft.mask import MaskAxis
from pencilcal.toolkit.synth.scenarios import make_scenario
from pencilcal.validation.shaft_score import Tolerance, detection_line, score_frame

#: A detection finds the shaft within these of its exact axis (undistorted px): the
#: detector's midlines are good to a few tenths of a degree and a pixel or two on renders.
TOLERANCE = Tolerance(angle_deg=1.5, offset_px=10.0)


def pivot_frames(seed, frames=30, epochs=3, move_deg=3.0, size=(960, 540), jpeg=80):
    """(scenario, the decoded frames (BGR uint8)) of a hard pivot sequence (module docstring)."""
    import cv2

    sc = make_scenario("pivot", frames, seed=seed, size=size, port_view=100.0, shaft_radius=4.0, tip=100.0,
                       height=60.0, epochs=epochs, epoch_move_deg=move_deg, angle_range_deg=(55.0, 125.0))
    out = []
    for i in range(frames):
        img = sc.render(i, color=True, background="tissue", noise=3.0, blur_px=1.5, lighting=0.3)
        ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, jpeg])
        out.append(cv2.imdecode(buf, cv2.IMREAD_COLOR))
    return sc, out


def truth_axes(sc):
    """Each frame's shaft axis as a `MaskAxis` in undistorted pixels (its point 40-100 mm
    from the port along the shaft)."""
    K = np.asarray(sc.camera.K, float)
    out = []
    for fr in sc.frames:
        F, d = np.asarray(fr["fulcrum_cam"], float), np.asarray(fr["shaft_direction_cam"], float)
        p = [K @ (F + s * d) for s in (40.0, 100.0)]
        ln, c = detection_line(np.r_[p[0][:2] / p[0][2], p[1][:2] / p[1][2]])
        out.append(MaskAxis(line=ln, point=c, kind="shaft", width_px=50.0, length_px=0.0, elongation=0.0,
                            edges=None, area=0))
    return out


def score(sc, shafts_per_frame):
    """(found, false) over the frames: `validation.shaft_score.score_frame` of each frame's
    `Shaft` list (ideal midlines) against its truth axis, `TOLERANCE`."""
    found = false = 0
    for ref, shafts in zip(truth_axes(sc), shafts_per_frame):
        fs = score_frame([{"midline": np.asarray(s.ideal_midline).tolist(), "score": s.score} for s in shafts], [ref],
                         TOLERANCE)
        found += fs.found
        false += fs.false
    return found, false


def lines_frames(sc, shafts_per_frame):
    """lines.json frame dicts of the frames' shafts."""
    return [{"image": fr["image"], "ok": True, "segments": np.zeros((0, 4)), "shafts": [s.to_dict() for s in sh]}
            for fr, sh in zip(sc.frames, shafts_per_frame)]
