"""Radial targets with exact truth: a Siemens star and a dartboard, and what a webcam makes of
them.

A radial target is drawn as *layers*: lists of polygons in the target frame (mm, the pencil's
frame: spoke k along ``(cos theta_k, sin theta_k)`` from the vertex) with one linear
reflectance each, painted in order over a uniform ground (`render_layers`). Every polygon is
scan-converted with exact area coverage through the camera's lens model (raster.py), so the
edges lie where the projected truth puts them; then the sensor model of `render.sensor_image`
(uneven light, blur, gamma, noise) and, as a webcam stores its frames, JPEG.

- `star_layers`: a Siemens star of wedges from the vertex to the pencil's outer radius (their
  outer ends arcs of the outline circle), dark on light or light on dark.
- `dartboard_pencil`, `dartboard_layers`: a regulation steel-tip board (20 sectors of 18 deg
  alternating black and cream, the "20" sector at the top; treble and double rings red and
  green, the bulls), with its wires, numbers and darts as clutter when asked for.
- `radial_pose`: the pose that shows a target's vertex at a chosen pixel, tilted by a chosen
  angle against its viewing ray.

Example
-------
>>> from pencilcal.toolkit.camera.model import Camera
>>> from pencilcal.toolkit.pencil.spec import pencil_from_dict
>>> star = pencil_from_dict({"start_deg": 0, "step_deg": 22.5, "count": 16, "shape": "wedge",
...                          "radius": [0, 40], "circles": [40]})
>>> cam = Camera("pinhole", 160, 120, [[150.0, 0, 79.5], [0, 150.0, 59.5], [0, 0, 1]])
>>> R, t = radial_pose(cam, (79.5, 59.5), 30.0, 40.0, fill=0.8)
>>> img = render_layers(cam, R, t, star_layers(star), noise=1.0, rng=0)
>>> img.shape, int(img[60, 80 + 20]) < int(img[60 + 20, 80 + 3])    # spoke 0 dark, a gap light
((120, 160), True)
"""
from __future__ import annotations

import numpy as np

from pencilcal.toolkit.errors import InputError
from pencilcal.toolkit.geometry.frames import rotation_from_rotvec
from pencilcal.toolkit.pencil.spec import Pencil
from pencilcal.toolkit.synth.polygons import annular_sector
from pencilcal.toolkit.synth.raster import target_coverage
from pencilcal.toolkit.synth.render import REFLECTANCE, sensor_image

__all__ = ["DARTBOARD", "star_layers", "dartboard_pencil", "dartboard_layers", "render_layers", "linear_layers",
           "radial_pose"]

#: A regulation steel-tip dartboard [mm] and its shades (linear reflectance of its colours'
#: luminance): 20 sectors of 18 deg, their boundaries on lines through the centre at
#: 9 + 18 k deg (the target frame's y runs down the board: the "20" sector, black, is
#: centred at -90 deg); the rings' radii, inner bull to the board's edge.
DARTBOARD = {
    "inner_bull": 6.35, "outer_bull": 15.9, "treble": (99.0, 107.0), "double": (162.0, 170.0), "board": 225.5,
    "black": 0.035, "cream": 0.70, "red": 0.12, "green": 0.17, "wire": 0.45, "number": 0.60,
}

def _ring(r0, r1):
    """An annulus as 36 annular sectors (each a simple polygon)."""
    edges = np.linspace(0.0, 2 * np.pi, 37)
    return [annular_sector(r0, r1, a, b) for a, b in zip(edges[:-1], edges[1:])]


def star_layers(pencil, *, ink=REFLECTANCE["ink"], paper=REFLECTANCE["paper"]):
    """The layers of a Siemens star: the pencil's wedges (shape "wedge") from its vertex to its
    outer radius, dark (`ink`) on a light disc (`paper`), or light wedges on a dark disc
    (polarity "light"). Returns [(polygons [(K, 2) mm], reflectance)], the disc first."""
    if pencil.shape != "wedge" or pencil.radius is None:
        raise InputError("a Siemens star needs a pencil of shape wedge with a radius")
    v = np.zeros(2) if pencil.vertex is None else np.asarray(pencil.vertex, float)
    r = float(pencil.radius[1])
    h = 0.5 * pencil.wedge
    wedges = [v + annular_sector(0.0, r, th - h, th + h) for th in pencil.angles]
    fg, bg = (ink, paper) if pencil.polarity != "light" else (paper, ink)
    return [([v + p for p in _ring(0.0, r * 1.15)], bg), (wedges, fg)]


def dartboard_pencil():
    """The dartboard's pencil: 20 sector boundaries at 9 + 18 k deg (shape "edge"; the sector
    that starts at the first, 9 to 27 deg (the "10"), is black: polarity "dark"), running from
    the outer bull to the double ring, with its rings as circles."""
    d = DARTBOARD
    angles = np.radians(9.0 + 18.0 * np.arange(20))
    circles = np.array([d["inner_bull"], d["outer_bull"], *d["treble"], *d["double"]])
    return Pencil(angles, np.zeros(2), np.array([d["outer_bull"], d["double"][1]]), None, "edge", None, "dark",
                  circles)


def dartboard_layers(*, wires=False, numbers=False, darts=0, rng=None):
    """The layers of a dartboard (`DARTBOARD`), centred on the origin.

    wires: the raised wires as light bands 1 mm wide along the sector boundaries and the
    rings (drawn in the plane: real ones stand ~1.5 mm proud of it); numbers: the ring of
    numbers as light bars beyond the double ring; darts: so many dark darts (a barrel and
    a flight, 60-90 mm long) stuck in the board at random, drawn from `rng`."""
    d = DARTBOARD
    step = np.radians(18.0)
    black, cream, red, green = d["black"], d["cream"], d["red"], d["green"]
    sectors = {"black": [], "cream": [], "red": [], "green": []}
    for k in range(20):
        a0 = np.radians(-99.0) + k * step  # sector k, the "20" (black) first
        dark = k % 2 == 0
        for r0, r1 in ((d["outer_bull"], d["treble"][0]), (d["treble"][1], d["double"][0])):
            sectors["black" if dark else "cream"].append(annular_sector(r0, r1, a0, a0 + step))
        for r0, r1 in (d["treble"], d["double"]):
            sectors["red" if dark else "green"].append(annular_sector(r0, r1, a0, a0 + step))
    layers = [(_ring(0.0, d["board"]), black), (sectors["black"], black), (sectors["cream"], cream),
              (sectors["red"], red), (sectors["green"], green), (_ring(d["inner_bull"], d["outer_bull"]), green),
              (_ring(0.0, d["inner_bull"]), red)]
    if wires:
        polys = []
        for k in range(20):
            a = np.radians(9.0) + k * step
            u, n = np.array([np.cos(a), np.sin(a)]), np.array([-np.sin(a), np.cos(a)]) * 0.5
            p0, p1 = d["outer_bull"] * u, d["double"][1] * u
            polys.append(np.array([p0 - n, p1 - n, p1 + n, p0 + n]))
        for r in (d["outer_bull"], *d["treble"], *d["double"]):
            polys += _ring(r - 0.5, r + 0.5)
        layers.append((polys, d["wire"]))
    if numbers:
        polys = []
        for k in range(20):  # one light bar per number, across the ring of numbers
            a = np.radians(-90.0) + k * step
            u, n = np.array([np.cos(a), np.sin(a)]), np.array([-np.sin(a), np.cos(a)])
            c = 195.0 * u
            polys.append(np.array([c - 10 * u - 2 * n, c + 10 * u - 2 * n, c + 10 * u + 2 * n, c - 10 * u + 2 * n]))
        layers.append((polys, d["number"]))
    if darts:
        rng = np.random.default_rng(rng)
        polys = []
        for _ in range(int(darts)):
            r, a, b = rng.uniform(20, 160), rng.uniform(0, 2 * np.pi), rng.uniform(0, 2 * np.pi)
            tip = r * np.array([np.cos(a), np.sin(a)])
            u, n = np.array([np.cos(b), np.sin(b)]), np.array([-np.sin(b), np.cos(b)])
            L = rng.uniform(60, 90)
            polys.append(np.array([tip - 2 * n, tip + L * u - 3 * n, tip + L * u + 3 * n, tip + 2 * n]))
            polys.append(np.array([tip + L * u, tip + (L + 25) * u - 9 * n, tip + (L + 30) * u,
                                   tip + (L + 25) * u + 9 * n]))
        layers.append((polys, 0.02))
    return layers


def render_layers(camera, R_cam_from_target, t_cam_from_target, layers, *, background=0.3, blur_px=0.0, noise=0.0,
                  lighting=0.0, gamma=1.0, exposure=1.0, jpeg_quality=None, rng=None):
    """Render target layers as `camera` sees them: (H, W) uint8.

    layers: [(polygons [(K, 2) target mm], reflectance)], painted in order (each over what is
    already there) on a uniform `background` reflectance; blur_px, noise, lighting, gamma,
    exposure as `render.render_frame`; jpeg_quality: store the frame as JPEG at this quality
    (1-100) and decode it again, as a webcam's stream does; rng: a numpy Generator or seed.
    """
    import cv2

    R = np.asarray(R_cam_from_target, float)
    t = np.asarray(t_cam_from_target, float).reshape(3)
    if (-R.T @ t)[2] >= 0:
        raise InputError("the camera is behind the target (it must see the printed face, z < 0 side)")
    rng = np.random.default_rng(rng) if not isinstance(rng, np.random.Generator) else rng
    img = linear_layers(camera, R, t, layers, background)
    out = sensor_image(img[..., None], float(lighting), float(exposure), blur_px, float(gamma), noise, rng)
    if jpeg_quality is not None:
        ok, buf = cv2.imencode(".jpg", out, [cv2.IMWRITE_JPEG_QUALITY, int(jpeg_quality)])
        out = cv2.imdecode(buf, cv2.IMREAD_GRAYSCALE)
    return out


def linear_layers(camera, R_cam_from_target, t_cam_from_target, layers, background=0.3):
    """The linear scene (H, W) of target layers as `camera` sees them, before any sensor:
    each layer's polygons painted with exact area coverage over what is already there, on a
    uniform `background` reflectance (`render_layers`' first step)."""
    R = np.asarray(R_cam_from_target, float)
    t = np.asarray(t_cam_from_target, float).reshape(3)
    img = np.full((camera.height, camera.width), float(background))
    for polys, refl in layers:
        c = np.clip(target_coverage(camera, R, t, [(p, 1) for p in polys]), 0.0, 1.0)
        img = img * (1.0 - c) + float(refl) * c
    return img


def radial_pose(camera, vertex_px, tilt_deg, radius, *, fill=0.6, axis_deg=0.0, roll_deg=0.0):
    """The pose of a radial target whose vertex images at `vertex_px` (raw pixels), its normal
    `tilt_deg` from the vertex's viewing ray (turned about an axis at `axis_deg` in the plane
    across the ray), its in-plane angle `roll_deg`, at the distance where a circle of
    `radius` [mm] about the vertex spans about `fill` of half the image's smaller side.

    Returns (R_cam_from_target (3, 3), t_cam_from_target (3,) [mm]), the target's vertex at
    its origin.
    """
    ray = camera.rays_from_pixels(np.asarray(vertex_px, float))
    f = camera.f_mean
    depth = f * float(radius) / (float(fill) * 0.5 * min(camera.width, camera.height))
    # a frame facing the camera along the ray, then tilted and rolled
    up = np.array([0.0, 1.0, 0.0])
    x = np.cross(up, ray)
    x /= np.linalg.norm(x)
    y = np.cross(ray, x)
    R0 = np.stack([x, y, ray], -1)  # target z along the ray, away from the camera
    a = np.radians(axis_deg)
    axis = np.cos(a) * x + np.sin(a) * y
    R = rotation_from_rotvec(np.radians(tilt_deg) * axis) @ R0 @ rotation_from_rotvec([0.0, 0.0, np.radians(roll_deg)])
    return R, depth * ray
