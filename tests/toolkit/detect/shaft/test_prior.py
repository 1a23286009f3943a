"""The pencil as a prior (shaft/prior.py, shaft/pencil_search.py, detect_shafts(axis_prior=)).

- the gate's chi2 is chi2(1) for lines through a noisy point (Monte Carlo, a finite point
  and one at infinity);
- the prior from a fulcrum ray, a point, a fulcrum file; at most one shaft per prior;
- on rendered pivot sequences as hard as real frames (tests/toolkit/detect/shaft/
  pivot_frames.py: colour, tissue with pale folds, blur, noise, JPEG, the camera moved
  twice): the epochs found from the frames, and the shaft found through each epoch's
  prior in >= 95 % of the frames with <= 0.05 false shafts a frame.
"""
from __future__ import annotations

import json

import numpy as np
import pytest

from pencilcal.toolkit.camera.model import Camera
from pencilcal.toolkit.detect.shaft.prior import (AXIS_GATE, AxisPrior, epoch_priors, fulcrum_prior, line_chi2,
                                                  prior_record, read_priors, select_through)
from pencilcal.toolkit.errors import InputError


def _line_through(p, angle):
    """The unit line (3,) through p (2,) with direction angle [rad]."""
    d = np.array([np.cos(angle), np.sin(angle)])
    n = np.array([-d[1], d[0]])
    return np.r_[n, -n @ p]


@pytest.mark.parametrize("at_infinity", [False, True])
def test_line_chi2_is_chi2_of_one_dof(at_infinity):
    """Lines through the true point, measured with angle and offset noise about their
    centre, against a prior point drawn from its own covariance: the mean chi2 is 1 and
    the gate at 0.999 passes all but about one in a thousand."""
    rng = np.random.default_rng(0)
    sa, so = np.radians(0.4), 1.5
    cov_l = np.diag([sa**2, so**2])
    if at_infinity:
        X = np.array([1.0, 0.2, 0.0]) / np.hypot(1.0, 0.2)
        t = np.array([-X[1], X[0], 0.0])
        C = 1e-5 * np.outer(t, t)  # the direction's variance [rad^2]
    else:
        xy = np.array([-900.0, 300.0])
        prior = AxisPrior.from_point(xy, np.array([[400.0, 100.0], [100.0, 64.0]]))
        X, C = prior.point, prior.cov
    chi = []
    for _ in range(3000):
        # the true point: the prior's, moved by its own noise (in the tangent plane)
        w, V = np.linalg.eigh(C)
        Xt = X + V @ (np.sqrt(np.maximum(w, 0)) * rng.standard_normal(3))
        c = np.array([300.0, 250.0]) + rng.uniform(-100, 100, 2)
        # the line through the true point and c, then its measurement
        if abs(Xt[2]) > 1e-12:
            p = Xt[:2] / Xt[2]
            ang = np.arctan2(*(c - p)[::-1])
        else:
            ang = np.arctan2(Xt[1], Xt[0])
        ang_m = ang + sa * rng.standard_normal()
        cm = c + so * rng.standard_normal() * np.array([-np.sin(ang_m), np.cos(ang_m)])
        chi.append(line_chi2(AxisPrior(X, C), _line_through(cm, ang_m), cm, cov_l))
    chi = np.array(chi)
    assert 0.9 < chi.mean() < 1.1
    assert np.mean(chi > AXIS_GATE) < 0.004


def test_prior_from_ray_is_the_point():
    """A finite fulcrum's ray and its covariance give the prior of its ideal pixel: the same
    chi2 for any line."""
    cam = Camera("pinhole", 960, 540, [[800.0, 0, 480], [0, 800.0, 270], [0, 0, 1]])
    xy = np.array([1500.0, -200.0])
    cov = np.array([[900.0, 200.0], [200.0, 300.0]])
    by_point = AxisPrior.from_point(xy, cov)
    r = np.r_[(xy - [480, 270]) / 800.0, 1.0]
    n = np.linalg.norm(r)
    J = (np.eye(3) - np.outer(r, r) / n**2)[:, :2] / n / 800.0
    by_ray = AxisPrior.from_ray(cam.K, r / n, J @ cov @ J.T)
    for ang in (0.1, 0.7, 2.0):
        line = _line_through(np.array([400.0, 300.0]), ang)
        cl = np.diag([1e-5, 2.0])
        assert line_chi2(by_ray, line, [400.0, 300.0], cl) == pytest.approx(line_chi2(by_point, line, [400, 300], cl),
                                                                             rel=1e-6)


def test_bad_priors():
    with pytest.raises(InputError, match="homogeneous"):
        AxisPrior(np.zeros(3), np.eye(3))
    with pytest.raises(InputError, match="widths"):
        AxisPrior(np.array([1.0, 0, 1]), np.eye(3) * 1e-6, widths=(30, 10))


class _S:
    """A stand-in shaft: ideal_midline, cov, score."""

    def __init__(self, p, q, score):
        self.ideal_midline = np.r_[p, q]
        self.cov = np.diag([np.radians(0.3) ** 2, 1.0])
        self.score = score


def test_one_shaft_per_prior_the_best_through_it():
    """Two instruments' priors; a tissue band with the best score passes through neither."""
    A = AxisPrior.from_point([-500.0, 100.0], np.eye(2) * 25)
    B = AxisPrior.from_point([1500.0, 600.0], np.eye(2) * 25)
    band = _S([0.0, 500.0], [900.0, 420.0], 900.0)
    a1, a2 = _S([100.0, 160.0], [600.0, 210.0], 300.0), _S([100.0, 220.0], [600.0, 320.0], 200.0)
    b1 = _S([1000.0, 500.0], [400.0, 380.0], 250.0)
    got = select_through([band, a2, a1, b1], [A, B])
    assert got == [a1, b1]
    assert select_through([band], [A]) == []


def _lines_frames(segs_per_frame):
    return [{"image": f"{k:03d}.png", "ok": True, "segments": np.zeros((0, 4)),
             "shafts": [{"midline": list(map(float, s)), "angle_sigma_deg": 0.3, "width_px": 40.0} for s in segs]}
            for k, segs in enumerate(segs_per_frame)]


def test_fulcrum_prior_ignores_a_static_band():
    """Eight frames of a shaft pivoting about (-400, 200), and a band of tissue found in six
    of them at the same place: the prior is the fulcrum, within its sd, not a point on the
    band."""
    rng = np.random.default_rng(2)
    cam = Camera("pinhole", 960, 540, [[800.0, 0, 480], [0, 800.0, 270], [0, 0, 1]])
    v = np.array([-400.0, 200.0])
    per = []
    for k in range(8):
        a = np.radians(-10 + 3 * k + 0.3 * rng.standard_normal())
        d = np.array([np.cos(a), np.sin(a)])
        segs = [np.r_[v + 800 * d, v + 1300 * d]]
        if k < 6:
            segs.append(np.array([500.0, 100.0, 900.0, 480.0]) + rng.normal(0, 0.3, 4))
        per.append(segs)
    p = fulcrum_prior(cam, _lines_frames(per))
    x = p.point[:2] / p.point[2]
    J = np.concatenate([np.eye(2), -x[:, None]], 1) / p.point[2]
    C = J @ p.cov @ J.T
    e = x - v
    assert float(e @ np.linalg.solve(C, e)) < 9.0
    assert p.widths == (40.0, 40.0)


def test_read_priors(tmp_path):
    """A fulcrum.json's axis_prior, each epoch's for its images; ray and ray_cov; vertex_px
    and its covariance (raw px); a file without one is an error naming it."""
    cam = Camera("opencv", 960, 540, [[800.0, 0, 480], [0, 800.0, 270], [0, 0, 1]], [-0.1, 0.01, 0, 0])
    a = AxisPrior.from_point([-300.0, 200.0], np.eye(2) * 16, widths=(30.0, 40.0))
    b = AxisPrior.from_point([1300.0, 200.0], np.eye(2) * 16)
    doc = {"axis_prior": prior_record(a), "ray": [0, 0, 1.0], "ray_cov": np.eye(3).tolist(),
           "epochs": [{"images": ["000.png", "001.png"], "axis_prior": prior_record(a)},
                      {"images": ["002.png"], "axis_prior": prior_record(b)}]}
    (tmp_path / "f.json").write_text(json.dumps(doc))
    default, by_image = read_priors(tmp_path / "f.json", cam)
    assert np.allclose(default.point, a.point) and default.widths == (30.0, 40.0)
    assert np.allclose(by_image["002.png"].point, b.point) and set(by_image) == {"000.png", "001.png", "002.png"}
    ray = np.r_[(np.array([-300.0, 200.0]) - [480, 270]) / 800.0, 1.0]
    (tmp_path / "r.yaml").write_text(f"ray: {(ray / np.linalg.norm(ray)).tolist()}\nray_cov: {(np.eye(3) * 1e-6).tolist()}\n")
    p, _ = read_priors(tmp_path / "r.yaml", cam)
    assert np.allclose(p.point, a.point, atol=1e-9)
    (tmp_path / "v.json").write_text(json.dumps({"vertex_px": [300.0, 200.0], "vertex_cov_px2": np.eye(2).tolist()}))
    p, _ = read_priors(tmp_path / "v.json", cam)
    ideal = cam.undistort_pixels(np.array([[300.0, 200.0]]))[0]
    assert np.allclose(p.point[:2] / p.point[2], ideal)
    (tmp_path / "n.json").write_text(json.dumps({"vertex_px": [1, 2]}))
    with pytest.raises(InputError, match="n.json: no fulcrum prior"):
        read_priors(tmp_path / "n.json", cam)
    (tmp_path / "l.json").write_text("[1, 2]")
    with pytest.raises(InputError, match="l.json"):
        read_priors(tmp_path / "l.json", cam)


@pytest.mark.slow
def test_rendered_pivots_epochs_and_the_prior():
    """Four rendered sequences of 30 frames (pivot_frames.py; the camera turned by 3 deg
    after frames 9 and 19): a first detection without a prior, its epochs
    (`pencil.epochs.frame_epochs`) and their priors (`shaft.prior.epoch_priors`), then every
    frame through its prior. Measured: without the prior 120 of 120 shafts found, 4 false
    (87 before an edge the fixed corridor misses was searched again in a wider one,
    `shaft.material_cue._band_edges`); with the prior 119 of 120, none false, every frame
    searched through the whole sequence's prior first and its epoch's where that finds
    nothing (seed 2 loses one; 116, none false, through each frame's epoch's prior alone,
    seeds 2 and 3 losing 2 frames each; 120 before the wider corridor; with every frame's line in, seed 2's first
    epoch ended at frame 9 and seed 3's second at 17, 1 and 3 frames off the camera's
    moves, and those seeds lost 1 and 3 frames through the prior). The epochs, from the first detection and
    from the shafts found through the prior: as many as the camera's, each change within 5
    frames of its move in all four (exact in 2 and 3 of 4: where the frames' lines run along
    the fulcrum's move, they pass near either point, and the change may fall anywhere among
    them)."""
    from pencilcal.toolkit.detect.shaft.detector import detect_shafts, detect_through
    from pencilcal.toolkit.pencil.epochs import frame_epochs
    from tests.toolkit.detect.shaft.pivot_frames import lines_frames, pivot_frames, score

    def near(got, truth):
        return len(got) == len(truth) and all(abs(g[0] - t[0]) <= 5 for g, t in zip(got, truth))

    total = found0 = false0 = found = false = close = 0
    for seed in range(4):
        sc, imgs = pivot_frames(seed)
        cam = sc.camera
        truth = [(e["first"], e["last"] + 1) for e in sc.extra["epochs"]]
        first = [detect_shafts(im, cam) for im in imgs]
        f0, fa0 = score(sc, first)
        frames = lines_frames(sc, first)
        bounds = frame_epochs(cam, frames).bounds
        priors = epoch_priors(cam, frames, bounds)
        through = [detect_through(im, cam, priors[fr["image"]]) for fr, im in zip(sc.frames, imgs)]
        f1, fa1 = score(sc, through)
        got = frame_epochs(cam, lines_frames(sc, through)).bounds
        print(f"seed {seed}: without the prior {f0} found, {fa0} false, epochs {bounds}; with it {f1}, {fa1}, "
              f"epochs {got}")
        total += len(imgs)
        found0, false0, found, false = found0 + f0, false0 + fa0, found + f1, false + fa1
        close += near(bounds, truth) + near(got, truth)
        assert all(len(s) <= 1 for s in through)
    assert found >= 0.95 * total
    assert false <= 0.05 * total
    assert found0 >= 0.95 * total
    assert close >= 7


def _parallel_frames(rng, n, angle_deg=30.0, at=(480.0, 270.0)):
    """n frames of a shaft sliding across the view at one angle (its sd 0.3 deg, as the
    lines' `_lines_frames` state): lines that meet at no finite point better than at
    infinity."""
    per = []
    for k in range(n):
        a = np.radians(angle_deg + 0.3 * rng.standard_normal())
        d = np.array([np.cos(a), np.sin(a)])
        c = np.asarray(at) + np.array([-d[1], d[0]]) * (30.0 * k - 15.0 * n)
        per.append([np.r_[c - 250 * d, c + 250 * d]])
    return per


def test_fulcrum_prior_at_infinity():
    """Lines that a point at infinity fits better than the robust finite fit (a shaft sliding
    across the view at one angle) give a prior at infinity, their common direction, not None:
    the next frame's line along that direction passes its gate, one 10 deg off does not."""
    rng = np.random.default_rng(0)
    cam = Camera("pinhole", 960, 540, [[800.0, 0, 480], [0, 800.0, 270], [0, 0, 1]])
    per = _parallel_frames(rng, 6)
    p = fulcrum_prior(cam, _lines_frames(per))
    assert p is not None and abs(p.point[2]) < 1e-12
    u = np.degrees(np.arctan2(p.point[1], p.point[0])) % 180.0
    assert abs(u - 30.0) < 1.5
    cov = np.diag([np.radians(0.3) ** 2, 1.0])
    assert line_chi2(p, _line_through([480.0, 270.0], np.radians(30.5)), [480.0, 270.0], cov) < AXIS_GATE
    assert line_chi2(p, _line_through([480.0, 270.0], np.radians(40.0)), [480.0, 270.0], cov) > AXIS_GATE


def test_every_epoch_gets_a_prior():
    """Two epochs: a shaft pivoting about (-400, 200), then one that fixes no finite point
    (it slides across the view: its prior is at infinity), each frame searched through the
    whole sequence's prior, then its epoch's; and an epoch with too few lines for a point of
    its own (two frames with a shaft): it searches through the sequence's prior, not
    without any."""
    rng = np.random.default_rng(2)
    cam = Camera("pinhole", 960, 540, [[800.0, 0, 480], [0, 800.0, 270], [0, 0, 1]])
    v = np.array([-400.0, 200.0])
    a = np.radians(-10 + 3 * np.arange(8) + 0.3 * rng.standard_normal(8))
    d = np.stack([np.cos(a), np.sin(a)], -1)
    pivot = [[seg] for seg in np.concatenate([v + 800 * d, v + 1300 * d], -1)]
    frames = _lines_frames(pivot + _parallel_frames(np.random.default_rng(0), 6))
    pri = epoch_priors(cam, frames, [(0, 8), (8, 14)])
    assert all(len(pri[f["image"]]) >= 1 and pri[f["image"]][0] is not None for f in frames)
    assert any(abs(p.point[2]) > 1e-6 for p in pri[frames[0]["image"]])
    assert any(abs(p.point[2]) < 1e-12 for p in pri[frames[-1]["image"]])
    few = _lines_frames(pivot + [[] for _ in range(4)] + [pivot[2], pivot[5]])
    pri = epoch_priors(cam, few, [(0, 8), (8, 14)])
    whole = fulcrum_prior(cam, few)
    last = pri[few[-1]["image"]]
    assert whole is not None and len(last) == 1 and last[0] is not None
    assert np.allclose(last[0].point, whole.point) and np.allclose(last[0].cov, whole.cov)


def test_prior_chi2():
    """Two priors' points differ by their chi-square (2 dof): 0 for one point (and for its
    negative, the same homogeneous point), about (d / sigma)^2 for a finite point moved d."""
    from pencilcal.toolkit.detect.shaft.prior import prior_chi2

    p = AxisPrior.from_point([300.0, -800.0], np.diag([100.0, 400.0]))
    assert prior_chi2(p, p) < 1e-9
    assert prior_chi2(AxisPrior(-p.point, p.cov), p) < 1e-9
    q = AxisPrior.from_point([300.0 + 5 * np.sqrt(200.0), -800.0], np.diag([100.0, 400.0]))
    assert abs(prior_chi2(q, p) - 25.0) < 0.5


@pytest.mark.parametrize("widths_seen", [2.0, 3.0])
def test_a_shaft_entering_through_a_port_in_view(widths_seen):
    """An instrument whose port is in view enters the view there, not at its border: a
    converging dark band from the port's image, 2 or 3 widths long, a bright wrist
    beyond it, over rendered tissue (`synth.tissue`: folds, fat; uneven light, blur,
    noise). Without the prior it is no shaft (it
    starts inside the view); through the prior at the port it is found, its axis through the
    port within 1 deg and 2 px. Measured: not found through the prior before a band from the
    prior's point counted as entering the view (`shaft.pencil_search._ends_at`)."""
    import cv2

    from pencilcal.toolkit.detect.shaft.detector import detect_shafts

    from pencilcal.toolkit.synth.render import sensor_image
    from pencilcal.toolkit.synth.tissue import tissue_image

    H, W = 480, 640
    img = np.array(tissue_image((H, W), seed=3)) * 0.7  # linear BGR
    port, u = np.array([260.0, 150.0]), np.array([-np.cos(0.6), np.sin(0.6)])
    n = np.array([-u[1], u[0]])
    w_far, w_near = 40.0, 52.0  # [px], wider towards the camera
    L = widths_seen * 0.5 * (w_far + w_near)
    tip = port + L * u
    band = np.array([port + 0.5 * w_far * n, tip + 0.5 * w_near * n, tip - 0.5 * w_near * n,
                     port - 0.5 * w_far * n])
    cv2.fillConvexPoly(img, np.round(band).astype(np.int32), (0.03, 0.03, 0.035))
    wrist = np.array([tip + 0.3 * w_near * n, tip + 0.3 * w_near * n + 40 * u, tip - 0.3 * w_near * n + 40 * u,
                      tip - 0.3 * w_near * n])
    cv2.fillConvexPoly(img, np.round(wrist).astype(np.int32), (0.6, 0.6, 0.62))
    img = sensor_image(img, 0.2, 1.0, 1.2, 2.2, 2.5, np.random.default_rng(5))
    assert not detect_shafts(img)
    got = detect_shafts(img, axis_prior=AxisPrior.from_point(port, np.eye(2) * 4.0))
    assert len(got) == 1
    m = np.asarray(got[0].midline, float).reshape(2, 2)
    d = (m[1] - m[0]) / np.linalg.norm(m[1] - m[0])
    assert np.degrees(np.arccos(min(1.0, abs(float(d @ u))))) < 1.0
    assert abs(float((port - m[0]) @ np.array([-d[1], d[0]]))) < 2.0


def _tissue_frame(seed):
    """(H, W) = (480, 640) linear BGR tissue (`synth.tissue`: folds, fat, uneven light)."""
    from pencilcal.toolkit.synth.tissue import tissue_image

    return np.array(tissue_image((480, 640), seed=seed)) * 0.7


def _quad(a, b, wa, wb, n):
    """The corners (4, 2) int32 of a band from a to b (2,), wa wide at a and wb at b, n its unit normal."""
    return np.round(np.array([a + 0.5 * wa * n, b + 0.5 * wb * n, b - 0.5 * wb * n, a - 0.5 * wa * n])).astype(np.int32)


def _found_through(got, port, u):
    """Whether the one shaft found lies within 1 deg and 3 px of the line through port (2,) along u (2,)."""
    if len(got) != 1:
        return False
    m = np.asarray(got[0].midline, float).reshape(2, 2)
    d = (m[1] - m[0]) / np.linalg.norm(m[1] - m[0])
    return bool(np.degrees(np.arccos(min(1.0, abs(float(d @ u))))) < 1.0
                and abs(float((m.mean(0) - port) @ np.array([-u[1], u[0]]))) < 3.0)


def test_a_close_shaft_seen_shorter_than_its_width():
    """An instrument close to the camera, its port beyond the view: the border cuts its shaft
    to 0.7 of its width (a dark band 110-120 px wide, 80 px seen), a bright tip beyond it,
    over rendered tissue with blur, noise and uneven light. Through the port's image it is
    found, its axis through the port within 1 deg and 3 px. Measured: not found before a
    band through the prior's point needed only half its width of length (1.5 widths)."""
    import cv2

    from pencilcal.toolkit.detect.shaft.detector import detect_shafts
    from pencilcal.toolkit.synth.render import sensor_image

    img = _tissue_frame(4)
    port, u = np.array([900.0, 380.0]), np.array([-1.0, -0.12]) / np.hypot(1.0, 0.12)
    n = np.array([-u[1], u[0]])
    a = port + ((port[0] - 660.0) / abs(u[0])) * u  # beyond the border
    b = port + ((port[0] - 560.0) / abs(u[0])) * u  # 80 px inside the border
    cv2.fillConvexPoly(img, _quad(a, b, 110.0, 120.0, n), (0.05, 0.05, 0.06))
    cv2.fillConvexPoly(img, _quad(b, b + 60 * u, 80.0, 84.0, n), (0.6, 0.6, 0.62))
    img = sensor_image(img, 0.2, 1.0, 1.2, 2.2, 2.5, np.random.default_rng(6))
    got = detect_shafts(img, axis_prior=AxisPrior.from_point(port, np.eye(2) * 4.0))
    assert _found_through(got, port, u)


def test_a_distal_part_joined_to_the_border_by_its_shaft():
    """A bright tip 1.5 widths long, 60 px wide, and the grey shaft it sits on, a fifth wider,
    running from the tip's collar to the view's border over 50 px only, its port beyond the
    view, over rendered tissue: the tip's band stops at the collar, short of the border,
    and the shaft's stub, 0.7 of its width, is taken alone by the material cue, off the axis. Through the port's image it is
    found (the shaft's material joins it to the border), its axis within 1 deg and 3 px.
    Measured: not found before a band joined to the border along its line by instrument
    material counted as entering the view."""
    import cv2

    from pencilcal.toolkit.detect.shaft.detector import detect_shafts
    from pencilcal.toolkit.synth.render import sensor_image

    img = _tissue_frame(5)
    port, u = np.array([560.0, 760.0]), np.array([-0.35, -1.0]) / np.hypot(0.35, 1.0)
    n = np.array([-u[1], u[0]])
    a = port + ((port[1] - 500.0) / abs(u[1])) * u  # beyond the border
    b = port + ((port[1] - 430.0) / abs(u[1])) * u  # 50 px inside it
    cv2.fillConvexPoly(img, _quad(a, b, 72.0, 72.0, n), (0.22, 0.22, 0.24))
    cv2.fillConvexPoly(img, _quad(b - 2 * u, b + 90 * u, 60.0, 60.0, n), (0.75, 0.75, 0.78))
    img = sensor_image(img, 0.2, 1.0, 1.2, 2.2, 2.5, np.random.default_rng(7))
    got = detect_shafts(img, axis_prior=AxisPrior.from_point(port, np.eye(2) * 4.0))
    assert _found_through(got, port, u)


def test_a_cone_from_a_port_in_view_with_a_long_bright_tip():
    """A shaft pointing at the camera from a port in view: a grey cone from the port (48 px
    wide there) widening to 110 px over 200 px (17 deg), and beyond it a bright tip 130 px
    long, wider still, on the same line through the port, over rendered tissue. The tip's
    constant width takes the vote by widths; the cone's width grows with the radius about the
    port while its angle stays. Through the port's image the cone is found, its axis within
    1 deg and 3 px. Measured: not found before the pairs also voted by their angle about the
    port (the tip's peak took the column)."""
    import cv2

    from pencilcal.toolkit.detect.shaft.detector import detect_shafts
    from pencilcal.toolkit.synth.render import sensor_image

    img = _tissue_frame(6)
    port, u = np.array([500.0, 190.0]), np.array([-np.cos(0.35), np.sin(0.35)])
    n = np.array([-u[1], u[0]])
    b = port + 200.0 * u
    cv2.fillConvexPoly(img, _quad(port, b, 48.0, 110.0, n), (0.3, 0.3, 0.32))
    cv2.circle(img, tuple(np.round(port).astype(int)), 24, (0.3, 0.3, 0.32), -1)
    cv2.fillConvexPoly(img, _quad(b + 4 * u, b + 130 * u, 115.0, 132.0, n), (0.95, 0.95, 0.98))
    img = sensor_image(img, 0.2, 1.0, 1.2, 2.2, 2.5, np.random.default_rng(8))
    got = detect_shafts(img, axis_prior=AxisPrior.from_point(port, np.eye(2) * 4.0))
    assert _found_through(got, port, u)


@pytest.mark.parametrize("case", [
    # tissue seed, port (beyond the view), direction [deg], tip, width, stripe's offset and width, grey
    (3, (-273.0, -59.0), 30.8, (339.0, 306.0), 47.0, 11.0, 21.0, 0.14),
    (17, (-46.0, 725.0), 304.2, (312.0, 198.0), 49.0, -11.0, 23.0, 0.12),
])
def test_the_outermost_pair_of_a_striped_shaft(case):
    """A dark grey shaft with a bright highlight stripe along it (a fifth of its width off its
    axis, reaching to 2 px of one edge), a bright tip beyond, its port beyond the view, over
    rendered tissue: through the port's image the shaft is found, not the grey part beside the
    stripe (a band between the tissue and the stripe, darker than both), its axis within 1 deg
    and 3 px. Measured: the grey part (23-24 px wide) was taken before the search preferred
    the outermost pair whose inside is one instrument (`pencil_search._outermost`)."""
    import cv2

    from pencilcal.toolkit.detect.shaft.detector import detect_shafts
    from pencilcal.toolkit.synth.render import sensor_image

    seed, port, deg, tip, w, off, sw, grey = case
    port, tip = np.array(port), np.array(tip)
    u = np.array([np.cos(np.radians(deg)), np.sin(np.radians(deg))])
    n = np.array([-u[1], u[0]])
    img = _tissue_frame(seed)
    cv2.fillConvexPoly(img, _quad(port, tip, w, w, n), (grey, grey, 1.05 * grey))
    cv2.fillConvexPoly(img, _quad(port + off * n, tip + off * n, sw, sw, n), (0.85, 0.85, 0.88))
    cv2.fillConvexPoly(img, _quad(tip, tip + 60 * u, 0.7 * w, 0.7 * w, n), (0.6, 0.6, 0.62))
    img = sensor_image(img, 0.2, 1.0, 1.2, 2.2, 2.5, np.random.default_rng(seed + 100))
    got = detect_shafts(img, axis_prior=AxisPrior.from_point(port, np.eye(2) * 4.0))
    assert _found_through(got, port, u)
    assert abs(got[0].width_px - w) < 4.0
