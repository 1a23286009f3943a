"""The other edge of a band, found from one strong edge: the material cue's proposals where
the region maps give only one side (`shaft.material_cue`).

A white or metal shaft whose colour the instrument-likeness map (`shaft.regions`) does not
tell from tissue, a blurred one, one in shadow: the map then holds a straight boundary of the
instrument only where something instrument-like lies beside it (a dark region: shadow, dark
tissue, the vignetted periphery), and no band between two boundaries is proposed. Here each
long straight boundary (a *seed*, at most `MAX_SEEDS`, the longest first) is taken as one
silhouette edge of a band on the side away from its region, and the band's other edge is
searched by a gradient model across it: at stations along the seed, the colour profile
along its normal, out to the widest band (work frame, Gaussian-smoothed along the profile,
sd `_SMOOTH_PX`), differentiated and projected on the reverse of the seed's own colour
transition (a band on a background: the far edge steps back to the colour the near edge
stepped from). The far edge is a straight line t(s) = t0 + b (s - s_mid) through the
stations' responses, b up to the largest convergence: a station supports it where the
response there reaches `_REL_STRENGTH` of the seed's step (and `Z_999` noise sd), and a
line is a candidate where `_MIN_SUPPORT` of the observable stations support it. Of the
candidates the **outermost** is the far edge, whatever lies inside (streaks, slots, a
sheen, a wrist's joint make inner edges of either sign): the band is the instrument's whole
silhouette. Searched from a seed that enters the view from its border (`partner_bands`'
from_border), a far edge that widens the band away from the border gives no band: under
perspective a shaft is the nearest the lens where it enters, the widest there, and the
outermost line that widens it lies on the tissue beyond the silhouette (a fold's rim, a
shadow's edge).

Each (seed, far edge) pair is a candidate band with its own region map: the pixels whose
colour is nearer the band's inside (median over the stations, between a quarter and three
quarters of the width) than either side's (beyond each edge, out to half a width), so that
the band test (`shaft.region_bands.evaluate_bands`: the inside the same all along, the
sides different) and everything after it judge it as they judge a band of the region maps.
A caller may make that map otherwise (`partner_bands`' colour_map, e.g. the edge pairs' with
lightness half-weighted) and keep it only across the seed's stretch (along_seed: the far edge
was searched there alone).

Work pixels throughout (as `shaft.regions`).

Example
-------
>>> import numpy as np, cv2
>>> from pencilcal.toolkit.detect.shaft.regions import BoundaryLines
>>> from pencilcal.toolkit.detect.shaft.work import Validity, WorkFrame
>>> img = np.zeros((240, 320, 3), np.uint8); img[:] = (40, 50, 90)            # dark tissue
>>> img[100:130, :] = (35, 38, 42)                                           # a dark shaft
>>> img = cv2.GaussianBlur(img, (0, 0), 2.0)
>>> wf = WorkFrame(img, None, Validity(None, img.shape[:2]), target_px=320)
>>> # the boundary of a dark region above the shaft (n: into that region, upwards)
>>> seed = BoundaryLines(p=np.array([[310.0, 99.5]]), u=np.array([[-1.0, 0.0]]), n=np.array([[0.0, -1.0]]),
...                      lo=np.array([0.0]), hi=np.array([290.0]), support=np.array([290.0]))
>>> lines, pairs, maps = partner_bands(wf, seed, 10.0, 80.0, 15.0, 1.0)
>>> len(pairs.i), round(float(lines.p[1][1] + (160 - lines.p[1][0]) * lines.u[1][1] / lines.u[1][0]), 0)
(1, 130.0)
>>> bool(maps[0][115, 160]), bool(maps[0][60, 160])
(True, False)
"""
from __future__ import annotations

import numpy as np

from pencilcal.toolkit.detect.shaft.regions import Z_999, BoundaryLines, RegionPairs, close_open
from pencilcal.toolkit.geometry.quantiles import median

__all__ = ["partner_bands", "turned_round", "MAX_SEEDS"]

#: Seeds searched per frame, the longest first.
MAX_SEEDS = 6  # (12 gave the same masked-source table at twice the cost)
_SMOOTH_PX = 1.0  # sd of the profile smoothing [work px]
_STEP_PX = 1.0  # profile sample spacing [work px] (the far edge is refitted at full resolution)
_MAX_STATIONS = 40
_REL_STRENGTH = 0.35  # a station supports a far edge whose response is this fraction of the seed's step
_MIN_SUPPORT = 0.5  # ... and a line is a candidate where this fraction of the stations support it
_SLOPES = 21  # slopes tried, over +-tan(largest convergence) (1.5 deg apart at 15 deg)


def _profiles(work, img, P, m, t):
    """All seeds' colours (N, T, C) float32 and observability (N, T) bool at P (S, 2) + t
    (T,) m (2,) (P and m: lists, one per seed; their stations stacked, N in all); img: the
    work frame's colours (h, w, C) float32. All seeds' samples in one remap (each sample is
    its own bilinear read: the same values as seed by seed)."""
    import cv2

    X = np.concatenate([(q[:, None, 0] + t[None, :] * d[0]).astype(np.float32) for q, d in zip(P, m)])
    Y = np.concatenate([(q[:, None, 1] + t[None, :] * d[1]).astype(np.float32) for q, d in zip(P, m)])
    col = cv2.remap(img, X, Y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    col = col.reshape(X.shape + (-1,))
    obs = cv2.remap(work.dist, X, Y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=-1) > 1.0
    return col, obs


def _median0(X):
    """np.median(X, axis=0) of a small (N, C) array, N >= 1 (the same values: the mean of the
    middle two of each sorted column; np.median's overhead is most of its cost here)."""
    Xs = np.sort(X, axis=0)
    n = Xs.shape[0]
    return Xs[(n - 1) // 2] if n % 2 else (Xs[n // 2 - 1] + Xs[n // 2]) / 2


def _far_edges(col, obs, cut, t, st, wmin, wmax, tan_max, noise, narrowing):
    """Per seed, (t0, b, supported (S,) bool) of its outermost far edge, or None (module
    docstring). col (N, T, C), obs (N, T): all seeds' profiles stacked, seed i's rows
    cut[i]:cut[i + 1]; st: each seed's stations (S,); narrowing: per seed, `_far_edge`'s.
    The smoothing, responses, support and its bound are formed for all seeds at once (each
    profile on its own: the same values as seed by seed); the candidates and the choice
    seed by seed (`_far_edge`)."""
    import cv2

    n = len(st)
    out = [None] * n
    N, T, C = col.shape
    jT = np.flatnonzero((t >= wmin) & (t <= wmax))  # the widths searched, as profile indices
    if N == 0 or jT.size == 0:
        return out
    j0 = int(np.searchsorted(t, 0.0))
    k = max(1, int(round(2.0 / _STEP_PX)))
    ok_seed = obs[:, j0 - k] & obs[:, j0 + k]
    r = int(np.ceil(3.0 * _SMOOTH_PX / _STEP_PX))
    # along each profile only (a kernel one row high): a row's values do not depend on its neighbours
    sm = cv2.GaussianBlur(col.reshape(N, T * C) if C == 1 else col, (2 * r + 1, 1), _SMOOTH_PX / _STEP_PX,
                          sigmaY=1e-6, borderType=cv2.BORDER_REPLICATE).reshape(N, T, C)
    proj = np.zeros((N, T), np.float32)
    thr, colours = [None] * n, [None] * n
    for i in range(n):
        a, e = cut[i], cut[i + 1]
        ok = ok_seed[a:e]
        if np.count_nonzero(ok) < 0.5 * (e - a):
            continue
        c_in, c_out = _median0(sm[a:e][ok, j0 + k]), _median0(sm[a:e][ok, j0 - k])
        d0 = c_in - c_out
        step = float(np.linalg.norm(d0))
        if step < Z_999 * noise * np.sqrt(2.0):
            continue
        # (S, T): the response of a step back to the seed's outside colour, per work px (on a
        # fresh copy of the seed's rows, aligned as its own array was: BLAS's path may depend on it)
        proj[a:e] = sm[a:e].copy() @ (-d0 / step)
        # a step of height `step` blurred by the smoothing (sd >= _SMOOTH_PX) peaks at most at
        # step / (sqrt(2 pi) sd)
        thr[i] = max(_REL_STRENGTH * step / (np.sqrt(2 * np.pi) * _SMOOTH_PX), Z_999 * noise / _SMOOTH_PX)
        colours[i] = (c_in, c_out)
    live = [i for i in range(n) if colours[i] is not None]
    if not live:
        return out
    g = np.gradient(proj, _STEP_PX, axis=1)
    sup = np.zeros((N, T), bool)
    for i in live:  # each seed's threshold compared as a scalar, as seed by seed
        sup[cut[i]:cut[i + 1]] = (g[cut[i]:cut[i + 1]] >= thr[i]) & obs[cut[i]:cut[i + 1]]
    # each slope's line through width index j at station s lies at profile index j + off
    bs = np.linspace(-tan_max, tan_max, _SLOPES)
    ds = np.concatenate([s - 0.5 * (s[0] + s[-1]) for s in st])
    off = np.rint(bs[:, None] * ds[None, :] / _STEP_PX).astype(np.intp)  # (slopes, N)
    spans = _supported_spans(sup, jT, np.abs(off).max(0), cut)
    for i in live:
        a, e = cut[i], cut[i + 1]
        if spans[i] is None:  # no line can have the support a candidate needs
            continue
        q_lo, q_hi = spans[i]
        out[i] = _far_edge(sm[a:e], obs[a:e], sup[a:e], g[a:e], off[:, a:e], jT[q_lo:q_hi], t, bs, k, *colours[i],
                           narrowing[i])
    return out


def _far_edge(sm, obs, sup, g, off, jT, t, bs, k, c_in, c_out, narrowing=0):
    """(t0, b, supported (S,) bool) of one seed's outermost far edge, or None: of its
    candidate lines (`_candidates`) at the widths jT, the outermost whose band is of the
    seed's inside material at its far rim; of the slopes that find it (within 2 px), the
    strongest. narrowing: +1 (-1) where the band must not widen with s increasing
    (decreasing): None where the far edge does (`partner_bands`' from_border); 0 for no
    such rule."""
    S, T = sup.shape
    cands = _candidates(obs, sup, g, off, jT, S, T)
    if not cands:
        return None
    same = _same_inside(sm, obs, np.array([c[3] for c in cands]), k, c_in, c_out)
    cands = [(t[j], resp, bs[a], jf, hit) for (j, resp, a, jf, hit), ok in zip(cands, same) if ok]
    if not cands:
        return None
    far = max(c[0] for c in cands)
    t0, _, b, _, hit = max((c for c in cands if c[0] >= far - 2.0), key=lambda c: c[1])
    # under perspective a band entering the view narrows away from the border (the part there
    # is the nearest the lens) or keeps its width: an outermost line that widens it lies on
    # the tissue beyond the silhouette (a fold's rim, a shadow's edge). The silhouette is then
    # no sure candidate (against a shadow darker than the shaft its step has the other sign),
    # and a line further in may cross from it to the fold: no far edge
    if narrowing * b > 1e-12:
        return None
    return t0, b, hit


def _supported_spans(sup, jT, reach, cut):
    """Per seed (rows cut[i]:cut[i + 1] of sup (N, T)), the range [q_lo, q_hi) of the width
    indices jT (Q,) where a line can be a candidate, or None: a candidate has support at
    `_MIN_SUPPORT` of at least half the seed's S stations, and a line through jT[q] meets
    station s within reach[s] (its largest slope offset) of jT[q], so at most as many
    stations support it as have support there (an exact bound, from one cumulative sum)."""
    N, T = sup.shape
    cs = np.zeros((N, T + 1), np.int32)
    np.cumsum(sup, axis=1, out=cs[:, 1:])
    hi = np.minimum(jT[None, :] + reach[:, None] + 1, T)
    lo = np.clip(jT[None, :] - reach[:, None], 0, T)
    rows = np.arange(N)[:, None]
    there = (cs[rows, hi] > cs[rows, lo]).astype(np.int32)
    bound = np.add.reduceat(there, np.asarray(cut[:-1]), axis=0)  # (seeds, Q)
    out = []
    for i in range(len(cut) - 1):
        can = np.flatnonzero(bound[i] >= _MIN_SUPPORT * 0.5 * (cut[i + 1] - cut[i]))
        out.append(None if can.size == 0 else (int(can[0]), int(can[-1]) + 1))
    return out


def _candidates(obs, sup, g, off, jT, S, T):
    """The candidate far edges [(profile index j at the midline station, mean response,
    slope index, profile indices (S,) of the line clipped to the profile, supported (S,)
    bool)]: per slope, each run of width indices jT (contiguous) whose line has support at
    `_MIN_SUPPORT` of its observed stations (at least half of them), at its strongest mean
    response. Every slope's lines in one gather of row slices."""
    Q = jT.size
    pad = int(np.abs(off).max())
    # profile codes (observed, supported), zero beyond the profile's ends
    code = np.zeros((S, T + 2 * pad), np.uint8)
    code[:, pad:pad + T] = obs.astype(np.uint8) | (sup.astype(np.uint8) << 1)
    win = np.lib.stride_tricks.sliding_window_view(code, Q, axis=1)  # (S, T + 2 pad - Q + 1, Q)
    got = win[np.arange(S)[None, :], off + (pad + int(jT[0]))]  # (slopes, S, Q)
    seen, hit = (got & 1).astype(bool), got >= 2
    n_seen = seen.sum(1)
    good = (hit.sum(1) >= _MIN_SUPPORT * np.maximum(n_seen, 1)) & (n_seen >= 0.5 * S)  # (slopes, Q)
    # each run of candidates (per slope, contiguous widths) at its strongest mean response:
    # the responses of every candidate line at once, then the first maximum of each run
    a, q = np.nonzero(good)
    if a.size == 0:
        return []
    jf = np.clip(jT[q][None, :] + off[a].T, 0, T - 1)  # (S, K)
    # summed over the stations in their order, as a run's block was
    resp = np.where(seen[a, :, q].T, g[np.arange(S)[:, None], jf], 0.0).sum(0) / np.maximum(n_seen[a, q], 1)
    run = np.cumsum(np.r_[True, (a[1:] != a[:-1]) | (q[1:] != q[:-1] + 1)])
    order = np.lexsort((-resp, run))  # stable: of equal responses the first, as argmax
    first = order[np.r_[True, run[order][1:] != run[order][:-1]]]
    return [(int(jT[q[i]]), resp[i], int(a[i]), jf[:, i], hit[a[i], :, q[i]]) for i in first]


def _same_inside(sm, obs, jf, k, c_in, c_out):
    """Per candidate far edge (its profile indices jf (N, S)), whether the colour just
    inside it (k samples inwards) is nearer the seed's inside colour c_in than its outside
    c_out, median over the stations: (N,) bool. A far edge beyond the instrument, on
    tissue, has tissue inside it."""
    rows = np.arange(sm.shape[0])[None, :]
    ji = np.clip(jf - k, 0, sm.shape[1] - 1)
    seen = obs[rows, ji]
    # the median of each candidate's seen stations: NaN sorts last, the middle of the rest
    V = np.sort(np.where(seen[..., None], sm[rows, ji], np.nan), axis=1)
    n = seen.sum(1)
    c = np.take_along_axis(V, np.maximum((n - 1) // 2, 0)[:, None, None], axis=1)[:, 0]  # (N, C)
    ok = n > 0
    return ok & (np.sum((c - c_in) ** 2, axis=1) < np.sum((c - c_out) ** 2, axis=1))


def _band_map(work, img, col, obs, t, t0, b, s, s_mid, colour_map=None):
    """The band's own region map (h, w) uint8 (module docstring); img: the work frame's
    colours (h, w, C) float32; colour_map: None, or the map of the pixels nearer the
    inside's colour than either side's, as `shaft.edge_pairs.colour_map` makes it from
    (img, valid (h, w) uint8, c_in, c1, c2)."""
    import cv2

    w = t0 + b * (s - s_mid)  # (S,)
    tt = t[None, :]
    inner = (tt >= 0.25 * w[:, None]) & (tt <= 0.75 * w[:, None]) & obs
    side1 = (tt <= -2.0) & (tt >= -0.5 * w[:, None]) & obs
    side2 = (tt >= w[:, None] + 2.0) & (tt <= 1.5 * w[:, None]) & obs
    if min(np.count_nonzero(inner), np.count_nonzero(side1), np.count_nonzero(side2)) < 10:
        return None
    # each channel's median as np.median's (`geometry.quantiles.median`: the same values, without
    # np.median's overheads, most of its cost on these few hundred samples)
    c_in, c1, c2 = (np.array([median(v[:, j]) for j in range(v.shape[1])]) for v in (col[k] for k in (inner, side1, side2)))
    if colour_map is not None:
        return colour_map(img, work.valid.view(np.uint8), c_in, c1, c2)
    # |x - c|^2 = |x|^2 - 2 x.c + |c|^2: the |x|^2 common to all three drops out
    d = [cv2.transform(img, (-2.0 * c).reshape(1, -1).astype(np.float32)).reshape(work.shape) + float(c @ c)
         for c in (c_in, c1, c2)]
    B = ((d[0] < np.minimum(d[1], d[2])) & work.valid).astype(np.uint8)
    return close_open(B)  # `shaft.regions.close_open`


def _narrowing(work, P):
    """+1 where the first of a seed's stations P (S, 2) [work px] is nearer the border of the
    view than its last (a band from there must narrow along the seed), else -1."""
    ends = np.clip(np.rint(P[[0, -1]]).astype(int), 0, np.array(work.shape[::-1]) - 1)
    d = work.dist[ends[:, 1], ends[:, 0]]
    return 1 if d[0] <= d[1] else -1


def turned_round(lines):
    """The same straight boundaries (`BoundaryLines`) with their normals turned round
    (n = (-u_y, u_x) into the other side: u, lo and hi reversed), so that `partner_bands`
    searches a band on the side of the region they bound.

    >>> L = BoundaryLines(p=np.array([[0.0, 5.0]]), u=np.array([[1.0, 0.0]]), n=np.array([[0.0, 1.0]]),
    ...                   lo=np.array([2.0]), hi=np.array([9.0]), support=np.array([7.0]))
    >>> R = turned_round(L)
    >>> R.n.tolist(), (R.p + R.lo[:, None] * R.u).tolist(), (R.p + R.hi[:, None] * R.u).tolist()
    ([[-0.0, -1.0]], [[9.0, 5.0]], [[2.0, 5.0]])
    """
    return BoundaryLines(p=lines.p, u=-lines.u, n=-lines.n, lo=-lines.hi, hi=-lines.lo, support=lines.support)


def _within_stretch(B, p, u, lo, hi):
    """The map B (h, w) uint8 kept between the normals to a seed (p + s u, s in [lo, hi],
    work px) at its two ends, zero beyond them (in place)."""
    import cv2

    n = np.array([-u[1], u[0]])
    far = 2.0 * float(np.hypot(*B.shape))
    quad = np.array([p + lo * u - far * n, p + hi * u - far * n, p + hi * u + far * n, p + lo * u + far * n])
    keep = np.zeros_like(B)
    cv2.fillConvexPoly(keep, np.rint(quad).astype(np.int32), 1)
    return cv2.bitwise_and(B, keep, dst=B)


def partner_bands(work, seeds, wmin, wmax, conv_max_deg, noise, max_seeds=MAX_SEEDS, from_border=False,
                  colour_map=None, along_seed=False):
    """Candidate bands from single edges (module docstring).

    Parameters
    ----------
    work : WorkFrame
    seeds : BoundaryLines
        The straight edges to start from (`shaft.regions.boundary_lines`, n into their
        region; the band is searched on the other side), work px.
    wmin, wmax : float [work px]
        The band widths searched.
    conv_max_deg : float
        The largest convergence of the two edges [deg].
    noise : float [grey levels]
        The work frame's noise sd per channel.
    from_border : bool
        The seeds enter the view from its border at their end nearer it (a shaft close to
        the lens): where the far edge widens the band away from that end, no band (under
        perspective the part at the border is the nearest the lens, the widest; a line that
        widens it lies on the tissue beyond the silhouette).
    colour_map : callable, optional
        The band's region map from its three colours (`_band_map`), e.g.
        `shaft.edge_pairs.colour_map`; default the nearest colour in BGR.
    along_seed : bool
        Each band's map kept only across its seed's stretch (between the normals at its
        ends): the far edge was searched there alone, so the band is evidence there alone.

    Returns
    -------
    (BoundaryLines, RegionPairs, list of (h, w) uint8)
        The lines (each pair's seed, reversed: the band on its left, and its far edge),
        the pairs between them, and each pair's region map.
    """
    order = np.argsort(-(seeds.hi - seeds.lo))[:max_seeds]
    tan_max = float(np.tan(np.radians(conv_max_deg)))
    t = np.arange(-0.5 * wmax - 3.0, 1.5 * wmax + 3.0 + _STEP_PX, _STEP_PX)
    img = work.colours
    P_, U_, LO, HI, maps, I, J, W = [], [], [], [], [], [], [], []
    st, Ps = [], []
    for k in order:
        lo, hi = float(seeds.lo[k]), float(seeds.hi[k])
        S = int(np.clip((hi - lo) / 2.0, 8, _MAX_STATIONS))
        st.append(lo + (np.arange(S) + 0.5) * (hi - lo) / S)
        Ps.append(seeds.p[k][None, :] + st[-1][:, None] * seeds.u[k][None, :])
    # across each seed, away from its region: into the band
    col_all, obs_all = _profiles(work, img, Ps, [-seeds.n[k] for k in order], t) if len(order) else (None, None)
    cut = np.r_[0, np.cumsum([len(q) for q in Ps])].tolist()
    narrowing = [_narrowing(work, P) if from_border else 0 for P in Ps]
    far = _far_edges(col_all, obs_all, cut, t, st, wmin, wmax, tan_max, noise, narrowing) if len(order) else []
    for i, (k, s, P, got) in enumerate(zip(order, st, Ps, far)):
        p, u, lo, hi = seeds.p[k], seeds.u[k], float(seeds.lo[k]), float(seeds.hi[k])
        m = -seeds.n[k]
        if got is None:
            continue
        col, obs = col_all[cut[i]:cut[i + 1]], obs_all[cut[i]:cut[i + 1]]
        t0, b, hit = got
        s_mid = 0.5 * (s[0] + s[-1])
        B = _band_map(work, img, col, obs, t, t0, b, s, s_mid, colour_map)
        if B is None:
            continue
        if along_seed:
            B = _within_stretch(B, p, u, lo, hi)
        # the seed reversed: the band on its left (n = (-u_y, u_x) into it)
        us, ls, hs = -u, -hi, -lo
        q0 = p + s_mid * u + t0 * m
        uf = u + b * m
        uf = uf / np.linalg.norm(uf)
        uf = uf if (-uf[1] * m[0] + uf[0] * m[1]) < 0 else -uf  # its left towards the seed
        sh = ((P[hit] + (t0 + b * (s[hit] - s_mid))[:, None] * m) - q0) @ uf
        I.append(len(P_))
        P_ += [p, q0]
        U_ += [us, uf]
        LO += [ls, float(sh.min())]
        HI += [hs, float(sh.max())]
        J.append(len(P_) - 1)
        W.append(t0)
        maps.append(B)
    U = np.array(U_).reshape(-1, 2)
    lines = BoundaryLines(p=np.array(P_).reshape(-1, 2), u=U, n=np.stack([-U[:, 1], U[:, 0]], -1) if len(U) else U,
                          lo=np.array(LO), hi=np.array(HI), support=np.array(HI) - np.array(LO))
    pairs = RegionPairs(i=np.array(I, int), j=np.array(J, int), width=np.array(W),
                        overlap=np.minimum(np.array(HI)[I] - np.array(LO)[I], np.array(HI)[J] - np.array(LO)[J])
                        if I else np.zeros(0))
    return lines, pairs, maps
