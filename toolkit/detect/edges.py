"""The edge-profile engine: subpixel edges across lines, robust line fits, honest variances.

Every detector here measures an edge the same way. At *stations* along a line (working
pixels, `working`), the grey-level profile across it is sampled in the raw image
(bilinear, `SAMPLE_STEP_PX` = 0.5 px steps along the normal, through the local Jacobian
of the lens map) and differentiated with a Gaussian-derivative kernel
(`derivative_kernel`); the subpixel edge is the peak of that derivative, refined by a
parabola through the logarithms of the three samples around the maximum (exact for a
Gaussian-blurred step): `edge_profiles`. Each station starts its samples at a different
fraction of a step (golden-ratio sequence), which spreads the ~3e-3 px phase bias of
bilinear resampling instead of letting it turn lines near 0, 45 and 90 deg.

A weighted line fit through the station edges (weights: squared edge strength), with
robust rejection of stations on other structures (beyond 3 robust sd) and the longest run
of supporting stations (`reject_outliers`, `robust_line_fit`), gives the line; its angle
and offset variances come from the scatter of the station edges about it, made honest for
correlated station errors (`fit_variances`).

Conventions: a line is ``[x1, y1, x2, y2]`` [px] with direction d = (p2 - p1) / |p2 - p1|
and normal n = (-d_y, d_x); a station at s [px] along d has its edge at t [px] along n.
Arrays of stations are (M, S): M lines, S stations each.

Example
-------
>>> import numpy as np
>>> from pencilcal.toolkit.detect.image import GrayImage
>>> img = GrayImage(np.where(np.arange(40)[None, :] >= 20, 200, 10).repeat(30, 0).astype(np.uint8))
>>> s = np.linspace(0.0, 20.0, 6)[None, :]          # stations up a vertical line at x = 21: n = +x
>>> p = edge_profiles(img, None, np.array([[21.0, 25.0]]), np.array([[0.0, -1.0]]), s, 2.0,
...                   derivative_kernel(1.0), 1.0)
>>> np.round(p.t, 1).tolist()                                    # the edge at x = 19.5
[[-1.5, -1.5, -1.5, -1.5, -1.5, -1.5]]
"""
from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from pencilcal.toolkit.detect.working import raw_frame

__all__ = [
    "mean_over",
    "SAMPLE_STEP_PX",
    "MIN_STATIONS",
    "REJECT_FLOOR_PX",
    "derivative_kernel",
    "station_counts",
    "stations",
    "EdgeProfiles",
    "edge_profiles",
    "masked_median",
    "relative_weights",
    "weighted_line",
    "best_run",
    "reject_outliers",
    "upper_pairs",
    "theil_sen",
    "robust_line_fit",
    "fit_variances",
    "DEFAULT_GAMMA",
    "linearised",
    "peak_near",
]

# Sampling of the profiles across a line: step along the normal [px]. A Gaussian-derivative
# kernel matched to a ~1 px blurred edge is close to the optimal (matched) filter; the
# log-parabola peak is exact for a Gaussian derivative profile.
SAMPLE_STEP_PX = 0.5
MIN_STATIONS = 6  # fewest stations a line is sampled at, and fewest inliers a fit needs
REJECT_FLOOR_PX = 0.2  # smallest rejection threshold of the robust line fits by default [px]
_SCATTER_FLOOR_PX = 0.01  # smallest per-station scatter [px] the uncertainty may assume
_GOLDEN = 0.6180339887498949  # sample phase of station j: frac(j * golden ratio) of a step
#: The encoding gamma of the frames by default: 8-bit video and JPEG (sRGB, BT.709) store
#: about (linear light)^(1/2.2); 1 says the frames are linear.
DEFAULT_GAMMA = 2.2
#: A linear edge's peak is climbed to from the encoded one's, at most this many samples away
#: (a black shaft's edge, blurred by 2.5 px all told, moves by ~0.7 of that: 1.7 px).
_LINEAR_REACH = 8


def derivative_kernel(sigma):
    """Gaussian-derivative taps at spacing `SAMPLE_STEP_PX`, unit response to a unit slope.

    sigma: sd [px] of the Gaussian. Returns (taps (2r + 1,) float32, r).

    >>> k, r = derivative_kernel(1.0)
    >>> r, k.dtype.name, round(float(np.sum(k * np.arange(-r, r + 1) * SAMPLE_STEP_PX)), 6)
    (6, 'float32', 1.0)
    """
    r = int(np.ceil(3.0 * sigma / SAMPLE_STEP_PX))
    x = np.arange(-r, r + 1) * SAMPLE_STEP_PX
    k = x * np.exp(-0.5 * (x / sigma) ** 2)
    return (k / np.sum(k * x)).astype(np.float32), r


def station_counts(lo, hi, step_px, max_stations, min_stations=MIN_STATIONS):
    """Number of stations (M,) int `step_px` apart over [lo, hi] (M,) [px], within
    [min_stations, max_stations]."""
    return np.clip(np.round((hi - lo) / step_px).astype(int) + 1, min_stations, max_stations)


def stations(lo, hi, cnt):
    """Station positions s (M, S) [px], `cnt` (M,) of them evenly over [lo, hi] (M,) (the
    last repeated to fill a row), and valid (M, S) bool: the real ones."""
    S = int(cnt.max())
    j = np.arange(S)
    valid = j[None, :] < cnt[:, None]
    s = lo[:, None] + np.minimum(j[None, :], cnt[:, None] - 1) * ((hi - lo) / (cnt - 1))[:, None]
    return s, valid


def linearised(values, gamma):
    """Encoded intensities (any shape) [grey levels] back in linear light, float32: the
    power law ``v^gamma`` (clipped at 0), scaled by ``255^(1 - gamma)`` so that 0 and 255
    stay put (a constant factor: no edge moves with it). gamma 1 returns the values.

    Blur and the lens's spread act on linear light: a step blurred and then encoded has the
    steepest gradient on its dark side, off the step; linearised it is back on it.

    >>> [round(float(v), 1) for v in linearised(np.array([0.0, 64.0, 255.0]), 2.2)]
    [0.0, 12.2, 255.0]
    """
    v = np.asarray(values, np.float32)
    if gamma == 1.0:
        return v
    return np.power(np.maximum(v, np.float32(0.0)), np.float32(gamma)) * np.float32(255.0 ** (1.0 - gamma))


def peak_near(g, jm, reach=_LINEAR_REACH):
    """The index (N,) of the local maximum of each row of g (N, T) that the samples jm (N,)
    climb to (the peak found on another response of the same edge: the encoded profile's;
    one sample at a time uphill, at most `reach`), kept one sample inside the row (a
    parabola needs both neighbours). Climbing keeps to the edge jm is on, where the largest
    response nearby could be another's. Also whether each climb ended on a peak within
    `reach` (N,) bool: a response still rising beyond it is led off by something else (a
    highlight beyond a black shaft's edge).

    >>> g = np.exp(-0.5 * ((np.arange(20.0) - 9.3) / 2.0) ** 2)[None]
    >>> [v.tolist() for v in peak_near(g, np.array([7]))]
    [[9], [True]]
    """
    N, T = g.shape
    rr = np.arange(N)
    j = np.clip(jm, 1, T - 2)
    for _ in range(reach + 1):
        c, lo, hi = g[rr, j], g[rr, j - 1], g[rr, j + 1]
        step = np.where((hi > c) & (hi >= lo), 1, np.where(lo > c, -1, 0))
        step[(j + step < 1) | (j + step > T - 2) | (np.abs(j + step - jm) > reach)] = 0
        if not step.any():
            break
        j = j + step
    c = g[rr, j]
    return j, (c >= g[rr, j - 1]) & (c >= g[rr, j + 1])


@dataclass(frozen=True, eq=False)
class EdgeProfiles:
    """The edge across M lines at S stations each (`edge_profiles`); arrays (M, S).

    Attributes
    ----------
    t : (M, S) [working px]
        The derivative's peak, along the normal n = (-u_y, u_x) from the station.
    g : (M, S) [grey levels / px]
        The signed derivative of the profiles as sampled (encoded) at their peak (positive:
        brighter on the +n side).
    strength : (M, S)
        What the peak maximised: g, or |g| for unsigned edges.
    inside : (M, S) bool
        The whole profile lies in the image.
    found : (M, S) bool
        A peak (strength > 0) within the search window.
    profiles : (M, S, T) float32 [grey levels]
        The sampled profiles, from the -n end to the +n end.
    clutter : (M, S) or None
        With a guard band: the largest |g| on the -n side short of the peak, relative to
        the peak's.
    """

    t: np.ndarray
    g: np.ndarray
    strength: np.ndarray
    inside: np.ndarray
    found: np.ndarray
    profiles: np.ndarray
    clutter: np.ndarray | None = None


def _profile_inside(img, rx, ry, jx, jy, lo_r, hi_r):
    """(M, S) bool: the profile from -lo_r to +hi_r [px along the normal] lies in the image
    and, with a valid region (`image.GrayImage.region`), both its ends in the region's
    interior (a field stop's edge is no edge of the scene)."""
    H, W = img.shape
    xa, xb = rx - lo_r * jx, rx + hi_r * jx
    ya, yb = ry - lo_r * jy, ry + hi_r * jy
    inside = ((np.minimum(xa, xb) >= 0) & (np.maximum(xa, xb) <= W - 1)
              & (np.minimum(ya, yb) >= 0) & (np.maximum(ya, yb) <= H - 1))
    if getattr(img, "region", None) is not None:
        inside &= img.in_region(xa, ya) & img.in_region(xb, yb)
    return inside & np.isfinite(rx) & np.isfinite(ry)


def _log_parabola(am, a0, ap):
    """Subpixel offset [samples] of the vertex of the parabola through log(am, a0, ap), 0
    where it has no maximum; also the mask of positive triples and the parabola's second
    difference (the curvature of the log response)."""
    with np.errstate(all="ignore"):
        pos = (am > 0) & (ap > 0) & (a0 > 0)
        lm, l0, lp = (np.log(np.where(pos, x, 1.0)) for x in (am, a0, ap))
        den = lm - 2 * l0 + lp
        off = np.where(pos & (den < 0), 0.5 * (lm - lp) / np.where(den < 0, den, -1.0), 0.0)
    return off, pos, den


def _slope_shift(prof, first, gs, pos, den, sigma_px, search):
    """How far [px] the grey-level slopes beside an edge pull the derivative's peak off it.

    For a blurred step of (signed) height a between ramps of slopes bL, bR the peak lies
    sigma_g^2 (bR - bL) / a from the edge, sigma_g the sd of the response (from the
    log-parabola's curvature `den`). Slopes from the outer 2.5 px of each side of the
    profiles (M, S, T) (the -n side starting at sample `first`); clipped to +-search / 2.
    """
    DT = SAMPLE_STEP_PX
    q = max(int(round(2.5 / DT)), 3)
    tt = (np.arange(q) - (q - 1) / 2.0) * DT
    den_t = np.sum(tt * tt)
    bL = (prof[..., first:first + q] @ tt.astype(np.float32)) / den_t
    bR = (prof[..., -q:] @ tt.astype(np.float32)) / den_t
    with np.errstate(all="ignore"):
        sg2 = np.where(pos & (den < 0), -(DT**2) / np.where(den < 0, den, -1.0), sigma_px**2 + 1.0)
        sg2 = np.clip(sg2, 0.25 * sigma_px**2, 9.0 * sigma_px**2 + 9.0)
        a_step = gs * np.sqrt(2.0 * np.pi * sg2)
        corr = np.where(a_step != 0, sg2 * (bR - bL) / np.where(a_step != 0, a_step, 1.0), 0.0)
    return np.clip(corr, -0.5 * search, 0.5 * search)


def _finite_or_zero(a):
    """`a` with its values that are not finite set to 0 (`a` itself when all are)."""
    fin = np.isfinite(a)
    return a if fin.all() else np.where(fin, a, 0)


def edge_profiles(img, camera, P0, u, s, search, kernel, sigma_px, *, unsigned=False, slope_correction=False,
                  guard_px=0.0, gamma=1.0):
    """The edge across lines at stations along them.

    Parameters
    ----------
    img : GrayImage
        The raw image.
    camera : Camera or None
        Lens model (working pixels are undistorted with one).
    P0 : (M, 2) [working px]
        A point of each line (s = 0).
    u : (M, 2)
        Unit direction of each line.
    s : (M, S) [px]
        Station positions along each line.
    search : float [px]
        The peak is looked for within +-search of the line.
    kernel : (taps, r)
        `derivative_kernel` (float32 taps).
    sigma_px : float [px]
        The kernel's sd (for the slope correction and the clutter gap).
    unsigned : bool
        Take the peak of |derivative| (an edge whose polarity may flip) instead of the
        derivative itself (an edge brighter on the +n side).
    slope_correction : bool
        Correct each peak for the grey-level slopes beside it (`_slope_shift`).
    guard_px : float [px]
        Also sample this far beyond the window on the -n side and report `clutter`: the
        largest |derivative| between there and 2.5 sd of the edge's own blurred response
        (sqrt(2) sigma_px) short of the peak, relative to the peak's (another edge beside
        this one pulls its peak off it).
    gamma : float
        The frames' encoding gamma (`linearised`). Other than 1, the edge is found on the
        sampled profiles as they are (the peak, its strength, `found`, `clutter`) and located
        on them linearised: the peak of their derivative the encoded one's climbs to
        (`peak_near`), refined and slope-corrected there (`t`).

    Returns
    -------
    EdgeProfiles
    """
    DT = SAMPLE_STEP_PX
    kern, r = kernel
    M, S = s.shape
    nx, ny = -u[:, 1], u[:, 0]
    cx = P0[:, 0, None] + s * u[:, 0, None]
    cy = P0[:, 1, None] + s * u[:, 1, None]
    rx, ry, jx, jy = raw_frame(camera, cx, cy, nx[:, None], ny[:, None])
    nw = int(np.ceil(search / DT)) + 1  # window half-width in samples (one beyond search)
    ng = int(np.ceil(guard_px / DT))
    half = nw + r
    t = np.arange(-half - ng, half + 1) * DT
    # each station's samples start at a different fraction of a step: bilinear resampling
    # biases an edge by ~3e-3 px depending on the phase of the samples against the pixel
    # grid; along lines near 0, 45 or 90 deg that phase drifts slowly and the bias would
    # turn the line by ~1e-4 rad. Spread evenly, it averages out instead.
    shift = np.remainder(np.arange(S) * _GOLDEN, 1.0) * DT  # (S,)
    inside = _profile_inside(img, rx, ry, jx, jy, (half + ng) * DT, half * DT)
    ts = t[None, :] + shift[:, None]  # (S, T)
    X = (rx[..., None] + jx[..., None] * ts).astype(np.float32)
    Y = (ry[..., None] + jy[..., None] * ts).astype(np.float32)
    prof = img.sample(_finite_or_zero(X), _finite_or_zero(Y))  # (M, S, T)
    # derivative along +t at the window positions -(nw + ng) .. nw, tap by tap (a handful of
    # vectorised multiply-adds beats a strided matrix product here)
    nwin = 2 * nw + 1 + ng
    g = kern[0] * prof[..., 0:nwin]
    for q in range(1, kern.size):
        g += kern[q] * prof[..., q:q + nwin]
    g2 = g.reshape(-1, nwin)
    a2 = np.abs(g2) if unsigned else g2
    jm = np.argmax(a2[:, ng + 1:-1], -1) + ng + 1  # the peak within +-search
    rr = np.arange(g2.shape[0])
    strength = a2[rr, jm].reshape(M, S).astype(float)
    g_enc = g2[rr, jm].reshape(M, S).astype(float)
    clutter = None
    if ng:
        gap = int(np.ceil(2.5 * np.sqrt(2.0) * sigma_px / DT))
        near = np.arange(nwin)[None, :] <= (jm - gap)[:, None]
        clutter = (np.max(np.where(near, a2, 0.0), -1) / np.maximum(a2[rr, jm], 1e-12)).reshape(M, S)
    lin = prof
    if gamma != 1.0:  # located on linear light (the docstring)
        lin = linearised(prof, gamma)
        g2 = kern[0] * lin[..., 0:nwin]
        for q in range(1, kern.size):
            g2 += kern[q] * lin[..., q:q + nwin]
        g2 = g2.reshape(-1, nwin)
        a2 = np.abs(g2) if unsigned else g2
        jm, top = peak_near(a2, jm)
        strength = np.where(top.reshape(M, S), strength, 0.0)
    am, a0, ap = (a2[rr, jm + o].reshape(M, S).astype(float) for o in (-1, 0, 1))
    gs = g2[rr, jm].reshape(M, S).astype(float)
    jm = jm.reshape(M, S) - ng
    off, pos, den = _log_parabola(am, a0, ap)
    tk = (jm - nw + np.clip(off, -0.5, 0.5)) * DT + shift[None, :]
    if slope_correction:
        tk = tk - _slope_shift(lin, ng, gs, pos, den, sigma_px, search)
    found = (strength > 0) & (a0 > 0) & (np.abs(tk) <= search)
    return EdgeProfiles(t=tk, g=g_enc, strength=strength, inside=inside, found=found, profiles=prof, clutter=clutter)


# ============================================================================ line fits


def masked_median(a, mask):
    """Median of each row of a (M, S) over mask (M, S) (NaN for an empty row); sort-based.

    >>> masked_median(np.array([[1.0, 5.0, 2.0], [3.0, 4.0, 9.0]]), np.array([[1, 1, 1], [0, 0, 0]], bool)).tolist()
    [2.0, nan]
    """
    M, S = a.shape
    cnt = mask.sum(-1)
    if S == 0:
        return np.full(M, np.nan)
    b = np.sort(np.where(mask, a, np.inf), axis=-1)
    r = np.arange(M)
    lo = np.maximum((cnt - 1) // 2, 0)  # cnt <= S: no upper clip needed
    hi = np.minimum(cnt // 2, S - 1)
    with np.errstate(invalid="ignore"):
        med = 0.5 * (b[r, lo] + b[r, hi])
    return np.where(cnt > 0, med, np.nan)


def relative_weights(strength, base):
    """Station weights (M, S): squared edge strength over its median on `base`, 0 elsewhere."""
    w = strength * strength
    return np.where(base, w / np.maximum(np.nan_to_num(masked_median(w, base), nan=1.0), 1e-300)[:, None], 0.0)


def weighted_line(s, t, w, mask):
    """Weighted least-squares lines t = tm + b (s - sm), one per row of (M, S) arrays.

    Returns (sm, tm, b, Sss, W), each (M,): the weighted centroid, the slope, the weighted
    sum of squares of s about sm and the total weight.

    >>> s = np.arange(5.0)[None]; sm, tm, b, Sss, W = weighted_line(s, 1 + 0.5 * s, np.ones((1, 5)), s >= 0)
    >>> float(sm[0]), float(tm[0]), float(b[0])
    (2.0, 2.0, 0.5)
    """
    wm = np.where(mask, w, 0.0)
    W = np.maximum(wm.sum(-1), 1e-300)
    sm = np.sum(wm * s, -1) / W
    tm = np.sum(wm * t, -1) / W
    ds = s - sm[:, None]
    Sss = np.maximum(np.sum(wm * ds * ds, -1), 1e-300)
    b = np.sum(wm * ds * (t - tm[:, None]), -1) / Sss
    return sm, tm, b, Sss, W


def best_run(s, mask, w, max_gap):
    """Keep, per row, the run of stations in mask (M, S) (gaps <= max_gap [px] along s) of
    largest total weight w.

    >>> best_run(np.arange(6.0)[None], np.array([[1, 1, 0, 0, 1, 0]], bool), np.ones((1, 6)), 1.5).tolist()
    [[True, True, False, False, False, False]]
    """
    M, S = mask.shape
    if S == 0:
        return mask
    idx = np.where(mask, np.arange(S), -1)
    prev = np.maximum.accumulate(idx, axis=1)  # last inlier at or before each station
    prev_before = np.concatenate([np.full((M, 1), -1), prev[:, :-1]], 1)
    has_prev = prev_before >= 0
    s_prev = s[np.arange(M)[:, None], np.maximum(prev_before, 0)]
    start = mask & (~has_prev | (s - s_prev > max_gap))
    run = np.cumsum(start, 1) * mask  # 1-based run id of each inlier, 0 elsewhere
    flat = (np.arange(M)[:, None] * (S + 1) + run).ravel()
    tot = np.bincount(flat, np.where(mask, w, 0.0).ravel(), M * (S + 1)).reshape(M, S + 1)
    tot[:, 0] = -1.0
    best = np.argmax(tot, 1)
    return mask & (run == best[:, None])


def reject_outliers(s, t, w, base, inl, floor_px, max_gap=None, iters=5):
    """Robust inliers (M, S) of weighted line fits t ~ s: starting from `inl`, stations of
    `base` whose weighted residual lies within 3 robust sd (at least floor_px [px]) of the
    fit, and with `max_gap` the best run of them (`best_run`), until nothing changes (at
    most `iters` fits)."""
    for _ in range(iters):
        sm, tm, b, Sss, Wt = weighted_line(s, t, w, inl)
        res = t - tm[:, None] - b[:, None] * (s - sm[:, None])
        e_n = res * np.sqrt(w)
        sc = 1.4826 * masked_median(np.abs(e_n), inl)
        thr = np.maximum(3.0 * np.nan_to_num(sc, nan=0.0), floor_px)
        new = base & (np.abs(e_n) <= thr[:, None])
        if max_gap is not None:
            new = best_run(s, new, w, max_gap)
        if np.array_equal(new, inl):
            break
        inl = new
    return inl


@functools.lru_cache(maxsize=None)
def upper_pairs(n):
    """np.triu_indices(n, 1), made once per n (read-only): the pairs (i < j) of n items."""
    i, j = np.triu_indices(n, 1)
    i.flags.writeable = False
    j.flags.writeable = False
    return i, j


def theil_sen(s, t, mask, n_max=160):
    """Per row, the Theil-Sen line (median of the pairwise slopes, then median intercept)
    through the stations in mask (M, S) (at most n_max of them, evenly picked): a start that
    half of the stations can contradict. Returns b, a (M,) with t ~ a + b s; NaN for rows
    with fewer than 3 stations.

    >>> s = np.arange(10.0); t = 2 * s + 1; t[:3] += 50                    # 3 outliers
    >>> b, a = theil_sen(s[None], t[None], np.ones((1, 10), bool)); float(b[0]), float(a[0])
    (2.0, 1.0)
    """
    M = s.shape[0]
    b_out = np.full(M, np.nan)
    a_out = np.full(M, np.nan)
    for m in range(M):
        idx = np.flatnonzero(mask[m])
        if idx.size < 3:
            continue
        if idx.size > n_max:
            idx = idx[np.linspace(0, idx.size - 1, n_max).astype(int)]
        sv, tv = s[m, idx], t[m, idx]
        i, j = upper_pairs(idx.size)
        ds = sv[j] - sv[i]
        good = np.abs(ds) > 1e-9
        if not np.any(good):
            continue
        b = np.median((tv[j] - tv[i])[good] / ds[good])
        b_out[m] = b
        a_out[m] = np.median(tv - b * sv)
    return b_out, a_out


def _seeded_start(s, t, w, base, labels, floor_px):
    """Inliers (1, S) near the line through the best-weighted stretch (`labels`, one row),
    within 3 sd of that line's prediction (its own scatter and the uncertainty of its
    extrapolation) or floor_px: where the evidence comes in far-apart stretches, a
    stretch pulled off the line (a printed bar captured near an instrument's tip) cannot
    tilt the start, however many stations it has."""
    lab = labels[0]
    G = int(lab.max()) + 1 if np.any(lab >= 0) else 0
    if G < 2:
        return None
    wt = np.bincount(lab[lab >= 0], w[0][lab >= 0], G)
    seed = base[0] & (lab == int(np.argmax(wt)))
    if seed.sum() < 4:
        return None
    sm, tm, b, Sss, Wt = weighted_line(s, t, w, seed[None])
    r = t[0] - tm[0] - b[0] * (s[0] - sm[0])
    s02 = max(float(np.sum(w[0][seed] * r[seed] ** 2) / max(seed.sum() - 2, 1)), floor_px**2 / 9.0)
    pred = np.sqrt(s02 * (1.0 / np.maximum(w[0], 1e-12) + 1.0 / Wt[0] + (s[0] - sm[0]) ** 2 / Sss[0]))
    return base & (np.abs(r) <= np.maximum(3.0 * pred, floor_px))[None, :]


def robust_line_fit(s, t, w, base, max_gap=None, floor_px=REJECT_FLOOR_PX, robust_start=False, seed_labels=None):
    """Robust weighted line fits t = tm + b (s - sm), one per row of (M, S) arrays.

    Residuals beyond 3 robust sd (or floor_px [px]) are rejected, then (with max_gap [px])
    the best run of stations with gaps <= max_gap kept (`reject_outliers`). With
    robust_start the first inliers are those near the `theil_sen` line (a stretch of
    stations pulled off the edge by something beside it, up to nearly half of them, cannot
    tilt the start); with seed_labels (1, S) (one row: the stretches of its stations) those
    near the line through its best-weighted stretch, where that leaves at least MIN_STATIONS.

    Returns sm, tm, b, Sss, Wt (M,) (`weighted_line` of the inliers), res (M, S) the
    residuals and inl (M, S) the inliers.
    """
    inl = base
    start = _seeded_start(s, t, w, base, seed_labels, floor_px) if seed_labels is not None else None
    if start is not None and start.sum() >= MIN_STATIONS:
        inl = start
    elif robust_start:
        b0, a0 = theil_sen(s, t, base)
        r0 = t - a0[:, None] - b0[:, None] * s
        sc = 1.4826 * masked_median(np.abs(r0), base)
        thr = np.maximum(3.0 * np.nan_to_num(sc, nan=np.inf), floor_px)
        start = base & (np.abs(r0) <= thr[:, None])
        inl = np.where((start.sum(-1) >= MIN_STATIONS)[:, None], start, base)
    inl = reject_outliers(s, t, w, base, inl, floor_px, max_gap, iters=5)
    sm, tm, b, Sss, Wt = weighted_line(s, t, w, inl)
    res = t - tm[:, None] - b[:, None] * (s - sm[:, None])
    return sm, tm, b, Sss, Wt, res, inl


def _batch_means(rp, wp, n, B, min_blocks):
    """Block-means estimate of s0^2 (M,) from residuals rp and weights wp (M, S) (inliers
    packed to the left, n (M,) of them) in blocks of B (M,) stations; 0 with fewer than
    min_blocks blocks (too few to say anything)."""
    M, S = rp.shape
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
    return np.where(nb >= min_blocks, out, 0.0)


def fit_variances(res, w, inl, Sss, Wt, long_blocks=0, min_rho=0.0):
    """Variances (M,) of the slope and of the offset at the centroid of weighted line fits
    (`weighted_line`: Sss, Wt), from the scatter of the station edges about them (residuals
    res, weights w, inliers inl, all (M, S)), honest when their errors are correlated.

    Textbook: s0^2 / Sxx and s0^2 / W with s0^2 = sum w r^2 / (N - 2) (weights relative).
    Neighbouring stations share pixels, and real edges wander smoothly (texture, shading,
    print), so station errors are correlated and the textbook values are too small. Two
    corrections, the larger wins:

    - AR(1): the textbook value times (1 + rho) / (1 - rho), rho the lag-1 autocorrelation
      of the weighted residuals (clipped to [min_rho, 0.9]); right for short-range
      correlation. A negative rho (errors that alternate, and so average out faster than
      independent ones) lowers the value only with min_rho < 0: clipped at 0, the variance
      of AR(1) station errors of rho -0.1 is 1.15 times too large, and the slope's coverage
      73 % instead of 68 % (synthetic edges, docs/method.md);
    - batch means: the residuals averaged over blocks of B = ceil(1.5 N^(1/3)) neighbouring
      stations; the scatter of the block means (B r_b^2, N / B - 2 degrees of freedom)
      replaces s0^2. It captures correlation over up to B stations (in effect a Bartlett
      window), with no bias from the fit itself (a residual-based Newey-West sum is biased
      low by 25 % here: the residuals of a line fit are orthogonal to the fit's regressors).

    With `long_blocks` > 0 a third estimate uses that many blocks spanning the whole line:
    it sees deviations correlated over a large part of the line (tissue texture beside an
    instrument's edge) at the price of a noisier value. None of them drops below a
    per-station scatter of 0.01 px (the limit of bilinear resampling).

    Returns (var_slope, var_offset), each (M,).
    """
    n = inl.sum(-1)
    dof = np.maximum(n - 2, 1)
    wr = np.where(inl, w * res * res, 0.0)
    s02 = np.maximum(wr.sum(-1) / dof, _SCATTER_FLOOR_PX**2)
    en = np.where(inl, res * np.sqrt(w), 0.0)
    order = np.argsort(~inl, axis=1, kind="stable")  # inliers packed to the left
    en = np.take_along_axis(en, order, 1)
    num = np.sum(en[:, 1:] * en[:, :-1], -1)
    rho = np.clip(num / np.maximum(np.sum(en * en, -1), 1e-300), min_rho, 0.9)
    s_ar = s02 * (1.0 + rho) / (1.0 - rho)
    rp = np.take_along_axis(np.where(inl, res, 0.0), order, 1)
    wp = np.take_along_axis(np.where(inl, w, 0.0), order, 1)
    B = np.maximum(np.ceil(1.5 * np.cbrt(np.maximum(n, 1))), 1).astype(int)
    s_bm = _batch_means(rp, wp, n, B, 5)
    if long_blocks:
        s_bm = np.maximum(s_bm, _batch_means(rp, wp, n, np.maximum(n // long_blocks, 1), long_blocks))
    s2 = np.maximum(s_ar, s_bm)
    return s2 / Sss, s2 / Wt


def mean_over(x, axis, start=0, stop=None):
    """``x[..., start:stop, ...].mean(axis)`` over an axis before x's last (float32 or
    float64): the same values (numpy adds the samples along such an axis one after the other,
    then divides by their count, as intp), as whole-array additions of the slices, without a
    reduction over a middle axis of a few samples (several times its cost).

    >>> x = np.random.default_rng(0).normal(size=(3, 5, 20, 3)).astype(np.float32)
    >>> bool(np.array_equal(mean_over(x, 2, -6), x[:, :, -6:].mean(2)))
    True
    """
    if not 0 <= axis < x.ndim - 1:
        raise ValueError(f"mean_over: axis {axis} is not before the last of {x.ndim}")
    idx = range(x.shape[axis])[start:stop]
    lead = (slice(None),) * axis
    out = x[lead + (idx[0],)].copy()
    for k in idx[1:]:
        out += x[lead + (k,)]
    return np.true_divide(out, np.intp(len(idx)), out=out, casting="unsafe")

