"""Shaded instrument shafts lit from the endoscope, rendered physically, with exact truth.

An endoscope carries its light beside its lens, so a shaft is lit from (almost) the viewing
direction: where its surface turns away from the camera it also turns away from the light,
and it darkens towards its silhouette. This module renders that, to measure edge models
against (`detect.shaft.limb`): a cylinder of radius r along an axis, each ray intersected
exactly, shaded by a microfacet BRDF with the light at the camera centre:

- irradiance ``E = P / z^2`` (z the hit's distance from the light), incidence cosine
  ``c = n . v`` (n the surface normal, v towards the camera = towards the light);
- diffuse (Lambert) ``albedo / pi * c``;
- specular (Cook-Torrance, GGX): with the light at the camera the half vector is v, so
  ``D(c) G(c) F0 / (4 c)`` with ``D = a^2 / (pi (c^2 (a^2 - 1) + 1)^2)``, Smith's
  ``G = G1(c)^2``, ``G1 = 2 c / (c + sqrt(a^2 + (1 - a^2) c^2))`` and Schlick's F = F0
  (v . h = 1); a the roughness.

Pixels within `_LIMB_PX` of a silhouette line or where the shaft's cover changes are the
mean of ``supersample^2`` rays spread over the pixel's square (the limb's shading has an
unbounded slope: a pixel-centre sample would misplace it); the others one ray at the
centre. The background is a flat colour with an optional smooth gradient. Then the
sensor (`render.sensor_image`): optical blur on linear light, gamma encoding, noise,
8 bits. `MATERIALS` holds the settings the tests sweep: a matte coat, a glossy one, dark
and bright metal.

Truth (`ShadedTruth`): the exact silhouette lines (`pencil.cylinder.project_cylinder`) in
undistorted pixels, and the band's width across the axis image at any point.

Conventions: OpenCV camera frame, pixel (0, 0) the centre of the top-left pixel; lengths
in mm; linear radiance in [0, 1] of full scale before the sensor.

Example
-------
>>> from pencilcal.toolkit.camera.model import Camera
>>> cam = Camera("pinhole", 160, 120, [[150.0, 0, 79.5], [0, 150.0, 59.5], [0, 0, 1]])
>>> img, truth = render_shaded_shaft(cam, [0.0, 0, 60], [1.0, 0, 0.2], 4.0, MATERIALS["dark_metal"],
...                                  noise=0.0, rng=0)
>>> img.shape, img.dtype.name, round(truth.width_at([79.5, 59.5]), 2)
((120, 160, 3), 'uint8', 20.05)
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pencilcal.toolkit.errors import InputError
from pencilcal.toolkit.pencil.cylinder import project_cylinder
from pencilcal.toolkit.synth.render import sensor_image

__all__ = ["Material", "MATERIALS", "ShadedTruth", "shaft_radiance", "shaft_light", "render_shaded_shaft"]

_LIMB_PX = 2.5  # pixels this close to a silhouette line are supersampled [px]


@dataclass(frozen=True)
class Material:
    """A shaft's surface: albedo (diffuse reflectance), f0 (specular reflectance at normal
    incidence), roughness (GGX a), colour (B, G, R) the tint of its light."""

    name: str
    albedo: float
    f0: float
    roughness: float
    colour: tuple = (1.0, 1.0, 1.0)


#: The settings the edge model is measured on: a matte coat, a glossy coat, dark and bright
#: (polished) metal.
MATERIALS = {
    "matte": Material("matte", 0.55, 0.04, 0.9, (0.92, 0.95, 1.0)),
    "glossy": Material("glossy", 0.12, 0.05, 0.12, (0.9, 0.9, 0.9)),
    "dark_metal": Material("dark_metal", 0.03, 0.35, 0.35, (0.95, 0.97, 1.0)),
    "bright_metal": Material("bright_metal", 0.02, 0.9, 0.2, (0.9, 0.95, 1.0)),
}


@dataclass(frozen=True, eq=False)
class ShadedTruth:
    """The exact outline of a rendered shaft: lines (2, 3) its silhouette lines in
    undistorted pixels, ``a u + b v + c = 0`` with (a, b) unit and positive inside the band;
    normals (2, 3) the tangent planes' unit normals; axis_point (3,), axis_direction (3,)
    [mm, camera frame]; radius [mm]; K (3, 3) the camera matrix of the undistorted pixels."""

    lines: np.ndarray
    normals: np.ndarray
    axis_point: np.ndarray
    axis_direction: np.ndarray
    radius: float
    K: np.ndarray

    def width_at(self, point):
        """The band's width [px] across the axis image at the undistorted pixel point (2,):
        between the silhouette lines along the normal of the axis image (the bisecting
        plane's image, `detect.shaft.axis.plane_bisector`)."""
        n1, n2 = self.normals
        la = (n1 - n2) @ np.linalg.inv(self.K)
        na = la[:2] / np.hypot(la[0], la[1])
        p = np.asarray(point, float)
        d = [(-(ln[:2] @ p + ln[2]) / (ln[:2] @ na)) for ln in self.lines]
        return float(abs(d[0] - d[1]))


def _hits(rays, A, d, r, s_range):
    """Ray (..., 3) hits of the cylinder (axis point A, unit d, radius r, along-axis range
    s_range from A): (hit (...) bool, cosine c = n . v (...), distance z (...) [mm])."""
    w = rays - (rays @ d)[..., None] * d
    a0 = -(A - (A @ d) * d)
    qa = np.sum(w * w, -1)
    qb = 2.0 * (w @ a0)
    qc = a0 @ a0 - r * r
    disc = qb * qb - 4 * qa * qc
    with np.errstate(invalid="ignore", divide="ignore"):
        z = (-qb - np.sqrt(np.maximum(disc, 0.0))) / (2 * qa)
    X = z[..., None] * rays
    s = (X - A) @ d
    hit = (disc > 0) & (z > 0) & (s >= s_range[0]) & (s <= s_range[1])
    n = X - A - s[..., None] * d
    with np.errstate(invalid="ignore", divide="ignore"):
        n = n / np.linalg.norm(n, axis=-1, keepdims=True)
    c = np.clip(-np.sum(n * rays, -1), 0.0, 1.0)
    return hit, np.where(hit, c, 0.0), np.where(hit, z, np.inf)


def shaft_radiance(c, z, material, power=2500.0):
    """Linear radiance (...) of a shaft's point seen at incidence cosine c (...) from
    distance z (...) [mm], lit from the camera by a light of intensity `power` (radiance
    ``power / z^2`` times the BRDF times c: module docstring)."""
    c = np.asarray(c, float)
    a2 = material.roughness ** 2
    D = a2 / (np.pi * (c * c * (a2 - 1.0) + 1.0) ** 2)
    G1 = 2 * c / np.maximum(c + np.sqrt(a2 + (1 - a2) * c * c), 1e-300)
    spec = np.where(c > 0, D * G1 * G1 * material.f0 / (4 * np.maximum(c, 1e-300)), 0.0)
    return power / np.asarray(z, float) ** 2 * (material.albedo / np.pi * c + spec)


def _line_distance(camera, px, lines):
    """Least distance (...) [px] of raw pixels px (..., 2) from the undistorted lines (2, 3)."""
    ideal = np.asarray(camera.undistort_pixels(px.reshape(-1, 2)), float).reshape(px.shape)
    dist = np.abs(ideal @ lines[:, :2].T + lines[:, 2])
    return np.nan_to_num(dist.min(-1), nan=np.inf)


def shaft_light(camera, axis_point, axis_direction, radius, material, *, extent=(-1e4, 1e4), power=2500.0,
                supersample=8):
    """One shaded shaft's linear light before any background or sensor (module docstring):
    (radiance (H, W), cover (H, W) the share of each pixel the shaft covers, hit (H, W) bool
    the pixels whose centre it covers, full (H, W) bool those of them away from its outline,
    outline: `project_cylinder`'s).
    Arguments as `render_shaded_shaft`'s. InputError when the shaft is not in view."""
    A = np.asarray(axis_point, float)
    d = np.asarray(axis_direction, float) / np.linalg.norm(axis_direction)
    outline = project_cylinder(camera.K, A, d, radius)
    W, H = camera.width, camera.height
    uu, vv = np.meshgrid(np.arange(W, dtype=float), np.arange(H, dtype=float))
    px = np.stack([uu, vv], -1)
    rays = np.asarray(camera.rays_from_pixels(px), float)
    ok = np.all(np.isfinite(rays), -1)
    rays = np.where(ok[..., None], rays, [0.0, 0.0, 1.0])
    hit, c, z = _hits(rays, A, d, radius, extent)
    hit &= ok
    rad = np.where(hit, shaft_radiance(c, z, material, power), 0.0)
    cover = hit.astype(float)
    # supersampled where the limb or the shaft's ends cross a pixel
    edge = _line_distance(camera, px, outline.lines) < _LIMB_PX
    hp = np.pad(hit, 1, mode="edge")
    edge |= (hp[1:-1, :-2] != hit) | (hp[1:-1, 2:] != hit) | (hp[:-2, 1:-1] != hit) | (hp[2:, 1:-1] != hit)
    iy, ix = np.nonzero(edge)
    n = int(supersample)
    off = (np.arange(n) + 0.5) / n - 0.5
    ox, oy = np.meshgrid(off, off)
    sub = np.stack([ix[:, None] + ox.ravel(), iy[:, None] + oy.ravel()], -1)
    sr = np.asarray(camera.rays_from_pixels(sub), float)
    sok = np.all(np.isfinite(sr), -1)
    sh, sc, sz = _hits(np.where(sok[..., None], sr, [0.0, 0.0, 1.0]), A, d, radius, extent)
    sh &= sok
    rad[iy, ix] = np.where(sh, shaft_radiance(sc, sz, material, power), 0.0).mean(-1)
    cover[iy, ix] = sh.mean(-1)
    if not hit.any() and not cover.any():
        raise InputError("render_shaded_shaft: the shaft is not in view")
    return rad, cover, hit, hit & ~edge, outline


def render_shaded_shaft(camera, axis_point, axis_direction, radius, material, *, extent=(-1e4, 1e4),
                        background=(0.10, 0.12, 0.22), gradient=0.0, shaft_level=0.3, power=2500.0, blur_px=0.8,
                        noise=1.0, gamma=2.2, supersample=8, rng=None):
    """A frame (H, W, 3) uint8 BGR of one shaded shaft over a flat background, and its
    `ShadedTruth` (module docstring).

    camera: the `Camera` (any lens model); axis_point (3,) [mm], axis_direction (3,): the
    axis in the camera frame; radius [mm]; material: a `Material`; extent (2,) [mm]: the
    shaft's stretch along the axis from axis_point; background (3,): its linear BGR, or an
    (H, W, 3) linear image (a tissue backdrop); gradient: a linear ramp across the image of
    that fraction of it (0: flat); shaft_level: the exposure that puts the shaft's median
    radiance at this linear level (None: the raw radiance, ``power`` at 1 mm); blur_px:
    optical blur sd [px]; noise: sensor noise sd [grey levels] at mid-grey
    (`render.sensor_image`); gamma: the encoding gamma; supersample: rays per pixel side
    near the outline; rng: a numpy Generator or seed. InputError when the camera lies
    inside the cylinder.
    """
    rng = np.random.default_rng(rng)
    A = np.asarray(axis_point, float)
    d = np.asarray(axis_direction, float) / np.linalg.norm(axis_direction)
    rad, cover, hit, full, outline = shaft_light(camera, A, d, radius, material, extent=extent, power=power,
                                            supersample=supersample)
    if shaft_level is not None:
        rad = rad * (float(shaft_level) / max(float(np.median(rad[full if full.any() else hit])), 1e-300))
    W, H = camera.width, camera.height
    uu = np.arange(W, dtype=float)[None, :]
    bg = np.asarray(background, float)
    if bg.ndim == 1:
        bg = bg * (1.0 + gradient * ((uu / max(W - 1, 1)) - 0.5))[..., None]
    img = bg * (1.0 - cover)[..., None] + rad[..., None] * np.asarray(material.colour, float)
    return sensor_image(img, 0.0, 1.0, blur_px, gamma, noise, rng), ShadedTruth(
        outline.lines, outline.normals, A, d, float(radius), np.asarray(camera.K, float))
