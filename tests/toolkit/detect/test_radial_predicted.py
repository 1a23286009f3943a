"""A star's edges searched for where an orientation predicts them: not found where nothing is
printed (tests/validation/test_radial_predicted.py: found where they are, on photographs)."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from pencilcal.toolkit.camera.model import Camera
from pencilcal.toolkit.detect.radial import detect_radial_edges
from pencilcal.toolkit.detect.radial_predicted import predicted_edges
from pencilcal.toolkit.pencil.spec import image_angles, pencil_from_dict
from pencilcal.toolkit.synth.radial import radial_pose, render_layers, star_layers

CAM = Camera("opencv", 1280, 960, [[1000.0, 0, 643.1], [0, 1000.5, 477.4], [0, 0, 1]], [-0.1, 0.0, 0.0, 0.0])
STAR = pencil_from_dict({"start_deg": 0, "step_deg": 5.625, "count": 64, "shape": "wedge", "radius": [12, 70],
                         "polarity": "dark"})


def _frame(printed, seed=3):
    """A 64-wedge star half the frame's height at 45 deg, blurred by 1.3 px."""
    R, t = radial_pose(CAM, (640, 480), 45.0, 70.0, fill=0.5, axis_deg=20, roll_deg=0)
    img = render_layers(CAM, R, t, star_layers(printed), blur_px=1.3, noise=2.0, gamma=2.2, lighting=0.3,
                        jpeg_quality=80, rng=seed)
    return img, R, t


def _truth_record(R, t, found, labelled):
    """An orientation record at the truth whose lines are the found edges nearest the
    edges `labelled`: what a first fit that labelled those gives the prediction."""
    x = t[:2] / t[2]
    ea, _, _ = STAR.edge_angles()
    true = image_angles(R, x, ea)
    d = found.ideal[:, 2:] - found.ideal[:, :2]
    vpx = CAM.undistort_pixels(CAM.project(t))
    out = np.sign(np.sum(d * (0.5 * (found.ideal[:, :2] + found.ideal[:, 2:]) - vpx), -1))
    a = np.arctan2(d[:, 1] * out / CAM.K[1, 1], d[:, 0] * out / CAM.K[0, 0])
    res = np.angle(np.exp(1j * (a[:, None] - true[None, labelled])))
    seg = np.argmin(np.abs(res), 0)
    return SimpleNamespace(ok=True, R_cam_from_target=R, lines={
        "angle": a[seg], "sigma": np.maximum(found.angle_sigma[seg], 1e-4), "spoke": np.asarray(labelled),
        "segment": seg, "theta": ea[labelled], "vertex": x}), true


def test_nothing_kept_where_nothing_is_printed():
    """Where a wedge is not printed (paper between its neighbours) its predicted edges show
    no step out of the noise and are not kept; the printed wedges' edges are."""
    gone = [40, 41, 42]  # three neighbouring wedges left out of the print
    printed = pencil_from_dict({"angles_deg": [float(a) for i, a in enumerate(np.arange(64) * 5.625) if i not in gone],
                                "shape": "wedge", "radius": [0, 70], "polarity": "dark", "wedge_deg": 2.8125})
    img, R, t = _frame(printed, seed=4)
    first = detect_radial_edges(img, CAM, edges=128, joint="all")
    ea, spoke, _ = STAR.edge_angles()
    rec, true = _truth_record(R, t, first, np.flatnonzero(~np.isin(spoke, gone) & (np.arange(128) % 3 != 0)))
    pred = predicted_edges(CAM, STAR, rec, first.segments)
    more = detect_radial_edges(img, CAM, edges=128, joint="all", predicted=pred)
    d = more.ideal[:, 2:] - more.ideal[:, :2]
    vpx = CAM.undistort_pixels(CAM.project(t))
    out = np.sign(np.sum(d * (0.5 * (more.ideal[:, :2] + more.ideal[:, 2:]) - vpx), -1))
    a = np.arctan2(d[:, 1] * out / CAM.K[1, 1], d[:, 0] * out / CAM.K[0, 0])
    res = np.abs(np.angle(np.exp(1j * (a[:, None] - true[None]))))
    hit = np.argmin(res, 1)
    assert not np.any(np.isin(spoke[hit], gone) & (np.min(res, 1) < 0.5 * np.radians(2.8125)))
    assert np.isin(spoke[hit], np.setdiff1d(np.arange(64), gone)).sum() > len(first) - 3
