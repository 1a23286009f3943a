"""Reference shaft axes from hand-drawn instrument masks (the real-set tests' ground truth).

For each connected component of an instrument mask (at least `min_area` pixels):

1. its outer contour, less the points on the image border or on the valid region's boundary
   (the mask stops there; that is no silhouette);
2. RANSAC for the longest straight stretch: a line through two contour points, its inliers
   (within `tol` px), and among them the longest run of contour-consecutive inliers (gaps up
   to `gap` points): a silhouette edge is one contiguous stretch of the boundary;
3. the same for the second edge, among stretches within 12 deg of the first, on the other
   side of the mask, 15-320 px away;
4. each edge refitted by total least squares to its run; the straight shaft is where both
   runs overlap along the axis (the wrist and jaws are left out: their boundary is not on
   these two lines).

The reference axis is the plane bisector of the two edges (`shaft.axis.plane_bisector`, the
detector's construction, with the same nominal camera), its point the middle of the overlap.
The masks are polygons drawn by hand, straight to about a pixel, and one follows a shaft's
shadow for part of its length: a reference good to a few tenths of a degree.
"""
from __future__ import annotations

import numpy as np


def _line_tls(P):
    c = P.mean(0)
    u = np.linalg.svd(P - c, full_matrices=False)[2][0]
    return c, u, np.array([-u[1], u[0]])


def _runs(flag, gap):
    """Runs of True in a cyclic bool array, bridging gaps of up to `gap` False: index arrays."""
    N = flag.size
    idx = np.flatnonzero(flag)
    if idx.size == 0:
        return []
    d = np.diff(np.r_[idx, idx[0] + N])
    start = (np.argmax(d) + 1) % idx.size
    order = np.r_[idx[start:], idx[:start] + N]
    runs, cur = [], [order[0]]
    for a, b in zip(order[:-1], order[1:]):
        if b - a <= gap + 1:
            cur.append(b)
        else:
            runs.append(np.array(cur) % N)
            cur = [b]
    runs.append(np.array(cur) % N)
    return runs


def _best_stretch(P, usable, rng, tol=2.5, gap=10, iters=800, constraint=None):
    cand = np.flatnonzero(usable)
    if cand.size < 10:
        return None
    best = None
    for _ in range(iters):
        i, j = rng.choice(cand, 2, replace=False)
        d = P[j] - P[i]
        L = np.hypot(*d)
        if L < 20:
            continue
        u = d / L
        n = np.array([-u[1], u[0]])
        if constraint is not None and not constraint(u, P[i]):
            continue
        for run in _runs((np.abs((P - P[i]) @ n) < tol) & usable, gap):
            if best is None or run.size > best.size:
                best = run
    if best is None:
        return None
    for _ in range(2):
        c, u, n = _line_tls(P[best].astype(float))
        runs = [q for q in _runs((np.abs((P - c) @ n) < tol) & usable, gap) if np.intersect1d(q, best).size]
        if not runs:
            break
        best = max(runs, key=len)
    return best


def _edges(C, comp, usable, rng):
    """The two silhouette stretches of one component's contour C (N, 2), or None."""
    run1 = _best_stretch(C, usable, rng)
    if run1 is None or run1.size < 40:
        return None
    c1, u1, n1 = _line_tls(C[run1].astype(float))
    ys, xs = np.nonzero(comp)
    side = np.sign(np.median((np.c_[xs, ys] - c1) @ n1))
    us2 = usable.copy()
    us2[run1] = False

    def other_side(u, p0):
        return abs(u @ u1) >= np.cos(np.radians(12)) and 15 < (p0 - c1) @ n1 * side < 320

    run2 = _best_stretch(C, us2, rng, constraint=other_side)
    if run2 is None or run2.size < 40:
        return None
    return run1, run2


def reference_axes(mask, valid, K, min_area=3000, seed=0):
    """Reference axes of the instruments of a mask (H, W) bool, inside the valid region's
    mask valid (H, W) bool: a list of dicts with `line` (3,) the axis (a^2 + b^2 = 1) and
    `mid` (2,) its point [px], `edges` the two stretches' points."""
    import cv2

    from pencilcal.toolkit.detect.shaft.axis import plane_bisector

    H, W = mask.shape
    rng = np.random.default_rng(seed)
    n_lab, lab, st, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8), connectivity=8)
    vb = cv2.erode(valid.astype(np.uint8), np.ones((7, 7), np.uint8))
    out = []
    for k in range(1, n_lab):
        if st[k, 4] < min_area:
            continue
        comp = (lab == k).astype(np.uint8)
        cs, _ = cv2.findContours(comp, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
        C = max(cs, key=len)[:, 0, :]
        usable = (C[:, 0] > 2) & (C[:, 0] < W - 3) & (C[:, 1] > 2) & (C[:, 1] < H - 3) & (vb[C[:, 1], C[:, 0]] > 0)
        got = _edges(C, comp, usable, rng)
        if got is None:
            continue
        (c1, u1, _), (c2, u2, _) = (_line_tls(C[r].astype(float)) for r in got)
        s1, s2 = C[got[0]] @ u1, C[got[1]] @ u1
        lo, hi = max(s1.min(), s2.min()), min(s1.max(), s2.max())
        if hi - lo < 20:
            continue
        s_mid = 0.5 * (lo + hi)
        mid = 0.5 * (c1 + (s_mid - c1 @ u1) / (u1 @ u1) * u1 + c2 + (s_mid - c2 @ u1) / (u2 @ u1) * u2)
        lines = [np.cross(np.r_[c, 1.0], np.r_[c + u, 1.0]) for c, u in ((c1, u1), (c2, u2))]
        la = plane_bisector(K, lines[0], lines[1], mid)
        out.append(dict(line=la, mid=mid - (la[:2] @ mid + la[2]) * la[:2], edges=(C[got[0]], C[got[1]])))
    return out
