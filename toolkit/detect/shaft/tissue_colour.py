"""Tissue is not an instrument, by its colour: a band as coloured as the tissue, or more, is
tissue in shadow.

An instrument is grey, black or metal: what colour it shows is the tissue's, mirrored (metal,
a specular streak) or cast on it, and always less of it than the tissue itself has. A dark gap
between two tissues (the fat and the bowel at the edge of a phantom's cavity, a fold's shadow)
has two long edges like a shaft and, in a dark frame, passes the learned pixel map
(`shaft.pixel_evidence`, whose chromaticity fades towards black), but a shadow keeps the
tissue's chromaticity, and light reflected back and forth in a cavity deepens it: the gaps
of the dVRK phantom are twice as coloured as its median tissue.

A band's *tissue colour* is the chromaticity of its inside (median over the middle `INNER`
of its width, `STATIONS` x `ACROSS` samples, the chromaticity ``x = (R - G) / S``, ``y = (R +
G - 2 B) / (sqrt(3) S)``, ``S = R + G + B + 3``: unlike the pixel map's it keeps a dark pixel's
colour, and is unchanged by shading under a power-law gamma) projected on the frame's median
chromaticity over the valid region (the tissue's hue), as a fraction of that median's. An
instrument has at most about 1 (bright shafts between saturated tissue: 1.04 at most on the
masked real sources; black and grey ones 0.0-0.4; one off the tissue's hue negative);
a detection over `MAX_TISSUE_COLOUR` is dropped (`detector.detect_shafts`' ``tissue_colour``).
How it was chosen (leave one source out on the masked sources) and what it gives on the
unmasked ones: docs/method.md, tissue colour. The same measure of a band's two flanks, the
tissue right beside it (`flank_colour`), is what a dark band's colour is compared with in
`shaft.grey_material`.

Example
-------
>>> import numpy as np
>>> img = np.zeros((180, 320, 3), np.uint8); img[:] = (90, 110, 190)          # pink tissue
>>> img[40:60] = (12, 16, 64)                                                  # a deep red gap
>>> img[120:140] = (40, 40, 42)                                                # a black shaft
>>> mids = np.array([[0.0, 49.5, 319.0, 49.5], [0.0, 129.5, 319.0, 129.5]])
>>> tissue_colour(img, mids, np.array([20.0, 20.0])).round(2).tolist()
[2.25, 0.07]
"""
from __future__ import annotations

import numpy as np

from pencilcal.toolkit.detect.shaft.work import Validity
from pencilcal.toolkit.errors import InputError

__all__ = ["tissue_colour", "tissue_colour_map", "shaft_tissue_colour", "flank_colour", "shaft_flank_colour", "MAX_TISSUE_COLOUR",
           "STATIONS", "ACROSS", "INNER", "FLANK"]

#: The most tissue colour a detection may have (module docstring); chosen on the masked real
#: sources (docs/method.md).
MAX_TISSUE_COLOUR = 1.25
#: Samples along the midline and across the band's inner part.
STATIONS, ACROSS = 24, 7
#: The fraction of the band's width sampled, about its midline (its outline mixes both sides).
INNER = 0.6
#: The flanks beside a band (`flank_colour`): from and to these distances from its midline, in
#: widths (0.1 to 0.5 of a width outside each edge: the tissue right beside it, off its blurred
#: outline).
FLANK = (0.6, 1.0)
_FRAME_SAMPLES = 20000  # about as many pixels of the frame for its median chromaticity
_EPS = 1.0  # added to each channel [DN]: a black pixel has no colour, not an undefined one


def _chromaticity(bgr):
    """(..., 2) opponent chromaticity of (..., 3) BGR values (module docstring)."""
    f = np.asarray(bgr, float)  # one conversion, the channels read as views
    b, g, r = f[..., 0], f[..., 1], f[..., 2]
    S = r + g + b + 3.0 * _EPS
    out = np.empty(S.shape + (2,))
    np.divide(r - g, S, out=out[..., 0])
    np.divide(r + g - 2.0 * b, np.sqrt(3.0) * S, out=out[..., 1])
    return out


def _frame_chromaticity(img, validity):
    """(2,) the median chromaticity of the frame's valid pixels, on a grid of about
    `_FRAME_SAMPLES` of them."""
    H, W = img.shape[:2]
    step = max(1, int(np.sqrt(H * W / _FRAME_SAMPLES)))
    # the grid's distances as `Validity.distance` gives them (without a region, from its
    # rows' and columns')
    xs, ys = np.arange(step // 2, W, step, dtype=float), np.arange(step // 2, H, step, dtype=float)
    keep = validity.grid_distance(xs, ys) > 0
    if not keep.any():
        keep[:] = True
    # the grid as a strided view, masked (or whole, where every pixel is kept): the same
    # pixels in the same order as indexing the frame at the grid's points, without a gather
    # over the whole frame
    grid = img[step // 2:H:step, step // 2:W:step]
    return np.median(_chromaticity(grid.reshape(-1, 3) if keep.all() else grid[keep]), 0)


def tissue_colour_map(colours, valid=None):
    """(h, w) each pixel's tissue colour (module docstring): the chromaticity of colours (h,
    w, 3) BGR projected on the median chromaticity of the pixels where valid ((h, w) bool;
    None: all), about `_FRAME_SAMPLES` of them, as a fraction of it.

    >>> img = np.zeros((40, 60, 3), np.uint8); img[:] = (90, 110, 190); img[:, :10] = (40, 40, 42)
    >>> [round(float(v), 2) for v in tissue_colour_map(img)[0, [0, 30]]]
    [0.07, 1.0]
    """
    import cv2

    c = np.asarray(colours)
    step = max(1, int(np.sqrt(c.shape[0] * c.shape[1] / _FRAME_SAMPLES)))
    grid = c[step // 2::step, step // 2::step]
    keep = None if valid is None else np.asarray(valid, bool)[step // 2::step, step // 2::step]
    mx, my = np.median(_chromaticity(grid.reshape(-1, 3) if keep is None or not keep.any() else grid[keep]), 0)
    # the chromaticity's projection is linear in B, G, R over their sum: two weighted sums of
    # the channels in one pass (float32), not the chromaticity of every pixel
    r3 = 1.0 / np.sqrt(3.0)
    W = np.array([[-2.0 * my * r3, my * r3 - mx, mx + my * r3], [1.0, 1.0, 1.0]])
    W[0] /= max(mx * mx + my * my, 1e-12)
    out = cv2.transform(np.ascontiguousarray(c, np.float32), W.astype(np.float32))
    return out[..., 0] / (out[..., 1] + 3.0 * _EPS)  # the two channels as views, not split


def _inside(img, midline, width, across=None):
    """(K, 3) BGR samples of the inner part of one band (raw px), those off the image left out;
    across: (lo, hi) the offsets from its midline sampled, in widths (default the middle
    `INNER` of it)."""
    import cv2

    a, b = np.asarray(midline, float).reshape(2, 2)
    L = float(np.hypot(*(b - a)))
    if not np.isfinite(L) or L <= 0:
        return np.zeros((0, 3))
    n = np.array([a[1] - b[1], b[0] - a[0]]) / L
    lo, hi = (-0.5 * INNER, 0.5 * INNER) if across is None else across
    s = np.linspace(0.0, 1.0, STATIONS)[:, None, None]
    t = float(width) * np.linspace(lo, hi, ACROSS)[None, :, None]
    P = (a + s * (b - a) + t * n).reshape(-1, 2)
    H, W = img.shape[:2]
    P = P[(P[:, 0] >= 0) & (P[:, 1] >= 0) & (P[:, 0] <= W - 1) & (P[:, 1] <= H - 1)].astype(np.float32)
    if not len(P):
        return np.zeros((0, 3))
    return cv2.remap(img, np.ascontiguousarray(P[None, :, 0]), np.ascontiguousarray(P[None, :, 1]),
                     cv2.INTER_LINEAR)[0].reshape(-1, 3)


def _bands(image, midlines, widths, what):
    """(image (H, W, 3), midlines (N, 4), widths (N,)) as arrays, checked (`what` names the
    measure in the one-line error)."""
    img = np.asarray(image)
    if img.ndim != 3 or img.shape[2] != 3:
        raise InputError(f"{what} needs a colour (BGR) frame, got shape {img.shape}")
    mids = np.asarray(midlines, float).reshape(-1, 4)
    wds = np.asarray(widths, float).reshape(-1)
    if len(mids) != len(wds):
        raise InputError(f"{what}: {len(mids)} midlines but {len(wds)} widths")
    return img, mids, wds


def tissue_colour(image, midlines, widths, valid_region=None, validity=None):
    """The tissue colour (N,) of bands in a BGR frame (module docstring).

    image: (H, W, 3) uint8 BGR; midlines: (N, 4) [raw px]; widths: (N,) [px] (a shaft's
    ``width_px``: undistorted, which the raw band's differs from by the lens's local scale
    only); valid_region: as `detect_shafts`' (the frame's median is taken inside it), or
    validity: its `work.Validity`. A band without samples in the image has 0 (no evidence
    either way). A frame without colour (the median grey) gives 0 for every band.
    """
    img, mids, wds = _bands(image, midlines, widths, "tissue colour")
    if not len(mids):
        return np.zeros(0)
    validity = Validity(valid_region, img.shape[:2]) if validity is None else validity
    c = _frame_chromaticity(img, validity)
    cc = float(c @ c)
    out = np.zeros(len(mids))
    if cc < 1e-6:  # a grey scene: no tissue hue to compare with
        return out
    for k, (m, w) in enumerate(zip(mids, wds)):
        v = _inside(img, m, w)
        if len(v):
            out[k] = float(np.median(_chromaticity(v), 0) @ c) / cc
    return out


def flank_colour(image, midlines, widths, valid_region=None, validity=None):
    """The tissue colour (N,) of the tissue right beside bands: of their two flanks (`FLANK`:
    0.1 to 0.5 of a width outside each edge, `STATIONS` x `ACROSS` samples each, the median
    chromaticity along the tissue's hue as in `tissue_colour`), the lesser.

    A shadow keeps the colour of the tissue it falls on, so a dark band of tissue (a gap, a
    fold's shadow) is as coloured as its flanks or more; an instrument in the same shadow
    mirrors part of it only (`shaft.grey_material`). Arguments as `tissue_colour`'s; NaN
    for a band with a flank off the image, 0 for every band of a frame without colour.

    >>> img = np.zeros((180, 320, 3), np.uint8); img[:] = (90, 110, 190)
    >>> img[:90] = (40, 50, 95)                                       # a shadow over the top half
    >>> img[60:80] = (30, 33, 45)                                     # a black shaft in it
    >>> mids, wds = np.array([[0.0, 69.5, 319.0, 69.5]]), np.array([20.0])
    >>> tissue_colour(img, mids, wds).round(2).tolist(), flank_colour(img, mids, wds).round(2).tolist()
    ([0.53], [1.16])
    """
    img, mids, wds = _bands(image, midlines, widths, "flank colour")
    validity = Validity(valid_region, img.shape[:2]) if validity is None else validity
    c = _frame_chromaticity(img, validity) if len(mids) else np.zeros(2)
    cc = float(c @ c)
    out = np.zeros(len(mids))
    if cc < 1e-6:  # a grey scene: no tissue hue to compare with
        return out
    full = STATIONS * ACROSS
    for k, (m, w) in enumerate(zip(mids, wds)):
        sides = [_inside(img, m, w, across) for across in (FLANK, (-FLANK[1], -FLANK[0]))]
        # a flank cut by the image's edge is not the tissue beside the band along its run
        out[k] = np.nan if min(len(v) for v in sides) < full // 2 else min(
            float(np.median(_chromaticity(v), 0) @ c) / cc for v in sides)
    return out


def _of_shafts(measure, image, shafts, valid_region, validity):
    """`measure` (`tissue_colour` or `flank_colour`) of detected shafts (`detector.Shaft`, or
    lines.json records with ``midline`` and ``width_px``)."""
    if not len(shafts):
        return np.zeros(0)
    get = (lambda s, k: s[k]) if isinstance(shafts[0], dict) else getattr
    return measure(image, [np.asarray(get(s, "midline"), float) for s in shafts],
                   [float(get(s, "width_px")) for s in shafts], valid_region, validity)


def shaft_flank_colour(image, shafts, valid_region=None, validity=None):
    """`flank_colour` of detected shafts (`detector.Shaft`, or lines.json records with
    ``midline`` and ``width_px``)."""
    return _of_shafts(flank_colour, image, shafts, valid_region, validity)


def shaft_tissue_colour(image, shafts, valid_region=None, validity=None):
    """`tissue_colour` of detected shafts (`detector.Shaft`, or lines.json records with
    ``midline`` and ``width_px``)."""
    return _of_shafts(tissue_colour, image, shafts, valid_region, validity)
