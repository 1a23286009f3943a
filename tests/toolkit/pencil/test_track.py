"""Tracking from frame to frame: labels by the previous frame, checked, with the full search
as the fallback."""
from __future__ import annotations

import numpy as np

from pencilcal.toolkit.camera.model import Camera
from pencilcal.toolkit.geometry.frames import rotation_about_axis
from pencilcal.toolkit.pencil.orient import orient_segments
from pencilcal.toolkit.pencil.spec import Pencil, image_angles
from pencilcal.toolkit.pencil.track import orient_tracked, prior_labels

CAM = Camera("pinhole", 1280, 720, [[900.0, 0, 639.5], [0, 900.0, 359.5], [0, 0, 1]])
PEN = Pencil(np.radians(np.arange(8) * 20.0 - 70.0))


def _segments(tilt_deg, extra=0, seed=0):
    """Spoke segments (8 + extra, 4) raw px of the pencil tilted about x, vertex at the
    centre, 0.2 px noise on the end points; `extra` random clutter segments."""
    rng = np.random.default_rng(seed)
    R = rotation_about_axis([1.0, 0.0, 0.0], np.radians(tilt_deg)) @ rotation_about_axis([0, 0, 1.0], 0.3)
    a = image_angles(R, np.zeros(2), PEN.angles)
    c = np.array([639.5, 359.5])
    u = np.stack([np.cos(a), np.sin(a)], -1)
    seg = np.concatenate([c + 60 * u, c + 320 * u], -1) + rng.normal(0, 0.2, (8, 4))
    if extra:
        seg = np.concatenate([seg, rng.uniform([0, 0, 0, 0], [1279, 719, 1279, 719], (extra, 4))])
    return seg


def test_tracked_frames_equal_the_full_run_when_the_labels_agree():
    prev = None
    for k, tilt in enumerate(np.linspace(20, 40, 6)):
        seg = _segments(tilt, extra=5, seed=k)
        full = orient_segments(CAM, seg, PEN, endpoint_sigma_px=0.3)
        rec, tracked = orient_tracked(CAM, seg, PEN, prev, endpoint_sigma_px=0.3)
        assert tracked == (k > 0)
        assert np.array_equal(rec.spokes, full.spokes)
        assert abs(rec.tilt_deg - full.tilt_deg) < 1e-9
        prev = rec


def test_a_prior_that_does_not_fit_falls_back_to_the_full_search():
    prev, _ = orient_tracked(CAM, _segments(30), PEN, None)
    # the pencil turned by half a spoke step since: every label by the prior would be wrong
    R = rotation_about_axis([0, 0, 1.0], np.radians(10.0)) @ np.asarray(prev.R_cam_from_target)
    moved = prev.replace(R_cam_from_target=R)
    assert (prior_labels(CAM, _segments(30), PEN, moved) >= 0).sum() < 3
    seg = _segments(30, seed=3)
    rec, tracked = orient_tracked(CAM, seg, PEN, moved)
    full = orient_segments(CAM, seg, PEN)
    assert not tracked and np.array_equal(rec.spokes, full.spokes) and rec.tilt_deg == full.tilt_deg


def test_no_previous_estimate_means_the_full_search():
    failed = orient_segments(CAM, np.zeros((0, 4)), PEN)
    rec, tracked = orient_tracked(CAM, _segments(25), PEN, failed)
    assert not tracked and rec.ok


def test_bars_handed_over_undistorted_give_the_same_frames():
    # a lens with k1: the bars' midlines given in undistorted pixels as well (the detector's,
    # `orient_segments`' ideal) are not undistorted again; the same labels and the same
    # estimates to far below their sigmas (the noise scale is taken at the ideal centres)
    cam = Camera("opencv", 1280, 720, CAM.K, [-0.2, 0.05, 0.0, 0.0, 0.0])
    prev = prev_ideal = None
    for k, tilt in enumerate(np.linspace(20, 40, 6)):
        ideal = _segments(tilt, extra=2, seed=k)
        raw = cam.distort_pixels(ideal.reshape(-1, 2)).reshape(-1, 4)
        width = np.full(len(raw), 3.0)
        assert np.array_equal(prior_labels(cam, raw, PEN, prev, ideal=ideal), prior_labels(cam, raw, PEN, prev)) \
            if prev is not None else True
        rec, tracked = orient_tracked(cam, raw, PEN, prev, bar_width_px=width)
        rec_i, tracked_i = orient_tracked(cam, raw, PEN, prev_ideal, bar_width_px=width, ideal=ideal)
        assert rec.ok and tracked == tracked_i == (k > 0)
        assert np.array_equal(rec.spokes, rec_i.spokes)
        assert abs(rec.tilt_deg - rec_i.tilt_deg) < 1e-3 * rec.tilt_sigma_deg
        assert abs(rec.tilt_sigma_deg - rec_i.tilt_sigma_deg) < 1e-3 * rec.tilt_sigma_deg
        assert np.max(np.abs(rec.vertex_px - rec_i.vertex_px)) < 1e-3
        prev, prev_ideal = rec, rec_i


def test_a_star_printed_wider_than_its_file_is_tracked_at_its_printed_width():
    # ink spread: every wedge 1.2 times the file's width; the full search fits the printed
    # width (`orient._printed_wedge`), and tracked frames must too, or their labelled edges
    # miss the file's edges by many sigmas and every frame falls back to the full search
    from pencilcal.toolkit.pencil.spec import pencil_from_dict

    base = {"start_deg": 0, "step_deg": 22.5, "count": 16, "shape": "wedge", "polarity": "dark"}
    star = pencil_from_dict(base)
    printed = pencil_from_dict(dict(base, wedge_deg=1.2 * 11.25))
    prev = None
    for k, tilt in enumerate(np.linspace(30, 35, 4)):
        rng = np.random.default_rng(k)
        R = rotation_about_axis([1.0, 0, 0], np.radians(tilt)) @ rotation_about_axis([0, 0, 1.0], 0.3)
        a = image_angles(R, np.zeros(2), printed.edge_angles()[0])
        u = np.stack([np.cos(a), np.sin(a)], -1)
        c = np.array([639.5, 359.5])
        seg = np.concatenate([c + 60 * u, c + 320 * u], -1) + rng.normal(0, 0.1, (a.size, 4))
        full = orient_segments(CAM, seg, star, endpoint_sigma_px=0.1)
        rec, tracked = orient_tracked(CAM, seg, star, prev, endpoint_sigma_px=0.1)
        assert full.spokes_used == 16
        assert tracked == (k > 0) and rec.spokes_used == 16
        normals = [rec.normal] if not rec.ambiguous else [rec.normal, rec.normal_twin]
        err = min(np.degrees(np.arccos(np.clip(np.asarray(n) @ R[:, 2], -1, 1))) for n in normals)
        assert err < 4 * rec.normal_sigma_deg
        prev = rec


def test_a_fit_that_keeps_fewer_lines_stays_tracked_unless_the_full_search_explains_more():
    # two of eight spokes seen off the vertex (a hand's edge, a bent bar): the tracked fit
    # keeps six lines, fewer than the previous frame's eight less one; the full search
    # explains no more of them, so the labels the previous frame predicts are kept (a full
    # search on a few lines can pick a labelling shifted by one spoke about as well)
    prev = orient_segments(CAM, _segments(30.0), PEN, endpoint_sigma_px=0.3)
    assert prev.ok and prev.lines_used == 8
    seg = _segments(31.0, seed=1)
    n = np.array([-(seg[:2, 3] - seg[:2, 1]), seg[:2, 2] - seg[:2, 0]]).T
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    seg[:2] += np.tile(25.0 * n, 2)  # 25 px beside their spokes
    full = orient_segments(CAM, seg, PEN, endpoint_sigma_px=0.3)
    rec, tracked = orient_tracked(CAM, seg, PEN, prev, endpoint_sigma_px=0.3)
    assert full.ok and full.lines_used <= 6
    assert tracked and rec.ok and rec.lines_used == 6
    assert np.array_equal(rec.spokes[2:], np.arange(2, 8)) and np.all(rec.spokes[:2] == -1)
