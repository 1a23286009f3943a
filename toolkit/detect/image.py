"""Grey images for the detectors: one channel in its own grey levels, sampled bilinearly.

Every detector works on one grey channel (`GrayImage`): BGR is converted, 16-bit and float
images keep their own grey levels for the subpixel fits, and the OpenCV line detectors get
an 8-bit copy (``GrayImage.u8``). Pixels are OpenCV's: pixel (0, 0) is the centre of the
top-left pixel, x (u) right, y (v) down; samples are bilinear with the border replicated.

Example
-------
>>> import numpy as np
>>> img = GrayImage(np.arange(12, dtype=np.uint8).reshape(3, 4))
>>> img.shape, img.sample([1.5], [0.0]).tolist(), int(img.u8[2, 3])
((3, 4), [1.5], 11)
"""
from __future__ import annotations

import numpy as np

from pencilcal.toolkit.detect.region.valid import DETECTION_MARGIN_PX
from pencilcal.toolkit.errors import InputError

__all__ = ["GrayImage", "gray_image", "to_u8"]

_CV_MAX_COLS = 2048  # cv2.remap wants map sides below SHRT_MAX: sample in rows of this width


def _gray2d(image):
    """The image as one 2-D grey channel, in its own dtype (BGR converted)."""
    import cv2

    img = np.asarray(image)
    if img.ndim == 3 and img.shape[2] == 1:
        img = img[..., 0]
    if img.ndim == 3 and img.shape[2] in (3, 4):
        if img.shape[2] == 4:
            img = img[..., :3]
        if img.dtype not in (np.uint8, np.uint16, np.float32):
            img = img.astype(np.float32)
        img = cv2.cvtColor(np.ascontiguousarray(img), cv2.COLOR_BGR2GRAY)
    if img.ndim != 2 or img.size == 0:
        raise InputError(f"image: expected (H, W) or (H, W, 3), got shape {np.asarray(image).shape}")
    if img.dtype == np.bool_:
        img = img.astype(np.uint8) * 255
    return np.ascontiguousarray(img)


def to_u8(img):
    """(H, W) uint8 version of a 2-D grey image, for the OpenCV detectors.

    uint8 stays as it is; float images already in 0..255 keep their levels (rounded); others
    (16-bit, float beyond 0..255) are stretched from their minimum to their maximum.

    >>> to_u8(np.array([[0.0, 1000.0]], np.float32)).tolist()
    [[0, 255]]
    """
    if img.dtype == np.uint8:
        return img
    f = img.astype(np.float32, copy=False)
    lo, hi = float(np.min(f)), float(np.max(f))
    if img.dtype != np.uint16 and lo >= 0 and hi <= 255:
        lo, hi = 0.0, 255.0  # float images already in 8-bit units stay as they are
    return np.clip(np.round((f - lo) * (255.0 / max(hi - lo, 1e-12))), 0, 255).astype(np.uint8)


def gray_image(image):
    """(H, W) float32 grey levels and (H, W) uint8 for the detectors.

    image: (H, W) or (H, W, 3) BGR, uint8/uint16/float. 16-bit and float images keep their
    own grey levels for the refit; the detectors get them scaled to 0..255.

    >>> f, u = gray_image(np.full((2, 3, 3), 7, np.uint8))
    >>> f.dtype.name, f.shape, int(u[0, 0])
    ('float32', (2, 3), 7)
    """
    g = _gray2d(image)
    return g.astype(np.float32, copy=False), to_u8(g)


def _sample(img, x, y):
    """Bilinear samples of img (2-D float32) at float coordinates x, y (any equal shapes)."""
    import cv2

    shape = np.shape(x)
    n = int(np.prod(shape))
    if n == 0:
        return np.zeros(shape, np.float32)
    cols = min(n, _CV_MAX_COLS)
    rows = -(-n // cols)
    mx = np.zeros(rows * cols, np.float32)
    my = np.zeros(rows * cols, np.float32)
    mx[:n] = np.ravel(x)
    my[:n] = np.ravel(y)
    out = cv2.remap(img, mx.reshape(rows, cols), my.reshape(rows, cols), cv2.INTER_LINEAR,
                    borderMode=cv2.BORDER_REPLICATE)
    return out.reshape(-1)[:n].reshape(shape)


def _span(v, n):
    """(first, last + 1) pixel index [0, n] of the crop that bilinear samples at v (float32)
    need (one pixel more on each side); (0, n) when none is finite. The plain min and max
    when every value is finite (the common case: one pass each instead of NaN-aware ones).
    """
    lo, hi = np.min(v), np.max(v)
    if not (np.isfinite(lo) and np.isfinite(hi)):
        if not np.any(np.isfinite(v)):
            return 0, n
        with np.errstate(invalid="ignore"):
            lo, hi = np.nanmin(v), np.nanmax(v)
    return int(np.clip(np.floor(lo) - 1, 0, n - 1)), int(np.clip(np.ceil(hi) + 2, 1, n))


class GrayImage:
    """A grey image to sample from: bilinear interpolation on a float32 copy of just the part
    the samples need (converting a whole 1080p frame costs more than a whole refit).

    Parameters
    ----------
    image : (H, W) or (H, W, 3) array
        Grey or BGR, 8/16 bit or float (bool: 0/255).
    valid_region : region.ValidRegion, optional
        Where the scene is (a field stop, letterbox bars): the detectors judge edges only by
        samples in it (`in_region`). None, or a region that covers the whole image: the
        image itself.

    Attributes
    ----------
    src : (H, W) array
        The grey channel in the image's own dtype.
    shape : (H, W)
    u8 : (H, W) uint8
        The 8-bit version for the detectors (`to_u8`), made once when first asked for.
    region : region.ValidRegion or None
        The valid region, None where it covers the whole image.
    """

    def __init__(self, image, valid_region=None):
        self.src = _gray2d(image)
        self.shape = self.src.shape
        self._u8 = None
        self._f32 = None  # the whole frame as float32, once crops get large
        covers = valid_region is None or valid_region.covers_image(self.shape)
        self.region = None if covers else valid_region
        self._usable = None  # the region's interior, made once when first asked for

    @property
    def u8(self):
        if self._u8 is None:
            self._u8 = to_u8(self.src)
        return self._u8

    def sample(self, x, y):
        """Bilinear samples (float32, the shape of x) at float coordinates x, y [px] (equal
        shapes), the border replicated."""
        x = np.asarray(x, np.float32)
        y = np.asarray(y, np.float32)
        if x.size == 0:
            return np.zeros(x.shape, np.float32)
        H, W = self.shape
        if self.src.dtype == np.float32:
            return _sample(self.src, x, y)
        x0, x1 = _span(x, W)
        y0, y1 = _span(y, H)
        x1, y1 = max(x1, x0 + 1), max(y1, y0 + 1)
        if (x1 - x0) * (y1 - y0) > 0.25 * H * W:
            # samples all over the frame (a refit pass over every candidate edge): convert
            # the frame once instead of a crop of most of it at every call
            if self._f32 is None:
                self._f32 = self.src.astype(np.float32)
            return _sample(self._f32, x, y)
        crop = self.src[y0:y1, x0:x1].astype(np.float32)
        return _sample(crop, x - np.float32(x0), y - np.float32(y0))

    def inverted(self):
        """The same image with its grey levels turned over (light bars become dark ones):
        8/16-bit images as max - level, float ones as (min + max) - level (0..255 ones as
        255 - level), with the same valid region.

        >>> GrayImage(np.array([[0, 200]], np.uint8)).inverted().src.tolist()
        [[255, 55]]
        """
        g = self.src
        if np.issubdtype(g.dtype, np.integer):
            inv = (np.iinfo(g.dtype).max - g).astype(g.dtype)
        else:
            lo, hi = float(np.min(g)), float(np.max(g))
            top = 255.0 if lo >= 0 and hi <= 255 else lo + hi
            inv = (top - g).astype(g.dtype)
        out = GrayImage(inv)
        out.region, out._usable = self.region, self._usable
        return out

    def in_region(self, x, y):
        """(bool, the shape of x) points x, y [px] whose nearest pixel lies in the valid region,
        at least `region.DETECTION_MARGIN_PX` inside its boundary (the image border is no
        boundary); points beyond the image or not finite are not. Without a region: the
        points within the image.

        >>> from pencilcal.toolkit.detect.region.valid import ValidRegion
        >>> img = GrayImage(np.zeros((20, 20), np.uint8), ValidRegion.from_circle(10, 10, 8, 20, 20))
        >>> img.in_region(np.array([10.0, 15.0, 16.5, 19.0]), np.full(4, 10.0)).tolist()
        [True, True, False, False]
        """
        H, W = self.shape
        x = np.asarray(x, float)
        y = np.asarray(y, float)
        with np.errstate(invalid="ignore"):
            ok = (x >= 0) & (x <= W - 1) & (y >= 0) & (y <= H - 1)
        if self.region is None:
            return ok
        if self._usable is None:
            self._usable = self.region.interior(DETECTION_MARGIN_PX, self.shape)
        xi = np.clip(np.rint(np.where(ok, x, 0)), 0, W - 1).astype(np.intp)
        yi = np.clip(np.rint(np.where(ok, y, 0)), 0, H - 1).astype(np.intp)
        return ok & self._usable[yi, xi]

    def nearest(self, x, y):
        """Grey level (float64, the shape of x) of the pixel nearest each point [px], clamped
        to the image."""
        H, W = self.shape
        xi = np.clip(np.rint(np.nan_to_num(x)), 0, W - 1).astype(np.intp)
        yi = np.clip(np.rint(np.nan_to_num(y)), 0, H - 1).astype(np.intp)
        return self.src[yi, xi].astype(float)
