"""A tissue-like backdrop for instrument frames: what an endoscope sees behind a shaft.

`tissue_image` paints, in image space, the clutter that fools a shaft detector on real
frames: a pink, unevenly shaded surface with fine texture, pale tubular folds (bowel loops,
the edges of a gallbladder: bands with two long, soft edges and a highlight along them, at
any angle), yellow fat between them and specular spots. It is not a 3-D scene: it stands
for what lies far behind the instrument, fixed to the image while the camera holds still
(`scenarios.Scenario.render` draws one per camera pose). Linear light, BGR.

Example
-------
>>> img = tissue_image((120, 160), seed=0)
>>> img.shape, img.dtype.name, bool(0.0 <= img.min() and img.max() <= 1.0)
((120, 160, 3), 'float64', True)
"""
from __future__ import annotations

import functools

import numpy as np

__all__ = ["tissue_image", "TISSUE", "FAT"]

#: Linear BGR reflectance of the tissue and of the fat.
TISSUE = (0.32, 0.36, 0.62)
FAT = (0.12, 0.45, 0.62)
_FOLDS = 9  # folds at the image's size of 1000 px diagonal (scaled with its area)


def _noise(rng, shape, cell):
    """Smooth noise (H, W) of unit sd at the scale of `cell` px (cubic upsampling)."""
    import cv2

    H, W = shape
    gh, gw = H // cell + 3, W // cell + 3
    up = cv2.resize(rng.standard_normal((gh, gw)).astype(np.float32), (gw * cell, gh * cell),
                    interpolation=cv2.INTER_CUBIC)
    out = up[:H, :W]
    return (out - out.mean()) / max(float(out.std()), 1e-6)


def _fold(rng, shape, diag):
    """One fold: the tube's distance field along a curved centre line. Returns (centre
    distance (H, W) [px], radius [px])."""
    import cv2

    H, W = shape
    radius = rng.uniform(0.015, 0.045) * diag
    # a quadratic curve from one side of the image to another, bent by up to a third
    p0 = rng.uniform([-0.1 * W, -0.1 * H], [1.1 * W, 1.1 * H])
    a = rng.uniform(0, np.pi)
    d = np.array([np.cos(a), np.sin(a)])
    L = rng.uniform(0.5, 1.2) * diag
    p2 = p0 + L * d
    p1 = 0.5 * (p0 + p2) + rng.uniform(-0.3, 0.3) * L * np.array([-d[1], d[0]])
    t = np.linspace(0.0, 1.0, 200)[:, None]
    pts = ((1 - t) ** 2 * p0 + 2 * (1 - t) * t * p1 + t**2 * p2).astype(np.int32)
    mask = np.full((H, W), 255, np.uint8)
    cv2.polylines(mask, [pts.reshape(-1, 1, 2)], False, 0, 1)
    return np.minimum(cv2.distanceTransform(mask, cv2.DIST_L2, 5).astype(np.float64), 10.0 * diag), radius


def tissue_image(shape, seed=0, color=True, folds=None):
    """A tissue-like backdrop (module docstring): (H, W, 3) linear BGR, or (H, W, 1) grey
    (its luminance) without colour; shape (H, W) [px]; seed: an int or a tuple of ints (the
    same seed, the same image); folds: how many (default `_FOLDS` per 1000 px of diagonal,
    scaled by the image's area). The last few are kept (a read-only array)."""
    seed = tuple(int(v) for v in np.atleast_1d(seed))
    return _tissue((int(shape[0]), int(shape[1])), seed, bool(color), None if folds is None else int(folds))


@functools.lru_cache(maxsize=4)
def _tissue(shape, seed, color, folds):
    rng = np.random.default_rng([*seed, 881])
    H, W = int(shape[0]), int(shape[1])
    diag = float(np.hypot(H, W))
    n = int(round(_FOLDS * (diag / 1000.0) ** 2)) if folds is None else int(folds)
    shade = 1.0 + 0.18 * _noise(rng, (H, W), max(int(diag / 6), 4))
    fine = 1.0 + 0.06 * _noise(rng, (H, W), 2) + 0.05 * _noise(rng, (H, W), 6)
    fat = np.clip(_noise(rng, (H, W), max(int(diag / 25), 3)) - 1.2, 0.0, 1.0)
    img = np.array(TISSUE)[None, None, :] * (1.0 - fat[..., None]) + np.array(FAT)[None, None, :] * fat[..., None]
    img = img * shade[..., None] * fine[..., None]
    for _ in range(n):
        dist, r = _fold(rng, (H, W), diag)
        inside = dist < r
        z = np.sqrt(np.clip(1.0 - (dist / r) ** 2, 0.0, 1.0))  # the tube's height over its radius
        pale = rng.uniform(1.15, 1.45)
        lit = (0.55 + 0.45 * z) * pale  # brighter along the crest, falling towards both edges
        img = np.where(inside[..., None], img * lit[..., None], img)
        # a thin highlight along the crest, on the glossy ones
        if rng.uniform() < 0.6:
            img = img + (0.12 * np.exp(-0.5 * (dist / max(0.15 * r, 0.8)) ** 2) * inside)[..., None]
    spots = (rng.uniform(size=(H, W)) < 3e-5).astype(np.float32)
    if spots.any():
        import cv2

        img = img + 0.8 * cv2.GaussianBlur(spots, (0, 0), 1.5)[..., None] * 60.0
    img = np.clip(img, 0.0, 1.0)
    if not color:
        img = (img @ np.array([0.114, 0.587, 0.299]))[..., None]
    img.setflags(write=False)
    return img
