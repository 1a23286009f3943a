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


def test_a_missing_edge_predicted_at_a_frontal_view():
    """Face on, the tilt moves no image angle to first order: the rotation's tilt columns are
    the finite differences' remainder, and at this roll they are parallel. The missing edge
    is still predicted, its sd the roll's alone (the lines' sd over the root of their count,
    at the search's outer end), not dropped for an sd of NaN."""
    cam = Camera("pinhole", 640, 480, [[500.0, 0, 320], [0, 500.0, 240], [0, 0, 1]])
    pen = pencil_from_dict({"start_deg": 0, "step_deg": 90, "count": 4, "shape": "wedge", "radius": [0, 50]})
    th, _, kind = pen.edge_angles()
    roll = np.radians(305.0)
    R = np.array([[np.cos(roll), -np.sin(roll), 0], [np.sin(roll), np.cos(roll), 0], [0, 0, 1]])
    used = np.delete(np.arange(8), 1)
    a = image_angles(R, np.zeros(2), th[used])
    u = np.stack([np.cos(a), np.sin(a)], -1)
    seg = np.concatenate([np.full((7, 2), [320.0, 240.0]), [320, 240] + 100 * u], -1)
    seg = np.where((kind[used] > 0)[:, None], seg, seg[:, [2, 3, 0, 1]])  # brighter along n
    rec = SimpleNamespace(ok=True, R_cam_from_target=R, lines={
        "angle": a, "sigma": np.full(7, 1e-3), "spoke": used, "segment": np.arange(7), "theta": th[used],
        "vertex": np.zeros(2)})
    p = predicted_edges(cam, pen, rec, seg)
    assert p is not None and p["edge"].tolist() == [1]
    d = p["lines"][0, 2:] - p["lines"][0, :2]
    assert abs(np.angle(np.exp(1j * (np.arctan2(d[1], d[0]) - image_angles(R, np.zeros(2), th[1:2])[0])))) < 1e-9
    r = np.hypot(*d)
    assert np.isclose(p["sd"][0], r * 1e-3 / np.sqrt(7), rtol=1e-3), (p["sd"][0], r)
