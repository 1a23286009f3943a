"""The line noise estimated per sequence (sequence_noise): sigmas that cover 68 % of the
errors whatever noise was assumed."""
from __future__ import annotations

import numpy as np
import pytest

from pencilcal.toolkit.geometry.frames import angle_between
from pencilcal.toolkit.pencil.orient import orient_segments
from pencilcal.toolkit.pencil.sequence_noise import MIN_DOF, estimate_sequence_noise, rescale, sequence_noise, \
    variance_factor
from tests.helpers import fan, frame, hd_camera


def _sequence(rng, noise_px, n=120):
    cam = hd_camera()
    pen = fan(radius=None)
    out = []
    for _ in range(n):
        seg, R, t = frame(cam, pen, rng.uniform(25, 55), 250.0, rng, noise_px=noise_px)
        out.append((seg, R, t))
    return cam, pen, out


def _coverage(cam, records, truth):
    hits = []
    for rec, (_, R, t) in zip(records, truth):
        if not rec.ok:
            continue
        true_tilt = np.degrees(angle_between(R[:, 2], cam.rays_from_pixels(cam.project(t))))
        hits.append(abs(rec.tilt_deg - true_tilt) < rec.tilt_sigma_deg)
    return float(np.mean(hits))


@pytest.mark.parametrize("noise_px", [0.15, 1.2])
def test_estimated_noise_covers_68_percent(rng, noise_px):
    """The assumed 0.5 px is too pessimistic (0.15 px) or too optimistic (1.2 px): the tilt
    sigmas then cover far from 68 %; with the sequence's estimated noise, 68 +- 8 %."""
    cam, pen, seq = _sequence(rng, noise_px)
    seq = [f for f in seq if orient_segments(cam, f[0], pen, endpoint_sigma_px=0.5 * noise_px / 0.5).ok]
    assert len(seq) >= 0.95 * 120

    def run(sigma):
        return [orient_segments(cam, seg, pen, endpoint_sigma_px=sigma) for seg, _, _ in seq]

    assumed = _coverage(cam, run(0.5), seq)
    scaled, est = estimate_sequence_noise(run, 0.5)
    assert est.dof >= 0.95 * sum(r.lines_used - 3 for r in scaled) and est.rejected <= 3
    assert est.scale == pytest.approx(noise_px / 0.5, rel=0.1)
    assert (assumed > 0.9) if noise_px < 0.5 else (assumed < 0.45)
    assert 0.60 <= _coverage(cam, scaled, seq) <= 0.76


def test_an_outlier_frame_does_not_inflate_the_noise(rng):
    cam, pen, seq = _sequence(rng, 0.3, n=40)
    records = [orient_segments(cam, seg, pen, endpoint_sigma_px=0.3) for seg, _, _ in seq]
    bad = records[5].replace(chi2=records[5].chi2 * 400)
    _, est = sequence_noise(records[:5] + [bad] + records[6:])
    assert est.rejected >= 1 and 0.8 < est.scale < 1.25


def test_too_few_dof_leaves_the_records():
    assert variance_factor([1.0, 2.0], [2, 3]) is None and MIN_DOF > 5


def test_rescale_keeps_the_lens_term(rng):
    cam, pen, seq = _sequence(rng, 0.5, n=1)
    C = np.diag([1.0, 1.0, 4.0, 4.0, 1e-6, 1e-6, 0, 0, 1e-6])
    rec = orient_segments(cam, seq[0][0], pen, intrinsics_cov=C)
    r2 = rescale(rec, 4.0)
    assert r2.tilt_sigma_deg == pytest.approx(2 * rec.tilt_sigma_deg)
    lens = rec.tilt_sigma_total_deg**2 - rec.tilt_sigma_deg**2
    assert r2.tilt_sigma_total_deg**2 - r2.tilt_sigma_deg**2 == pytest.approx(lens)
    np.testing.assert_allclose(r2.vertex_cov_px2, 4 * rec.vertex_cov_px2)


def _pivot_frames(cam, rng, noise_px, n=40):
    X = np.array([30.0, -20.0, 150.0])
    frames = []
    for _ in range(n):
        d = rng.normal(size=3)
        d -= d @ X / (X @ X) * X
        d /= np.linalg.norm(d)
        p = cam.project(np.array([X + 15 * d, X + 90 * d])) + noise_px * rng.normal(size=(2, 2))
        frames.append({"image": "f.png", "ok": True, "segments": p.reshape(1, 4)})
    return X, frames


def test_fulcrum_noise_scales_the_ray_sigma(rng):
    from pencilcal.toolkit.pencil.fulcrum import fulcrum_from_frames
    from pencilcal.toolkit.pencil.sequence_noise import estimate_fulcrum_noise, fulcrum_noise

    cam = hd_camera()
    errs, sig = [], []
    for _ in range(60):
        X, frames = _pivot_frames(cam, rng, 1.5)
        f, est = estimate_fulcrum_noise(lambda s: fulcrum_from_frames(cam, frames, endpoint_sigma_px=s), 0.5)
        assert 2.0 < est["vertex"].scale < 5.0 and est["pivot"] is None
        errs.append(np.degrees(angle_between(np.asarray(f.ray), X)))
        sig.append(f.ray_sigma_deg)
    # the ray's error is 2-D: its RMS against the RMS sigma
    assert 0.75 < np.sqrt(np.mean(np.square(errs))) / np.sqrt(np.mean(np.square(sig))) < 1.33
    # detector sigmas (inflate only) are kept when the lines scatter less than they say
    X, frames = _pivot_frames(cam, rng, 0.1)
    f0 = fulcrum_from_frames(cam, frames, endpoint_sigma_px=0.5)
    f1, est = fulcrum_noise(f0, inflate_only=True)
    assert est["vertex"].variance_factor == 1.0 and f1.ray_sigma_deg == f0.ray_sigma_deg


def test_what_orient_and_fulcrum_write_as_their_noise(rng):
    """`orientations_with_noise` and `fulcrum_with_noise`: the user's noise kept as given, lines
    without sigmas estimated (with a warning when they scatter more than twice the assumed
    noise), and too few degrees of freedom said so."""
    from pencilcal.toolkit.pencil.fulcrum import fulcrum_from_frames
    from pencilcal.toolkit.pencil.sequence_noise import fulcrum_with_noise, orientations_with_noise

    cam, pen, seq = _sequence(rng, 1.5, n=30)

    def run(sigma):
        return [orient_segments(cam, seg, pen, endpoint_sigma_px=sigma) for seg, _, _ in seq]

    first = run(0.5)
    out, rec, msg = orientations_with_noise(first, run, 0.5, given=True, angle_sigma=0.1)
    assert out is first and rec == {"estimated": False, "endpoint_sigma_px": 0.5, "angle_sigma_deg": 0.1} and msg is None
    out, rec, msg = orientations_with_noise(first, run, 0.5, floor=0.05, fix_hint="give the noise")
    assert rec["estimated"] and rec["assumed_endpoint_sigma_px"] == 0.5 and 2.4 < rec["sigma_scale"] < 3.6
    assert msg.startswith("the lines scatter 3") and "the assumed 0.5 px end point noise" in msg
    assert msg.endswith("degrees of freedom; give the noise)")
    k = next(i for i, r in enumerate(first) if r.ok)
    assert out[k].tilt_sigma_deg > 2 * first[k].tilt_sigma_deg
    _, rec, msg = orientations_with_noise(first[:1], run, 0.5, estimable=False)
    assert rec["estimated"] is False and "too few degrees of freedom" in rec["reason"] and rec["inflate_only"]

    X, frames = _pivot_frames(cam, rng, 1.5)
    f0 = fulcrum_from_frames(cam, frames, endpoint_sigma_px=0.5)
    f, rec, msg = fulcrum_with_noise(f0, lambda s: fulcrum_from_frames(cam, frames, endpoint_sigma_px=s), 0.5, frames)
    assert rec["assumed_endpoint_sigma_px"] == 0.5 and f.ray_sigma_deg > 2 * f0.ray_sigma_deg
    assert msg.startswith("the fulcrum's lines scatter") and rec["pivot"] is None
    f, rec, msg = fulcrum_with_noise(f0, None, 0.5, frames, given=True)
    assert f is f0 and rec == {"estimated": False, "endpoint_sigma_px": 0.5} and msg is None
