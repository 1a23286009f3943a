"""Cameras, poses and edge measurements shared by the tests of toolkit/synth."""
from __future__ import annotations

import numpy as np

from pencilcal.toolkit.camera.model import Camera
from pencilcal.toolkit.geometry.frames import rotation_about_axis


def small_camera(model):
    """640x480 cameras with strong distortion (the edge tests want curved edges)."""
    if model == "fisheye":
        return Camera("fisheye", 640, 480, [[260.0, 0, 321.3], [0, 260.2, 238.2], [0, 0, 1]],
                      [0.03, -0.01, 0.002, -0.0005])
    K = [[520.0, 0, 321.3], [0, 520.4, 238.2], [0, 0, 1]]
    if model == "opencv":
        return Camera("opencv", 640, 480, K, [-0.3, 0.12, 0.0005, -0.0003, -0.02])
    return Camera("pinhole", 640, 480, K)


def board_pose(tilt_deg, distance, spin=0.2):
    R = rotation_about_axis([1.0, 0.3, 0.0], np.radians(tilt_deg)) @ rotation_about_axis([0, 0, 1.0], spin)
    return R, np.array([0.0, 0.0, distance]) - R @ np.array([87.5, 62.5, 0.0])


def true_edge_x(camera, R, t, rows, line_point, line_dir, lim_deg=None):
    """Band-averaged x of the projected target line over each pixel row [v - 0.5, v + 0.5]."""
    s = np.linspace(-3000.0, 3000.0, 600001)
    P = (np.asarray(line_point) + s[:, None] * np.asarray(line_dir)) @ R.T + t
    px = camera.project(P)
    # keep the part of the line the lens model maps faithfully (inside the image's field)
    corners = np.array([[0, 0], [camera.width - 1, 0], [0, camera.height - 1], [camera.width - 1, camera.height - 1.0]])
    max_angle = np.max(np.arccos(camera.rays_from_pixels(corners)[:, 2]))
    ang = np.arccos(P[:, 2] / np.linalg.norm(P, axis=1))
    ok = np.all(np.isfinite(px), 1) & (ang <= max_angle)
    px = px[ok][np.argsort(px[ok][:, 1])]
    out = []
    for v in rows:
        if not px[0, 1] < v - 1 < v + 1 < px[-1, 1]:
            out.append(np.nan)  # the sampled part of the line does not reach this row
            continue
        yy = np.linspace(v - 0.5, v + 0.5, 101)
        out.append(np.interp(yy, px[:, 1], px[:, 0]).mean())
    return np.array(out)


def area_edge(row_values, a):
    """Edge position along a row from the pixel-integrated profile (values 0 left of the
    edge, 1 right of it, starting at column a): the 50 % crossing of the box-filtered
    edge, exact for a straight edge whatever its angle."""
    return a - 0.5 + np.sum(1.0 - row_values)
