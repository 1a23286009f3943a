"""Line segments with subpixel precision and an honest angle uncertainty.

Pipeline of `detect_segments` (one grey image, one call):

1. *detect*: OpenCV's LSD (``cv2.createLineSegmentDetector``), FLD
   (``cv2.ximgproc.createFastLineDetector``) or EDLines (``cv2.ximgproc.createEdgeDrawing``)
   on the 8-bit image (`detect_raw`);
2. *orient* every fragment by its edge polarity (`orient_by_polarity`), so that opposite
   edges of a thin bar are never merged;
3. *undistort* the fragments when a camera is given: lens distortion bends long lines, so
   everything after this step works in ideal (undistorted) pixels, ``camera.undistort_pixels``;
4. *merge* collinear fragments, gaps allowed (`merge_collinear`);
5. *refit* every merged line to its edge pixels (`refine_segments`): at stations every
   2 px along the line the grey-level profile across it is sampled (bilinear, 0.5 px steps)
   and differentiated with a Gaussian-derivative kernel; the subpixel edge is the peak of
   that derivative, refined by a parabola through the logarithms of the three samples
   around the maximum (exact for a Gaussian-blurred step). Each station starts its samples
   at a different fraction of a step (golden-ratio sequence), which spreads the ~3e-3 px
   phase bias of bilinear resampling instead of letting it turn lines near 0, 45 and 90
   deg. A weighted line fit through the station edges (weights: squared edge strength),
   with robust rejection of stations on other structures (beyond 3 robust sd), trimmed to
   the longest run of supporting stations and leaving out the last 2 sigma + 1 px before
   each end (where a corner's blur pulls the edge), gives the line, its end points (where
   the edge response falls to half) and its uncertainty. A line whose edge runs on past
   the stations looked at is sampled again, further out, while the evidence continues.
   Under a camera the stations lie on the *undistorted* line and are sampled in the raw
   image through ``camera.distort_pixels`` and the local Jacobian of the lens map.

`detect_bars` pairs the two opposite edges of thin dark bars (the printed spokes, pencil.py)
and returns their midlines; `assemble_pencil` intersects segments robustly
(vertex.intersect_lines, on undistorted segments).

Conventions
-----------
- Pixels: OpenCV's, pixel (0, 0) is the centre of the top-left pixel; u right, v down.
- A segment is ``[x1, y1, x2, y2]`` [px]. Returned segments are in RAW (distorted) pixels,
  their end points are the ends of the fit in undistorted pixels mapped back through the
  lens model (``Segments.ideal`` keeps the undistorted ones).
- Direction and polarity: with d = (p2 - p1) / |p2 - p1| and n = (-d_y, d_x) (the normal of
  vertex.py), the image gets *brighter* along n. On screen (v down) the dark side is on the
  left when walking from p1 to p2.
- Uncertainty (the noise model of vertex.py): ``angle_sigma`` [rad] is the sd of the line's
  angle, ``offset_sigma`` [px] the sd of its perpendicular position at the segment midpoint
  (angle errors pivot about the weighted centroid of the stations, near the midpoint).
  Both come from the scatter of the station edges about the fitted line,
  sd(angle) = s_0 / sqrt(sum_k w_k (s_k - s_mean)^2), with s_0 made honest for correlated
  station errors (neighbouring stations share pixels; real edges wander smoothly): the
  larger of an AR(1) inflation and a batch-means estimate (`_fit_variances`). On the
  synthetic edges of tests/toolkit/detect/test_lines.py the angle error over its sd is N(0, 1)
  within 5 % (coverage of +-1 sd 0.65-0.72). When a camera is given they refer to the
  undistorted line, which is what the estimators use.

Example
-------
>>> import numpy as np
>>> from scipy.special import ndtr
>>> v, u = np.mgrid[0:240, 0:320].astype(float)
>>> n = np.array([-np.sin(0.3), np.cos(0.3)])                   # an edge at 0.3 rad
>>> img = 60 + 140 * ndtr((n[0] * (u - 160) + n[1] * (v - 120)) / 1.04)
>>> segs = detect_segments(img.astype(np.uint8), "lsd", min_length=50)
>>> len(segs), round(float(segs.angle[0]), 4), bool(segs.angle_sigma[0] < 1e-4)
(1, 0.3, True)
"""
from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from pencilcal.toolkit.errors import EstimationError, InputError

__all__ = [
    "DETECTORS",
    "lines_record",
    "default_min_length",
    "Segments",
    "Bars",
    "detect_raw",
    "orient_by_polarity",
    "merge_collinear",
    "refine_segments",
    "detect_segments",
    "detect_bars",
    "bar_midlines_on_plane",
    "assemble_pencil",
    "gray_image",
]

DETECTORS = ("lsd", "fld", "edlines")

# Sampling of the profiles across a line: step along the normal [px] and the sd of the
# Gaussian-derivative kernel [px]. A kernel matched to a ~1 px blurred edge is close to the
# optimal (matched) filter; the log-parabola peak is exact for a Gaussian derivative profile.
_DT = 0.5
_MAX_STATIONS = 400  # per line: long lines get sparser stations, the cost stays bounded
_MIN_STATIONS = 6
_DARK_GROW = 1
_FLOOR_PX = 0.01  # smallest per-station scatter [px] the uncertainty may assume
_CV_MAX_COLS = 2048  # cv2.remap wants map sides below SHRT_MAX: sample in rows of this width


# ============================================================================ results


@dataclass(frozen=True, eq=False)
class Segments:
    """Refined line segments of one image. M segments, every array has leading shape (M,).

    Attributes
    ----------
    segments : (M, 4) [px]
        ``[x1, y1, x2, y2]`` in raw (distorted) pixels, oriented so that the image is brighter
        on the side of n = (-d_y, d_x) (dark on the left on screen).
    ideal : (M, 4) [px]
        The same segments in undistorted pixels (``camera.undistort_pixels``); equal to
        `segments` without a camera.
    angle_sigma : (M,) [rad]
        sd of the angle of each (undistorted) line.
    offset_sigma : (M,) [px]
        sd of its perpendicular position at the segment midpoint.
    length : (M,) [px]
        Length of the undistorted segment.
    contrast : (M,) [grey levels]
        Median step across the edge (bright side minus dark side), > 0.
    residual_px : (M,) [px]
        RMS distance of the inlier station edges from the fitted line.
    stations : (M,) int
        Number of inlier stations (edge points) in the fit.
    """

    segments: np.ndarray
    ideal: np.ndarray
    angle_sigma: np.ndarray
    offset_sigma: np.ndarray
    length: np.ndarray
    contrast: np.ndarray
    residual_px: np.ndarray
    stations: np.ndarray

    def __len__(self) -> int:
        return int(self.segments.shape[0])

    @property
    def angle(self) -> np.ndarray:
        """(M,) [rad] oriented angle atan2(dv, du) of each undistorted segment."""
        d = self.ideal[:, 2:] - self.ideal[:, :2]
        return np.arctan2(d[:, 1], d[:, 0])

    def select(self, mask):
        """A new result with the rows `mask` (bool (M,) or indices) selects."""
        return type(self)(**{f.name: getattr(self, f.name)[mask] for f in fields(self)})

    @classmethod
    def empty(cls, **extra):
        z = np.zeros(0)
        base = dict(segments=np.zeros((0, 4)), ideal=np.zeros((0, 4)), angle_sigma=z, offset_sigma=z,
                    length=z, contrast=z, residual_px=z, stations=np.zeros(0, int))
        base.update(extra)
        return cls(**base)


@dataclass(frozen=True, eq=False)
class Bars(Segments):
    """Midlines of thin dark bars (`detect_bars`): a `Segments` whose rows are midlines.

    Extra attributes: ``width_px`` (M,) [px] the bar's width across the midline at its
    centre (undistorted pixels); ``edges`` (M, 2, 4) [px] its two edge segments in raw pixels
    (first edge along the midline's direction, second reversed).
    The midline is the bisector of the two edge lines; its angle sd is
    sqrt(sigma_1^2 + sigma_2^2) / 2. It runs between the bar's two end caps, located along
    the midline where the grey level crosses half-way between the bar and the background.
    """

    width_px: np.ndarray
    edges: np.ndarray

    @classmethod
    def empty(cls, **extra):
        return super().empty(width_px=np.zeros(0), edges=np.zeros((0, 2, 4)), **extra)


# ============================================================================ images


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


def _to_u8(img):
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
    """
    g = _gray2d(image)
    return g.astype(np.float32, copy=False), _to_u8(g)


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


class _Gray:
    """A grey image to sample from: bilinear interpolation on a float32 copy of just the part
    the samples need (converting a whole 1080p frame costs more than the whole refit)."""

    def __init__(self, image):
        self.src = _gray2d(image)
        self.shape = self.src.shape
        self._u8 = None
        self._f32 = None  # the whole frame as float32, once crops get large

    @property
    def u8(self):
        if self._u8 is None:
            self._u8 = _to_u8(self.src)
        return self._u8

    def sample(self, x, y):
        """Bilinear samples (float32) at float coordinates x, y (equal shapes), border
        replicated."""
        x = np.asarray(x, np.float32)
        y = np.asarray(y, np.float32)
        if x.size == 0:
            return np.zeros(x.shape, np.float32)
        H, W = self.shape
        if self.src.dtype == np.float32:
            return _sample(self.src, x, y)
        with np.errstate(invalid="ignore"):
            x0 = int(np.clip(np.floor(np.nanmin(x)) - 1, 0, W - 1)) if np.any(np.isfinite(x)) else 0
            x1 = int(np.clip(np.ceil(np.nanmax(x)) + 2, 1, W)) if np.any(np.isfinite(x)) else W
            y0 = int(np.clip(np.floor(np.nanmin(y)) - 1, 0, H - 1)) if np.any(np.isfinite(y)) else 0
            y1 = int(np.clip(np.ceil(np.nanmax(y)) + 2, 1, H)) if np.any(np.isfinite(y)) else H
        x1, y1 = max(x1, x0 + 1), max(y1, y0 + 1)
        if (x1 - x0) * (y1 - y0) > 0.25 * H * W:
            # samples all over the frame (a refit pass over every candidate edge): convert
            # the frame once instead of a crop of most of it at every call
            if self._f32 is None:
                self._f32 = self.src.astype(np.float32)
            return _sample(self._f32, x, y)
        crop = self.src[y0:y1, x0:x1].astype(np.float32)
        return _sample(crop, x - np.float32(x0), y - np.float32(y0))

    def nearest(self, x, y):
        """Grey level (float) of the pixel nearest each point, clamped to the image."""
        H, W = self.shape
        xi = np.clip(np.rint(np.nan_to_num(x)), 0, W - 1).astype(np.intp)
        yi = np.clip(np.rint(np.nan_to_num(y)), 0, H - 1).astype(np.intp)
        return self.src[yi, xi].astype(float)


# ============================================================================ detectors

_DETECTOR_CACHE = {}


def _lsd(params):
    import cv2

    key = ("lsd", tuple(sorted(params.items())))
    if key not in _DETECTOR_CACHE:
        _DETECTOR_CACHE[key] = cv2.createLineSegmentDetector(**params)
    return _DETECTOR_CACHE[key]


def _fld(params):
    import cv2

    key = ("fld", tuple(sorted(params.items())))
    if key not in _DETECTOR_CACHE:
        p = {"length_threshold": 10, **params}
        _DETECTOR_CACHE[key] = cv2.ximgproc.createFastLineDetector(**p)
    return _DETECTOR_CACHE[key]


def _edlines(params):
    import cv2

    key = ("edlines", tuple(sorted(params.items())))
    if key not in _DETECTOR_CACHE:
        ed = cv2.ximgproc.createEdgeDrawing()
        p = cv2.ximgproc.EdgeDrawing.Params()
        p.MinLineLength = 10
        for k, v in params.items():
            if not hasattr(p, k):
                raise InputError(f"edlines: unknown parameter {k!r}")
            setattr(p, k, v)
        ed.setParams(p)
        _DETECTOR_CACHE[key] = ed
    return _DETECTOR_CACHE[key]


def detect_raw(image, detector="lsd", params=None):
    """The chosen OpenCV detector's segments, as it returns them.

    Parameters
    ----------
    image : (H, W) or (H, W, 3) array
        Grey or BGR image (8/16 bit or float); detectors run on its 8-bit version.
    detector : {"lsd", "fld", "edlines"}
        ``cv2.createLineSegmentDetector`` (LSD, default refinement), FLD
        (``cv2.ximgproc.createFastLineDetector``, ``length_threshold=10``) or EDLines
        (``cv2.ximgproc.createEdgeDrawing`` + ``detectLines``, ``MinLineLength=10``).
    params : dict, optional
        Keyword arguments of the OpenCV constructor (lsd, fld) or fields of
        ``cv2.ximgproc.EdgeDrawing.Params`` (edlines), e.g. ``{"canny_th1": 20}``.

    Returns
    -------
    (N, 4) float64 [px]
        ``[x1, y1, x2, y2]`` in the image's (raw) pixels, in no particular orientation.

    Example
    -------
    >>> img = np.zeros((100, 100), np.uint8); img[:, 50:] = 200
    >>> detect_raw(img, "fld").shape[1]
    4
    """
    if detector not in DETECTORS:
        raise InputError(f"unknown detector {detector!r}; expected one of {', '.join(DETECTORS)}")
    params = dict(params or {})
    u8 = image.u8 if isinstance(image, _Gray) else _to_u8(_gray2d(image))
    try:
        if detector == "lsd":
            out = _lsd(params).detect(u8)[0]
        elif detector == "fld":
            out = _fld(params).detect(u8)
        else:
            ed = _edlines(params)
            ed.detectEdges(u8)
            out = ed.detectLines()
    except TypeError as e:
        raise InputError(f"{detector}: bad detector parameters {params}: {e}") from None
    if out is None:
        return np.zeros((0, 4))
    return np.asarray(out, float).reshape(-1, 4)


def orient_by_polarity(image, segments, offset_px=1.0):
    """Orient segments so that the image is brighter on the side of n = (-d_y, d_x).

    image: grey/BGR image; segments: (N, 4) [px]. Sums the grey-level differences across
    each segment at 1, 2 and 3 times `offset_px` on both sides, at 1/4, 1/2 and 3/4 of its
    length (several distances: a segment a pixel or two off its edge still sees it).
    Returns (oriented (N, 4), flipped (N,) bool).

    >>> img = np.zeros((50, 50), np.float32); img[25:] = 100        # bright below
    >>> orient_by_polarity(img, [[40.0, 24.5, 10.0, 24.5]])[0].tolist()   # d = +u: n = +v
    [[10.0, 24.5, 40.0, 24.5]]
    """
    seg = np.asarray(segments, float).reshape(-1, 4)
    img = image if isinstance(image, _Gray) else _Gray(image)
    if seg.shape[0] == 0:
        return seg.copy(), np.zeros(0, bool)
    p1, p2 = seg[:, None, :2], seg[:, None, 2:]
    d = p2 - p1
    L = np.maximum(np.linalg.norm(d, axis=-1, keepdims=True), 1e-12)
    nrm = np.concatenate([-d[..., 1:], d[..., :1]], -1) / L
    pts = p1 + np.array([0.25, 0.5, 0.75])[None, :, None] * d  # (N, 3, 2)
    off = (offset_px * np.array([1.0, 2.0, 3.0]))[None, :, None, None] * nrm[:, None]  # (N, 3, 1, 2)
    # the nearest pixels are enough for a sign, and need no float copy of the image
    a = img.nearest(*(pts[:, None] + off).transpose(3, 0, 1, 2))
    b = img.nearest(*(pts[:, None] - off).transpose(3, 0, 1, 2))
    flip = np.sum(a - b, (-1, -2)) < 0
    out = seg.copy()
    out[flip] = seg[flip][:, [2, 3, 0, 1]]
    return out, flip


# ============================================================================ merging


def _line_frame(seg):
    p1, p2 = seg[:, :2], seg[:, 2:]
    d = p2 - p1
    L = np.hypot(d[:, 0], d[:, 1])
    u = d / np.maximum(L, 1e-12)[:, None]
    n = np.stack([-u[:, 1], u[:, 0]], -1)
    return p1, u, n, L


def merge_collinear(segments, angle_tol_deg=2.0, dist_tol_px=1.5, max_gap_px=30.0, min_length_px=0.0):
    """Merge oriented fragments that lie on one line, gaps allowed.

    Two fragments join when their oriented directions differ by less than `angle_tol_deg`
    (plus up to 1/L_short rad, at most as much again: a short fragment's own angle is that
    uncertain), both end points of
    the shorter lie within `dist_tol_px` (growing with the extrapolation) of the longer's
    line, and the gap between them along it is at most `max_gap_px`. Joins are transitive
    (connected components); a fragment that ends up farther than 2 `dist_tol_px` from its
    group's line is split off again, so a slow drift cannot chain unrelated fragments.
    Orientation matters: fragments in opposite directions are edges of opposite polarity
    (`orient_by_polarity`) and never merge.

    Parameters
    ----------
    segments : (N, 4) [px]
        Oriented fragments, undistorted pixels (straight lines).
    min_length_px : float
        Fragments shorter than this are ignored (label -1).

    Returns
    -------
    merged : (K, 4) [px]
        One segment per group: the length-weighted total-least-squares line through the
        fragments (each taken as a uniform mass along it), spanning their projections.
    labels : (N,) int
        Group of each fragment (row of `merged`), -1 for ignored fragments.

    Example
    -------
    >>> m, lab = merge_collinear([[0, 0, 40, 0], [55, 0, 100, 0], [100, 10, 0, 10]])
    >>> np.round(m, 6).tolist(), lab.tolist()                     # the third runs the other way
    ([[0.0, 0.0, 100.0, 0.0], [100.0, 10.0, 0.0, 10.0]], [0, 0, 1])
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    seg = np.asarray(segments, float).reshape(-1, 4)
    N = seg.shape[0]
    labels = np.full(N, -1)
    p1, u, n, L = _line_frame(seg)
    keep = np.flatnonzero((L >= max(min_length_px, 1e-9)) & np.all(np.isfinite(seg), -1))
    if keep.size == 0:
        return np.zeros((0, 4)), labels
    s, p1, u, n, L = seg[keep], p1[keep], u[keep], n[keep], L[keep]
    c = p1 + 0.5 * L[:, None] * u
    theta = np.arctan2(u[:, 1], u[:, 0])
    tol = np.radians(angle_tol_deg)
    # a short fragment's own angle is uncertain by ~1 px / L: the tolerance grows for it,
    # up to twice the nominal one
    tol_b = tol + np.minimum(1.0 / L, tol)

    # candidate pairs: fragments that come within max_gap of each other with similar
    # directions. Points every max_gap along each fragment (ends included) go into a KD-tree
    # on (position, direction scaled so that the angle tolerance weighs like the gap); a
    # Hough-like (angle, offset) key would need an offset tolerance growing with the
    # distance from its origin and flood a busy image with candidates.
    reach = max(max_gap_px, 2.0) + dist_tol_px
    npts = np.ceil(L / max(max_gap_px, 2.0)).astype(int) + 1
    owner = np.repeat(np.arange(L.size), npts)
    first = np.cumsum(npts) - npts
    frac = (np.arange(owner.size) - first[owner]) / np.maximum(npts[owner] - 1, 1)
    pts = s[owner, :2] + frac[:, None] * (s[owner, 2:] - s[owner, :2])
    dscale = reach / (2.0 * np.sin(min(2.0 * tol, 1.5) / 2.0))
    feat = np.column_stack([pts, dscale * u[owner]])
    pp = cKDTree(feat).query_pairs(np.sqrt(2.0) * reach, output_type="ndarray")
    if pp.size:
        i, j = owner[pp[:, 0]], owner[pp[:, 1]]
        i, j = np.minimum(i, j), np.maximum(i, j)
        key = np.unique(i[i != j] * L.size + j[i != j])
        pairs = np.stack([key // L.size, key % L.size], -1)
    else:
        pairs = np.zeros((0, 2), int)
    if pairs.size:
        i, j = pairs[:, 0], pairs[:, 1]
        a = np.where(L[i] >= L[j], i, j)  # the longer one is the reference line
        b = np.where(L[i] >= L[j], j, i)
        dth = np.abs(np.angle(np.exp(1j * (theta[a] - theta[b]))))
        ok = dth <= tol_b[b]
        # the shorter's end points in the longer's frame (along, across)
        e1 = s[b, :2] - c[a]
        e2 = s[b, 2:] - c[a]
        al1, al2 = np.sum(e1 * u[a], -1), np.sum(e2 * u[a], -1)
        ac1, ac2 = np.sum(e1 * n[a], -1), np.sum(e2 * n[a], -1)
        half = 0.5 * L[a]
        lo, hi = np.minimum(al1, al2), np.maximum(al1, al2)
        gap = np.maximum(0.0, np.maximum(lo - half, -half - hi))
        # allowed offset grows with the distance the longer line is extrapolated over
        reach = np.maximum(np.abs(np.stack([al1, al2], -1)) - half[:, None], 0.0).max(-1)
        dtol = dist_tol_px + reach / L[a]  # the longer line's angle is known to ~1 px / L
        ok &= (np.abs(ac1) <= dtol) & (np.abs(ac2) <= dtol) & (gap <= max_gap_px)
        i, j = i[ok], j[ok]
    else:
        i = j = np.zeros(0, int)
    K = keep.size
    graph = coo_matrix((np.ones(i.size), (i, j)), shape=(K, K))
    _, lab = connected_components(graph, directed=False)

    def groups(lab):
        mid, inv = np.unique(lab, return_inverse=True)
        G = mid.size
        w = L
        W = np.bincount(inv, w, G)
        m = np.stack([np.bincount(inv, w * c[:, 0], G), np.bincount(inv, w * c[:, 1], G)], -1) / W[:, None]
        dc = c - m[inv]
        # second moments: centres' scatter plus each fragment's own extent (L^2 / 12 along u)
        sxx = np.bincount(inv, w * (dc[:, 0] ** 2 + L**2 / 12 * u[:, 0] ** 2), G)
        syy = np.bincount(inv, w * (dc[:, 1] ** 2 + L**2 / 12 * u[:, 1] ** 2), G)
        sxy = np.bincount(inv, w * (dc[:, 0] * dc[:, 1] + L**2 / 12 * u[:, 0] * u[:, 1]), G)
        phi = 0.5 * np.arctan2(2 * sxy, sxx - syy)
        dirs = np.stack([np.cos(phi), np.sin(phi)], -1)
        # orient along the fragments' mean direction
        mean_u = np.stack([np.bincount(inv, w * u[:, 0], G), np.bincount(inv, w * u[:, 1], G)], -1)
        dirs *= np.where(np.sum(dirs * mean_u, -1) < 0, -1.0, 1.0)[:, None]
        return inv, m, dirs

    inv, m, dirs = groups(lab)
    nd = np.stack([-dirs[:, 1], dirs[:, 0]], -1)
    far = np.maximum(np.abs(np.sum((s[:, :2] - m[inv]) * nd[inv], -1)),
                     np.abs(np.sum((s[:, 2:] - m[inv]) * nd[inv], -1)))
    split = far > 2 * dist_tol_px
    if np.any(split):
        lab = lab.copy()
        lab[split] = lab.max() + 1 + np.arange(int(split.sum()))
        inv, m, dirs = groups(lab)
    G = m.shape[0]
    t1 = np.sum((s[:, :2] - m[inv]) * dirs[inv], -1)
    t2 = np.sum((s[:, 2:] - m[inv]) * dirs[inv], -1)
    tmin = np.full(G, np.inf)
    tmax = np.full(G, -np.inf)
    np.minimum.at(tmin, inv, np.minimum(t1, t2))
    np.maximum.at(tmax, inv, np.maximum(t1, t2))
    merged = np.concatenate([m + tmin[:, None] * dirs, m + tmax[:, None] * dirs], -1)
    labels[keep] = inv
    return merged, labels


# ============================================================================ subpixel refit


@dataclass(frozen=True, eq=False)
class _Fit:
    """Per-line refit result in working (undistorted) pixels; arrays (M,)."""

    ok: np.ndarray
    p1: np.ndarray  # (M, 2) end points on the fitted line
    p2: np.ndarray
    centroid: np.ndarray  # (M, 2) weighted centroid of the inlier stations (angle pivot)
    angle_sigma: np.ndarray  # [rad]
    centre_sigma: np.ndarray  # [px] perpendicular sd at the centroid
    contrast: np.ndarray
    residual: np.ndarray
    count: np.ndarray

    def offset_sigma_at(self, q):
        """Perpendicular sd [px] of each line at points q (M, 2) (lever arm from the centroid)."""
        u = self.p2 - self.p1
        u = u / np.maximum(np.linalg.norm(u, axis=-1, keepdims=True), 1e-12)
        r = np.sum((q - self.centroid) * u, -1)
        return np.sqrt(self.centre_sigma**2 + (r * self.angle_sigma) ** 2)


def _deriv_kernel(sigma):
    """Gaussian-derivative taps at spacing _DT, normalised to unit response to a unit slope."""
    r = int(np.ceil(3.0 * sigma / _DT))
    x = np.arange(-r, r + 1) * _DT
    k = x * np.exp(-0.5 * (x / sigma) ** 2)
    return k / np.sum(k * x), r


def _masked_median(a, mask):
    """Median of each row of a (M, S) over mask (NaN for an empty row); sort-based, fast."""
    M, S = a.shape
    cnt = mask.sum(-1)
    if S == 0:
        return np.full(M, np.nan)
    b = np.sort(np.where(mask, a, np.inf), axis=-1)
    r = np.arange(M)
    lo = np.clip((cnt - 1) // 2, 0, S - 1)
    hi = np.clip(cnt // 2, 0, S - 1)
    with np.errstate(invalid="ignore"):
        med = 0.5 * (b[r, lo] + b[r, hi])
    return np.where(cnt > 0, med, np.nan)


def _wls(s, t, w, mask):
    """Weighted LS line t = tm + b (s - sm) per row; returns (sm, tm, b, Sss, W)."""
    wm = np.where(mask, w, 0.0)
    W = np.maximum(wm.sum(-1), 1e-300)
    sm = np.sum(wm * s, -1) / W
    tm = np.sum(wm * t, -1) / W
    ds = s - sm[:, None]
    Sss = np.maximum(np.sum(wm * ds * ds, -1), 1e-300)
    b = np.sum(wm * ds * (t - tm[:, None]), -1) / Sss
    return sm, tm, b, Sss, W


def _best_run(s, mask, w, max_gap):
    """Keep, per row, the run of inlier stations (gaps <= max_gap along s) of largest weight."""
    M, S = mask.shape
    if S == 0:
        return mask
    idx = np.where(mask, np.arange(S), -1)
    prev = np.maximum.accumulate(idx, axis=1)  # last inlier at or before each station
    prev_before = np.concatenate([np.full((M, 1), -1), prev[:, :-1]], 1)
    has_prev = prev_before >= 0
    s_prev = np.take_along_axis(s, np.maximum(prev_before, 0), 1)
    start = mask & (~has_prev | (s - s_prev > max_gap))
    run = np.cumsum(start, 1) * mask  # 1-based run id of each inlier, 0 elsewhere
    flat = (np.arange(M)[:, None] * (S + 1) + run).ravel()
    tot = np.bincount(flat, np.where(mask, w, 0.0).ravel(), M * (S + 1)).reshape(M, S + 1)
    tot[:, 0] = -1.0
    best = np.argmax(tot, 1)
    return mask & (run == best[:, None])


def _fit_variances(s, res, w, inl, sm, Sss, Wt, long_blocks=0):
    """Variances (M,) of the slope and of the offset at the centroid of the weighted line
    fits, from the scatter of the station edges, honest when their errors are correlated.

    Textbook: s0^2 / Sxx and s0^2 / W with s0^2 = sum w r^2 / (N - 2) (weights relative).
    Neighbouring stations share pixels, and real edges wander smoothly (texture, shading,
    print), so station errors are correlated and the textbook values are too small. Two
    corrections, the larger wins:

    - AR(1): the textbook value times (1 + rho) / (1 - rho), rho the lag-1 autocorrelation
      of the weighted residuals (clipped to [0, 0.9]); right for short-range correlation;
    - batch means: the residuals averaged over blocks of B = ceil(1.5 N^(1/3)) neighbouring
      stations; the scatter of the block means (B r_b^2, N / B - 2 degrees of freedom)
      replaces s0^2. It captures correlation over up to B stations (in effect a Bartlett
      window), with no bias from the fit itself (a residual-based Newey-West sum is biased
      low by 25 % here: the residuals of a line fit are orthogonal to the fit's regressors).

    With `long_blocks` > 0 a third estimate uses that many blocks spanning the whole line:
    it sees deviations correlated over a large part of the line (tissue texture beside an
    instrument's edge) at the price of a noisier value. None of them drops below a
    per-station scatter of _FLOOR_PX (the limit of bilinear resampling).
    """
    M, S = s.shape
    n = inl.sum(-1)
    dof = np.maximum(n - 2, 1)
    wr = np.where(inl, w * res * res, 0.0)
    s02 = np.maximum(wr.sum(-1) / dof, _FLOOR_PX**2)
    en = np.where(inl, res * np.sqrt(w), 0.0)
    order = np.argsort(~inl, axis=1, kind="stable")  # inliers packed to the left
    en = np.take_along_axis(en, order, 1)
    num = np.sum(en[:, 1:] * en[:, :-1], -1)
    rho = np.clip(num / np.maximum(np.sum(en * en, -1), 1e-300), 0.0, 0.9)
    s_ar = s02 * (1.0 + rho) / (1.0 - rho)
    rp = np.take_along_axis(np.where(inl, res, 0.0), order, 1)
    wp = np.take_along_axis(np.where(inl, w, 0.0), order, 1)

    def batch_means(B, min_blocks):
        # block b of size B; weights are relative (~1), so a block mean of B stations has
        # variance s0^2 / B and sw * mean^2 estimates s0^2
        nb = n // B
        j = np.arange(S)
        valid = j[None, :] < (nb * B)[:, None]
        flat = (np.arange(M)[:, None] * (S + 1) + np.where(valid, j[None, :] // B[:, None], S)).ravel()
        sw = np.bincount(flat, wp.ravel(), M * (S + 1)).reshape(M, S + 1)[:, :S]
        swr = np.bincount(flat, (wp * rp).ravel(), M * (S + 1)).reshape(M, S + 1)[:, :S]
        with np.errstate(all="ignore"):
            mean_r = np.where(sw > 0, swr / sw, 0.0)
        out = np.sum(sw * mean_r**2, -1) / np.maximum(nb - 2, 1)
        return np.where(nb >= min_blocks, out, 0.0)  # too few blocks to say anything

    s_bm = batch_means(np.maximum(np.ceil(1.5 * np.cbrt(np.maximum(n, 1))), 1).astype(int), 5)
    if long_blocks:
        s_bm = np.maximum(s_bm, batch_means(np.maximum(n // long_blocks, 1), long_blocks))
    s2 = np.maximum(s_ar, s_bm)
    return s2 / Sss, s2 / Wt


def _raw_frame(camera, cx, cy, nx, ny, every=8):
    """Raw pixels (rx, ry) of working points (cx, cy) (M, S) and the raw displacement (jx, jy)
    per unit of t along the working normal (nx, ny): the local Jacobian of the lens map,
    exact to second order over the few pixels a profile spans. The Jacobian changes slowly
    along a line: it is evaluated at every `every`-th station and interpolated (its error
    only rescales the profile by ~1e-6, which moves no edge)."""
    if camera is None:
        return cx, cy, np.broadcast_to(nx, cx.shape), np.broadcast_to(ny, cx.shape)
    K = np.asarray(camera.K, float)
    Kinv2 = np.linalg.inv(K[:2, :2])
    pts = np.stack([cx, cy], -1)
    raw = camera.distort_pixels(pts)
    S = cx.shape[-1]
    cols = np.unique(np.r_[np.arange(0, S, every), S - 1])
    sub = pts[:, cols]
    J = camera.jacobian_pixels_from_normalized((sub - K[:2, 2]) @ Kinv2.T) @ Kinv2  # d raw / d ideal
    jx = J[..., 0, 0] * nx + J[..., 0, 1] * ny
    jy = J[..., 1, 0] * nx + J[..., 1, 1] * ny
    if cols.size < S:
        j = np.arange(S)
        k = np.clip(np.searchsorted(cols, j, "right") - 1, 0, max(cols.size - 2, 0))
        k1 = np.minimum(k + 1, cols.size - 1)
        f = (j - cols[k]) / np.maximum(cols[k1] - cols[k], 1)
        jx = jx[:, k] * (1 - f) + jx[:, k1] * f
        jy = jy[:, k] * (1 - f) + jy[:, k1] * f
    return raw[..., 0], raw[..., 1], jx, jy


def _refit_pass(img, P1, P2, camera, search, ext, kern, r, step_px, max_gap_px, min_gradient, rel_gradient,
                floor_px, sigma_px=1.0, long_blocks=0, slope_correction=False, grow_frac=0.0):
    """One pass of the refit over lines P1 -> P2 (M, 2): see `_refit`. Returns a dict."""
    M = P1.shape[0]
    H, W = img.shape
    nk = kern.size
    d = P2 - P1
    L = np.hypot(d[:, 0], d[:, 1])
    ok = np.isfinite(L) & (L > 1e-6)
    L = np.where(ok, L, 1.0)
    ux, uy = d[:, 0] / L, d[:, 1] / L
    nx, ny = -uy, ux
    e = np.minimum(np.maximum(ext, grow_frac * L), 0.5 * L + 2.0)
    lo, hi = -e, L + e
    cnt = np.clip(np.round((hi - lo) / step_px).astype(int) + 1, _MIN_STATIONS, _MAX_STATIONS)
    S = int(cnt.max())
    if M >= 32 and M * S > 3 * int(cnt.sum()) + 8000:
        # lines of very different lengths: padding every line to the longest would waste
        # most of the work, so lines go in groups of similar length
        group = np.digitize(cnt, [24, 96])
        parts = [(np.flatnonzero(group == g_), None) for g_ in np.unique(group)]
        args = (camera, search, ext, kern, r, step_px, max_gap_px, min_gradient, rel_gradient, floor_px, sigma_px,
                long_blocks, slope_correction, grow_frac)
        outs = [(idx, _refit_pass(img, P1[idx], P2[idx], *args)) for idx, _ in parts]
        res = {}
        for k, v in outs[0][1].items():
            res[k] = np.zeros((M,) + v.shape[1:], v.dtype)
        for idx, o in outs:
            for k, v in o.items():
                res[k][idx] = v
        return res
    j = np.arange(S)
    st_valid = j[None, :] < cnt[:, None]
    s = lo[:, None] + np.minimum(j[None, :], cnt[:, None] - 1) * ((hi - lo) / (cnt - 1))[:, None]
    nw = int(np.ceil(search / _DT)) + 1  # window half-width in samples (one beyond search)
    half = nw + r
    t = np.arange(-half, half + 1) * _DT
    # each station's samples start at a different fraction of a step (golden-ratio sequence):
    # bilinear resampling biases an edge by ~3e-3 px depending on the phase of the samples
    # against the pixel grid; along lines near 0, 45 or 90 deg that phase drifts slowly and
    # the bias would turn the line by ~1e-4 rad. Spread evenly, it averages out instead.
    shift = np.remainder(j * 0.6180339887498949, 1.0) * _DT  # (S,)
    cx = P1[:, 0, None] + s * ux[:, None]
    cy = P1[:, 1, None] + s * uy[:, None]
    rx, ry, jx, jy = _raw_frame(camera, cx, cy, nx[:, None], ny[:, None])
    reach = half * _DT
    inside = ((rx - reach * np.abs(jx) >= 0) & (rx + reach * np.abs(jx) <= W - 1)
              & (ry - reach * np.abs(jy) >= 0) & (ry + reach * np.abs(jy) <= H - 1))
    inside &= np.isfinite(rx) & np.isfinite(ry)
    ts = t[None, :] + shift[:, None]  # (S, T)
    X = (rx[..., None] + jx[..., None] * ts).astype(np.float32)
    Y = (ry[..., None] + jy[..., None] * ts).astype(np.float32)
    prof = img.sample(X, Y)  # (M, S, T)
    # derivative along +t at the window positions |t| <= nw * DT, tap by tap (a handful of
    # vectorised multiply-adds beats a strided matrix product here)
    nwin = 2 * nw + 1
    g = kern[0] * prof[..., 0:nwin]
    for q in range(1, nk):
        g += kern[q] * prof[..., q:q + nwin]
    g2 = g.reshape(-1, nwin)
    jm = np.argmax(g2[:, 1:-1], -1) + 1
    rr = np.arange(g2.shape[0])
    gm, g0, gp = (g2[rr, jm + o].reshape(M, S).astype(float) for o in (-1, 0, 1))
    jm = jm.reshape(M, S)
    with np.errstate(all="ignore"):
        # log-parabola: exact vertex for a Gaussian-shaped response
        pos = (gm > 0) & (gp > 0) & (g0 > 0)
        lm, l0, lp = (np.log(np.where(pos, x, 1.0)) for x in (gm, g0, gp))
        den = lm - 2 * l0 + lp
        off = np.where(pos & (den < 0), 0.5 * (lm - lp) / np.where(den < 0, den, -1.0), 0.0)
    tk = (jm - nw + np.clip(off, -0.5, 0.5)) * _DT + shift
    if slope_correction:
        # grey-level slopes beside the edge (shading, texture) pull the derivative's peak off
        # the edge: for a blurred step of height a between ramps of slopes bL, bR, the peak
        # lies at sigma_g^2 (bR - bL) / a, sigma_g the sd of the response (from the
        # log-parabola's curvature). Slopes from the outer 2.5 px of each side.
        q = max(int(round(2.5 / _DT)), 3)
        tt = (np.arange(q) - (q - 1) / 2.0) * _DT
        den_t = np.sum(tt * tt)
        bL = (prof[..., :q] @ tt.astype(np.float32)) / den_t
        bR = (prof[..., -q:] @ tt.astype(np.float32)) / den_t
        with np.errstate(all="ignore"):
            sg2 = np.where(pos & (den < 0), -(_DT**2) / np.where(den < 0, den, -1.0), sigma_px**2 + 1.0)
            sg2 = np.clip(sg2, 0.25 * sigma_px**2, 9.0 * sigma_px**2 + 9.0)
            a_step = g0 * np.sqrt(2.0 * np.pi * sg2)
            corr = np.where(a_step > 0, sg2 * (bR - bL) / a_step, 0.0)
        tk = tk - np.clip(corr, -0.5 * search, 0.5 * search)
    peak_ok = (g0 > 0) & (np.abs(tk) <= search)
    base = st_valid & inside & peak_ok & ok[:, None]
    med = _masked_median(g0, base)
    base &= (g0 >= min_gradient) & (g0 >= rel_gradient * med[:, None])
    w = g0 * g0
    w = np.where(base, w / np.maximum(_masked_median(w, base), 1e-300)[:, None], 0.0)
    inl = base
    for _ in range(4):
        sm, tm, b, Sss, Wt = _wls(s, tk, w, inl)
        res = tk - tm[:, None] - b[:, None] * (s - sm[:, None])
        e_n = res * np.sqrt(w)
        scale = 1.4826 * _masked_median(np.abs(e_n), inl)
        thr = np.maximum(3.0 * np.nan_to_num(scale, nan=0.0), floor_px)
        new = _best_run(s, base & (np.abs(e_n) <= thr[:, None]), w, max_gap_px)
        if np.array_equal(new, inl):
            break
        inl = new
    rows = np.arange(M)
    k1 = np.argmax(inl, 1)
    k2 = S - 1 - np.argmax(inl[:, ::-1], 1)
    s_first, s_last = s[rows, k1], s[rows, k2]
    # near its ends an edge usually meets another (a corner, a junction) whose blur pulls the
    # gradient peak off the line by a fraction of a pixel, on one side only: stations
    # within 2 sd of the blur + 1 px of the ends take no part in the fit
    margin = 2.0 * sigma_px + 1.0
    core = inl & (s >= (s_first + margin)[:, None]) & (s <= (s_last - margin)[:, None])
    use_core = core.sum(-1) >= _MIN_STATIONS
    inl = np.where(use_core[:, None], core, inl)
    sm, tm, b, Sss, Wt = _wls(s, tk, w, inl)
    res = tk - tm[:, None] - b[:, None] * (s - sm[:, None])
    count = inl.sum(-1)
    ok &= count >= _MIN_STATIONS
    # sharpen the ends to where the edge response falls to half its median: the response
    # along a blurred edge that stops is a blurred step, so its half point is the end of the
    # edge (stations alone would quantise the ends to step_px)
    gh = 0.5 * _masked_median(g0, inl)
    gv = np.where(peak_ok & inside & st_valid, np.maximum(g0, 0.0), 0.0)
    ends = []
    for k, kout, s_end in ((k1, k1 - 1, s_first), (k2, k2 + 1, s_last)):
        kin = np.clip(kout, 0, S - 1)
        exists = (kout >= 0) & (kout < cnt) & ok
        gi, go = g0[rows, k], gv[rows, kin]
        cross = exists & (go < gh) & (gi >= gh)
        frac = np.where(cross, (gi - gh) / np.where(cross, gi - go, 1.0), 0.0)
        ends.append(np.where(cross, s[rows, k] + frac * (s[rows, kin] - s[rows, k]), s_end))
    s_first, s_last = ends
    # the edge runs on beyond the stations looked at: worth growing the line
    touch = ok & ((k1 == 0) | (k2 == cnt - 1))
    dev = np.maximum(np.abs(tm + b * (s_first - sm)), np.abs(tm + b * (s_last - sm)))

    def at(sv):
        tv = tm + b * (sv - sm)
        return np.stack([P1[:, 0] + sv * ux + tv * nx, P1[:, 1] + sv * uy + tv * ny], -1)

    var_b, var_a = _fit_variances(s, res, w, inl, sm, Sss, Wt, long_blocks)
    cst = _masked_median(prof[..., -3:].mean(-1) - prof[..., :3].mean(-1), inl)
    return dict(
        ok=ok, p1=at(s_first), p2=at(s_last), centroid=at(sm),
        angle_sigma=np.sqrt(var_b) / (1.0 + b * b), centre_sigma=np.sqrt(var_a),
        contrast=np.nan_to_num(cst), residual=np.sqrt(np.sum(np.where(inl, res * res, 0.0), -1) / np.maximum(count, 1)),
        count=count, touch=touch, dev=dev,
    )


def _refit(img, lines, camera=None, *, search=2.0, extend=8.0, sigma_px=1.0, step_px=2.0, max_gap_px=30.0,
           min_gradient=2.0, rel_gradient=0.3, floor_px=0.1, max_passes=4, grow=True, long_blocks=0,
           slope_correction=False):
    """Refit oriented lines (M, 4) in working pixels to the edges of `img` (float32, raw).

    A pass samples stations every `step_px` from `extend` before the first end to `extend`
    beyond the second, profiles +-(search + kernel) across; the edge at each station is the
    peak of the Gaussian-derivative response (sd `sigma_px`) within +-search; a robust
    weighted line fit (residuals beyond 3 robust sd or `floor_px` rejected) is trimmed to the
    best run of stations with gaps <= max_gap_px. The edge points are exact wherever the
    window holds the edge, whatever the line's own angle, so one pass is enough unless the
    window was off-centre (the fit strays more than search/2 from the line sampled) or,
    with `grow`, the edge runs on past the stations: then the line is sampled again from
    its new fit, looking max(extend, L / 4) further, up to `max_passes` in all. Returns a
    `_Fit`.
    """
    st = _refit_start(img, lines, camera, search=search, extend=extend, sigma_px=sigma_px, step_px=step_px,
                      max_gap_px=max_gap_px, min_gradient=min_gradient, rel_gradient=rel_gradient,
                      floor_px=floor_px, long_blocks=long_blocks, slope_correction=slope_correction)
    _refit_more(st, None, grow=grow, max_passes=max_passes)
    return st.fit()


@dataclass
class _RefitState:
    """A refit in progress: the last pass's result per line (dict of (M, ...) arrays) and
    what a further pass needs. `_refit_more` runs further passes over some lines in place;
    `fit()` is the `_Fit` so far."""

    img: object
    args: tuple
    search: float
    res: dict

    def fit(self):
        return _Fit(**{f.name: self.res[f.name] for f in fields(_Fit)})


def _refit_start(img, lines, camera=None, *, search=2.0, extend=8.0, sigma_px=1.0, step_px=2.0, max_gap_px=30.0,
                 min_gradient=2.0, rel_gradient=0.3, floor_px=0.1, long_blocks=0, slope_correction=False):
    """The first pass of `_refit` over lines (M, 4); returns a `_RefitState`."""
    lines = np.asarray(lines, float).reshape(-1, 4)
    M = lines.shape[0]
    kern, r = _deriv_kernel(sigma_px)
    kern = kern.astype(np.float32)
    args = (camera, search, extend, kern, r, step_px, max_gap_px, min_gradient, rel_gradient, floor_px, sigma_px,
            long_blocks, slope_correction)
    if M == 0:
        res = {k: np.zeros((0, 2)) if k in ("p1", "p2", "centroid") else
               np.zeros(0, bool if k in ("ok", "touch") else int if k == "count" else float)
               for k in [f.name for f in fields(_Fit)] + ["touch", "dev"]}
    else:
        res = _refit_pass(img, lines[:, :2], lines[:, 2:], *args)
    return _RefitState(img, args, search, res)


def _refit_more(st, idx=None, *, grow=True, max_passes=4):
    """Further passes of a refit (`_refit`) over the lines `idx` (all when None) of the
    `_RefitState` st, in place: while a line's fit strayed more than search/2 from the line
    sampled or, with `grow`, its edge runs on past the stations; at most max_passes - 1."""
    res = st.res
    sel = np.arange(res["ok"].shape[0]) if idx is None else np.asarray(idx, int)
    for _ in range(max_passes - 1):
        need = sel[res["ok"][sel] & ((res["dev"][sel] > 0.5 * st.search) | (grow & res["touch"][sel]))]
        if need.size == 0:
            break
        # a line still growing looks a quarter of its length further each time
        new = _refit_pass(st.img, res["p1"][need], res["p2"][need], *st.args, grow_frac=0.25 if grow else 0.0)
        good = new["ok"]
        for k in res:
            res[k][need[good]] = new[k][good]
        # a line that grew is looked at again only if it still touches the end
        res["touch"][need[~good]] = False
        res["dev"][need[~good]] = 0.0


# ============================================================================ public pipeline


def _check_camera_image(camera, img):
    if camera is not None and (img.shape[1], img.shape[0]) != (camera.width, camera.height):
        raise InputError(f"image is {img.shape[1]}x{img.shape[0]} but the camera was calibrated at "
                         f"{camera.width}x{camera.height}")


def _undistort(camera, px):
    """camera.undistort_pixels, fast: OpenCV's iterative undistortPoints (C++) run to
    convergence, checked by redistorting with the Camera; points that do not come back to
    1e-6 px go through the Camera's own (slower, fold-aware) Newton solver."""
    px = np.asarray(px, float).reshape(-1, 2)
    if camera.model != "opencv" or px.shape[0] == 0:
        return camera.undistort_pixels(px)
    import cv2

    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-14)
    x = cv2.undistortPoints(px.reshape(-1, 1, 2), np.asarray(camera.K), np.asarray(camera.dist),
                            criteria=crit).reshape(-1, 2).astype(float)
    with np.errstate(invalid="ignore"):
        bad = ~(np.max(np.abs(camera.pixels_from_normalized(x) - px), -1) < 1e-6)
    if np.any(bad):
        x[bad] = camera.normalized_from_pixels(px[bad])
    K = np.asarray(camera.K, float)
    return np.stack([K[0, 0] * x[:, 0] + K[0, 1] * x[:, 1] + K[0, 2], K[1, 1] * x[:, 1] + K[1, 2]], -1)


def _to_working(camera, raw):
    raw = np.asarray(raw, float).reshape(-1, 4)
    if camera is None:
        return raw.copy()
    return _undistort(camera, raw.reshape(-1, 2)).reshape(-1, 4)


def _to_raw(camera, ideal):
    ideal = np.asarray(ideal, float).reshape(-1, 4)
    if camera is None:
        return ideal.copy()
    return camera.distort_pixels(ideal.reshape(-1, 2)).reshape(-1, 4)


def _segments_from_fit(fit, camera, min_length):
    ideal = np.concatenate([fit.p1, fit.p2], -1)
    L = np.hypot(*(fit.p2 - fit.p1).T)
    keep = fit.ok & (L >= min_length) & np.all(np.isfinite(ideal), -1)
    ideal = ideal[keep]
    raw = _to_raw(camera, ideal)
    good = np.all(np.isfinite(raw), -1)
    idx = np.flatnonzero(keep)[good]
    mid = 0.5 * (fit.p1[idx] + fit.p2[idx])
    sub = _Fit(**{f.name: getattr(fit, f.name)[idx] for f in fields(fit)})
    return Segments(
        segments=raw[good],
        ideal=ideal[good],
        angle_sigma=fit.angle_sigma[idx],
        offset_sigma=sub.offset_sigma_at(mid),
        length=L[idx],
        contrast=fit.contrast[idx],
        residual_px=fit.residual[idx],
        stations=fit.count[idx].astype(int),
    ), sub


def _refit_opts(search_px, sigma_px, step_px, max_gap_px, extend_px, min_gradient):
    if not (search_px > 0 and sigma_px > 0 and step_px > 0):
        raise InputError("search_px, sigma_px and step_px must be positive")
    return dict(search=search_px, extend=extend_px, sigma_px=sigma_px, step_px=step_px, max_gap_px=max_gap_px,
                min_gradient=min_gradient)


def refine_segments(image, segments, camera=None, *, search_px=2.0, sigma_px=1.0, step_px=2.0,
                    max_gap_px=30.0, extend_px=8.0, min_gradient=2.0, min_length=0.0):
    """Refit given segments (raw pixels) to the image's edges with subpixel precision.

    Parameters
    ----------
    image : (H, W) or (H, W, 3) array
        The image the segments were found in.
    segments : (M, 4) [px]
        Raw pixel segments, each within ~`search_px` of an edge; any orientation.
    camera : Camera, optional
        Fit straight lines in undistorted pixels (the image of a straight edge is curved).
    search_px : float
        Half-width [px] of the search for the edge across the line (first pass; the second,
        centred pass uses min(search_px, 1.25)).
    sigma_px : float
        sd [px] of the Gaussian-derivative kernel across the edge (~ the edge blur).
    step_px : float
        Spacing of the stations along the line [px]; ~2 px keeps them nearly independent
        (each station's bilinear samples reach 1 px to either side).
    max_gap_px : float
        Longest run of stations without edge support [px] inside one segment.
    extend_px : float
        The first pass looks this far beyond each end for the edge to continue.
    min_gradient : float
        Weakest edge accepted at a station [grey levels / px].
    min_length : float
        Shorter refitted segments are dropped [px].

    Returns
    -------
    Segments
        Oriented (bright on the n side), one row per segment that could be refitted, in the
        input order.

    Example
    -------
    >>> img = np.zeros((60, 80), np.float32); img[:, 40:] = 200     # vertical edge at u = 39.5
    >>> r = refine_segments(img, [[41.0, 10.0, 41.0, 50.0]])
    >>> np.round(r.segments[0, [0, 2]], 3).tolist(), bool(r.stations[0] > 10)
    ([39.5, 39.5], True)
    """
    img = _Gray(image)
    _check_camera_image(camera, img)
    seg, _ = orient_by_polarity(img, segments)
    work = _to_working(camera, seg)
    fit = _refit(img, work, camera, **_refit_opts(search_px, sigma_px, step_px, max_gap_px, extend_px, min_gradient))
    return _segments_from_fit(fit, camera, min_length)[0]


def _detect_working(img, detector, camera, detector_params, min_fragment=4.0, scale=1.0, dark_grow=0):
    """Raw detector fragments, oriented by polarity, in working (undistorted) pixels.

    With `scale` < 1 the detector runs on the image reduced by that factor (area
    averaging) and its fragments are mapped back to full-resolution pixels: proposals for
    a refit on the full image, which alone sets the accuracy. With `dark_grow` = k > 0 the
    image is first eroded by a (2k+1)^2 square, which widens dark features by k px on each
    side, and the fragments are moved back by k px towards their dark side."""
    if scale < 1.0:
        import cv2

        H, W = img.shape
        src = img.u8
        if dark_grow > 0:
            src = cv2.erode(src, np.ones((2 * dark_grow + 1, 2 * dark_grow + 1), np.uint8))
        small = cv2.resize(src, (max(int(round(W * scale)), 8), max(int(round(H * scale)), 8)),
                           interpolation=cv2.INTER_AREA)
        sx, sy = W / small.shape[1], H / small.shape[0]
        # pixel centres: x_full + 0.5 = (x_small + 0.5) * s
        raw = (detect_raw(small, detector, detector_params) + 0.5) * np.array([sx, sy, sx, sy]) - 0.5
    else:
        raw = detect_raw(img.u8, detector, detector_params)
        dark_grow = 0
    L = np.hypot(raw[:, 2] - raw[:, 0], raw[:, 3] - raw[:, 1])
    raw = raw[L >= min_fragment]
    raw, _ = orient_by_polarity(img, raw, 1.0 / min(scale, 1.0))
    if dark_grow > 0 and raw.shape[0]:
        d = raw[:, 2:] - raw[:, :2]
        n = np.stack([-d[:, 1], d[:, 0]], -1) / np.maximum(np.hypot(d[:, 0], d[:, 1]), 1e-12)[:, None]
        raw = raw - dark_grow * np.concatenate([n, n], -1)  # n points to the bright side
    work = _to_working(camera, raw)
    good = np.all(np.isfinite(work), -1)
    return raw[good], work[good]


def _dedupe(img, camera, fit, opts, angle_tol_deg, dist_tol_px, max_gap_px):
    """Merge refitted lines that turned out to be one edge, and refit the merged ones."""
    lines = np.concatenate([fit.p1, fit.p2], -1)[fit.ok]
    if lines.shape[0] < 2:
        return fit
    merged, lab = merge_collinear(lines, angle_tol_deg, dist_tol_px, max_gap_px)
    counts = np.bincount(lab[lab >= 0], minlength=merged.shape[0])
    if np.all(counts <= 1):
        return fit
    ok_idx = np.flatnonzero(fit.ok)
    single = ok_idx[counts[lab] == 1]
    multi = merged[counts > 1]
    fit2 = _refit(img, multi, camera, **opts)
    cat = {}
    for f in fields(fit):
        a, b = getattr(fit, f.name)[single], getattr(fit2, f.name)
        cat[f.name] = np.concatenate([a, b], 0)
    return _Fit(**cat)


def detect_segments(image, detector="lsd", *, camera=None, min_length=20.0, merge=True, refine=True,
                    angle_tol_deg=2.0, dist_tol_px=1.5, max_gap_px=30.0, search_px=2.0, sigma_px=1.0,
                    step_px=2.0, min_gradient=2.0, detector_params=None):
    """Line segments of an image: OpenCV detector, merging, subpixel refit with uncertainty.

    Parameters
    ----------
    image : (H, W) or (H, W, 3) array
        Grey or BGR, 8/16 bit or float.
    detector : {"lsd", "fld", "edlines"}
        The OpenCV detector that proposes fragments (`detect_raw`).
    camera : Camera, optional
        Lens model: lines are merged and fitted straight in undistorted pixels and returned
        in raw pixels (their ends mapped back). Its image size must match the image's.
    min_length : float
        Shortest segment returned [px].
    merge : bool
        Merge collinear fragments first (`merge_collinear` with `angle_tol_deg`,
        `dist_tol_px`, `max_gap_px`); after the refit, lines that turn out to lie on one
        edge are merged again.
    refine : bool
        Refit to the edge pixels (default). False returns the (merged) detector output with
        the end-point model of vertex.py (0.5 px per end point) for the uncertainty; it is
        there for comparisons.
    search_px, sigma_px, step_px, min_gradient
        Refit settings, see `refine_segments`.
    detector_params : dict, optional
        Passed to the OpenCV detector (`detect_raw`).

    Returns
    -------
    Segments
        Oriented segments (bright side along n = (-d_y, d_x)) with angle and offset sd.

    Example
    -------
    >>> import cv2
    >>> img = np.zeros((200, 300), np.uint8); img[60:140, 50:250] = 180   # a bright box
    >>> segs = detect_segments(cv2.GaussianBlur(img, (0, 0), 1.0), "lsd", min_length=50)
    >>> len(segs), np.round(np.sort(segs.length)).tolist()
    (4, [80.0, 80.0, 200.0, 200.0])
    """
    img = _Gray(image)
    _check_camera_image(camera, img)
    _, work = _detect_working(img, detector, camera, detector_params)
    opts = _refit_opts(search_px, sigma_px, step_px, max_gap_px, 8.0, min_gradient)
    lines = merge_collinear(work, angle_tol_deg, dist_tol_px, max_gap_px)[0] if merge else work
    L = np.hypot(lines[:, 2] - lines[:, 0], lines[:, 3] - lines[:, 1])
    # the refit can grow a line by 8 px or more at each end: keep the ones that might make it
    lines = lines[L >= max(0.5 * min_length, min_length - 16.0, 4.0)]
    if not refine:
        L = np.hypot(lines[:, 2] - lines[:, 0], lines[:, 3] - lines[:, 1])
        lines = lines[L >= min_length]
        L = L[L >= min_length]
        raw = _to_raw(camera, lines)
        z = np.zeros(len(lines))
        return Segments(segments=raw, ideal=lines, angle_sigma=np.sqrt(2.0) * 0.5 / L,
                        offset_sigma=np.full(len(lines), 0.5 / np.sqrt(2.0)), length=L, contrast=z,
                        residual_px=z, stations=np.zeros(len(lines), int))
    fit = _refit(img, lines, camera, **opts)
    if merge:
        fit = _dedupe(img, camera, fit, opts, min(angle_tol_deg, 1.0), min(dist_tol_px, 1.0), max_gap_px)
    return _segments_from_fit(fit, camera, min_length)[0]


# ============================================================================ pairs of edges


@dataclass(frozen=True, eq=False)
class _Pairs:
    """Geometry of candidate edge pairs (a, b), K pairs, working pixels.

    b is taken reversed (its direction then runs along a's). Bisector: unit normal `N`
    (K, 2) and offset `C` (K,) with N . x + C = 0, direction `D` along a. `lo`, `hi`: extent of
    the overlap of the two edges along D from the foot point `O` (K, 2); `span_lo`, `span_hi`
    the union. `width` across the bisector at the overlap centre; `conv` the angle between
    the edges [rad]; `side_a`, `side_b` the signed distance of the other edge's centre from
    each edge (negative: on its dark side).
    """

    a: np.ndarray
    b: np.ndarray
    N: np.ndarray
    C: np.ndarray
    D: np.ndarray
    O: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    span_lo: np.ndarray
    span_hi: np.ndarray
    a_lo: np.ndarray
    a_hi: np.ndarray
    b_lo: np.ndarray
    b_hi: np.ndarray
    width: np.ndarray
    conv: np.ndarray
    side_a: np.ndarray
    side_b: np.ndarray

    def take(self, idx):
        """The pairs `idx` selects."""
        kw = {f.name: getattr(self, f.name)[idx] for f in fields(self)}
        out = _Pairs(**kw)
        object.__setattr__(out, "_lines", tuple(v[idx] for v in self._lines))
        return out

    def point(self, along):
        return self.O + along[..., None] * self.D if np.ndim(along) == 1 else \
            self.O[:, None, :] + along[..., None] * self.D[:, None, :]

    def width_at(self, along):
        """Distance between the two edge lines across the bisector at `along` (K,) [px]."""
        return self._width(self.point(along))

    def _width(self, m):
        na, ca, nb, cb = self._lines
        N = self.N
        lam_a = -(np.sum(na * m, -1) + ca) / np.sum(na * N, -1)
        lam_b = -(np.sum(nb * m, -1) + cb) / np.sum(nb * N, -1)
        return np.abs(lam_a - lam_b)


def _pair_geometry(lines, a, b):
    """`_Pairs` for the oriented lines (M, 4) and pair indices a, b (K,)."""
    P = np.asarray(lines, float)
    pa1, pa2 = P[a, :2], P[a, 2:]
    pb1, pb2 = P[b, 2:], P[b, :2]  # b reversed
    ua = pa2 - pa1
    ua /= np.linalg.norm(ua, axis=-1, keepdims=True)
    ub = pb2 - pb1
    ub /= np.linalg.norm(ub, axis=-1, keepdims=True)
    na = np.stack([-ua[:, 1], ua[:, 0]], -1)
    nb = np.stack([-ub[:, 1], ub[:, 0]], -1)  # = -(b's own normal)
    ca = -np.sum(na * pa1, -1)
    cb = -np.sum(nb * pb1, -1)
    Nn = na + nb
    norm = np.linalg.norm(Nn, axis=-1)
    N = Nn / norm[:, None]
    C = (ca + cb) / norm
    D = np.stack([N[:, 1], -N[:, 0]], -1)
    O = -C[:, None] * N
    al = [np.sum((q - O) * D, -1) for q in (pa1, pa2, pb1, pb2)]
    a_lo, a_hi = np.minimum(al[0], al[1]), np.maximum(al[0], al[1])
    b_lo, b_hi = np.minimum(al[2], al[3]), np.maximum(al[2], al[3])
    lo, hi = np.maximum(a_lo, b_lo), np.minimum(a_hi, b_hi)
    conv = np.abs(np.arctan2(ua[:, 0] * ub[:, 1] - ua[:, 1] * ub[:, 0], np.sum(ua * ub, -1)))
    cen_a, cen_b = 0.5 * (pa1 + pa2), 0.5 * (pb1 + pb2)
    # b's own normal is -nb: its dark side is +nb
    side_a = np.sum(na * cen_b, -1) + ca
    side_b = -(np.sum(nb * cen_a, -1) + cb)
    pr = _Pairs(a=np.asarray(a), b=np.asarray(b), N=N, C=C, D=D, O=O, lo=lo, hi=hi,
                span_lo=np.minimum(a_lo, b_lo), span_hi=np.maximum(a_hi, b_hi), a_lo=a_lo, a_hi=a_hi,
                b_lo=b_lo, b_hi=b_hi, width=np.zeros(len(a)), conv=conv, side_a=side_a, side_b=side_b)
    object.__setattr__(pr, "_lines", (na, ca, nb, cb))
    object.__setattr__(pr, "width", pr._width(pr.point(0.5 * (lo + hi))))
    return pr


def _antiparallel_candidates(lines, max_conv, max_width, min_aspect, min_overlap=0.0):
    """Index pairs (a, b), a < b, of oriented lines that may be the two edges of one bar.

    Necessary conditions only, each with slack, on (M, 4) lines running with their bright
    side on the left (`orient_by_polarity`), for bars at most `max_width` wide whose
    edges overlap by at least `min_aspect` times the width and by `min_overlap`:
    directions opposite within `max_conv` [rad]; each line's centre on the other's dark
    side (the test `_pair_geometry` calls side_a, side_b < 0) and within the widest bar
    the shorter line allows (+ half the other's length times tan(max_conv) + 1 px) of the
    other line; and the two overlap along a's direction by more than `min_overlap` - 2 px
    - width * sin(max_conv).

    The aspect bound makes this near-linear on busy frames: a bar is at most a quarter as
    wide as its shorter edge is long, so the centres of a pair lie within ~1.4 lengths of
    the longer line's centre, and each line queries a KD-tree of centres with that radius
    (short texture fragments meet only their close neighbours).
    """
    from scipy.spatial import cKDTree

    P = np.asarray(lines, float)
    M = P.shape[0]
    if M < 2:
        return np.zeros(0, int), np.zeros(0, int)
    p1, p2 = P[:, :2], P[:, 2:]
    d = p2 - p1
    L = np.hypot(d[:, 0], d[:, 1])
    u = d / np.maximum(L, 1e-12)[:, None]
    n = np.stack([-u[:, 1], u[:, 0]], -1)  # bright side
    c = 0.5 * (p1 + p2)
    off = -np.sum(n * p1, -1)
    tan_c = np.tan(min(max_conv, 1.0))
    wcap = np.minimum(max_width, (L + 2.0) / min_aspect)  # the widest bar each line allows
    # every pair is found from its longer line (ties: the larger index)
    R = L + wcap + 0.5 * L * tan_c + 3.0
    nb = cKDTree(c).query_ball_point(c, R, return_sorted=False)
    cnt = np.fromiter(map(len, nb), int, M)
    if cnt.sum() == 0:
        return np.zeros(0, int), np.zeros(0, int)
    a = np.repeat(np.arange(M), cnt)
    b = np.concatenate([np.asarray(x, int) for x in nb])
    keep = (L[b] < L[a]) | ((L[b] == L[a]) & (b > a))
    a, b = a[keep], b[keep]
    ok = np.sum(u[a] * u[b], -1) <= -np.cos(max_conv)
    a, b = a[ok], b[ok]
    # each centre on the other's dark side, within the widest bar (+ the tilt's reach)
    sa = np.sum(n[a] * c[b], -1) + off[a]
    sb = np.sum(n[b] * c[a], -1) + off[b]
    w = np.minimum(wcap[a], wcap[b])
    ok = (sa < 0) & (sb < 0)
    ok &= (sa >= -(w + 0.5 * L[b] * tan_c + 1.0)) & (sb >= -(w + 0.5 * L[a] * tan_c + 1.0))
    a, b, sa, sb = a[ok], b[ok], sa[ok], sb[ok]
    # overlap along a: b's end points projected on a's direction against [0, L_a] (the
    # bisector's direction differs by up to max_conv / 2: slack in proportion to the width)
    ua, pa = u[a], p1[a]
    t1 = np.sum((p1[b] - pa) * ua, -1)
    t2 = np.sum((p2[b] - pa) * ua, -1)
    ov = np.minimum(L[a], np.maximum(t1, t2)) - np.maximum(0.0, np.minimum(t1, t2))
    ok = ov > min_overlap - 2.0 - np.maximum(-sa, -sb) * np.sin(min(max_conv, 1.0))
    a, b = a[ok], b[ok]
    swap = a > b
    a[swap], b[swap] = b[swap], a[swap]
    return a, b


def _complete_partners(img, camera, lines, idx, max_width, min_aspect, max_conv, min_length, stations=5):
    """Second edges for lines `idx` of (M, 4) oriented working lines that have none.

    A detector on a reduced image often reports one edge of a thin bar only (its two edges
    blur into one outline), or a piece of it. Across each line at least `min_length` long,
    into its dark side, the grey-level profile at `stations` places along it is searched for
    the bar's far edge: the first place where the profile, having fallen below half-way
    between the bright side's level and the darkest value, climbs back above it, within the
    widest bar the line allows (max_width, and 1/min_aspect of its length). Where at least
    4 stations agree on a straight edge within max_conv of antiparallel and 1 px, that edge
    (reversed: its bright side outwards, spanning the line's extent) is a proposal like the
    detector's own. Accuracy comes from the refit later; this only has to land within its
    search window, so each profile is mapped to raw pixels by its two ends (the lens map
    is smooth over a bar's width).

    Returns (new lines (K, 4), origin index into `lines` of each (K,)).
    """
    idx = np.asarray(idx, int)
    P = np.asarray(lines, float)[idx]
    p1, p2 = P[:, :2], P[:, 2:]
    d = p2 - p1
    L = np.hypot(d[:, 0], d[:, 1])
    long_enough = L >= min_length
    idx, p1, p2, d, L = idx[long_enough], p1[long_enough], p2[long_enough], d[long_enough], L[long_enough]
    K = idx.size
    if K == 0:
        return np.zeros((0, 4)), np.zeros(0, int)
    u = d / L[:, None]
    n = np.stack([-u[:, 1], u[:, 0]], -1)  # bright side
    reach = np.minimum(max_width, (L + 2.0) / min_aspect) + 2.0
    T = 32
    step = np.maximum(0.5, reach / T)
    f = (np.arange(stations) + 0.5) / stations
    base = p1[:, None, :] + (f[None, :, None] * d[:, None, :])  # (K, S, 2)
    t0, t1 = -3.0 * step, T * step  # 3 samples on the bright side, T into the dark side
    ends = np.stack([base - t0[:, None, None] * n[:, None, :], base - t1[:, None, None] * n[:, None, :]])
    r0, r1 = _to_raw_pts(camera, ends)  # (K, S, 2) each
    g = (np.arange(-3, T + 1) + 3.0) / (T + 3.0)  # (T + 4,) from t0 to t1
    pts = r0[:, :, None, :] + g[None, None, :, None] * (r1 - r0)[:, :, None, :]
    prof = img.sample(pts[..., 0], pts[..., 1]).astype(float)  # (K, S, T + 4)
    bright = prof[..., :2].mean(-1)
    inner = prof[..., 4:]  # t = step, 2 step, ... into the dark side
    dark = inner.min(-1)
    half = 0.5 * (bright + dark)
    below = inner < half[..., None]
    # the bar's interior starts at the line (within 2 px) and the far edge is the first
    # climb back above half-way after it
    first_below = np.argmax(below, -1)
    above_after = ~below & (np.cumsum(below, -1) > 0)
    k = np.clip(np.argmax(above_after, -1), 1, T - 1)
    found = above_after.any(-1) & ((first_below + 1) * step[:, None] <= 2.0 + step[:, None])
    found &= (bright - dark) >= 8.0
    q0 = np.take_along_axis(inner, (k - 1)[..., None], -1)[..., 0]
    q1 = np.take_along_axis(inner, k[..., None], -1)[..., 0]
    with np.errstate(all="ignore"):
        fr = np.clip((half - q0) / (q1 - q0), 0.0, 1.0)
    tk = (k + fr) * step[:, None]
    ok = found.sum(-1) >= stations - 1
    if not np.any(ok):
        return np.zeros((0, 4)), np.zeros(0, int)
    # a straight far edge: least squares of the crossing distance against the position along
    s = f[None, :] * L[:, None]
    w = found.astype(float)
    W_ = np.maximum(w.sum(-1), 1.0)
    sm = (w * s).sum(-1) / W_
    tm = (w * tk).sum(-1) / W_
    ds = s - sm[:, None]
    slope = (w * ds * (tk - tm[:, None])).sum(-1) / np.maximum((w * ds * ds).sum(-1), 1e-12)
    res = np.where(found, tk - tm[:, None] - slope[:, None] * ds, 0.0)
    ok &= np.sqrt((res * res).sum(-1) / W_) <= 1.0
    ok &= (np.abs(np.arctan(slope)) <= max_conv) & (tm >= 1.0)
    o = np.flatnonzero(ok)
    if o.size == 0:
        return np.zeros((0, 4)), np.zeros(0, int)
    # far edge across the line's whole extent, reversed
    e1 = tm[o] - slope[o] * sm[o]
    e2 = tm[o] + slope[o] * (L[o] - sm[o])
    q1 = p1[o] - e1[:, None] * n[o]
    q2 = p2[o] - e2[:, None] * n[o]
    return np.concatenate([q2, q1], -1), idx[o]


def _duplicates(seg, valid, score, tol_px=1.5):
    """(K,) True for segments (K, 4) that repeat a valid one: both ends within `tol_px` of
    its line and inside its extent (either way round), and it longer or, when the two
    cover each other, better by `score`. Two copies of one edge that the merge left apart
    (a detector's fragment and a completed edge a pixel off) refit to the same edge, and
    their pairs to the same bar or a piece of it."""
    K = seg.shape[0]
    dup = np.zeros(K, bool)
    idx = np.flatnonzero(valid)
    if idx.size < 2:
        return dup
    S = seg[idx]
    d = S[:, 2:] - S[:, :2]
    L = np.hypot(d[:, 0], d[:, 1])
    u = d / np.maximum(L, 1e-12)[:, None]
    n = np.stack([-u[:, 1], u[:, 0]], -1)
    e1 = S[None, :, :2] - S[:, None, :2]  # [i, j]: j's ends from i's first end
    e2 = S[None, :, 2:] - S[:, None, :2]
    perp = np.maximum(np.abs(np.sum(e1 * n[:, None], -1)), np.abs(np.sum(e2 * n[:, None], -1)))
    a1, a2 = np.sum(e1 * u[:, None], -1), np.sum(e2 * u[:, None], -1)
    inside = (np.minimum(a1, a2) >= -tol_px) & (np.maximum(a1, a2) <= L[:, None] + tol_px)
    within = (perp <= tol_px) & inside  # [i, j]: j lies on i
    np.fill_diagonal(within, False)
    order = np.argsort(-score[idx], kind="stable")
    rank = np.empty(idx.size, int)
    rank[order] = np.arange(idx.size)
    better = rank[:, None] < rank[None, :]  # [i, j]: i ranks above j
    dup[idx] = np.any(within & (~within.T | better), 0)
    return dup


def _clear_of_neighbours(img, camera, E, sub, a, b, opts, reach, step=2.0):
    """Refit the edges of the chosen bars (pairs a, b of the (M, 4) edges E, `_Fit` sub) on
    the part of each that lies `reach` px or more from every other chosen edge but its
    partner; returns (E, sub) with those edges replaced.

    A fan's spokes crowd near the vertex: there a neighbouring bar's edge falls inside an
    edge's profile window (`reach`: search + 3 sd of the kernel), pulls the derivative's peak
    towards it, and turns the edge by up to ~0.05 deg, the same way on every spoke, which
    reads as tilt (measured: +1 sd on a 13-spoke fan 10 deg apart, +0.2 sd after). Only
    pairs of edges whose segments come within `reach` are looked at. The refit then uses the
    clear run of stations only, if it is at least 40% of the edge and 15 px long and leaves
    out at least 2 reach (less is what the refit drops by an edge's ends anyway); the edge's
    ends stay where they were, moved onto the new line, so the bar keeps its extent.
    """
    K = a.size
    if K < 2:
        return E, sub
    idx = np.concatenate([a, b])
    n2 = idx.size
    partner = np.r_[np.arange(K, n2), np.arange(K)]
    P = E[idx]
    p1 = P[:, :2]
    d = P[:, 2:] - p1
    L = np.hypot(d[:, 0], d[:, 1])
    u = d / np.maximum(L, 1e-12)[:, None]
    c = p1 + 0.5 * d
    # pairs of edges that can come within reach: centres closer than half their lengths + reach
    cd = np.hypot(*(c[:, None, :] - c[None, :, :]).transpose(2, 0, 1))
    close = cd <= 0.5 * (L[:, None] + L[None, :]) + reach
    np.fill_diagonal(close, False)
    close[np.arange(n2), partner] = False
    pi, pj = np.nonzero(close)
    # the pairs that do come within reach: segment-to-segment distance (0 when they cross)
    p2 = P[:, 2:]

    def to_seg(x, j):  # distance of points x (K, 2) from segments j
        t = np.clip(np.sum((x - p1[j]) * u[j], -1), 0.0, L[j])
        return np.hypot(*(x - p1[j] - t[:, None] * u[j]).T)

    def side(o, v, x):
        return np.sign(v[:, 0] * (x[:, 1] - o[:, 1]) - v[:, 1] * (x[:, 0] - o[:, 0]))

    cross = ((side(p1[pi], d[pi], p1[pj]) * side(p1[pi], d[pi], p2[pj]) < 0)
             & (side(p1[pj], d[pj], p1[pi]) * side(p1[pj], d[pj], p2[pi]) < 0))
    seg_d = np.minimum.reduce([to_seg(p1[pi], pj), to_seg(p2[pi], pj), to_seg(p1[pj], pi), to_seg(p2[pj], pi)])
    within = cross | (seg_d < reach)
    pi, pj = pi[within], pj[within]
    if pi.size == 0:
        return E, sub
    S = int(np.ceil(L[np.unique(pi)].max() / step)) + 1
    s = np.minimum(np.arange(S)[None, :] * step, L[:, None])  # (n2, S) stations along each edge
    valid = np.arange(S)[None, :] * step <= L[:, None] + 1e-9
    pts = p1[:, None, :] + s[..., None] * u[:, None, :]
    q = pts[pi] - p1[pj][:, None, :]  # (pairs, S, 2)
    t = np.clip(np.sum(q * u[pj][:, None, :], -1), 0.0, L[pj][:, None])
    dist = np.hypot(*(q - t[..., None] * u[pj][:, None, :]).transpose(2, 0, 1))
    near = np.zeros((n2, S), bool)
    np.logical_or.at(near, pi, dist < reach)
    near &= valid
    hit = np.flatnonzero(near.any(1))
    if hit.size == 0:
        return E, sub
    clear = _best_run(s[hit], valid[hit] & ~near[hit], np.ones((hit.size, S)), 1.5 * step)
    has = clear.any(1)
    k1 = np.argmax(clear, 1)
    k2 = S - 1 - np.argmax(clear[:, ::-1], 1)
    r = np.arange(hit.size)
    s_lo, s_hi = s[hit][r, k1], s[hit][r, k2]
    # an edge that only meets another near its end (squares touching at a corner, a row of
    # them) lost nothing the refit used (it drops the stations by its ends anyway); a spoke
    # converging on its neighbour at a small angle loses reach / sin(angle), tens of px
    worth = has & ((s_hi - s_lo) >= np.maximum(0.4 * L[hit], 15.0)) & (L[hit] - (s_hi - s_lo) >= 2.0 * reach)
    hit, s_lo, s_hi = hit[worth], s_lo[worth], s_hi[worth]
    if hit.size == 0:
        return E, sub
    trimmed = np.concatenate([p1[hit] + s_lo[:, None] * u[hit], p1[hit] + s_hi[:, None] * u[hit]], -1)
    new = _refit_start(img, trimmed, camera, **dict(opts, extend=0.0)).fit()
    good = new.ok
    hit, rows = hit[good], idx[hit[good]]
    if hit.size == 0:
        return E, sub
    # the new line through the new centroid; the old ends moved across onto it
    nu = new.p2[good] - new.p1[good]
    nu /= np.maximum(np.linalg.norm(nu, axis=-1, keepdims=True), 1e-12)
    cen = new.centroid[good]

    def onto(p):
        return cen + np.sum((p - cen) * nu, -1)[:, None] * nu

    E = E.copy()
    E[rows] = np.concatenate([onto(E[rows, :2]), onto(E[rows, 2:])], -1)
    fields_new = {f.name: getattr(sub, f.name).copy() for f in fields(sub)}
    for name in ("angle_sigma", "centre_sigma", "centroid", "residual", "count", "contrast"):
        fields_new[name][rows] = getattr(new, name)[good]
    fields_new["p1"][rows], fields_new["p2"][rows] = E[rows, :2], E[rows, 2:]
    return E, _Fit(**fields_new)


def _greedy(a, b, cost, M):
    """Pairs in order of increasing cost, each line used at most once. Returns indices."""
    used = np.zeros(M, bool)
    chosen = []
    for k in np.argsort(cost, kind="stable"):
        if not used[a[k]] and not used[b[k]]:
            used[a[k]] = used[b[k]] = True
            chosen.append(k)
    return np.asarray(chosen, int)


def _to_raw_pts(camera, pts):
    return pts if camera is None else camera.distort_pixels(pts)


def _bar_darkness(img, camera, pr, contrast=None):
    """How much of the strip between two edges is dark, at 15 places along its overlap.

    Returns (K,) the fraction of places where the midline is darker than the surroundings
    (3 px beyond each edge) by half the edges' contrast (by default the median of that
    difference itself): ~1 for a bar; a row of squares whose edges line up, or two bars'
    outer edges, leave bright gaps on the midline.
    """
    f = np.linspace(0.05, 0.95, 15)
    al = pr.lo[:, None] + f[None, :] * (pr.hi - pr.lo)[:, None]
    m = pr.point(al)  # (K, 15, 2)
    off = (0.5 * pr.width + 3.0)[:, None, None] * pr.N[:, None, :]
    pts = _to_raw_pts(camera, np.stack([m, m + off, m - off]))  # (3, K, 15, 2)
    v = img.sample(pts[..., 0], pts[..., 1])
    diff = 0.5 * (v[1] + v[2]) - v[0]
    if contrast is None:
        contrast = np.median(diff, -1)
    return np.mean(diff > 0.5 * np.maximum(contrast, 1e-9)[:, None], -1)


def _refine_caps(img, camera, p1, p2, width, contrast):
    """Move the midline's ends (K, 2) to the bar's end caps: along the midline the grey level
    steps from the bar's to the background's; the cap is where it crosses half-way (the
    blurred step is symmetric about the true end). Ends without a clear step stay."""
    K = p1.shape[0]
    if K == 0:
        return p1, p2
    d = p2 - p1
    L = np.linalg.norm(d, axis=-1)
    u = d / L[:, None]
    nrm = np.stack([-u[:, 1], u[:, 0]], -1)
    A = np.minimum(np.maximum(2.0 * width, 6.0), 0.4 * L)  # reach of the profile [px]
    tau = np.linspace(-1.0, 1.0, 41)  # in units of A, outward positive
    lat = np.array([-0.25, 0.0, 0.25])
    ends = np.stack([p1, p2])  # (2, K, 2)
    dirn = np.stack([-u, u])  # outwards
    pts = (ends[:, :, None, None, :]
           + (A[:, None, None] * tau[None, None, :])[None, ..., None] * dirn[:, :, None, None, :]
           + (width[:, None, None] * lat[None, :, None])[None, ..., None] * nrm[None, :, None, None, :])
    pts = _to_raw_pts(camera, pts)  # (2, K, 3, T, 2)
    prof = img.sample(pts[..., 0], pts[..., 1]).mean(2).reshape(2 * K, -1)  # (2K, T)
    inner = np.median(prof[:, :10], -1)
    outer = np.median(prof[:, -10:], -1)
    half = 0.5 * (inner + outer)
    good = (outer - inner) > 0.3 * np.tile(contrast, 2)
    above = prof >= half[:, None]
    # crossings from below to above going outwards; take the one nearest the old end
    cross = ~above[:, :-1] & above[:, 1:]
    q0, q1 = prof[:, :-1], prof[:, 1:]
    with np.errstate(all="ignore"):
        fr = (half[:, None] - q0) / (q1 - q0)
    tc = tau[:-1][None, :] + fr * (tau[1] - tau[0])
    dist = np.where(cross, np.abs(tc), np.inf)
    k = np.argmin(dist, 1)
    r = np.arange(2 * K)
    has = np.isfinite(dist[r, k]) & good
    shift = np.where(has, tc[r, k] * np.tile(A, 2), 0.0).reshape(2, K)
    new = ends + shift[..., None] * dirn
    return new[0], new[1]


def detect_bars(image, detector="lsd", *, camera=None, width_px_range=None, min_length=30.0, min_aspect=4.0,
                max_convergence_deg=3.0, min_overlap=0.5, refine_ends=True, search_px=None, sigma_px=1.0,
                step_px=2.0, max_gap_px=30.0, min_gradient=2.0, detector_params=None, proposal_scale=None):
    """Midlines of thin dark bars (the printed spokes of a pencil) with angle uncertainty.

    Each bar has two long edges of opposite polarity (dark inside). Pairs of edges running
    in opposite directions (`orient_by_polarity`), within `max_convergence_deg`, whose dark
    sides face each other, that overlap along at least `min_overlap` of the shorter, enclose
    a strip that is dark at 85 % of 15 places along it, and are at least `min_aspect` times
    longer than wide, are bars; each edge belongs to one bar at most (narrowest pair first).
    An edge whose profile windows reach another chosen bar's edge (spokes crowding near a
    fan's vertex) is refitted on its part clear of it (`_clear_of_neighbours`).
    Only edges of candidate pairs (the same tests, with slack, on the unrefined lines) are
    refitted, and only edges that still pair after the first pass of the refit get further
    passes (growing along their length), so a busy image (a ChArUco board beside the fan)
    costs little more than the detector: its squares are too short for their width, and
    rows of squares are not dark all along.

    Parameters
    ----------
    image : (H, W) or (H, W, 3) array
    detector : {"lsd", "fld", "edlines"}
    camera : Camera, optional
        Lens model; see `detect_segments`. Midlines are returned in raw pixels.
    width_px_range : (2,) [px], optional
        Accepted bar widths (undistorted pixels); default 2.5 px to 1/8 of the image's
        smaller side. Bars narrower than ~2.5 px have no separate edges for the detectors.
    min_length : float
        Shortest midline [px].
    refine_ends : bool
        Locate the end caps along the midline (half-way crossing of the grey level); else the
        ends are the mean of the two edges' ends.
    search_px : float, optional
        Edge search half-width of the refit; default half the smallest width, within
        [0.75, 2] px, so that the refit never jumps to the bar's other edge.
    max_gap_px : float
        Largest gap between fragments merged into one edge [px]. After the refit an edge must
        be continuous (gaps of at most 2.5 station steps): squares in a row, whose edges line
        up with gaps between them, make no bar.
    sigma_px, step_px, min_gradient, detector_params
        As in `detect_segments`.
    proposal_scale : float in [0.25, 1] or None
        The detector runs on the image reduced by this factor (area averaging); its lines
        are proposals that the refit then fits at full resolution, so the accuracy of what
        is found does not depend on it. On the reduced image the detector often reports one
        edge of a thin bar only (the two blur into one outline), or a piece of it: each line
        that no partner covers along most of its length is given one by a search across its
        dark side at full resolution (`_complete_partners`), and FLD (EDLines) is asked for
        no fragment shorter than 0.9 `min_length` (full-resolution pixels): a bar's edges are
        as long as the bar. Default None: 0.5 when the image's smaller side is 720 px or
        more (1080p: orientation from a frame ~2x faster, the same bars on the test scenes),
        else 1.

    Returns
    -------
    Bars
        Midlines (M, 4) in raw pixels, running like their first edge (so n points from the
        midline towards that edge; `orient.orient_segments` orients spokes from the vertex
        itself), with ``angle_sigma`` = sqrt(s1^2 + s2^2) / 2 of the edge fits,
        ``offset_sigma`` at the midline's midpoint, ``width_px`` and ``edges``. Under
        perspective the bisector sits ~w^2 / (4 D) off the true centre line (D the distance
        to the plane's horizon): no angle error, but a few offset sd; once the plane is
        known, `bar_midlines_on_plane` removes it.

    Example
    -------
    >>> img = np.full((120, 200), 220, np.uint8); img[55:61, 20:180] = 30   # a 6 px bar
    >>> bars = detect_bars(img, "lsd")
    >>> len(bars), np.round(bars.ideal[0], 2).tolist(), np.round(bars.width_px, 2).tolist()
    (1, [179.5, 57.5, 19.5, 57.5], [6.0])
    """
    img = _Gray(image)
    _check_camera_image(camera, img)
    H, W = img.shape
    wmin, wmax = (2.5, max(min(H, W) / 8.0, 10.0)) if width_px_range is None else map(float, width_px_range)
    if not (0 < wmin < wmax):
        raise InputError(f"width_px_range must be (min, max) with 0 < min < max, got {width_px_range!r}")
    if search_px is None:
        search_px = float(np.clip(0.5 * wmin, 0.75, 2.0))
    conv = np.radians(max_convergence_deg)
    if proposal_scale is None:
        proposal_scale = 0.5 if min(H, W) >= 720 else 1.0
    if not 0.25 <= proposal_scale <= 1.0:
        raise InputError(f"proposal_scale must be in [0.25, 1], got {proposal_scale!r}")
    params = dict(detector_params or {})
    if proposal_scale < 1.0:
        # fragments of a bar's edges on the reduced image are (nearly) as long as the bar
        shortest = max(10, int(0.9 * proposal_scale * min_length))
        if detector == "fld":
            params.setdefault("length_threshold", shortest)
        elif detector == "edlines":
            params.setdefault("MinLineLength", shortest)
    _, work = _detect_working(img, detector, camera, params, scale=proposal_scale, dark_grow=_DARK_GROW)
    lines = merge_collinear(work, 2.0, 1.5, max_gap_px)[0]
    L = np.hypot(lines[:, 2] - lines[:, 0], lines[:, 3] - lines[:, 1])
    keep = L >= max(0.5 * min_length, 4.0)
    lines, L = lines[keep], L[keep]

    def rough_pairs():
        # candidate pairs on the unrefined lines, with slack
        a, b = _antiparallel_candidates(lines, conv + np.radians(3.0), 1.4 * wmax + 1.0, 0.7 * min_aspect,
                                        0.3 * min_length)
        if a.size == 0:
            return a, b, np.zeros(0)
        pr = _pair_geometry(lines, a, b)
        ok = ((pr.hi - pr.lo) >= 0.3 * min_length) & (pr.width >= 0.6 * wmin - 1.0) & (pr.width <= 1.4 * wmax + 1.0)
        ok &= (pr.side_a < 0) & (pr.side_b < 0) & ((pr.hi - pr.lo) >= 0.7 * min_aspect * pr.width)
        sel = np.flatnonzero(ok)
        # a dark strip all along (checked on the rough lines already: refitting the edges of
        # every square of a ChArUco board beside the fan would cost more than the detector)
        ok[sel] = _bar_darkness(img, camera, pr.take(sel)) >= 0.7
        return a[ok], b[ok], (pr.hi - pr.lo)[ok]

    a, b, ov = rough_pairs()
    if proposal_scale < 1.0:
        # on the reduced image the detector often sees one edge of a thin bar only, or a
        # piece of it: look for the other across the dark side of every line that no
        # partner covers along most of its length
        cover = np.zeros(lines.shape[0])
        for idx in (a, b):
            np.maximum.at(cover, idx, ov / np.maximum(L[idx], 1e-9))
        lone = np.flatnonzero(cover < 0.7)
        new, org = _complete_partners(img, camera, lines, lone, 1.4 * wmax + 1.0, 0.7 * min_aspect,
                                      conv + np.radians(3.0), min_length)
        if new.shape[0]:
            # a completed edge and a piece of it the detector did see become one line
            lines = merge_collinear(np.concatenate([lines, new]), 2.0, 1.5, max_gap_px)[0]
            L = np.hypot(lines[:, 2] - lines[:, 0], lines[:, 3] - lines[:, 1])
            a, b, ov = rough_pairs()
    if a.size == 0:
        return Bars.empty()
    edges_idx, inv = np.unique(np.concatenate([a, b]), return_inverse=True)
    # a printed bar's edge is continuous: the refit keeps only an unbroken run of stations
    # (fragments are merged across gaps first), so edges of squares in a row, lined up
    # with gaps between them, do not make a bar
    opts = _refit_opts(search_px, sigma_px, step_px, 2.5 * step_px, 8.0, min_gradient)
    # (no second merge here: each edge goes into one bar at most, so a duplicate edge
    # costs nothing but itself)
    st = _refit_start(img, lines[edges_idx], camera, **opts)
    # Further passes (a window that was off-centre, an edge that runs on past the stations
    # and grows by a quarter of its length each time) cost more than the first one on a
    # busy frame, where most edges touch their ends (rows of squares): they are run only
    # for edges that still pair as a bar after the first (angles, sides, width).
    fit = st.fit()
    okf = np.flatnonzero(fit.ok)
    E = np.concatenate([fit.p1, fit.p2], -1)[okf]
    a, b = _antiparallel_candidates(E, conv, wmax + 2.0, 0.7 * min_aspect)
    if a.size:
        pr = _pair_geometry(E, a, b)
        ok = (pr.conv <= conv) & (pr.side_a < 0) & (pr.side_b < 0) & (pr.width >= wmin) & (pr.width <= wmax)
        ok &= (pr.hi - pr.lo) >= 0.7 * min_aspect * pr.width
        _refit_more(st, okf[np.unique(np.concatenate([a[ok], b[ok]]))], grow=True)
        fit = st.fit()
    okf = fit.ok
    E = np.concatenate([fit.p1, fit.p2], -1)[okf]
    sub = _Fit(**{f.name: getattr(fit, f.name)[okf] for f in fields(fit)})
    a, b = _antiparallel_candidates(E, conv, wmax + 2.0, min_aspect)
    if a.size == 0:
        return Bars.empty()
    pr = _pair_geometry(E, a, b)
    La = np.hypot(*(sub.p2 - sub.p1).T)
    ok = (pr.conv <= conv) & (pr.side_a < 0) & (pr.side_b < 0)
    ok &= (pr.width >= wmin) & (pr.width <= wmax)
    ok &= (pr.hi - pr.lo) >= np.maximum(min_overlap * np.minimum(La[a], La[b]), min_aspect * pr.width)
    pr = pr.take(np.flatnonzero(ok))
    if pr.a.size:
        dark = _bar_darkness(img, camera, pr, np.minimum(sub.contrast[pr.a], sub.contrast[pr.b]))
        pr = pr.take(np.flatnonzero(dark >= 0.85))
    if pr.a.size == 0:
        return Bars.empty()
    pr = pr.take(_greedy(pr.a, pr.b, pr.width, E.shape[0]))
    a, b = pr.a, pr.b
    # edges whose profiles reach a neighbouring bar (near a fan's vertex) are refitted on
    # their clear part; reach = the profile window, search + 3 sd of the kernel (a wider
    # margin for the other bar's blur trimmed so much that the normal's error grew)
    E, sub = _clear_of_neighbours(img, camera, E, sub, a, b, opts, search_px + 3.0 * sigma_px)
    pr = _pair_geometry(E, a, b)
    # ends: the mean of the two edges' ends, then the caps
    s1 = 0.5 * (pr.a_lo + pr.b_lo)
    s2 = 0.5 * (pr.a_hi + pr.b_hi)
    m1, m2 = pr.point(s1), pr.point(s2)
    width = pr.width_at(0.5 * (s1 + s2))
    if refine_ends:
        m1, m2 = _refine_caps(img, camera, m1, m2, width, np.minimum(sub.contrast[a], sub.contrast[b]))
    mid = 0.5 * (m1 + m2)
    ang_sig = 0.5 * np.sqrt(sub.angle_sigma[a] ** 2 + sub.angle_sigma[b] ** 2)
    off_sig = 0.5 * np.sqrt(_sel(sub, a).offset_sigma_at(mid) ** 2 + _sel(sub, b).offset_sigma_at(mid) ** 2)
    ideal = np.concatenate([m1, m2], -1)
    Lm = np.hypot(*(m2 - m1).T)
    keep = (Lm >= min_length) & np.all(np.isfinite(ideal), -1)
    raw = _to_raw(camera, ideal)
    keep &= np.all(np.isfinite(raw), -1)
    keep &= ~_duplicates(ideal, keep, (sub.count[a] + sub.count[b]).astype(float))
    edges = np.stack([_to_raw(camera, E[a]), _to_raw(camera, E[b])], 1)
    return Bars(
        segments=raw[keep],
        ideal=ideal[keep],
        angle_sigma=ang_sig[keep],
        offset_sigma=off_sig[keep],
        length=Lm[keep],
        contrast=np.minimum(sub.contrast[a], sub.contrast[b])[keep],
        residual_px=np.sqrt(0.5 * (sub.residual[a] ** 2 + sub.residual[b] ** 2))[keep],
        stations=(sub.count[a] + sub.count[b])[keep].astype(int),
        width_px=width[keep],
        edges=edges[keep],
    )


def bar_midlines_on_plane(bars, camera, normal):
    """The exact images of the bars' centre lines once the plane they are printed on is known.

    The bisector of a bar's two edges (`detect_bars`) is not quite the image of its centre
    line under perspective: along a cut across the bar, the image of the 3D midpoint is the
    harmonic conjugate of the plane's horizon with respect to the two edges, w^2 / (4 D)
    from the bisector towards the horizon (w the bar's width, D the distance to the
    horizon, both in pixels): ~0.006-0.02 px for 8 px bars at 20-45 deg tilt. That turns no
    angle, but it is several times the bisector's offset sd. With the plane's normal (e.g.
    the `normal` of orientation.json, R_cam_from_target[:, 2]) each edge's back-projected
    plane meets the target plane in a 3D line, the centre line lies midway between the two
    and its image is exact.

    Parameters
    ----------
    bars : Bars
        From `detect_bars` with the same camera.
    camera : Camera
    normal : (3,) array_like
        Unit normal of the printed plane in the camera frame (either sign).

    Returns
    -------
    Bars
        A copy whose `segments` / `ideal` lie on the exact centre lines, their ends the old
        ends moved across onto them; everything else unchanged.

    Example
    -------
    See tests/toolkit/detect/test_lines.py (test_bar_midlines_on_plane).
    """
    from dataclasses import replace

    if len(bars) == 0:
        return bars
    n = np.asarray(normal, float).reshape(3)
    n = n / np.linalg.norm(n)
    K = np.asarray(camera.K, float)
    K2, k = K[:2, :2], K[:2, 2]
    K2inv = np.linalg.inv(K2)
    E = np.stack([_to_working(camera, bars.edges[:, 0]), _to_working(camera, bars.edges[:, 1])], 1)  # (M, 2, 4)

    def plane(seg):
        # back-projected plane m . (x, y, 1) = 0 of a segment in undistorted pixels
        p1, p2 = seg[..., :2], seg[..., 2:]
        d = p2 - p1
        npx = np.stack([-d[..., 1], d[..., 0]], -1)
        c = -np.sum(npx * p1, -1)
        m = np.concatenate([npx @ K2, (np.sum(npx * k, -1) + c)[..., None]], -1)
        return m / np.linalg.norm(m, axis=-1, keepdims=True)

    m = plane(E)  # (M, 2, 3)
    d = np.cross(m, n)  # directions of the two 3D edges
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    d[:, 1] *= np.sign(np.sum(d[:, 0] * d[:, 1], -1))[:, None]
    dm = d[:, 0] + d[:, 1]
    dm /= np.linalg.norm(dm, axis=-1, keepdims=True)
    # on each edge, the point with d . X = 0 (the same cut across the bar) on n . X = 1
    A = np.stack([m, np.broadcast_to(n, m.shape), np.broadcast_to(dm[:, None, :], m.shape)], -2)  # (M, 2, 3, 3)
    X = np.linalg.solve(A, np.broadcast_to(np.array([0.0, 1.0, 0.0]), m.shape)[..., None])[..., 0]
    M3 = 0.5 * (X[:, 0] + X[:, 1])
    mm = np.cross(M3, dm)  # the centre line's plane through the camera centre
    # back to a line in undistorted pixels: mm[:2] . K2^-1 (p - k) + mm[2] = 0
    npx = mm[:, :2] @ K2inv
    c = mm[:, 2] - np.sum(npx * k, -1)
    nn = np.linalg.norm(npx, axis=-1)
    npx, c = npx / nn[:, None], c / nn
    ideal = bars.ideal.copy()
    for j in (0, 2):
        p = ideal[:, j:j + 2]
        ideal[:, j:j + 2] = p - (np.sum(npx * p, -1) + c)[:, None] * npx
    return replace(bars, ideal=ideal, segments=_to_raw(camera, ideal))


def _sel(fit, idx):
    return _Fit(**{f.name: getattr(fit, f.name)[idx] for f in fields(fit)})


# ============================================================================ pencil assembly


def default_min_length(shape, bars):
    """Shortest line [px] written by default for a frame of `shape` (H, W[, C]).

    20 px for edge segments. For bars 20 px or 1/30 of the frame's smaller side, whichever
    is longer (36 px at 1080p): relative to the frame as OpenCV's ArUco
    ``minMarkerPerimeterRate``, since a spoke that short carries ~1/100 of the weight of
    one across a sixth of the frame (angle variance ~ 1 / length^3) and, on a busy frame,
    the shorter fragments are mostly texture.
    """
    return max(20.0, min(shape[0], shape[1]) / 30.0) if bars else 20.0


def lines_record(name, image, camera=None, detector="lsd", bars=False, shaft=False, min_length=None, bar_width=None,
                 proposal_scale=None):
    """One lines.json frame (lines_io) from one decoded image.

    name: the frame's name; image: (H, W[, 3]); camera: Camera or None; detector: one of
    DETECTORS; bars: midlines of dark bars (`detect_bars`, the printed spokes) instead of
    edge segments (`detect_segments`); shaft: also ``shafts`` (`toolkit.shafts.detect_shafts`);
    min_length [px] (None: `default_min_length`); bar_width: (2,) accepted bar widths [px]
    or None; proposal_scale: see `detect_bars`. The one place where
    `lines`, `orient IMAGES` and `fulcrum IMAGES` turn a frame into lines.
    """
    if min_length is None:
        min_length = default_min_length(np.shape(image), bars)
    if bars:
        segs = detect_bars(image, detector, camera=camera, min_length=min_length, width_px_range=bar_width,
                           proposal_scale=proposal_scale)
    else:
        segs = detect_segments(image, detector, camera=camera, min_length=min_length)
    rec = {
        "image": name,
        "ok": True,
        "error": None,
        "segments": segs.segments,
        "angle_sigma_deg": np.degrees(segs.angle_sigma),
        "offset_sigma_px": segs.offset_sigma,
    }
    if bars:
        rec["width_px"] = segs.width_px
    if shaft:
        from pencilcal.toolkit.detect.shafts import detect_shafts

        rec["shafts"] = [s.to_dict() for s in detect_shafts(image, camera)]
    return rec


def assemble_pencil(segments, angle_sigma=None, camera=None, *, offset_sigma=None, min_length=8.0, **intersect_kw):
    """The vertex of a pencil of segments, spurious segments rejected.

    Undistorts the segments (lines, not images) and intersects them with
    `vertex.intersect_lines` (robust: MSAC over pairs of lines, then the weighted
    least-squares intersection of the inliers, with covariance).

    Parameters
    ----------
    segments : (M, 4) [px] or Segments
        Raw pixel segments, or a `Segments`/`Bars` result (then `angle_sigma` and
        `offset_sigma` default to its own and its undistorted segments are used).
    angle_sigma : scalar or (M,) [rad], optional
        Angle sd of each line; None: the end-point model of `intersect_lines`.
    camera : Camera, optional
        Lens model; None treats the pixels as undistorted.
    offset_sigma : scalar or (M,) [px], optional
        Perpendicular sd at each segment's centre; default 0.3 px for plain arrays.
    min_length : float
        Shorter (undistorted) segments are left out [px].
    **intersect_kw
        Passed to `vertex.intersect_lines` (inlier_confidence, max_pairs, seed, ...).

    Returns
    -------
    fit : vertex.VertexFit
        In undistorted pixels; ``camera.distort_pixels(fit.vertex)`` is the raw vertex.
    inliers : (M,) bool
        Segments that pass through the vertex (False for short or non-finite ones too).

    Raises
    ------
    EstimationError
        Fewer than two usable segments, parallel lines, no common point.

    Example
    -------
    >>> v = np.array([300.0, 200.0])
    >>> phi = np.radians([0.0, 40.0, 80.0, 120.0])
    >>> d = np.stack([np.cos(phi), np.sin(phi)], -1)
    >>> segs = np.concatenate([v + 50 * d, v + 150 * d], -1)
    >>> segs = np.vstack([segs, [[0.0, 0.0, 100.0, 10.0]]])          # one spurious segment
    >>> fit, inl = assemble_pencil(segs, np.radians(0.05))
    >>> np.round(fit.vertex, 6).tolist(), inl.tolist()
    ([300.0, 200.0], [True, True, True, True, False])
    """
    from pencilcal.toolkit.pencil.vertex import intersect_lines

    if isinstance(segments, Segments):
        ideal = segments.ideal
        if angle_sigma is None:
            angle_sigma = segments.angle_sigma
        if offset_sigma is None:
            offset_sigma = segments.offset_sigma
    else:
        raw = np.asarray(segments, float)
        if raw.ndim != 2 or raw.shape[1] != 4:
            raise InputError(f"segments: expected shape (M, 4) [x1, y1, x2, y2], got {raw.shape}")
        ideal = _to_working(camera, raw) if camera is not None else raw.copy()
    if offset_sigma is None:
        offset_sigma = 0.3
    M = ideal.shape[0]
    L = np.hypot(ideal[:, 2] - ideal[:, 0], ideal[:, 3] - ideal[:, 1])
    usable = np.all(np.isfinite(ideal), -1) & (L >= min_length)
    idx = np.flatnonzero(usable)
    if idx.size < 2:
        raise EstimationError(f"vertex: needs at least two usable segments, got {idx.size} of {M}")

    def pick(v):
        if v is None:
            return None
        a = np.asarray(v, float)
        return a if a.ndim == 0 else np.broadcast_to(a, (M,))[idx]

    fit = intersect_lines(ideal[idx], angle_sigma=pick(angle_sigma), offset_sigma=pick(offset_sigma),
                          robust=True, **intersect_kw)
    inliers = np.zeros(M, bool)
    inliers[idx] = fit.inliers
    return fit, inliers
