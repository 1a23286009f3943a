"""The 3-D fulcrum from detected shafts (fulcrum.fulcrum_point), end to end.

- `test_edge_cov_carries_the_midline_covariance`: the detector's per-edge covariance
  (`shaft_axis.edge_covariance`, about each edge segment's centre) propagated through the
  plane bisector gives back the midline covariance the detector reports: the two are one
  error model, and the 3-D axis is propagated from the same one.
- `test_fulcrum_point_monte_carlo`: lines.json frames of a pivoting 8 mm shaft (1080p, f = 900
  px, fulcrum off the image) whose edges carry `edge_cov`, perturbed by noise drawn from that
  covariance: the 3-D point's RMSE over its Cramer-Rao bound (the point covariance of the
  exact axes) is at most 1.2, and 60-76 % of the points fall in their own point_cov's 68 %
  region (chi2, 3 dof); `test_fulcrum_point_takes_the_axes_scatter`: with edges 1.5 times
  noisier than stated the covariance takes the axes' variance factor.
- `test_target_rendered_port_view`: the issue's target on rendered frames (simulate's pivot
  scenario in its port view: 1080p, 8 mm shaft 80-125 mm from the camera, 30 frames, the
  fulcrum above the image): 3-D point error <= 1 mm, median axis direction error <= 0.3 deg.
  Rendered at simulate's gamma 2.2 (detected with the default gamma 2.2), and linear (gamma
  1, detected with gamma=1). On the encoded levels the gradient peaks of the shaft's blurred
  edges lean towards its dark inside: the band came out ~0.6 % narrow, every axis as far too,
  and the point missed by 1.5 mm (its sigma 1.3 mm); located on linearised levels the point
  is within 0.15 mm, the median direction error 0.04 deg (docs/method.md). A pinhole camera:
  the edge cue misses shafts the default camera's distortion bends at the image corners.
"""
from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import chi2

from pencilcal.toolkit.camera.model import Camera
from pencilcal.toolkit.detect.shaft.axis import plane_bisector
from pencilcal.toolkit.detect.shaft.detector import detect_shafts
from pencilcal.toolkit.geometry.frames import angle_between
from pencilcal.toolkit.pencil.cylinder import fulcrum_3d, project_cylinder, shaft_axis, shaft_axis_record
from pencilcal.toolkit.pencil.fulcrum import fulcrum_from_frames, fulcrum_point
from pencilcal.toolkit.pencil.vertex import segment_lines
from tests.toolkit.detect.shaft.test_detector import render_shaft, shaft_from
from tests.toolkit.pencil.test_cylinder import FULCRUM, HEIGHT, K, RADIUS, WIDTH, pivot_frames

Q68_3 = chi2.ppf(0.68, 3)


def _lines_px(edges, d_phi=np.zeros(2), d_c=np.zeros(2)):
    """Homogeneous pixel lines (2, 3) of edges (2, 4) turned by d_phi about their centres and
    shifted by d_c along their normals (the edge_cov convention)."""
    seg = segment_lines(edges)
    phi = np.arctan2(seg.direction[:, 1], seg.direction[:, 0]) + d_phi
    nu = np.stack([-np.sin(phi), np.cos(phi)], -1)
    return np.concatenate([nu, (-np.sum(nu * seg.centre, -1) - d_c)[:, None]], -1)


def test_edge_cov_carries_the_midline_covariance():
    cam = Camera("opencv", 640, 480, [[420.0, 0, 319.5], [0, 420.0, 239.5], [0, 0, 1]], [-0.25, 0.07, 0, 0, 0])
    img = render_shaft(cam, [shaft_from([-30.0, 14.0, 22.0], [2.0, -4.0, 85.0])], np.random.default_rng(1))
    (s,) = detect_shafts(img, cam)
    Kc = np.asarray(cam.K, float)
    inside = np.mean(s.ideal_edges.reshape(2, 2, 2).mean(1), 0)
    ref = 0.5 * (s.ideal_midline[:2] + s.ideal_midline[2:])
    base = plane_bisector(Kc, *_lines_px(s.ideal_edges), inside)

    def angle_offset(q):
        la = plane_bisector(Kc, *_lines_px(s.ideal_edges, q[[0, 2]], q[[1, 3]]), inside)
        la = la if la[:2] @ base[:2] >= 0 else -la
        return np.array([np.arctan2(-la[0], la[1]), la[:2] @ ref + la[2]])

    J = np.stack([(angle_offset(h) - angle_offset(-h)) / 2e-5 for h in np.eye(4) * 1e-5], -1)
    C = np.zeros((4, 4))
    C[:2, :2], C[2:, 2:] = s.edge_cov
    cov = J @ C @ J.T
    assert s.edge_cov.shape == (2, 2, 2) and np.all(np.linalg.eigvalsh(s.edge_cov) > 0)
    assert np.allclose(cov, s.cov, rtol=0.02, atol=1e-12), (cov, s.cov)


def _pinhole():
    return Camera("pinhole", WIDTH, HEIGHT, K, [])


def _frames(segs, covs):
    return [{"image": f"{k:03d}.png", "ok": True, "segments": np.zeros((0, 4)),
             "shafts": [{"midline": [0.0, 0.0, 1.0, 1.0], "edges": segs[k].tolist(), "edge_cov": covs[k].tolist()}]}
            for k in range(len(segs))]


def _monte_carlo(noise, trials=150, seed=11):
    """(RMSE over the Cramer-Rao bound, coverage of point_cov's 68 % region, the variance
    factors) of `fulcrum_point` on the pivot's edges perturbed by `noise` times the noise
    their `edge_cov` states."""
    segs, _ = pivot_frames()
    length = np.linalg.norm(segs[..., 2:] - segs[..., :2], axis=-1)               # (30, 2)
    # a detector-like edge covariance: 0.3 px station noise over the edge, and a correlated
    # (angle, offset) term as an off-centre station centroid gives
    sa, so = 0.3 * np.sqrt(12.0 / 40.0) / length, np.full(length.shape, 0.3 / np.sqrt(40.0))
    covs = np.zeros(segs.shape[:2] + (2, 2))
    covs[..., 0, 0], covs[..., 1, 1] = sa**2, so**2
    covs[..., 0, 1] = covs[..., 1, 0] = 0.4 * sa * so
    cam = _pinhole()
    exact = shaft_axis(K, segs, RADIUS, edge_cov=covs)
    crlb = fulcrum_3d(exact.axis_point, exact.axis_direction, exact.axis_cov, robust=False).point_cov
    rng = np.random.default_rng(seed)
    L = noise * np.linalg.cholesky(covs)
    errs, m2, factors = [], [], []
    for _ in range(trials):
        z = np.einsum("nkij,nkj->nki", L, rng.normal(size=segs.shape[:2] + (2,)))  # (d_phi, d_c) per edge
        noisy = np.empty_like(segs)
        for n in range(len(segs)):
            lines = _lines_px(segs[n], z[n, :, 0], z[n, :, 1])
            seg = segment_lines(segs[n])
            # the refitted edge: the moved line over the same stretch (centre's foot, same length)
            c = seg.centre - (np.sum(lines[:, :2] * seg.centre, -1) + lines[:, 2])[:, None] * lines[:, :2]
            t = np.stack([lines[:, 1], -lines[:, 0]], -1) * np.sign(np.sum(np.stack([lines[:, 1], -lines[:, 0]], -1)
                                                                              * seg.direction, -1))[:, None]
            noisy[n] = np.concatenate([c - 0.5 * length[n, :, None] * t, c + 0.5 * length[n, :, None] * t], -1)
        pt = fulcrum_point(cam, _frames(noisy, covs), 2 * RADIUS)
        e = pt.fit.point - FULCRUM
        errs.append(e)
        m2.append(e @ np.linalg.solve(pt.fit.point_cov, e))
        factors.append(pt.variance_factor)
    errs, m2 = np.array(errs), np.array(m2)
    ratio = np.sqrt(np.mean(np.sum(errs**2, -1))) / np.sqrt(np.trace(crlb))
    return ratio, float(np.mean(m2 <= Q68_3)), np.array(factors)


def test_fulcrum_point_monte_carlo():
    ratio, coverage, factors = _monte_carlo(1.0)
    assert ratio <= 1.2, ratio
    assert 0.60 <= coverage <= 0.76, coverage
    assert np.median(factors) == 1.0 and np.all(factors >= 1.0)


def test_fulcrum_point_takes_the_axes_scatter():
    """Edges 1.5 times noisier than their edge_cov says (as the short shafts of real frames
    are): the point's covariance takes the used axes' chi2 per degree of freedom, the axes
    fitted again at that noise so that the gate does not truncate it. Measured (150 draws):
    the factor's median 1.89 (the true 2.25), 49 % of the points in their 68 % region, where
    the covariance without the factor held 22 % (33 % with the factor of the first fit
    alone, median 1.50: the gate at the stated noise left out the larger residuals)."""
    _, coverage, factors = _monte_carlo(1.5, trials=60, seed=3)
    assert 1.4 <= np.median(factors) <= 2.6, np.median(factors)
    assert coverage >= 0.4, coverage


def test_fulcrum_point_lens_cov_is_the_spread_the_intrinsics_cause():
    """The 3-D point's intrinsics term (`point_lens_cov`): exact edges seen through lenses
    drawn from the intrinsics' covariance (focal lengths 3 px, principal point 4 px, k1
    0.01) scatter the point as lens_cov says: the mean squared Mahalanobis distance near 3
    (3 dof) and the scatter's trace within 15 % of lens_cov's, and the totals add up."""
    from pencilcal.toolkit.camera.intrinsics import intrinsics_vector, with_intrinsics

    segs, _ = pivot_frames()
    length = np.linalg.norm(segs[..., 2:] - segs[..., :2], axis=-1)
    covs = np.zeros(segs.shape[:2] + (2, 2))
    covs[..., 0, 0], covs[..., 1, 1] = (0.3 * np.sqrt(12.0 / 40.0) / length) ** 2, 0.3**2 / 40.0
    cam = Camera("opencv", WIDTH, HEIGHT, K, [0.0, 0.0, 0.0, 0.0, 0.0])
    C = np.diag([9.0, 9.0, 16.0, 16.0, 1e-4, 0.0, 0.0, 0.0, 0.0])
    frames = _frames(segs, covs)
    pt = fulcrum_point(cam, frames, 2 * RADIUS, intrinsics_cov=C)
    assert pt.lens_cov is not None and np.all(np.linalg.eigvalsh(pt.lens_cov) > 0)
    rec = pt.to_dict()
    assert np.allclose(rec["point_cov_total"], np.asarray(rec["point_cov"]) + pt.lens_cov)
    assert rec["point_sigma_total"] > rec["point_sigma"]
    assert "point_cov_total" not in fulcrum_point(cam, frames, 2 * RADIUS).to_dict()
    rng = np.random.default_rng(5)
    th0 = intrinsics_vector(cam)
    pts = np.array([fulcrum_point(with_intrinsics(cam, rng.multivariate_normal(th0, C)), frames, 2 * RADIUS,
                                  robust=False).fit.point for _ in range(120)])
    d = pts - pt.fit.point
    m2 = np.einsum("ni,ij,nj->n", d, np.linalg.inv(pt.lens_cov), d)
    assert 2.4 <= np.mean(m2) <= 3.6, np.mean(m2)
    assert abs(np.trace(np.cov(d.T)) / np.trace(pt.lens_cov) - 1.0) < 0.15



def test_fulcrum_point_width_term_is_the_spread_a_shared_width_error_causes():
    """The 3-D point's term of a band-width error shared by the sequence (`point_width_cov`):
    exact edges with every band widened by the same pixels (up to 2 SD) move the point as
    the term says (the relative move per SD within 5 % of its relative sd), the term joins
    point_cov, and none is added at width_sd_px 0."""
    from pencilcal.toolkit.pencil.band_width import widen_bands

    SD = 1.8
    segs, _ = pivot_frames()
    length = np.linalg.norm(segs[..., 2:] - segs[..., :2], axis=-1)
    covs = np.zeros(segs.shape[:2] + (2, 2))
    covs[..., 0, 0], covs[..., 1, 1] = (0.3 * np.sqrt(12.0 / 40.0) / length) ** 2, 0.3**2 / 40.0
    cam = _pinhole()
    pt = fulcrum_point(cam, _frames(segs, covs), 2 * RADIUS, width_sd_px=SD)
    rec = pt.to_dict()
    X = np.asarray(pt.fit.point, float)
    assert np.allclose(rec["point_cov"], np.asarray(pt.fit.point_cov) + np.asarray(rec["point_cov_width"]))
    assert rec["point_sigma"] > float(pt.fit.point_sigma)
    bare = fulcrum_point(cam, _frames(segs, covs), 2 * RADIUS, width_sd_px=0.0).to_dict()
    assert bare["point_cov_width"] is None and np.allclose(bare["point_cov"], pt.fit.point_cov)
    eps = np.array([-2.0, -1.0, 1.0, 2.0]) * SD
    moved = [fulcrum_point(cam, _frames(widen_bands(segs, e), covs), 2 * RADIUS, robust=False).fit.point for e in eps]
    rel = [(q - X) @ X / (X @ X) for q in moved]
    # a band read wider puts the point nearer: its relative move per px of width, times the sd
    slope = np.polyfit(eps, rel, 1)[0]
    assert slope < 0 and abs(-slope * SD / rec["point_width_sd"] - 1.0) < 0.05, slope
    # the term lies along the move: what is left of the move off its direction is small
    g = np.asarray(rec["point_cov_width"])
    assert np.linalg.eigvalsh(g)[-1] == pytest.approx(np.trace(g))


def test_fulcrum_point_gives_each_band_the_width_sd_of_its_class():
    """By default each band's width sd is its class's (`band_width.band_width_sd`: edge
    model, polarity, width): the term is the move of the point when every band widens by its
    own sd, and limb-located bands give a smaller term than step bands."""
    from pencilcal.toolkit.pencil.band_width import band_width_sd, widen_bands

    segs, _ = pivot_frames()
    length = np.linalg.norm(segs[..., 2:] - segs[..., :2], axis=-1)
    covs = np.zeros(segs.shape[:2] + (2, 2))
    covs[..., 0, 0], covs[..., 1, 1] = (0.3 * np.sqrt(12.0 / 40.0) / length) ** 2, 0.3**2 / 40.0
    cam = _pinhole()

    def frames(model, e=None):
        out = _frames(segs if e is None else e, covs)
        for k, f in enumerate(out):
            f["shafts"][0].update(polarity=("dark", "bright")[k % 2], width_px=40.0 + 3.0 * k, edge_model=model)
        return out

    step = fulcrum_point(cam, frames("step"), 2 * RADIUS).to_dict()
    limb = fulcrum_point(cam, frames("limb"), 2 * RADIUS).to_dict()
    assert 0 < limb["point_width_sd"] < step["point_width_sd"]
    sd = np.array([band_width_sd(f["shafts"][0]) for f in frames("step")])
    assert len(set(sd.round(6))) > 1  # the classes differ
    X = np.asarray(step["point"])
    moved = [fulcrum_point(cam, frames("step", np.array([widen_bands(b, t * s)[0] for b, s in zip(segs, sd)])),
                           2 * RADIUS, robust=False).fit.point for t in (-1.0, 1.0)]
    rel = 0.5 * (moved[0] - moved[1]) @ X / (X @ X)
    assert abs(rel / step["point_width_sd"] - 1.0) < 0.05, rel


def test_fulcrum_point_names_an_outlier_frame_and_needs_two_axes():
    segs, _ = pivot_frames(n=12)
    covs = np.broadcast_to(np.diag([1e-8, 0.01]), segs.shape[:2] + (2, 2)).copy()
    bad = segs.copy()
    bad[4] = bad[4] + np.array([60.0, 0.0, 60.0, 0.0])               # another shaft, 60 px aside
    pt = fulcrum_point(_pinhole(), _frames(bad, covs), 2 * RADIUS)
    rec = pt.to_dict()
    assert [o["image"] for o in rec["point_outliers"]] == ["004.png"]
    assert np.linalg.norm(np.asarray(rec["point"]) - FULCRUM) < 0.05
    assert rec["point_axes_used"] == 11 and len(rec["point_axes"]) == 12
    with pytest.raises(Exception, match="two shafts"):
        fulcrum_point(_pinhole(), _frames(segs[:1], covs[:1]), 2 * RADIUS)


@pytest.mark.slow
@pytest.mark.parametrize("gamma", [2.2, 1.0])
def test_target_rendered_port_view(gamma):
    from pencilcal.toolkit.synth.scenarios import default_camera, make_scenario

    cam = default_camera("pinhole", (1920, 1080))
    sc = make_scenario("pivot", 30, 0, camera=cam, shaft_radius=4.0, port_view=100.0, height=150.0, tip=90.0,
                       fulcrum=(700.0, 600.0))
    F = sc.extra["pivot"]["fulcrum_cam"]
    v = cam.project(F)
    assert not (0 <= v[0] < 1920 and 0 <= v[1] < 1080)                  # the port is off the image
    frames, dir_err = [], []
    for i, truth in enumerate(sc.frames):
        img = sc.render(i, noise=5.0, blur_px=1.5, background=0.8, gamma=gamma)
        opts = {} if gamma == 2.2 else {"gamma": gamma}  # 2.2: the default, simulate's and the detector's
        shafts = [s.to_dict() for s in detect_shafts(img, cam, **opts)[:1]]
        frames.append({"image": truth["image"], "ok": True, "segments": np.zeros((0, 4)), "shafts": shafts})
        assert 60.0 <= np.linalg.norm(truth["axis_point_cam"]) <= 150.0
    res = fulcrum_from_frames(cam, frames, shaft_diameter=8.0)
    rec = res.to_dict()
    for a in rec["point_axes"]:
        k = int(a["image"][:3])
        sh = frames[k]["shafts"][a["shaft"]]
        ax = shaft_axis_record(cam, sh["edges"], sh["edge_cov"], 8.0)
        dir_err.append(np.degrees(angle_between(np.asarray(ax["axis_direction"]), sc.frames[k]["axis_direction_cam"])))
    err = np.linalg.norm(np.asarray(rec["point"]) - F)
    assert len(dir_err) >= 25, len(dir_err)
    assert err <= 1.0, (err, rec["point_sigma"])
    assert np.median(dir_err) <= 0.3, np.median(dir_err)


def test_point_jackknife_keeps_a_consistent_point_and_raises_a_moved_one():
    from pencilcal.validation.checks import point_jackknife

    segs, _ = pivot_frames()
    covs = np.zeros(segs.shape[:2] + (2, 2))
    covs[..., 0, 0], covs[..., 1, 1] = 1e-7, 0.01
    cam = _pinhole()
    frames = _frames(segs, covs)
    full = fulcrum_point(cam, frames, 2 * RADIUS)
    same, rec = point_jackknife(cam, frames, 2 * RADIUS, full)
    assert not rec["inflated"] and rec["frames"] == len(frames) and same is full
    # the second half of the frames 5 px off in the image: the robust fit keeps one half, and
    # leaving a frame out moves it (30 px off, the other half is an outlier group every time)
    moved = segs.copy()
    moved[len(segs) // 2:] += 5.0
    frames = _frames(moved, covs)
    full = fulcrum_point(cam, frames, 2 * RADIUS)
    raised, rec = point_jackknife(cam, frames, 2 * RADIUS, full)
    assert rec["inflated"] and rec["ratio"] > 3
    assert float(raised.fit.point_sigma) == pytest.approx(rec["point_sigma_jackknife"])


def test_point_jackknife_is_not_judged_on_too_few_axes():
    """A point that uses the axes of fewer than `POINT_JACKKNIFE_AXES` frames: its
    leave-one-out points measure the gate (an unused axis left out changes nothing, a used
    one leaves too few), so the jackknife is not judged and says why."""
    from pencilcal.validation.checks import POINT_JACKKNIFE_AXES, point_jackknife
    from pencilcal.validation.fulcrum_run import jackknife_sigmas

    segs, _ = pivot_frames(n=12)
    covs = np.broadcast_to(np.diag([1e-8, 0.01]), segs.shape[:2] + (2, 2)).copy()
    cam = _pinhole()
    frames = _frames(segs[:POINT_JACKKNIFE_AXES - 1], covs[:POINT_JACKKNIFE_AXES - 1])
    pt = fulcrum_point(cam, frames, 2 * RADIUS)
    same, rec = point_jackknife(cam, frames, 2 * RADIUS, pt)
    assert same is pt and rec["ratio"] is None and not rec["inflated"] and "fewer than" in rec["reason"]
    frames = _frames(segs[:POINT_JACKKNIFE_AXES], covs[:POINT_JACKKNIFE_AXES])
    _, rec = point_jackknife(cam, frames, 2 * RADIUS, fulcrum_point(cam, frames, 2 * RADIUS))
    assert rec["ratio"] is not None and "reason" not in rec
    spread = _frames(segs[::5], covs[::5])                      # 3 frames over the whole pivot
    for f in spread:                                            # with their midlines, for the image fit
        e = np.asarray(f["shafts"][0]["edges"])
        b = e[1] if np.dot(e[1, 2:] - e[1, :2], e[0, 2:] - e[0, :2]) > 0 else np.r_[e[1, 2:], e[1, :2]]
        f["shafts"][0].update(midline=((e[0] + b) / 2).tolist(), angle_sigma_deg=0.1, offset_sigma_px=0.5)
    res = fulcrum_from_frames(cam, spread, shaft_diameter=2 * RADIUS)
    _, jrec, said = jackknife_sigmas(res, cam, spread, min_frames=3)
    assert jrec["point"]["ratio"] is None and any("not judged" in m for m in said)


# Edge-level pivots like a da Vinci endoscope's (one eye): f = 520 px, 640x480, 50 frames of
# an 8 mm shaft whose tip is 40-150 mm away, the fulcrum some 60 mm to the side, each frame's
# two edges seen over 100-300 px with 0.3 px noise where 0.15 px is stated, the port's play
# 0-1 mm (docs/method.md, "The 3-D fulcrum from the shaft's diameter").
_KE = np.array([[520.0, 0, 319.5], [0, 520.0, 239.5], [0, 0, 1]])


def _edge_level_frames(rng, F, n=50, sd=0.3, stated=0.15, play=1.0):
    """lines.json frames of a shaft pivoting about F (3,) [mm] with play, as above."""
    def proj(X):
        return (_KE @ X)[:2] / X[2]

    def inside(p):
        return 5 <= p[0] <= 635 and 5 <= p[1] <= 475

    frames = []
    while len(frames) < n:
        T = rng.uniform(40, 150) * np.linalg.solve(_KE, [rng.uniform(60, 580), rng.uniform(60, 420), 1.0])
        d = (T - F) / np.linalg.norm(T - F)
        off = rng.normal(size=3)
        off -= (off @ d) * d
        A = F + rng.uniform(0, play) * off / np.linalg.norm(off)
        tip = A + ((T - A) @ d) * d
        p0, s_end = proj(tip), None
        for s in np.linspace(0, (T - A) @ d, 400)[1:]:  # back from the tip while in view, 300 px at most
            if (tip - s * d)[2] < 10 or not inside(proj(tip - s * d)):
                break
            s_end = s
            if np.linalg.norm(proj(tip - s * d) - p0) >= 300:
                break
        if s_end is None or np.linalg.norm(proj(tip - s_end * d) - p0) < 100:
            continue
        p1 = proj(tip - s_end * d)
        edges, covs = [], []
        for a, b, c in project_cylinder(_KE, A, d, 4.0).lines:
            nrm = np.array([a, b])
            q0, q1 = p0 - (nrm @ p0 + c) * nrm, p1 - (nrm @ p1 + c) * nrm
            L = np.linalg.norm(q1 - q0)
            phi = np.arctan2(*(q1 - q0)[::-1]) + rng.normal(0, sd * np.sqrt(12.0) / L)
            u = np.array([np.cos(phi), np.sin(phi)])
            cen = 0.5 * (q0 + q1) + rng.normal(0, sd) * np.array([-u[1], u[0]])
            edges.append(np.r_[cen - 0.5 * L * u, cen + 0.5 * L * u])
            covs.append(np.diag([(stated * np.sqrt(12.0) / L) ** 2, stated**2]))
        frames.append({"image": f"{len(frames):03d}.png", "ok": True, "segments": np.zeros((0, 4)),
                       "shafts": [{"midline": [0.0, 0.0, 1.0, 1.0], "edges": np.array(edges).tolist(),
                                   "edge_cov": np.array(covs).tolist()}]})
    return frames


def test_fulcrum_point_covers_play_and_edge_noise(pivots=12):
    """Edges twice as noisy as stated and the port's play: the point's covariance takes a
    factor on the axes' covariances and the play (as the stereo axes'), each axis weighed at
    the line through the point. Measured (these 12 pivots): median chi2 of the error 3.3,
    RMS 0.58 mm, 6 of 12 in the 68 % region, 11 of 12 within 3 sigma; with the variance
    factor alone and the axes weighed at their own estimates: median chi2 20.2, RMS 0.92 mm,
    1 of 12, 3 of 12 within 3 sigma (docs/method.md has the figures of 160 pivots)."""
    rng = np.random.default_rng(26)
    cam = Camera("pinhole", 640, 480, _KE, [])
    m2, err = [], []
    for _ in range(pivots):
        F = np.array([60.0 * rng.choice([-1, 1]), rng.uniform(-20, 20), rng.uniform(70, 110)])
        pt = fulcrum_point(cam, _edge_level_frames(rng, F), 8.0)
        e = pt.fit.point - F
        m2.append(e @ np.linalg.solve(pt.fit.point_cov, e))
        err.append(e)
        assert 0.0 < pt.to_dict()["point_play_sigma"] <= 1.0
    m2, err = np.array(m2), np.array(err)
    assert np.median(m2) < 5.0, m2
    assert np.mean(m2 <= chi2.ppf(0.9973, 3)) >= 0.8, m2
    assert np.sqrt(np.mean(np.sum(err**2, -1))) < 0.7


def test_fulcrum_point_keeps_the_factor_where_the_play_is_beyond_a_port():
    """A fulcrum that moved 20 mm halfway (an arm re-set): the play that scatter reads is
    beyond what a port allows (1/8 of the diameter), so the point is the variance factor's
    alone, with the axes weighed at their own estimates, whose jackknife then judges it."""
    from pencilcal.toolkit.pencil.fulcrum import _point_with_noise, frame_axes

    rng = np.random.default_rng(5)
    cam = Camera("pinhole", 640, 480, _KE, [])
    frames = (_edge_level_frames(rng, np.array([60.0, 0.0, 90.0]), n=12, play=0.5)
              + _edge_level_frames(rng, np.array([60.0, 20.0, 90.0]), n=12, play=0.5))
    pt = fulcrum_point(cam, frames, 8.0)
    P, D, C = (np.array(v) for v in frame_axes(cam, frames, 8.0)[:3])
    plain, factor, play, term = _point_with_noise(P, D, C, True)
    assert np.allclose(pt.fit.point, plain.point) and np.allclose(pt.fit.point_cov, plain.point_cov)
    assert pt.variance_factor == factor > 1.0 and pt.play == play == 0.0 and term is None


def test_fulcrum_point_takes_the_play_the_lines_read():
    """Edges precise to 0.1 px stated as 1 px (a floor), and the port's play (up to 0.7 mm,
    0.29 mm sd per direction): each axis's offset at the point, extrapolated over the shaft,
    is stated larger than the play, so the axes' chi2 reads none, while the image lines'
    offsets at the vertex show it. Given the lines' reading (``lines_play``, an angle), the
    point is the same and its covariance gains the play's term (``play_cov``): what offsets
    of that sd, independent between frames, move the axes' weighted mean by. Checked against
    the scatter of the same estimator over redrawn plays."""
    rng = np.random.default_rng(26)
    cam = Camera("pinhole", 640, 480, _KE, [])
    F = np.array([60.0, rng.uniform(-20, 20), rng.uniform(70, 110)])
    sd = 0.7 / np.sqrt(6.0)                                 # per direction, of a uniform radius in a disc
    points, terms = [], []
    for k in range(40):
        frames = _edge_level_frames(np.random.default_rng([26, k]), F, n=30, sd=0.1, stated=1.0, play=0.7)
        if k == 0:
            plain = fulcrum_point(cam, frames, 8.0)
        pt = fulcrum_point(cam, frames, 8.0, lines_play=sd / np.linalg.norm(F))
        points.append(pt.fit.point)
        terms.append(pt.play_cov)
    assert plain.play == 0.0 and plain.play_cov is None
    assert pt.play == 0.0 and np.allclose(points[0], plain.fit.point)
    assert np.allclose(pt.cov, pt.fit.point_cov + pt.width_cov + pt.play_cov)
    assert pt.to_dict()["point_cov_play"] == pt.play_cov.tolist()
    u = F / np.linalg.norm(F)
    V = np.linalg.svd(np.eye(3) - np.outer(u, u))[0][:, :2]            # across the line of sight
    scatter = V.T @ np.cov(np.array(points).T) @ V
    term = V.T @ np.mean(terms, 0) @ V
    # the redrawn plays scatter the point across the line of sight by what the term says
    # (the edges' own noise, 0.1 px, adds little): measured 0.96 and 1.12 times its sds; within
    # 40 draws' sampling error
    ratio = np.sqrt(np.linalg.eigvalsh(np.linalg.solve(np.linalg.cholesky(term), np.linalg.solve(
        np.linalg.cholesky(term), scatter).T)))
    assert np.all((ratio > 0.7) & (ratio < 1.4)), ratio


def test_leave_one_out_points_are_the_points_of_the_other_frames():
    """The jackknife's points from the axes found once (`leave_one_out_points`) are, number
    for number, `fulcrum_point` of the frames without each one, with a frame without a
    shaft, a shaft without edge_cov and one whose edge has no length (no axis) among them;
    every shaft's axis found with the others is the one it has on its own, and every axis's
    covariance at the point the one it has alone."""
    from pencilcal.toolkit.pencil.cylinder import axis_frame
    from pencilcal.toolkit.pencil.fulcrum import _covariances_at_point, frame_axes, leave_one_out_points

    rng = np.random.default_rng(11)
    cam = Camera("opencv", 640, 480, _KE, [-0.1, 0.02, 0.0, 0.0, 0.0])
    frames = _edge_level_frames(rng, np.array([60.0, 0.0, 90.0]), n=10, play=0.5)
    P, D, C, _, measured, *_ = frame_axes(cam, frames, 8.0)
    alone = [shaft_axis_record(cam, e, c, 8.0) for e, c in measured]
    assert P == [a["axis_point"] for a in alone] and D == [a["axis_direction"] for a in alone]
    assert C == [a["axis_cov"] for a in alone]
    P, D, C = np.array(P), np.array(D), np.array(C)
    E = axis_frame(P, D)
    ideal = np.array([cam.undistort_pixels(np.reshape(e, (-1, 2))).reshape(2, 4) for e, _ in measured])
    cov = np.array([np.reshape(c, (2, 2, 2)) for _, c in measured])
    x = np.array([61.0, 1.0, 92.0])
    together = _covariances_at_point(_KE, (ideal, cov), 4.0, P, D, C, E, x)
    one = [_covariances_at_point(_KE, (ideal[i:i + 1], cov[i:i + 1]), 4.0, P[i:i + 1], D[i:i + 1], C[i:i + 1],
                                 E[i:i + 1], x)[0] for i in range(len(P))]
    assert np.array_equal(together, np.array(one)) and not np.array_equal(together, C)

    frames[2]["shafts"][0]["edge_cov"] = None
    frames[4]["shafts"].append({**frames[4]["shafts"][0], "edges": [[100.0, 100, 100, 100], [110, 100, 200, 120]]})
    frames.insert(6, {"image": "none.png", "ok": True, "segments": np.zeros((0, 4)), "shafts": []})
    loo = leave_one_out_points(cam, frames, 8.0)
    assert [k for k, _ in loo] == [k for k, f in enumerate(frames) if f["shafts"]]
    for k, x in loo:
        assert np.array_equal(x, fulcrum_point(cam, frames[:k] + frames[k + 1:], 8.0).fit.point)


def _leaning(frames, which, px):
    """frames with the tip end of both edges of the frames `which` moved px inwards (a near
    shaft's edges run on along its narrower wrist)."""
    for i in which:
        e = np.array(frames[i]["shafts"][0]["edges"], float)
        for k in range(2):
            u = e[k, 2:] - e[k, :2]
            nrm = np.array([-u[1], u[0]]) / np.linalg.norm(u)
            nrm *= np.sign(nrm @ (e[1 - k, :2] - e[k, :2]))
            e[k, :2] += px * nrm
        frames[i]["shafts"][0]["edges"] = e.tolist()
    return frames


def test_fulcrum_point_leaves_out_the_axes_misread_alike(monkeypatch):
    """With ``scatter_gate=True`` (the default): clean edges (0.05 px) stated at a floor (0.5 px) and a
    fifth of the frames with both edges' tip ends 5 px inside the band: at the stated size
    those axes pass the 99 % gate and pull the point (1.37 mm off); gated at the axes' own
    scatter they are left out (0.06 mm; docs/method.md, "The gate at the axes' own scatter";
    rendered pivots 2663 left 11.97 -> 0.65 mm)."""
    import pencilcal.toolkit.pencil.fulcrum as fulcrum_module

    rng = np.random.default_rng(11)
    cam = Camera("pinhole", 640, 480, _KE, [])
    F = np.array([60.0, 0.0, 90.0])
    frames = _leaning(_edge_level_frames(rng, F, n=40, sd=0.05, stated=0.5, play=0.2), range(8), 5.0)
    pt = fulcrum_point(cam, frames, 8.0)
    assert not np.any(np.asarray(pt.fit.inliers)[:8])
    gated = np.linalg.norm(pt.fit.point - F)
    monkeypatch.setattr(fulcrum_module, "scatter_inliers", lambda P, D, C: np.ones(len(P), bool))
    plain = fulcrum_point(cam, frames, 8.0, scatter_gate=True)
    assert np.all(np.asarray(plain.fit.inliers)[:8])
    assert gated < 0.5 < np.linalg.norm(plain.fit.point - F), (gated, np.linalg.norm(plain.fit.point - F))


def test_scatter_gate_keeps_the_stated_gate_for_axes_noisier_than_stated():
    """Edges twice as noisy as stated (as the real phantom's, whose axes scatter 2-5 times
    their stated variance) over 13 frames: the stated 99 % gate leaves out five, and
    a subset fixed there (``limit`` infinite: the gate before it read the axes' own scale)
    would keep the noise fit from taking them back at its factor; at an own scale above
    `SCATTER_LIMIT` the gate keeps every axis and the point is the plain one, to the bit."""
    from pencilcal.toolkit.pencil.cylinder import fulcrum_3d as fit3d
    from pencilcal.toolkit.pencil.fulcrum import frame_axes
    from pencilcal.toolkit.pencil.scatter_gate import SCATTER_LIMIT, own_scale, scatter_inliers

    rng = np.random.default_rng(9)
    cam = Camera("pinhole", 640, 480, _KE, [])
    frames = _edge_level_frames(rng, np.array([60.0, 0.0, 90.0]), n=13, sd=1.0, stated=0.5, play=0.2)
    P, D, C = (np.array(v) for v in frame_axes(cam, frames, 8.0)[:3])
    assert own_scale(fit3d(P, D, C)) > SCATTER_LIMIT
    assert not np.all(scatter_inliers(P, D, C, limit=np.inf))
    assert np.all(scatter_inliers(P, D, C))
    gated, plain = fulcrum_point(cam, frames, 8.0, scatter_gate=True), fulcrum_point(cam, frames, 8.0, scatter_gate=False)
    assert np.array_equal(gated.fit.point, plain.fit.point)
    assert np.array_equal(gated.fit.point_cov, plain.fit.point_cov)
