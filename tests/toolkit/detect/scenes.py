"""Synthetic scenes for the detector tests: rendered planes with dark polygons, printed
fans of bars, single edges, and the comparison of found lines with the truth.

Synthetic images (`render_plane`): convex dark polygons on a bright plane seen by a camera,
rendered per pixel from the exact geometry: the ray of every raw pixel is intersected with
the plane, each polygon edge's signed distance is converted to pixels through its gradient
on the pixel grid (first order, exact at the edge), and the coverage is
Phi(d / s) with s = sqrt(blur^2 + 1/12): a Gaussian blur of `blur` px after integration over
the pixel's area (the box's variance is 1/12 in every direction; the small difference in
shape is symmetric, so it moves no edge). Corners use inclusion-exclusion of the half
planes (approximate within ~2 px of a corner only). Noise N(0, 2) grey levels, then uint8.
"""
from __future__ import annotations

import numpy as np
from scipy.special import ndtr

from pencilcal.toolkit.pencil.spec import Pencil, project_spokes
from tests.helpers import pose_facing


def normalized_grid(camera, u0, v0, u1, v1):
    """Normalised coordinates (H, W, 2) of the raw pixels [u0, u1) x [v0, v1)."""
    import cv2

    v, u = np.mgrid[v0:v1, u0:u1].astype(float)
    px = np.stack([u, v], -1)
    if camera.model == "opencv":
        # OpenCV's iterative undistortion run to convergence agrees with Camera to 1e-11 px
        # and is ~5x faster on a million pixels
        crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-15)
        return cv2.undistortPoints(px.reshape(-1, 1, 2), camera.K, camera.dist, criteria=crit).reshape(px.shape)
    return camera.normalized_from_pixels(px)


def edge_px(dist):
    """A smooth signed distance field on the pixel grid, in pixels (first order)."""
    gy, gx = np.gradient(dist)
    return dist / np.maximum(np.hypot(gx, gy), 1e-300)


def render_plane(camera, R, t, polygons, *, blur=1.0, noise=2.0, bright=210.0, dark=40.0, rng=None, margin=12):
    """uint8 image of dark convex polygons (target-plane (K, 2) vertex lists, length units) on
    a bright plane with pose R, t (R_cam_from_target, t_cam_from_target)."""
    R, t = np.asarray(R, float), np.asarray(t, float)
    H, W = camera.height, camera.width
    img = np.full((H, W), float(bright))
    allv = np.concatenate([np.asarray(p, float) for p in polygons])
    px = camera.project(np.c_[allv, np.zeros(len(allv))] @ R.T + t)
    u0, v0 = np.maximum(np.floor(px.min(0)) - margin, 0).astype(int)
    u1, v1 = np.minimum(np.ceil(px.max(0)) + margin + 1, [W, H]).astype(int)
    x = normalized_grid(camera, u0, v0, u1, v1)
    ray = np.concatenate([x, np.ones_like(x[..., :1])], -1)
    lam = (R[:, 2] @ t) / (ray @ R[:, 2])
    ab = (lam[..., None] * ray - t) @ R[:, :2]  # target-plane coordinates of each pixel
    s = np.sqrt(blur**2 + 1.0 / 12.0)
    alpha = np.zeros(ab.shape[:2])
    for poly in polygons:
        P = np.asarray(poly, float)
        c = P.mean(0)
        a = np.ones(ab.shape[:2])
        for k in range(len(P)):
            p, q = P[k], P[(k + 1) % len(P)]
            d = q - p
            n = np.array([-d[1], d[0]]) / np.hypot(*d)
            if n @ (c - p) < 0:
                n = -n  # inward
            a -= 1.0 - ndtr(edge_px((ab - p) @ n) / s)
        alpha += np.clip(a, 0.0, 1.0)
    img[v0:v1, u0:u1] = bright - (bright - dark) * np.minimum(alpha, 1.0)
    if noise and rng is not None:
        img = img + rng.normal(0.0, noise, img.shape)
    return np.clip(np.round(img), 0, 255).astype(np.uint8)


def bar_polygons(pencil, width=None):
    """Target-plane rectangles (4, 2) of a pencil's bars (width: the bar width, length unit)."""
    w = pencil.width if width is None else width
    V = np.zeros(2) if pencil.vertex is None else pencil.vertex
    out = []
    for th in pencil.angles:
        e, f = np.array([np.cos(th), np.sin(th)]), np.array([-np.sin(th), np.cos(th)])
        r0, r1 = pencil.radius
        out.append(np.array([V + r0 * e - w / 2 * f, V + r1 * e - w / 2 * f, V + r1 * e + w / 2 * f,
                             V + r0 * e + w / 2 * f]))
    return out


def fan_scene(camera, rng, tilt_deg=30.0, depth=250.0, pixel=None, width=1.5, noise=2.0, extra=()):
    """A rendered fan of 8 bars (20 deg apart, radius 10..50, `width` wide) and its truth.

    Returns (image, pencil, R, t, true_ideal (8, 4) spoke centre lines in undistorted px)."""
    pen = Pencil(np.radians(np.arange(8) * 20.0), np.zeros(2), np.array([10.0, 50.0]), width)
    if pixel is None:
        pixel = rng.uniform([0.4 * camera.width, 0.4 * camera.height], [0.6 * camera.width, 0.6 * camera.height])
    R, t = pose_facing(camera, pixel, tilt_deg, depth, rng)
    img = render_plane(camera, R, t, bar_polygons(pen) + list(extra), noise=noise, rng=rng)
    raw = project_spokes(camera, R, t, pen)
    ideal = camera.undistort_pixels(raw.reshape(-1, 2)).reshape(-1, 4)
    return img, pen, R, t, ideal


def line_errors(found, truth):
    """For each found ideal segment: (index of the nearest true line, perpendicular distances
    of its two ends [px], angle error [rad] as lines, along-line positions of its ends
    relative to the true segment's ends [px])."""
    out = []
    for q in np.asarray(found, float):
        best = None
        for j, tr in enumerate(np.asarray(truth, float)):
            d = tr[2:] - tr[:2]
            L = np.hypot(*d)
            u = d / L
            n = np.array([-u[1], u[0]])
            dist = np.array([n @ (q[:2] - tr[:2]), n @ (q[2:] - tr[:2])])
            if best is None or np.abs(dist).max() < np.abs(best[1]).max():
                qa = np.arctan2(q[3] - q[1], q[2] - q[0])
                ang = np.angle(np.exp(2j * (qa - np.arctan2(d[1], d[0])))) / 2
                al = np.sort([u @ (q[:2] - tr[:2]), u @ (q[2:] - tr[:2])]) - np.array([0.0, L])
                best = (j, dist, ang, al)
        out.append(best)
    return out


def edge_image(theta, rng, shape=(240, 320), centre=None, half_length=90.0, blur=1.0, noise=2.0):
    """A bright rectangle, 2 half_length long along theta and 0.35 times as deep, whose long
    side through `centre` is the edge; returns (uint8 image, centre, unit direction)."""
    H, W = shape
    c = np.array([W / 2, H / 2]) + rng.uniform(-1, 1, 2) if centre is None else np.asarray(centre, float)
    d = np.array([np.cos(theta), np.sin(theta)])
    n = np.array([-d[1], d[0]])
    v, u = np.mgrid[0:H, 0:W].astype(float)
    p = np.stack([u - c[0], v - c[1]], -1)
    s = np.sqrt(blur**2 + 1.0 / 12.0)
    across = ndtr((p @ n) / s)  # bright on the +n side
    along = ndtr((half_length - np.abs(p @ d)) / s)  # the edge ends (ends are blurred too)
    depth = ndtr((max(0.35 * 2 * half_length, 30.0) - p @ n) / s)
    img = 60.0 + 140.0 * np.clip(across + along + depth - 2.0, 0, 1) + rng.normal(0, noise, (H, W))
    return np.clip(np.round(img), 0, 255).astype(np.uint8), c, d
