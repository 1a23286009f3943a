"""A printed sheet's bend (`pencil.bend`): each line's turn under it, and the normal's
covariance it widens where the lines show it."""
from __future__ import annotations

import numpy as np
import pytest

from pencilcal.toolkit.camera.model import Camera
from pencilcal.toolkit.pencil.bend import bend_response
from pencilcal.toolkit.pencil.orient import orient_segments
from pencilcal.toolkit.pencil.spec import pencil_from_dict
from pencilcal.toolkit.synth.radial import radial_pose

_CAM = Camera("opencv", 1280, 960, [[1000.0, 0, 640.0], [0, 1000.0, 480.0], [0, 0, 1]], [0.0, 0, 0, 0])
_SHEET_MM = 148.5  # the bend's reach: curl_mm off the plane this far from the vertex


def _edge_points(R, t, theta, curl_mm, curl_deg, r=np.linspace(12.0, 70.0, 30)):
    """(len(r), 2) px: an edge at target angle theta [rad] of a sheet bent into a cylinder
    z = curl_mm (u / 148.5)^2 along curl_deg, as `synth.radial_photo.curled` bends it."""
    u = np.outer(r, [np.cos(theta), np.sin(theta)])
    d = np.array([np.cos(np.radians(curl_deg)), np.sin(np.radians(curl_deg))])
    return _CAM.project(np.c_[u, curl_mm * (u @ d / _SHEET_MM) ** 2] @ R.T + t)


def _fitted(px):
    """A straight segment (4,) fitted through points (K, 2) [px]: its ends, the points' extent."""
    c = px.mean(0)
    d = np.linalg.eigh(np.cov((px - c).T))[1][:, 1]
    s = (px - c) @ d
    return np.r_[c + s.min() * d, c + s.max() * d]


def _half_star(curl_mm, curl_deg, tilt_deg=40.0, seed=1, noise_deg=0.01, offset_px=0.05, declared_deg=None):
    """A 64-wedge star's edges on one side of the vertex (180 deg of them), on a sheet bent
    curl_mm at 148.5 mm from the vertex along curl_deg, each edge's segment fitted through its
    image and given noise of those sds (declared_deg: the angle sd the fit is told, default
    noise_deg): (orientation, the normal's error [deg])."""
    rng = np.random.default_rng(seed)
    star = pencil_from_dict({"start_deg": 0, "step_deg": 360.0 / 64, "count": 64, "shape": "wedge",
                             "radius": [0, 70]})
    R, t = radial_pose(_CAM, [620.0, 500.0], tilt_deg, 70.0, fill=0.8, axis_deg=30.0, roll_deg=10.0)
    edges = star.edge_angles()[0]
    keep = np.flatnonzero(np.mod(edges, 2 * np.pi) < np.pi)
    segs = []
    for e in edges[keep]:
        seg = _fitted(_edge_points(R, t, e, curl_mm, curl_deg))
        c, h = 0.5 * (seg[:2] + seg[2:]), 0.5 * (seg[2:] - seg[:2])
        a = rng.normal(0.0, np.radians(noise_deg))
        h = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]) @ h
        c = c + rng.normal(0.0, offset_px) * np.array([-h[1], h[0]]) / np.hypot(*h)
        segs.append(np.r_[c - h, c + h])
    rec = orient_segments(_CAM, np.array(segs), star, angle_sigma=np.radians(declared_deg or noise_deg),
                          offset_sigma=offset_px, labels=keep, keep_lines=True)
    err = min(np.degrees(np.arccos(np.clip(np.asarray(n) @ R[:, 2], -1, 1))) for n in (rec.normal, rec.normal_twin))
    return rec, float(err)


def test_a_lines_turn_under_a_bend_is_the_image_of_the_bent_edge():
    """`bend_response`: each edge's angle change per unit bend, against the line fitted through
    the image of the edge on a sheet bent a little (a cylinder along 30 deg, its curvature times
    the vertex's depth 0.01: b = 0.01 (c^2, c s, s^2)), within 3 % of the largest change."""
    R, t = radial_pose(_CAM, [600.0, 450.0], 45.0, 70.0, fill=0.7, axis_deg=60.0, roll_deg=0.0)
    depth = float(t[2])
    theta = np.radians(np.arange(0.0, 360.0, 15.0))
    Kinv = np.linalg.inv(np.asarray(_CAM.K, float))

    def lines(curl_mm):
        seg = np.array([_fitted(_edge_points(R, t, th, curl_mm, 30.0)) for th in theta])
        seg = np.concatenate([seg[:, :2] @ Kinv[:2, :2].T + Kinv[:2, 2], seg[:, 2:] @ Kinv[:2, :2].T + Kinv[:2, 2]], 1)
        return seg, np.arctan2(seg[:, 3] - seg[:, 1], seg[:, 2] - seg[:, 0])

    kappa = 0.01  # curvature [1/mm] times the depth [mm]
    curl = kappa / depth * _SHEET_MM**2 / 2  # z = curl (u / 148.5)^2 = kappa u^2 / (2 depth)
    flat, a0 = lines(0.0)
    _, a1 = lines(curl)
    c, s = np.cos(np.radians(30.0)), np.sin(np.radians(30.0))
    G, _ = bend_response(R, t[:2] / t[2], flat[:, :2], flat[:, 2:], np.full(theta.size, 1e-4),
                         np.full(theta.size, 1e-4))
    want = np.angle(np.exp(1j * (a1 - a0)))
    got = G @ (kappa * np.array([c * c, c * s, s * s]))
    assert np.max(np.abs(got - want)) < 0.03 * np.max(np.abs(want)), (got, want)


def test_a_flat_sheet_keeps_its_sigma():
    """A flat sheet's lines show no bend beyond chance: its covariance is the lines' own,
    no bend term added."""
    rec, err = _half_star(0.0, 0.0)
    assert "bend_cov" not in rec.lines and err < 3 * rec.normal_sigma_deg


def test_a_bent_sheet_widens_the_normal():
    """A half star (64 wedges, the 64 edges on one side) on a sheet curled 0.4 mm at 148.5 mm
    (0.09 mm at the star's rim), tilted 40 deg, curled along 8 directions 22.5 deg apart: the
    bend turns the normal 0.04-0.09 deg, 9-13 times the lines' own sigma (0.006 deg). With
    the bend the lines show in the covariance, 5 of the 8 lie within 3 sigmas (0.6-1.6); those
    bent along 67.5-112.5 deg (4.2, 4.7 and 3.0 sigmas) bend the lines much as a tilt does and
    show less of it in their residuals."""
    ratios = []
    for curl_deg in np.arange(0.0, 180.0, 22.5):
        rec, err = _half_star(0.4, curl_deg)
        ratios.append(err / rec.normal_sigma_deg)
    assert sum(r < 3.0 for r in ratios) >= 5, ratios
    assert max(ratios) < 6.0, ratios


def test_lines_noisier_than_their_sds_widen_the_normal_by_their_misfit():
    """Lines whose angles scatter twice their sds (a flat sheet): the misfit, chi2 per degree of
    freedom about 4, scales their error variances, so the normal's sigma doubles, and the bend
    is told from that noise (its chi2 12.7 against the lines' own sds, 3.5 against the
    widened: no bend taken); its sigma is then the one the lines told their true sds give."""
    told, _ = _half_star(0.0, 0.0, noise_deg=0.02, declared_deg=0.01)
    right, _ = _half_star(0.0, 0.0, noise_deg=0.02)
    assert told.bend_taken is False and told.bend_chi2 > 7.81 > told.bend_chi2 / told.misfit_scale
    assert 2.5 < told.misfit_scale < 6.0, told.misfit_scale
    assert right.misfit_scale < 1.6, right.misfit_scale
    # the sigma of lines told half their sds, widened by their misfit, is the one of lines told
    # their true sds (without the scale it would be half of it)
    assert 0.8 < told.normal_sigma_deg / right.normal_sigma_deg < 1.25, (told.normal_sigma_deg, right.normal_sigma_deg)


def _full_star_with_circle(curl_mm, curl_deg, seed=3):
    """A 64-wedge star's 128 edges all round and its 70 mm outline (180 points, 0.1 px
    noise) on a sheet bent as `_half_star`'s, tilted 40 deg: the orientation."""
    rng = np.random.default_rng(seed)
    star = pencil_from_dict({"start_deg": 0, "step_deg": 360.0 / 64, "count": 64, "shape": "wedge",
                             "radius": [0, 70], "circles": [70]})
    R, t = radial_pose(_CAM, [620.0, 500.0], 40.0, 70.0, fill=0.8, axis_deg=30.0, roll_deg=10.0)
    edges = star.edge_angles()[0]
    segs = []
    for e in edges:
        seg = _fitted(_edge_points(R, t, e, curl_mm, curl_deg))
        c, h = 0.5 * (seg[:2] + seg[2:]), 0.5 * (seg[2:] - seg[:2])
        a = rng.normal(0.0, np.radians(0.01))
        h = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]) @ h
        segs.append(np.r_[c - h, c + h] + rng.normal(0.0, 0.05) * np.r_[-h[1], h[0], -h[1], h[0]] / np.hypot(*h))
    phi = np.linspace(0, 2 * np.pi, 180, endpoint=False)
    u = 70.0 * np.stack([np.cos(phi), np.sin(phi)], 1)
    d = np.array([np.cos(np.radians(curl_deg)), np.sin(np.radians(curl_deg))])
    ring = _CAM.project(np.c_[u, curl_mm * (u @ d / _SHEET_MM) ** 2] @ R.T + t) + rng.normal(0, 0.1, (phi.size, 2))
    return orient_segments(_CAM, np.array(segs), star, angle_sigma=np.radians(0.01), offset_sigma=0.05,
                           labels=np.arange(edges.size), keep_lines=True, circle_points=ring), R


@pytest.mark.parametrize("curl_deg", [0.0, 90.0])
def test_the_circles_agree_with_the_lines_on_a_bent_sheet(curl_deg):
    """A bent sheet (0.4 mm at 148.5 mm) lifts the star's outline twice round it: its ellipse is
    a circle's on a plane 0.06-0.09 deg off (9-12 of the circle's own sigmas), where the
    lines, all round the vertex, hardly move (0.002 deg). Without the bend the agreement's
    chi2 was 87-170 (circle_consistent false); with the bend the two normals share (each
    one's response to it) the circles' sigma holds their error and the check passes. A flat
    sheet keeps its circles' sigma."""
    rec, R = _full_star_with_circle(0.4, curl_deg)
    err = np.degrees(np.arccos(np.clip(np.asarray(rec.circle_normal) @ R[:, 2], -1, 1)))
    assert rec.bend_taken is True and rec.bend_chi2 > 100
    assert rec.circle_consistent and rec.circle_chi2 < 9.21, rec.circle_chi2
    assert 0.04 < err < 2.0 * rec.circle_normal_sigma_deg, (err, rec.circle_normal_sigma_deg)
    flat, _ = _full_star_with_circle(0.0, curl_deg)
    assert flat.bend_taken is False and flat.circle_normal_sigma_deg < 0.01
