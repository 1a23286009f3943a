"""Bands between two edges, judged along their length: the third step of `shaft.detector`.

A candidate shaft is a pair of edges (`pairs.EdgePairs`, K pairs, working pixels). Its
cross-section is sampled at stations s (K, S) [px along the bisector]: the level inside
(bins clear of the edges' blur), and beyond each edge. A station is

- *shaft* when both edges are there (the inside differs from both sides by over four
  noise sd, in the same sense: darker or brighter than both) and the inside keeps the
  band's own level (a robust trend along the band: the lighting changes slowly) and shape;
- *neutral* when the inside keeps the band's level but an edge is missing (the shaft
  passes over a background of its own grey);
- *contradicting* when the inside does not keep the band's level: a row of a printed
  board (black and white squares alternate inside it), the paper beyond a shaft's tip.

The band is the run of stations with the largest sum of +1 (shaft), +0.3 (neutral), -1.5
(contradicting) (`assess_bands`); `assess_chords` looks along each band's whole chord
through the image, from border to border, and tells whether the run reaches the border.
`nested_bands` tells which bands lie inside others. Grey levels are the image's own;
noise sd `sig_n` [grey levels]; blur `blur_px` [px].

Example
-------
>>> import numpy as np
>>> best_segment(np.array([[-1.0, 2.0, 3.0, -4.0, 1.0]]))
(array([1]), array([2]), array([5.]))
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pencilcal.toolkit.detect.edges import masked_median
from pencilcal.toolkit.detect.working import to_raw_points, to_raw_smooth, to_working

__all__ = ["BandAssessment", "BandChords", "assess_bands", "assess_chords", "best_segment", "border_polygon",
           "nested_bands"]

_N_OUT, _N_IN = 4, 12  # cross-section bins beyond each edge and inside the band
_W_SHAFT, _W_NEUTRAL, _W_CONTRA = 1.0, 0.3, -1.5  # station scores: shaft, neutral, contradicting


@dataclass(frozen=True, eq=False)
class BandAssessment:
    """The stations of K bands (`assess_bands`) and each band's run of stations.

    Attributes
    ----------
    i, j : (K,) int
        First and last station of the run (inclusive).
    best : (K,)
        The run's score (sum of the station scores).
    n_shaft : (K,) int
        Shaft stations in the run.
    contra : (K,)
        Fraction of the run's valid stations that contradict the band.
    one_sided : (K,)
        Fraction of the run's valid stations where exactly one edge is seen.
    bg, glare : (K,) or None
        Mean fraction of background-like bins inside, and fraction of shaft stations with a
        highlight inside, over the run's shaft stations (None for a coarse look).
    dark : (K,) bool
        The shaft darker than its surroundings at most of the run's shaft stations.
    shaft : (K, S) bool
        Shaft stations.
    in_img : (K, S) bool
        Stations whose inside bins lie in the image.
    """

    i: np.ndarray
    j: np.ndarray
    best: np.ndarray
    n_shaft: np.ndarray
    contra: np.ndarray
    one_sided: np.ndarray
    bg: np.ndarray | None
    glare: np.ndarray | None
    dark: np.ndarray
    shaft: np.ndarray
    in_img: np.ndarray


@dataclass(frozen=True, eq=False)
class BandChords:
    """`assess_bands` along each band's whole chord through the image (`assess_chords`).

    q: the `BandAssessment`; s (K, S) [px] the stations along the bisector; step (K,) [px]
    their spacing; lo_run, hi_run (K,) [px] the run along the bisector; touch (K,) bool:
    the run reaches the image border.
    """

    q: BandAssessment
    s: np.ndarray
    step: np.ndarray
    lo_run: np.ndarray
    hi_run: np.ndarray
    touch: np.ndarray


def _band_profiles(img, camera, pr, s, blur_px, n_in=_N_IN):
    """Cross-sections of bands at along positions s (K, S): (K, S, U) grey levels, _N_OUT
    bins beyond edge a (outer first), n_in inside, _N_OUT beyond edge b; valid (K, S) (all
    bins inside the image, edges not crossed), valid_in (K, S) (the inside bins are) and
    in_img (K, S) (the inside bins are in the image, whether or not the edges have crossed).
    With a valid region (`image.GrayImage.region`) "in the image" means in its interior.

    Inside, the bins keep max(0.1 w, 2 blur_px) (at most 0.4 w) away from the edges;
    outside they run from 2 blur_px + 1 to that plus max(0.3 w, 4) px beyond them, so that
    neither side reads the blur of an edge, however thin the band. The bins are placed on
    the straight raw segment between the two edge points (exact raw points), which is as
    good as the curved image of the working cross-section over a band's width.
    """
    A, B, w = pr.edge_points(s)
    w = w * np.sign(pr.signed_width_at(0.5 * (pr.lo + pr.hi)))[:, None]  # > 0 until the edges cross
    Ar, Br = to_raw_smooth(camera, A), to_raw_smooth(camera, B)
    wp = np.maximum(w, 1e-6).astype(np.float32)
    d_in = np.minimum(np.maximum(0.1 * wp, 2.0 * blur_px), 0.4 * wp)
    d0 = np.float32(2.0 * blur_px + 1.0)
    d1 = d0 + np.maximum(0.3 * wp, 4.0)
    q_out = np.linspace(0.0, 1.0, _N_OUT, dtype=np.float32)
    q_in = np.linspace(0.0, 1.0, n_in, dtype=np.float32)
    out = (d0 + q_out * (d1 - d0)[..., None]) / wp[..., None]
    f = np.concatenate([-out[..., ::-1], (d_in[..., None] + q_in * (wp - 2 * d_in)[..., None]) / wp[..., None],
                        1.0 + out], -1)  # (K, S, U) along A -> B
    Ar, Br = Ar.astype(np.float32), Br.astype(np.float32)
    dx, dy = (Br - Ar)[..., 0], (Br - Ar)[..., 1]
    X = Ar[..., 0, None] + f * dx[..., None]
    Y = Ar[..., 1, None] + f * dy[..., None]
    H, W = img.shape
    with np.errstate(invalid="ignore"):
        inside = (X >= 0) & (X <= W - 1) & (Y >= 0) & (Y <= H - 1)
    if getattr(img, "region", None) is not None:
        inside &= img.in_region(X, Y)  # the valid region's boundary is the border of the view
    ok = w > 0
    in_img = np.all(inside[..., _N_OUT:_N_OUT + n_in], -1)
    valid_in = in_img & ok
    valid = np.all(inside, -1) & ok
    X[~inside] = 0.0
    Y[~inside] = 0.0
    return img.sample(X, Y), valid, valid_in, in_img


@dataclass(frozen=True, eq=False)
class _Stations:
    """Per-station measures of band cross-sections (K, S): I (inside level), Oa, Ob (levels
    beyond each edge), C (the smaller contrast), edge (both edges there), one (exactly one),
    dark (the inside darker); bg, glare only for a full look."""

    I: np.ndarray
    Oa: np.ndarray
    Ob: np.ndarray
    C: np.ndarray
    edge: np.ndarray
    one: np.ndarray
    dark: np.ndarray
    bg: np.ndarray | None = None
    glare: np.ndarray | None = None


def _background_like(pin, I, Oa, Ob, C, dark):
    """(bg, glare) (K, S): the fraction of the inside bins pin (K, S, n_in) that look like the
    background, and whether there is a highlight inside.

    For a dark station (mirrored for a bright one) a bin within half the contrast of the
    outside level is background-like, except on the flanks of a highlight (a bin brighter
    than the outside by half the contrast: glare); on a bright station a bin darker than
    the outside by half the contrast counts too. A specular stripe and its flanks excepted.
    """
    sign = np.where(dark, 1.0, -1.0).astype(np.float32)
    O = np.where(dark, 0.5 * (Oa + Ob), -0.5 * (Oa + Ob))
    pi = sign[..., None] * pin
    half = 0.5 * np.maximum(C, 1e-9)[..., None]
    like = np.abs(pi - O[..., None]) < half
    beyond = pi > O[..., None] + half
    glare = beyond & dark[..., None]
    near = glare.copy()
    for k in (1, 2):
        near[..., k:] |= glare[..., :-k]
        near[..., :-k] |= glare[..., k:]
    bg = np.mean((like & ~near) | (beyond & ~dark[..., None]), -1)
    shine = (pi < (sign * I)[..., None] - half) & ~dark[..., None]
    return bg, np.any(glare | shine, -1)


def _stations(prof, valid, sig_n, full=True):
    """Per-station measures (`_Stations`) of band cross-sections (K, S, U): edge means both
    edges are there, the inside darker or brighter than both sides by over 4 noise sd."""
    n_in = prof.shape[-1] - 2 * _N_OUT
    pa = np.sort(prof[..., :_N_OUT], -1)
    pb = np.sort(prof[..., _N_OUT + n_in:], -1)
    pin = prof[..., _N_OUT:_N_OUT + n_in]
    h, hi = (_N_OUT - 1) // 2, _N_OUT // 2
    Oa, Ob = 0.5 * (pa[..., h] + pa[..., hi]), 0.5 * (pb[..., h] + pb[..., hi])
    ps = np.sort(pin, -1)
    I = 0.5 * (ps[..., (n_in - 1) // 2] + ps[..., n_in // 2])
    c_e = max(4.0 * sig_n, 6.0)
    Ea, Eb = I - Oa, I - Ob
    dark = (Ea < 0) & (Eb < 0)
    bright = (Ea > 0) & (Eb > 0)
    edge = valid & (dark | bright) & (np.abs(Ea) >= c_e) & (np.abs(Eb) >= c_e)
    one = valid & ((np.abs(Ea) >= c_e) != (np.abs(Eb) >= c_e))  # exactly one edge there
    C = np.minimum(np.abs(Ea), np.abs(Eb))
    if not full:
        return _Stations(I=I, Oa=Oa, Ob=Ob, C=C, edge=edge, one=one, dark=dark)
    bg, glare = _background_like(pin, I, Oa, Ob, C, dark)
    return _Stations(I=I, Oa=Oa, Ob=Ob, C=C, edge=edge, one=one, dark=dark, bg=bg, glare=glare)


def _level_trend(I, s, edge, C, sig_n, iters=3):
    """Robust quadratic trend of the inside level along each band (K, S), from its edge
    stations (the lighting changes slowly along a shaft, by a fifth towards a bright corner);
    returns (trend (K, S), tol (K,)): a station keeps the band's level when within tol of the
    trend (3 noise sd, or 0.35 of the band's median contrast). Beyond the edge stations the
    trend is held at its last value, not extrapolated."""
    K = I.shape[0]
    Cm = np.nan_to_num(masked_median(C, edge), nan=0.0)
    tol = np.maximum(3.0 * sig_n, 0.35 * Cm)
    n_e = edge.sum(-1)
    s_c = np.sum(np.where(edge, s, 0.0), -1) / np.maximum(n_e, 1)
    span = np.maximum(np.max(np.where(edge, np.abs(s - s_c[:, None]), 0.0), 1), 1.0)
    x = (s - s_c[:, None]) / span[:, None]
    x2 = x * x
    a = np.nan_to_num(masked_median(I, edge), nan=0.0)
    b = np.zeros(K)
    c = np.zeros(K)
    xp = [x**p for p in range(5)]
    for _ in range(iters):
        use = edge & (np.abs(I - (a[:, None] + b[:, None] * x + c[:, None] * x2)) <= tol[:, None])
        wv = use.astype(float)
        wI = wv * I
        m = [np.sum(wv * xp[p], -1) for p in range(5)]
        r = [np.sum(wI * xp[p], -1) for p in range(3)]
        n = m[0]
        A = np.stack([np.stack([m[0], m[1], m[2]], -1), np.stack([m[1], m[2], m[3]], -1),
                      np.stack([m[2], m[3], m[4]], -1)], -2) + 1e-9 * np.eye(3)
        rv = np.stack(r, -1)
        quad = n >= 12
        lin = (n >= 4) & ~quad
        if np.any(quad):
            sol = np.linalg.solve(A[quad], rv[quad][..., None])[..., 0]
            a[quad], b[quad], c[quad] = sol.T
        if np.any(lin):
            sol = np.linalg.solve(A[lin][:, :2, :2], rv[lin][:, :2, None])[..., 0]
            a[lin], b[lin], c[lin] = sol[:, 0], sol[:, 1], 0.0
    xl = np.min(np.where(edge, x, np.inf), 1)
    xh = np.max(np.where(edge, x, -np.inf), 1)
    xc = np.clip(x, np.where(np.isfinite(xl), xl, 0.0)[:, None], np.where(np.isfinite(xh), xh, 0.0)[:, None])
    return a[:, None] + b[:, None] * xc + c[:, None] * xc * xc, tol


def best_segment(score):
    """Per row of score (K, S), the run [i, j] (inclusive) of largest sum (Kadane through
    prefix sums). Returns i, j, best (K,)."""
    K, S = score.shape
    C0 = np.concatenate([np.zeros((K, 1)), np.cumsum(score, 1)], 1)
    minpref = np.minimum.accumulate(C0[:, :-1], 1)
    gain = C0[:, 1:] - minpref
    j = np.argmax(gain, 1)
    best = gain[np.arange(K), j]
    cols = np.arange(S + 1)[None, :]
    i = np.argmin(np.where(cols <= j[:, None], C0, np.inf), 1)
    return i, j, best


def _consistent(prof, st, trend, tol, n_in):
    """(K, S) bool: stations whose inside keeps the band's level (within tol of the trend)
    and its cross-section: the median shape of the inside over the edge stations that keep
    the level (each station's bins less its level), kept when half its bins are within
    tol."""
    K, S, U = prof.shape
    pin = prof[..., _N_OUT:_N_OUT + n_in] - st.I[..., None]
    lvl_ok = np.abs(st.I - trend) <= tol[:, None]
    ref = st.edge & lvl_ok
    T = masked_median(pin.transpose(0, 2, 1).reshape(K * n_in, S), np.repeat(ref, n_in, 0)).reshape(K, n_in)
    shape_ok = np.mean(np.abs(pin - np.nan_to_num(T)[:, None, :]) <= tol[:, None, None], -1) >= 0.5
    return lvl_ok & shape_ok


def assess_bands(img, camera, pr, s, valid_s, sig_n, blur_px, full=True):
    """Classify the stations s (K, S) [px along] (valid_s (K, S): the real ones) of bands
    `pr` and find each band's run (module docstring). Returns a `BandAssessment`. Without
    `full` (a first, coarse look) the inside has 8 bins and the background and highlight
    measures are left out."""
    n_in = _N_IN if full else 8
    prof, valid_e, valid, in_img = _band_profiles(img, camera, pr, s, blur_px, n_in)
    valid &= valid_s
    st = _stations(prof, valid_e & valid_s, sig_n, full)
    trend, tol = _level_trend(st.I, s, st.edge, st.C, sig_n)
    cons = valid & _consistent(prof, st, trend, tol, n_in)
    shaft = cons & st.edge
    neutral = cons & ~st.edge
    contra = valid & ~cons
    score = np.where(shaft, _W_SHAFT, np.where(neutral, _W_NEUTRAL, np.where(contra, _W_CONTRA, 0.0)))
    i, j, best = best_segment(score)
    # trimmed to stations with evidence for the band
    cols = np.arange(s.shape[1])[None, :]
    pos = (score > 0) & (cols >= i[:, None]) & (cols <= j[:, None])
    has = pos.any(-1)
    i = np.where(has, np.argmax(pos, 1), i)
    j = np.where(has, s.shape[1] - 1 - np.argmax(pos[:, ::-1], 1), j)
    run = (cols >= i[:, None]) & (cols <= j[:, None])
    n_sh = np.sum(run & shaft, -1)
    n_x = np.sum(run & contra, -1)
    n_v = np.sum(run & valid, -1)
    f = np.maximum(n_sh, 1)
    bg = np.sum(np.where(run & shaft, st.bg, 0.0), -1) / f if full else None
    glare = np.sum(run & shaft & st.glare, -1) / f if full else None
    dark = np.sum(run & shaft & st.dark, -1) / f >= 0.5
    one_sided = np.sum(run & valid & st.one, -1) / np.maximum(np.sum(run & valid, -1), 1)
    return BandAssessment(i=i, j=j, best=best, n_shaft=n_sh, contra=n_x / np.maximum(n_v, 1), one_sided=one_sided,
                          bg=bg, glare=glare, dark=dark, shaft=shaft, in_img=in_img & valid_s)


def _chord(pr, polygon):
    """Along-range [lo, hi] (K,) of each band's bisector inside the image (polygon: the
    image border in working px, closed (P, 2)): the crossings nearest the band's centre on
    either side."""
    c = pr.point(0.5 * (pr.lo + pr.hi))  # (K, 2)
    D = pr.D
    q0, q1 = polygon[:-1], polygon[1:]
    e = q1 - q0  # (P, 2)
    # c + s D = q0 + v e  ->  solve per (band, edge)
    det = D[:, None, 0] * (-e[None, :, 1]) - D[:, None, 1] * (-e[None, :, 0])
    rx = q0[None, :, 0] - c[:, None, 0]
    ry = q0[None, :, 1] - c[:, None, 1]
    with np.errstate(divide="ignore", invalid="ignore"):
        sv = (rx * (-e[None, :, 1]) - ry * (-e[None, :, 0])) / det
        vv = (D[:, None, 0] * ry - D[:, None, 1] * rx) / det
    hit = np.isfinite(sv) & (vv >= 0) & (vv <= 1)
    lo = np.max(np.where(hit & (sv < 0), sv, -np.inf), 1)
    hi = np.min(np.where(hit & (sv >= 0), sv, np.inf), 1)
    along_c = np.sum((c - pr.O) * D, -1)
    return along_c + lo, along_c + hi


def border_polygon(camera, W, H):
    """The border of a W x H image in working pixels, a closed polygon (P, 2) (the raw
    border sampled at 48 points a side and undistorted, without a camera the 4 corners)."""
    if camera is None:
        return np.array([[-0.5, -0.5], [W - 0.5, -0.5], [W - 0.5, H - 0.5], [-0.5, H - 0.5], [-0.5, -0.5]])
    n = 48
    xs = np.linspace(0.0, W - 1.0, n)
    ys = np.linspace(0.0, H - 1.0, n)
    raw = np.concatenate([np.stack([xs, 0 * xs], -1), np.stack([0 * ys + W - 1, ys], -1),
                          np.stack([xs[::-1], 0 * xs + H - 1], -1), np.stack([0 * ys, ys[::-1]], -1)])
    work = to_working(camera, raw.reshape(-1, 4)).reshape(-1, 2)
    work = work[np.all(np.isfinite(work), -1)]
    return np.concatenate([work, work[:1]])


def assess_chords(img, camera, pr, polygon, sig_n, blur_px, border_px, max_stations, min_step=0.0, full=True):
    """`assess_bands` at stations along each band's whole chord through the image (from
    border to border along its bisector; `polygon`: `border_polygon`), at most max_stations
    of them, min_step [px] apart. A run reaches the border when it does not stop more than
    border_px [raw px] before the inside of the band leaves the image. Returns `BandChords`."""
    c_lo, c_hi = _chord(pr, polygon)
    c_lo = np.where(np.isfinite(c_lo), c_lo, pr.span_lo)
    c_hi = np.where(np.isfinite(c_hi), c_hi, pr.span_hi)
    step = np.maximum(min_step, (c_hi - c_lo) / (max_stations - 1))
    step = np.maximum(step, 1e-6)
    cnt = np.minimum(np.floor((c_hi - c_lo) / step).astype(int) + 1, max_stations)
    S = int(cnt.max())
    jj = np.arange(S)
    s = c_lo[:, None] + np.minimum(jj[None, :], cnt[:, None] - 1) * step[:, None]
    q = assess_bands(img, camera, pr, s, jj[None, :] < cnt[:, None], sig_n, blur_px, full)
    rows = np.arange(pr.a.size)
    lo_run, hi_run = s[rows, q.i], s[rows, q.j]
    vs = q.in_img  # the image border, not where the edges would cross
    first = np.argmax(vs, 1)
    last = S - 1 - np.argmax(vs[:, ::-1], 1)
    # the gaps between the run's ends and the last stations seen, in raw pixels: border_px
    # is a distance in the image, and a lens that compresses its periphery (a fisheye)
    # stretches it in undistorted pixels by half or more
    along = np.stack([lo_run, s[rows, first], hi_run, s[rows, last]], -1)  # (K, 4)
    pts = to_raw_points(camera, pr.O[:, None, :] + along[..., None] * pr.D[:, None, :])
    gap = np.linalg.norm(pts[:, 0::2] - pts[:, 1::2], axis=-1)  # (K, 2)
    gap = np.where(np.isfinite(gap), gap, np.abs(along[:, 0::2] - along[:, 1::2]))
    touch = np.any(gap <= border_px, -1)
    return BandChords(q=q, s=s, step=step, lo_run=lo_run, hi_run=hi_run, touch=touch)


def nested_bands(pr, lo, hi):
    """(K, K) bool [i, j]: band j lies inside band i (both of j's edges between i's edges,
    1.5 px allowed, at j's centre, which lies within i's run [lo_i, hi_i]), j != i."""
    na, ca, nb, cb = pr.edge_lines
    K = pr.a.size
    q = pr.point(0.5 * (lo + hi))
    ends = []
    for (n, c) in ((na, ca), (nb, cb)):
        lam = -(np.sum(n * q, -1) + c) / np.sum(n * pr.N, -1)
        ends.append(q + lam[:, None] * pr.N)
    pts = np.stack(ends, 1)  # (K, 2, 2)
    ea = np.einsum("id,jkd->ijk", na, pts) + ca[:, None, None]
    eb = np.einsum("id,jkd->ijk", nb, pts) + cb[:, None, None]
    sa = np.sign(np.sum(na * q, -1) + ca)[:, None, None]
    sb = np.sign(np.sum(nb * q, -1) + cb)[:, None, None]
    tol = 1.5
    inside = np.all((ea * sa > -tol) & (eb * sb > -tol), -1)
    along = np.einsum("id,jd->ij", pr.D, q) - np.sum(pr.D * pr.O, -1)[:, None]
    inside &= (along >= lo[:, None]) & (along <= hi[:, None])
    return inside & ~np.eye(K, dtype=bool)
