"""Procedural textures for the synthetic scene: a mip-mapped noise texture and its lookup.

`texture_pyramid` makes the table's texture (multi-octave noise, no repeats, rich in
features for structure from motion); `sample_texture` reads it trilinearly at a pixel's
footprint, and `plane_texture` finds what a pixel's viewing ray sees of a textured plane.
Texture coordinates are texels of level 0 (texel centres at integers); lengths on the
planes are in the target's unit (mm).

Example
-------
>>> pyr = texture_pyramid(0, (64, 64))
>>> len(pyr), pyr[0].shape, pyr[0].dtype.name
(3, (64, 64), 'float32')
>>> float(sample_texture(pyr, [np.nan], [0.0], [1.0])[0]) == float(pyr[-1].mean())   # no ray: the mean
True
"""
from __future__ import annotations

import functools

import numpy as np

__all__ = ["texture_pyramid", "sample_texture", "plane_texture"]


@functools.lru_cache(maxsize=4)
def texture_pyramid(seed, shape):
    """Procedural multi-octave noise with a soft contrast curve: blobs at every scale,
    never repeating, rich in SIFT features.

    seed: int; shape: (H, W) texels of level 0. Returns a tuple of read-only float32 mip
    levels (level l is about (H / 2^l, W / 2^l)), values about 0.1..0.5 (linear
    reflectance). The last four pyramids are kept (functools.lru_cache).
    """
    import cv2

    rng = np.random.default_rng([int(seed), 7919])
    H, W = shape
    acc = np.zeros((H, W), np.float32)
    for cell in (2, 4, 8, 16, 32, 64, 128, 256):
        gh, gw = H // cell + 4, W // cell + 4
        g = rng.standard_normal((gh, gw)).astype(np.float32)
        up = cv2.resize(g, (gw * cell, gh * cell), interpolation=cv2.INTER_CUBIC)
        oy, ox = rng.integers(0, cell, 2)
        # a nearly flat spectrum: features at every scale from 1 mm to 10 cm
        acc += (cell / 2.0) ** 0.15 * up[oy:oy + H, ox:ox + W]
    acc = (acc - acc.mean()) / acc.std()
    tex = (0.30 + 0.20 * np.tanh(1.3 * acc)).astype(np.float32)
    levels = [tex]
    while min(levels[-1].shape) > 16:
        levels.append(cv2.pyrDown(levels[-1]))
    for lv in levels:
        lv.setflags(write=False)
    return tuple(levels)


def sample_texture(pyramid, u, v, footprint):
    """Trilinear (mip-mapped) texture lookup, wrapping around the texture's edges.

    u, v: (N,) texel coordinates at level 0 (texel centres at integers); footprint: (N,)
    texels per pixel. Returns (N,) float32; non-finite inputs give the texture's mean.
    """
    import cv2

    u, v, footprint = (np.asarray(a, float).ravel() for a in (u, v, footprint))
    n = u.size
    ok = np.isfinite(u) & np.isfinite(v) & np.isfinite(footprint)
    out = np.full(n, float(pyramid[-1].mean()), np.float32)
    if not np.any(ok):
        return out
    u, v = u[ok], v[ok]
    level = np.clip(np.log2(np.maximum(footprint[ok], 1.0)), 0.0, len(pyramid) - 1.0)
    # cv2.remap wants 2-D maps below 32767 a side: fold the samples into rows of 1024
    m = u.size
    rows = -(-m // 1024)
    pad = rows * 1024 - m
    acc = np.zeros(m, np.float32)
    for lv in range(int(np.floor(level.min())), int(np.ceil(level.max())) + 1):
        w = np.maximum(0.0, 1.0 - np.abs(level - lv))
        sel = w > 0
        if not np.any(sel):
            continue
        s = 2.0 ** lv
        # level-0 coordinate u sits at (u + 0.5) / 2^l - 0.5 on level l (texel centres)
        mx = np.pad(((u + 0.5) / s - 0.5).astype(np.float32), (0, pad)).reshape(rows, 1024)
        my = np.pad(((v + 0.5) / s - 0.5).astype(np.float32), (0, pad)).reshape(rows, 1024)
        val = cv2.remap(pyramid[lv], mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP).ravel()[:m]
        acc += (w * val).astype(np.float32)
    out[ok] = acc
    return out


def plane_texture(pyramid, texel, rays_t, C_t, Q, n, e1, e2, offset, pixel_angle):
    """Texture seen along target-frame unit rays (N, 3) from C_t on the plane through Q
    with unit normal n and in-plane unit axes e1, e2 [mm]; `offset` (2,) [mm] shifts the
    texture. Returns (N,) float32 (the texture's mean where a ray misses the plane).

    The mip level follows the pixel's footprint on the plane, distance * pixel_angle /
    sqrt(|cos(incidence)|): the geometric mean of its two axes, a fair compromise
    between blur and aliasing at grazing angles.
    """
    cos_i = rays_t @ n
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.dot(Q - C_t, n) / cos_i
    s = np.where(s > 0, s, np.nan)
    P = C_t + s[:, None] * rays_t - Q
    u = (P @ e1 + offset[0]) / texel - 0.5
    v = (P @ e2 + offset[1]) / texel - 0.5
    fp = s * pixel_angle / np.sqrt(np.abs(cos_i)) / texel
    return sample_texture(pyramid, u, v, fp)
