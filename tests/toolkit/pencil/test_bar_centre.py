"""Bar midlines moved onto the printed centre lines (toolkit/pencil/bar_centre.py), and the
sigmas of fans of bars found on renders: a Monte Carlo over rendered tilt sweeps that
fails when the reported tilt, normal or vertex sigmas do not hold (issue 14 item 3)."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import binom

from pencilcal.toolkit.camera.model import Camera
from pencilcal.toolkit.detect.lines import detect_frame_lines
from pencilcal.toolkit.detect.pairs import pair_geometry
from pencilcal.toolkit.pencil.bar_centre import centre_lines, centre_offsets
from pencilcal.toolkit.pencil.estimator import pencil_covariance
from pencilcal.toolkit.pencil.orient import orient_segments
from pencilcal.toolkit.pencil.sequence_noise import sequence_noise
from pencilcal.toolkit.synth.scenarios import make_scenario
from pencilcal.toolkit.synth.sheet import layout_sheet

CHI2_2_68 = -2.0 * np.log(1.0 - 0.6827)  # 68.27 % quantile of chi-square(2), 2.30


def _model_bar(K, n, X1, X2, half):
    """A bar's centre line X1 -> X2 on the plane of unit normal n (camera frame) and its two
    edges at +-half across it: (centre (4,), edge a (4,), edge b reversed (4,)) in px."""
    e = np.cross(n, X2 - X1)
    e /= np.linalg.norm(e)

    def px(X):
        x = K @ X
        return x[:2] / x[2]

    c = np.r_[px(X1), px(X2)]
    a = np.r_[px(X1 + half * e), px(X2 + half * e)]
    b = np.r_[px(X2 - half * e), px(X1 - half * e)]
    return c, a, b


def test_centre_lines_are_exact_on_a_model_bar():
    """The bisector of a bar's exact edges, moved by centre_lines, lies on the image of the
    bar's centre line (to ~4e-6 px), whatever the sign of the
    normal; the shift itself is w^2 / (4 V) towards the horizon, here 0.02-0.1 px."""
    K = np.array([[900.0, 0, 640.0], [0, 900.0, 360.0], [0, 0, 1]])
    cam = Camera("pinhole", 1280, 720, K)
    shifts = []
    for tilt in (30.0, 55.0, 70.0):
        g = np.radians(tilt)
        n = np.array([0.0, -np.sin(g), np.cos(g)])  # the plane n . X = 400 n_z, through (0, 0, 400)
        X0 = np.array([5.0, -20.0, 0.0])
        X0[2] = (400.0 * n[2] - n[:2] @ X0[:2]) / n[2]
        for phi in np.radians([0.0, 25.0, 60.0, 100.0, 150.0]):
            u = np.cross(n, [np.sin(phi), np.cos(phi), 0.0])
            u /= np.linalg.norm(u)
            c, a, b = _model_bar(K, n, X0 + 15.0 * u, X0 + 80.0 * u, 2.0)
            pr = pair_geometry(np.stack([a, b]), [0], [1])
            ends = np.array([pr.a_lo[0], pr.a_hi[0]])
            mid = pr.point(ends).reshape(1, 4)  # the bisector, as detect.bars forms the midline
            w = pr.width_at(np.array([ends.mean()]))
            t = (c[2:] - c[:2]) / np.linalg.norm(c[2:] - c[:2])
            nrm = np.array([-t[1], t[0]])
            for sign in (1.0, -1.0):
                fixed = centre_lines(cam, mid, w, sign * n)[0]
                off = [(fixed[:2] - c[:2]) @ nrm, (fixed[2:] - c[:2]) @ nrm]
                assert np.max(np.abs(off)) < 1e-5, (tilt, phi, off)
            shifts.append(np.abs(centre_offsets(K, mid, w, n)).max())
    assert 0.02 < max(shifts) < 0.2
    # a bar with no width, or over the horizon, is left as it is
    seg = np.array([[600.0, 300.0, 700.0, 320.0], [600.0, 300.0, 700.0, 320.0]])
    out = centre_lines(cam, seg, [np.nan, 0.0], n)
    assert np.array_equal(out, seg)


def _sweep_frames(sheet, axes, tilts, size, noise, blur, seed0=0, light=False):
    """Rendered frames of tilt sweeps (one per axis) at `tilts` [deg], with their truth."""
    out = []
    n = len(tilts) + 1
    for k, axis in enumerate(axes):
        sc = make_scenario("tilt-sweep", n, seed=seed0 + k, sheet=sheet, size=size, axis_deg=axis,
                           max_tilt_deg=tilts[-1])
        for i in range(1, n):  # frame 0 is frontal
            img = sc.render(i, noise=noise, blur_px=blur)
            out.append((sc.camera, 255 - img if light else img, sc.frames[i]))
    return out


def _oriented(frames, pencil, polarity="dark"):
    """Each frame's orientation as `orient IMAGES` finds it (the spokes' midlines, their own
    sigmas, the sequence's inflate-only factor): (records, factor, each frame's lines)."""
    recs, found = [], []
    for cam, img, fr in frames:
        lines = detect_frame_lines(fr["image"], img, cam, bars=True, bar_polarity=polarity)
        found.append(lines)
        recs.append(orient_segments(cam, lines.segments, pencil, angle_sigma=np.radians(lines.angle_sigma_deg),
                                    offset_sigma=lines.offset_sigma_px, bar_width_px=lines.width_px,
                                    keep_lines=True))
    scaled, est = sequence_noise(recs, inflate_only=True)
    return scaled, 1.0 if est is None else est.variance_factor, found


def _coverage(frames, pencil, recs, factor):
    """(tilt, normal, vertex) coverage of the 68 % regions, and the tilt z values."""
    tz, nc, vc = [], [], []
    for (cam, img, fr), r in zip(frames, recs):
        assert r.ok, r.error
        tz.append((r.tilt_deg - fr["tilt_deg"]) / r.tilt_sigma_deg)
        R = np.asarray(fr["R_cam_from_target"])
        n_true = R[:, 2]
        # the closer twin (the twin choice is tested elsewhere) and its covariance
        Rc = min((np.asarray(r.R_cam_from_target), np.asarray(r.R_cam_from_target_twin)),
                 key=lambda M: -abs(M[:, 2] @ n_true))
        L = r.lines
        cov, _, _ = pencil_covariance(Rc, L["vertex"], pencil.angles[L["spoke"]], L["sigma"], L["vertex_cov"])
        n = Rc[:, 2]
        X = np.array([[0, -n[2], n[1]], [n[2], 0, -n[0]], [-n[1], n[0], 0]])
        b1 = np.cross(n, [1.0, 0, 0])
        b1 /= np.linalg.norm(b1)
        B = np.stack([b1, np.cross(n, b1)])
        e = B @ (n_true * np.sign(n_true @ n) - n)
        nc.append(e @ np.linalg.solve(B @ X @ cov @ X.T @ B.T * factor, e))
        dv = np.asarray(r.vertex_px) - np.asarray(fr["vertex_px"])
        vc.append(dv @ np.linalg.solve(np.asarray(r.vertex_cov_px2), dv))
    tz, nc, vc = map(np.asarray, (tz, nc, vc))
    return np.mean(np.abs(tz) <= 1.0), np.mean(nc <= CHI2_2_68), np.mean(vc <= CHI2_2_68), tz


def _band(n, level=0.99):
    """The binomial band of a coverage over n frames when the sigmas are right."""
    return binom.ppf((1 - level) / 2, n, 0.6827) / n, binom.ppf((1 + level) / 2, n, 0.6827) / n


@pytest.mark.slow
def test_thin_printed_lines_sigmas_hold_on_renders():
    """Issue 12's fan: 9 printed lines 1.2 mm wide (~3 px) at 1280x720, low noise (the
    0.001-0.01 deg regime of issue 14): over 30 frames of 5 tilt sweeps the tilt, the
    normal (chi-square, 2 dof) and the vertex fall inside their 68 % regions within the
    binomial band (99 %), and |error| / sigma has an RMS near 1. Sigmas 4-8 times too
    small would cover ~15-25 %. Measured over 132 frames (docs/uncertainty.md): tilt 73 %,
    normal 66 %, vertex 68 %, RMS z 0.93."""
    sheet = layout_sheet(spokes=9, width=1.2)
    frames = _sweep_frames(sheet, axes=(10.0, 45.0, 80.0, 115.0, 150.0), tilts=np.linspace(12.0, 72.0, 6),
                           size=(1280, 720), noise=2.0, blur=0.6, seed0=40)
    recs, factor, _ = _oriented(frames, sheet.pencil)
    tilt, normal, vertex, tz = _coverage(frames, sheet.pencil, recs, factor)
    lo, hi = _band(len(frames))
    assert lo <= tilt <= hi and lo <= normal <= hi and lo <= vertex <= hi, (tilt, normal, vertex, (lo, hi))
    assert 0.6 < np.sqrt(np.mean(tz**2)) < 1.5


def _towards_horizon(cam, fr, pencil, segments, spokes):
    """Offsets [px] of the segments' midpoints (labelled spokes) from the true centre lines,
    positive towards the plane's horizon."""
    R, t, K = np.asarray(fr["R_cam_from_target"]), np.asarray(fr["t_cam_from_target"]), np.asarray(cam.K)
    horizon = np.linalg.inv(K).T @ R[:, 2]  # horizon . (x, y, 1) = 0
    ideal = cam.undistort_pixels(np.asarray(segments).reshape(-1, 2)).reshape(-1, 4)
    out = []
    for k in np.flatnonzero(spokes >= 0):
        th = pencil.angles[spokes[k]]
        P = np.array([[pencil.vertex[0] + q * np.cos(th), pencil.vertex[1] + q * np.sin(th), 0.0]
                      for q in pencil.radius]) @ R.T + t
        x = P @ K.T
        a, b = x[0, :2] / x[0, 2], x[1, :2] / x[1, 2]
        u = (b - a) / np.linalg.norm(b - a)
        nrm = np.array([-u[1], u[0]])
        c = 0.5 * (a + b)
        # + towards the horizon: where horizon . (x, y, 1) moves towards 0
        side = -np.sign(horizon[:2] @ nrm) * np.sign(horizon @ np.r_[c, 1.0])
        out.append((0.5 * (ideal[k, :2] + ideal[k, 2:]) - a) @ nrm * side)
    return out


@pytest.mark.slow
def test_thick_bars_vertex_holds_on_their_centre_lines():
    """4 mm bars (~10 px) at low noise: the bisector of a bar's edges sits w^2 / (4 V) off its
    centre line, away from the horizon (0.01-0.04 px, several offset sigmas), which pulls
    the vertex. orient_segments with bar_width_px fits the centre lines instead: the mean
    offset falls to a fifth (measured -0.011 -> -0.002 px here) and the vertex's chi-square
    (2 dof) is within its 68 % region as often as it should be (measured on 132 frames:
    20 % -> 68 %; here 20 % -> 70 % of 10 frames)."""
    sheet = layout_sheet(spokes=9, width=4.0, radius=(35.0, 90.0))
    frames = _sweep_frames(sheet, axes=(20.0, 100.0), tilts=np.linspace(30.0, 70.0, 5), size=(1280, 720),
                           noise=2.0, blur=0.6, seed0=60)
    recs, factor, found = _oriented(frames, sheet.pencil)
    tilt, normal, vertex, tz = _coverage(frames, sheet.pencil, recs, factor)
    lo, _ = _band(len(frames))
    assert vertex >= lo, vertex
    assert abs(np.mean(tz)) < 0.6  # the bias of the bisectors read as tilt, gone
    before, after = [], []
    for (cam, img, fr), r, lines in zip(frames, recs, found):
        before += _towards_horizon(cam, fr, sheet.pencil, lines.segments, r.spokes)
        moved = centre_lines(cam, lines.segments, lines.width_px, r.normal)
        after += _towards_horizon(cam, fr, sheet.pencil, moved, r.spokes)
    assert len(before) >= 80 and np.mean(before) < -0.005
    assert abs(np.mean(after)) < 0.35 * abs(np.mean(before)), (np.mean(before), np.mean(after))
