"""The split-chance runner: a calibration's own views simulated under its own noise model."""
from __future__ import annotations

import numpy as np

from pencilcal.toolkit.board.calibrate import calibrate, synthetic_detections
from pencilcal.toolkit.board.spec import board_from_dict
from pencilcal.toolkit.camera.model import Camera
from pencilcal.validation.split_chance import run, simulated_views, summary

BOARD = board_from_dict({"type": "chessboard", "squares": [9, 6], "square": 25.0})
CAM = Camera("opencv", 640, 480, [[530.0, 0, 320.0], [0, 530.0, 240.0], [0, 0, 1]], [-0.2, 0.05, 0, 0, 0])


def _calibrated(noise_px=0.3, views=14, seed=3):
    dets = synthetic_detections(CAM, BOARD, views=views, noise_px=noise_px, seed=seed)
    return dets, calibrate(dets, BOARD, (640, 480), warp=True, corner_noise=True)


def test_simulated_views_carry_the_calibrations_own_noise():
    dets, res = _calibrated()
    sim, truth = simulated_views(res, dets, BOARD, 7)
    assert [s is not None for s in sim] == list(res.used)
    # the same corners of the same views, and errors of the level the calibration measured
    again = calibrate(sim, BOARD, (640, 480), warp=True, corner_noise=True, outlier_view_sigma=None)
    assert sum(again.used) == sum(res.used)
    assert abs(again.rms_px / res.rms_px - 1.0) < 0.1, (again.rms_px, res.rms_px)
    # the truth is the calibration's own estimate: the new fit lands within a few sigmas of it
    z = (again.solution.theta[:4] - truth[:4]) / np.sqrt(np.diag(again.covariance.intrinsics)[:4])
    assert np.all(np.abs(z) < 4.0), z


def test_the_runs_read_against_the_real_split():
    dets, res = _calibrated()
    rows = [run(res, dets, BOARD, s, repeats=1) for s in (1, 2, 3)]
    assert all(r["views"] == sum(res.used) and np.isfinite(r["ratio"]) for r in rows)
    s = summary(rows, observed=sorted(r["ratio"] for r in rows)[1])
    assert s["runs"] == 3 and abs(s["at_least"] - 2 / 3) < 1e-9
    assert 0.0 < s["mean_ratio2"] < 10.0 and 0.0 <= s["within_1"] <= 1.0
