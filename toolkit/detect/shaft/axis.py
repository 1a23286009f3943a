"""The image of a shaft's axis from its two silhouette edges, with its uncertainty.

A shaft is a cylinder. Its two silhouette edges back-project to the two planes through the
camera centre that touch it; every point of its axis lies at the radius from both, so the
axis lies in the plane that bisects them, and its image is that plane's image
(`plane_bisector`): with the planes' unit normals n1, n2 (``n = K^T l / |K^T l|``, oriented so
that a ray between the edges is on the positive side of both) the axis plane is n1 - n2 and
its image ``l = K^-T (n1 - n2)``. This is exact for any pose, where the 2-D bisector of the
two edges is not (a shaft seen obliquely is wider at its near end on one side than on the
other). Without a camera a nominal pinhole stands in for K (`shaft.work.axis_matrix`).

`midline_from_edges` builds the midline from two `shaft.silhouette.EdgeLine` fits (ideal pixels):
over the stretch where both edges were seen, from the wide (near) end to the narrow one.
Its angle and offset (at the midline's centre) have the covariance propagated linearly from
the two edge fits (their offset and slope variances, a-posteriori: the scatter of the
stations about each line, inflated for correlated station errors, `edges.fit_variances`),
plus a measured floor (`EDGE_FLOOR_PX`): what the edge fits cannot see, a bias of each edge's
position that their stations share (shading, a shadow or a sheen beside the silhouette,
what lies behind the shaft), modelled as an error of sd `EDGE_FLOOR_PX` at either end of
each edge, independent (so the edge's offset gains EDGE_FLOOR_PX^2 / 2 and its slope
2 EDGE_FLOOR_PX^2 / L^2, L its seen length): a short shaft's midline is less sure of its
angle than a long one's.

How the floor was measured (docs/method.md, instrument shafts; tests/toolkit/detect/
test_shafts_real.py repeats it): on the masked real sets (dvrk-suturing-masks,
box-trainer-and-greenscreen), the angle errors of the matched midlines against the
principal axes of the straight parts of the hand-drawn masks, with their propagated
variances v_stat + f^2 v_floor (`Midline.cov_stat`, `cov_floor`), give chi2/N = 1 at f = 2.8
px. It is tested where it was not fitted: each masked frame left out in turn (the others'
floor, 1.9-3.5 px, keeps its midlines within the chi2 0.999 quantile), and the phantom
sequence's fulcrum (chi2/dof of its consistent majority, 1.9-2.7 with this floor).

`measure_edge_pair` measures the edges of a band of the edge cue (`shaft.detector`, frames without
colour contrast) at paired stations across it (each edge where it is seen cleanly, its
gradient peak optionally corrected for the grey-level slopes beside it), each a robust line
fit with one offset per polarity (`class_line_fit`: the gradient peak of a blurred,
gamma-encoded edge leans towards its dark side, so an edge seen against black print sits
apart from the same edge against white paper), the line being its best-seen class.

Positions are working (ideal) pixels [px]; s along and t across a line.

Example
-------
>>> import numpy as np
>>> K = np.array([[500.0, 0, 320], [0, 500.0, 240], [0, 0, 1]])
>>> l1, l2 = np.array([0.0, 1.0, -200.0]), np.array([0.0, 1.0, -260.0])   # y = 200, y = 260
>>> np.round(plane_bisector(K, l1, l2, [320.0, 230.0]), 3).tolist()        # not y = 230
[0.0, 1.0, -230.036]
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pencilcal.toolkit.detect.edges import (
    DEFAULT_GAMMA,
    MIN_STATIONS,
    REJECT_FLOOR_PX,
    derivative_kernel,
    edge_profiles,
    fit_variances,
    masked_median,
    theil_sen,
)
from pencilcal.toolkit.detect.shaft.silhouette import EdgeLine

__all__ = ["EDGE_FLOOR_PX", "plane_bisector", "Midline", "floor_variances", "edge_covariance", "midline_from_edges",
           "class_line_fit", "class_edge", "measure_edge_pair"]

#: The error floor of an edge's position at either end [px], measured on the masked real
#: sets and tested on the phantom sequence (module docstring).
EDGE_FLOOR_PX = 2.8
_MAX_CLUTTER = 0.25  # largest gradient beside an edge point, relative to its own
_MIN_OVERLAP_PX = 10.0  # the two edges must be seen together along at least this [px]


def plane_bisector(K, l1, l2, inside, Kinv=None):
    """The image (3,) of the plane bisecting the planes back-projected from the edge lines
    l1, l2 (3,) [ideal px, homogeneous], normalised (a^2 + b^2 = 1); inside (2,) [px]: a
    point between the edges (it orients the planes); Kinv: K's inverse, when at hand. See
    the module docstring."""
    K = np.asarray(K, float)
    Kinv = np.linalg.inv(K) if Kinv is None else Kinv
    r = Kinv @ np.r_[np.asarray(inside, float), 1.0]
    ns = []
    for ln in (l1, l2):
        n = K.T @ np.asarray(ln, float)
        n = n / np.linalg.norm(n)
        ns.append(n if n @ r >= 0 else -n)
    la = Kinv.T @ (ns[0] - ns[1])
    return la / np.hypot(la[0], la[1])


@dataclass(frozen=True, eq=False)
class Midline:
    """A shaft's axis image over its visible stretch (`midline_from_edges`), ideal pixels.

    Attributes
    ----------
    ends : (2, 2) [px]
        From the wide (near) end to the narrow (far) end.
    line : (3,)
        The axis line ``a x + b y + c = 0``, a^2 + b^2 = 1.
    centre : (2,) [px]
        The midline's centre, where `offset_sigma` holds.
    width_px : float [px]
        The distance between the edges across the axis at the centre.
    angle_sigma : float [rad]
        sd of the midline's angle (floor included).
    offset_sigma : float [px]
        sd of its perpendicular position at the centre (floor included).
    cov : (2, 2)
        Covariance of (angle [rad], offset [px]) (floor included); cov_stat without it, and
        cov_floor the floor's part per px^2 of floor (cov = cov_stat + floor_px^2 cov_floor).
    convergence_deg : float [deg]
        The angle between the two edges.
    edges : (2, 4) [px]
        The two edge lines over their seen stretches ``[x1, y1, x2, y2]``.
    edge_cov : (2, 2, 2)
        Per edge, the covariance of its (angle [rad], offset [px]) errors about the centre of
        its segment in `edges` (`edge_covariance`; floor included): the angle of the
        direction from its first end to its second, the offset along that direction turned
        by +90 deg. What a caller needs to carry the edges' errors into anything built from
        them (the shaft's 3-D axis, `pencil.cylinder.shaft_axis`).
    """

    ends: np.ndarray
    line: np.ndarray
    centre: np.ndarray
    width_px: float
    angle_sigma: float
    offset_sigma: float
    cov: np.ndarray
    cov_stat: np.ndarray
    cov_floor: np.ndarray
    convergence_deg: float
    edges: np.ndarray
    edge_cov: np.ndarray | None = None


def _angle_offset(line, ref):
    """The direction angle [rad] of a line (3,) and the signed distance of ref (2,) from it."""
    return float(np.arctan2(-line[0], line[1])), float(line[0] * ref[0] + line[1] * ref[1] + line[2])


def _axis_jacobian(K, e1, e2, inside, la, ref):
    """Jacobian (2, 4) of (angle [rad], offset at ref [px]) of the plane bisector of edges
    e1, e2 with respect to their (tm, b), by central differences at their sds."""
    Kinv = np.linalg.inv(K)

    def axis(p):
        l = plane_bisector(K, e1.line(e1.tm + p[0], e1.b + p[1]), e2.line(e2.tm + p[2], e2.b + p[3]), inside, Kinv)
        return _angle_offset(l if l[:2] @ la[:2] >= 0 else -l, ref)

    sd = np.sqrt(np.maximum([e1.var_t, e1.var_b, e2.var_t, e2.var_b], 1e-12))
    J = np.zeros((2, 4))
    for k in range(4):
        dp = np.zeros(4)
        dp[k] = sd[k]
        (a1, o1), (a0, o0) = axis(dp), axis(-dp)
        J[:, k] = [np.angle(np.exp(1j * (a1 - a0))) / (2 * sd[k]), (o1 - o0) / (2 * sd[k])]
    return J


def floor_variances(e, floor_px):
    """The (tm, b) variances (2,) an edge `EdgeLine` gains from an error of sd floor_px [px]
    at either end of its seen stretch, independent (module docstring)."""
    L = max(e.s_hi - e.s_lo, 1.0)
    return np.array([0.5 * floor_px**2, 2.0 * floor_px**2 / L**2])


def edge_covariance(e, floor_px=EDGE_FLOOR_PX):
    """(2, 2) covariance of an `EdgeLine`'s (angle [rad], offset [px]) errors about the
    centre of its seen stretch (the midpoint of `EdgeLine.ends`), floor included.

    The fit gives the variances of its offset tm and slope b, uncorrelated at the stations'
    centroid sm; the floor adds `floor_variances` to them, as `midline_from_edges` does. The
    line through ``p0 + s u + (tm + b (s - sm)) n`` has the direction angle
    ``sigma atan(b)`` (sigma = +1 when n is u turned by +90 deg, else -1), so
    ``d angle = sigma db / (1 + b^2)``; its offset at the centre s_c moves by
    ``dtm + (s_c - sm) db`` along n, ``sigma / sqrt(1 + b^2)`` of that across the line.
    The signs cancel in the covariance (angle and offset both follow the segment's own
    direction, `pencil.cylinder` conventions).

    >>> import numpy as np
    >>> e = EdgeLine(np.zeros(2), np.array([1.0, 0.0]), np.array([0.0, 1.0]), 30.0, 0.0, 0.0, 0.01, 1e-6,
    ...              0.0, 100.0, 50, 1.0, 0.1)
    >>> c = edge_covariance(e, floor_px=0.0)                 # centroid 20 px before the centre
    >>> np.round(c / [[1e-6, 1e-5], [1e-5, 1e-2]], 6).tolist()
    [[1.0, 2.0], [2.0, 1.04]]
    """
    var = np.array([e.var_t, e.var_b]) + floor_variances(e, floor_px)
    sc = 0.5 * (e.s_lo + e.s_hi)
    q = 1.0 + e.b * e.b
    J = np.array([[0.0, 1.0 / q], [1.0 / np.sqrt(q), (sc - e.sm) / np.sqrt(q)]])
    return (J * var) @ J.T


def midline_from_edges(K, e1, e2, floor_px=EDGE_FLOOR_PX):
    """The midline (`Midline`) of the shaft between the edge fits e1, e2 (`EdgeLine`,
    ideal px), or None when they are not seen together along `_MIN_OVERLAP_PX` or meet
    within the stretch (they are no silhouettes of one cylinder).

    K: (3, 3) the camera matrix (`shaft.work.axis_matrix`); floor_px: the edges' error
    floor [px] (`floor_variances`).

    >>> import numpy as np
    >>> mk = lambda y, n: EdgeLine(np.array([0.0, y]), np.array([1.0, 0.0]), np.array([0.0, n]), 50.0, 0.0,
    ...                            0.0, 0.01, 1e-6, 0.0, 100.0, 50, 1.0, 0.1)
    >>> m = midline_from_edges(np.array([[500.0, 0, 50], [0, 500.0, 40], [0, 0, 1]]), mk(20.0, -1.0), mk(60.0, 1.0),
    ...                        floor_px=0.0)
    >>> round(m.width_px, 2), np.round(m.centre, 2).tolist(), round(float(m.offset_sigma), 3)
    (40.0, [50.0, 40.0], 0.071)
    """
    ends = [e.ends() for e in (e1, e2)]
    mid = 0.25 * (ends[0][0] + ends[0][1] + ends[1][0] + ends[1][1])
    l1, l2 = e1.line(), e2.line()
    la = plane_bisector(K, l1, l2, mid)
    ua, na = np.array([la[1], -la[0]]), la[:2]
    e_a = np.sort((ends[0] - mid) @ ua)
    e_b = np.sort((ends[1] - mid) @ ua)
    lo, hi = max(e_a[0], e_b[0]), min(e_a[1], e_b[1])
    if hi - lo < _MIN_OVERLAP_PX:
        return None
    vp = np.cross(l1, l2)
    if abs(vp[2]) > 1e-12:
        s_vp = float((vp[:2] / vp[2] - mid) @ ua)
        if lo <= s_vp <= hi:
            return None
    foot = mid - (la[:2] @ mid + la[2]) * la[:2]
    A, B = foot + lo * ua, foot + hi * ua
    ref = foot + 0.5 * (lo + hi) * ua

    def width(P):
        return abs(float(-(l1[:2] @ P + l1[2]) / (l1[:2] @ na) + (l2[:2] @ P + l2[2]) / (l2[:2] @ na)))

    if width(B) > width(A):
        A, B = B, A
    J = _axis_jacobian(K, e1, e2, mid, la, ref)
    cov_stat = (J * np.array([e1.var_t, e1.var_b, e2.var_t, e2.var_b])) @ J.T
    cov = cov_stat + (J * np.r_[floor_variances(e1, floor_px), floor_variances(e2, floor_px)]) @ J.T
    d1, d2 = l1[:2], l2[:2]
    conv = float(np.degrees(np.arccos(np.clip(abs(d1 @ d2), 0.0, 1.0))))
    return Midline(ends=np.stack([A, B]), line=la, centre=ref, width_px=width(ref),
                   angle_sigma=float(np.sqrt(cov[0, 0])), offset_sigma=float(np.sqrt(cov[1, 1])), cov=cov,
                   cov_stat=cov_stat, cov_floor=(J * np.r_[floor_variances(e1, 1.0), floor_variances(e2, 1.0)]) @ J.T,
                   convergence_deg=conv, edges=np.stack([ends[0].reshape(-1), ends[1].reshape(-1)]),
                   edge_cov=np.stack([edge_covariance(e1, floor_px), edge_covariance(e2, floor_px)]))


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
    present = np.unique(cls[base])
    masks = {c: cls == c for c in present}
    classes = [c for c in present if np.count_nonzero(base & masks[c]) >= 4]
    if not classes:
        return None
    cm = [masks[c] for c in classes]
    okc = [base & m for m in cm]  # the stations of each class
    ok = np.logical_or.reduce(okc)
    big = max(range(len(classes)), key=lambda k: w[okc[k]].sum())
    b = theil_sen(s[None], t[None], okc[big][None])[0][0]
    if not np.isfinite(b):
        return None
    inl = ok.copy()
    off = [None] * len(classes)
    for it in range(iters):
        r = np.full(s.shape, np.inf)
        for k in range(len(classes)):
            m = (inl & cm[k]) if it else okc[k]
            if not m.any():
                continue
            if it == 0:
                off[k] = np.median(t[m] - b * s[m])
            sel = okc[k]
            r[sel] = t[sel] - b * s[sel] - off[k]
        ar = np.abs(r)
        sc = 1.4826 * np.median(ar[ok & np.isfinite(r)])
        new = ok & (ar <= max(3.0 * sc, floor_px))
        if np.count_nonzero(new) < MIN_STATIONS:
            return None
        if it >= 2 and np.array_equal(new, inl):
            break  # the same inliers give the same fit: every further pass repeats this one
        inl = new
        # weighted least squares: one slope, class offsets
        num = den = 0.0
        sub = []
        for k in range(len(classes)):
            m = inl & cm[k]
            wc = w[m]
            if wc.size == 0:
                sub.append(None)
                continue
            sk, tk = s[m], t[m]
            sub.append((wc, sk, tk))
            W = wc.sum()
            ds = sk - (wc * sk).sum() / W
            num += (wc * ds * (tk - (wc * tk).sum() / W)).sum()
            den += (wc * ds**2).sum()
        if den <= 0:
            return None
        b = num / den
        for k, got in enumerate(sub):
            if got is not None:
                wc, sk, tk = got
                off[k] = (wc * (tk - b * sk)).sum() / wc.sum()
    return b, {c: off[k] for k, c in enumerate(classes) if off[k] is not None}, inl


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


def class_edge(P0, U, n_ab, s, t, w, base, g):
    """One edge of a band from its stations (S,) (`class_line_fit`, one offset per
    polarity): an `EdgeLine` on its best-seen class, n pointing out of the band, with the
    variances of that class' offset and of the common slope (`edges.fit_variances`), and
    its inlier stations (S,); or None.

    P0 (2,) [px], U (2,): the edge's first point and unit direction, the stations s (S,)
    [px] along U from P0; n_ab (2,): the unit normal into the band (the profiles' +t
    side); t (S,) [px]: each station's edge along n_ab; w (S,): its weight; base (S,) bool:
    the stations with an edge; g (S,): its signed derivative (the polarity classes).

    >>> import numpy as np
    >>> s = np.arange(20.0); g = np.where(s % 2 == 0, 2.0, -1.0)   # two polarities, 0.6 px apart
    >>> e, inl = class_edge(np.zeros(2), np.array([1.0, 0.0]), np.array([0.0, 1.0]), s, np.where(g > 0, 0.3, -0.3),
    ...                     g * g, np.ones(20, bool), g)
    >>> round(e.tm, 3) + 0.0, round(e.b, 3) + 0.0, int(inl.sum())     # the stronger class, t along -n_ab
    (-0.3, 0.0, 20)
    """
    cls = (g > 0).astype(int)
    fit = class_line_fit(s, t, w, base, cls)
    if fit is None:
        return None
    b, off, inl = fit
    c0 = max(off, key=lambda c: np.sum(w[inl & (cls == c)]))
    offs = np.zeros(s.shape)
    for c, v in off.items():
        offs[cls == c] = v
    res = np.where(inl, t - b * s - offs, 0.0)
    sel = inl & (cls == c0)
    wc = np.where(sel, w, 0.0)
    Wt = max(float(wc.sum()), 1e-300)
    sm = float(np.sum(wc * s) / Wt)
    Sss = 0.0
    for c in off:
        m = inl & (cls == c)
        if m.any():
            sc = np.sum(w[m] * s[m]) / np.sum(w[m])
            Sss += float(np.sum(w[m] * (s[m] - sc) ** 2))
    var_b, var_t = fit_variances(res[None], w[None], inl[None], np.array([max(Sss, 1e-300)]), np.array([Wt]))
    sv = s[inl]
    # the frame of EdgeLine: the outward normal is -n_ab (t and the slope change sign)
    return EdgeLine(p0=P0, u=U, n=-n_ab, sm=sm, tm=-float(off[c0] + b * sm), b=-float(b), var_t=float(var_t[0]),
                    var_b=float(var_b[0]), s_lo=float(sv.min()), s_hi=float(sv.max()), count=int(inl.sum()),
                    frac=float(inl.sum()) / max(int(base.sum()), 1), rms=float(np.sqrt(np.mean(res[inl] ** 2)))), inl


def _measure_edges(img, camera, one, pts, shaft, search, kernel, sigma_px, slope_correction, guard_px, gamma):
    """Both edges of the band `one` (`pairs.EdgePairs`, one pair) measured at the stations
    pts (S, 2) on its bisector where each is seen cleanly (no other edge beside it), each
    fitted on its own (`class_edge`); both must fit at `MIN_STATIONS` shaft stations at
    least. Returns the two `EdgeLine` and their `EdgePairs`, or None."""
    from pencilcal.toolkit.detect.pairs import antiparallel_pairs, pair_geometry

    w, P0, U, s2 = _edge_frames(one, pts)
    n_ab = np.stack([-U[:, 1], U[:, 0]], -1)
    p = edge_profiles(img, camera, P0, U, s2, search, kernel, sigma_px, unsigned=True,
                      slope_correction=slope_correction, guard_px=guard_px, gamma=gamma)
    a = np.abs(p.g)
    base = p.inside & p.found & (a > 0) & (p.clutter <= _MAX_CLUTTER) & (w[0] * np.sign(np.median(w[0])) > 0)[None, :]
    med = masked_median(a, base & shaft[None, :])
    base &= a >= 0.35 * np.nan_to_num(med, nan=np.inf)[:, None]
    w2 = np.where(base, a * a, 0.0)
    w2 = w2 / np.maximum(np.nan_to_num(masked_median(w2, base), nan=1.0), 1e-300)[:, None]
    edges, both = [], shaft.copy()
    for e in range(2):
        fit = class_edge(P0[e], U[e], n_ab[e], s2[e], p.t[e], w2[e], base[e], p.g[e])
        if fit is None:
            return None
        edges.append(fit[0])
        both &= fit[1]
    if both.sum() < MIN_STATIONS:
        return None
    seg = np.stack([edges[0].ends().reshape(-1), edges[1].ends().reshape(-1)])
    pair = pair_geometry(*antiparallel_pairs(seg, np.array([0]), np.array([1])))
    return edges, pair


def measure_edge_pair(img, camera, pr, k, lo, hi, shaft_at, search, sigma_px, slope_correction, gamma=DEFAULT_GAMMA):
    """The two edges of band k of `pr` (`pairs.EdgePairs`) measured at paired stations over
    its run [lo, hi] [px] along its bisector (module docstring): each edge at every station
    of the run where it is seen cleanly and the band was seen as a shaft (shaft_at(s) ->
    bool), twice (the second time with the search narrowed to 1.5 px around the first fit).
    search, sigma_px [px]: the edge search half-width and the Gaussian-derivative sd; gamma:
    the frame's encoding gamma (each edge located on linear light, `edges.edge_profiles`).
    Returns the two `shaft.silhouette.EdgeLine` (working px) or None.
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
    edges = None
    for it in range(2):
        got = _measure_edges(img, camera, one, pts, shaft, search if it == 0 else min(search, 1.5), kernel,
                             sigma_px, slope_correction, guard_px, gamma)
        if got is None:
            return None
        edges, one = got
    return edges
