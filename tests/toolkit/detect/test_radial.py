"""The edges of radial targets on rendered webcam frames: every edge found, each through the
vertex as its sigmas say, the circle points on the outline, clutter beside it."""
from __future__ import annotations

import numpy as np
import pytest

from pencilcal.toolkit.camera.model import Camera
from pencilcal.toolkit.detect.radial import detect_radial_edges, orient_radial_edges
from pencilcal.toolkit.errors import InputError
from pencilcal.toolkit.pencil.spec import image_angles, pencil_from_dict
from pencilcal.toolkit.synth.radial import dartboard_layers, dartboard_pencil, radial_pose, render_layers, star_layers

CAM = Camera("opencv", 1280, 960, [[1000.0, 0, 643.1], [0, 1000.5, 477.4], [0, 0, 1]], [-0.2, 0.0, 0.0, 0.0])


def _star(n, polarity="dark"):
    return pencil_from_dict({"start_deg": 0, "step_deg": 360.0 / n, "count": n, "shape": "wedge", "radius": [0, 70],
                             "circles": [70], "polarity": polarity})


def _residuals(found, pen, R, t):
    """Each found edge's angle error [rad] against the nearest true edge of its kind of
    polarity, and its sigma."""
    x = t[:2] / t[2]
    ea, _, _ = pen.edge_angles()
    true = image_angles(R, x, ea)
    vpx = CAM.undistort_pixels(CAM.project(t))
    mid = 0.5 * (found.ideal[:, :2] + found.ideal[:, 2:])
    d = found.ideal[:, 2:] - found.ideal[:, :2]
    out = np.sign(np.sum(d * (mid - vpx), -1))
    a = np.arctan2(d[:, 1] * out / CAM.K[1, 1], d[:, 0] * out / CAM.K[0, 0])  # normalised coordinates
    res = np.angle(np.exp(1j * (a[:, None] - true[None, :])))
    k = np.argmin(np.abs(res), 1)
    return res[np.arange(len(a)), k], k


@pytest.mark.parametrize("n,tilt,polarity,joint", [(16, 40.0, "dark", "crowded"), (64, 25.0, "dark", "crowded"),
                                                  (64, 50.0, "light", "crowded"), (64, 50.0, "light", "all")])
def test_every_edge_of_a_star(n, tilt, polarity, joint):
    """All 2n edges, the vertex within 0.02 px (a 1 px blur, gamma 2.2, JPEG 85, k1 -0.2),
    the angle errors as large as their sigmas say (located on linear light: on the encoded
    levels every edge sat 0.5 px into its dark side and missed the vertex), located where
    clear of their neighbours or every one jointly with them (a star's wedges)."""
    pen = _star(n, polarity)
    R, t = radial_pose(CAM, (700, 450), tilt, 70.0, fill=0.8, axis_deg=30, roll_deg=10)
    img = render_layers(CAM, R, t, star_layers(pen), blur_px=1.0, noise=2.0, gamma=2.2, lighting=0.3,
                        jpeg_quality=85, rng=1)
    found = detect_radial_edges(img, CAM, edges=2 * n, joint=joint)
    r, k = _residuals(found, pen, R, t)
    assert len(found) == 2 * n and np.unique(k).size == 2 * n
    assert np.hypot(*(found.vertex - CAM.undistort_pixels(CAM.project(t)))) < 0.02
    z = r / found.angle_sigma
    assert 0.5 < np.sqrt(np.mean(z**2)) < 1.5


def test_a_dense_star_steeply_tilted():
    """A 128-wedge star at 57 deg blurred by 1.3 px: on its far side neighbouring edges lie
    closer than CLEAR_SIGMAS blur sds over their whole length, and are located jointly with
    their neighbours (`radial_joint`): 224 of the 256 edges found (235 lines, 11 of them a
    second line on an edge already found), the vertex within 0.05 px, the angle errors about
    as large as their sigmas say (z rms 1.32). Located only where clear, 101 edges of 256."""
    pen = _star(128)
    R, t = radial_pose(CAM, (640, 480), 57.0, 70.0, fill=0.85, axis_deg=200, roll_deg=40)
    img = render_layers(CAM, R, t, star_layers(pen), blur_px=1.3, noise=2.0, gamma=2.2, lighting=0.3,
                        jpeg_quality=85, rng=2)
    found = detect_radial_edges(img, CAM, edges=256)
    r, k = _residuals(found, pen, R, t)
    assert np.unique(k).size >= 215 and len(found) - np.unique(k).size <= 15
    assert np.hypot(*(found.vertex - CAM.undistort_pixels(CAM.project(t)))) < 0.05
    z = r / found.angle_sigma
    assert 0.5 < np.sqrt(np.mean(z**2)) < 1.6


def test_joint_is_crowded_or_all():
    with pytest.raises(InputError, match="joint"):
        detect_radial_edges(np.zeros((60, 80), np.uint8), edges=20, joint="every")


def test_dartboard_in_its_clutter():
    """A dartboard with its wires, numbers and three darts: its sector boundaries found
    (the darts hide a few), and the ring of numbers, whose bars point at the bull, no
    boundary."""
    pen = dartboard_pencil()
    R, t = radial_pose(CAM, (620, 500), 45.0, 225.0, fill=0.85, axis_deg=70, roll_deg=5)
    img = render_layers(CAM, R, t, dartboard_layers(wires=True, numbers=True, darts=3, rng=4), blur_px=1.0,
                        noise=2.0, gamma=2.2, lighting=0.3, jpeg_quality=85, rng=4)
    found = detect_radial_edges(img, CAM, edges=20)
    r, k = _residuals(found, pen, R, t)
    on_boundary = np.abs(r) < np.radians(0.2)
    assert np.unique(k[on_boundary]).size >= 17
    assert len(found.circle_points) > 200



@pytest.mark.parametrize("seed,tilt,axis,roll,vertex,offset", [(0, 50.0, 70.0, 5.0, (620, 500), 1.2),
                                                              (2, 40.0, 320.0, 100.0, (600, 480), 1.8)])
def test_a_wire_side_beside_every_boundary(seed, tilt, axis, roll, vertex, offset):
    """A faint light line 1.2-2.6 mm beside every boundary in its dark sector, from 60 mm
    out to the double ring (a raised wire's side seen obliquely, as on the shared photographs:
    a quarter of the boundary's step): a companion of the boundary, not an edge nor its
    neighbour (`radial._companions`). Counted as a neighbour it left the boundaries nowhere
    clear: 17 and 13 of the 20 were used (measured before the rule); now every one, the
    normal within its sigmas."""
    pen = dartboard_pencil()
    R, t = radial_pose(CAM, vertex, tilt, 225.0, fill=0.85, axis_deg=axis, roll_deg=roll)
    side = []
    for k in range(20):
        a = np.radians(9.0 + 18.0 * k)
        u, n = np.array([np.cos(a), np.sin(a)]), np.array([-np.sin(a), np.cos(a)]) * (1.0 if k % 2 == 0 else -1.0)
        side.append(np.array([60 * u + offset * n, 168 * u + offset * n, 168 * u + (offset + 0.8) * n,
                              60 * u + (offset + 0.8) * n]))  # towards the dark sector
    layers = dartboard_layers(wires=True, numbers=True) + [(side, 0.2)]
    img = render_layers(CAM, R, t, layers, blur_px=1.0, noise=2.0, gamma=2.2, lighting=0.3, jpeg_quality=85, rng=seed)
    _, rec = orient_radial_edges(img, CAM, pen, edges=20)
    assert rec.ok and rec.spokes_used == 20
    err = np.degrees(np.arccos(np.clip(np.asarray(rec.normal) @ R[:, 2], -1, 1)))
    assert err < 4 * rec.normal_sigma_deg, (err, rec.normal_sigma_deg)

def test_edges_trimmed_at_the_double_ring():
    """The same cluttered dartboard oriented with its edges trimmed where the sectors end:
    the ring found for it (`spokes_end_ring`) is the double ring's outer edge (170 mm: the
    true ring's image within 3 px all round), no edge runs on more than a pixel or two past
    it, and no boundary is lost by the trim."""
    from pencilcal.toolkit.detect.image import GrayImage
    from pencilcal.toolkit.detect.radial_circles import spokes_end_ring
    from pencilcal.toolkit.pencil.circle import spokes_end
    from pencilcal.toolkit.pencil.orient import orient_segments

    pen = dartboard_pencil()
    R, t = radial_pose(CAM, (620, 500), 45.0, 225.0, fill=0.85, axis_deg=70, roll_deg=5)
    img = render_layers(CAM, R, t, dartboard_layers(wires=True, numbers=True, darts=3, rng=4), blur_px=1.0,
                        noise=2.0, gamma=2.2, lighting=0.3, jpeg_quality=85, rng=4)
    plain = detect_radial_edges(img, CAM, edges=20)
    rec0 = orient_segments(CAM, plain.segments, pen, angle_sigma=plain.angle_sigma, offset_sigma=plain.offset_sigma,
                           circle_points=plain.circle_points, keep_lines=True)
    rho_end, ratio = spokes_end(CAM, rec0, plain.segments, pen)
    C = spokes_end_ring(GrayImage(img), CAM, np.asarray(rec0.R_cam_from_target), np.asarray(rec0.lines["vertex"]),
                        pen.angles, rho_end, ratio, 2.2)
    a = np.linspace(0, 2 * np.pi, 360, endpoint=False)
    ring = CAM.undistort_pixels(CAM.project((R @ np.stack([170 * np.cos(a), 170 * np.sin(a), 0 * a])).T + t))
    vpx = CAM.undistort_pixels(CAM.project(t))
    u = (ring - vpx) / np.hypot(*(ring - vpx).T)[:, None]
    # the conic's distance along each ray from the vertex against the true ring's
    vh, uh = np.r_[vpx, 1.0], np.c_[u, np.zeros(len(u))]
    qa, qb, qc = np.einsum("ei,ij,ej->e", uh, C, uh), uh @ C @ vh, vh @ C @ vh
    rho = (-qb + np.sign(qa) * np.sqrt(qb * qb - qa * qc)) / qa
    assert np.max(np.abs(rho - np.hypot(*(ring - vpx).T))) < 3.0
    found, rec = orient_radial_edges(img, CAM, pen, edges=20)
    far = np.maximum(*(np.hypot(*(CAM.undistort_pixels(found.segments[:, 2 * i:2 * i + 2]) - vpx).T) for i in (0, 1)))
    # of the edges that cross the ring's radius at their direction: none beyond it by over 2 px
    d = 0.5 * (found.ideal[:, :2] + found.ideal[:, 2:]) - vpx
    r_ring = np.interp(np.arctan2(d[:, 1], d[:, 0]), np.arctan2(u[:, 1], u[:, 0]), np.hypot(*(ring - vpx).T),
                       period=2 * np.pi)
    inside = np.hypot(*d.T) < r_ring
    assert np.all(far[inside] < r_ring[inside] + 2.0)
    assert rec.spokes_used >= rec0.spokes_used

def test_circle_points_hold_the_outline():
    """Of the edge points across rays, those of the star's outline lie on the image of the
    circle of radius 70 mm about the vertex, within 0.3 px."""
    pen = _star(32)
    R, t = radial_pose(CAM, (640, 480), 35.0, 70.0, fill=0.75, axis_deg=-20, roll_deg=40)
    img = render_layers(CAM, R, t, star_layers(pen), blur_px=1.0, noise=2.0, gamma=2.2, jpeg_quality=85, rng=2)
    found = detect_radial_edges(img, CAM, edges=64)
    pts = CAM.undistort_pixels(found.circle_points)
    a = np.linspace(0, 2 * np.pi, 3600, endpoint=False)
    circle = CAM.undistort_pixels(CAM.project((R @ np.stack([70 * np.cos(a), 70 * np.sin(a), 0 * a])).T + t))
    dist = np.min(np.hypot(pts[:, None, 0] - circle[None, :, 0], pts[:, None, 1] - circle[None, :, 1]), 1)
    on = dist < 0.3
    assert on.sum() >= 24  # a point at the tip of each of the 32 wedges but those cut off


def test_a_star_beside_a_board():
    """The star of `pencilcal target --star` beside its ChArUco board: the vertex is the
    star's, where edges of every direction meet, not a corner of the board, whose rows of
    square edges pass through it from two."""
    from tests.helpers import star_sheet_view

    img, cam, sheet, R, t = star_sheet_view(32, 30.0, 260.0)
    found = detect_radial_edges(img, cam, edges=64)
    assert len(found) == 64
    v3 = np.r_[sheet.pencil.vertex, 0.0]
    assert np.hypot(*(found.vertex - cam.undistort_pixels(cam.project(R @ v3 + t)))) < 0.1


@pytest.mark.parametrize("blur,start", [(0.7, 1.2), (1.3, 1.1)])
def test_the_joint_location_fits_the_blur(blur, start):
    """The blur the joint location fits, from a start 20-30 % off: the render's Gaussian with
    the pixel's and bilinear sampling's spread, sqrt(blur^2 + 1/4) px, within 3 %; measured on
    the image (`_edge_blur`) it was 3-26 % off on 128-wedge renders, and every edge of a dense
    star moved with it."""
    from pencilcal.toolkit.detect.image import GrayImage
    from pencilcal.toolkit.detect.radial_joint import joint_refit

    pen = _star(64)
    cam = Camera("pinhole", 480, 360, [[400.0, 0, 239.5], [0, 400.0, 179.5], [0, 0, 1]])
    R, t = radial_pose(cam, (240, 180), 0.0, 70.0, fill=0.9)
    img = GrayImage(render_layers(cam, R, t, star_layers(pen), blur_px=blur, noise=1.0, rng=3))
    a = np.arange(128) * np.pi / 64 - np.pi / 128  # frontal: the image angles are the plane's
    sign = np.where(np.arange(128) % 2 == 0, -1.0, 1.0)
    u = np.stack([np.cos(a), np.sin(a)], -1)
    v = np.array([240.0, 180.0])
    fit, fitted = joint_refit(img, None, np.concatenate([v + 0 * u, v + 100 * u], -1), v, sign,
                              start * np.hypot(blur, 0.5), np.full(128, 25.0), np.full(128, 150.0))
    assert fit.ok.all()
    assert abs(fitted / np.hypot(blur, 0.5) - 1) < 0.03, fitted
    _, held = joint_refit(img, None, np.concatenate([v + 0 * u, v + 100 * u], -1), v, sign, 1.0,
                          np.full(128, 25.0), np.full(128, 150.0), fit_blur=False)
    assert held == 1.0


def test_blur_scale_follows_the_lens():
    """Barrel distortion shrinks the raw image more along the radius than across it: an edge
    blurred by 1 raw px is blurred by more working px, the more so across a tangential edge
    (its normal along the radius); 1 at the centre and without a camera."""
    from pencilcal.toolkit.detect.working import blur_scale

    x = np.array([[643.1, 1043.1]]), np.array([[477.4, 477.4]])  # the centre, 400 px right of it
    radial = blur_scale(CAM, *x, np.ones((1, 1)), np.zeros((1, 1)))  # normal along the radius
    across = blur_scale(CAM, *x, np.zeros((1, 1)), np.ones((1, 1)))
    assert np.allclose([radial[0, 0], across[0, 0]], 1.0, atol=1e-6)
    assert radial[0, 1] > across[0, 1] > 1.0
    # k1 -0.2 at r = 0.4: tangential scale 1 + k1 r^2 = 0.968, radial 1 + 3 k1 r^2 = 0.904 (their inverses)
    r2 = (400 / 1000.0) ** 2
    assert np.isclose(across[0, 1], 1 / (1 - 0.2 * r2), rtol=2e-3) and np.isclose(radial[0, 1], 1 / (1 - 0.6 * r2), rtol=2e-3)


def test_the_trims_second_pass_reuses_the_first():
    """With a memo the second pass (`outer`) starts from the edges the first located and
    gives what a detection from scratch gives, bit for bit; the memo is not used for other
    options. On a dartboard whose print beyond the double ring runs on along its boundaries,
    where the trim changes edges."""
    from dataclasses import fields

    from pencilcal.toolkit.detect.edges import DEFAULT_GAMMA
    from pencilcal.toolkit.detect.image import GrayImage
    from pencilcal.toolkit.detect.radial import _sector_boundaries
    from pencilcal.toolkit.detect.radial_circles import spokes_end_ring
    from pencilcal.toolkit.pencil.circle import spokes_end
    from pencilcal.toolkit.pencil.orient import orient_segments
    from tests.helpers import dartboard_with_print

    img, cam, pen, _, _ = dartboard_with_print()
    memo = {}
    first = detect_radial_edges(img, cam, edges=20, memo=memo)
    rec = orient_segments(cam, first.segments, pen, angle_sigma=first.angle_sigma, offset_sigma=first.offset_sigma,
                          circle_points=first.circle_points, keep_lines=True)
    # the ring where the spokes end, found on the image as `trimmed_at_spokes_end` finds it
    end = spokes_end(cam, rec, first.segments, pen)
    assert end is not None and set(memo) == {"of", "key", "located"}
    C = spokes_end_ring(GrayImage(img), cam, np.asarray(rec.R_cam_from_target, float),
                        np.asarray(rec.lines["vertex"], float), _sector_boundaries(pen), end[0], end[1], DEFAULT_GAMMA)
    assert C is not None

    def same(a, b):
        return all(np.array_equal(getattr(a, f.name), getattr(b, f.name)) for f in fields(a))

    trimmed = detect_radial_edges(img, cam, edges=20, outer=C, memo=memo)
    assert same(trimmed, detect_radial_edges(img, cam, edges=20, outer=C)) and not same(trimmed, first)
    other = detect_radial_edges(img, cam, edges=20, outer=C, memo=memo, min_length=40.0)
    assert same(other, detect_radial_edges(img, cam, edges=20, outer=C, min_length=40.0))
    assert memo["key"][1] == 40.0  # the memo now holds those options' edges


def test_the_joint_location_follows_motion_blur(monkeypatch):
    """A star smeared by a 3 px motion along 30 deg (over a 0.7 px Gaussian): the blur across
    an edge is widest where the edge's normal lies along the motion, and the joint location's
    blur model has a covariance (`radial_joint.DIRECTIONAL_BLUR`). Edges 1-3 px apart near the
    vertex: one sd for every edge left them 0.009 deg rms off, 1.4 times their sigmas; the
    directional blur (switched on here) 0.004 deg, 0.9 times."""
    import cv2

    from pencilcal.toolkit.detect.image import GrayImage
    from pencilcal.toolkit.detect.radial_joint import joint_refit
    from pencilcal.toolkit.detect import radial_joint
    from pencilcal.toolkit.synth.radial_photo import _motion_kernel

    monkeypatch.setattr(radial_joint, "DIRECTIONAL_BLUR", True)  # off by default (measured mixed on photographs)

    pen = pencil_from_dict({"start_deg": 0, "step_deg": 360 / 64, "count": 64, "shape": "wedge", "radius": [0, 60]})
    cam = Camera("pinhole", 480, 360, [[400.0, 0, 239.5], [0, 400.0, 179.5], [0, 0, 1]])
    R, t = radial_pose(cam, (240, 180), 0.0, 60.0, fill=0.9)
    sharp = render_layers(cam, R, t, star_layers(pen), blur_px=0.7).astype(float)
    img = cv2.filter2D(sharp, -1, _motion_kernel(3.0, np.radians(30.0)))
    img = GrayImage(np.clip(img + np.random.default_rng(0).normal(0, 0.5, img.shape), 0, 255).astype(np.float32))
    a = np.arange(128) * np.pi / 64 - np.pi / 128  # frontal: the image angles are the plane's
    sign = np.where(np.arange(128) % 2 == 0, -1.0, 1.0)
    u = np.stack([np.cos(a + 0.002), np.sin(a + 0.002)], -1)
    v = np.array([240.0, 180.0])
    fit, _ = joint_refit(img, None, np.concatenate([v + 0 * u, v + 100 * u], -1), v, sign, 1.0,
                         np.full(128, 20.0), np.full(128, 150.0))
    err = np.angle(np.exp(1j * (np.arctan2(*(fit.p2 - fit.p1)[:, ::-1].T) - np.where(sign > 0, a, a + np.pi))))
    assert fit.ok.all()
    assert np.degrees(np.sqrt(np.mean(err ** 2))) < 0.006
    assert np.sqrt(np.mean((err / fit.angle_sigma) ** 2)) < 1.15
