"""Real-looking synthetic frames with exact truth: what a camera sees of the printed sheet.

`render_frame` draws the `Sheet` (sheet.py), optionally on a `Backdrop` (a textured table
with boxes, a wall beyond) and under an `Instrument` shaft (objects.py), for a camera with
any supported lens model.

Rendering method
----------------
Every polygon of the scene (squares, marker cells, spoke bars, the paper, the table, the
boxes, the shaft's silhouette) is clipped to the camera's view, projected exactly and
scan-converted with exact area coverage (raster.py): without blur and noise a pixel is the
box-filter average of the scene over its square. Shading (the table's procedural texture,
texture.py; the boxes; the shaft's metallic look) is evaluated along interpolated per-pixel
rays; the geometry of every edge comes from the exact forward projection.

After the scene: optional smooth multiplicative lighting field (vignetting and a random
gradient), Gaussian blur (the optics), gamma encoding and signal-dependent sensor noise,
all drawn from the generator passed in, so a seed gives the same image bit for bit.

Conventions: OpenCV camera frame and pixels (pixel (0, 0) is the centre of the top-left
pixel); transforms ``a_from_b``; lengths in the target's unit (mm).

Example
-------
>>> import numpy as np
>>> from pencilcal.toolkit.camera.model import Camera
>>> from pencilcal.toolkit.synth.sheet import layout_sheet
>>> sheet = layout_sheet()
>>> cam = Camera("pinhole", 320, 240, [[250.0, 0, 159.5], [0, 250.0, 119.5], [0, 0, 1]])
>>> R, t = np.eye(3), np.array([-131.0, -62.0, 400.0])   # frontal, 400 mm away
>>> img = render_frame(cam, R, t, sheet, background="plain")
>>> img.shape, img.dtype.name
((240, 320), 'uint8')
"""
from __future__ import annotations

import math
from types import MappingProxyType

import numpy as np

from pencilcal.toolkit.errors import InputError
from pencilcal.toolkit.synth.objects import Backdrop, face_shade
from pencilcal.toolkit.synth.polygons import rect
from pencilcal.toolkit.synth.raster import pixel_rays, render_coverage, to_camera
from pencilcal.toolkit.synth.texture import plane_texture, sample_texture

__all__ = ["render_frame", "render_scene", "REFLECTANCE", "sensor_image", "lighting_gain"]


def _readonly(values):
    """A read-only float array of `values`."""
    a = np.array(values, float)
    a.setflags(write=False)
    return a


#: Linear reflectances (0..1) of the scene's materials before lighting.
REFLECTANCE = MappingProxyType({"paper": 0.85, "ink": 0.045, "wall": 0.22, "plain": 0.30})


# Tints (B, G, R) for colour output; luminance comes from the reflectances above.
_TINT = MappingProxyType({
    "paper": _readonly([0.97, 0.99, 1.0]),
    "ink": _readonly([1.0, 1.0, 1.0]),
    "table": _readonly([0.62, 0.86, 1.12]),   # a warm wood-like brown
    "wall": _readonly([1.10, 1.0, 0.90]),
    "plain": _readonly([1.0, 1.0, 1.0]),
    "shaft": _readonly([1.0, 1.0, 1.0]),
})


def _as_rng(rng):
    """A numpy Generator: `rng` itself, or one seeded by it (an int, a seed sequence or None)."""
    if isinstance(rng, np.random.Generator):
        return rng
    return np.random.default_rng(rng)


def lighting_gain(W, H, strength, rng):
    """A smooth multiplicative gain (H, W), or None for `strength` <= 0: vignetting plus a
    random tilted, slightly curved field drawn from `rng`."""
    if strength <= 0:
        return None
    u = (np.arange(W) - (W - 1) / 2.0) / (max(W, H) / 2.0)
    v = (np.arange(H) - (H - 1) / 2.0) / (max(W, H) / 2.0)
    uu, vv = np.meshgrid(u, v)
    a, b, c, d = rng.uniform(-1.0, 1.0, 4)
    gain = 1.0 + strength * (0.5 * a * uu + 0.5 * b * vv + 0.25 * c * uu * vv + 0.25 * d * (uu * uu - vv * vv))
    vignette = 1.0 - 0.35 * strength * (uu * uu + vv * vv)
    return np.maximum(gain * vignette, 0.05)


def render_frame(camera, R_cam_from_target, t_cam_from_target, sheet, *, instrument=None,
                 background="table", blur_px=0.0, noise=0.0, lighting=0.0, gamma=1.0, exposure=1.0,
                 color=False, rng=None, scene=None):
    """Render what `camera` sees of the sheet (and a backdrop and an instrument).

    Parameters
    ----------
    camera : Camera
        Any supported lens model (pinhole, opencv, fisheye).
    R_cam_from_target : (3, 3) array_like
    t_cam_from_target : (3,) array_like
        Pose of the sheet: p_cam = R p_target + t [mm]. The camera must see the printed
        face (its centre on the -z side of the sheet).
    sheet : Sheet
    instrument : Instrument, optional
        A shaft drawn over everything else (it is closer to the camera than the sheet).
    background : "table" | "plain" | float | Backdrop | ndarray
        "table": `Backdrop.around(sheet)` (textured table, boxes, wall); "plain" or a
        number: a uniform grey (linear reflectance, default 0.3) around the paper; an
        (H, W, 3) or (H, W, 1) array: an image-space backdrop in linear light (e.g.
        `tissue.tissue_image`) drawn instead of the sheet and everything else (the
        instrument alone over it).
    blur_px : float
        Standard deviation of a Gaussian blur (the optics) [pixels]; 0 for none.
    noise : float
        Sensor noise: standard deviation at mid grey [grey levels of the 8-bit output];
        it scales as sqrt(0.25 + 0.75 I / 128) with the level I (shot plus read noise).
    lighting : float
        Strength (0..1) of the smooth uneven lighting field (vignetting and a random
        gradient); 0 for uniform light.
    gamma : float
        Encoding gamma: output = 255 (linear)^(1/gamma). 1 keeps the image linear, which
        keeps a blurred edge's 50 % level exactly on the edge; 2.2 looks like a camera.
    exposure : float
        Multiplies the linear image before encoding.
    color : bool
        (H, W, 3) BGR output instead of (H, W) grey.
    rng : numpy Generator or int or None
        Source of the lighting field and noise; a seed gives identical images.
    scene : (H, W, C) float array, optional
        `render_scene` of the same camera, pose, sheet, background and colour: the frames of
        a fixed camera share it (the backdrop is most of the work), so a sequence renders
        it once; only the instrument and the sensor are added here.

    Returns
    -------
    (H, W) or (H, W, 3) uint8 ndarray

    Raises
    ------
    InputError
        If the camera is behind the sheet or inside the instrument.

    Notes
    -----
    Without blur and noise, a pixel is the exact box-filter average of the scene over its
    square (module docstring): edges of the printed pattern lie where the projected truth
    puts them, to ~1e-3 px, for every lens model. Shading colours (texture, shaft) are
    evaluated at the pixel centre.

    Example
    -------
    >>> from pencilcal.toolkit.camera.model import Camera
    >>> cam = Camera("opencv", 160, 120, [[150.0, 0, 79.5], [0, 150.0, 59.5], [0, 0, 1]], [-0.1, 0.02, 0, 0])
    >>> from pencilcal.toolkit.synth.sheet import layout_sheet
    >>> img = render_frame(cam, np.eye(3), [-131.0, -62.0, 600.0], layout_sheet(), noise=2.0, rng=1)
    >>> img.shape
    (120, 160)
    """
    R, t = _pose(R_cam_from_target, t_cam_from_target)
    rng = _as_rng(rng)
    if scene is None:
        img = render_scene(camera, R, t, sheet, background=background, color=color)
    else:
        img = np.array(scene, np.float64)
        if img.shape != (camera.height, camera.width, 3 if color else 1):
            raise InputError(f"render_frame: the scene is {img.shape}, the camera's frame {camera.height}x{camera.width}")
    if instrument is not None:
        _draw_instrument(img, camera, R, t, instrument, color)
    return sensor_image(img, float(lighting), float(exposure), blur_px, float(gamma), noise, rng)


def render_scene(camera, R_cam_from_target, t_cam_from_target, sheet, *, background="table", color=False):
    """The linear image (H, W, 1 or 3) of the sheet and its backdrop that `camera` sees, before
    an instrument, the lighting and the sensor (`render_frame`'s scene, its arguments).

    Example
    -------
    >>> from pencilcal.toolkit.camera.model import Camera
    >>> from pencilcal.toolkit.synth.sheet import layout_sheet
    >>> cam = Camera("pinhole", 160, 120, [[150.0, 0, 79.5], [0, 150.0, 59.5], [0, 0, 1]])
    >>> sc = render_scene(cam, np.eye(3), [-131.0, -62.0, 600.0], layout_sheet())
    >>> a = render_frame(cam, np.eye(3), [-131.0, -62.0, 600.0], layout_sheet(), noise=2.0, rng=1)
    >>> bool(np.array_equal(a, render_frame(cam, np.eye(3), [-131.0, -62.0, 600.0], layout_sheet(),
    ...                                     noise=2.0, rng=1, scene=sc)))
    True
    """
    R, t = _pose(R_cam_from_target, t_cam_from_target)
    W, H = camera.width, camera.height
    C_t = -R.T @ t  # camera centre in the target frame
    if C_t[2] >= 0:
        raise InputError("the camera is behind the sheet (it must see the printed face, z < 0 side)")
    nch = 3 if color else 1
    img = np.empty((H, W, nch), np.float64)
    if isinstance(background, np.ndarray):
        bg = np.asarray(background, np.float64)
        if bg.ndim != 3 or bg.shape[:2] != (H, W) or bg.shape[2] not in (1, 3):
            raise InputError(f"background image must be ({H}, {W}, 3) or ({H}, {W}, 1), got {bg.shape}")
        img[:] = bg if bg.shape[2] == nch else (bg @ np.array([0.114, 0.587, 0.299]))[..., None] if nch == 1 else bg
        return img
    c_paper, c_ink = _sheet_coverage(camera, R, t, sheet)
    backdrop = _backdrop(background, sheet)
    paper_term = REFLECTANCE["paper"] * (c_paper - c_ink)[..., None] * _tint("paper", color)
    ink_term = REFLECTANCE["ink"] * c_ink[..., None] * _tint("ink", color)
    if backdrop is None:
        _draw_plain(img, background, c_paper, paper_term + ink_term, color)
    else:
        _draw_table_scene(img, camera, R, t, C_t, backdrop, c_paper, paper_term + ink_term, color)
    return img


def _pose(R_cam_from_target, t_cam_from_target):
    """R (3, 3) and t (3,) as float arrays, checked finite (InputError)."""
    R = np.asarray(R_cam_from_target, float)
    t = np.asarray(t_cam_from_target, float).reshape(3)
    if R.shape != (3, 3) or not np.all(np.isfinite(R)) or not np.all(np.isfinite(t)):
        raise InputError("R_cam_from_target must be a finite 3x3 matrix and t a finite 3-vector")
    return R, t


def _tint(name, color):
    """(3,) BGR tint of a material for colour output, (1,) ones for grey."""
    return _TINT[name] if color else np.ones(1)


def _sheet_coverage(camera, R, t, sheet):
    """(c_paper, c_ink): (H, W) coverage of the paper and of the ink (clipped to 0..1 and to
    the paper) for the pose R (3, 3), t (3,) [mm] of the sheet."""
    sheet_polys = [(to_camera(R, t, p), s) for p, s in sheet.ink_polygons]
    c_ink = render_coverage(camera, sheet_polys)
    c_paper = render_coverage(camera, [(to_camera(R, t, sheet.paper_polygon()), 1)])
    c_paper = np.clip(c_paper, 0.0, 1.0)
    c_ink = np.clip(c_ink, 0.0, c_paper)
    return c_paper, c_ink


def _backdrop(background, sheet):
    """The Backdrop that `background` asks for, or None for a uniform grey."""
    if isinstance(background, str) and background == "table":
        return Backdrop.around(sheet)
    if isinstance(background, Backdrop):
        return background
    return None


def _draw_plain(img, background, c_paper, sheet_term, color):
    """img (H, W, C) = a uniform grey around the paper ("plain": `REFLECTANCE["plain"]`, or
    the number `background`) plus `sheet_term` (H, W, C), the printed sheet."""
    if isinstance(background, str):
        if background != "plain":
            raise InputError(f"background must be 'table', 'plain', a number or a Backdrop, got {background!r}")
        grey = REFLECTANCE["plain"]
    else:
        grey = float(background)
    img[:] = grey * (1.0 - c_paper)[..., None] * _tint("plain", color)
    img += sheet_term


def _draw_table_scene(img, camera, R, t, C_t, backdrop, c_paper, sheet_term, color):
    """img (H, W, C) = the sheet (`sheet_term`) on the backdrop's textured table, the room
    beyond it, and the boxes on it. C_t (3,): camera centre in the target frame [mm]."""
    rays = pixel_rays(camera)
    x0, y0, x1, y1 = backdrop.table
    c_table = np.clip(render_coverage(camera, [(to_camera(R, t, rect(x0, y0, x1, y1)), 1)]), 0.0, 1.0)
    c_paper = np.minimum(c_paper, c_table)
    img[:] = sheet_term
    # the texture only where the table shows, the wall only where the table does not
    sel = (c_table - c_paper) > 0
    if np.any(sel):
        rays_t = rays[sel].astype(np.float64) @ R  # R^T d
        tex = plane_texture(backdrop.texture, backdrop.texel, rays_t, C_t, np.array([x0, y0, 0.0]),
                            np.array([0.0, 0.0, 1.0]), np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0]),
                            (0.0, 0.0), _pixel_angle(camera))
        tex *= face_shade(np.array([0.0, 0.0, -1.0]))
        img[sel] += (tex * (c_table - c_paper)[sel])[:, None] * _tint("table", color)
    sel = c_table < 1
    if np.any(sel):
        # the room beyond the table: the texture, blurred and faint, on a sphere far away
        rt = rays[sel].astype(np.float64) @ R
        az = np.arctan2(rt[:, 1], rt[:, 0])
        el = np.arcsin(np.clip(rt[:, 2], -1.0, 1.0))
        room = sample_texture(backdrop.texture, az * 400.0, el * 400.0, np.full(az.shape, 16.0))
        wall = REFLECTANCE["wall"] * (0.7 + 1.0 * room)
        img[sel] += (wall * (1.0 - c_table[sel]))[:, None] * _tint("wall", color)
    _draw_boxes(img, camera, R, t, C_t, rays, backdrop, color)


def _draw_instrument(img, camera, R, t, instrument, color):
    """Composite the instrument's shaft over img (H, W, C) (it is closer than anything else)."""
    outline = instrument.outline(R, t)
    if outline is None:
        return
    c_shaft, sl = render_coverage(camera, [(outline, 1)], window=True)
    if c_shaft.size:
        c = np.clip(c_shaft, 0.0, 1.0)
        sel = c > 0
        lum = instrument.shade(R, t, pixel_rays(camera)[sl][sel].astype(np.float64))
        win = img[sl]
        win[sel] = win[sel] * (1.0 - c[sel])[:, None] + (c[sel] * lum)[:, None] * _tint("shaft", color)


def sensor_image(img, lighting, exposure, blur_px, gamma, noise, rng):
    """What the camera records of the linear scene img (H, W, C): uneven lighting, exposure,
    optical blur, gamma encoding and sensor noise (arguments as `render_frame`'s), in that
    order; (H, W) or (H, W, 3) uint8."""
    H, W, nch = img.shape
    gain = lighting_gain(W, H, lighting, rng)
    if gain is not None:
        img *= gain[..., None]
    img *= exposure
    if blur_px and blur_px > 0:
        import cv2

        img = cv2.GaussianBlur(img.astype(np.float32), (0, 0), float(blur_px), borderType=cv2.BORDER_REFLECT)
        img = img.reshape(H, W, nch).astype(np.float64)
    out = 255.0 * np.clip(img, 0.0, 1.0) ** (1.0 / gamma)
    if noise and noise > 0:
        sigma = float(noise) * np.sqrt(0.25 + 0.75 * out / 128.0)
        out = out + sigma * rng.standard_normal(out.shape)
    out = np.clip(np.rint(out), 0, 255).astype(np.uint8)
    return out[..., 0] if nch == 1 else out


def _pixel_angle(camera):
    """Angle one pixel subtends near the image centre [rad]."""
    return 1.0 / camera.f_mean


def _draw_boxes(img, camera, R, t, C_t, rays, backdrop, color):
    """Composite the backdrop's boxes over img (H, W, C), far to near (painter's order).

    The visible faces of one box partition its silhouette, so they are added up before
    compositing: no background leaks through the seams between faces.
    """
    if not backdrop.boxes:
        return
    order = sorted(backdrop.boxes, key=lambda b: -np.linalg.norm(
        np.array([(b[0] + b[2]) / 2, (b[1] + b[3]) / 2, -b[4] / 2]) - C_t))
    pyr = backdrop.texture
    trng = np.random.default_rng([backdrop.seed, 31337])
    tints = {b: (trng.uniform(0.75, 1.2, 3) if color else np.ones(1)) for b in backdrop.boxes}
    H, W = img.shape[:2]
    pa = _pixel_angle(camera)
    for k, box in enumerate(order):
        x0, y0, x1, y1, h = box
        z0 = -h
        faces = [  # (corners (4, 3), outward normal)
            (np.array([[x0, y0, z0], [x1, y0, z0], [x1, y1, z0], [x0, y1, z0]]), np.array([0, 0, -1.0])),
            (np.array([[x0, y0, 0], [x1, y0, 0], [x1, y0, z0], [x0, y0, z0]]), np.array([0, -1.0, 0])),
            (np.array([[x0, y1, 0], [x1, y1, 0], [x1, y1, z0], [x0, y1, z0]]), np.array([0, 1.0, 0])),
            (np.array([[x0, y0, 0], [x0, y1, 0], [x0, y1, z0], [x0, y0, z0]]), np.array([-1.0, 0, 0])),
            (np.array([[x1, y0, 0], [x1, y1, 0], [x1, y1, z0], [x1, y0, z0]]), np.array([1.0, 0, 0])),
        ]
        parts = []
        for fi, (corners, n) in enumerate(faces):
            if np.dot(n, C_t - corners.mean(0)) <= 0:
                continue  # faces away from the camera
            cov, sl = render_coverage(camera, [(to_camera(R, t, corners), 1)], window=True)
            if cov.size == 0:
                continue
            cov = np.clip(cov, 0.0, 1.0)
            sel = cov > 0
            e1 = corners[1] - corners[0]
            e2 = corners[3] - corners[0]
            e1 /= np.linalg.norm(e1)
            e2 /= np.linalg.norm(e2)
            rays_t = rays[sl][sel].astype(np.float64) @ R
            off = (97.0 * (fi + 1) + 401.0 * k, 53.0 * (fi + 1) + 211.0 * k)
            # boxes: the same texture at 2.5x finer scale and brighter, so they stand out
            val = plane_texture(pyr, backdrop.texel / 2.5, rays_t, C_t, corners[0], n, e1, e2, off, pa)
            parts.append((cov, sel, sl, (0.25 + 1.2 * val) * face_shade(n)))
        if not parts:
            continue
        total = np.zeros((H, W))
        acc = np.zeros((H, W, img.shape[2]))
        for cov, sel, sl, val in parts:
            total[sl] += cov
            acc[sl][sel] += (cov[sel] * val)[:, None] * tints[box]
        total = np.clip(total, 0.0, 1.0)
        img *= (1.0 - total)[..., None]
        img += acc
