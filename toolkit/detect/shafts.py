"""Instrument shafts: the two long edges of a cylinder, their axis and apparent width.

A rigid instrument's shaft is a cylinder. Its image is a band bounded by two long, straight
edges (in undistorted pixels) that converge slightly under perspective towards the far end
(by more than 10 degrees on close-range endoscope frames); the image of its axis lies between
them. What tells a shaft from the other bands of a scene is not its grey level against its
surroundings (a grey metal shaft is darker than white paper and brighter than black print,
so its edges flip polarity along their length) but the band itself: a cylinder looks the
same all along its length (its shading depends only on the angle around its axis), whatever
lies behind it, it is seen from the image border (an instrument enters the view from
outside) to its tip, and both its edges end where it ends. `detect_shafts` therefore works
with unsigned edges and judges whole bands:

1. *proposals*: a line detector (LSD by default) on a reduced copy of the image (fine texture
   averages out, the shaft's edges do not), fragments undistorted and grouped along lines
   *whatever their polarity* (lines.merge_collinear on unsigned directions), gaps allowed;
   the groups with enough fragment support are the line hypotheses;
2. *edges*: the hypotheses that have a partner at a shaft's width are refitted at full
   resolution to the peak of the gradient *magnitude* across them (Gaussian-derivative
   profiles at stations along the line, a robust weighted line fit, the best run of
   stations with gaps up to `max_gap_px`), so an edge whose polarity flips is one line;
3. *bands*: pairs of edges, converging by at most `max_convergence_deg`, at a width in
   `width_px_range`, overlapping. The cross-section of each candidate band is sampled at
   stations along its whole chord through the image, from border to border: the level
   inside (bins clear of the edges' blur), and beyond each edge. A station is
   - *shaft* when both edges are there (the inside differs from both sides by over four
     noise sd, in the same sense: darker or brighter than both) and the inside keeps the
     band's own level (a robust linear trend along the band: the lighting changes slowly);
   - *neutral* when the inside keeps the band's level but an edge is missing (the shaft
     passes over a background of its own grey: the polarity flip, a table);
   - *contradicting* when the inside does not keep the band's level: a row of a printed
     board (black and white squares alternate inside it), the paper beyond a shaft's tip.
   The band is the run of stations with the largest sum of +1 (shaft), +0.3 (neutral),
   -1.5 (contradicting): it runs from the shaft's tip to where the shaft leaves the image,
   across polarity flips, and stops where a planar structure stops looking like a band.
   Kept: bands with few contradicting stations (`max_background`), whose cross-section
   holds no strip of background (the gap between two instruments), with both edges seen
   along at least half of `min_length` and, with `from_border`, reaching the image border
   (the margins of a sheet and the rows of a board end inside the view; the gap is measured
   in raw pixels), or, where no band does, clean ones. The score is the length along which
   the band is seen as a shaft. A band inside a wider one that shares an edge with it or
   runs along its axis (the strips beside a specular stripe) gives way to it when the wider
   one is clean and has a highlight.
4. *axis*: the edges of the kept bands are measured once more at paired stations across
   the band (at shaft stations only, each edge point optionally corrected for the grey-level
   slopes beside it), each edge is a robust line fit, and the midline is the line through
   the midpoints of the paired edge points. Its angle and offset uncertainties come from
   the scatter of those midpoints about it, with the corrections for correlated errors of
   lines.py (short-range AR(1), batch means, and blocks spanning the whole line), so they
   include what biases the two edges differently (texture, print crossing the shaft at
   slightly different places on each side), while what moves both edges alike (the
   shift of a gamma-encoded blurred edge towards its dark side, which flips with the
   polarity) cancels in the midline and does not count against it. With a camera the
   midline is moved onto the plane through the camera centre that bisects the two planes
   back-projected from the edges: it contains the cylinder's axis exactly (the cylinder is
   symmetric about any plane through its axis, so its two tangent planes from the camera
   are mirror images in the plane through the axis). Without a camera the image bisector
   is used (exact for a shaft viewed symmetrically; 0.03-0.16 px off in the geometries of
   tests/toolkit/detect/test_shafts.py).

Limits: a shaft seen only over a background of its own grey level, or only in part of its
length without reaching the border (pass ``from_border=False``), is found from what remains;
a band of paper that reaches the image border with a clean cross-section (a sheet running
out of the view) is a shaft candidate too, scored by the length along which both its edges
are seen, so give the width you expect (`width_px_range`) where that can happen.

Conventions as in lines.py: pixels with (0, 0) the centre of the top-left pixel; midlines
and edges in raw pixels, widths and uncertainties in undistorted pixels.

Example
-------
>>> import numpy as np
>>> img = np.full((240, 320), 170, np.uint8)
>>> pts = np.array([[0, 80], [0, 160], [300, 135], [300, 105]], np.int32)   # converging
>>> import cv2; _ = cv2.fillConvexPoly(img, pts, 40)
>>> sh = detect_shafts(cv2.GaussianBlur(img, (0, 0), 1.0), min_length=100)
>>> len(sh), round(float(sh[0].width_px))                  # 55 px at x = 150, plus the fill's rims
(1, 56)
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pencilcal.toolkit.errors import InputError
from pencilcal.toolkit.detect.lines import (
    _DT,
    orient_by_polarity,
    _best_run,
    _check_camera_image,
    _deriv_kernel,
    _fit_variances,
    _Gray,
    _masked_median,
    _pair_geometry,
    _raw_frame,
    _to_raw,
    _to_working,
    _wls,
    detect_raw,
    merge_collinear,
)

__all__ = ["Shaft", "detect_shafts", "estimate_noise"]


@dataclass(frozen=True, eq=False)
class Shaft:
    """One instrument shaft.

    Attributes
    ----------
    midline : (4,) [px]
        Image of the axis ``[x1, y1, x2, y2]`` in raw pixels, over the visible shaft, from
        the wide (near) end to the narrow (far) end.
    width_px : float
        Apparent width across the midline at its centre [undistorted px].
    angle_sigma : float
        sd of the midline's angle [rad] (undistorted), from the scatter of the midpoints of
        the paired edge points about it (module docstring, step 4).
    offset_sigma : float
        sd of its perpendicular position at its centre [px].
    edges : (2, 4) [px]
        The two edges in raw pixels.
    score : float
        Evidence [px]: the length along which the band is seen as a shaft (both edges, the
        shaft's own cross-section).
    ideal_midline : (4,) [px]
        The midline in undistorted pixels.
    convergence_deg : float
        Angle between the two edges [deg].
    polarity : str
        "dark" (shaft darker than its surroundings along most of its length) or "bright".
    """

    midline: np.ndarray
    width_px: float
    angle_sigma: float
    offset_sigma: float
    edges: np.ndarray
    score: float
    ideal_midline: np.ndarray
    convergence_deg: float
    polarity: str

    def to_dict(self) -> dict:
        """The lines.json record: midline, width_px, angle_sigma_deg (INTERFACES.md) + extras."""
        return {
            "midline": [float(v) for v in self.midline],
            "width_px": float(self.width_px),
            "angle_sigma_deg": float(np.degrees(self.angle_sigma)),
            "offset_sigma_px": float(self.offset_sigma),
            "edges": [[float(v) for v in e] for e in self.edges],
            "convergence_deg": float(self.convergence_deg),
            "polarity": self.polarity,
            "score": float(self.score),
        }


_LAPLACE_DIFF = np.array([[1, -2, 1], [-2, 4, -2], [1, -2, 1]], np.float32)


def estimate_noise(image):
    """Standard deviation of white image noise [grey levels] (Immerkaer 1996).

    The image is filtered with the difference of two Laplacians, which cancels structure up
    to second order; sd = sqrt(pi / 2) / 6 * mean |response|. Image edges inflate it
    slightly; textured images more.

    >>> rng = np.random.default_rng(0)
    >>> round(estimate_noise(100 + rng.normal(0, 3, (200, 200))), 1)
    3.0
    """
    import cv2

    g = _Gray(image).src.astype(np.float32)
    if min(g.shape) < 3:
        return 0.0
    r = cv2.filter2D(g, -1, _LAPLACE_DIFF, borderType=cv2.BORDER_REFLECT)[1:-1, 1:-1]
    # edges and texture give a few large responses: the median of |r| (scaled to the mean of
    # a half-normal) resists them
    return float(np.median(np.abs(r)) / 0.6745 / 6.0)


def _noise(img):
    """`estimate_noise` from ten bands of full-resolution rows spread over the image (a
    quarter of a large image: the same value within a few percent, at a fraction of the
    cost)."""
    import cv2

    g = img.src
    H, W = g.shape
    if H * W <= 400_000 or H < 80:
        return estimate_noise(g)
    rows = max(8, H // 40)
    starts = np.unique(np.linspace(0, H - rows, 10).astype(int))
    r = [np.abs(cv2.filter2D(g[s:s + rows].astype(np.float32), -1, _LAPLACE_DIFF)[1:-1, 1:-1]).ravel()
         for s in starts]
    return float(np.median(np.concatenate(r)) / 0.6745 / 6.0)


# ----------------------------------------------------------------------------- proposals


def _unsigned(lines):
    """Lines (M, 4) oriented with d_x > 0 (d_y > 0 when vertical): one direction per line,
    whatever the polarity of its edge."""
    out = np.array(lines, float).reshape(-1, 4)
    d = out[:, 2:] - out[:, :2]
    flip = (d[:, 0] < 0) | ((d[:, 0] == 0) & (d[:, 1] < 0))
    out[flip] = out[flip][:, [2, 3, 0, 1]]
    return out


def _proposals(img, detector, camera, scale, detector_params):
    """Fragments from the detector on a reduced image, in full-resolution working pixels,
    oriented by polarity (lines.orient_by_polarity: brighter on the left)."""
    import cv2

    u8 = img.u8
    H, W = img.shape
    if scale < 1.0:
        small = cv2.resize(u8, (max(int(round(W * scale)), 8), max(int(round(H * scale)), 8)),
                           interpolation=cv2.INTER_AREA)
        sx, sy = W / small.shape[1], H / small.shape[0]
        raw = detect_raw(small, detector, detector_params)
        # pixel centres: x_full + 0.5 = (x_small + 0.5) * s
        raw = (raw + 0.5) * np.array([sx, sy, sx, sy]) - 0.5
    else:
        raw = detect_raw(u8, detector, detector_params)
    L = np.hypot(raw[:, 2] - raw[:, 0], raw[:, 3] - raw[:, 1])
    raw = raw[L >= 8.0]
    raw = orient_by_polarity(img, raw, 1.0 / min(scale, 1.0))[0]
    work = _to_working(camera, raw)
    return work[np.all(np.isfinite(work), -1)]


def _both_ways(lines):
    """Unsigned lines (`_unsigned`) plus, for those within 6 deg of vertical (where that
    orientation turns over), a reversed copy: collinear lines always meet in one direction."""
    work = _unsigned(lines)
    d = work[:, 2:] - work[:, :2]
    near_v = np.abs(d[:, 0]) < np.sin(np.radians(6.0)) * np.hypot(d[:, 0], d[:, 1])
    return np.concatenate([work, work[near_v][:, [2, 3, 0, 1]]])


def _dedupe(lines, support, tol_px=2.0, tol_deg=1.0):
    """Drop lines (M, 4) that repeat a better-supported one (both ends within tol_px of its
    line, directions within tol_deg either way): the near-vertical groups come twice."""
    M = lines.shape[0]
    if M < 2:
        return np.arange(M)
    p1, p2 = lines[:, :2], lines[:, 2:]
    d = p2 - p1
    L = np.maximum(np.hypot(d[:, 0], d[:, 1]), 1e-9)
    u = d / L[:, None]
    n = np.stack([-u[:, 1], u[:, 0]], -1)
    c = np.sum(n * p1, -1)
    par = np.abs(u @ u.T) > np.cos(np.radians(tol_deg))
    d1 = np.abs(p1 @ n.T - c[None, :])  # [j, i]: line j's first end from line i
    d2 = np.abs(p2 @ n.T - c[None, :])
    # ... and mostly within line i's extent
    a1 = p1 @ u.T - np.sum(u * p1, -1)[None, :]  # [j, i] along line i
    a2 = p2 @ u.T - np.sum(u * p1, -1)[None, :]
    lo, hi = np.minimum(a1, a2), np.maximum(a1, a2)
    ov = np.minimum(hi, L[None, :]) - np.maximum(lo, 0.0)
    on = (d1 < tol_px) & (d2 < tol_px) & par & (ov >= 0.5 * np.minimum(L[:, None], L[None, :]))
    order = np.argsort(-support, kind="stable")
    keep = np.ones(M, bool)
    for i in order:
        if keep[i]:
            dup = on[:, i] & keep
            dup[i] = False
            keep[dup] = False
    return np.flatnonzero(keep)


# --------------------------------------------------------------------- edges (unsigned)


def _edge_samples(img, camera, P0, u, s, search, kern, r, sigma_px, slope_correction=False, guard_px=0.0):
    """The edge across lines at stations: P0 (M, 2) a point of each line, u (M, 2) its unit
    direction (working px), s (M, S) station positions along it.

    Profiles across (along n = (-u_y, u_x)) are sampled in the raw image, differentiated
    with the Gaussian-derivative kernel, and the peak of the gradient *magnitude* within
    +-search is located to subpixel precision (log-parabola). Returns t (M, S) the peak's
    offset along n [working px], g (M, S) the signed gradient there (grey levels / px,
    positive: brighter on the +n side), ok (M, S) (profile inside the image, peak within
    the window) and, with guard_px > 0, clutter (M, S): the largest gradient magnitude on
    the -n side between guard_px beyond the window and 2.5 kernel sd (of the edge's own
    blurred response, sqrt(2) sigma_px) short of the peak, relative to the peak's (another
    edge beside this one: a printed bar along an instrument's silhouette pulls its gradient
    peak off it by up to a pixel).
    """
    M, S = s.shape
    nx, ny = -u[:, 1], u[:, 0]
    cx = P0[:, 0, None] + s * u[:, 0, None]
    cy = P0[:, 1, None] + s * u[:, 1, None]
    rx, ry, jx, jy = _raw_frame(camera, cx, cy, nx[:, None], ny[:, None])
    H, W = img.shape
    nk = kern.size
    nw = int(np.ceil(search / _DT)) + 1
    ng = int(np.ceil(guard_px / _DT))
    half = nw + r
    t = np.arange(-half - ng, half + 1) * _DT
    # sample phases spread over the pixel grid (golden-ratio sequence; see lines._refit_pass)
    shift = np.remainder(np.arange(S) * 0.6180339887498949, 1.0) * _DT
    lo_r, hi_r = (half + ng) * _DT, half * _DT
    xa, xb = rx - lo_r * jx, rx + hi_r * jx
    ya, yb = ry - lo_r * jy, ry + hi_r * jy
    inside = ((np.minimum(xa, xb) >= 0) & (np.maximum(xa, xb) <= W - 1)
              & (np.minimum(ya, yb) >= 0) & (np.maximum(ya, yb) <= H - 1))
    inside &= np.isfinite(rx) & np.isfinite(ry)
    ts = t[None, :] + shift[:, None]
    X = (rx[..., None] + jx[..., None] * ts).astype(np.float32)
    Y = (ry[..., None] + jy[..., None] * ts).astype(np.float32)
    prof = img.sample(np.where(np.isfinite(X), X, 0), np.where(np.isfinite(Y), Y, 0))
    nwin = 2 * nw + 1 + ng  # window positions -(nw + ng) .. nw
    g = kern[0] * prof[..., 0:nwin]
    for q in range(1, nk):
        g += kern[q] * prof[..., q:q + nwin]
    g2 = g.reshape(-1, nwin)
    a2 = np.abs(g2)
    jm = np.argmax(a2[:, ng + 1:-1], -1) + ng + 1  # the peak within +-search
    rr = np.arange(g2.shape[0])
    am, a0, ap = (a2[rr, jm + o].reshape(M, S).astype(float) for o in (-1, 0, 1))
    gs = g2[rr, jm].reshape(M, S).astype(float)
    clutter = None
    if ng:
        gap = int(np.ceil(2.5 * np.sqrt(2.0) * sigma_px / _DT))
        cols = np.arange(nwin)[None, :]
        near = cols <= (jm - gap)[:, None]
        clutter = (np.max(np.where(near, a2, 0.0), -1) / np.maximum(a2[rr, jm], 1e-12)).reshape(M, S)
    jm = jm.reshape(M, S) - ng
    with np.errstate(all="ignore"):
        pos = (am > 0) & (ap > 0) & (a0 > 0)
        lm, l0, lp = (np.log(np.where(pos, x, 1.0)) for x in (am, a0, ap))
        den = lm - 2 * l0 + lp
        off = np.where(pos & (den < 0), 0.5 * (lm - lp) / np.where(den < 0, den, -1.0), 0.0)
    tk = (jm - nw + np.clip(off, -0.5, 0.5)) * _DT + shift[None, :]
    if slope_correction:
        # grey-level slopes beside the edge pull the derivative's peak off it: for a blurred
        # step of (signed) height a between ramps of slopes bL, bR the peak lies
        # sigma_g^2 (bR - bL) / a from the edge (lines._refit_pass)
        q = max(int(round(2.5 / _DT)), 3)
        tt = (np.arange(q) - (q - 1) / 2.0) * _DT
        den_t = np.sum(tt * tt)
        bL = (prof[..., ng:ng + q] @ tt.astype(np.float32)) / den_t
        bR = (prof[..., -q:] @ tt.astype(np.float32)) / den_t
        with np.errstate(all="ignore"):
            sg2 = np.where(pos & (den < 0), -(_DT**2) / np.where(den < 0, den, -1.0), sigma_px**2 + 1.0)
            sg2 = np.clip(sg2, 0.25 * sigma_px**2, 9.0 * sigma_px**2 + 9.0)
            a_step = gs * np.sqrt(2.0 * np.pi * sg2)
            corr = np.where(a_step != 0, sg2 * (bR - bL) / np.where(a_step != 0, a_step, 1.0), 0.0)
        tk = tk - np.clip(corr, -0.5 * search, 0.5 * search)
    ok = inside & (a0 > 0) & (np.abs(tk) <= search)
    if ng:
        return tk, gs, ok, clutter
    return tk, gs, ok


def _theil_sen(s, t, mask, n_max=160):
    """Per row, the Theil-Sen line (median of the pairwise slopes, then median intercept)
    through the stations in mask (at most n_max of them, evenly picked): a start that half
    of the stations can contradict. Returns b, a with t ~ a + b s; NaN for rows with fewer
    than 3 stations."""
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
        i, j = np.triu_indices(idx.size, 1)
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
    stretch pulled off the shaft (a printed bar captured near the tip) cannot tilt the
    start, however many stations it has."""
    lab = labels[0]
    G = int(lab.max()) + 1 if np.any(lab >= 0) else 0
    if G < 2:
        return None
    wt = np.bincount(lab[lab >= 0], w[0][lab >= 0], G)
    seed = base[0] & (lab == int(np.argmax(wt)))
    if seed.sum() < 4:
        return None
    sm, tm, b, Sss, Wt = _wls(s, t, w, seed[None])
    r = t[0] - tm[0] - b[0] * (s[0] - sm[0])
    s02 = max(float(np.sum(w[0][seed] * r[seed] ** 2) / max(seed.sum() - 2, 1)), floor_px**2 / 9.0)
    pred = np.sqrt(s02 * (1.0 / np.maximum(w[0], 1e-12) + 1.0 / Wt[0] + (s[0] - sm[0]) ** 2 / Sss[0]))
    return base & (np.abs(r) <= np.maximum(3.0 * pred, floor_px))[None, :]


def _line_fit(s, t, w, base, max_gap=None, floor_px=0.2, robust_start=False, seed_labels=None):
    """Robust weighted line fits t = tm + b (s - sm), one per row: residuals beyond 3 robust
    sd (or floor_px) rejected, then (with max_gap) the best run of stations with gaps <=
    max_gap kept. With robust_start the first inliers are those near the Theil-Sen line
    (a stretch of stations pulled off the edge by something beside it, up to nearly half of
    them, cannot tilt the start). Returns sm, tm, b, Sss, Wt, res, inl."""
    inl = base
    start = _seeded_start(s, t, w, base, seed_labels, floor_px) if seed_labels is not None else None
    if start is not None and start.sum() >= 6:
        inl = start
    elif robust_start:
        b0, a0 = _theil_sen(s, t, base)
        r0 = t - a0[:, None] - b0[:, None] * s
        sc = 1.4826 * _masked_median(np.abs(r0), base)
        thr = np.maximum(3.0 * np.nan_to_num(sc, nan=np.inf), floor_px)
        start = base & (np.abs(r0) <= thr[:, None])
        inl = np.where((start.sum(-1) >= 6)[:, None], start, base)
    for _ in range(5):
        sm, tm, b, Sss, Wt = _wls(s, t, w, inl)
        res = t - tm[:, None] - b[:, None] * (s - sm[:, None])
        e_n = res * np.sqrt(w)
        sc = 1.4826 * _masked_median(np.abs(e_n), inl)
        thr = np.maximum(3.0 * np.nan_to_num(sc, nan=0.0), floor_px)
        new = base & (np.abs(e_n) <= thr[:, None])
        if max_gap is not None:
            new = _best_run(s, new, w, max_gap)
        if np.array_equal(new, inl):
            break
        inl = new
    sm, tm, b, Sss, Wt = _wls(s, t, w, inl)
    res = t - tm[:, None] - b[:, None] * (s - sm[:, None])
    return sm, tm, b, Sss, Wt, res, inl


def _refit_lines(img, camera, lines, *, search, sigma_px, step_px, extend_px, max_gap_px, min_gradient,
                 rel_gradient=0.35, passes=2, max_stations=48, grow=False):
    """Refit lines (M, 4) (working px) to the unsigned edges beside them, growing them
    along the edge while it goes on (each pass looks max(extend_px, L / 4) beyond the ends
    of the run found so far, bridging gaps up to max_gap_px). Returns the refitted lines
    (M, 4) (the run of inlier stations), ok (M,) and the number of inlier stations (M,)."""
    kern, r = _deriv_kernel(sigma_px)
    kern = kern.astype(np.float32)
    P1, P2 = lines[:, :2].copy(), lines[:, 2:].copy()
    M = P1.shape[0]
    ok = np.zeros(M, bool)
    count = np.zeros(M, int)
    todo = np.arange(M)
    for it in range(passes):
        if todo.size == 0:
            break
        p1, p2 = P1[todo], P2[todo]
        d = p2 - p1
        L = np.maximum(np.hypot(d[:, 0], d[:, 1]), 1e-9)
        u = d / L[:, None]
        e = np.maximum(extend_px, 0.25 * L) if (it > 0 and grow) else np.full(L.shape, float(extend_px))
        lo, hi = -e, L + e
        cnt = np.clip(np.round((hi - lo) / step_px).astype(int) + 1, 6, max_stations)
        S = int(cnt.max())
        j = np.arange(S)
        st_valid = j[None, :] < cnt[:, None]
        s = lo[:, None] + np.minimum(j[None, :], cnt[:, None] - 1) * ((hi - lo) / (cnt - 1))[:, None]
        t, g, good = _edge_samples(img, camera, p1, u, s, search, kern, r, sigma_px)
        a = np.abs(g)
        base = good & st_valid & (a >= min_gradient)
        med = _masked_median(a, base)
        base &= a >= rel_gradient * np.nan_to_num(med, nan=np.inf)[:, None]
        w = a * a
        w = np.where(base, w / np.maximum(np.nan_to_num(_masked_median(w, base), nan=1.0), 1e-300)[:, None], 0.0)
        sm, tm, b, Sss, Wt, res, inl = _line_fit(s, t, w, base, max_gap_px)
        n_in = inl.sum(-1)
        good_fit = n_in >= 6
        rows = np.arange(todo.size)
        k1 = np.argmax(inl, 1)
        k2 = S - 1 - np.argmax(inl[:, ::-1], 1)
        s1, s2 = s[rows, k1], s[rows, k2]
        n = np.stack([-u[:, 1], u[:, 0]], -1)
        q1 = p1 + s1[:, None] * u + (tm + b * (s1 - sm))[:, None] * n
        q2 = p1 + s2[:, None] * u + (tm + b * (s2 - sm))[:, None] * n
        # a pass that loses the line keeps the previous one
        upd = good_fit | (it == 0)
        P1[todo[upd]], P2[todo[upd]] = q1[upd], q2[upd]
        ok[todo[upd]] = good_fit[upd]
        count[todo[upd]] = n_in[upd]
        # look again where the window was off-centre, or where the edge runs on past the
        # stations looked at
        dev = np.maximum(np.abs(tm + b * (s1 - sm)), np.abs(tm + b * (s2 - sm)))
        touch = ((k1 <= 1) | (k2 >= cnt - 2)) & grow
        todo = todo[good_fit & ((dev > 0.5 * search) | touch)]
    return np.concatenate([P1, P2], -1), ok, count


def _partnered(E, conv_max, wmin, wmax, min_overlap):
    """Which lines (M, 4) (unsigned) have a possible partner: a nearly parallel line at a
    distance in [wmin, wmax] overlapping it by min_overlap."""
    a, b = _parallel_candidates(E, conv_max, wmax)
    if a.size == 0:
        return np.zeros(E.shape[0], bool)
    pr = _pair_geometry(*_oriented_pairs(E, a, b))
    ok = (pr.width >= 0.7 * wmin) & (pr.width <= 1.2 * wmax + 3.0) & (pr.hi - pr.lo >= min_overlap)
    out = np.zeros(E.shape[0], bool)
    out[a[ok]] = True
    out[b[ok]] = True
    return out


def _parallel_candidates(E, max_conv, max_dist):
    """Index pairs (a, b), a < b, of unsigned lines within max_conv of parallel whose
    centres are within max_dist + half their lengths (KD-tree on doubled angles)."""
    from scipy.spatial import cKDTree

    M = E.shape[0]
    if M < 2:
        return np.zeros(0, int), np.zeros(0, int)
    d = E[:, 2:] - E[:, :2]
    th2 = 2.0 * np.arctan2(d[:, 1], d[:, 0])
    v = np.stack([np.cos(th2), np.sin(th2)], -1)
    r = 2.0 * np.sin(min(max_conv, 1.5))
    pp = cKDTree(v).query_pairs(r, output_type="ndarray")
    if pp.size == 0:
        return np.zeros(0, int), np.zeros(0, int)
    a, b = pp[:, 0], pp[:, 1]
    c = 0.5 * (E[:, :2] + E[:, 2:])
    L = np.hypot(d[:, 0], d[:, 1])
    near = np.linalg.norm(c[a] - c[b], axis=-1) <= max_dist + 0.5 * (L[a] + L[b])
    return a[near], b[near]


def _oriented_pairs(E, a, b):
    """(lines, a, b') for lines._pair_geometry, which wants the two edges of a pair running
    in opposite directions: b' indexes b reversed (rows M.. of the returned lines) where b
    runs along a."""
    M = E.shape[0]
    E2 = np.concatenate([E, E[:, [2, 3, 0, 1]]])
    da, db = E[a, 2:] - E[a, :2], E[b, 2:] - E[b, :2]
    same = np.sum(da * db, -1) > 0
    return E2, a, np.where(same, b + M, b)


def _to_raw_pts(camera, pts):
    return pts if camera is None else camera.distort_pixels(pts)


def _signed_width(pr, along):
    """Width across the bisector at `along` (K,), signed: it changes sign where the edges cross."""
    m = pr.point(along)
    na, ca, nb, cb = pr._lines
    lam_a = -(np.sum(na * m, -1) + ca) / np.sum(na * pr.N, -1)
    lam_b = -(np.sum(nb * m, -1) + cb) / np.sum(nb * pr.N, -1)
    return lam_b - lam_a


# ------------------------------------------------------------------------ band profiles

_N_OUT, _N_IN = 4, 12  # cross-section bins beyond each edge and inside the band


def _edge_points(pr, s):
    """Working points (K, S, 2) of edges a and b across the bisector at along positions
    s (K, S), and the signed width (K, S)."""
    m = pr.O[:, None, :] + s[..., None] * pr.D[:, None, :]
    na, ca, nb, cb = pr._lines
    N = pr.N[:, None, :]
    lam_a = -(np.sum(na[:, None, :] * m, -1) + ca[:, None]) / np.sum(na * pr.N, -1)[:, None]
    lam_b = -(np.sum(nb[:, None, :] * m, -1) + cb[:, None]) / np.sum(nb * pr.N, -1)[:, None]
    return m + lam_a[..., None] * N, m + lam_b[..., None] * N, lam_b - lam_a


def _to_raw_smooth(camera, P, every=4):
    """Raw pixels of working points P (K, S, 2) that vary smoothly along S: exact at every
    `every`-th station (and the last), linear in between (the images of straight lines bend
    by far less than a pixel over a few stations)."""
    if camera is None:
        return P
    S = P.shape[1]
    cols = np.unique(np.r_[np.arange(0, S, every), S - 1])
    sub = camera.distort_pixels(P[:, cols])
    if cols.size == S:
        return sub
    j = np.arange(S)
    k = np.clip(np.searchsorted(cols, j, "right") - 1, 0, max(cols.size - 2, 0))
    k1 = np.minimum(k + 1, cols.size - 1)
    f = ((j - cols[k]) / np.maximum(cols[k1] - cols[k], 1))[None, :, None]
    return sub[:, k] * (1 - f) + sub[:, k1] * f


def _band_profiles(img, camera, pr, s, blur_px, n_in=_N_IN):
    """Cross-sections of bands at along positions s (K, S): (K, S, U) grey levels, _N_OUT
    bins beyond edge a (outer first), n_in inside, _N_OUT beyond edge b; valid (K, S) (all
    bins inside the image, edges not crossed), valid_in (K, S) (the inside bins are) and
    in_img (K, S) (the inside bins are in the image, whether or not the edges have crossed).

    Inside, the bins keep max(0.1 w, 2 blur_px) (at most 0.4 w) away from the edges;
    outside they run from 2 blur_px + 1 to that plus max(0.3 w, 4) px beyond them, so that
    neither side reads the blur of an edge, however thin the band. The bins are placed on
    the straight raw segment between the two edge points (exact raw points), which is as
    good as the curved image of the working cross-section over a band's width.
    """
    A, B, w = _edge_points(pr, s)
    w = w * np.sign(_signed_width(pr, 0.5 * (pr.lo + pr.hi)))[:, None]  # > 0 until the edges cross
    Ar, Br = _to_raw_smooth(camera, A), _to_raw_smooth(camera, B)
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
    ok = w > 0
    in_img = np.all(inside[..., _N_OUT:_N_OUT + n_in], -1)
    valid_in = in_img & ok
    valid = np.all(inside, -1) & ok
    X[~inside] = 0.0
    Y[~inside] = 0.0
    return img.sample(X, Y), valid, valid_in, in_img


def _stations(prof, valid, sig_n, full=True):
    """Per-station measures of band cross-sections (K, S, U).

    Returns a dict: I (inside level), Oa, Ob (levels beyond each edge), edge (both edges
    there, the inside darker or brighter than both sides by over 4 noise sd), dark (the
    inside darker), bg (fraction of the inside bins that look like the background, as in
    lines: a specular stripe and its flanks excepted), glare (a highlight inside); the last
    two only with `full`.
    """
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
        return dict(I=I, Oa=Oa, Ob=Ob, C=C, edge=edge, one=one, dark=dark)
    # background-like bins inside: for a dark station (mirrored for a bright one) within
    # half the contrast of the outside level, except on the flanks of a highlight (a bin
    # brighter than the outside by half the contrast: glare); on a bright station a bin
    # darker than the outside by half the contrast counts too
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
    return dict(I=I, Oa=Oa, Ob=Ob, C=C, edge=edge, one=one, dark=dark, bg=bg, glare=np.any(glare | shine, -1))


def _level_trend(I, s, edge, C, sig_n, iters=3):
    """Robust quadratic trend of the inside level along each band (K, S), from its edge
    stations (the lighting changes slowly along a shaft, by a fifth towards a bright corner);
    returns (trend (K, S), tol (K,)): a station keeps the band's level when within tol of the
    trend (3 noise sd, or 0.35 of the band's median contrast). Beyond the edge stations the
    trend is held at its last value, not extrapolated."""
    K = I.shape[0]
    Cm = np.nan_to_num(_masked_median(C, edge), nan=0.0)
    tol = np.maximum(3.0 * sig_n, 0.35 * Cm)
    n_e = edge.sum(-1)
    s_c = np.sum(np.where(edge, s, 0.0), -1) / np.maximum(n_e, 1)
    span = np.maximum(np.max(np.where(edge, np.abs(s - s_c[:, None]), 0.0), 1), 1.0)
    x = (s - s_c[:, None]) / span[:, None]
    x2 = x * x
    a = np.nan_to_num(_masked_median(I, edge), nan=0.0)
    b = np.zeros(K)
    c = np.zeros(K)
    for _ in range(iters):
        use = edge & (np.abs(I - (a[:, None] + b[:, None] * x + c[:, None] * x2)) <= tol[:, None])
        wv = use.astype(float)
        m = [np.sum(wv * x**p, -1) for p in range(5)]
        r = [np.sum(wv * I * x**p, -1) for p in range(3)]
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


_W_SHAFT, _W_NEUTRAL, _W_CONTRA = 1.0, 0.3, -1.5
_MAX_ONE_SIDED = 0.3  # largest fraction of a band's stations with exactly one of its edges
_WIDTH_TEST = True
_AMBIG = True
_TAU0 = 0.03  # smallest sd of the midline's offset shared along a stretch, per px of sigma_px


def _best_segment(score):
    """Per row of score (K, S), the run [i, j] (inclusive) of largest sum (Kadane through
    prefix sums). Returns i, j, best."""
    K, S = score.shape
    C0 = np.concatenate([np.zeros((K, 1)), np.cumsum(score, 1)], 1)
    minpref = np.minimum.accumulate(C0[:, :-1], 1)
    gain = C0[:, 1:] - minpref
    j = np.argmax(gain, 1)
    best = gain[np.arange(K), j]
    cols = np.arange(S + 1)[None, :]
    i = np.argmin(np.where(cols <= j[:, None], C0, np.inf), 1)
    return i, j, best


def _assess_bands(img, camera, pr, s, valid_s, sig_n, blur_px, full=True):
    """Classify the stations s (K, S) of bands and find each band's run (module docstring,
    step 3). Returns a dict of per-band results and the station classes. Without `full`
    (a first, coarse look) the inside has 8 bins and the background and highlight measures
    are left out."""
    n_in = _N_IN if full else 8
    prof, valid_e, valid, in_img = _band_profiles(img, camera, pr, s, blur_px, n_in)
    valid &= valid_s
    st = _stations(prof, valid_e & valid_s, sig_n, full)
    trend, tol = _level_trend(st["I"], s, st["edge"], st["C"], sig_n)
    # the band's own cross-section: the median shape of the inside over its edge stations
    # (each station's bins less its level); a station keeps it when 3/4 of its bins do
    K, S, U = prof.shape
    pin = prof[..., _N_OUT:_N_OUT + n_in] - st["I"][..., None]
    lvl_ok = np.abs(st["I"] - trend) <= tol[:, None]
    ref = st["edge"] & lvl_ok
    T = _masked_median(pin.transpose(0, 2, 1).reshape(K * n_in, S), np.repeat(ref, n_in, 0)).reshape(K, n_in)
    shape_ok = np.mean(np.abs(pin - np.nan_to_num(T)[:, None, :]) <= tol[:, None, None], -1) >= 0.5
    cons = valid & lvl_ok & shape_ok
    shaft = cons & st["edge"]
    neutral = cons & ~st["edge"]
    contra = valid & ~cons
    score = np.where(shaft, _W_SHAFT, np.where(neutral, _W_NEUTRAL, np.where(contra, _W_CONTRA, 0.0)))
    i, j, best = _best_segment(score)
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
    bg = np.sum(np.where(run & shaft, st["bg"], 0.0), -1) / f if full else None
    glare = np.sum(run & shaft & st["glare"], -1) / f if full else None
    dark = np.sum(run & shaft & st["dark"], -1) / f >= 0.5
    one_sided = np.sum(run & valid & st["one"], -1) / np.maximum(np.sum(run & valid, -1), 1)
    return dict(one_sided=one_sided, trend=trend, tol=tol, lvl_ok=lvl_ok, shape_ok=shape_ok, i=i, j=j, best=best, n_shaft=n_sh, contra=n_x / np.maximum(n_v, 1), bg=bg, glare=glare,
                dark=dark, shaft=shaft, valid=valid, in_img=in_img & valid_s, st=st)


def _chord_assess(img, camera, pr, polygon, sig_n, blur_px, border_px, max_stations, min_step=0.0, full=True):
    """`_assess_bands` at stations along each band's whole chord through the image (from
    border to border along its bisector), at most max_stations of them, min_step apart.
    Returns (q, s, step, lo_run, hi_run, touch): the run [lo_run, hi_run] along the
    bisector and whether it reaches the border (it does not stop before the inside of the
    band leaves the image)."""
    c_lo, c_hi = _chord(pr, polygon)
    c_lo = np.where(np.isfinite(c_lo), c_lo, pr.span_lo)
    c_hi = np.where(np.isfinite(c_hi), c_hi, pr.span_hi)
    step = np.maximum(min_step, (c_hi - c_lo) / (max_stations - 1))
    step = np.maximum(step, 1e-6)
    cnt = np.minimum(np.floor((c_hi - c_lo) / step).astype(int) + 1, max_stations)
    S = int(cnt.max())
    jj = np.arange(S)
    s = c_lo[:, None] + np.minimum(jj[None, :], cnt[:, None] - 1) * step[:, None]
    q = _assess_bands(img, camera, pr, s, jj[None, :] < cnt[:, None], sig_n, blur_px, full)
    rows = np.arange(pr.a.size)
    lo_run, hi_run = s[rows, q["i"]], s[rows, q["j"]]
    vs = q["in_img"]  # the image border, not where the edges would cross
    first = np.argmax(vs, 1)
    last = S - 1 - np.argmax(vs[:, ::-1], 1)
    # the gaps between the run's ends and the last stations seen, in raw pixels: border_px
    # is a distance in the image, and a lens that compresses its periphery (a fisheye)
    # stretches it in undistorted pixels by half or more
    along = np.stack([lo_run, s[rows, first], hi_run, s[rows, last]], -1)  # (K, 4)
    pts = _to_raw_pts(camera, pr.O[:, None, :] + along[..., None] * pr.D[:, None, :])
    gap = np.linalg.norm(pts[:, 0::2] - pts[:, 1::2], axis=-1)  # (K, 2)
    gap = np.where(np.isfinite(gap), gap, np.abs(along[:, 0::2] - along[:, 1::2]))
    touch = np.any(gap <= border_px, -1)
    return q, s, step, lo_run, hi_run, touch


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


_BORDER_CACHE = {}
_DEBUG = None


def _border_polygon(camera, W, H):
    """The image border in working pixels, a closed polygon (P, 2) (cached per camera)."""
    if camera is None:
        return np.array([[-0.5, -0.5], [W - 0.5, -0.5], [W - 0.5, H - 0.5], [-0.5, H - 0.5], [-0.5, -0.5]])
    key = (id(camera), camera)
    if key not in _BORDER_CACHE:
        n = 48
        xs = np.linspace(0.0, W - 1.0, n)
        ys = np.linspace(0.0, H - 1.0, n)
        raw = np.concatenate([np.stack([xs, 0 * xs], -1), np.stack([0 * ys + W - 1, ys], -1),
                              np.stack([xs[::-1], 0 * xs + H - 1], -1), np.stack([0 * ys, ys[::-1]], -1)])
        work = _to_working(camera, raw.reshape(-1, 4)).reshape(-1, 2)
        work = work[np.all(np.isfinite(work), -1)]
        if len(_BORDER_CACHE) > 16:
            _BORDER_CACHE.clear()
        _BORDER_CACHE[key] = np.concatenate([work, work[:1]])
    return _BORDER_CACHE[key]


def _plane_bisector(camera, pr):
    """Bisecting line (N, C) (K, 2), (K,) in undistorted pixels of the two planes through the
    camera centre that the edges back-project to (see the module docstring)."""
    K = np.asarray(camera.K, float)
    K2, k = K[:2, :2], K[:2, 2]
    K2inv = np.linalg.inv(K2)
    na, ca, nb, cb = pr._lines
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


def _contains(pr, lo, hi):
    """(K, K) bool [i, j]: band j lies inside band i (both of j's edges between i's edges,
    1.5 px allowed, at j's centre, which lies within i's run [lo_i, hi_i]), j != i."""
    na, ca, nb, cb = pr._lines
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


# ----------------------------------------------------------------------------- the axis


def _class_line_fit(s, t, w, base, cls, floor_px=0.2, iters=6):
    """Robust weighted fit t ~ b s + c_class (one slope, one offset per class: the gradient
    peak of a blurred, gamma-encoded edge leans towards its dark side, so an edge seen
    against black print sits apart from the same edge against white paper), one row.

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
    b = _theil_sen(s[None], t[None], (ok & (cls == big))[None])[0][0]
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
        if new.sum() < 6:
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


def _measure_axis(img, camera, pr, k, lo, hi, shaft_at, search, sigma_px, slope_correction, floor_px=0.2,
                  guard_px=None, max_clutter=0.25, tau0_px=None):
    """Edges and midline of band k from paired stations over its run [lo, hi] along its
    bisector (module docstring, step 4).

    Each edge is measured at every station of the run where it is seen cleanly (no other
    edge beside it) and fitted on its own, robustly, with one offset per polarity
    (`_class_line_fit`); the midline is the robust line through the midpoints of the
    stations where both edges fit and the band was seen as a shaft (shaft_at(s) -> bool).
    Returns a dict or None: the pair geometry of the refitted edges, the midline
    t = tm + b (s - sm) in its frame and the variances of b and of the offset at sm.
    """
    kern, r = _deriv_kernel(sigma_px)
    kern = kern.astype(np.float32)
    if guard_px is None:
        guard_px = 3.0 * sigma_px + 1.0
    if tau0_px is None:
        tau0_px = _TAU0 * sigma_px
    L = hi - lo
    step = max(2.5, L / 300.0)
    S = int(np.floor(L / step)) + 1
    if S < 6:
        return None
    sv = lo + step * np.arange(S)
    shaft = shaft_at(sv)
    if shaft.sum() < 6:
        return None
    one = pr.take(np.array([k]))
    pts = one.O[0] + sv[:, None] * one.D[0]  # station points on the bisector
    na, ca, nb, cb = (v[0] for v in one._lines)
    for it in range(2):
        sv = (pts - one.O[0]) @ one.D[0]
        A, B, w = _edge_points(one, sv[None, :])
        A, B = A[0], B[0]
        # each edge sampled along its own normal n = (-u_y, u_x), pointing into the band
        ua = np.array([na[1], -na[0]])
        ub = np.array([nb[1], -nb[0]])
        ua = ua if np.dot(np.array([-ua[1], ua[0]]), B[0] - A[0]) > 0 else -ua
        ub = ub if np.dot(np.array([-ub[1], ub[0]]), A[0] - B[0]) > 0 else -ub
        P0 = np.stack([A[0], B[0]])
        U = np.stack([ua, ub])
        n_ab = np.stack([-U[:, 1], U[:, 0]], -1)
        s2 = np.stack([np.sum((A - A[0]) * ua, -1), np.sum((B - B[0]) * ub, -1)])
        srch = search if it == 0 else min(search, 1.5)
        t, g, good, clutter = _edge_samples(img, camera, P0, U, s2, srch, kern, r, sigma_px, slope_correction,
                                            guard_px=guard_px)
        a = np.abs(g)
        base = good & (a > 0) & (clutter <= max_clutter) & (w[0] * np.sign(np.median(w[0])) > 0)[None, :]
        med = _masked_median(a, base & shaft[None, :])
        base &= a >= 0.35 * np.nan_to_num(med, nan=np.inf)[:, None]
        w2 = np.where(base, a * a, 0.0)
        w2 = w2 / np.maximum(np.nan_to_num(_masked_median(w2, base), nan=1.0), 1e-300)[:, None]
        ends, inl = [], []
        for e in range(2):
            fit = _class_line_fit(s2[e], t[e], w2[e], base[e], (g[e] > 0).astype(int), floor_px)
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
        inl = np.stack(inl)
        both = inl[0] & inl[1] & shaft
        if both.sum() < 6:
            return None
        Enew = np.stack(ends)
        E2, ia, ib = _oriented_pairs(Enew, np.array([0]), np.array([1]))
        one = _pair_geometry(E2, ia, ib)
        na, ca, nb, cb = (v[0] for v in one._lines)
    # midpoints of the paired edge points, in the frame of the final bisector
    pa_ = P0[0] + s2[0][:, None] * U[0] + t[0][:, None] * n_ab[0]
    pb_ = P0[1] + s2[1][:, None] * U[1] + t[1][:, None] * n_ab[1]
    mid = 0.5 * (pa_ + pb_)
    N, D, O = one.N[0], one.D[0], one.O[0]
    ms = (mid - O) @ D
    mt = mid @ N + one.C[0]
    cls = 2 * (g[0] > 0) + (g[1] > 0)
    loose = base[0] & base[1] & shaft
    if _WIDTH_TEST:
        both &= _width_inliers(ms, np.abs((pb_ - pa_) @ N), both, cls)
        if both.sum() < 6:
            return None
    wa, wb = np.where(both, w2[0], 0.0), np.where(both, w2[1], 0.0)
    wm = np.where(both, 1.0 / (1.0 / np.maximum(wa, 1e-12) + 1.0 / np.maximum(wb, 1e-12)), 0.0)
    wm = wm / np.maximum(np.median(wm[both]), 1e-300)
    sm, tm, b, Sss, Wt, res, inl_m = _line_fit(ms[None], mt[None], wm[None], both[None], None, floor_px,
                                               robust_start=True, seed_labels=_stretches(ms, both, cls)[None])
    var_b, var_a = _fit_variances(ms[None], res, wm[None], inl_m, sm, Sss, Wt, long_blocks=8)
    # stretches of one background bias the midline alike (module docstring, step 4)
    lab = _stretches(ms, inl_m[0], cls)
    s02 = float(np.sum(wm * res[0] ** 2 * inl_m[0]) / max(int(inl_m.sum()) - 2, 1))
    va_re, vb_re, tau = _stretch_variances(ms, res[0], wm, lab, float(sm[0]), max(s02, 1e-6), tau0_px)
    var_b = np.maximum(var_b, vb_re)
    var_a = np.maximum(var_a, va_re)
    if _AMBIG:
        # the stations the robust fits left out, unless far off: where they tell another
        # line (a stretch pulled off by something along an edge can outnumber the rest),
        # the difference counts as uncertainty
        r_all = mt - tm[0] - b[0] * (ms - sm[0])
        lo_ = loose & (np.abs(r_all) <= 2.0)
        if lo_.sum() >= 6:
            wl = np.where(lo_, np.maximum(np.minimum(w2[0], w2[1]), 1e-12), 0.0)
            sm2, tm2, b2, _, _ = _wls(ms[None], mt[None], wl[None], lo_[None])
            db = float(b2[0] - b[0])
            da = float(tm2[0] + b2[0] * (sm[0] - sm2[0]) - tm[0])
            var_b = var_b + db * db
            var_a = var_a + da * da
    if _DEBUG is not None:
        _DEBUG.setdefault("axis", []).append(dict(mid=mid, both=both, inl=inl_m[0], res=res[0], wm=wm, t=t, g=g,
                                                  pa=pa_, pb=pb_, w2=w2))
    return dict(pair=one, edges=Enew, sm=float(sm[0]), tm=float(tm[0]), b=float(b[0]),
                var_b=float(var_b[0]), var_a=float(var_a[0]), n=int(inl_m.sum()),
                s_lo=float(ms[inl_m[0]].min()), s_hi=float(ms[inl_m[0]].max()))


def _width_inliers(s, w, use, cls, floor=0.25, iters=4):
    """Stations whose width w is not above the band's lower envelope w ~ c_class + k s (one
    offset per class with 6 stations or more, one slope) by more than 3 robust sd (at least
    `floor` px).

    Something dark lying along a dark shaft's silhouette (a printed bar under or beside it),
    or bright along a bright one, merges with it and pulls that edge outwards: the band
    looks wider there, never narrower. The envelope is fitted to the narrower half of the
    stations (twice refitted), so that such a stretch cannot carry it, however long it is.
    Returns (N,) bool.
    """
    ok = use.copy()
    classes = [c for c in np.unique(cls[use]) if np.sum(use & (cls == c)) >= 6]
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


def _stretches(s, use, cls, gap_steps=3.0):
    """Labels (N,) of the stretches of stations `use` (sorted by s): runs of one class
    (`cls`: which way each edge turns, i.e. what lies behind the shaft on either side)
    without gaps over gap_steps station spacings; -1 outside `use`."""
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


def _stretch_variances(s, res, w, lab, s0, s02, tau0):
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


# ------------------------------------------------------------------------------ detector


def detect_shafts(image, camera=None, *, detector="lsd", min_length=None, width_px_range=None,
                  max_convergence_deg=30.0, max_shafts=4, scale=None, max_gap_px=None, search_px=3.0,
                  sigma_px=1.5, min_support=0.3, max_background=0.1, slope_correction=True, from_border=True,
                  border_px=None, min_score_ratio=0.25, detector_params=None):
    """Instrument shafts in one image: midline (the axis image), width, angle uncertainty.

    Parameters
    ----------
    image : (H, W) or (H, W, 3) array
        Grey or BGR frame.
    camera : Camera, optional
        Lens model. Edges are fitted straight in undistorted pixels and the midline is the
        exact image of the axis (module docstring); its image size must match.
    detector : {"lsd", "fld", "edlines"}
        Proposal detector (run on the reduced image).
    min_length : float, optional
        Shortest edge [px]; default 1/8 of the image diagonal. The band must be seen as a
        shaft (both edges) along at least half of it.
    width_px_range : (2,) [px], optional
        Accepted apparent widths (at the overlap centre); default 6 px to 0.7 of the
        image's smaller side.
    max_convergence_deg : float
        Largest angle between the two edges.
    max_shafts : int
        At most this many shafts, best score first.
    min_score_ratio : float
        Drop shafts whose score is below this fraction of the best one's.
    scale : float, optional
        Reduction of the image for the proposals; default so that its larger side is ~640 px.
    max_gap_px : float, optional
        Longest stretch without edge evidence inside one edge; default 1/10 of the diagonal.
    search_px, sigma_px : float
        Edge search half-width and Gaussian-derivative sd of the full-resolution fits [px].
    min_support : float
        The two edges must overlap along at least this fraction of the shorter one
        (occlusion allowed), and along at least half of `min_length`.
    max_background : float
        Largest fraction of the band's stations whose inside contradicts the band's level,
        and largest fraction of its cross-section that may look like the background.
    from_border : bool
        Keep only bands that run to the image border (within `border_px`, default 3 % of the
        diagonal + 8 px): an instrument enters the view from outside, whereas the long strips
        of a scene (a sheet's margin, a row of a board, a table's edge) end inside it. False
        also finds a shaft whose near part is hidden.
    slope_correction : bool
        Correct each edge point for the grey-level slopes beside it (the shading of the
        metal, tissue texture): between ramps of slopes bL and bR a blurred step of height a
        has its gradient peak sigma^2 (bR - bL) / a off the edge. Without it, edges on
        textured tissue carry biases that are smooth along the edge, invisible in the
        residuals, and turn the midline by a few sd. Only for shafts wider than twice the
        profile's reach (~2 (search + 6 sigma + 2.5) px, 24 px by default): on a thinner one
        the slopes would be read off the other edge.
    detector_params : dict, optional
        Passed to the detector.

    Returns
    -------
    list of Shaft
        Best score first; empty when none is found.

    Example
    -------
    See the module docstring.
    """
    img = _Gray(image)
    _check_camera_image(camera, img)
    H, W = img.shape
    diag = float(np.hypot(H, W))
    if min_length is None:
        min_length = diag / 8.0
    if border_px is None:
        border_px = 0.03 * diag + 8.0
    if max_gap_px is None:
        max_gap_px = diag / 10.0
    wmin, wmax = (6.0, 0.7 * min(H, W)) if width_px_range is None else map(float, width_px_range)
    if not (0 < wmin < wmax):
        raise InputError(f"width_px_range must be (min, max) with 0 < min < max, got {width_px_range!r}")
    if scale is None:
        scale = min(1.0, 640.0 / max(H, W))
    if not (0 < scale <= 1):
        raise InputError(f"scale must be in (0, 1], got {scale!r}")
    conv_max = np.radians(max_convergence_deg)

    # 1. proposals: pieces of edges of one polarity
    frag = _proposals(img, detector, camera, scale, detector_params)
    if frag.shape[0] < 2:
        return []
    merged, lab = merge_collinear(frag, 3.0, 1.5 / scale, max_gap_px)
    Lf = np.hypot(frag[:, 2] - frag[:, 0], frag[:, 3] - frag[:, 1])
    support = np.bincount(lab[lab >= 0], Lf[lab >= 0], merged.shape[0])
    hyp = _unsigned(merged[support >= 0.2 * min_length])
    if hyp.shape[0] < 2:
        return []
    # 2. edges: the pieces with a possible partner, refitted to the unsigned edge, then
    # joined whatever their polarity (accurate pieces, tight tolerances: the two edges of a
    # thin shaft are not chained together through the clutter between them)
    hyp = hyp[_partnered(hyp, conv_max + np.radians(2.0), wmin, wmax, 0.1 * min_length)]
    if hyp.shape[0] < 2:
        return []
    sig_n = _noise(img)
    min_grad = max(2.0, 1.5 * sig_n)
    P, ok, cnt = _refit_lines(img, camera, hyp, search=search_px, sigma_px=sigma_px, step_px=3.0,
                              extend_px=5.0, max_gap_px=max_gap_px, min_gradient=min_grad)
    Lp = np.hypot(P[:, 2] - P[:, 0], P[:, 3] - P[:, 1])
    P = P[ok & (Lp >= 0.1 * min_length)]
    if P.shape[0] < 2:
        return []
    P2 = _both_ways(P)
    joined, lab = merge_collinear(P2, 1.0, 1.5, max_gap_px)
    Lj = np.hypot(P2[:, 2] - P2[:, 0], P2[:, 3] - P2[:, 1])
    support = np.bincount(lab[lab >= 0], Lj[lab >= 0], joined.shape[0])
    good = support >= 0.25 * min_length
    E, support = _unsigned(joined[good]), support[good]
    keep = _dedupe(E, support)
    E = E[keep]
    if E.shape[0] < 2:
        return []
    # 3. bands
    a, b = _parallel_candidates(E, conv_max, wmax)
    if a.size == 0:
        return []
    E2, a, b2 = _oriented_pairs(E, a, b)
    pr = _pair_geometry(E2, a, b2)
    ov = pr.hi - pr.lo
    ok = (pr.conv <= conv_max) & (pr.width >= wmin) & (pr.width <= wmax)
    # pieces of edges pair up too: the band is traced along its whole chord below
    ok &= ov >= 0.25 * min_length
    w0 = _signed_width(pr, 0.5 * (pr.lo + pr.hi))
    ok &= (_signed_width(pr, pr.span_lo) * w0 > 0.25 * w0**2) & (_signed_width(pr, pr.span_hi) * w0 > 0.25 * w0**2)
    pr = pr.take(np.flatnonzero(ok))
    if pr.a.size == 0:
        return []
    # a quick look at 12 stations along each overlap: most strips of the scene's patterns
    # (rows of a board, several squares wide) contradict themselves there already
    s0 = pr.lo[:, None] + np.linspace(0.04, 0.96, 12)[None, :] * (pr.hi - pr.lo)[:, None]
    q0 = _assess_bands(img, camera, pr, s0, np.ones(s0.shape, bool), sig_n, sigma_px, full=False)
    pr = pr.take(np.flatnonzero(q0["n_shaft"] >= 5))
    if pr.a.size == 0:
        return []
    # a coarse look along each band's whole chord through the image (48 stations), then a
    # fine one (every 5 px) at the most promising
    poly = _border_polygon(camera, W, H)
    q, s, step, lo_run, hi_run, touch = _chord_assess(img, camera, pr, poly, sig_n, sigma_px, border_px, 48,
                                                      full=False)
    score = q["n_shaft"] * step
    ok = (q["best"] > 0) & (score >= 0.3 * min_length) & (q["one_sided"] <= 0.4) & (q["contra"] <= 0.35)
    cand = np.flatnonzero(ok)
    if _DEBUG is not None:
        _DEBUG.update(n_pre=pr.a.size, n_cand=cand.size)
    if cand.size == 0:
        return []
    # the best 16, those that enter from the border first, and always the best few that do
    # not: where none of the former holds up, they are what the from_border fallback judges
    # (an instrument whose back end is in view: a short one, a wide-angle lens)
    cand = cand[np.lexsort((-score[cand], ~touch[cand]))]
    cand = np.concatenate([cand[:16], cand[16:][~touch[cand[16:]]][:4]])
    pr = pr.take(cand)
    q, s, step, lo_run, hi_run, touch = _chord_assess(img, camera, pr, poly, sig_n, sigma_px, border_px, 300,
                                                      min_step=5.0)
    if _DEBUG is not None:
        _DEBUG.update(E=E, pr=pr, q=q, s=s, step=step)
    score = q["n_shaft"] * step
    ok = (score >= 0.5 * min_length) & (q["contra"] <= max_background) & (q["bg"] <= max_background)
    ok &= q["best"] > 0
    ok &= q["n_shaft"] >= min_support * (q["j"] - q["i"] + 1)
    # a cylinder's two silhouettes see alike backgrounds: where one edge is lost, mostly so
    # is the other; a strip of a planar pattern loses one side at a time (a sheet's margin
    # beside the white squares of a board)
    ok &= q["one_sided"] <= _MAX_ONE_SIDED
    if not np.any(ok):
        return []
    # nested bands give way to the band around them when they are parts of a shaft with a
    # specular stripe (module docstring, step 3); the band around them enters from the
    # border if they do (the stripe may be seen where an edge is hidden)
    inside = _contains(pr, lo_run, hi_run)
    Ea, Eb = pr.a % E.shape[0], pr.b % E.shape[0]
    shares = ((Ea[:, None] == Ea[None, :]) | (Ea[:, None] == Eb[None, :])
              | (Eb[:, None] == Ea[None, :]) | (Eb[:, None] == Eb[None, :]))
    cq = pr.point(0.5 * (lo_run + hi_run))
    off_axis = np.abs(np.einsum("id,jd->ij", pr.N, cq) + pr.C[:, None])
    parallel = np.abs(np.einsum("id,jd->ij", pr.D, pr.D)) > np.cos(np.radians(3.0) + pr.conv[:, None])
    along_axis = parallel & (off_axis < 0.25 * pr.width[:, None])
    wider = pr.width[:, None] > pr.width[None, :] + 2.0
    outer_ok = ok & (q["bg"] <= 0.1) & (q["glare"] >= 0.3)
    gives = inside & wider & (shares | along_axis) & outer_ok[:, None] & ok[None, :] \
        & (score[:, None] >= 0.5 * score[None, :])  # [i, j]: j gives way to i
    nested = np.any(gives, 0)
    touch = touch | np.any(gives & touch[None, :], 1)
    ok &= ~nested
    if from_border:
        if np.any(ok & touch):
            ok &= touch
        else:
            # none enters from the border (the instrument's back end is in view: a short one, a
            # wide-angle lens; or its near part is hidden): only a clean band will do, with
            # little background or contradiction inside. Its one-sided stations count as for
            # any band: they tell what lies beside a shaft (on a textured table up to 0.3 of
            # them for shafts that do enter from the border), not where the shaft begins
            ok &= (q["bg"] <= 0.1) & (q["contra"] <= 0.1) & (q["one_sided"] <= _MAX_ONE_SIDED)
    if not np.any(ok):
        return []
    # one band found from several pairs of pieces of its edges: the best one stays
    # (the others stand by: where the axis of the best cannot be measured, its pieces of
    # edges being too short to extrapolate, the next one is measured instead)
    order = np.argsort(-np.where(ok, score, -np.inf), kind="stable")
    alts = {}
    for ii, k in enumerate(order):
        if not ok[k]:
            continue
        alts[k] = [k]
        for k2 in order[ii + 1:]:
            if ok[k2] and abs(float(pr.N[k] @ cq[k2] + pr.C[k])) < 0.25 * pr.width[k] + 1.0 \
                    and abs(float(pr.D[k] @ pr.D[k2])) > np.cos(np.radians(2.0)) \
                    and abs(pr.width[k2] - pr.width[k]) < 0.25 * pr.width[k] + 2.0:
                ok[k2] = False
                alts[k].append(k2)
    if _DEBUG is not None:
        _DEBUG.update(ok=ok.copy(), nested=nested, score=score)
    # best first, each edge in one shaft
    used = np.zeros(E.shape[0], bool)
    chosen = []
    for k in np.argsort(-np.where(ok, score, -np.inf), kind="stable"):
        if not ok[k] or used[Ea[k]] or used[Eb[k]]:
            continue
        used[Ea[k]] = used[Eb[k]] = True
        chosen.append(k)
        if len(chosen) >= max_shafts:
            break
    chosen = [k for k in chosen if score[k] >= min_score_ratio * score[chosen[0]]]
    # 4. the axis of each
    reach = search_px + 3.0 * sigma_px + 2.5 + 3.0 * sigma_px
    out = []

    def measure(k):
        sk, shk = s[k], q["shaft"][k]

        def shaft_at(sv, sk=sk, shk=shk):
            idx = np.clip(np.rint((sv - sk[0]) / (sk[1] - sk[0])).astype(int), 0, sk.size - 1)
            return shk[idx]

        wide = min(abs(float(_signed_width(pr.take(np.array([k])), np.array([lo_run[k]]))[0])),
                   abs(float(_signed_width(pr.take(np.array([k])), np.array([hi_run[k]]))[0]))) > 2 * reach
        return _measure_axis(img, camera, pr, k, lo_run[k], hi_run[k], shaft_at, search_px, sigma_px,
                             slope_correction and wide)

    for k0 in chosen:
        for k in alts[k0]:
            m = measure(k)
            if m is not None:
                break
        if m is None:
            continue
        one = m["pair"]
        N0, D0, O0 = one.N[0], one.D[0], one.O[0]
        # the midline: t = tm + b (s - sm) in the bisector's frame
        run_pts = pr.O[k] + np.array([lo_run[k], hi_run[k]])[:, None] * pr.D[k]
        ends_s = (run_pts - O0) @ D0  # along positions in the new frame
        P = O0 + ends_s[:, None] * D0 + (m["tm"] + m["b"] * (ends_s - m["sm"]))[:, None] * N0
        if camera is not None:
            # onto the plane bisector: move by its offset from the image bisector at the ends
            Np, Cp = _plane_bisector(camera, one)
            img_off = P @ N0 + one.C[0]  # the midline's offset from the image bisector
            base_pts = P - img_off[:, None] * N0
            lam = -(base_pts @ Np[0] + Cp[0]) / (N0 @ Np[0])
            P = P + lam[:, None] * N0
        na, ca, nb, cb = (v[0] for v in one._lines)

        def width(pt, na=na, ca=ca, nb=nb, cb=cb, N0=N0):
            return abs((-(nb @ pt + cb) / (nb @ N0)) - (-(na @ pt + ca) / (na @ N0)))

        if width(P[0]) < width(P[1]):
            P = P[::-1]
        mid_pt = 0.5 * (P[0] + P[1])
        ang_sig = np.sqrt(m["var_b"]) / (1.0 + m["b"] ** 2)
        r_c = float((mid_pt - O0) @ D0 - m["sm"])
        off_sig = float(np.sqrt(m["var_a"] + (r_c * ang_sig) ** 2))
        ideal = P.reshape(-1)
        raw = _to_raw(camera, ideal)[0]
        if not np.all(np.isfinite(raw)):
            continue
        edges = _to_raw(camera, m["edges"])
        out.append(Shaft(
            midline=raw,
            width_px=float(width(mid_pt)),
            angle_sigma=float(ang_sig),
            offset_sigma=off_sig,
            edges=edges,
            score=float(score[k]),
            ideal_midline=ideal,
            convergence_deg=float(np.degrees(one.conv[0])),
            polarity="dark" if q["dark"][k] else "bright",
        ))
    return out
