"""The sd of white image noise [grey levels], for thresholds relative to the noise.

Immerkaer's estimate (1996): the image filtered with the difference of two Laplacians,
which cancels structure up to second order; sd = sqrt(pi / 2) / 6 * mean |response|, here
from the median of |response| (scaled to the mean of a half-normal), which resists the
few large responses of edges and texture.

Example
-------
>>> import numpy as np
>>> rng = np.random.default_rng(0)
>>> round(estimate_noise(100 + rng.normal(0, 3, (200, 200))), 1)
3.0
"""
from __future__ import annotations

import numpy as np

from pencilcal.toolkit.detect.image import GrayImage

__all__ = ["estimate_noise", "noise_of"]

_LAPLACE_DIFF = np.array([[1, -2, 1], [-2, 4, -2], [1, -2, 1]], np.float32)


def estimate_noise(image):
    """Standard deviation of white image noise [grey levels] (Immerkaer 1996).

    image: (H, W) or (H, W, 3) array (BGR is converted to grey). Image edges inflate it
    slightly; textured images more.

    >>> rng = np.random.default_rng(0)
    >>> round(estimate_noise(100 + rng.normal(0, 3, (200, 200))), 1)
    3.0
    """
    import cv2

    src = GrayImage(image).src
    if min(src.shape) < 3:
        return 0.0
    if src.dtype == np.uint8:
        return _median_response_u8([src])
    g = src.astype(np.float32)
    r = cv2.filter2D(g, -1, _LAPLACE_DIFF, borderType=cv2.BORDER_REFLECT)[1:-1, 1:-1]
    # edges and texture give a few large responses: the median of |r| (scaled to the mean of
    # a half-normal) resists them
    return float(np.median(np.abs(r)) / 0.6745 / 6.0)


def noise_of(img):
    """`estimate_noise` of a `GrayImage` from ten bands of full-resolution rows spread over
    it (a quarter of a large image: the same value within a few percent, at a fraction of
    the cost); the whole image when it is small."""
    import cv2

    g = img.src
    H, W = g.shape
    if H * W <= 400_000 or H < 80:
        return estimate_noise(g)
    rows = max(8, H // 40)
    starts = np.unique(np.linspace(0, H - rows, 10).astype(int))
    if g.dtype == np.uint8:
        return _median_response_u8([g[s:s + rows] for s in starts])
    r = [np.abs(cv2.filter2D(g[s:s + rows].astype(np.float32), -1, _LAPLACE_DIFF)[1:-1, 1:-1]).ravel()
         for s in starts]
    return float(np.median(np.concatenate(r)) / 0.6745 / 6.0)


def _median_response_u8(blocks):
    """`estimate_noise` of 8-bit blocks (list of (h, w) uint8) together: their responses are
    integers (|r| <= 16 x 255), so the median comes from one histogram, exactly the float32
    median at a third of its cost."""
    import cv2

    k = _LAPLACE_DIFF.astype(np.int16)
    h = sum(np.bincount(np.abs(cv2.filter2D(b, cv2.CV_16S, k)[1:-1, 1:-1]).ravel(), minlength=4081)
            for b in blocks)
    cum = np.cumsum(h)
    n = int(cum[-1])
    lo, hi = np.searchsorted(cum, [(n - 1) // 2 + 1, n // 2 + 1])
    return float(np.float32((int(lo) + int(hi)) / 2.0) / 0.6745 / 6.0)
