"""The two-halves check's readings: the halves' difference along its predicted modes, and
each view's own focal scale against its corner noise (a focus that changed between views).

Synthetic views of a 12 x 9 chessboard through a 960x540 endoscope-like lens; the figures
quoted are docs/calibration.md's (section The da Vinci left odd/even split, measured a third
time).
"""
from __future__ import annotations

import numpy as np
import pytest

from pencilcal.toolkit.board.calibrate import calibrate
from pencilcal.toolkit.board.detect import BoardDetection
from pencilcal.toolkit.board.spec import board_from_dict
from pencilcal.toolkit.board.synthetic import synthetic_detections
from pencilcal.toolkit.camera.model import Camera
from pencilcal.validation.calibration_checks import calibration_halves, view_focal_scales
from pencilcal.validation.calibration_verdict import judge

BOARD = board_from_dict({"type": "chessboard", "squares": [12, 9], "square": 4.77})
LENS = Camera("opencv", 960, 540, [[770.0, 0, 489.0], [0, 771.0, 262.0], [0, 0, 1]], [-0.38, 0.21, 0, 0, -0.05])
GEOMETRY = {"tilt_deg": [30, 35, 40, 45, 20, 25, 30, 50], "distance": [300, 310, 320, 330, 400, 420, 440, 460],
            "area_fraction": [0.2] * 8}
UMAP = {"covered_fraction": 0.8, "median_covered_px": 0.2, "max_covered_px": 0.4}


def _views(seed, focal_sd=0.0, views=24):
    """Synthetic detections; with `focal_sd` each view sees the lens at a focal length of its
    own, scaled by 1 + N(0, focal_sd^2) (a focus that moved between views): its corners'
    offsets from the principal point scale so, exactly, before the noise."""
    clean = synthetic_detections(LENS, BOARD, views=views, noise_px=0.0, seed=seed, tilt_deg=50.0)
    rng = np.random.default_rng([seed, 11])
    pp = np.array([LENS.cx, LENS.cy])
    out = []
    for d in clean:
        s = 1.0 + focal_sd * rng.normal()
        px = pp + (np.asarray(d.corners, float) - pp) * s + 0.2 * rng.normal(size=np.shape(d.corners))
        out.append(BoardDetection(d.ids, px, d.image_size, d.marker_ids, d.marker_corners))
    return out


@pytest.fixture(scope="module")
def honest():
    dets = _views(1780)
    return dets, calibrate(dets, BOARD, LENS.size, corner_noise=True, warp=True)


def test_each_views_focal_scale_scatters_as_its_noise_says(honest):
    dets, res = honest
    v = view_focal_scales(res, dets, BOARD)
    assert v["views"] == 24 and len(v["largest"]) == 3
    # measured over 40 seeds (1780-1819): chi2/dof 0.88 +- 0.28, p under 0.05 in 2 of 40, under
    # 0.001 in none
    assert 0.4 < v["chi2_per_dof"] < 1.8 and v["p_value"] > 1e-3, v


def test_a_focus_that_moved_between_views_is_found_and_warned_about():
    # 0.5 % per view: 3.9 px of focal length, 2.8 x a view's own sigma (0.18 %) here.
    # Measured over 20 seeds (1820-1839): chi2/dof 2.2-3.4, p under 0.001 in every run; the
    # scatter beyond the noise 0.27-0.49 % (the views' levels take in part of it)
    dets = _views(1781, focal_sd=0.005)
    res = calibrate(dets, BOARD, LENS.size, corner_noise=True, warp=True)
    v = view_focal_scales(res, dets, BOARD)
    assert v["p_value"] < 1e-3 and v["chi2_per_dof"] > 2.0, v
    assert 0.002 < v["tau"] < 0.007, v
    halves = {"odd_even": {"chi2_per_dof": 1.0, "projection_ratio": 1.0, "p_value": 0.5},
              "pooled": {"chi2_per_dof": 1.0, "projection_ratio": 1.0}, "view_focal_scale": v}
    w = judge(24, halves, UMAP, GEOMETRY).warnings
    assert any("focal scale beyond their corner noise" in x for x in w), w
    ok = dict(halves, view_focal_scale={**v, "p_value": 0.3})
    assert not any("focal scale" in x for x in judge(24, ok, UMAP, GEOMETRY).warnings)


def test_the_projection_ratio_is_the_difference_along_its_modes(honest):
    dets, res = honest
    oe = calibration_halves(res, dets, BOARD, repeats=0)["odd_even"]
    md = oe["projection_modes"]
    assert md["share"] == sorted(md["share"], reverse=True) and 0 < md["share"][0] <= 1
    # ratio^2 = sum share_k z_k^2 over every mode; the three kept hold most of it
    lo = sum(s * z * z for s, z in zip(md["share"], md["z"]))
    assert lo <= oe["projection_ratio"] ** 2 * (1 + 1e-6) + md["outside_px2"]
    assert md["outside_px2"] < 1e-6 * oe["projection_rms_px"] ** 2 + 1e-12
