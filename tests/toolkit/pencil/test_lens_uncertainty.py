"""The intrinsics' uncertainty in orient's and fulcrum's sigmas (lens_uncertainty), by Monte Carlo.

The lines are exact in raw pixels; the camera the estimate uses is drawn from the intrinsics'
covariance around the true one. The spread of the estimates around the truth is then the
intrinsics' term alone: the totals minus the noise-only variances must predict it.
"""
from __future__ import annotations

import numpy as np
import pytest

from pencilcal.toolkit.camera.intrinsics import IntrinsicsCovariance, intrinsic_names, intrinsics_vector, \
    with_intrinsics
from pencilcal.toolkit.geometry.frames import angle_between
from pencilcal.toolkit.pencil.fulcrum import fulcrum_from_frames
from pencilcal.toolkit.pencil.orient import orient_segments
from tests.helpers import fan, frame, hd_camera


def _cov(camera):
    """A calibration-like covariance: 1.5 px focal, 2 px centre, correlated fx/fy, small distortion."""
    names = intrinsic_names(camera)
    sd = {"fx": 1.5, "fy": 1.5, "cx": 2.0, "cy": 2.0, "k1": 2e-3, "k2": 4e-3, "p1": 1e-4, "p2": 1e-4, "k3": 5e-3}
    s = np.array([sd.get(n, 0.0) for n in names])
    C = np.diag(s**2)
    C[0, 1] = C[1, 0] = 0.9 * s[0] * s[1]
    return C


def _draws(camera, C, n, rng):
    th = intrinsics_vector(camera)
    L = np.linalg.cholesky(C + 1e-18 * np.eye(len(th)))
    return [with_intrinsics(camera, th + L @ rng.normal(size=th.size)) for _ in range(n)]


def test_orient_totals_predict_the_spread_from_the_intrinsics(rng):
    cam = hd_camera()
    C = _cov(cam)
    pen = fan()  # the spoke radii resolve the twin: the sigmas are those of the true solution
    seg, R, t = frame(cam, pen, 40.0, 250.0, rng)
    n_true = R[:, 2]
    tilt_true = np.degrees(angle_between(n_true, t))
    rec0 = orient_segments(cam, seg, pen, intrinsics_cov=C)
    assert rec0.intrinsics_used and rec0.tilt_sigma_total_deg > rec0.tilt_sigma_deg
    assert np.degrees(angle_between(np.asarray(rec0.normal), n_true)) < 1e-6
    # the intrinsics' part of the variance, as the record states it
    tilt_lens = np.sqrt(rec0.tilt_sigma_total_deg**2 - rec0.tilt_sigma_deg**2)
    normal_lens = np.sqrt(rec0.normal_sigma_total_deg**2 - rec0.normal_sigma_deg**2)
    v_lens = rec0.vertex_cov_total_px2 - rec0.vertex_cov_px2
    dt, dn, dv = [], [], []
    for c in _draws(cam, C, 150, rng):
        rec = orient_segments(c, seg, pen)
        assert rec.ok
        dn.append(np.degrees(angle_between(np.asarray(rec.normal), n_true)))
        dt.append(rec.tilt_deg - tilt_true)
        dv.append(rec.vertex_px - cam.project(t))
    dt, dn, dv = np.array(dt), np.array(dn), np.array(dv)
    assert 0.8 < np.sqrt(np.mean(dt**2)) / tilt_lens < 1.25
    # the normal's error is 2-D (its angle's mean square is the trace)
    assert 0.8 < np.sqrt(np.mean(dn**2)) / normal_lens < 1.25
    emp = np.cov(dv.T, bias=True) + np.outer(dv.mean(0), dv.mean(0))
    assert 0.75 < np.trace(emp) / np.trace(v_lens) < 1.33


def test_no_covariance_no_totals(rng):
    cam = hd_camera()
    pen = fan(radius=None)
    seg, _, _ = frame(cam, pen, 40.0, 250.0, rng)
    rec = orient_segments(cam, seg, pen)  # the camera carries no statistics
    assert rec.intrinsics_used is None and rec.tilt_sigma_total_deg is None
    assert "tilt_sigma_total_deg" not in rec.to_dict()
    # the covariance as a record of named intrinsics works the same as the bare matrix
    C = _cov(cam)
    a = orient_segments(cam, seg, pen, intrinsics_cov=C)
    b = orient_segments(cam, seg, pen, intrinsics_cov=IntrinsicsCovariance(intrinsic_names(cam), C))
    assert a.tilt_sigma_total_deg == pytest.approx(b.tilt_sigma_total_deg, rel=1e-9)


def test_fulcrum_ray_total_predicts_the_spread_from_the_intrinsics(rng):
    """A pivoting shaft's lines through a fulcrum: the ray's total sigma holds the lens term."""
    cam = hd_camera()
    C = _cov(cam)
    X = np.array([30.0, -20.0, 150.0])  # the fulcrum in the camera frame
    frames = []
    for _ in range(12):
        d = rng.normal(size=3)
        d -= d @ X / (X @ X) * X  # off the viewing ray, so the lines are not degenerate
        d /= np.linalg.norm(d)
        p = cam.project(np.array([X + 10 * d, X + 80 * d]))
        frames.append({"image": "f.png", "ok": True, "segments": p.reshape(1, 4)})
    ray_true = X / np.linalg.norm(X)
    f0 = fulcrum_from_frames(cam, frames, intrinsics_cov=C)
    assert f0.intrinsics_used and f0.ray_sigma_total_deg > f0.ray_sigma_deg
    lens = np.sqrt(f0.ray_sigma_total_deg**2 - f0.ray_sigma_deg**2)
    err = []
    for c in _draws(cam, C, 100, rng):
        f = fulcrum_from_frames(c, frames)
        err.append(np.degrees(angle_between(np.asarray(f.ray), ray_true)))
    assert 0.75 < np.sqrt(np.mean(np.square(err))) / lens < 1.33
