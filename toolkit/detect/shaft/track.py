"""The edge cue from frame to frame: a shaft found again in a corridor around where it was.

In a video an instrument moves between frames, but not far across the view, and it keeps
its width. `corridor_edges` looks for a prior shaft's band (the previous frame's) in a
corridor around its midline, without the edge cue's proposals (`shaft.edge_cue`, steps 1
and 2: the line detector over the whole frame, the hypotheses, their refits):

1. *stations*: `STATIONS` cross-sections perpendicular to the prior midline, evenly from
   a tenth of its length before its wide end to a tenth beyond its narrow end, each
   ``reach_px`` either side of it (plus the band's width), sampled in the raw image like
   the edge profiles (`edges.SAMPLE_STEP_PX`, a Gaussian derivative of `sigma_px`);
2. *band candidates*: at each station, pairs of unsigned gradient peaks (local maxima over
   +-1.5 px, at least the edge cue's least gradient) whose distance is the prior's width
   there within `WIDTH_TOL`; the `PER_STATION` strongest (the weaker peak of the pair);
3. *the band*: the straight line through the candidates' centres that the most stations
   support (a candidate within `TOL_PX` of it, of the same relative width within
   0.15), from every pair of two stations' strongest two candidates a third of the
   stations apart or more, turned by at most `MAX_TURN_DEG` from the prior; each of its two edges fitted by least squares to
   the inliers' peaks. At least `MIN_SUPPORT` of the stations in view must support it.

The edges are then refitted at full resolution and judged as the edge cue judges its
edges (`shaft.edge_cue.refit_edges`, `shaft.edge_cue.bands_from_edges`): a band found
here is a shaft only where a full detection would keep it too, and it is measured the same
way. Working pixels (`working`); the options those of `shaft.detector.detect_shafts`.

A shaft the material cue found (on a colour frame, against tissue whose grey levels may
match the instrument's: the edge cue need not see it) is found again by its colour instead
(`material_edges`): its two silhouette edges fitted as that cue fits them
(`shaft.silhouette.fit_edges`, the colour profile projected on each edge's own colour
difference), first within the reach around the prediction over its predicted stretch, then
in the cue's own corridor around that fit; kept where both edges hold along `MIN_SEEN` of
the prior's stretch and the width stays within `COLOUR_WIDTH_TOL` of the prior's. (A shaft
pushed further into the view is seen at its full length again at the next full detection.)

Example
-------
>>> import numpy as np, cv2
>>> from types import SimpleNamespace
>>> from pencilcal.toolkit.detect.image import GrayImage
>>> img = np.full((240, 320), 170, np.uint8)
>>> _ = cv2.fillConvexPoly(img, np.array([[0, 100], [0, 124], [319, 136], [319, 112]], np.int32), 40)
>>> prior = np.array([[0.0, 95.0, 319.0, 110.0], [0.0, 119.0, 319.0, 134.0]])   # 3 deg off, 10 px up
>>> e = corridor_edges(GrayImage(cv2.GaussianBlur(img, (0, 0), 1.0)), None, prior, SimpleNamespace(sigma_px=1.5),
...                    1.0, 40.0)
>>> bool(np.all(np.abs(e[:, [1, 3]] - [[99.5, 111.5], [124.5, 136.5]]) < 1.0))   # the edges at x = 0 and 319
True
"""
from __future__ import annotations

import numpy as np

from pencilcal.toolkit.detect.edges import MIN_STATIONS, SAMPLE_STEP_PX, derivative_kernel
from pencilcal.toolkit.detect.working import to_raw_smooth

__all__ = ["corridor_edges", "material_edges", "band_colours", "REACH", "STATIONS", "WIDTH_TOL", "PER_STATION", "TOL_PX",
           "MAX_TURN_DEG", "MIN_SUPPORT", "MIN_SEEN", "COLOUR_WIDTH_TOL"]

#: Half-width of the corridor around a prior shaft, as a fraction of the image diagonal
#: (beyond the band's own width): how far a shaft may move between two frames.
REACH = 0.08
#: Cross-sections of the corridor.
STATIONS = 32
#: A band candidate's width within this fraction of the prior's width at its station.
WIDTH_TOL = 0.25
#: Band candidates kept per station (the strongest).
PER_STATION = 5
#: A candidate supports a line through the band's centres within this distance [px].
TOL_PX = 2.0
#: Largest turn of the band from the prior midline [deg].
MAX_TURN_DEG = 20.0
#: Fewest stations supporting the band, as a fraction of those in view.
MIN_SUPPORT = 0.3
#: A colour-tracked shaft's edges must hold along this fraction of the prior's stretch.
MIN_SEEN = 0.5
#: A colour-tracked edge's first fit (within the reach) is taken when its stations lie within
#: this RMS of its line [px] (a silhouette's ~0.7; the tissue's own edges, taken at some
#: stations, scatter by far more).
FIRST_RMS_PX = 2.0
#: A colour-tracked shaft's width within this fraction of the prior's (a shaft's apparent
#: width changes by about a per cent a frame as it moves; an edge of the tissue taken for
#: one of its own changes it by far more).
COLOUR_WIDTH_TOL = 0.1
_PEAKS = 40  # strongest gradient peaks per station looked at
_SEEDS = 2  # the line hypotheses join two stations' strongest candidates
_NMS = 3  # non-maximum suppression half-window [samples]


def _edge_offsets(edges, A, u, n, s):
    """Offsets t (2, S) along n of the two edge lines (2, 4) at the stations A + s u."""
    p, q = edges[:, :2], edges[:, 2:]
    d = (q - p) / np.maximum(np.linalg.norm(q - p, axis=-1, keepdims=True), 1e-12)
    ne = np.stack([-d[:, 1], d[:, 0]], -1)
    ce = -np.sum(ne * p, -1)
    pts = A[None, :] + s[:, None] * u[None, :]  # (S, 2)
    den = ne @ n  # (2,)
    with np.errstate(divide="ignore", invalid="ignore"):
        return -(pts @ ne.T + ce[None, :]).T / den[:, None]


def _profiles(img, camera, A, u, n, s, half):
    """Grey levels (S, T) across the corridor at the stations A + s u, at t (T,) from -half
    to +half along n, and where they lie in the image and the valid region (S, T)."""
    t = np.arange(-half, half + 0.5 * SAMPLE_STEP_PX, SAMPLE_STEP_PX)
    pts = A + s[:, None, None] * u + t[None, :, None] * n  # (S, T, 2) working
    raw = to_raw_smooth(camera, pts, every=8)
    x, y = raw[..., 0], raw[..., 1]
    inside = img.in_region(x, y) & np.isfinite(x) & np.isfinite(y)
    prof = img.sample(np.where(inside, x, 0.0), np.where(inside, y, 0.0))
    return prof, inside, t


def _gradient(prof, inside, kern, r):
    """|derivative| (S, T) along t of the profiles, and where all its taps are inside."""
    import cv2

    g = cv2.filter2D(np.ascontiguousarray(prof, np.float32), -1, kern[None, :], anchor=(r, 0),
                     borderType=cv2.BORDER_REPLICATE)
    ok = cv2.erode(inside.astype(np.uint8), np.ones((1, 2 * r + 1), np.uint8), borderType=cv2.BORDER_CONSTANT,
                   borderValue=0) > 0
    return np.abs(g), ok


def _candidates(a, ok, t, w_prior, min_gradient):
    """Band candidates per station: (centre (S, K), left, right peak (S, K), width ratio
    (S, K), score (S, K), valid (S, K)) for the K = `PER_STATION` strongest pairs of peaks
    at the prior's width (module docstring, step 2)."""
    import cv2

    S = a.shape[0]
    dil = cv2.dilate(a, np.ones((1, 2 * _NMS + 1), np.uint8))
    peak = ok & (a >= dil) & (a >= min_gradient)
    ap = np.where(peak, a, 0.0)
    idx = np.argsort(-ap, axis=1, kind="stable")[:, :_PEAKS]
    rows = np.arange(S)[:, None]
    sp, tp = ap[rows, idx], t[idx]
    vp = sp > 0
    d = tp[:, None, :] - tp[:, :, None]  # [k, i, j]: t_j - t_i
    ratio = d / np.maximum(w_prior, 1e-9)[:, None, None]
    good = vp[:, :, None] & vp[:, None, :] & (np.abs(ratio - 1.0) <= WIDTH_TOL)
    sc = np.where(good, np.minimum(sp[:, :, None], sp[:, None, :]), 0.0).reshape(S, -1)
    best = np.argsort(-sc, axis=1, kind="stable")[:, :PER_STATION]
    P = tp.shape[1]
    i, j = best // P, best % P
    left, right = tp[rows, i], tp[rows, j]
    score = sc[rows, best]
    return 0.5 * (left + right), left, right, (right - left) / np.maximum(w_prior, 1e-9)[:, None], score, score > 0


def _best_line(s, centre, ratio, score, valid):
    """The hypothesis (a, b, ratio) t = a + b s with the most supporting stations, its
    support and its inliers (S, K) (module docstring, step 3); None without one."""
    S, K = centre.shape
    st = np.repeat(np.arange(S), K)
    c, r, w, v = centre.ravel(), ratio.ravel(), score.ravel(), valid.ravel()
    ids = np.flatnonzero(v)
    seeds = np.flatnonzero(v & (np.tile(np.arange(K), S) < _SEEDS))
    if seeds.size < 2:
        return None
    i, j = np.triu_indices(seeds.size, 1)
    i, j = seeds[i], seeds[j]
    far = (st[j] - st[i]) >= max(S // 3, 2)
    i, j = i[far], j[far]
    b = (c[j] - c[i]) / (s[st[j]] - s[st[i]])
    keep = (np.abs(b) <= np.tan(np.radians(MAX_TURN_DEG))) & (np.abs(r[j] - r[i]) <= 0.15)
    i, j, b = i[keep], j[keep], b[keep]
    if i.size == 0:
        return None
    a0 = c[i] - b * s[st[i]]
    rh = 0.5 * (r[i] + r[j])
    sv = s[st[ids]]
    inl = (np.abs(c[ids][None, :] - (a0[:, None] + b[:, None] * sv[None, :])) <= TOL_PX) \
        & (np.abs(r[ids][None, :] - rh[:, None]) <= 0.15)  # (H, C)
    per = np.zeros((i.size, S), bool)
    rows = np.repeat(np.arange(i.size), ids.size)
    per[rows[inl.ravel()], np.tile(st[ids], i.size)[inl.ravel()]] = True
    support = per.sum(-1)
    strength = np.where(inl, w[ids][None, :], 0.0).sum(-1)
    h = int(np.lexsort((-strength, -support))[0])
    mask = np.zeros(S * K, bool)
    mask[ids[inl[h]]] = True
    return (a0[h], b[h], rh[h]), int(support[h]), mask.reshape(S, K)


def _edge_fit(s, t, keep):
    """Least-squares line t = a + b s through the stations keep (N,), one pass of rejection
    beyond 1.5 px; (a, b) or None."""
    for _ in range(2):
        if keep.sum() < MIN_STATIONS:
            return None
        b, a = np.polyfit(s[keep], t[keep], 1)
        keep = keep & (np.abs(t - (a + b * s)) <= 1.5)
    return (a, b) if keep.sum() >= MIN_STATIONS else None


def corridor_edges(img, camera, prior, o, sig_n, reach_px):
    """The two edge lines (2, 4) [working px] of the band in the corridor around a prior
    shaft, or None (module docstring).

    img: `image.GrayImage`; prior: the prior's two edges (2, 4) [working px]; o: the
    options of `shaft.detector.detect_shafts` (sigma_px); sig_n: the image noise sd (the least
    gradient is the edge cue's, max(2, 1.5 sig_n)); reach_px: how far the band may have
    moved [px].
    """
    E = np.asarray(prior, float).reshape(2, 4)
    mid = 0.5 * (E[0] + (E[1] if np.dot(E[0, 2:] - E[0, :2], E[1, 2:] - E[1, :2]) > 0 else E[1, [2, 3, 0, 1]]))
    A, B = mid[:2], mid[2:]
    L = float(np.hypot(*(B - A)))
    if not L > 0:
        return None
    u = (B - A) / L
    n = np.array([-u[1], u[0]])
    s = np.linspace(-0.1 * L, 1.1 * L, STATIONS)
    te = _edge_offsets(E, A, u, n, s)
    w_prior = np.abs(te[1] - te[0])
    if not np.all(np.isfinite(w_prior)):
        return None
    half = reach_px + (1.0 + WIDTH_TOL) * float(np.max(w_prior)) + 3.0 * o.sigma_px
    prof, inside, t = _profiles(img, camera, A, u, n, s, half)
    a, ok = _gradient(prof, inside, *derivative_kernel(o.sigma_px))
    in_view = int(np.sum(np.any(ok, -1)))
    cen, left, right, ratio, score, valid = _candidates(a, ok, t, w_prior, max(2.0, 1.5 * sig_n))
    got = _best_line(s, cen, ratio, score, valid)
    if got is None:
        return None
    _, support, inl = got
    if support < max(MIN_STATIONS, MIN_SUPPORT * in_view):
        return None
    # one candidate per station: the strongest of its inliers
    k = np.argmax(np.where(inl, score, -1.0), 1)
    use = inl.any(1)
    rows = np.arange(s.size)
    out = []
    for side in (left, right):
        fit = _edge_fit(s, side[rows, k], use)
        if fit is None:
            return None
        lo, hi = s[use].min(), s[use].max()
        ends = [A + sv * u + (fit[0] + fit[1] * sv) * n for sv in (lo, hi)]
        out.append(np.concatenate(ends))
    return np.stack(out)


def _specs(edges, shrink=0.0):
    """`shaft.silhouette.fit_edges` specs (p0, u, n_out, s0, s1) of a shaft's two edges (2, 4)
    [ideal px], each over the stretch where both are (their overlap along the first one),
    less `shrink` of it at each end, its normal pointing away from the other edge."""
    E = np.asarray(edges, float).reshape(2, 4)
    c = E.reshape(2, 2, 2).mean((0, 1))
    u0 = (E[0, 2:] - E[0, :2]) / max(float(np.hypot(*(E[0, 2:] - E[0, :2]))), 1e-12)
    t = (E.reshape(2, 2, 2) - E[0, :2]) @ u0  # (2 edges, 2 ends) along the first edge
    lo, hi = max(t[0].min(), t[1].min()), min(t[0].max(), t[1].max())
    lo, hi = lo + shrink * (hi - lo), hi - shrink * (hi - lo)
    out = []
    for e in E:
        p, q = e[:2], e[2:]
        u = (q - p) / max(float(np.hypot(*(q - p))), 1e-12)
        n = np.array([-u[1], u[0]])
        n = n if float((p - c) @ n) >= 0 else -n
        a, b = sorted([float((E[0, :2] + lo * u0 - p) @ u), float((E[0, :2] + hi * u0 - p) @ u)])
        out.append((p, u, n, a, b))
    return out


def material_edges(image, camera, validity, noise, prior, reach_px, corridor_px, width_px, colours=None):
    """The two silhouette edges (`shaft.silhouette.EdgeLine`, ideal px) of a shaft the
    material cue found, looked for again around its predicted edges `prior` (2, 4) [ideal
    px], within reach_px; None where they do not hold (module docstring).

    image: the raw colour frame (float32 once for several calls); validity:
    `shaft.work.Validity`; noise: its noise sd per channel; corridor_px: the material cue's
    corridor; width_px: the prior's width [px]; colours: (inside, outside) the prior's band
    colours (`band_colours`): the band found must keep the inside's colour, nearer it than
    half the way to the outside's (a band beside the shaft holds tissue).
    """
    from pencilcal.toolkit.detect.shaft.silhouette import fit_edges

    first = fit_edges(image, camera, validity, noise, _specs(prior, 0.05), max(float(reach_px), corridor_px))
    good = [f is not None and f.rms <= FIRST_RMS_PX for f in first]
    if not any(good):
        return None
    edges = [np.concatenate(f.ends()) if g else None for f, g in zip(first, good)]
    if not all(good):  # the other edge: the good one's line moved across by the width
        f = first[good.index(True)]
        # its normal points out of the shaft: the other edge lies a width the other way
        edges[good.index(False)] = np.concatenate([f.point_at(f.s_lo) - width_px * f.n,
                                                   f.point_at(f.s_hi) - width_px * f.n])
    again = np.stack(edges)
    fits = fit_edges(image, camera, validity, noise, _specs(again), corridor_px)
    if any(f is None for f in fits):
        return None
    seen = min(f.s_hi - f.s_lo for f in fits)
    L = 0.9 * min(float(np.hypot(*(e[2:] - e[:2]))) for e in prior)
    w = abs(float(fits[1].line() @ np.r_[fits[0].point_at(0.5 * (fits[0].s_lo + fits[0].s_hi)), 1.0]))
    if seen < MIN_SEEN * L or abs(w / max(width_px, 1e-9) - 1.0) > COLOUR_WIDTH_TOL:
        return None
    if colours is not None:
        E = np.stack([np.concatenate(f.ends()) for f in fits])
        inside, _ = band_colours(image, camera, E)
        ref_in, ref_out = colours
        if not np.linalg.norm(_chroma(inside) - _chroma(ref_in)) <= 0.5 * np.linalg.norm(_chroma(ref_out) - _chroma(ref_in)):
            return None
    return fits


def _chroma(bgr):
    """(2,) the colour without its brightness: (B - G, R - G) over their sum."""
    b, g, r = (float(v) for v in bgr)
    return np.array([b - g, r - g]) / max(b + g + r, 1e-9)


def band_colours(image, camera, edges, stations=32):
    """(inside, outside): the mean colour (3,) of a shaft's band between its two edges (2, 4)
    [ideal px], over its middle half across, and of the strips beside it (a quarter of the
    width wide, a quarter beyond each edge), at `stations` places along its middle 90 %.
    image: the raw colour frame."""
    import cv2

    E = np.asarray(edges, float).reshape(2, 4)
    p0, p1 = E[0, :2], E[0, 2:]
    q = E[1] if float((E[1, 2:] - E[1, :2]) @ (p1 - p0)) >= 0 else E[1, [2, 3, 0, 1]]
    f = np.linspace(0.05, 0.95, stations)[:, None]
    a, b = p0 + f * (p1 - p0), q[:2] + f * (q[2:] - q[:2])  # (S, 2) on each edge
    across = np.array([0.3, 0.4, 0.5, 0.6, 0.7, -0.375, -0.25, 1.25, 1.375])  # from a (0) to b (1)
    pts = a[:, None, :] + across[None, :, None] * (b - a)[:, None, :]  # (S, 9, 2)
    raw = to_raw_smooth(camera, pts.transpose(1, 0, 2), every=8).transpose(1, 0, 2).astype(np.float32)
    img = np.asarray(image, np.float32)
    v = cv2.remap(img, raw[..., 0], raw[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)  # (S, 9, 3)
    return v[:, :5].reshape(-1, 3).mean(0), v[:, 5:].reshape(-1, 3).mean(0)
