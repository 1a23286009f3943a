"""Bands between two long straight grey-level edges: the material cue's proposals where the
region maps give neither side (`shaft.material_cue`).

A dark grasper in the dark periphery, a grey shaft whose colour the instrument-likeness map
(`shaft.regions`) does not tell from the tissue beside it, a close shaft whose edges converge
under perspective: its two silhouette edges are clean straight steps of grey level, but no
level of the map has a region with both as its boundaries, so no band is proposed. Here the
edges are taken from the grey levels themselves:

1. *segments*: OpenCV's fast line detector (FLD) on the work frame (480 px on its longer
   side: no full-resolution pass) reduced by `_FLD_SCALE`, in the mean of its luma and red
   (`_edge_channel`), its segments at least half the least length long (FLD's own length
   threshold: merging shorter fragments cost as much as FLD itself and found nothing more)
   whose middle is off the valid region's boundary (the field stop's own edge is no
   instrument's), the `MAX_SEGMENTS` longest;
2. *pairs*: each segment taken with either side as its band (`shaft.regions.region_pairs`
   on the segments listed twice, once per orientation): two lines facing each other,
   at a width in range, converging by at most the largest convergence (a close cylinder's
   edges converge under perspective: `PAIR_MAX_CONVERGENCE_DEG`), overlapping along half the
   least length;
3. *material*: at `_STATIONS` stations along the overlap, the mean colour of the band's
   inside (the middle `_INSIDE` of its width) and of each outside (strips `_SIDE_PX` work px
   beyond each edge). A station is *good* where the inside differs from both outsides by
   `MIN_CONTRAST_SD` noise sd (and `_REL_CONTRAST` of the band's median contrast) and its
   colour lies within half the median contrast of the inside colours' straight-line trend
   along the band (one material, its shading changing slowly along it). A pair is a
   candidate where `_MIN_GOOD` of its observable stations are good, half of them are
   observable (a band between a bright shaft and the field stop has no outside there), and
   its inside is more instrument-like than both outsides (the median over the good stations
   of the inside's `shaft.regions` likeness less the larger outside's exceeds
   `_LIKENESS_MARGIN`: a fold or a vessel of tissue between two edges is tissue inside). Its
   score is the overlap times the fraction of good stations, times the overlap in
   `_SHORT_WIDTHS` widths where it is seen along fewer (the material cue takes no shorter
   band for a shaft); the best `MAX_PAIRS`, none covering most of a better one;
   *outlines*: a pair whose inside is not one material (a clip applier's or a grasper's
   metal limbs with the tissue seen through the slot between them, jaw edges inside) is an
   instrument's outline where its *rims* are one: at a station the colour just inside each
   edge (`_RIM_PX` work px: past the edge's blur and FLD's location error, inside the thinnest
   limb) differs from the outside beyond that edge as a good station's inside does, the two
   rims lie within half that of each other, and their mean differs from the inside as much
   (structure inside: the rims of a band of one material, tissue where the likeness says so,
   are its inside); a pair failing the material test is an outline where `_MIN_GOOD` of its
   observable stations are so, scored as above with that fraction.
   The best `MAX_OUTLINES` of them lying inside none of the pairs kept get a place of their
   own (an outline displaces no band of one material, and a limb's band inside it does not
   stop it: `_outlines`);
4. each candidate gets its own region map, as a band from a single edge does
   (`shaft.partner`): the pixels whose colour is nearer the band's median inside colour than
   either outside's (in `_FEATURE`: luma, half-weighted, and chroma, so that a grey shaft's
   streaks and sheen stay inside it), so that the band test
   (`shaft.region_bands.evaluate_bands`) and everything after it judge it as they judge a
   band of the region maps. An outline's map is the quadrilateral between its two segments
   (whatever lies inside is the instrument's): the band test then judges its sides (the
   material beside it, on the frame's own likeness map) and the judge its edges, fitted again
   at full resolution, its elongation, its pixel evidence and its colour, as every band's.

Work pixels throughout (as `shaft.regions`). The proposals cost 6-7 ms of process time
per 1080p frame (the 16 hysterectomy frames, one thread, on a loaded machine), FLD on the
reduced frame 2 ms of it, the colour maps and the candidates' material about 1.2 ms each.

Example
-------
>>> import numpy as np, cv2
>>> from pencilcal.toolkit.detect.shaft.work import Validity, WorkFrame
>>> img = np.zeros((240, 320, 3), np.uint8); img[:] = (35, 45, 100)             # dark tissue
>>> _ = cv2.fillConvexPoly(img, np.array([[0, 90], [319, 100], [319, 140], [0, 130]], np.int32), (22, 22, 24))
>>> img = cv2.GaussianBlur(img, (0, 0), 1.5)                                 # a dark grey shaft
>>> wf = WorkFrame(img, None, Validity(None, img.shape[:2]), target_px=320)
>>> from pencilcal.toolkit.detect.shaft.regions import material_map
>>> lines, pairs, maps = pair_bands(wf, 10.0, 80.0, 20.0, 1.0, 60.0, material_map(wf).likeness)
>>> len(pairs.i), abs(float(pairs.width[0]) - 41.0) < 1.5   # 41 px: the fill takes both rims
(1, True)
>>> bool(maps[0][115, 160]), bool(maps[0][60, 160])
(True, False)
"""
from __future__ import annotations

import numpy as np

from pencilcal.toolkit.detect.edges import mean_over
from pencilcal.toolkit.detect.shaft.regions import BoundaryLines, RegionPairs, close_open, region_pairs

__all__ = ["pair_bands", "candidate_pairs", "edge_segments", "colour_map", "MAX_PAIRS", "MAX_SEGMENTS",
           "PAIR_MAX_CONVERGENCE_DEG", "MIN_CONTRAST_SD"]

#: Candidate bands per frame, the best first (4 gave one detection more on the 64 real frames
#: of the masked sources, the hysterectomy and the dVRK phantom, a false band on the phantom,
#: at 0.6 ms of CPU a 1080p frame for the fourth colour map and its band's judging).
MAX_PAIRS = 3
#: Outlines per frame besides them (a pair whose rims are an instrument's, its inside not one
#: material: module docstring, step 3); their map is a fill of a quadrilateral, the cost one
#: more band judged where a frame has one.
MAX_OUTLINES = 1
#: Segments paired per frame, the longest first.
MAX_SEGMENTS = 48
#: The largest convergence of a pair's edges [deg]: a cylinder close to the lens, its axis
#: inclined towards the camera, is seen with edges converging by up to about 2 atan(r / d)
#: (r its radius, d its near end's distance): 25 deg at 2.3 radii, a 10 mm shaft 11 mm away.
PAIR_MAX_CONVERGENCE_DEG = 25.0
_FLD_SCALE = 0.5  # FLD runs on the work frame reduced by this (area-averaged: tissue texture gives fewer
# fragments, and the cost is a quarter; the band's edges are refitted at full resolution)
_CANNY = (20, 50)  # FLD's hysteresis thresholds: a dark grasper in a dark periphery steps by ~15 levels
_FRAGMENT_PX = 5.0  # FLD's shortest segment at least [px of the reduced frame]
_OFF_BOUNDARY_PX = 3.0  # a segment's middle at least this far inside the valid region [work px]
_MAX_CANDIDATES = 60  # pairs judged by their material, the longest overlaps first
_STATIONS = 16
_INSIDE = np.linspace(0.25, 0.75, 5)  # across the band, 0 and 1 its edges
_SIDE_PX = np.array([2.0, 3.5, 5.0])  # outside samples beyond each edge [work px]
#: The least contrast of a band's inside with each outside [noise sd] (step 2); the bands in
#: shadow (`shaft.shadow_bands`) ask it of their lightness.
MIN_CONTRAST_SD = 6.0
_REL_CONTRAST = 0.5
_MIN_GOOD = 0.6
_LUMA_WEIGHT = 0.5
_SHORT_WIDTHS = 1.5
_RIM_PX = np.array([1.5, 2.5])  # rim samples inside each edge [work px] (module docstring, step 3)
_LIKENESS_MARGIN = 0.0  # the inside's instrument-likeness above the outsides' by more than this
_SAME_BAND = 0.8  # a candidate covering this fraction of a better one's area is that band again


def _edge_channel(work):
    """The grey levels the edges are found in: on a colour frame the mean of the luma and
    the red channel (grey metal and pink tissue of one lightness differ in red; a dark grasper
    on dark tissue in lightness), else the luma."""
    return 0.5 * (work.luma + work.colours[..., 2]) if work.bgr.ndim == 3 else work.luma


def edge_segments(work, min_len, channel=None):
    """The straight grey-level edges of the work frame (module docstring, step 1): (N, 4)
    [work px], the longest first; in channel ((h, w) grey levels 0-255) where given, else in
    `_edge_channel`'s."""
    import cv2

    g = np.clip(_edge_channel(work) if channel is None else channel, 0, 255).astype(np.uint8)
    f = _FLD_SCALE
    g = cv2.resize(g, (max(8, round(g.shape[1] * f)), max(8, round(g.shape[0] * f))), interpolation=cv2.INTER_AREA)
    fld = cv2.ximgproc.createFastLineDetector(length_threshold=max(int(_FRAGMENT_PX), int(0.5 * min_len * f)),
                                              canny_th1=_CANNY[0], canny_th2=_CANNY[1])
    raw = fld.detect(g)
    if raw is None:
        return np.zeros((0, 4))
    seg = (raw.reshape(-1, 4).astype(float) + 0.5) / f - 0.5  # work px
    L = np.hypot(seg[:, 2] - seg[:, 0], seg[:, 3] - seg[:, 1])
    mid = 0.5 * (seg[:, :2] + seg[:, 2:])
    h, w = work.shape
    xi = np.clip(np.rint(mid[:, 0]).astype(int), 0, w - 1)
    yi = np.clip(np.rint(mid[:, 1]).astype(int), 0, h - 1)
    ok = (L >= 0.5 * min_len) & (work.dist[yi, xi] >= _OFF_BOUNDARY_PX)
    seg, L = seg[ok], L[ok]
    return seg[np.argsort(-L, kind="stable")][:MAX_SEGMENTS]


def _both_ways(seg):
    """`shaft.regions.BoundaryLines` of segments (N, 4), each listed twice (rows k and N +
    k): the band on its left, then on its right."""
    p = seg[:, :2]
    d = seg[:, 2:] - p
    L = np.hypot(d[:, 0], d[:, 1])
    u = d / np.maximum(L, 1e-12)[:, None]
    P = np.concatenate([p, seg[:, 2:]])
    U = np.concatenate([u, -u])
    N = np.stack([-U[:, 1], U[:, 0]], -1)
    lo = np.zeros(2 * len(seg))
    hi = np.concatenate([L, L])
    return BoundaryLines(p=P, u=U, n=N, lo=lo, hi=hi, support=hi.copy())


def _cross_sections(lines, pairs):
    """Per pair, the two edges' points (K, S, 2) each at `_STATIONS` stations over their
    overlap along the band's mean axis."""
    I, J = pairs.i, pairs.j
    ua = lines.u[I] - lines.u[J]
    ua /= np.maximum(np.linalg.norm(ua, axis=1, keepdims=True), 1e-12)

    def ends(K):
        a = np.sum((lines.p[K] + lines.lo[K, None] * lines.u[K]) * ua, 1)
        b = np.sum((lines.p[K] + lines.hi[K, None] * lines.u[K]) * ua, 1)
        return np.minimum(a, b), np.maximum(a, b)

    (a0, a1), (b0, b1) = ends(I), ends(J)
    lo, hi = np.maximum(a0, b0), np.minimum(a1, b1)
    A = lo[:, None] + (np.arange(_STATIONS) + 0.5)[None, :] / _STATIONS * (hi - lo)[:, None]

    def at(K):
        t = (A - np.sum(lines.p[K] * ua, 1)[:, None]) / np.sum(lines.u[K] * ua, 1)[:, None]
        return lines.p[K][:, None, :] + t[..., None] * lines.u[K][:, None, :]

    return at(I), at(J)


def _sample(work, imgs, X):
    """Per image of imgs ((h, w, C) or (h, w) float32 each) its values (..., C) float32 at
    work points X (..., 2), and the points' observability (...) bool: one map for all."""
    import cv2

    flat = X.reshape(-1, 2).astype(np.float32)
    n = flat.shape[0]
    cols = min(max(n, 1), 1024)
    rows = -(-n // cols)
    M = np.full((rows * cols, 2), -1e4, np.float32)
    M[:n] = flat
    mx, my = M[:, 0].reshape(rows, cols), M[:, 1].reshape(rows, cols)
    vals = []
    for img in imgs:
        col = cv2.remap(img, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
        C = img.shape[2] if img.ndim == 3 else 1
        vals.append(col.reshape(-1, C)[:n].reshape(X.shape[:-1] + (C,)))
    d = cv2.remap(work.dist, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=-1)
    return vals, d.reshape(-1)[:n].reshape(X.shape[:-1]) > 1.0


def _median_where(x, mask):
    """The median over axis 1 of x (K, S, ...) where mask (K, S) holds (the lower middle of
    an even count; 0 where none does)."""
    m = mask.reshape(mask.shape + (1,) * (x.ndim - 2))
    V = np.sort(np.where(m, x, np.inf), axis=1)
    n = np.count_nonzero(mask, 1)
    idx = np.maximum((n - 1) // 2, 0).reshape((-1, 1) + (1,) * (x.ndim - 2))
    out = np.take_along_axis(V, idx, axis=1)[:, 0]
    return np.where((n > 0).reshape((-1,) + (1,) * (x.ndim - 2)), out, 0.0)


def _trend(c, mask):
    """The straight-line trend (K, S, C) of colours c (K, S, C) along the stations, fitted
    by least squares where mask (K, S) holds (a shaft's shading changes slowly along it)."""
    t = np.linspace(-1.0, 1.0, c.shape[1])[None, :]
    w = mask.astype(float)
    n = np.maximum(w.sum(1), 1.0)[:, None]
    tm = (w * t).sum(1, keepdims=True) / n
    cm = (w[..., None] * c).sum(1) / n
    dt = (t - tm) * w
    b = (dt[..., None] * c).sum(1) / np.maximum((dt * (t - tm)).sum(1), 1e-9)[:, None]
    return cm[:, None, :] + (t - tm)[..., None] * b[:, None, :]


def _material(work, img, lines, pairs, noise, likeness):
    """Per pair (module docstring, steps 3-4): (score (K,), inside, side1, side2 colours (3,
    K, 3), outline score (K,): 0 but for an outline, `_outline`); img (h, w, 3) BGR float32,
    likeness (h, w) float32 the instrument-likeness."""
    Pi, Pj = _cross_sections(lines, pairs)
    across = Pj - Pi
    w = np.maximum(np.linalg.norm(across, axis=-1, keepdims=True), 1e-9)
    e = across / w
    inside = Pi[:, :, None, :] + _INSIDE[None, None, :, None] * across[:, :, None, :]
    out_i = Pi[:, :, None, :] - _SIDE_PX[None, None, :, None] * e[:, :, None, :]
    out_j = Pj[:, :, None, :] + _SIDE_PX[None, None, :, None] * e[:, :, None, :]
    # and the rims just inside each edge (`_outline`), in the same pass
    rim_i = Pi[:, :, None, :] + _RIM_PX[None, None, :, None] * e[:, :, None, :]
    rim_j = Pj[:, :, None, :] - _RIM_PX[None, None, :, None] * e[:, :, None, :]
    X = np.concatenate([inside, out_i, out_j, rim_i, rim_j], 2)
    (col, lik), obs = _sample(work, (img, likeness), X)
    lik = lik[..., 0]
    ni, ns, nr = _INSIDE.size, _SIDE_PX.size, _RIM_PX.size
    seen = np.all(obs[:, :, :ni + 2 * ns], 2)  # (K, S)
    cin = mean_over(col, 2, 0, ni)  # col[:, :, :ni].mean(2), `edges.mean_over`
    c1 = mean_over(col, 2, ni, ni + ns)
    c2 = mean_over(col, 2, ni + ns, ni + 2 * ns)
    con = np.minimum(np.linalg.norm(cin - c1, axis=-1), np.linalg.norm(cin - c2, axis=-1))  # (K, S)
    n_seen = np.count_nonzero(seen, 1)
    med_con = _median_where(con, seen)
    good = seen & (con >= np.maximum(MIN_CONTRAST_SD * noise, _REL_CONTRAST * med_con)[:, None])
    good &= np.linalg.norm(cin - _trend(cin, seen), axis=-1) <= 0.5 * med_con[:, None]
    frac = np.count_nonzero(good, 1) / np.maximum(n_seen, 1)
    ok = (n_seen >= 0.5 * _STATIONS) & (frac >= _MIN_GOOD)
    # more instrument-like than both outsides (median over the good stations)
    more = lik[:, :, :ni].mean(2) - np.maximum(lik[:, :, ni:ni + ns].mean(2),
                                               lik[:, :, ni + ns:ni + 2 * ns].mean(2))
    ok &= _median_where(more, good) > _LIKENESS_MARGIN
    # a band seen along fewer than `_SHORT_WIDTHS` widths is no shaft (`shaft.material_cue`
    # judges so): such a pair ranks after the elongated ones
    short = np.minimum(1.0, pairs.overlap / (_SHORT_WIDTHS * pairs.width))
    score = np.where(ok, pairs.overlap * frac * short, 0.0)
    ref = np.stack([_median_where(c, good) for c in (cin, c1, c2)])  # (3, K, C)
    # the pairs failing it whose rims are an instrument's outline, their score apart
    rims = mean_over(col, 2, ni + 2 * ns, ni + 2 * ns + nr), mean_over(col, 2, ni + 2 * ns + nr)
    outline, ofrac = _outline(rims, cin, c1, c2, seen, noise)
    outline &= ~ok
    return score, ref, np.where(outline, pairs.overlap * ofrac * short, 0.0)


def _outline(rims, cin, c1, c2, seen, noise):
    """(ok (K,), frac (K,)): the pairs whose rims are an instrument's outline (module
    docstring, step 3): at each station the colour just inside each edge (rims: two (K, S, 3),
    at `_RIM_PX`) differs from the outside beyond it (c1, c2 (K, S, 3)) as a good station's
    inside does, the two rims are alike within half that and their mean differs from the
    inside (cin (K, S, 3)) as much; ok where `_MIN_GOOD` of the observable stations (seen (K,
    S)) are so, frac their fraction. noise: one work pixel's sd [grey levels]."""
    ri, rj = rims
    con = np.minimum(np.linalg.norm(ri - c1, axis=-1), np.linalg.norm(rj - c2, axis=-1))
    med = _median_where(con, seen)
    least = np.maximum(MIN_CONTRAST_SD * noise, _REL_CONTRAST * med)[:, None]
    good = seen & (con >= least) & (np.linalg.norm(ri - rj, axis=-1) <= 0.5 * con)
    # and unlike the inside between them: structure inside (a band of one colour whose rims
    # are its inside is a band of one material, tissue where the likeness says so)
    good &= np.linalg.norm(0.5 * (ri + rj) - cin, axis=-1) >= least
    n_seen = np.count_nonzero(seen, 1)
    frac = np.count_nonzero(good, 1) / np.maximum(n_seen, 1)
    return (n_seen >= 0.5 * _STATIONS) & (frac >= _MIN_GOOD), frac


def _quad(lines, i, j):
    """The convex quadrilateral (4, 2) float32 between two lines' segments."""
    import cv2

    pts = [lines.p[k] + t * lines.u[k] for k in (i, j) for t in (lines.lo[k], lines.hi[k])]
    return cv2.convexHull(np.array(pts, np.float32))[:, 0, :]


def _distinct(lines, pairs, order):
    """Of the pairs in order (best first), those not covering `_SAME_BAND` of a kept one's
    area (nor it of theirs), at most `MAX_PAIRS`."""
    import cv2

    kept, polys = [], []
    for k in order:
        Q = _quad(lines, pairs.i[k], pairs.j[k])
        a = abs(cv2.contourArea(Q))
        if a <= 0:
            continue
        if any(cv2.intersectConvexConvex(Q, P)[0] > _SAME_BAND * min(a, abs(cv2.contourArea(P))) for P in polys):
            continue
        kept.append(k)
        polys.append(Q)
        if len(kept) == MAX_PAIRS:
            break
    return kept


def _outlines(lines, pairs, kept, order):
    """Of the outlines in order (best first), the best `MAX_OUTLINES` that lie inside none of
    the kept pairs nor of each other (`_SAME_BAND` of their own area), in places of their own
    (an outline displaces no band of one material); a kept pair inside an outline, one of its
    limbs, does not stop it: of an instrument the outermost edge pair, whatever lies inside."""
    import cv2

    polys = [_quad(lines, pairs.i[k], pairs.j[k]) for k in kept]
    out = []
    for k in order:
        if len(out) == MAX_OUTLINES:
            break
        Q = _quad(lines, pairs.i[k], pairs.j[k])
        a = abs(cv2.contourArea(Q))
        if a <= 0 or any(cv2.intersectConvexConvex(Q, P)[0] > _SAME_BAND * a for P in polys):
            continue
        out.append(k)
        polys.append(Q)
    return out


def _quad_map(lines, pairs, k, valid):
    """The region map (h, w) uint8 of an outline's pair k: the quadrilateral between its two
    segments, in valid ((h, w) uint8 0/1): whatever lies inside is the instrument's."""
    import cv2

    B = np.zeros_like(valid)
    cv2.fillConvexPoly(B, np.rint(_quad(lines, pairs.i[k], pairs.j[k])).astype(np.int32), 1)
    return cv2.bitwise_and(B, valid)


#: BGR to the features the band's map compares: luma (weighted by `_LUMA_WEIGHT`: a grey
#: shaft's streaks and sheen change its lightness, not its colour) and the two chroma
#: differences of YCrCb, Cr = 0.713 (R - Y) and Cb = 0.564 (B - Y) (their offsets cancel).
_Y = np.array([0.114, 0.587, 0.299])
_FEATURE = np.array([_LUMA_WEIGHT * _Y, 0.713 * (np.array([0.0, 0.0, 1.0]) - _Y),
                     0.564 * (np.array([1.0, 0.0, 0.0]) - _Y)])


def colour_map(img, valid, c_in, c1, c2):
    """The pixels (h, w) uint8 whose features (`_FEATURE` of img (h, w, 3) BGR) are nearer
    c_in's than c1's and c2's (BGR colours), in valid ((h, w) uint8 0/1), closed and opened
    by 3 x 3."""
    import cv2

    cs = np.stack([c_in, c1, c2]).astype(np.float64)
    fc = cs @ _FEATURE.T
    # |F x - F c|^2 less the |F x|^2 common to all three: -2 (F^T F c) . x + |F c|^2, the
    # three colours in one pass over the BGR frame
    M = np.c_[-2.0 * fc @ _FEATURE, np.sum(fc * fc, 1)]
    # each outside's less the inside's (three rows: OpenCV's fast path)
    d1, d2, _ = cv2.split(cv2.transform(img, (M - M[0])[[1, 2, 0]].astype(np.float32)))
    B = cv2.bitwise_and((cv2.min(d1, d2) > 0).view(np.uint8), valid)
    return close_open(B)  # `shaft.regions.close_open`


def candidate_pairs(segments, wmin, wmax, conv_max_deg, min_len):
    """(BoundaryLines, RegionPairs): segments (N, 4) [work px] as lines, each both ways, and
    the pairs among them that may bound a band (`shaft.regions.region_pairs`, the longest
    overlaps first, at most `_MAX_CANDIDATES`): the candidates whose material `pair_bands`
    judges. Arguments as `pair_bands` takes them."""
    lines = _both_ways(np.asarray(segments, float).reshape(-1, 4))
    return lines, region_pairs(lines, wmin, wmax, conv_max_deg, 0.5 * min_len, _MAX_CANDIDATES)


def pair_bands(work, wmin, wmax, conv_max_deg, noise, min_len, likeness, segments=None, with_maps=True,
               candidates=None):
    """Candidate bands between pairs of grey-level edges (module docstring).

    Parameters
    ----------
    work : WorkFrame
    wmin, wmax, conv_max_deg : float
        The least and largest widths of a band [work px], and its edges' largest
        convergence [deg].
    noise : float [grey levels]
        The sd of one work pixel's noise in each channel.
    min_len : float [work px]
        The least length of a shaft: segments and overlaps at least half of it.
    likeness : (h, w) float32
        The work frame's instrument-likeness (`shaft.regions.MaterialMap.likeness`).
    segments : (N, 4), optional
        The edges to pair [work px]; default `edge_segments`.
    with_maps : bool
        False: each pair's region map is None (the caller makes its own).
    candidates : (BoundaryLines, RegionPairs), optional
        `candidate_pairs` of the segments, where the caller has them already.

    Returns
    -------
    (BoundaryLines, RegionPairs, list of (h, w) uint8)
        The lines, the pairs between them (at most `MAX_PAIRS`, the best first) and each
        pair's region map, as `shaft.partner.partner_bands` returns them.
    """
    if candidates is None:
        seg = edge_segments(work, min_len) if segments is None else segments
        candidates = candidate_pairs(seg, wmin, wmax, conv_max_deg, min_len)
    lines, pairs = candidates
    empty = RegionPairs(i=np.zeros(0, int), j=np.zeros(0, int), width=np.zeros(0), overlap=np.zeros(0))
    if len(pairs.i) == 0:
        return lines, empty, []
    img = work.colours  # read-only float32, made once for all stages
    score, ref, outline = _material(work, img, lines, pairs, noise, np.asarray(likeness, np.float32))
    order = [k for k in np.argsort(-score, kind="stable") if score[k] > 0]
    keep = _distinct(lines, pairs, order)
    keep += _outlines(lines, pairs, keep, [k for k in np.argsort(-outline, kind="stable") if outline[k] > 0])
    outline = outline > 0
    if not keep:
        return lines, empty, []
    valid = work.valid.view(np.uint8)
    maps = ([_quad_map(lines, pairs, k, valid) if outline[k] else colour_map(img, valid, *ref[:, k]) for k in keep]
            if with_maps else [None] * len(keep))
    keep = np.array(keep, int)
    return lines, RegionPairs(i=pairs.i[keep], j=pairs.j[keep], width=pairs.width[keep],
                              overlap=pairs.overlap[keep]), maps
