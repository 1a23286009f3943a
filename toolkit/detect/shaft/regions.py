"""Instrument-like regions of a colour frame and the bands between their straight
boundaries: the proposals of the shaft detector's material cue (`shaft.detector`).

1. *material map* (`material_map`, work frame, `shaft.work`): how instrument-like each pixel
   is, from the frame's own colour statistics. The colour direction is the opponent
   chromaticity ``x = (R - G) / S, y = (R + G - 2 B) / (sqrt(3) S)``, ``S = R + G + B + 3
   eps``; grey (black, white, metal) sits at (0, 0). eps = `DARK_DAMPING` x the median
   brightness: a pixel ten times darker than the scene keeps half of its colour, so black
   (whose colour is only noise) reads as grey. The dominant (tissue) colour is the mode of
   the 2-D chromaticity histogram, refined by the mean within `_MODE_RADIUS`; u is its
   direction and p = c . u each pixel's projection on it. The likeness is ``(p_med - p) /
   p_med`` (0: typical tissue, 1: grey, > 1: a colour opposite to tissue such as a
   grey-blue drape) plus the darkness ``clip(1 - Y / Y_med, 0, 1)`` on the same 0..1 scale
   (a black shaft whose sheen reflects the tissue's colour is still dark). Hue changes at
   the tissue's saturation (fat, blood) and shadows, which keep their colour direction,
   stay near 0. The map is *informative* when the frame has a colour: p_med exceeds `Z_999`
   noise sd of one pixel's projection (from the image noise and brightness). A grey frame,
   or a colour frame of a grey scene, has no material cue, and the shaft detector judges its
   bands by their edges alone (`shaft.detector`).
2. *levels* (`region_levels`): `LEVELS` recursive two-class Otsu splits of the likeness
   over the valid region. The instruments are its upper tail and may cover only a few
   percent of the view, so each split isolates a more extreme part. At each level the
   region ("all"), its darker part (an Otsu split of its luma: a black shaft against a
   grey drape is instrument-like on both sides of its edge but differs in lightness) and,
   at the last level, the darker part of that (`DARK_SPLITS`: where the drape is dim and
   shaded itself, the first split of the luma separates the drape's light and dark parts,
   the second the black shaft from the dark drape; at the levels above, whose region still
   holds tissue and drape, it would split their shading into more bands); a map that
   repeats an earlier one is marked so and not searched again.
3. *boundaries* (`boundary_lines`): every contour of a level's map (after a 3 x 3 close and
   open) is approximated by a polygon (Douglas-Peucker, `_DP_EPS_PX`); its sides at least
   half the least length long whose middle is off the valid region's boundary are refitted
   by total least squares to their contour points and oriented with the region on their left
   (n = (-u_y, u_x) points into it). Collinear sides with the region on the same side are
   grouped (`_GROUP_TOL_PX`, `_GROUP_TOL_DEG`): a boundary interrupted by a thread or a fold
   is one line.
4. *pairs* (`region_pairs`): two lines with the region between them (antiparallel, each
   facing the other), at a width in range, overlapping, whose meeting point (the axis'
   vanishing point) lies outside the overlap. Every pair of straight boundaries is one
   hypothesis, whatever component it belongs to, which also splits touching instruments.

Steps 3 and 4 of all a frame's levels run in one batch each (`boundary_lines_many`,
`region_pairs_many`: the same lines and pairs as map by map, without numpy's per-call
overheads for each of the 5-7 maps).
A frame's levels and their boundaries are computed once (`frame_regions`, by the shaft
detector) and handed to each cue that reads them: the material cue's bands and the border
cue's seeds (`shaft.border_band`) are the same lines.

Coordinates are work pixels; widths and lengths too.

Example
-------
>>> import numpy as np
>>> from pencilcal.toolkit.detect.shaft.work import Validity, WorkFrame
>>> img = np.zeros((240, 320, 3), np.uint8); img[:] = (90, 110, 200)        # pink tissue
>>> img[100:140, :] = (60, 60, 60)                                           # a grey band
>>> wf = WorkFrame(img, None, Validity(None, img.shape[:2]), target_px=320)
>>> mm = material_map(wf)
>>> mm.informative, round(float(mm.likeness[20, 160]), 2), round(float(mm.likeness[120, 160]), 1)
(True, 0.0, 1.6)
>>> lines = boundary_lines(mm.likeness > 0.7, wf.dist, 40.0)
>>> len(lines.p), [round(float(v)) for v in np.sort(np.abs(lines.n[:, 1]))]
(2, [1, 1])
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from pencilcal.toolkit.detect.edges import upper_pairs
from pencilcal.toolkit.detect.noise import estimate_noise
from pencilcal.toolkit.geometry.quantiles import median

__all__ = ["DARK_DAMPING", "Z_999", "LEVELS", "DARK_SPLITS", "MaterialMap", "material_map", "otsu_threshold",
           "region_levels", "FrameRegions", "frame_regions", "BoundaryLines", "boundary_lines", "boundary_lines_many",
           "RegionPairs", "region_pairs", "region_pairs_many", "scene_angle", "close_open"]

#: eps of the chromaticity, as a fraction of the median brightness: a pixel this much darker
#: than the scene keeps half of its colour (0.01-0.1 give the same maps on the real sets).
DARK_DAMPING = 0.1
#: The one-sided 0.999 normal quantile, the detector's significance level.
Z_999 = 3.090232306167813
#: Recursive Otsu levels of the likeness: tissue / instrument-like, then the more extreme part
#: of that, then the most extreme.
LEVELS = 3
#: The recursive Otsu splits of the luma within a level's region: its darker part, and at the
#: last level the darker part of that too (a black shaft against a dim grey-blue drape is
#: instrument-like on both sides of its edge; the drape's own shading takes the first split,
#: the shaft the second).
DARK_SPLITS = ("dark", "darker")
_SAME_MAP = 0.02  # two level maps differing in fewer pixels than this fraction are one
_MODE_RADIUS = 0.03  # the dominant colour: mean of the chromaticities this close to the mode
_HIST_BINS = 200  # chromaticity histogram bins over [-1, 1] per axis
_SAMPLES = 20000  # pixels the colour statistics are taken from
_DP_EPS_PX = 1.5  # Douglas-Peucker tolerance of the region boundaries [work px]
_OFF_BOUNDARY_PX = 3.0  # a boundary side's middle at least this far from the valid region's edge [work px]
_GROUP_TOL_PX, _GROUP_TOL_DEG = 2.0, 3.0  # collinear boundary sides: offset [work px], angle [deg]


@dataclass(frozen=True, eq=False)
class MaterialMap:
    """The instrument-likeness of a work frame (`material_map`).

    Attributes
    ----------
    likeness : (h, w) float32
        0 = typical tissue, 1 = grey or black (Gaussian-smoothed, sd 1 work px).
    tissue : (2,)
        The dominant chromaticity (x, y).
    p_med : float
        The median projection of the chromaticities on the tissue's direction.
    noise : float
        The noise sd of one pixel's projection (from the image noise and brightness).
    luma_noise : float [grey levels]
        The noise sd of the work frame's luma.
    y_med : float [grey levels]
        The median brightness of the valid region.
    informative : bool
        The frame has a colour: p_med > `Z_999` noise.
    """

    likeness: np.ndarray
    tissue: np.ndarray
    p_med: float
    noise: float
    luma_noise: float
    y_med: float
    informative: bool


def _dominant(xv, yv):
    """The mode (2,) of the chromaticities xv, yv (N,): the peak of their smoothed 2-D
    histogram, refined by the mean of those within `_MODE_RADIUS`."""
    import cv2

    nb = _HIST_BINS
    qx = np.clip(((xv + 1) * nb / 2).astype(int), 0, nb - 1)
    qy = np.clip(((yv + 1) * nb / 2).astype(int), 0, nb - 1)
    h = np.bincount(qx * nb + qy, minlength=nb * nb).reshape(nb, nb).astype(np.float32)
    h = cv2.GaussianBlur(h, (0, 0), 1.5)
    i, j = np.unravel_index(int(np.argmax(h)), h.shape)
    mu = np.array([(i + 0.5) * 2 / nb - 1, (j + 0.5) * 2 / nb - 1])
    xv, yv = np.asarray(xv, np.float64), np.asarray(yv, np.float64)
    for _ in range(3):
        near = (xv - mu[0]) ** 2 + (yv - mu[1]) ** 2 < _MODE_RADIUS**2
        if np.count_nonzero(near) < 10:
            break
        mu = np.array([xv[near].mean(), yv[near].mean()])
    return mu


def material_map(work):
    """The instrument-likeness of each work pixel (module docstring, step 1).

    work: `shaft.work.WorkFrame` (a BGR copy; a grey one gives an uninformative map of
    darkness alone). Returns a `MaterialMap`.
    """
    import cv2

    valid = work.valid & (work.dist > 1.0)
    if np.count_nonzero(valid) < 100:
        valid = np.ones(work.shape, bool)
    F = work.colours  # (h, w, C) float32, shared with the later stages
    if F.shape[-1] == 1:
        F = np.repeat(F, 3, -1)
    B, G, R = F[..., 0], F[..., 1], F[..., 2]
    iv = np.flatnonzero(valid.ravel())
    iv = iv[::max(1, iv.size // _SAMPLES)]
    bright = (B + G + R) * (1.0 / 3.0)
    y_med = max(float(median(bright.ravel()[iv])), 1.0)
    S = R + G + B + 3.0 * max(DARK_DAMPING * y_med, 1.0)
    x = (R - G) / S
    y = (R + G - 2.0 * B) / (np.sqrt(3.0) * S)
    mu = _dominant(x.ravel()[iv], y.ravel()[iv])
    nm = float(np.hypot(*mu))
    u = mu / nm if nm > 1e-6 else np.array([1.0, 0.0])
    p = x * u[0] + y * u[1]
    pv = p.ravel()[iv]
    pm = float(median(pv))
    # the frame has a colour when the dominant one stands out of the noise of a projection
    # (a grey frame, or a colour frame of a grey scene, has none)
    # an 8-bit frame's luma holds whole levels: its noise from a histogram, exactly
    luma_noise = estimate_noise(work.luma.astype(np.uint8) if work.bgr.dtype == np.uint8 else work.luma)
    noise = np.sqrt(2.0) * luma_noise / (3.0 * (1.0 + DARK_DAMPING) * y_med)
    informative = bool(work.bgr.ndim == 3 and pm > Z_999 * max(noise, 1e-6))
    # a scene that is almost grey itself: the scale stays >= 3 x the robust spread of p, so
    # the likeness does not blow up
    mad = 1.4826 * float(median(np.abs(pv - pm)))
    scale = max(pm, 3.0 * mad, 1e-3)
    dark = np.clip(1.0 - bright * (1.0 / y_med), 0.0, 1.0)
    s = cv2.GaussianBlur(((pm - p) * (1.0 / scale) + dark).astype(np.float32), (0, 0), 1.0)
    return MaterialMap(likeness=s, tissue=mu, p_med=pm, noise=noise, luma_noise=float(luma_noise), y_med=y_med,
                       informative=informative)


def otsu_threshold(v, bins=128):
    """Otsu's two-class threshold of the samples v (N,) (histogram of `bins` over their
    range). 8-bit samples are counted per level first (the same histogram, from one pass).

    >>> t = otsu_threshold(np.r_[np.zeros(50), np.ones(50)]); 0.0 < t < 1.0
    True
    >>> y = np.random.default_rng(0).integers(3, 250, 999).astype(np.uint8)
    >>> otsu_threshold(y) == otsu_threshold(y.astype(np.float32))
    True
    """
    import cv2

    v = np.asarray(v)
    if v.dtype == np.uint8:  # each level's bin from its count: the same bins as of every sample
        if 0 < v.size < 1 << 24:  # counted by OpenCV (whole counts, exact in float32): a third of bincount's cost
            cnt = cv2.calcHist([v.reshape(-1, 1)], [0], None, [256], [0, 256]).reshape(-1).astype(np.int64)
        else:
            cnt = np.bincount(v.reshape(-1), minlength=256)
        lev = np.flatnonzero(cnt)
        if lev.size == 0:
            return float(np.max(v))  # (an empty v: np.max's error, as below)
        v, weights = lev, cnt[lev]
    else:
        weights = None
    lo, hi = float(np.min(v)), float(np.max(v))
    if hi - lo < 1e-6:
        return hi
    # np.histogram's bins (the last one closed), by one bincount: several times faster
    if weights is None and bins < 256 and v.size < 1 << 24 and math.isfinite(hi - lo):
        # the bin indices (0..bins) stored as bytes as they are computed (the same
        # truncation of the same float64 products) and counted by OpenCV (whole counts,
        # exact in float32): no frame-sized float64 and integer copies
        idx = np.empty(v.shape, np.uint8)
        np.multiply(np.subtract(v, lo, dtype=np.float64), bins / (hi - lo), out=idx, casting="unsafe")
        np.minimum(idx, bins - 1, out=idx)
        h = cv2.calcHist([idx.reshape(-1, 1)], [0], None, [bins], [0, bins]).reshape(-1).astype(np.int64)
    else:
        idx = np.subtract(v, lo, dtype=np.float64)
        idx = (np.multiply(idx, bins / (hi - lo), out=idx)).astype(np.intp)
        h = np.bincount(np.minimum(idx, bins - 1, out=idx), weights, minlength=bins)
        h = h if weights is None else h.astype(np.int64)
    e = np.linspace(lo, hi, bins + 1)
    p = h / max(h.sum(), 1)
    x = 0.5 * (e[:-1] + e[1:])
    w = np.cumsum(p)
    m = np.cumsum(p * x)
    with np.errstate(all="ignore"):
        sb = (m[-1] * w - m) ** 2 / (w * (1 - w))
    sb[~np.isfinite(sb)] = -1
    return float(e[int(np.argmax(sb)) + 1])


_K3, _K5 = np.ones((3, 3), np.uint8), np.ones((5, 5), np.uint8)


def close_open(B):
    """A binary map B (h, w) uint8 closed, then opened, by 3 x 3 (OpenCV's morphologyEx, its
    borders neutral): the same pixels from three passes instead of four (the close's erosion
    and the open's, two 3 x 3 erosions, are one 5 x 5).

    >>> B = (np.random.default_rng(0).random((40, 50)) < 0.5).astype(np.uint8)
    >>> import cv2; k3 = np.ones((3, 3), np.uint8)
    >>> bool(np.array_equal(close_open(B), cv2.morphologyEx(cv2.morphologyEx(B, cv2.MORPH_CLOSE, k3), cv2.MORPH_OPEN, k3)))
    True
    """
    import cv2

    return cv2.dilate(cv2.erode(cv2.dilate(B, _K3), _K5), _K3)


def region_levels(mm, work, n_levels=LEVELS):
    """The binary maps of the levels (module docstring, step 2): a list of (level index,
    kind "all" or one of `DARK_SPLITS`, (h, w) uint8 map after a 3 x 3 close and open,
    repeat), "all" first at each level; repeat: the map differs from an earlier one in under
    `_SAME_MAP` of its pixels (its boundaries, and bands, are that one's).

    mm: the frame's `MaterialMap`; work: its `shaft.work.WorkFrame`. A frame's levels are
    read by the material cue and the border cue alike: the detector computes them once per
    frame (`frame_regions`) and hands them to both."""
    vin = work.valid & (work.dist > 1.0)
    v = np.clip(mm.likeness[vin], -0.5, 2.0)
    # an 8-bit frame's luma holds whole levels: thresholded from their counts (`otsu_threshold`)
    luma = work.luma.astype(np.uint8) if work.bgr.dtype == np.uint8 else work.luma
    out, counts = [], []
    for lev in range(n_levels):
        if v.size < 50:
            break
        t = otsu_threshold(v)
        v = v[v > t]
        B0 = (mm.likeness > t) & vin
        maps = [("all", B0)]
        M = B0
        # the second split at the last (most instrument-like) level only: above it the region
        # still holds tissue and drape, whose shading it would split into more bands (a shaft
        # read together with its shadow)
        for kind in DARK_SPLITS if lev == n_levels - 1 else DARK_SPLITS[:1]:
            yv = luma[M]
            if yv.size <= 50:
                break
            M = M & (work.luma < otsu_threshold(yv))
            maps.append((kind, M))
        for kind, B in maps:
            Bm = close_open(B.astype(np.uint8))
            nb = int(np.count_nonzero(Bm))
            n = max(nb, 1)
            # two maps whose counts differ by at least the tolerance differ in at least as
            # many pixels: compared only where they might not
            repeat = any(abs(nb - no) < _SAME_MAP * n and np.count_nonzero(Bm != o[2]) < _SAME_MAP * n
                         for o, no in zip(out, counts))
            out.append((lev, kind, Bm, repeat))
            counts.append(nb)
    return out


def _dot2(a, b):
    """np.sum(a * b, -1) of two (..., 2) arrays: the same values (a sum of two terms is one
    addition in any order), without a reduction over an axis of two (ten times the cost
    for a few thousand rows).

    >>> a, b = np.random.default_rng(0).normal(size=(2, 50, 2))
    >>> bool(np.array_equal(_dot2(a, b), np.sum(a * b, -1)))
    True
    """
    return a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1]


def _tls(M):
    """Centres (K, 2) and unit directions (K, 2) of the total-least-squares lines of point
    moments M (K, 6) = (n, sx, sy, sxx, syy, sxy)."""
    n = M[..., 0]
    cx, cy = M[..., 1] / n, M[..., 2] / n
    vxx = M[..., 3] / n - cx * cx
    vyy = M[..., 4] / n - cy * cy
    vxy = M[..., 5] / n - cx * cy
    th = 0.5 * np.arctan2(2 * vxy, vxx - vyy)
    return np.stack([cx, cy], -1), np.stack([np.cos(th), np.sin(th)], -1)


def _contour_sides(contours, seg_min):
    """The Douglas-Peucker sides of closed contours (each (N, 1, 2)) at least seg_min points
    long: (kept contours, a, b, source), the contours that have any, per side (K,) its index
    range [a, b) in the kept contours laid out twice in a row each (b may run past its
    contour's end: it wraps), and per side the index of its contour in `contours`. A polygon vertex is the first contour point at its position;
    every contour's vertices are found by one sort of all their points."""
    import cv2

    polys = [cv2.approxPolyDP(c, _DP_EPS_PX, True)[:, 0, :] for c in contours]
    idx = np.array([k for k, q in enumerate(polys) if len(q) >= 2], np.intp)
    cs = [contours[k] for k in idx]
    polys = [polys[k] for k in idx]
    if not cs:
        return [], np.zeros(0, np.intp), np.zeros(0, np.intp), np.zeros(0, np.intp)
    n = np.array([len(c) for c in cs])
    start = np.concatenate([[0], np.cumsum(n)[:-1]])
    P = np.concatenate([c[:, 0, :] for c in cs]).astype(np.int64)
    V = np.concatenate(polys).astype(np.int64)
    nv = np.array([len(q) for q in polys])
    cid_p, cid_v = np.repeat(np.arange(len(cs)), n), np.repeat(np.arange(len(cs)), nv)
    span = np.int64(100003) * 100003  # a contour's keys below it, each contour its own range
    key = cid_p * span + P[:, 0] * 100003 + P[:, 1]
    kv = cid_v * span + V[:, 0] * 100003 + V[:, 1]
    order = np.argsort(key, kind="stable")
    pos = np.minimum(np.searchsorted(key[order], kv), len(key) - 1)
    g = np.sort(order[pos])  # the vertices' points, contour after contour, in contour order
    cid = cid_v  # sorted by contour already: each contour's vertices stay in its range
    a = g - start[cid]
    last = np.r_[cid[1:] != cid[:-1], True]
    first = np.r_[True, cid[1:] != cid[:-1]]
    b = np.empty_like(a)
    b[:-1] = a[1:]
    b[last] = a[first] + n[cid[last]]  # the last side wraps to the first vertex
    keep = (b - a) >= seg_min
    has = np.bincount(cid[keep], minlength=len(cs)) > 0
    off = 2 * np.concatenate([[0], np.cumsum(np.where(has, n, 0))[:-1]])  # doubled layout of the kept
    sel = keep & has[cid]
    return [c for c, h in zip(cs, has) if h], a[sel] + off[cid[sel]], b[sel] + off[cid[sel]], idx[cid[sel]]


def _sides(contours, maps, dist, seg_min):
    """Per map of maps (each (h, w) uint8), the straight sides (K, 4) of its contours
    (contours: a list per map of (N, 1, 2) each), oriented with the region on their left, and
    their point moments (K, 6); None for a map without any. The maps' contours are measured
    together: each contour is laid out twice in a row, so that a side may wrap, and the
    moments of every side come from one cumulative sum (of integers: exact, whatever
    precedes them)."""
    h, w = dist.shape
    cs = [c for cm in contours for c in cm if len(c) >= 4 * seg_min]
    owner = np.array([k for k, cm in enumerate(contours) for c in cm if len(c) >= 4 * seg_min], np.intp)
    kept, a, b, src = _contour_sides(cs, seg_min)
    Ps = [c[:, 0, :] for c in kept for _ in range(2)]
    if not Ps:
        return [None] * len(maps)
    side_map = owner[src]
    P2 = np.concatenate(Ps).astype(np.float64)
    x, y = P2[:, 0], P2[:, 1]
    # one contiguous cumulative sum per moment (a cumulative sum down the columns of an
    # (N, 6) stack strides through memory: four times the cost); whole numbers, so exact
    cum = np.empty((6, P2.shape[0] + 1))
    cum[:, 0] = 0.0
    cum[0, 1:] = np.arange(1, P2.shape[0] + 1)
    for k, v in enumerate((x, y, x * x, y * y, x * y), 1):
        np.cumsum(v, out=cum[k, 1:])
    cum = cum.T
    M = cum[b + 1] - cum[a]
    cen, u = _tls(M)
    u[_dot2(u, P2[b] - P2[a]) < 0] *= -1
    ta = _dot2(P2[a] - cen, u)
    tb = _dot2(P2[b] - cen, u)
    A, B = cen + ta[:, None] * u, cen + tb[:, None] * u
    mi = np.clip(np.round(0.5 * (A + B)).astype(int), 0, [w - 1, h - 1])
    ok = (tb - ta >= seg_min) & (dist[mi[:, 1], mi[:, 0]] >= _OFF_BOUNDARY_PX)
    some = np.bincount(side_map[ok], minlength=len(maps)) > 0
    A, B, u, M, side_map = A[ok], B[ok], u[ok], M[ok], side_map[ok]
    n = np.stack([-u[:, 1], u[:, 0]], -1)
    Q = A[:, None, :] + np.linspace(0.2, 0.8, 5)[None, :, None] * (B - A)[:, None, :]
    pl = np.clip(np.round(Q + 2 * n[:, None, :]).astype(int), 0, [w - 1, h - 1])
    pr = np.clip(np.round(Q - 2 * n[:, None, :]).astype(int), 0, [w - 1, h - 1])
    stack = np.stack(maps)
    sm = side_map[:, None]
    left = stack[sm, pl[..., 1], pl[..., 0]].mean(1) - stack[sm, pr[..., 1], pr[..., 0]].mean(1)
    ok = np.abs(left) >= 0.5
    sw = (left < 0)[:, None]
    seg, M, side_map = np.concatenate([np.where(sw, B, A), np.where(sw, A, B)], -1)[ok], M[ok], side_map[ok]
    return [(seg[side_map == k], M[side_map == k]) if some[k] else None for k in range(len(maps))]


@dataclass(frozen=True, eq=False)
class BoundaryLines:
    """Straight region boundaries (`boundary_lines`), G of them, work pixels.

    p (G, 2) a point, u (G, 2) the unit direction, n (G, 2) = (-u_y, u_x) the normal into
    the region, lo, hi (G,) the extent along u from p [px], support (G,) the total length of
    the sides grouped into each [px].
    """

    p: np.ndarray
    u: np.ndarray
    n: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    support: np.ndarray

    def take(self, index):
        """The lines at index (integer indices or a (G,) bool mask), as `BoundaryLines`.

        >>> L = BoundaryLines(p=np.zeros((3, 2)), u=np.tile([1.0, 0.0], (3, 1)), n=np.tile([0.0, 1.0], (3, 1)),
        ...                   lo=np.zeros(3), hi=np.array([5.0, 9.0, 7.0]), support=np.array([5.0, 9.0, 7.0]))
        >>> L.take([2, 0]).hi.tolist(), L.take(L.hi > 6).support.tolist()
        ([7.0, 5.0], [9.0, 7.0])
        """
        return BoundaryLines(p=self.p[index], u=self.u[index], n=self.n[index], lo=self.lo[index], hi=self.hi[index],
                             support=self.support[index])


def _tls_one(m):
    """Centre (2,) and unit direction (2,) of the total-least-squares line of one moment
    vector m (6,) (`_tls` for one row, in plain floats)."""
    n = m[0]
    cx, cy = m[1] / n, m[2] / n
    th = 0.5 * math.atan2(2 * (m[5] / n - cx * cy), (m[3] / n - cx * cx) - (m[4] / n - cy * cy))
    return np.array([cx, cy]), np.array([math.cos(th), math.sin(th)])


def _group(seg, mom):
    """Greedy collinear grouping of oriented sides seg (K, 4) with point moments mom (K, 6),
    the longest first: a side joins when its direction and both its ends agree with the
    seed's line, then with the line through the pooled points (total least squares).
    Returns `BoundaryLines`."""
    d = seg[:, 2:] - seg[:, :2]
    L = np.hypot(d[:, 0], d[:, 1])
    u = d / L[:, None]
    A, B = seg[:, :2], seg[:, 2:]
    n = np.stack([-u[:, 1], u[:, 0]], -1)
    cos_tol = np.cos(np.maximum(np.radians(_GROUP_TOL_DEG), np.arctan2(2 * _GROUP_TOL_PX, L)))
    c = _dot2(n * 0.5, A + B)
    # [i, j]: side j lies on side i's line
    near = (u @ u.T > cos_tol[None, :]) & (np.abs(A @ n.T - c[None, :]).T < _GROUP_TOL_PX) \
        & (np.abs(B @ n.T - c[None, :]).T < _GROUP_TOL_PX)
    alone = (near.sum(0) + near.sum(1)) == 2  # on no other side's line, no other on its own
    used = alone.copy()
    # their own lines, as they are: (p, u, lo, hi, support) arrays
    cen, dirs = _tls(mom[alone])
    dirs *= np.where(_dot2(dirs, u[alone]) < 0, -1.0, 1.0)[:, None]
    ta, tb = _dot2(A[alone] - cen, dirs), _dot2(B[alone] - cen, dirs)
    lone = (cen, dirs, np.minimum(ta, tb), np.maximum(ta, tb), L[alone])
    out = []
    order = np.argsort(-L)
    for i in order[~alone[order]]:
        if used[i]:
            continue
        mem = np.flatnonzero(near[i] & ~used)
        mem = mem if i in mem else np.append(mem, i)
        p, nu = _tls_one(mom[mem].sum(0))
        ui = nu if nu @ u[i] >= 0 else -nu
        cand = np.flatnonzero(~used & (u @ ui > cos_tol))
        nv = np.array([-ui[1], ui[0]])
        ok = (np.abs((A[cand] - p) @ nv) < _GROUP_TOL_PX) & (np.abs((B[cand] - p) @ nv) < _GROUP_TOL_PX)
        if np.any(ok):
            mem = np.union1d(cand[ok], [i])
            p, nu = _tls_one(mom[mem].sum(0))
            ui = nu if nu @ ui >= 0 else -nu
        used[mem] = True
        a = np.concatenate([(A[mem] - p) @ ui, (B[mem] - p) @ ui])
        out.append((p, ui, float(a.min()), float(a.max()), float(L[mem].sum())))
    P = np.concatenate([lone[0], np.array([o[0] for o in out]).reshape(-1, 2)])
    U = np.concatenate([lone[1], np.array([o[1] for o in out]).reshape(-1, 2)])
    lo, hi, sup = (np.concatenate([lone[k], np.array([o[k] for o in out], float)]) for k in (2, 3, 4))
    return BoundaryLines(p=P, u=U, n=np.stack([-U[:, 1], U[:, 0]], -1), lo=lo, hi=hi, support=sup)


def boundary_lines(Bm, dist, seg_min):
    """The straight boundaries of a binary region map (module docstring, step 3).

    Bm: (h, w) bool or uint8 region; dist: (h, w) [work px] distance to the valid region's
    boundary (`WorkFrame.dist`); seg_min: the least side length [work px]. Returns
    `BoundaryLines`.
    """
    return boundary_lines_many([Bm], dist, seg_min)[0]


def boundary_lines_many(maps, dist, seg_min):
    """`boundary_lines` of each of several region maps of one work frame (the same lines as
    one map at a time): their contours' sides found and measured in one batch (`_sides`),
    then grouped map by map. maps: (h, w) bool or uint8 each."""
    import cv2

    maps = [np.asarray(Bm, np.uint8) for Bm in maps]  # no copy of a uint8 map (findContours leaves it)
    contours = [cv2.findContours(Bm, cv2.RETR_LIST, cv2.CHAIN_APPROX_NONE)[0] for Bm in maps]
    out = []
    for got in _sides(contours, maps, dist, seg_min):
        if got is None:
            z = np.zeros((0, 2))
            out.append(BoundaryLines(p=z, u=z, n=z, lo=np.zeros(0), hi=np.zeros(0), support=np.zeros(0)))
        else:
            out.append(_group(*got))
    return out


@dataclass(frozen=True, eq=False)
class FrameRegions:
    """One frame's region levels and their straight boundaries (`frame_regions`), computed
    once per frame and read by the material cue and the border cue alike.

    levels: `region_levels`' list of (level, kind, (h, w) uint8 map, repeat); lines: the
    `BoundaryLines` of each map that is no repeat, in the same order (empty with no level)."""

    levels: list
    lines: list


def frame_regions(mm, work, seg_min):
    """`FrameRegions` of one frame: its levels (`region_levels`) and the boundaries of each
    level's map that is no repeat (`boundary_lines_many`, sides at least seg_min [work px]).

    mm: the frame's `MaterialMap`; work: its `shaft.work.WorkFrame`.

    >>> from pencilcal.toolkit.detect.shaft.work import Validity, WorkFrame
    >>> img = np.zeros((240, 320, 3), np.uint8); img[:] = (90, 110, 200)
    >>> img[100:140, :] = (60, 60, 60)
    >>> wf = WorkFrame(img, None, Validity(None, img.shape[:2]), target_px=320)
    >>> fr = frame_regions(material_map(wf), wf, 20.0)
    >>> len(fr.lines) == sum(not repeat for *_, repeat in fr.levels), [len(L.p) for L in fr.lines][0]
    (True, 2)
    """
    levels = region_levels(mm, work)
    maps = [Bm for _, _, Bm, repeat in levels if not repeat]
    return FrameRegions(levels=levels, lines=boundary_lines_many(maps, work.dist, seg_min) if maps else [])


@dataclass(frozen=True, eq=False)
class RegionPairs:
    """Candidate bands between two region boundaries (`region_pairs`), K of them: i, j (K,)
    the boundary lines (`BoundaryLines` indices), width (K,) and overlap (K,) [work px]."""

    i: np.ndarray
    j: np.ndarray
    width: np.ndarray
    overlap: np.ndarray


def region_pairs(lines, wmin, wmax, max_conv_deg, min_overlap, max_pairs):
    """Pairs of boundary lines that may bound a band of region (module docstring, step 4):
    antiparallel within max_conv_deg [deg], facing each other, width in [wmin, wmax] [work
    px] at the middle of their overlap (>= min_overlap [px]), width of one sign and at least
    wmin / 2 at the overlap's ends. The max_pairs longest overlaps first. Returns
    `RegionPairs`."""
    return region_pairs_many([lines], wmin, wmax, max_conv_deg, min_overlap, max_pairs)[0]


def region_pairs_many(sets, wmin, wmax, max_conv_deg, min_overlap, max_pairs):
    """`region_pairs` of each of several `BoundaryLines` (a frame's region maps), the pairs
    of all tested together (each set's lines paired only among themselves; the same pairs as
    one set at a time)."""
    if not sets:
        return []
    sizes = [len(L.p) for L in sets]
    off = np.cumsum([0] + sizes)
    I, J = (np.concatenate(x) for x in zip(*[upper_pairs(G) for G in sizes]))
    shift = np.repeat(off[:-1], [G * (G - 1) // 2 for G in sizes])
    I, J = I + shift, J + shift
    P, U, N = (np.concatenate([getattr(L, f) for L in sets]).reshape(-1, 2) for f in ("p", "u", "n"))
    LO, HI = (np.concatenate([getattr(L, f) for L in sets]) for f in ("lo", "hi"))
    ok = _dot2(U[I], U[J]) < -np.cos(np.radians(max_conv_deg))
    I, J = I[ok], J[ok]
    ua = U[I] - U[J]
    ua /= np.maximum(np.sqrt(_dot2(ua, ua)), 1e-12)[:, None]  # np.linalg.norm's value
    na = np.stack([-ua[:, 1], ua[:, 0]], -1)
    dot = _dot2

    def ext(K):
        a, b = dot(P[K] + LO[K, None] * U[K], ua), dot(P[K] + HI[K, None] * U[K], ua)
        return np.minimum(a, b), np.maximum(a, b)

    def at(K, a):
        return P[K] + ((a - dot(P[K], ua)) / dot(U[K], ua))[:, None] * U[K]

    (ai0, ai1), (aj0, aj1) = ext(I), ext(J)
    lo, hi = np.maximum(ai0, aj0), np.minimum(ai1, aj1)
    # the overlap first (cheap, and most pairs fail it): the other tests only on those left
    q = np.flatnonzero(hi - lo >= min_overlap)
    I, J, ua, na, lo, hi = I[q], J[q], ua[q], na[q], lo[q], hi[q]
    dm = at(J, 0.5 * (lo + hi)) - at(I, 0.5 * (lo + hi))
    sep = dot(dm, na)
    w = np.abs(sep)
    ok = (dot(N[I], dm) > 0) & (dot(N[J], -dm) > 0) & (w >= wmin) & (w <= wmax)
    q = np.flatnonzero(ok)
    I, J, ua, na, lo, hi, sep, w = I[q], J[q], ua[q], na[q], lo[q], hi[q], sep[q], w[q]
    s_lo, s_hi = dot(at(J, lo) - at(I, lo), na), dot(at(J, hi) - at(I, hi), na)
    ok = (np.sign(s_lo) == np.sign(sep)) & (np.sign(s_hi) == np.sign(sep))
    ok &= np.minimum(np.abs(s_lo), np.abs(s_hi)) >= 0.5 * wmin
    owner = np.searchsorted(off, I, side="right") - 1  # each pair's set
    out = []
    for m in range(len(sets)):
        k = np.flatnonzero(ok & (owner == m))
        k = k[np.argsort(-(hi - lo)[k], kind="stable")][:max_pairs]
        out.append(RegionPairs(i=I[k] - off[m], j=J[k] - off[m], width=w[k], overlap=(hi - lo)[k]))
    return out


def scene_angle(bgr, valid, patch):
    """The colour variability of the scene at the scale of a band [deg]: the spectral
    angles between the mean colours of neighbouring patches `patch` work px apart inside the
    valid region (h, w), their median + 3 x 1.4826 MAD (a pair of patches straddling an
    instrument's edge is an outlier of that distribution: instruments cover a minor part of
    the view). 5 deg when there are too few patches."""
    import cv2

    p = max(int(round(patch)), 2)
    h, w = valid.shape
    hh, ww = h // p, w // p
    if hh < 3 or ww < 3 or bgr.ndim != 3:
        return 5.0
    f = cv2.resize(bgr[:hh * p, :ww * p].astype(np.float32), (ww, hh), interpolation=cv2.INTER_AREA)
    v = cv2.resize(valid[:hh * p, :ww * p].astype(np.float32), (ww, hh), interpolation=cv2.INTER_AREA) > 0.99
    nf = f / (np.linalg.norm(f, axis=2, keepdims=True) + 1e-6)
    angs = []
    for a, b, va, vb in ((nf[:, :-1], nf[:, 1:], v[:, :-1], v[:, 1:]), (nf[:-1], nf[1:], v[:-1], v[1:])):
        c = np.clip(np.sum(a * b, 2)[va & vb], -1, 1)
        angs.append(np.degrees(np.arccos(c)))
    A = np.concatenate(angs)
    if A.size < 10:
        return 5.0
    med = float(median(A))
    return med + 3 * 1.4826 * float(median(np.abs(A - med)))

