"""The circular field stop of an endoscope image: the circle step of `region.detect`.

`detect_circle` looks for a circle inside the content rectangle (what the letterbox bars
leave) of the per-pixel maximum of a sequence's frames:

1. *edge points* on a working image (longer side `work_size`, Gaussian sd 1 px): the top
   10 % of gradient magnitudes, kept only where they look like a field boundary: 3 px
   outside at least `MIN_STEP` levels darker than 3 px inside and at most 60 % of it,
   the surround flat (5 x 5 sd 4 px outside within 15 % of that step);
2. *candidates* from weighted RANSAC (point triples, and pairs whose gradient normals meet
   at the centre) and from Hough voting along the gradients, the centre within 20 % of the
   rectangle's and the radius in [0.3 min side, 1.4 half-diagonal];
3. *validation* by radial profiles every 1.5 px along the circle's visible arc: a profile
   supports it where the outside is dark and flat and the 50 % crossing lies on the
   circle; the most complete candidate wins (completeness >= 0.6, >= 0.8 with fewer than
   40 supporting profiles); a short arc fixes the boundary but not the curvature, so the
   radius is swept x0.85...1.6 with the centre refitted;
4. *refinement* at full resolution: 50 % crossings on radial profiles, a geometric
   least-squares circle (Huber, then a 3 MAD refit; the centre alone on arcs under 90
   deg), three passes; it must keep 80 % of the coarse completeness.

Returns the circle at the 50 % level and the boundary's 10-90 % ramp width, from which
`region.detect` sets the margin. Pixels as everywhere in pencilcal: (0, 0) the centre of
the top-left pixel.

Example
-------
>>> import numpy as np
>>> p = np.array([[10.0, 0.0], [0.0, 10.0], [-10.0, 0.0], [0.0, -10.0]]) + [3.0, 4.0]
>>> np.round(fit_circle(p), 6).tolist()
[3.0, 4.0, 10.0]
"""
from __future__ import annotations

import math

import numpy as np

__all__ = ["MIN_STEP", "edge_ramp", "fit_circle", "detect_circle"]

#: Smallest step [grey levels] between the surround and the content that counts as a
#: boundary (also the bars' floor in region.detect): below it, compression and sensor
#: noise make one up anywhere.
MIN_STEP = 8.0
_REL_DARK = 0.4  # the surround is at most 1 - this of the content level (60 %)
_FLAT_OUT = 0.15  # a candidate edge point's surround sd, at most this fraction of its step
_FLAT_PROFILE = 0.35  # a supporting profile's outer p90 - p10, at most this fraction of its step
_CENTRE_BOX = 0.2  # the centre lies within this fraction of the rectangle's sides of its centre
_COMPLETE = 0.6  # supported / visible profiles of an accepted circle (0.8 with < 40 profiles)
_COMPLETE_FEW = 0.8
_MIN_SUPPORT = 12  # supporting profiles of an accepted circle
_KEEP_REFINED = 0.8  # the refined circle keeps this fraction of the coarse completeness
_SHORT_ARC_DEG = 90.0  # below this arc the refit keeps the radius (the curvature is unknown)


# ============================================================================ fits


def edge_ramp(prof, s, out_lvl, in_lvl, centre=0.0):
    """Where a dark-outside, bright-inside ramp crosses 50 %, 10 % and 90 % of its step.

    Parameters
    ----------
    prof : (n, L) [grey levels]
        Profiles sampled at offsets s (L,) [px] increasing outward.
    out_lvl, in_lvl : (n,)
        The surround's and the content's levels.
    centre : float [px]
        Of several 50 % crossings the one nearest this offset is taken.

    Returns
    -------
    s50, s10, s90 : (n,) [px]
        s50 NaN where 50 % is never crossed; s10 (the ramp's outer end) and s90 (its inner
        end) fall back to the window's ends.

    >>> s = np.arange(-4.0, 5.0)
    >>> prof = np.array([[9, 9, 9, 9, 5, 1, 1, 1, 1.0]])
    >>> [round(float(v[0]), 6) for v in edge_ramp(prof, s, np.ones(1), np.full(1, 9.0))]
    [0.0, 0.8, -0.8]
    """
    n, L = prof.shape
    rows = np.arange(n)
    idx = np.arange(L - 1)
    st = in_lvl - out_lvl
    ds = np.diff(s)

    def interp(k, lvl):
        a, b = prof[rows, k], prof[rows, k + 1]
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.where(b != a, (lvl - a) / (b - a), 0.5)
        return s[k] + np.clip(t, 0.0, 1.0) * ds[k]

    def changes(lvl):
        above = prof >= lvl[:, None]
        return above[:, :-1] != above[:, 1:]

    lv50 = out_lvl + 0.5 * st
    cost = np.where(changes(lv50), np.abs(s[:-1] + 0.5 * ds - centre)[None, :], np.inf)
    k50 = np.argmin(cost, axis=1)
    s50 = np.where(np.isfinite(cost[rows, k50]), interp(k50, lv50), np.nan)
    lv90 = out_lvl + 0.9 * st
    k90 = np.where(changes(lv90) & (idx[None, :] <= k50[:, None]), idx[None, :], -1).max(axis=1)
    s90 = np.where(k90 >= 0, interp(np.maximum(k90, 0), lv90), s[0])
    lv10 = out_lvl + 0.1 * st
    k10 = np.where(changes(lv10) & (idx[None, :] >= k50[:, None]), idx[None, :], L).min(axis=1)
    s10 = np.where(k10 < L - 1, interp(np.minimum(k10, L - 2), lv10), s[-1])
    return s50, s10, s90


def fit_circle(pts, init=None, iters=20, huber=None):
    """Geometric least-squares circle (cx, cy, r) [px] through points (N, 2) (Gauss-Newton
    from the algebraic fit or `init`; Huber weights with threshold `huber` [px])."""
    x, y = pts[:, 0].astype(float), pts[:, 1].astype(float)
    if init is None:
        sol = np.linalg.lstsq(np.stack([x, y, np.ones_like(x)], axis=1), x * x + y * y, rcond=None)[0]
        cx, cy = sol[0] / 2, sol[1] / 2
        r = math.sqrt(max(sol[2] + cx * cx + cy * cy, 1e-12))
    else:
        cx, cy, r = init
    for _ in range(iters):
        dx, dy = x - cx, y - cy
        rho = np.hypot(dx, dy) + 1e-12
        res = rho - r
        w = np.ones_like(res)
        if huber is not None:
            a = np.abs(res)
            w = np.where(a <= huber, 1.0, huber / np.maximum(a, 1e-12))
        J = np.stack([-dx / rho, -dy / rho, -np.ones_like(rho)], axis=1)
        JW = J * w[:, None]
        try:
            step = np.linalg.solve(JW.T @ J + 1e-9 * np.eye(3), -(JW.T @ res))
        except np.linalg.LinAlgError:
            break
        cx, cy, r = cx + step[0], cy + step[1], r + step[2]
        if np.abs(step).max() < 1e-4:
            break
    return float(cx), float(cy), float(abs(r))


def _fit_centre(pts, r, init, iters=15):
    """Centre (cx, cy) [px] of the circle of radius r best fitting points (N, 2)."""
    cx, cy = init
    x, y = pts[:, 0], pts[:, 1]
    for _ in range(iters):
        dx, dy = x - cx, y - cy
        rho = np.hypot(dx, dy) + 1e-12
        J = np.stack([-dx / rho, -dy / rho], axis=1)
        try:
            step = np.linalg.solve(J.T @ J + 1e-9 * np.eye(2), -(J.T @ (rho - r)))
        except np.linalg.LinAlgError:
            break
        cx, cy = cx + step[0], cy + step[1]
        if np.abs(step).max() < 1e-3:
            break
    return float(cx), float(cy)


def _circle_from_3(P):
    """Circumcircles (cx, cy, r) (K,) of point triples P (K, 3, 2); cx NaN for collinear ones."""
    ax, ay, bx, by, cx, cy = P[:, 0, 0], P[:, 0, 1], P[:, 1, 0], P[:, 1, 1], P[:, 2, 0], P[:, 2, 1]
    d = 2.0 * (ax * (by - cy) + bx * (cy - ay) + cx * (ay - by))
    a2, b2, c2 = ax * ax + ay * ay, bx * bx + by * by, cx * cx + cy * cy
    with np.errstate(divide="ignore", invalid="ignore"):
        ux = (a2 * (by - cy) + b2 * (cy - ay) + c2 * (ay - by)) / d
        uy = (a2 * (cx - bx) + b2 * (ax - cx) + c2 * (bx - ax)) / d
    r = np.hypot(ax - ux, ay - uy)
    return np.where(np.abs(d) < 1e-9, np.nan, ux), uy, r


def _angular_span(th):
    """Total angle [deg] covered by angles th [rad], in 5 deg bins."""
    if len(th) == 0:
        return 0.0
    return 5.0 * len(np.unique(np.floor(np.degrees(np.mod(th, 2 * np.pi)) / 5.0)))


# ============================================================================ candidates


def _boundary_points(g, Rin):
    """Edge points of the working image g (h, w) inside Rin (h, w) bool that look like a field
    boundary (module docstring, step 1): xs, ys, unit gradient ux, uy (towards the bright
    side), sampling weights; None when fewer than 20."""
    import cv2

    gx = cv2.Sobel(g, cv2.CV_32F, 1, 0, ksize=3) / 8.0
    gy = cv2.Sobel(g, cv2.CV_32F, 0, 1, ksize=3) / 8.0
    mag = cv2.magnitude(gx, gy)
    if not Rin.any():
        return None
    thr = max(float(np.percentile(mag[Rin], 90)), 1.0)
    ys, xs = np.nonzero(Rin & (mag >= thr))
    if len(xs) < 20:
        return None
    ux, uy = gx[ys, xs] / mag[ys, xs], gy[ys, xs] / mag[ys, xs]
    hs, ws = g.shape

    def at(k):
        return (np.clip(np.rint(ys + k * uy), 0, hs - 1).astype(int),
                np.clip(np.rint(xs + k * ux), 0, ws - 1).astype(int))

    vo, vi = g[at(-3.0)], g[at(3.0)]
    mu = cv2.blur(g, (5, 5))
    sd = np.sqrt(np.maximum(cv2.blur(g * g, (5, 5)) - mu * mu, 0.0))
    sdo = sd[at(-4.0)]
    keep = (vi - vo >= MIN_STEP) & (vo <= (1.0 - _REL_DARK) * vi) & (sdo <= _FLAT_OUT * (vi - vo))
    if keep.sum() < 20:
        return None
    # sampling weight: how dark and flat the outer side is (surround-likeness)
    rel = 1.0 - vo[keep] / np.maximum(vi[keep], 1e-6)
    weight = (rel**4 / (1.0 + sdo[keep])).astype(float)
    return xs[keep].astype(float), ys[keep].astype(float), ux[keep], uy[keep], weight


def _hough_candidates(xs, ys, ux, uy, box, rmin, rmax, rng, max_pts=6000, n_peaks=4):
    """Circles (cx, cy, r, votes, peak) from centre votes along the gradients, then a radius
    histogram per centre peak."""
    import cv2

    sel = np.arange(len(xs)) if len(xs) <= max_pts else rng.choice(len(xs), max_pts, replace=False)
    bx0, bx1, by0, by1 = box
    b = 2.0
    nbx, nby = int(math.ceil((bx1 - bx0) / b)) + 1, int(math.ceil((by1 - by0) / b)) + 1
    rho = np.arange(rmin, rmax, 1.5, dtype=np.float32)
    ix = np.floor((xs[sel, None] + rho[None, :] * ux[sel, None] - bx0) / b).astype(np.int32)
    iy = np.floor((ys[sel, None] + rho[None, :] * uy[sel, None] - by0) / b).astype(np.int32)
    ok = (ix >= 0) & (ix < nbx) & (iy >= 0) & (iy < nby)
    acc = np.bincount((iy[ok] * nbx + ix[ok]).ravel(), minlength=nbx * nby).astype(np.float32).reshape(nby, nbx)
    acc = cv2.GaussianBlur(acc, (0, 0), 1.0)
    py, px = np.nonzero((acc == cv2.dilate(acc, np.ones((5, 5), np.uint8))) & (acc > 0))
    cands = []
    for k in np.argsort(-acc[py, px])[:n_peaks]:
        cx, cy = bx0 + (px[k] + 0.5) * b, by0 + (py[k] + 0.5) * b
        dx, dy = cx - xs, cy - ys
        d = np.hypot(dx, dy) + 1e-6
        m = ((dx * ux + dy * uy) / d >= 0.95) & (d >= rmin) & (d <= rmax)
        if m.sum() < 10:
            continue
        h = np.bincount(np.floor(d[m] - rmin).astype(int), minlength=int(rmax - rmin) + 2).astype(np.float32)
        h = np.convolve(h, np.ones(3, np.float32), mode="same")
        for _ in range(2):
            j = int(np.argmax(h))
            if h[j] <= 0:
                break
            cands.append((float(cx), float(cy), float(rmin + j + 0.5), float(h[j]), float(acc[py[k], px[k]])))
            h[max(0, j - 4):j + 5] = 0
    return cands


def _ransac_hypotheses(xs, ys, ux, uy, pw, rng, n_hyp):
    """Circle hypotheses (cx, cy, r) from weighted minimal samples: point triples whose
    gradients point to the centre, and pairs whose gradient normals meet at it."""
    M = len(xs)
    P = np.stack([xs, ys], axis=1)
    idx = rng.choice(M, size=(n_hyp, 3), p=pw)
    cx, cy, r = _circle_from_3(P[idx])
    ok = np.isfinite(cx)
    ii, cx, cy, r = idx[ok], cx[ok], cy[ok], r[ok]
    cosv = ((cx[:, None] - xs[ii]) * ux[ii] + (cy[:, None] - ys[ii]) * uy[ii]) / np.maximum(r[:, None], 1e-9)
    good = (cosv >= 0.9).all(axis=1)
    cx, cy, r = cx[good], cy[good], r[good]
    j = rng.choice(M, size=(n_hyp, 2), p=pw)
    a, b = j[:, 0], j[:, 1]
    det = ux[a] * (-uy[b]) - uy[a] * (-ux[b])
    ok2 = np.abs(det) >= math.sin(math.radians(20))
    with np.errstate(all="ignore"):  # parallel normals (det 0) are dropped by ok2
        dx, dy = xs[b] - xs[a], ys[b] - ys[a]
        ta = (dx * (-uy[b]) - dy * (-ux[b])) / det
        tb = (ux[a] * dy - uy[a] * dx) / det
        ok2 &= (ta > 0) & (tb > 0) & (np.abs(ta - tb) <= 0.05 * np.maximum(ta, tb))
        px, py, pr = (xs[a] + ta * ux[a])[ok2], (ys[a] + ta * uy[a])[ok2], (0.5 * (ta + tb))[ok2]
    return np.concatenate([cx, px]), np.concatenate([cy, py]), np.concatenate([r, pr])


def _ransac_candidates(pts, box, R, rmin, rmax, rng, n_hyp=1500, max_pts=2000, n_keep=8):
    """The best distinct RANSAC circles (cx, cy, r, score, 0), each polished on its inliers.
    Hypotheses score inliers x min(1, inliers / the points expected on the visible arc)."""
    xs, ys, ux, uy, w = pts
    n_all = len(xs)
    if n_all < 10:
        return []
    w = np.asarray(w, float) + 1e-9
    if n_all > max_pts:
        sel = rng.choice(n_all, max_pts, replace=False)
        xs, ys, ux, uy, w = xs[sel], ys[sel], ux[sel], uy[sel], w[sel]
    density = len(xs) / float(n_all)  # boundary points per px of arc after subsampling
    cx, cy, r = _ransac_hypotheses(xs, ys, ux, uy, w / w.sum(), rng, n_hyp)
    bx0, bx1, by0, by1 = box
    ok = (cx >= bx0) & (cx <= bx1) & (cy >= by0) & (cy <= by1) & (r >= rmin) & (r <= rmax)
    ccx, ccy, rr = cx[ok], cy[ok], r[ok]
    if len(ccx) == 0:
        return []
    scores = np.zeros(len(ccx))
    tol = max(1.5, 0.004 * rmax)
    th = np.linspace(0, 2 * np.pi, 90, endpoint=False)
    ct, st_ = np.cos(th)[None, :], np.sin(th)[None, :]
    rx0, ry0, rx1, ry1 = R
    for s0 in range(0, len(ccx), 200):
        a, b, c = ccx[s0:s0 + 200, None], ccy[s0:s0 + 200, None], rr[s0:s0 + 200, None]
        dx, dy = a - xs[None], b - ys[None]
        d = np.hypot(dx, dy)
        n_in = ((np.abs(d - c) <= tol) & ((dx * ux[None] + dy * uy[None]) >= 0.9 * d)).sum(axis=1).astype(float)
        bx, by = a + c * ct, b + c * st_
        vis = ((bx >= rx0) & (bx <= rx1) & (by >= ry0) & (by <= ry1)).mean(axis=1)
        scores[s0:s0 + 200] = n_in * np.minimum(1.0, n_in / np.maximum(vis * 2 * np.pi * c[:, 0] * density, 1.0))
    return _distinct_circles(ccx, ccy, rr, scores, np.stack([xs, ys], 1), ux, uy, tol, n_keep)


def _distinct_circles(ccx, ccy, rr, scores, P, ux, uy, tol, n_keep):
    """The best-scoring circles, those within 3 % of a better one dropped, each refitted to
    its inlier points P (N, 2)."""
    def near(c, others):
        return any(abs(c[0] - o[0]) < 0.03 * c[2] and abs(c[1] - o[1]) < 0.03 * c[2] and abs(c[2] - o[2]) < 0.03 * c[2]
                   for o in others)

    out, raw = [], []
    for k in np.argsort(-scores):
        if scores[k] < 10 or len(out) >= n_keep or len(raw) >= 3 * n_keep:
            break
        c = (float(ccx[k]), float(ccy[k]), float(rr[k]))
        if near(c, raw):
            continue
        raw.append(c)
        dx, dy = c[0] - P[:, 0], c[1] - P[:, 1]
        d = np.hypot(dx, dy)
        inl = (np.abs(d - c[2]) <= tol) & ((dx * ux + dy * uy) >= 0.9 * d)
        if inl.sum() >= 6:
            c = fit_circle(P[inl], init=c, iters=10)
        if not near(c, out):
            out.append(c + (float(scores[k]), 0.0))
    return out


# ============================================================================ support


def _circle_profiles(img, c, r, R, w, step_px=1.5, ds=1.0):
    """Radial profiles (outward, offsets s (L,) [px] in [-w, w]) across the circle every
    `step_px` of its arc inside the rectangle R: angles th (n,), s, profiles (n, L) (NaN
    outside R)."""
    import cv2

    cx, cy = c
    x0, y0, x1, y1 = R
    n = int(min(4000, max(64, 2 * math.pi * r / step_px)))
    th = np.linspace(0, 2 * np.pi, n, endpoint=False)
    bx, by = cx + r * np.cos(th), cy + r * np.sin(th)
    th = th[(bx >= x0 + 1) & (bx <= x1 - 1) & (by >= y0 + 1) & (by <= y1 - 1)]
    ct, st_ = np.cos(th), np.sin(th)
    s = np.arange(-w, w + ds / 2, ds, dtype=np.float32)
    mx = (cx + (r + s[None, :]) * ct[:, None]).astype(np.float32)
    my = (cy + (r + s[None, :]) * st_[:, None]).astype(np.float32)
    if len(th):
        prof = cv2.remap(img, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    else:
        prof = np.zeros((0, len(s)), np.float32)
    inside = (mx >= x0) & (mx <= x1) & (my >= y0) & (my <= y1)
    return th, s.astype(float), np.where(inside, prof, np.nan).astype(np.float32)


def _row_quantiles(a, qs):
    """Quantiles of each row of a (n, L), NaN ignored (nearest rank, one sort)."""
    srt = np.sort(a, axis=1)  # NaN sort last
    n = np.sum(np.isfinite(a), axis=1)
    out = []
    for q in qs:
        k = np.clip(np.round(q * (n - 1)).astype(int), 0, a.shape[1] - 1)
        out.append(np.where(n > 0, np.take_along_axis(srt, k[:, None], axis=1)[:, 0], np.nan))
    return out


def _levels(prof, s, w):
    """Inner and outer levels (n,) (medians over the window's ends), the outer spread
    (p90 - p10) and which profiles are usable. Near the image border a profile's outer end
    can be missing: the outer level then comes from whatever lies outside the circle
    (s >= 1.5 px), so a circle just inside the border is still checked."""
    inner_part, outer_part, near_part = prof[:, s <= -w / 3.0], prof[:, s >= w / 3.0], prof[:, s >= 1.5]
    n_out = np.sum(np.isfinite(outer_part), axis=1)
    usable = (np.sum(np.isfinite(inner_part), axis=1) >= 2) & (np.sum(np.isfinite(near_part), axis=1) >= 1)
    (inner,) = _row_quantiles(inner_part, [0.5])
    outer, o10, o90 = _row_quantiles(outer_part, [0.5, 0.1, 0.9])
    nearm, n10, n90 = _row_quantiles(near_part, [0.5, 0.1, 0.9])
    few = n_out < 2
    return inner, np.where(few, nearm, outer), np.where(few, n90 - n10, o90 - o10), usable


def _boundary_like(inner, outer, spread, usable):
    """(n,) bool: profiles whose outside is dark (<= 60 % of the inside, MIN_STEP below it) and flat."""
    step = inner - outer
    return usable & (step >= MIN_STEP) & (spread <= _FLAT_PROFILE * np.maximum(step, 1e-6)) & \
        (outer <= (1 - _REL_DARK) * inner)


def _support(img, c, r, R, w, tol):
    """Evidence for a field boundary along the circle's visible arc: {visible, supported,
    completeness, ...} and the supporting 50 % crossings (K, 2) [px] (or None)."""
    th, s, prof = _circle_profiles(img, c, r, R, w)
    if len(th) == 0:
        return dict(visible=0, supported=0, completeness=0.0), None
    inner, outer, spread, usable = _levels(prof, s, w)
    cand = _boundary_like(inner, outer, spread, usable)
    s50 = np.full(len(th), np.nan)
    if cand.any():
        # NaNs lie only outward, beyond the image: the outer level stands in
        p = np.where(np.isfinite(prof[cand]), prof[cand], outer[cand][:, None])
        s50[cand] = edge_ramp(p, s, outer[cand], inner[cand])[0]
    sup = cand & np.isfinite(s50) & (np.abs(s50) <= tol)
    nvis = int(usable.sum())
    res = dict(visible=nvis, supported=int(sup.sum()), completeness=float(sup.sum() / max(nvis, 1)))
    if not sup.any():
        return res, None
    rr = r + s50[sup]
    return res, np.stack([c[0] + rr * np.cos(th[sup]), c[1] + rr * np.sin(th[sup])], axis=1)


# ============================================================================ search


def _variants(g, cand, Rw, w, tol, rmin, rmax, box, sweep):
    """The candidate circle polished on its support, and (with `sweep`, on a short arc) the
    radius swept x0.85...1.6 with the centre refitted: ([((cx, cy, r), support), ...],
    whether it was swept)."""
    cx, cy, r = cand[:3]
    rw, rh = Rw[2] - Rw[0], Rw[3] - Rw[1]
    sup, pts = _support(g, (cx, cy), r, Rw, w, tol)
    if pts is not None and len(pts) >= 8:
        c2 = fit_circle(pts, init=(cx, cy, r), huber=1.0)
        if abs(c2[0] - cx) < 0.1 * rw and abs(c2[1] - cy) < 0.1 * rh and rmin <= c2[2] <= rmax * 1.05:
            sup2, pts2 = _support(g, c2[:2], c2[2], Rw, w, tol)
            if sup2["supported"] >= sup["supported"]:
                (cx, cy, r), sup, pts = c2, sup2, pts2
    out = [((cx, cy, r), sup)]
    sweep = sweep and pts is not None and len(pts) >= 8 and sup["completeness"] < 0.9
    if sweep:
        for f in (0.85, 1.15, 1.35, 1.6):
            r2 = r * f
            if not (rmin <= r2 <= rmax):
                continue
            c3 = _fit_centre(pts, r2, (cx, cy))
            if box[0] <= c3[0] <= box[1] and box[2] <= c3[1] <= box[3]:
                out.append(((c3[0], c3[1], r2), _support(g, c3, r2, Rw, w, tol)[0]))
    return out, sweep


def _coarse_circle(g, Rw, rng):
    """The best-supported circle (cx, cy, r, support) in working pixels inside the
    rectangle Rw (module docstring, steps 1-3), or None; and diagnostics."""
    hs, ws = g.shape
    rw, rh = Rw[2] - Rw[0], Rw[3] - Rw[1]
    yy, xx = np.mgrid[0:hs, 0:ws]
    Rin = (xx >= Rw[0] + 3) & (xx <= Rw[2] - 3) & (yy >= Rw[1] + 3) & (yy <= Rw[3] - 3)
    rcx, rcy = 0.5 * (Rw[0] + Rw[2]), 0.5 * (Rw[1] + Rw[3])
    # the centre within +-20 %: the farthest corner is at most 1.4 half-diagonals away
    rmin, rmax = 0.3 * min(rw, rh), 1.4 * 0.5 * math.hypot(rw, rh)
    box = (rcx - _CENTRE_BOX * rw, rcx + _CENTRE_BOX * rw, rcy - _CENTRE_BOX * rh, rcy + _CENTRE_BOX * rh)
    pts = _boundary_points(g, Rin)
    if pts is None:
        return None, {"why": "too few boundary-like edge points"}
    cands = _ransac_candidates(pts, box, Rw, rmin, rmax, rng)
    cands += _hough_candidates(*pts[:4], box, rmin, rmax, rng)
    w, tol = max(6.0, 0.03 * min(rw, rh)), max(2.0, 0.01 * min(rw, rh))
    best, n_sweep = None, 0
    for cand in sorted(cands, key=lambda c: -c[3]):
        variants, swept = _variants(g, cand, Rw, w, tol, rmin, rmax, box, n_sweep < 4)
        n_sweep += swept
        for (vx, vy, vr), vs in variants:
            score = vs["supported"] * vs["completeness"]
            need = _COMPLETE if vs["supported"] >= 40 else _COMPLETE_FEW
            if vs["completeness"] >= need and vs["supported"] >= _MIN_SUPPORT and (best is None or score > best[0]):
                best = (score, vx, vy, vr, vs)
    diag = {"n_cand": len(cands), "n_edge": int(len(pts[0]))}
    if best is None:
        diag["why"] = "no circle with a boundary along >= 60 % of its visible arc"
        return None, diag
    diag["support"] = best[4]
    return best[1:], diag


def _refine_pass(hif, c, R, wf):
    """One refinement pass at full resolution: the circle (cx, cy, r) fitted to the 50 %
    crossings of radial profiles (module docstring, step 4), its ramp, the arc [deg]; or
    None with too few profiles."""
    Cx, Cy, Rr = c
    th, s, prof = _circle_profiles(hif, (Cx, Cy), Rr, R, wf, step_px=2.0)
    if len(th) < _MIN_SUPPORT:
        return None
    inner, outer, spread, usable = _levels(prof, s, wf)
    cand = _boundary_like(inner, outer, spread, usable)
    if cand.sum() < _MIN_SUPPORT:
        return None
    p = np.where(np.isfinite(prof[cand]), prof[cand], outer[cand][:, None])
    s50, s10, s90 = edge_ramp(p, s, outer[cand], inner[cand])
    okk = np.isfinite(s50)
    thc = th[cand][okk]
    rr = Rr + s50[okk]
    P = np.stack([Cx + rr * np.cos(thc), Cy + rr * np.sin(thc)], axis=1)
    span = _angular_span(thc)
    long_arc = span >= _SHORT_ARC_DEG
    c1 = fit_circle(P, init=(Cx, Cy, Rr), huber=1.0) if long_arc else _fit_centre(P, Rr, (Cx, Cy)) + (Rr,)
    res = np.hypot(P[:, 0] - c1[0], P[:, 1] - c1[1]) - c1[2]
    good = np.abs(res) <= 3.0 * max(0.5, 1.4826 * float(np.median(np.abs(res))))
    if good.sum() >= 8:
        c1 = fit_circle(P[good], init=c1) if long_arc else _fit_centre(P[good], Rr, c1[:2]) + (Rr,)
    rmp = (s10 - s90)[okk][good]
    return c1, (float(np.median(rmp)) if rmp.size else 1.0), span


def detect_circle(hi, R, work_size, rng):
    """The circular field boundary inside the content rectangle R (x0, y0, x1, y1) [px] of
    the image hi (H, W) uint8 (the frames' per-pixel maximum brightness).

    Returns ((cx, cy, r50), ramp) [px] (the circle at the 50 % level, the boundary's median
    10-90 % ramp width) or (None, None), and diagnostics (dict).
    """
    import cv2

    H, W = hi.shape
    x0, y0, x1, y1 = R
    scale = min(1.0, float(work_size) / max(H, W))
    ws, hs = max(16, int(round(W * scale))), max(16, int(round(H * scale)))
    sx, sy = W / ws, H / hs
    small = cv2.resize(hi, (ws, hs), interpolation=cv2.INTER_AREA) if scale < 1 else hi
    g = cv2.GaussianBlur(small.astype(np.float32), (0, 0), 1.0)
    # pixel centres: x_w = (x + 0.5) / sx - 0.5
    Rw = ((x0 + 0.5) / sx - 0.5, (y0 + 0.5) / sy - 0.5, (x1 + 0.5) / sx - 0.5, (y1 + 0.5) / sy - 0.5)
    if Rw[2] - Rw[0] < 32 or Rw[3] - Rw[1] < 32:
        return (None, None), {"why": "content rectangle too small"}
    coarse, diag = _coarse_circle(g, Rw, rng)
    if coarse is None:
        return (None, None), diag
    cx, cy, r, sup = coarse
    c0 = ((cx + 0.5) * sx - 0.5, (cy + 0.5) * sy - 0.5, r * 0.5 * (sx + sy))
    diag["coarse"] = [round(v, 2) for v in c0]
    c, ramp = c0, None
    hif = hi.astype(np.float32)
    wf = max(8.0, 2.5 * max(sx, sy) + 6.0)
    for _ in range(3):
        step = _refine_pass(hif, c, R, wf)
        if step is None:
            break
        c, ramp, diag["arc_span_deg"] = step
        wf = max(6.0, min(wf, 3.0 * ramp + 4.0))
    if ramp is None:
        diag["why_refine"] = "refinement failed: using the coarse circle"
        return (c0, max(sx, sy)), diag
    # the refined circle must still be supported along its visible arc
    cw = ((c[0] + 0.5) / sx - 0.5, (c[1] + 0.5) / sy - 0.5)
    w, tol = max(6.0, 0.03 * min(Rw[2] - Rw[0], Rw[3] - Rw[1])), max(2.0, 0.01 * min(Rw[2] - Rw[0], Rw[3] - Rw[1]))
    sup_f = _support(g, cw, c[2] / (0.5 * (sx + sy)), Rw, w, tol)[0]
    diag["support_refined"] = sup_f
    if sup_f["completeness"] < _KEEP_REFINED * sup["completeness"]:
        diag["why_refine"] = "refined circle loses support: using the coarse circle"
        return (c0, ramp), diag
    return (c, ramp), diag
