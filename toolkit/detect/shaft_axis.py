"""The axis of a shaft from its two edges: the fourth step of `shafts`.

The edges of a kept band are measured once more at paired stations across the band (at
shaft stations only, each edge point optionally corrected for the grey-level slopes
beside it), each edge is a robust line fit with one offset per polarity
(`class_line_fit`), and the midline is the line through the midpoints of the paired edge
points (`measure_axis`). Its angle and offset uncertainties come from the scatter of those
midpoints about it, with the corrections for correlated errors of `edges.fit_variances`
(short-range AR(1), batch means, and blocks spanning the whole line) and a shared offset
per stretch of one background (`stretch_variances`), so they include what biases the two
edges differently (texture, print crossing the shaft at slightly different places on each
side), while what moves both edges alike (the shift of a gamma-encoded blurred edge
towards its dark side, which flips with the polarity) cancels in the midline.

With a camera the midline is moved onto the plane through the camera centre that bisects
the two planes back-projected from the edges (`plane_bisector`): it contains the
cylinder's axis exactly (the cylinder is symmetric about any plane through its axis, so
its two tangent planes from the camera are mirror images in the plane through the axis).

Positions are working pixels [px]; s along and t across a line.

Example
-------
>>> import numpy as np
>>> s = np.arange(12.0); t = 0.1 * s + np.where(s < 6, 0.0, 2.0)      # two offsets, one slope
>>> b, off, inl = class_line_fit(s, t, np.ones(12), np.ones(12, bool), (s >= 6).astype(int))
>>> round(float(b), 6), {int(k): round(float(v), 6) for k, v in off.items()}, int(inl.sum())
(0.1, {0: 0.0, 1: 2.0}, 12)
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pencilcal.toolkit.detect.edges import (
    MIN_STATIONS,
    REJECT_FLOOR_PX,
    derivative_kernel,
    edge_profiles,
    fit_variances,
    masked_median,
    robust_line_fit,
    theil_sen,
    weighted_line,
)
from pencilcal.toolkit.detect.pairs import EdgePairs, antiparallel_pairs, pair_geometry

__all__ = ["AxisFit", "measure_axis", "class_line_fit", "width_inliers", "stretches", "stretch_variances",
           "plane_bisector"]

_TAU0 = 0.03  # smallest sd of the midline's offset shared along a stretch, per px of sigma_px
_MAX_CLUTTER = 0.25  # largest gradient beside an edge point, relative to its own


@dataclass(frozen=True, eq=False)
class AxisFit:
    """The midline of one band (`measure_axis`): t = tm + b (s - sm) in the frame of the
    bisector of the refitted edges (`pair`, one pair), with the variances of b and of the
    offset at sm [px^2]; `edges` (2, 4) [working px] the refitted edges; n the inlier
    midpoints, over [s_lo, s_hi] [px along]."""

    pair: EdgePairs
    edges: np.ndarray
    sm: float
    tm: float
    b: float
    var_b: float
    var_a: float
    n: int
    s_lo: float
    s_hi: float


def class_line_fit(s, t, w, base, cls, floor_px=REJECT_FLOOR_PX, iters=6):
    """Robust weighted fit t ~ b s + c_class (one slope, one offset per class: the gradient
    peak of a blurred, gamma-encoded edge leans towards its dark side, so an edge seen
    against black print sits apart from the same edge against white paper), one row of
    stations (S,).

    The start is the Theil-Sen line of the class with the most stations (half of them may
    be pulled off by something lying along the edge); then residuals beyond 3 robust sd (at
    least floor_px) are rejected. Classes with fewer than 4 stations are left out. Returns
    (b, offsets dict, inl (S,) bool) or None.
    """
    classes = [c for c in np.unique(cls[base]) if np.sum(base & (cls == c)) >= 4]
    if not classes:
        return None
    ok = base & np.isin(cls, classes)
    big = max(classes, key=lambda c: np.sum(w[ok & (cls == c)]))
    b = theil_sen(s[None], t[None], (ok & (cls == big))[None])[0][0]
    if not np.isfinite(b):
        return None
    inl = ok.copy()
    off = {}
    for it in range(iters):
        r = np.full(s.shape, np.inf)
        for c in classes:
            m = (inl if it else ok) & (cls == c)
            if not np.any(m):
                continue
            if it == 0:
                off[c] = np.median(t[m] - b * s[m])
            sel = ok & (cls == c)
            r[sel] = t[sel] - b * s[sel] - off[c]
        sc = 1.4826 * np.median(np.abs(r[ok & np.isfinite(r)]))
        new = ok & (np.abs(r) <= max(3.0 * sc, floor_px))
        if new.sum() < MIN_STATIONS:
            return None
        inl = new
        # weighted least squares: one slope, class offsets
        num = den = 0.0
        for c in classes:
            m = inl & (cls == c)
            if m.sum() == 0:
                continue
            wc = w[m]
            sc_, tc_ = np.sum(wc * s[m]) / wc.sum(), np.sum(wc * t[m]) / wc.sum()
            num += np.sum(wc * (s[m] - sc_) * (t[m] - tc_))
            den += np.sum(wc * (s[m] - sc_) ** 2)
        if den <= 0:
            return None
        b = num / den
        for c in classes:
            m = inl & (cls == c)
            if m.sum():
                off[c] = np.sum(w[m] * (t[m] - b * s[m])) / w[m].sum()
    return b, off, inl


@dataclass(frozen=True, eq=False)
class _EdgeStations:
    """Both edges of one band measured at paired stations (`_measure_edges`): P0 (2, 2) a
    point, U (2, 2) the direction and n_ab (2, 2) the normal (into the band) of each edge's
    frame; s2, t, g, base, w2 (2, S) the stations along each, the edge across, its signed
    gradient, the usable stations and their weights; both (S,) the stations where both
    edges fit; edges (2, 4) the refitted edges and pair their `EdgePairs`."""

    P0: np.ndarray
    U: np.ndarray
    n_ab: np.ndarray
    s2: np.ndarray
    t: np.ndarray
    g: np.ndarray
    base: np.ndarray
    w2: np.ndarray
    both: np.ndarray
    edges: np.ndarray
    pair: EdgePairs


def _edge_frames(one, pts):
    """Frames of the two edges of the band `one` at the station points pts (S, 2) on its
    bisector: (A, B) (S, 2) the edge points, w (S,) the signed width, P0, U (each edge's
    first point and direction, sampled along its own normal, pointing into the band) and
    s2 (2, S) the stations along each."""
    na, ca, nb, cb = (v[0] for v in one.edge_lines)
    sv = (pts - one.O[0]) @ one.D[0]
    A, B, w = one.edge_points(sv[None, :])
    A, B = A[0], B[0]
    ua = np.array([na[1], -na[0]])
    ub = np.array([nb[1], -nb[0]])
    ua = ua if np.dot(np.array([-ua[1], ua[0]]), B[0] - A[0]) > 0 else -ua
    ub = ub if np.dot(np.array([-ub[1], ub[0]]), A[0] - B[0]) > 0 else -ub
    P0 = np.stack([A[0], B[0]])
    U = np.stack([ua, ub])
    s2 = np.stack([np.sum((A - A[0]) * ua, -1), np.sum((B - B[0]) * ub, -1)])
    return w, P0, U, s2


def _measure_edges(img, camera, one, pts, shaft, search, kernel, sigma_px, slope_correction, guard_px):
    """Both edges of the band `one` measured at the stations pts (S, 2) on its bisector
    where each is seen cleanly (no other edge beside it), each fitted on its own, robustly,
    with one offset per polarity (`class_line_fit`). Returns `_EdgeStations` or None."""
    w, P0, U, s2 = _edge_frames(one, pts)
    n_ab = np.stack([-U[:, 1], U[:, 0]], -1)
    p = edge_profiles(img, camera, P0, U, s2, search, kernel, sigma_px, unsigned=True,
                      slope_correction=slope_correction, guard_px=guard_px)
    t, g = p.t, p.g
    a = np.abs(g)
    base = p.inside & p.found & (a > 0) & (p.clutter <= _MAX_CLUTTER) & (w[0] * np.sign(np.median(w[0])) > 0)[None, :]
    med = masked_median(a, base & shaft[None, :])
    base &= a >= 0.35 * np.nan_to_num(med, nan=np.inf)[:, None]
    w2 = np.where(base, a * a, 0.0)
    w2 = w2 / np.maximum(np.nan_to_num(masked_median(w2, base), nan=1.0), 1e-300)[:, None]
    ends, inl = [], []
    for e in range(2):
        fit = class_line_fit(s2[e], t[e], w2[e], base[e], (g[e] > 0).astype(int))
        if fit is None:
            return None
        b_e, off_e, inl_e = fit
        # the edge line: the offset of its best-seen class
        c0 = max(off_e, key=lambda c: np.sum(w2[e][inl_e & ((g[e] > 0) == c)]))
        s_e = s2[e][inl_e]
        q1 = P0[e] + s_e.min() * U[e] + (off_e[c0] + b_e * s_e.min()) * n_ab[e]
        q2 = P0[e] + s_e.max() * U[e] + (off_e[c0] + b_e * s_e.max()) * n_ab[e]
        ends.append(np.r_[q1, q2])
        inl.append(inl_e)
    both = inl[0] & inl[1] & shaft
    if both.sum() < MIN_STATIONS:
        return None
    edges = np.stack(ends)
    pair = pair_geometry(*antiparallel_pairs(edges, np.array([0]), np.array([1])))
    return _EdgeStations(P0=P0, U=U, n_ab=n_ab, s2=s2, t=t, g=g, base=base, w2=w2, both=both, edges=edges, pair=pair)


def _left_out_shift(es, ms, mt, shaft, sm, tm, b):
    """(db, da): how far the line through the stations the robust fits left out (unless far
    off: within 2 px of the midline) lies from the midline t = tm + b (s - sm), in slope and
    in offset at sm; None with fewer than MIN_STATIONS such stations. Where they tell another line (a
    stretch pulled off by something along an edge can outnumber the rest), the difference
    counts as uncertainty."""
    loose = es.base[0] & es.base[1] & shaft
    r_all = mt - tm - b * (ms - sm)
    lo_ = loose & (np.abs(r_all) <= 2.0)
    if lo_.sum() < MIN_STATIONS:
        return None
    wl = np.where(lo_, np.maximum(np.minimum(es.w2[0], es.w2[1]), 1e-12), 0.0)
    sm2, tm2, b2, _, _ = weighted_line(ms[None], mt[None], wl[None], lo_[None])
    return float(b2[0] - b), float(tm2[0] + b2[0] * (sm - sm2[0]) - tm)


def _fit_midline(es, shaft, tau0_px):
    """The midline through the midpoints of the paired edge points of `es` where both edges
    fit, the band was seen as a shaft and the width is not pulled outwards
    (`width_inliers`), with its variances. Returns an `AxisFit` or None."""
    P0, U, n_ab, s2, t, g, w2 = es.P0, es.U, es.n_ab, es.s2, es.t, es.g, es.w2
    one = es.pair
    # midpoints of the paired edge points, in the frame of the final bisector
    pa_ = P0[0] + s2[0][:, None] * U[0] + t[0][:, None] * n_ab[0]
    pb_ = P0[1] + s2[1][:, None] * U[1] + t[1][:, None] * n_ab[1]
    mid = 0.5 * (pa_ + pb_)
    N, D, O = one.N[0], one.D[0], one.O[0]
    ms = (mid - O) @ D
    mt = mid @ N + one.C[0]
    cls = 2 * (g[0] > 0) + (g[1] > 0)
    both = es.both & width_inliers(ms, np.abs((pb_ - pa_) @ N), es.both, cls)
    if both.sum() < MIN_STATIONS:
        return None
    wa, wb = np.where(both, w2[0], 0.0), np.where(both, w2[1], 0.0)
    wm = np.where(both, 1.0 / (1.0 / np.maximum(wa, 1e-12) + 1.0 / np.maximum(wb, 1e-12)), 0.0)
    wm = wm / np.maximum(np.median(wm[both]), 1e-300)
    sm, tm, b, Sss, Wt, res, inl_m = robust_line_fit(ms[None], mt[None], wm[None], both[None], None, REJECT_FLOOR_PX,
                                                     robust_start=True, seed_labels=stretches(ms, both, cls)[None])
    var_b, var_a = fit_variances(res, wm[None], inl_m, Sss, Wt, long_blocks=8)
    # stretches of one background bias the midline alike (module docstring)
    lab = stretches(ms, inl_m[0], cls)
    s02 = float(np.sum(wm * res[0] ** 2 * inl_m[0]) / max(int(inl_m.sum()) - 2, 1))
    va_re, vb_re, _ = stretch_variances(ms, res[0], wm, lab, float(sm[0]), max(s02, 1e-6), tau0_px)
    var_b = np.maximum(var_b, vb_re)
    var_a = np.maximum(var_a, va_re)
    shift = _left_out_shift(es, ms, mt, shaft, sm[0], tm[0], b[0])
    if shift is not None:
        db, da = shift
        var_b = var_b + db * db
        var_a = var_a + da * da
    return AxisFit(pair=one, edges=es.edges, sm=float(sm[0]), tm=float(tm[0]), b=float(b[0]),
                   var_b=float(var_b[0]), var_a=float(var_a[0]), n=int(inl_m.sum()),
                   s_lo=float(ms[inl_m[0]].min()), s_hi=float(ms[inl_m[0]].max()))


def measure_axis(img, camera, pr, k, lo, hi, shaft_at, search, sigma_px, slope_correction):
    """Edges and midline of band k of `pr` from paired stations over its run [lo, hi] [px]
    along its bisector (module docstring).

    Each edge is measured at every station of the run where it is seen cleanly, twice (the
    second time with the search narrowed to 1.5 px around the first fit); the midline is
    the robust line through the midpoints of the stations where both edges fit and the
    band was seen as a shaft (shaft_at(s) -> bool). search, sigma_px [px]: the edge search
    half-width and the Gaussian-derivative sd. Returns an `AxisFit` or None.
    """
    kernel = derivative_kernel(sigma_px)
    guard_px = 3.0 * sigma_px + 1.0
    L = hi - lo
    step = max(2.5, L / 300.0)
    S = int(np.floor(L / step)) + 1
    if S < MIN_STATIONS:
        return None
    sv = lo + step * np.arange(S)
    shaft = shaft_at(sv)
    if shaft.sum() < MIN_STATIONS:
        return None
    one = pr.take(np.array([k]))
    pts = one.O[0] + sv[:, None] * one.D[0]  # station points on the bisector
    for it in range(2):
        es = _measure_edges(img, camera, one, pts, shaft, search if it == 0 else min(search, 1.5), kernel,
                            sigma_px, slope_correction, guard_px)
        if es is None:
            return None
        one = es.pair
    return _fit_midline(es, shaft, _TAU0 * sigma_px)


def width_inliers(s, w, use, cls, floor=0.25, iters=4):
    """Stations whose width w (N,) [px] is not above the band's lower envelope
    w ~ c_class + k s (one offset per class with MIN_STATIONS stations or more, one slope) by more than
    3 robust sd (at least `floor` px).

    Something dark lying along a dark shaft's silhouette (a printed bar under or beside it),
    or bright along a bright one, merges with it and pulls that edge outwards: the band
    looks wider there, never narrower. The envelope is fitted to the narrower half of the
    stations (twice refitted), so that such a stretch cannot carry it, however long it is.
    Returns (N,) bool.
    """
    ok = use.copy()
    classes = [c for c in np.unique(cls[use]) if np.sum(use & (cls == c)) >= MIN_STATIONS]
    if not classes:
        return ok
    ok &= np.isin(cls, classes)
    sel = ok.copy()
    k = 0.0
    off = {c: np.median(w[ok & (cls == c)]) for c in classes}
    for _ in range(iters):
        # slope within classes, offsets per class, from the selected stations
        num = den = 0.0
        for c in classes:
            m = sel & (cls == c)
            if m.sum() >= 2:
                ds = s[m] - s[m].mean()
                num += np.sum(ds * (w[m] - w[m].mean()))
                den += np.sum(ds * ds)
        k = num / den if den > 0 else 0.0
        r = np.full(w.shape, np.nan)
        for c in classes:
            m = ok & (cls == c)
            m_sel = sel & (cls == c)
            off[c] = np.median(w[m_sel] - k * s[m_sel]) if m_sel.any() else np.median(w[m] - k * s[m])
            r[m] = w[m] - k * s[m] - off[c]
        # the narrower half of each class
        sel = ok.copy()
        for c in classes:
            m = ok & (cls == c)
            sel[m] = r[m] <= np.median(r[m])
    lower = r[sel]
    sc = 1.4826 * 2.0 * np.median(np.abs(lower - np.median(lower))) if lower.size else 0.0
    keep = ok & (r <= max(3.0 * sc, floor))
    # a stretch widened by a fraction of a pixel shows in the running median of 9 stations
    idx = np.flatnonzero(ok)
    idx = idx[np.argsort(s[idx], kind="stable")]
    if idx.size >= 9:
        from scipy.ndimage import median_filter

        rm = median_filter(r[idx], size=9, mode="nearest")
        keep[idx[rm > max(3.0 * sc / 3.0, 0.5 * floor)]] = False
    return keep


def stretches(s, use, cls, gap_steps=3.0):
    """Labels (N,) of the stretches of stations `use` (sorted by s): runs of one class
    (`cls`: which way each edge turns, i.e. what lies behind the shaft on either side)
    without gaps over gap_steps station spacings; -1 outside `use`.

    >>> stretches(np.arange(6.0), np.ones(6, bool), np.array([0, 0, 1, 1, 1, 0])).tolist()
    [0, 0, 1, 1, 1, 2]
    """
    lab = np.full(s.shape, -1)
    idx = np.flatnonzero(use)
    if idx.size == 0:
        return lab
    idx = idx[np.argsort(s[idx], kind="stable")]
    ds = np.diff(s[idx])
    step = float(np.median(ds)) if ds.size else 1.0
    new = np.r_[True, (cls[idx][1:] != cls[idx][:-1]) | (ds > gap_steps * step)]
    lab[idx] = np.cumsum(new) - 1
    return lab


def stretch_variances(s, res, w, lab, s0, s02, tau0):
    """Variances of the slope and of the value at s0 of a weighted line fit (weights w,
    residuals res) when each stretch (`lab` >= 0) shares an unknown offset of sd tau (what
    lies behind the shaft biases the two edges' gradient peaks differently, by the same
    amount all along a stretch; a bias that looks like a tilt of the line to the residuals
    when the stretches are few) and the stations have independent errors of variance
    s02 / w.

    tau^2 comes from the scatter of the stretches' mean residuals (method of moments, G - 2
    degrees of freedom), never below tau0^2. Sandwich covariance of the weighted fit:
    A^-1 + tau^2 A^-1 (sum_c u_c u_c^T) A^-1, A the fit's normal matrix, u_c its rows summed
    over stretch c. Returns var_a, var_b, tau.
    """
    sel = lab >= 0
    if not np.any(sel):
        return 0.0, 0.0, 0.0
    G = int(lab.max()) + 1
    lab, x, r, p = lab[sel], s[sel] - s0, res[sel], w[sel] / s02
    P0, P1, Pr = (np.bincount(lab, v, G) for v in (p, p * x, p * r))
    A = np.array([[P0.sum(), P1.sum()], [P1.sum(), np.sum(p * x * x)]])
    Ai = np.linalg.pinv(A)
    tau2 = tau0**2
    if G > 2:
        rbar = Pr / np.maximum(P0, 1e-300)
        tau2 = max(tau2, float((np.sum(rbar**2) - np.sum(1.0 / np.maximum(P0, 1e-300))) / (G - 2)))
    U = np.stack([P0, P1], -1)
    cov = Ai + tau2 * Ai @ (U.T @ U) @ Ai
    return float(cov[0, 0]), float(cov[1, 1]), float(np.sqrt(tau2))


def plane_bisector(camera, pr):
    """Bisecting line (N, C) (K, 2), (K,) in undistorted pixels of the two planes through the
    camera centre that the edges of the pairs `pr` back-project to (see the module
    docstring), oriented as the image bisector."""
    K = np.asarray(camera.K, float)
    K2, k = K[:2, :2], K[:2, 2]
    K2inv = np.linalg.inv(K2)
    na, ca, nb, cb = pr.edge_lines
    # interior point: the image bisector at the overlap centre
    q = pr.point(0.5 * (pr.lo + pr.hi))
    xq = np.concatenate([(q - k) @ K2inv.T, np.ones((q.shape[0], 1))], -1)

    def plane(n, c):
        m = np.concatenate([n @ K2, (np.sum(n * k, -1) + c)[:, None]], -1)  # m . (x, 1) = 0
        m /= np.linalg.norm(m, axis=-1, keepdims=True)
        return m * np.where(np.sum(m * xq, -1) < 0, -1.0, 1.0)[:, None]

    m = plane(na, ca) - plane(nb, cb)
    # back to pixels: m[:2] . K2^-1 (p - k) + m[2] = 0
    Np = m[:, :2] @ K2inv
    Cp = m[:, 2] - np.sum(Np * k, -1)
    nrm = np.linalg.norm(Np, axis=-1)
    Np, Cp = Np / nrm[:, None], Cp / nrm
    # same orientation as the image bisector
    flip = np.sum(Np * pr.N, -1) < 0
    return np.where(flip[:, None], -Np, Np), np.where(flip, -Cp, Cp)
