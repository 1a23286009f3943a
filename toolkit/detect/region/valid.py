"""The valid region of an image: where the scene is, inside an endoscope's circular field
stop or between letterbox bars, minus static burnt-in overlays.

A `ValidRegion` is a circle ``(cx, cy, r)`` intersected with the image rectangle, or a
polygon (a letterbox rectangle, the full image, a circle clipped by bars, any simple
polygon), optionally minus axis-aligned boxes (``holes``: overlays), or a raster (a mask
file). The detectors (`segments`, `bars`, `shaft.detector`) take one and find nothing on its
boundary: the edge of a field stop is a strong, straight-ish edge that is no line of the
scene. `region.detect.detect_valid_region` finds it from the frames of a sequence;
`read_mask_file` reads a user's mask (a PNG, or JSON/YAML with a circle or a polygon).

Conventions
-----------
- Pixels: (0, 0) is the centre of the top-left pixel, x right, y down. The image rectangle
  is ``[0, W-1] x [0, H-1]`` (the centres of the outermost pixels), so the full image is
  ``{"polygon": [[0, 0], [W-1, 0], [W-1, H-1], [0, H-1]]}``.
- `distance_to_boundary` is signed [px], positive inside; a pixel on the image border has
  distance 0; the boundary belongs to the region. `mask`, `contains` and
  `distance_to_boundary` agree pixel for pixel.
- `to_dict` is exactly ``{"circle": [cx, cy, r]}`` or ``{"polygon": [[x, y], ...]}`` (the
  record in lines.json, docs/formats.md); holes only when asked for.

Example
-------
>>> reg = ValidRegion.from_circle(50.0, 40.0, 30.0, width=100, height=80)
>>> reg.to_dict(), bool(reg.contains([50, 40])), bool(reg.contains([2, 2]))
({'circle': [50.0, 40.0, 30.0]}, True, False)
>>> float(reg.distance_to_boundary([60.0, 40.0]))
20.0
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from typing import Any, Mapping

import numpy as np

from pencilcal.toolkit.errors import InputError

__all__ = ["ValidRegion", "read_mask_file", "DETECTION_MARGIN_PX", "KINDS"]

#: The detectors keep every sample they judge an edge by (profile windows, band
#: cross-sections) at least this far inside the region's boundary [px]: the detected
#: region is already shrunk past the field edge's blur (region.detect), this keeps the
#: kernels' tails off it too. The image border is no boundary (nothing lies beyond it).
DETECTION_MARGIN_PX = 2.0

#: What a region describes: the whole image, a letterbox rectangle, a circular field, a
#: polygon (a circle clipped by bars, a user's polygon) or a raster mask.
KINDS = ("full", "letterbox", "circle", "polygon", "raster")

_EPS = 1e-7  # [px] the boundary belongs to the region, up to rounding
_MAX_SAGITTA_PX = 0.1  # a circle's inscribed polygon deviates from it by less [px]


# ============================================================================ geometry


def _rect_sdf(x, y, rect):
    """Signed distance [px] (positive inside) to the axis-aligned box rect (x0, y0, x1, y1); exact."""
    x0, y0, x1, y1 = rect
    dx = np.maximum(x0 - x, x - x1)
    dy = np.maximum(y0 - y, y - y1)
    outside = np.hypot(np.maximum(dx, 0.0), np.maximum(dy, 0.0))
    inside = np.minimum(np.maximum(dx, dy), 0.0)
    return -(outside + inside)


def _poly_orient(poly):
    """The polygon (P, 2) with positive signed area (interior on the left of each edge)."""
    x, y = poly[:, 0], poly[:, 1]
    a2 = float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))
    return poly[::-1].copy() if a2 < 0 else poly.copy()


def _poly_area(poly):
    x, y = poly[:, 0], poly[:, 1]
    return 0.5 * abs(float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y)))


def _poly_is_convex(poly):
    p = _poly_orient(poly)
    e = np.roll(p, -1, axis=0) - p
    cr = e[:, 0] * np.roll(e, -1, axis=0)[:, 1] - e[:, 1] * np.roll(e, -1, axis=0)[:, 0]
    scale = max(1.0, float(np.abs(e).max()) ** 2)
    return bool(np.all(cr >= -1e-9 * scale))


def _seg_dist(px, py, poly):
    """Unsigned distance [px] from points to the polygon's boundary (min over its edges)."""
    d = np.full(px.shape, np.inf)
    for (ax, ay), (bx, by) in zip(poly, np.roll(poly, -1, axis=0)):
        ex, ey = bx - ax, by - ay
        l2 = ex * ex + ey * ey
        t = np.zeros_like(px) if l2 <= 0 else np.clip(((px - ax) * ex + (py - ay) * ey) / l2, 0.0, 1.0)
        d = np.minimum(d, np.hypot(px - (ax + t * ex), py - (ay + t * ey)))
    return d


def _halfplanes(poly):
    """Inward unit normals n (E, 2) and offsets c (E,), n.p + c >= 0 inside (convex, oriented)."""
    e = np.roll(poly, -1, axis=0) - poly
    ln = np.hypot(e[:, 0], e[:, 1])
    keep = ln > 1e-12
    a, e, ln = poly[keep], e[keep], ln[keep]
    n = np.stack([-e[:, 1], e[:, 0]], axis=1) / ln[:, None]
    return n, -(n[:, 0] * a[:, 0] + n[:, 1] * a[:, 1])


def _even_odd(px, py, poly):
    """(...) bool: inside a simple polygon by the even-odd rule."""
    inside = np.zeros(px.shape, dtype=bool)
    for (ax, ay), (bx, by) in zip(poly, np.roll(poly, -1, axis=0)):
        cond = (ay > py) != (by > py)
        with np.errstate(divide="ignore", invalid="ignore"):
            xint = ax + (py - ay) * (bx - ax) / (by - ay)
        inside ^= cond & (px < xint)
    return inside


def _poly_sdf(px, py, poly, convex):
    """Signed distance [px] to an oriented polygon: exact, positive inside."""
    if convex:
        n, c = _halfplanes(poly)
        h = np.full(px.shape, np.inf)
        for (nx, ny), ci in zip(n, c):
            h = np.minimum(h, nx * px + ny * py + ci)
        inside = h >= -_EPS
        if np.all(inside):
            return h
        return np.where(inside, np.maximum(h, 0.0), -_seg_dist(px, py, poly))
    d = _seg_dist(px, py, poly)
    return np.where(_even_odd(px, py, poly) | (d <= 1e-9), d, -d)


def _isect(p, q, axis, val):
    t = (val - p[axis]) / (q[axis] - p[axis])
    r = (p[0] + t * (q[0] - p[0]), p[1] + t * (q[1] - p[1]))
    return (val, r[1]) if axis == 0 else (r[0], val)


def clip_polygon_to_rect(poly, rect):
    """The polygon (P, 2) clipped to the box rect (x0, y0, x1, y1) (Sutherland-Hodgman): (Q, 2).

    >>> clip_polygon_to_rect(np.array([[-1.0, -1], [3, -1], [3, 3], [-1, 3]]), (0, 0, 2, 2)).tolist()
    [[0.0, 2.0], [0.0, 0.0], [2.0, 0.0], [2.0, 2.0]]
    """
    x0, y0, x1, y1 = rect
    out = [tuple(p) for p in poly]
    for axis, val, keep_ge in ((0, x0, True), (0, x1, False), (1, y0, True), (1, y1, False)):
        if not out:
            break
        inp, out = out, []
        for i in range(len(inp)):
            p, q = inp[i - 1], inp[i]
            pin = (p[axis] >= val) if keep_ge else (p[axis] <= val)
            qin = (q[axis] >= val) if keep_ge else (q[axis] <= val)
            if qin:
                if not pin:
                    out.append(_isect(p, q, axis, val))
                out.append(q)
            elif pin:
                out.append(_isect(p, q, axis, val))
    return np.asarray(out, dtype=float).reshape(-1, 2)


def circle_polygon(cx, cy, r, max_sagitta=_MAX_SAGITTA_PX):
    """(P, 2) polygon inscribed in the circle, its chords within `max_sagitta` [px] of it
    (so it lies inside: conservative), 32 to 4096 vertices.

    >>> circle_polygon(0.0, 0.0, 10.0).shape, circle_polygon(0.0, 0.0, 1000.0).shape
    ((32, 2), (223, 2))
    """
    dth = 2.0 * math.sqrt(2.0 * max_sagitta / max(r, 1e-6))
    n = int(min(4096, max(32, math.ceil(2 * math.pi / dth))))
    th = np.linspace(0, 2 * np.pi, n, endpoint=False)
    return np.stack([cx + r * np.cos(th), cy + r * np.sin(th)], axis=1)


def _on_rect_edge(p, q, rect, tol=1e-6):
    x0, y0, x1, y1 = rect
    return any(abs(p[axis] - val) <= tol and abs(q[axis] - val) <= tol
               for axis, val in ((0, x0), (0, x1), (1, y0), (1, y1)))


def _clip_halfplane(poly, n, off):
    """The convex polygon (P, 2) clipped to n . p >= off."""
    out = []
    for i in range(len(poly)):
        p, q = poly[i - 1], poly[i]
        fp, fq = n @ p - off, n @ q - off
        if fq >= 0:
            if fp < 0:
                out.append(p + (q - p) * (fp / (fp - fq)))
            out.append(q)
        elif fp >= 0:
            out.append(p + (q - p) * (fp / (fp - fq)))
    return np.asarray(out, float).reshape(-1, 2)


def _offset_convex(poly, shift):
    """Each edge of a convex oriented polygon (P, 2) moved inward by shift (P,) [px]; None
    when nothing is left."""
    e = np.roll(poly, -1, axis=0) - poly
    ln = np.hypot(e[:, 0], e[:, 1])
    keep = ln > 1e-12
    a, e, ln, shift = poly[keep], e[keep], ln[keep], np.asarray(shift)[keep]
    n = np.stack([-e[:, 1], e[:, 0]], axis=1) / ln[:, None]
    big = 1e7  # half-planes n.p >= n.a + shift, intersected by clipping a big box
    cur = np.array([[-big, -big], [big, -big], [big, big], [-big, big]], float)
    for ni, ai, si in zip(n, a, shift):
        cur = _clip_halfplane(cur, ni, float(ni @ ai + si))
        if len(cur) < 3:
            return None
    return None if _poly_area(cur) <= 1e-9 else cur


def _convex_poly_mask(poly, h, w):
    """(h, w) bool: pixel centres inside a convex oriented polygon (row spans)."""
    n, c = _halfplanes(poly)
    ys = np.arange(h, dtype=float)
    lo = np.full(h, -np.inf)
    hi = np.full(h, np.inf)
    ok = np.ones(h, bool)
    for (nx, ny), ci in zip(n, c):
        rhs = -(ny * ys + ci) - _EPS  # nx * x >= rhs
        if abs(nx) < 1e-12:
            ok &= (ny * ys + ci) >= -_EPS
        elif nx > 0:
            lo = np.maximum(lo, rhs / nx)
        else:
            hi = np.minimum(hi, rhs / nx)
    xa = np.clip(np.ceil(lo - 1e-9), 0, w).astype(int)
    xb = np.clip(np.floor(hi + 1e-9), -1, w - 1).astype(int)
    xx = np.arange(w)[None, :]
    return (xx >= xa[:, None]) & (xx <= xb[:, None]) & ok[:, None]


def _is_rect(arr):
    if len(arr) != 4:
        return False
    return len(np.unique(np.round(arr[:, 0], 9))) == 2 and len(np.unique(np.round(arr[:, 1], 9))) == 2


def _self_intersects(arr):
    """True when two non-adjacent edges of the polygon (P, 2) cross."""
    n = len(arr)
    segs = [(arr[i], arr[(i + 1) % n]) for i in range(n)]

    def cross(o, a, b):
        return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])

    for i in range(n):
        for j in range(i + 2, n):
            if i == 0 and j == n - 1:
                continue
            (p1, p2), (p3, p4) = segs[i], segs[j]
            d1, d2 = cross(p3, p4, p1), cross(p3, p4, p2)
            d3, d4 = cross(p1, p2, p3), cross(p1, p2, p4)
            if d1 * d2 < 0 and d3 * d4 < 0:
                return True
    return False


def _numbers(v, name, n):
    """`v` as a list of n finite floats; InputError naming `name` otherwise."""
    if isinstance(v, (str, bytes)) or not isinstance(v, (list, tuple, np.ndarray)):
        raise InputError(f"{name} must be a list of {n} numbers, got {type(v).__name__}")
    if len(v) != n:
        raise InputError(f"{name} must have {n} numbers, got {len(v)}")
    out = []
    for x in v:
        if isinstance(x, bool) or not isinstance(x, (int, float, np.integer, np.floating)):
            raise InputError(f"{name} must contain numbers, got {x!r}")
        if not math.isfinite(float(x)):
            raise InputError(f"{name} must contain finite numbers, got {x!r}")
        out.append(float(x))
    return out


def _raster_sdf(ras):
    """(H, W) float32 signed distance [px] of a bool raster's pixels to its boundary
    (pixel-quantised: the first pixel inside 0, the first outside -1)."""
    import cv2

    m = np.pad(ras.astype(np.uint8), 1)
    din = cv2.distanceTransform(m, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)[1:-1, 1:-1]
    dout = cv2.distanceTransform(1 - m, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)[1:-1, 1:-1]
    return np.where(ras, din - 1.0, -dout).astype(np.float32)


def _raster_polygon(ras):
    """[[x, y], ...] of the largest outer contour of a bool raster (within 0.5 px)."""
    import cv2

    cs, _ = cv2.findContours(ras.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    if not cs:
        raise InputError("mask is empty: no polygon")
    c = cv2.approxPolyDP(max(cs, key=cv2.contourArea), 0.5, True).reshape(-1, 2)
    return [[float(x), float(y)] for x, y in c]


def _holes_from(value):
    """Holes ((x0, y0, x1, y1), ...) of a region record's 'holes'; InputError otherwise."""
    if not isinstance(value, (list, tuple)):
        raise InputError("'holes' must be a list of [x0, y0, x1, y1]")
    out = []
    for i, hb in enumerate(value):
        v = _numbers(hb, f"holes[{i}]", 4)
        if not (v[0] <= v[2] and v[1] <= v[3]):
            raise InputError(f"holes[{i}] must have x0 <= x1 and y0 <= y1, got {v}")
        out.append(tuple(v))
    return tuple(out)


def _shape_of(shape):
    """(H, W) ints of `shape`, or (None, None); InputError for a bad one."""
    if shape is None:
        return None, None
    try:
        h, w = int(shape[0]), int(shape[1])
    except (TypeError, ValueError, IndexError):
        raise InputError(f"shape must be (H, W), got {shape!r}") from None
    if h <= 0 or w <= 0:
        raise InputError(f"shape must be positive, got {shape!r}")
    return h, w


def _polygon_from(pl):
    """((x, y), ...) of a region record's 'polygon', checked (InputError)."""
    if not isinstance(pl, (list, tuple)) or isinstance(pl, (str, bytes)):
        raise InputError("'polygon' must be a list of [x, y] points")
    if len(pl) < 3:
        raise InputError(f"polygon needs at least 3 points, got {len(pl)}")
    pts = tuple(tuple(_numbers(p, f"polygon[{i}]", 2)) for i, p in enumerate(pl))
    arr = np.asarray(pts, float)
    if len(arr) > 3 and not _poly_is_convex(arr) and _self_intersects(arr):
        raise InputError("polygon is self-intersecting")
    if _poly_area(arr) <= 1e-9:
        raise InputError("polygon has zero area (collinear or repeated points)")
    return pts


# ============================================================================ the region


@dataclass(frozen=True, eq=True)
class ValidRegion:
    """The valid part of an image.

    Exactly one of `circle`, `polygon` or `raster` describes the shape.

    Attributes
    ----------
    width, height : int or None
        The image size [px] (None: unknown; `mask` then needs a shape).
    circle : (cx, cy, r) [px] or None
        The disc, intersected with the image rectangle when the size is known.
    polygon : ((x, y), ...) [px] or None
        A letterbox rectangle, the full image or any simple polygon (intersected with the
        image rectangle too).
    holes : ((x0, y0, x1, y1), ...) [px]
        Axis-aligned boxes removed from the region (static overlays); their boundary
        belongs to the region.
    kind : str
        One of `KINDS`.
    raster : (H, W) bool or None
        A mask read from an image (`to_dict` gives the polygon of its largest outer contour).
    info : dict
        The detector's diagnostics (thresholds, the un-eroded fit, margins); not compared.

    Example
    -------
    >>> full = ValidRegion.full(200, 160)
    >>> full.to_dict()["polygon"][2], bool(full.mask().all()), full.covers_image()
    ([199.0, 159.0], True, True)
    """

    width: int | None
    height: int | None
    circle: tuple | None = None
    polygon: tuple | None = None
    holes: tuple = ()
    kind: str = "polygon"
    raster: np.ndarray | None = field(default=None, compare=False, repr=False)
    info: dict = field(default_factory=dict, compare=False, repr=False)
    _cache: dict = field(default_factory=dict, compare=False, repr=False, init=False)

    __hash__ = None  # a raster and the info make it mutable in effect

    def __getstate__(self):
        # what it derives (the raster's distance field, the interiors) is made again where
        # it is needed, not sent to worker processes
        return {**self.__dict__, "_cache": {}}

    # ------------------------------------------------------------------ constructors

    @classmethod
    def full(cls, width, height):
        """The whole W x H image."""
        w, h = int(width), int(height)
        return cls(w, h, polygon=((0.0, 0.0), (w - 1.0, 0.0), (w - 1.0, h - 1.0), (0.0, h - 1.0)), kind="full")

    @classmethod
    def from_circle(cls, cx, cy, r, width=None, height=None, **kw):
        """The disc of centre (cx, cy) and radius r [px] (within the image when its size is given)."""
        return cls(width, height, circle=(float(cx), float(cy), float(r)), kind="circle", **kw)

    @classmethod
    def from_rect(cls, x0, y0, x1, y1, width=None, height=None, kind="letterbox", **kw):
        """The rectangle [x0, x1] x [y0, y1] [px]."""
        poly = ((float(x0), float(y0)), (float(x1), float(y0)), (float(x1), float(y1)), (float(x0), float(y1)))
        return cls(width, height, polygon=poly, kind=kind, **kw)

    # ------------------------------------------------------------------ size

    @property
    def shape(self):
        """(H, W) of the image, or None when unknown."""
        return None if self.width is None or self.height is None else (int(self.height), int(self.width))

    def _image_rect(self, shape=None):
        shp = shape if shape is not None else self.shape
        return None if shp is None else (0.0, 0.0, int(shp[1]) - 1.0, int(shp[0]) - 1.0)

    def _check_shape(self, shape):
        if shape is None:
            if self.shape is None:
                raise InputError("the region has no image size: pass shape=(H, W)")
            return self.shape
        shape = (int(shape[0]), int(shape[1]))
        if self.shape is not None and shape != self.shape:
            raise InputError(f"shape {shape} differs from the region's image size {self.shape}")
        return shape

    # ------------------------------------------------------------------ distance, mask

    def _raster_distance(self):
        if "sdf" not in self._cache:
            self._cache["sdf"] = _raster_sdf(self.raster)
        return self._cache["sdf"]

    def _sdf_xy(self, x, y, shape=None):
        x = np.asarray(x, dtype=float)
        y = np.asarray(y, dtype=float)
        if self.raster is not None:
            d = self._raster_distance()
            h, w = d.shape
            out = d[np.clip(np.rint(np.nan_to_num(y)), 0, h - 1).astype(int),
                    np.clip(np.rint(np.nan_to_num(x)), 0, w - 1).astype(int)]
            r = _rect_sdf(x, y, (0.0, 0.0, w - 1.0, h - 1.0))  # beyond the image: the distance to it
            d = np.where(r < 0, np.minimum(r, out), out)
        elif self.circle is not None:
            cx, cy, r = self.circle
            d = r - np.hypot(x - cx, y - cy)
        else:
            poly = _poly_orient(np.asarray(self.polygon, dtype=float))
            d = _poly_sdf(x, y, poly, _poly_is_convex(poly))
        rect = self._image_rect(shape)
        if rect is not None and self.raster is None:
            d = np.minimum(d, _rect_sdf(x, y, rect))
        for hb in self.holes:
            d = np.minimum(d, -_rect_sdf(x, y, hb))
        return d

    def distance_to_boundary(self, points):
        """Signed distance [px] of points (..., 2) to the region's boundary, positive inside: (...).

        Exact inside; outside it is the distance to the nearest constraint (circle, polygon,
        image rectangle or hole), a lower bound where two constraints meet. A raster's is
        pixel-quantised.

        >>> ValidRegion.full(10, 10).distance_to_boundary([[1, 5], [-3, 5]]).tolist()
        [1.0, -3.0]
        """
        p = np.asarray(points, dtype=float)
        if p.shape[-1] != 2:
            raise InputError(f"points must have shape (..., 2), got {p.shape}")
        return self._sdf_xy(p[..., 0], p[..., 1])

    def distance_grid(self, shape, step_px):
        """Signed distance (Gy, Gx) float32 [px] to the boundary (`distance_to_boundary`) on the
        grid x = 0, step, ... up to W - 1 + step, y likewise, of an image of `shape` (H, W):
        made once per size and step (read-only), since a video's every frame samples it.

        >>> ValidRegion.full(10, 10).distance_grid((10, 10), 8.0).shape
        (3, 3)
        """
        H, W = int(shape[0]), int(shape[1])
        key = ("grid", H, W, float(step_px))
        if key not in self._cache:
            gx = np.arange(0.0, W - 1 + step_px, step_px)
            gy = np.arange(0.0, H - 1 + step_px, step_px)
            X, Y = np.meshgrid(gx, gy)
            g = np.ascontiguousarray(np.asarray(self.distance_to_boundary(np.stack([X, Y], -1)), np.float32))
            g.flags.writeable = False
            self._cache[key] = g
        return self._cache[key]

    def contains(self, points):
        """(...) bool: points (..., 2) [px] inside the region (boundary included)."""
        return self.distance_to_boundary(points) >= -_EPS

    def _shape_mask(self, h, w):
        if self.raster is not None:
            return self.raster.copy()
        if self.circle is not None:
            cx, cy, r = self.circle
            yy = np.arange(h, dtype=float)[:, None]
            xx = np.arange(w, dtype=float)[None, :]
            return (r - np.sqrt((xx - cx) ** 2 + (yy - cy) ** 2)) >= -_EPS
        poly = _poly_orient(np.asarray(self.polygon, dtype=float))
        if _poly_is_convex(poly):
            return _convex_poly_mask(poly, h, w)
        m = np.zeros((h, w), bool)
        xx = np.arange(w, dtype=float)
        for y0 in range(0, h, 64):
            X, Y = np.meshgrid(xx, np.arange(y0, min(h, y0 + 64), dtype=float))
            m[y0:y0 + X.shape[0]] = _poly_sdf(X, Y, poly, False) >= -_EPS
        return m

    def mask(self, shape=None):
        """(H, W) bool: the pixels whose centre lies in the region (holes removed).

        >>> ValidRegion.from_rect(1, 0, 2, 1, 4, 2).mask().astype(int).tolist()
        [[0, 1, 1, 0], [0, 1, 1, 0]]
        """
        h, w = self._check_shape(shape)
        m = self._shape_mask(h, w)
        for (x0, y0, x1, y1) in self.holes:
            # pixels strictly inside the hole (its boundary belongs to the region)
            xa, xb = max(0, math.floor(x0 + _EPS) + 1), min(w - 1, math.ceil(x1 - _EPS) - 1)
            ya, yb = max(0, math.floor(y0 + _EPS) + 1), min(h - 1, math.ceil(y1 - _EPS) - 1)
            if xa <= xb and ya <= yb:
                m[ya:yb + 1, xa:xb + 1] = False
        return m

    def covers_image(self, shape=None):
        """True when every pixel of the image is valid (the detectors then work as without a
        region).

        >>> big, small = ValidRegion.from_circle(5, 5, 100, 10, 10), ValidRegion.from_circle(5, 5, 4, 10, 10)
        >>> big.covers_image(), small.covers_image()
        (True, False)
        """
        h, w = self._check_shape(shape)
        if self.holes:
            return False
        if self.raster is not None:
            return bool(self.raster.all())
        corners = np.array([[0.0, 0.0], [w - 1.0, 0.0], [w - 1.0, h - 1.0], [0.0, h - 1.0]])
        if self.circle is not None or _poly_is_convex(np.asarray(self.polygon, float)):
            return bool(np.all(self._sdf_xy(corners[:, 0], corners[:, 1], (h, w)) >= -_EPS))
        return bool(self.mask((h, w)).all())

    def interior(self, margin_px=DETECTION_MARGIN_PX, shape=None):
        """(H, W) bool: the pixels at least `margin_px` [px] inside the region's boundary,
        where the image border is no boundary (pixel-quantised, within 0.5 px): where the
        detectors may look.

        >>> reg = ValidRegion.from_rect(0, 0, 5, 3, 10, 4)
        >>> reg.interior(2.0).astype(int).tolist()[0]
        [1, 1, 1, 1, 0, 0, 0, 0, 0, 0]
        """
        import cv2

        # made once per margin and size (read-only): a video's every frame asks for it, and
        # a 1080p one costs ~25 ms
        key = ("interior", float(margin_px), self._check_shape(shape))
        if key in self._cache:
            return self._cache[key]
        m = self.mask(shape)
        if margin_px > 0 and not m.all():
            pad = np.pad(m, 1, constant_values=True).astype(np.uint8)
            d = cv2.distanceTransform(pad, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)[1:-1, 1:-1]
            # d: from a valid pixel's centre to the nearest invalid one's; the boundary lies
            # about half a pixel short of it
            m = d >= margin_px + 0.5
        m.flags.writeable = False
        self._cache[key] = m
        return m

    def outline(self, shape=None):
        """The region's outer boundary within the image: a closed polygon (P + 1, 2) [px]
        (the last point repeats the first), holes left out.

        >>> ValidRegion.full(4, 3).outline().tolist()
        [[0.0, 0.0], [3.0, 0.0], [3.0, 2.0], [0.0, 2.0], [0.0, 0.0]]
        """
        h, w = self._check_shape(shape)
        if self.raster is not None:
            poly = np.asarray(_raster_polygon(self.raster), float)
        elif self.circle is not None:
            poly = circle_polygon(*self.circle)
        else:
            poly = np.asarray(self.polygon, float)
        poly = _poly_orient(clip_polygon_to_rect(poly, (0.0, 0.0, w - 1.0, h - 1.0)))
        if len(poly) < 3:
            raise InputError("the region holds no part of the image")
        return np.concatenate([poly, poly[:1]])

    # ------------------------------------------------------------------ derived

    def eroded(self, margin_px):
        """The region shrunk by `margin_px` [px]: the circle's radius or the polygon's edges
        move inward, holes grow. Edges of a full or letterbox polygon that lie on the image
        border stay (the image border is sharp). InputError when nothing would be left.

        >>> ValidRegion.from_circle(100, 80, 60, 200, 160).eroded(5).circle
        (100.0, 80.0, 55.0)
        """
        m = float(margin_px)
        if not math.isfinite(m) or m < 0:
            raise InputError(f"margin_px must be a finite number >= 0, got {margin_px!r}")
        holes = tuple((a - m, b - m, c + m, d + m) for (a, b, c, d) in self.holes)
        info = dict(self.info, eroded_by=self.info.get("eroded_by", 0.0) + m)
        if self.raster is not None:
            ras = self.raster if m == 0 else _raster_sdf(self.raster) >= m
            return ValidRegion(self.width, self.height, holes=holes, kind="raster", raster=ras, info=info)
        if self.circle is not None:
            cx, cy, r = self.circle
            if r - m <= 0:
                raise InputError(f"eroding by {m} px removes the whole circle (r={r:.1f})")
            return ValidRegion(self.width, self.height, circle=(cx, cy, r - m), holes=holes, kind=self.kind,
                               info=info)
        poly = _poly_orient(np.asarray(self.polygon, dtype=float))
        if not _poly_is_convex(poly):
            raise InputError("eroded() supports only convex polygons")
        rect = self._image_rect()
        shift = np.full(len(poly), m)
        if rect is not None and self.kind in ("full", "letterbox"):
            for i, (p, q) in enumerate(zip(poly, np.roll(poly, -1, axis=0))):
                if _on_rect_edge(p, q, rect):
                    shift[i] = 0.0
        newp = _offset_convex(poly, shift)
        if newp is None:
            raise InputError(f"eroding by {m} px removes the whole polygon")
        kind = self.kind if self.kind != "full" or m == 0 else "letterbox"
        return ValidRegion(self.width, self.height, polygon=tuple(map(tuple, newp.tolist())), holes=holes,
                           kind=kind, info=info)

    # ------------------------------------------------------------------ records

    def to_dict(self, include_holes=False):
        """``{"circle": [cx, cy, r]}`` or ``{"polygon": [[x, y], ...]}`` [px] (a raster: the
        polygon of its largest outer contour); ``"holes"`` too with `include_holes`."""
        if self.circle is not None:
            d: dict[str, Any] = {"circle": [float(v) for v in self.circle]}
        elif self.polygon is not None:
            d = {"polygon": [[float(x), float(y)] for x, y in self.polygon]}
        else:
            d = {"polygon": _raster_polygon(self.raster)}
        if include_holes and self.holes:
            d["holes"] = [[float(v) for v in hb] for hb in self.holes]
        return d

    @classmethod
    def from_dict(cls, d, shape=None):
        """The region of a record ``{"circle": [cx, cy, r]}`` or ``{"polygon": [[x, y], ...]}``
        (optional ``"holes": [[x0, y0, x1, y1], ...]``); `shape` (H, W) sets the image size.
        InputError (one line naming the problem) for anything else.

        >>> ValidRegion.from_dict({"circle": [1, 2, -3]})
        Traceback (most recent call last):
        ...
        pencilcal.toolkit.errors.InputError: circle radius must be > 0, got -3.0
        """
        if not isinstance(d, Mapping):
            raise InputError(f"region must be a mapping with key 'circle' or 'polygon', got {type(d).__name__}")
        unknown = set(d.keys()) - {"circle", "polygon", "holes"}
        if unknown:
            raise InputError(f"unknown region key(s) {sorted(map(str, unknown))}; expected 'circle' or 'polygon' "
                             "(and optional 'holes')")
        if ("circle" in d) == ("polygon" in d):
            raise InputError("region must have exactly one of 'circle' or 'polygon'")
        h, w = _shape_of(shape)
        holes = _holes_from(d["holes"]) if "holes" in d else ()
        if "circle" in d:
            cx, cy, r = _numbers(d["circle"], "circle", 3)
            if r <= 0:
                raise InputError(f"circle radius must be > 0, got {r}")
            return cls(w, h, circle=(cx, cy, r), holes=holes, kind="circle")
        pts = _polygon_from(d["polygon"])
        arr = np.asarray(pts, float)
        kind = "polygon"
        if w is not None and _is_rect(arr):
            (x0, y0), (x1, y1) = arr.min(0), arr.max(0)
            whole = max(abs(x0), abs(y0), abs(x1 - (w - 1)), abs(y1 - (h - 1))) < 1e-6
            kind = "full" if whole else "letterbox"
        return cls(w, h, polygon=pts, holes=holes, kind=kind)


# ============================================================================ mask files


def _region_file(path, h, w):
    """The region of a JSON/YAML file (a record, or one under ``valid_region``)."""
    from pencilcal.toolkit.io.files import load_structured

    data = load_structured(path, "mask file")
    if isinstance(data, Mapping) and "valid_region" in data:  # also a lines.json's
        data = data["valid_region"]
    try:
        reg = ValidRegion.from_dict(data, shape=(h, w))
    except InputError as e:
        raise InputError(f"{path}: {e}") from None
    if not reg.mask().any():
        raise InputError(f"{path}: the region contains no pixel of a {w}x{h} image")
    return reg


def read_mask_file(path, shape):
    """A user's valid region: `ValidRegion` of kind "raster" or as the file says.

    Parameters
    ----------
    path : str or Path
        An image (``.png``, ``.bmp``, ``.tif``, ...) whose nonzero pixels are valid, of the
        frames' size; or ``.json`` / ``.yaml`` / ``.yml`` holding ``{"circle": [cx, cy, r]}``
        or ``{"polygon": [[x, y], ...]}`` [px] (optional ``holes``), also under a top-level
        ``valid_region`` key (a lines.json written by `pencilcal lines` has one).
    shape : (H, W)
        The frames' size.

    Raises
    ------
    InputError
        Naming the file: missing, unreadable, of another size, empty, not valid JSON/YAML,
        a bad record, or a region with no pixel in the image.
    """
    from pencilcal.toolkit.io.images import decode_image

    p = os.fspath(path)
    h, w = _shape_of(shape)
    if h is None:
        raise InputError(f"{p}: the frames' shape (H, W) is needed to read a mask")
    if not os.path.isfile(p):
        raise InputError(f"{p}: no such mask file")
    if os.path.splitext(p)[1].lower() in (".json", ".yaml", ".yml"):
        return _region_file(p, h, w)
    img, err = decode_image(p, min_side=1)  # a mask of the wrong size is said below, with both sizes
    if img is None:
        raise InputError(f"{p}: not a readable mask image nor a .json/.yaml region ({err})")
    if img.shape[:2] != (h, w):
        raise InputError(f"{p}: mask is {img.shape[1]}x{img.shape[0]}, the images are {w}x{h}")
    m = (img if img.ndim == 2 else img.max(axis=2)) != 0
    if not m.any():
        raise InputError(f"{p}: mask has no nonzero (valid) pixel")
    return ValidRegion(w, h, kind="raster", raster=m, info={"source": p})
