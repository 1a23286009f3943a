"""Synthetic pencils seen by real-looking cameras, with exact truth, for the tests."""
from __future__ import annotations

import numpy as np

from pencilcal.toolkit.camera.model import Camera
from pencilcal.toolkit.geometry.frames import rotation_about_axis, rotation_to_z
from pencilcal.toolkit.pencil.spec import Pencil, project_spokes

Z = np.array([0.0, 0.0, 1.0])


def hd_camera(model="opencv"):
    """A 1920x1080 camera with strong distortion (as the contract check uses)."""
    K = np.array([[1500.0, 0, 955.0], [0, 1498.0, 545.0], [0, 0, 1]])
    if model == "opencv":
        return Camera("opencv", 1920, 1080, K, np.array([-0.3, 0.12, 0.0005, 0.0002, -0.02]))
    if model == "fisheye":
        return Camera("fisheye", 1920, 1080, np.array([[700.0, 0, 955.0], [0, 700.0, 545.0], [0, 0, 1]]),
                      np.array([0.05, -0.01, 0.003, -0.001]))
    return Camera("pinhole", 1920, 1080, K)


def fan(radius=(10.0, 50.0), vertex=(0.0, 0.0), count=8, step=20.0):
    return Pencil(np.radians(np.arange(count) * step), np.asarray(vertex, float),
                  None if radius is None else np.asarray(radius, float))


def pose_facing(camera, pixel, tilt_deg, depth, rng):
    """R, t with the vertex (target origin) imaged at `pixel`, tilted by `tilt_deg` from its ray."""
    ray = camera.rays_from_pixels(np.asarray(pixel, float))
    R = (rotation_to_z(ray).T @ rotation_about_axis(Z, rng.uniform(0, 2 * np.pi))
         @ rotation_about_axis([1.0, 0, 0], np.radians(tilt_deg)) @ rotation_about_axis(Z, rng.uniform(0, 2 * np.pi)))
    return R, ray * depth / ray[2]


def frame(camera, pencil, tilt_deg, depth, rng, noise_px=0.0, margin=20, tries=200, radii=(10.0, 50.0)):
    """Segments of a pencil fully inside the image. Returns (segments, R, t).

    The spokes run over the pencil's radius, or over `radii` when it has none.
    """
    for _ in range(tries):
        px = rng.uniform([400, 250], [camera.width - 400, camera.height - 250])
        R, t = pose_facing(camera, px, tilt_deg, depth, rng)
        seg = project_spokes(camera, R, t, pencil, None if pencil.radius is not None else radii)
        inside = (seg[:, 0::2].min() > margin and seg[:, 0::2].max() < camera.width - margin
                  and seg[:, 1::2].min() > margin and seg[:, 1::2].max() < camera.height - margin)
        if inside:
            return seg + noise_px * rng.normal(size=seg.shape), R, t
    raise RuntimeError("no pose keeps the pencil inside the image")


def two_spokes_and_a_stray(camera, pencil, rng, tilt_range=(70.0, 80.0), depth=300.0, noise_px=0.3):
    """Two spokes of `pencil` at a grazing tilt and a stray edge through the vertex's image
    (25-60 deg off a spoke, 60-240 px long): three lines that fit every labelling exactly.
    Returns (segments (3, 4), R, t)."""
    seg, R, t = frame(camera, pencil, rng.uniform(*tilt_range), depth, rng, noise_px=noise_px)
    keep = rng.choice(len(pencil.angles), 2, replace=False)
    v = camera.project(t)
    d = seg[keep[0], 2:] - v
    ang = np.arctan2(d[1], d[0]) + np.radians(rng.choice([-1, 1]) * rng.uniform(25, 60))
    u = np.array([np.cos(ang), np.sin(ang)])
    stray = np.r_[v + rng.uniform(20, 60) * u, v + rng.uniform(120, 260) * u]
    return np.r_[seg[keep], stray[None]], R, t


def clutter_segments(camera, k, rng, length=(20.0, 300.0)):
    """k random segments anywhere in the image: uniform centres and directions, lengths
    uniform in `length` [px]. Returns (k, 4) raw pixels."""
    c = rng.uniform([0.0, 0.0], [camera.width, camera.height], (k, 2))
    a = rng.uniform(0.0, np.pi, k)
    d = np.stack([np.cos(a), np.sin(a)], -1) * rng.uniform(*length, k)[:, None] / 2
    return np.c_[c - d, c + d]


def star_sheet_view(wedges, tilt_deg, distance, rng=0):
    """`pencilcal target --star` (the default A4 layout) as the default 1280x960 camera sees
    it from `distance` mm, `tilt_deg` from the star's axis, through a webcam's blur, noise,
    uneven light and gamma 2.2: (image, camera, sheet, R_cam_from_target, t_cam_from_target)."""
    from pencilcal.toolkit.synth.render import render_frame

    cam, sheet, R, t = _star_sheet_pose(wedges, tilt_deg, distance)
    img = render_frame(cam, R, t, sheet, blur_px=1.0, noise=2.0, gamma=2.2, lighting=0.3, rng=rng)
    return img, cam, sheet, R, t


def _star_sheet_pose(wedges, tilt_deg, distance):
    """(camera, sheet, R_cam_from_target, t_cam_from_target) of `star_sheet_view`."""
    from pencilcal.toolkit.synth.scenarios import default_camera, look_at
    from pencilcal.toolkit.synth.sheet import layout_sheet

    sheet = layout_sheet(star=wedges)
    cam = default_camera("opencv", (1280, 960))
    v3 = np.r_[sheet.pencil.vertex, 0.0]
    tilt = np.radians(tilt_deg)
    R, t = look_at(v3 + distance * np.array([0.6 * np.sin(tilt), -0.8 * np.sin(tilt), -np.cos(tilt)]),
                   0.3 * sheet.content_center + 0.7 * v3)
    return cam, sheet, R, t


def star_sheet_photo(wedges, tilt_deg, distance, rng=0):
    """`star_sheet_view`'s sheet photographed as a webcam does (`synth.radial_photo`): paper
    texture (3 %) and a printer's banding (3 %, 6 mm), the light's gradient (+-35 %) and
    vignetting, a Gaussian blur of 0.8 px, a defocus growing from 0.6 to 2.5 px across the
    star, 1 px of motion blur, noise, the camera's sharpening halos and JPEG 75:
    (image, camera, sheet, R_cam_from_target, t_cam_from_target)."""
    from pencilcal.toolkit.synth.radial_photo import banding, paper_texture, photo_sensor
    from pencilcal.toolkit.synth.render import render_scene

    cam, sheet, R, t = _star_sheet_pose(wedges, tilt_deg, distance)
    rng = np.random.default_rng(rng)
    lin = render_scene(cam, R, t, sheet)[..., 0] * paper_texture(cam, R, t, 0.03, rng) * banding(cam, R, t, 0.03, 6.0,
                                                                                                  0.0, 1.0)
    v = R @ np.r_[sheet.pencil.vertex, 0.0] + t
    x, y = cam.distort_pixels((np.asarray(cam.K, float)[:2, :2] @ (v[:2] / v[2]) + np.asarray(cam.K, float)[:2, 2])[None])[0]
    cond = dict(shading=0.5, shading_deg=30.0, vignette=0.4, blur_px=0.8, defocus_px=0.6, defocus_far_px=2.5,
                focus_px=[x - 200.0, y, 0.0, 400.0], motion_px=1.0, motion_deg=20.0, noise=2.5, sharpen=0.8,
                sharpen_px=1.2, jpeg=75)
    return photo_sensor(lin, cond, rng), cam, sheet, R, t


def dartboard_with_print():
    """A dartboard with its wires and, beyond the double ring, a maker's print of light
    sectors turned 2 deg from the boundaries (every other sector's), running on along them,
    as a 1280x960 webcam (k1 -0.2) sees it tilted 45 deg through blur, noise, uneven light,
    gamma 2.2 and JPEG 85: (image, camera, pencil, R_cam_from_target, t_cam_from_target)."""
    from pencilcal.toolkit.synth.polygons import annular_sector
    from pencilcal.toolkit.synth.radial import (DARTBOARD, dartboard_layers, dartboard_pencil, radial_pose,
                                                render_layers)

    cam = Camera("opencv", 1280, 960, [[1000.0, 0, 643.1], [0, 1000.5, 477.4], [0, 0, 1]], [-0.2, 0.0, 0.0, 0.0])
    R, t = radial_pose(cam, (620, 500), 45.0, 225.0, fill=0.85, axis_deg=70, roll_deg=5)
    a0 = np.radians(-97.0 + 36.0 * np.arange(10))
    print_ring = [annular_sector(176.0, 200.0, a, a + np.radians(18.0)) for a in a0]
    img = render_layers(cam, R, t, dartboard_layers(wires=True) + [(print_ring, DARTBOARD["cream"])], blur_px=1.0,
                        noise=2.0, gamma=2.2, lighting=0.3, jpeg_quality=85, rng=4)
    return img, cam, dartboard_pencil(), R, t
