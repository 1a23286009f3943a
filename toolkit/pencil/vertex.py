"""The vertex (fulcrum) of a pencil of image lines: robust weighted intersection and its bound.

Lines of an instrument pivoting about a fixed point all pass through that point's image.
This module intersects measured segments in *undistorted* ("ideal") pixel coordinates (the
caller undistorts) and reports the vertex with its covariance.

Conventions
-----------
- A segment is ``[x1, y1, x2, y2]`` [px], u right and v down (angles.py).
- Its line is ``a x + b y + c = 0`` with ``(a, b)`` a unit *normal*: the direction
  ``d = (x2 - x1, y2 - y1) / L`` turned by +90 deg, ``n = (-d_y, d_x)``; ``c = -n . m`` with
  ``m`` the segment centre. ``n . p + c`` is the signed perpendicular distance of p [px].
- Noise model (docs/method.md, "The fulcrum"): a fitted line is perturbed by an angle error
  (sd ``sigma_theta`` [rad]) that *pivots about the segment centre* and an independent
  perpendicular shift (sd ``sigma_c`` [px]). The perpendicular distance of the true vertex
  p from the measured line then has variance

      sigma_k^2 = sigma_c^2 + r_k^2 sigma_theta^2,    r_k = d_k . (p - m_k),

  r_k being the distance *along the line* from the segment centre to the foot of p (the
  lever arm of the angle error). Centre and angle errors are uncorrelated for a segment
  measured by its two end points or fitted through edge points centred on m, which is why
  the centre is the pivot. With this model the weighted least-squares intersection reaches
  the Cramer-Rao bound ``Cov = (sum n_k n_k^T / sigma_k^2)^-1`` (`vertex_crlb`; Monte Carlo
  RMSE / bound = 1.00-1.03 in tests/toolkit/pencil/test_vertex.py: 0.92 / 0.36 / 0.31 px for
  8 lines over 30 / 90 / 180 deg, 80-400 px from the vertex, 0.1 deg and 0.2 px of noise).
- Covariances are px^2 in the same pixel frame; `propagate_cov` carries them into
  normalised coordinates (or anywhere else through a Jacobian).

Example
-------
>>> import numpy as np
>>> v = np.array([320.0, 240.0])
>>> phi = np.radians([0.0, 40.0, 80.0, 120.0])
>>> d = np.stack([np.cos(phi), np.sin(phi)], -1)
>>> segs = np.concatenate([v + 100 * d, v + 300 * d], -1)       # (4, 4) spokes 100..300 px
>>> fit = intersect_lines(segs, angle_sigma=np.radians(0.1), offset_sigma=0.2)
>>> np.round(fit.vertex, 9).tolist(), fit.lines_used
([320.0, 240.0], 4)
>>> bool(np.allclose(fit.cov, vertex_crlb(v, segs, np.radians(0.1), 0.2)))
True
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from pencilcal.toolkit.geometry.angles import wrap_line
from pencilcal.toolkit.geometry.quantiles import chi2_isf
from pencilcal.toolkit.errors import EstimationError, InputError

__all__ = [
    "SegmentLines",
    "floored_vertex_cov",
    "segment_lines",
    "segment_angle_sigma",
    "VertexFit",
    "intersect_lines",
    "lines_through",
    "vertex_crlb",
    "propagate_cov",
    "LOCAL_CANDIDATES",
]


class SegmentLines(NamedTuple):
    """Line form of segments. Leading shape (...) as the segments'.

    normal: (..., 2) unit normal (a, b); offset: (...) c [px] with a x + b y + c = 0;
    centre: (..., 2) segment midpoint [px]; length: (...) [px];
    direction: (..., 2) unit vector from the first to the second end point.
    """

    normal: np.ndarray
    offset: np.ndarray
    centre: np.ndarray
    length: np.ndarray
    direction: np.ndarray


def segment_lines(segments):
    """Unit-normal line form of segments.

    segments: (..., 4) ``[x1, y1, x2, y2]`` [px]. Returns a `SegmentLines`; zero-length
    segments give NaN normals (validate first, `intersect_lines` does).

    >>> L = segment_lines([0.0, 5.0, 10.0, 5.0])                    # the line y = 5
    >>> L.normal.tolist(), float(L.offset), L.centre.tolist(), float(L.length)
    ([-0.0, 1.0], -5.0, [5.0, 5.0], 10.0)
    """
    s = np.asarray(segments, dtype=float)
    p1, p2 = s[..., 0:2], s[..., 2:4]
    delta = p2 - p1
    length = np.hypot(delta[..., 0], delta[..., 1])
    with np.errstate(invalid="ignore", divide="ignore"):
        d = delta / length[..., None]
    n = np.stack([-d[..., 1], d[..., 0]], -1)
    centre = 0.5 * (p1 + p2)
    c = -np.sum(n * centre, -1)
    return SegmentLines(n, c, centre, length, d)


def segment_angle_sigma(segments, endpoint_sigma_px):
    """Angle sd [rad] of segments known only by their two end points.

    Each end point carries independent isotropic noise of sd `endpoint_sigma_px` per
    coordinate; only the components perpendicular to the segment turn it, so
    ``sigma_theta = sqrt(2) * sigma / L``. (The perpendicular offset at the centre then has sd
    ``sigma / sqrt(2)``, uncorrelated with the angle.) A line fitted through many edge
    points is better than this; pass its own sd to `intersect_lines` when known.

    segments: (..., 4) [px]; endpoint_sigma_px: scalar or broadcastable [px]. Returns (...).

    >>> round(float(np.degrees(segment_angle_sigma([0, 0, 100, 0], 1.0))), 4)
    0.8103
    """
    length = segment_lines(segments).length
    return np.sqrt(2.0) * np.asarray(endpoint_sigma_px, dtype=float) / length


@dataclass(frozen=True, eq=False)
class VertexFit:
    """Result of `intersect_lines`. M is the number of input segments.

    vertex: (2,) [px] estimated intersection (undistorted pixels).
    cov: (2, 2) [px^2] its covariance from the noise model, (sum_inliers n n^T / sigma^2)^-1
        at the estimate: the Cramer-Rao bound evaluated at the estimate. Not rescaled by the
        residuals; compare `rms` with 1 to judge the noise model.
    inliers: (M,) bool, lines used in the final fit (all True when ``robust=False``).
    residuals: (M,) normalised signed perpendicular residuals (n . vertex + c) / sigma_k, of
        every line, outliers included.
    sigmas: (M,) [px] sd of each line's perpendicular distance at the vertex, sigma_k.
    lines_used: number of inliers.
    rms: RMS of `residuals` over the inliers (~1 when the noise model is right).
    rms_px: RMS perpendicular distance [px] of the inlier lines from the vertex.
    chi2: sum of squared normalised residuals of the inliers; dof = lines_used - 2.
    chi2_infinity: the same for the best point at infinity (all inliers parallel); the
        gain chi2_infinity - chi2 is the evidence that the vertex is finite. Exact when the
        test is close, else a lower bound (already decisive).
    condition: condition number of the information matrix sum n n^T / sigma^2.
    iterations: reweighting iterations of the last least-squares solve.
    gain: the MSAC evidence for the vertex, sum over the lines of T^2 - min(e_k^2, T^2)
        (each inlier adds up to T^2, the chi-square(1) inlier quantile; 0: no line through it).
    rival_gain: the same for the best other vertex the robust search found that shares at
        most two lines with this one (0 when there is none): in clutter, where random
        segments meet anywhere, it is close to `gain`, and the vertex is then one of many.
    rival_vertex: (2,) [px] that other vertex, or None.
    rival_lines: the lines through it.
    """

    vertex: np.ndarray
    cov: np.ndarray
    inliers: np.ndarray
    residuals: np.ndarray
    sigmas: np.ndarray
    lines_used: int
    rms: float
    rms_px: float
    chi2: float
    chi2_infinity: float
    condition: float
    iterations: int
    gain: float = 0.0
    rival_gain: float = 0.0
    rival_vertex: np.ndarray | None = None
    rival_lines: int = 0

    @property
    def dof(self) -> int:
        return self.lines_used - 2

    @property
    def std(self) -> np.ndarray:
        """(2,) [px] sd of u and v."""
        return np.sqrt(np.diag(self.cov))

    def ellipse(self, k=1.0):
        """Error ellipse: (major, minor) semi-axes [px] at k sd and the major axis's image
        angle [rad] in (-pi/2, pi/2]."""
        w, V = np.linalg.eigh(self.cov)
        ang = np.arctan2(V[1, 1], V[0, 1])
        ang = np.remainder(ang + np.pi / 2, np.pi) - np.pi / 2
        return k * np.sqrt(max(w[1], 0.0)), k * np.sqrt(max(w[0], 0.0)), float(ang)


# --------------------------------------------------------------------------- validation


def _check_segments(segments):
    try:
        s = np.asarray(segments, dtype=float)
    except (TypeError, ValueError):
        raise InputError("segments: expected an (M, 4) array of numbers [x1, y1, x2, y2]") from None
    if s.ndim != 2 or s.shape[1] != 4:
        raise InputError(f"segments: expected shape (M, 4) [x1, y1, x2, y2], got {s.shape}")
    bad = ~np.all(np.isfinite(s), axis=1)
    if np.any(bad):
        raise InputError(f"segments: row {int(np.argmax(bad))} is not finite (NaN or inf)")
    return s


def _check_sigma(value, m, name, positive):
    try:
        a = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise InputError(f"{name}: expected a number or {m} numbers") from None
    if a.ndim > 1 or (a.ndim == 1 and a.shape[0] != m):
        raise InputError(f"{name}: expected a scalar or shape ({m},), got {a.shape}")
    a = np.broadcast_to(a, (m,)).astype(float)
    if not np.all(np.isfinite(a)) or np.any(a < 0) or (positive and np.any(a == 0)):
        sign = "> 0" if positive else ">= 0"
        raise InputError(f"{name}: must be finite and {sign}, got {value!r}")
    return a


# --------------------------------------------------------------------------- core


def _line_var(p, lines, dm, st2, sc2):
    """Variance (M,) or (P, M) of the perpendicular distance of p (2,) or (P, 2) from each line.

    dm: (M,) d_k . m_k, so that the lever arm d_k . (p - m_k) is one matrix product.
    """
    r = p @ lines.direction.T - dm
    return sc2 + r * r * st2


def _normalised_residuals(p, lines, dm, st2, sc2, extra_var=None):
    """Distances (M,) of p (2,) from the lines over their sd, and those sds (M,);
    `extra_var` (M,) adds to the variances (the point's own uncertainty along each normal)."""
    var = _line_var(p, lines, dm, st2, sc2)
    if extra_var is not None:
        var = var + extra_var
    sig = np.sqrt(var)
    return (lines.normal @ p + lines.offset) / sig, sig


def _chi2_infinity(phi, st2, enough):
    """Smallest chi2 of the lines about a common point at infinity (all lines parallel).

    phi: (K,) line directions [rad]; st2: (K,) angle variances; enough: the caller only
    needs to know whether the value exceeds this.

    As the vertex runs off to infinity along u, line k's normalised residual tends to
    tan(phi_k - phi_u) / sigma_theta_k. With sin in place of tan the minimum over u has the
    closed form (W - |sum w_k exp(2 i phi_k)|) / 2, w_k = 1 / sigma_theta_k^2: a lower bound,
    returned when it already exceeds `enough` (the usual, well-spread case). Otherwise
    minimise the exact sum: it is convex between consecutive poles phi_k +- pi/2, so start
    from the best line direction and search the interval between its neighbouring poles.
    """
    if np.any(st2 <= 0):
        return np.inf  # exact angles: only exactly parallel lines meet at infinity
    w = 1.0 / st2
    lower = 0.5 * max(float(np.sum(w) - abs(np.sum(w * np.exp(2j * phi)))), 0.0)
    if lower >= enough:
        return lower

    def f(u):
        return np.sum(w * np.tan(wrap_line(u - phi)) ** 2, -1)

    # the sum at every line's own direction, (K, K) in rows of ~1M entries (8 MB)
    rows = max(1, (1 << 20) // phi.size)
    at_lines = np.concatenate([f(phi[i : i + rows, None]) for i in range(0, phi.size, rows)])
    best = phi[int(np.argmin(at_lines))]
    up = np.remainder(phi + np.pi / 2 - best, np.pi)  # distance to each pole going up
    up = up[up > 1e-12]
    if up.size == 0:  # every line along `best`: exactly parallel
        return 0.0
    hi = best + float(np.min(up))
    lo = best - float(np.min(np.pi - up))
    pad = 1e-9 * (hi - lo)
    from scipy.optimize import minimize_scalar

    res = minimize_scalar(f, bounds=(lo + pad, hi - pad), method="bounded", options={"xatol": 1e-12})
    return float(min(res.fun, f(best)))


def _weighted_ls(p0, n, c, D, dm, st2, sc2, tol, max_iter):
    """Iteratively reweighted LS intersection of lines (K rows each), starting at p0.

    The weights 1/sigma_k^2 depend on the vertex through the lever arms r_k, so solve with
    the weights frozen, update them, repeat; the weights vary slowly with p, so this
    converges in a few steps. Returns (p, iterations).
    """
    p = np.asarray(p0, dtype=float)
    it = 0
    for it in range(1, max_iter + 1):
        r = D @ p - dm
        nw = n / (sc2 + r * r * st2)[:, None]
        (f00, f01), (_, f11) = (nw.T @ n).tolist()
        # solve for the step from the residuals at p, not for p from the offsets c: the
        # normal equations square the condition number, and the error they leave scales
        # with the right-hand side, which is tiny near the solution
        g0, g1 = (-(nw.T @ (n @ p + c))).tolist()
        det = f00 * f11 - f01 * f01
        if not det > 1e-15 * (f00 + f11) ** 2:  # also catches NaN
            raise EstimationError("vertex: the lines are parallel, they meet only at infinity")
        step = np.array([f11 * g0 - f01 * g1, f00 * g1 - f01 * g0]) / det
        p = p + step
        if float(np.max(np.abs(step))) <= tol * (1.0 + float(np.max(np.abs(p)))):
            break
    return p, it


def _pair_hypotheses(lines, max_pairs, seed, min_sin):
    """Intersections (P, 2) of line pairs: all pairs if few, else a seeded sample."""
    m = lines.normal.shape[0]
    total = m * (m - 1) // 2
    if total <= max_pairs:
        i, j = np.triu_indices(m, 1)
    else:
        # a seeded sample keeps the result deterministic; even with 50 % outliers a random
        # pair is clean with probability 1/4, so 1024 pairs all miss with probability 1e-128;
        # the refinement, not the number of pairs, gives the accuracy
        rng = np.random.default_rng(seed)
        i = rng.integers(0, m, size=max_pairs)
        j = (i + rng.integers(1, m, size=max_pairs)) % m
    ni, nj = lines.normal[i], lines.normal[j]
    ci, cj = lines.offset[i], lines.offset[j]
    det = ni[:, 0] * nj[:, 1] - ni[:, 1] * nj[:, 0]  # sin of the angle between the lines
    ok = np.abs(det) > min_sin
    det = np.where(ok, det, 1.0)
    x = (-ci * nj[:, 1] + cj * ni[:, 1]) / det
    y = (-ni[:, 0] * cj + nj[:, 0] * ci) / det
    return np.stack([x, y], -1)[ok]


def _msac_costs(hyp, lines, dm, st2, sc2, t2, consistent):
    """MSAC cost sum_k min(e_k^2, T^2) (P,) of every hypothesis hyp (P, 2) [px] from its
    (P, M) normalised residuals, in blocks of ~16k entries (128 kB): temporaries that leave
    the cache cost more than the arithmetic. A line counts only where `consistent`."""
    m = lines.normal.shape[0]
    step = max(1, 16384 // m)
    cost = np.empty(hyp.shape[0])
    for i in range(0, hyp.shape[0], step):
        h = hyp[i : i + step]
        d = h @ lines.normal.T + lines.offset
        c = np.minimum(d * d / _line_var(h, lines, dm, st2, sc2), t2)
        if consistent is not None:
            c = np.where(consistent(h), c, t2)
        cost[i : i + step] = c.sum(1)
    return cost


def _msac_cost(p, e, t2, consistent):
    """MSAC cost sum_k min(e_k^2, T^2) of the point p (2,) from its normalised residuals e
    (M,), a line counting only where `consistent` (T^2 elsewhere)."""
    c = np.minimum(e * e, t2)
    if consistent is not None:
        c = np.where(consistent(np.asarray(p, float)[None])[0], c, t2)
    return float(c.sum())


def _refine_inliers(p, fit, classify, inliers, t2, start=None):
    """Weighted LS from p (2,) on its inliers (or, the first time, the lines `start` (M,)),
    re-classifying the lines until the inlier set is stable (2-3 rounds). Returns (p (2,),
    mask (M,), iterations, MSAC cost at p). EstimationError when fewer than two lines agree."""
    e, _ = classify(p)
    mask = inliers(p, e) if start is None else start
    for _ in range(10):
        if np.count_nonzero(mask) < 2:
            raise EstimationError("vertex: fewer than two lines agree on a common point")
        p, it = fit(p, mask)
        e, _ = classify(p)
        new = inliers(p, e)
        if np.array_equal(new, mask):
            break
        mask = new
    else:  # still changing (lines on the threshold): keep the last set, fit it
        if np.count_nonzero(mask) < 2:
            raise EstimationError("vertex: fewer than two lines agree on a common point")
        p, it = fit(p, mask)
        e, _ = classify(p)
    return p, mask, it, float(np.sum(np.where(inliers(p, e), np.minimum(e * e, t2), t2)))


#: With `intersect_lines`' start: a line whose squared normalised residual is over this
#: fraction of the inlier gate is also tried left out (the lower MSAC cost is kept).
NEAR_GATE = 0.25


def _refine_given(given, fit, refine, classify, t2):
    """`intersect_lines`' start: the vertex refined from the lines `given` (M,) bool, as
    `_refine_inliers` returns it, or None where they give none (fewer than two agreeing) or
    one that leaves a given line out (a wrong one among them pulled it): the search decides.
    A line it keeps near the gate (squared normalised residual over `NEAR_GATE` of it) is
    also tried left out, and the lower MSAC cost kept: the search, choosing by that cost,
    would leave it out."""
    m = given.size
    try:
        # from the offset-only solution of the given lines, as without a search
        best = refine(fit(np.zeros(2), given, 1, np.zeros(m))[0], given)
    except EstimationError:
        return None
    if np.any(given & ~best[1]):
        return None  # a given line is not through it: a wrong one among them, which the search finds
    e = classify(best[0])[0]
    for k in np.flatnonzero(best[1] & (e * e > NEAR_GATE * t2)):
        try:
            other = refine(best[0], best[1] & (np.arange(m) != k))
        except EstimationError:
            continue
        if other[3] < best[3] - 1e-9 * max(1.0, abs(best[3])):
            best = other
    return best


#: Hypotheses (best first) refined before the vertex is chosen (local optimisation); the
#: rival vertex (VertexFit.rival_gain) is the best of them.
LOCAL_CANDIDATES = 16


def _local_optimisation(hyp, cost, refine, start_inliers, no_vertex, spread):
    """Refine the `LOCAL_CANDIDATES` best hypotheses hyp (P, 2) by their MSAC cost (P,) and
    keep the best refined vertex; a pair's intersection is noisy, and in clutter a random
    point near many lines can score better than the true vertex before refinement.

    start_inliers(p) -> (M,) bool: the lines through a hypothesis before refinement;
    spread(p, mask) -> [px] how far apart two estimates of one vertex from those lines may
    lie (`_coincide`). Refined vertices that coincide (two groups of the same lines' edges,
    fragments of the same spokes, each refined to nearly the same point) are one candidate:
    the best is refined again on all their lines. Returns (p (2,), inliers (M,), iterations,
    rival): rival is (vertex (2,), gain, lines) of the best refined vertex elsewhere that
    shares at most two lines with the chosen one (None if none), gain = no_vertex - its cost
    (no_vertex: M T^2, the cost of no vertex at all).
    """
    order = np.argsort(cost, kind="stable")[:LOCAL_CANDIDATES]
    found, first_error = [], None
    for h in order:
        if found:
            own = start_inliers(hyp[h])  # (once, not once per found vertex)
            if any(np.all(f[1][own]) for f in found):
                continue  # its lines are all a found vertex's: it would refine to that one
        try:
            p, mask, it, c = refine(hyp[h])
        except EstimationError as e:
            first_error = first_error or e
            continue
        if not any(np.array_equal(mask, f[1]) for f in found):
            found.append((p, mask, it, c))
    if not found:
        raise first_error
    best = found[0]
    for f in found[1:]:  # only a strictly better one replaces the first
        if f[3] < best[3] - 1e-9 * max(1.0, abs(best[3])):
            best = f
    same = [f for f in found if f is not best and _coincide(best, f, spread)]
    if same:
        # one vertex seen through two groups of lines: refined on all of them
        union = best[1].copy()
        for f in same:
            union |= f[1]
        try:
            merged = refine(best[0], union)
        except EstimationError:
            merged = None
        if merged is not None and merged[3] <= best[3] + 1e-9 * max(1.0, abs(best[3])):
            best = merged
        found = [f for f in found if not any(f is g for g in same)]
    rivals = [f for f in found if f is not best and np.count_nonzero(f[1] & best[1]) <= 2
              and not _coincide(best, f, spread)]
    rival = None
    if rivals:
        r = min(rivals, key=lambda f: f[3])
        rival = (r[0], float(no_vertex - r[3]), int(np.count_nonzero(r[1])))
    return best[0], best[1], best[2], rival


#: Two refined vertices closer than this [px] are one, whatever their lines' sigmas: the two
#: sides of a dartboard's wires meet a fraction of a pixel apart, each group precisely; a
#: rival in clutter lies far away.
COINCIDE_PX = 2.0


def _coincide(a, b, spread):
    """Whether two refined vertices (p, mask, ...) are one: closer than the spread either
    one's lines allow (`intersect_lines`: three sds of the lines' distances from it) or
    than `COINCIDE_PX`."""
    d = float(np.hypot(*(np.asarray(a[0]) - np.asarray(b[0]))))
    return d <= max(spread(a[0], a[1]), spread(b[0], b[1]), COINCIDE_PX)


def intersect_lines(
    segments,
    angle_sigma=None,
    offset_sigma=0.2,
    robust=True,
    *,
    inlier_confidence=0.999,
    infinity_confidence=0.999,
    max_pairs=1024,
    seed=0,
    max_condition=1e12,
    tol=1e-12,
    max_iter=50,
    consistent=None,
    start=None,
):
    """Weighted least-squares intersection of image lines, optionally robust to outliers.

    segments: (M, 4) ``[x1, y1, x2, y2]`` [px], undistorted pixels, M >= 2.
    angle_sigma: scalar or (M,) sd [rad] of each line's angle, pivoting about the segment
        centre. None: as if each segment were known by its end points only, with sd
        ``sqrt(2) * offset_sigma`` per coordinate, i.e. ``2 * offset_sigma / L``
        (`segment_angle_sigma`); 0 ignores angle errors.
    offset_sigma: scalar or (M,) sd [px] (> 0) of each line's perpendicular position at its
        centre.
    robust: reject outlier lines (spurious segments). Hypotheses are the intersections of
        line pairs (every pair when M(M-1)/2 <= max_pairs, else `max_pairs` pairs drawn with
        `seed`), scored by the MSAC cost sum_k min(e_k^2, T^2) of the normalised residuals
        e_k; the best is refined by weighted LS on its inliers, re-classifying lines until
        the inlier set is stable. T^2 is the chi-square(1) quantile at `inlier_confidence`
        (10.8 at 0.999, |e| < 3.3). An exhaustive vectorised pair search was preferred to
        skimage.measure.ransac: it is deterministic and, the minimal sample being two
        lines, cheaper than a per-trial Python loop.
    infinity_confidence: the vertex must beat the best point at infinity (all inlier lines
        parallel) by the chi-square(1) quantile at this level, else EstimationError: a vertex
        the data cannot tell from infinity is refused rather than returned as a number.
    max_condition: EstimationError when the information matrix is worse conditioned
        (numerically parallel lines, which the previous test cannot see when angle_sigma is 0).
    tol, max_iter: convergence of the reweighting (relative step) and its iteration cap.
    consistent: optional prior knowledge of which lines can belong to a vertex: a callable
        ``consistent(points (P, 2)) -> (P, M) bool``; a line counts as an inlier of a point
        only where it is true (e.g. spokes of known radii must reach close to their vertex,
        which a stray line that merely points at it does not). Robust mode only.
    start: optional (M,) bool, robust mode: lines known to pass through the vertex (a
        video's spokes, labelled by the previous frame's orientation). The vertex is then
        refined from their weighted LS, re-classifying every line as the search does, instead
        of searching all pairs (no rival vertex is looked for; the search where the given
        lines agree on no point or one of them is left out): where the search would find
        the same inliers, the same vertex to the reweighting's tolerance at a fraction of
        its cost.

    Returns a `VertexFit`. Raises InputError for bad shapes, NaN/inf or zero-length
    segments, bad sigmas; EstimationError for fewer than two lines, parallel lines and a
    vertex at infinity.

    The estimate minimises sum_k (n_k . p + c_k)^2 / sigma_k^2 with the weights
    1 / sigma_k^2 = 1 / (sigma_c^2 + r_k^2 sigma_theta^2) re-evaluated at each iterate (see the
    module docstring for r_k); its covariance is ``(sum n_k n_k^T / sigma_k^2)^-1``.

    >>> segs = [[0, 0, 10, 0], [0, 1, 10, 11], [5, -5, 5, 5]]       # y = 0, y = x + 1, x = 5
    >>> fit = intersect_lines(segs, robust=False)
    >>> fit.lines_used, np.round(fit.vertex, 6).tolist()            # not concurrent: LS point
    (3, [3.679161, 1.320839])
    """
    s = _check_segments(segments)
    m = s.shape[0]
    if m < 2:
        raise EstimationError(f"vertex: needs at least two lines, got {m}")
    lines = segment_lines(s)
    if np.any(lines.length <= 0):
        raise InputError(f"segments: row {int(np.argmax(lines.length <= 0))} has zero length")
    sc = _check_sigma(offset_sigma, m, "offset_sigma", positive=True)
    if angle_sigma is None:
        st = 2.0 * sc / lines.length
    else:
        st = _check_sigma(angle_sigma, m, "angle_sigma", positive=False)
    st2, sc2 = st * st, sc * sc
    t2 = chi2_isf(1.0 - inlier_confidence, 1)
    dm = np.sum(lines.direction * lines.centre, -1)

    def fit(p, mask, iters=max_iter, st2=st2):
        return _weighted_ls(
            p, lines.normal[mask], lines.offset[mask], lines.direction[mask], dm[mask],
            st2[mask], sc2[mask], tol, iters,
        )

    def classify(p):
        return _normalised_residuals(p, lines, dm, st2, sc2)

    if robust and m > 2:
        def inliers(p, e):
            ok = e * e < t2
            return ok if consistent is None else ok & consistent(p[None])[0]

        def refine(p, start=None):
            return _refine_inliers(p, fit, classify, inliers, t2, start)

        def start_inliers(p):
            return inliers(p, classify(p)[0])

        def spread(p, mask):
            # two estimates of one vertex, each from half of these lines, differ by about
            # sqrt(2) sigma / sqrt(n / 2) = 2 sigma / sqrt(n) (sigma the lines' distance sd):
            # three of those
            _, sig = classify(p)
            return 6.0 * float(np.sqrt(np.mean(sig[mask] ** 2) / max(np.count_nonzero(mask), 1)))

        given = None if start is None else np.asarray(start, bool).reshape(m)
        found = None if given is None else _refine_given(given, fit, refine, classify, t2)
        if found is not None:
            (p, mask, it, _), rival = found, None
        else:  # no lines given, or no vertex from them: the search
            hyp = _pair_hypotheses(lines, max_pairs, seed, min_sin=1e-9)
            if hyp.shape[0] == 0:
                raise EstimationError("vertex: the lines are parallel, they meet only at infinity")
            cost = _msac_costs(hyp, lines, dm, st2, sc2, t2, consistent)
            p, mask, it, rival = _local_optimisation(hyp, cost, refine, start_inliers, m * t2, spread)
    else:
        mask, rival = np.ones(m, dtype=bool), None
        # start from the offset-only solution (lever arms unknown yet)
        p, _ = fit(np.zeros(2), mask, 1, np.zeros(m))
        p, it = fit(p, mask)

    e, sig = classify(p)
    n = lines.normal[mask]
    F = (n.T / sig[mask] ** 2) @ n
    ev = np.linalg.eigvalsh(F)
    cond = float(ev[1] / ev[0]) if ev[0] > 0 else np.inf
    if not np.isfinite(cond) or cond > max_condition:
        raise EstimationError(
            f"vertex: the lines are (nearly) parallel, intersection ill-conditioned (condition {cond:.3g})"
        )
    chi2 = float(np.sum(e[mask] ** 2))
    gain_min = chi2_isf(1.0 - infinity_confidence, 1)
    phi = np.arctan2(lines.direction[mask, 1], lines.direction[mask, 0])
    chi2_inf = _chi2_infinity(phi, st2[mask], chi2 + gain_min)
    if chi2_inf - chi2 < gain_min:
        # nearly parallel lines, or (robust=False) outliers that no finite point explains
        raise EstimationError(
            f"vertex: cannot be told from a point at infinity: a common direction fits the lines "
            f"with chi2 {chi2_inf:.4g}, the finite vertex with {chi2:.4g} (needs {gain_min:.3g} less)"
        )
    cov = np.linalg.inv(F)
    cov = 0.5 * (cov + cov.T)
    k = int(np.count_nonzero(mask))
    return VertexFit(
        vertex=p,
        cov=cov,
        inliers=mask,
        residuals=e,
        sigmas=sig,
        lines_used=k,
        rms=float(np.sqrt(chi2 / k)),
        rms_px=float(np.sqrt(np.mean((e[mask] * sig[mask]) ** 2))),
        chi2=chi2,
        chi2_infinity=chi2_inf,
        condition=cond,
        iterations=it,
        gain=float(m * t2 - _msac_cost(p, e, t2, consistent if robust else None)),
        rival_gain=0.0 if rival is None else rival[1],
        rival_vertex=None if rival is None else rival[0],
        rival_lines=0 if rival is None else rival[2],
    )


def lines_through(point, segments, angle_sigma, offset_sigma, point_cov=None, confidence=0.999):
    """Which lines pass through a known point, within their noise and the point's.

    point: (2,) [px]; segments: (M, 4) [px]; angle_sigma [rad], offset_sigma [px]: scalars or
    (M,), the noise model of the module docstring; point_cov: (2, 2) [px^2] or None.
    Returns (z (M,), through (M,) bool): each line's normalised distance from the point and
    whether z^2 is below the chi-square(1) quantile at `confidence`, the test
    `intersect_lines` uses for its inliers.

    >>> z, ok = lines_through([5.0, 0.0], [[0, 0, 10, 0], [5, -5, 5, 5], [0, 3, 10, 3]], 1e-3, 0.2)
    >>> ok.tolist()
    [True, True, False]
    """
    s = _check_segments(segments)
    m = s.shape[0]
    lines = segment_lines(s)
    sc = _check_sigma(offset_sigma, m, "offset_sigma", positive=True)
    st = _check_sigma(angle_sigma, m, "angle_sigma", positive=False)
    p = np.asarray(point, float).reshape(2)
    dm = np.sum(lines.direction * lines.centre, -1)
    extra = None if point_cov is None else np.einsum("mi,ij,mj->m", lines.normal, np.asarray(point_cov, float),
                                                      lines.normal)
    z, _ = _normalised_residuals(p, lines, dm, st * st, sc * sc, extra)
    return z, z * z < chi2_isf(1.0 - confidence, 1)


def vertex_crlb(vertex, segments, angle_sigma, offset_sigma):
    """Cramer-Rao bound (..., 2, 2) [px^2] of the vertex, (sum n_k n_k^T / sigma_k^2)^-1.

    vertex: (..., 2) true vertex [px]; segments: (..., M, 4) the true (noise-free) segments;
    angle_sigma [rad], offset_sigma [px]: scalars or (..., M), the noise model of the
    module docstring. Broadcasts over leading dimensions (e.g. Monte Carlo trials).
    Singular geometry (parallel lines) gives inf/NaN entries or raises LinAlgError.

    >>> v = np.zeros(2)
    >>> segs = np.array([[100.0, 0, 200, 0], [0, 100, 0, 200]])     # two lines at 90 deg
    >>> np.round(vertex_crlb(v, segs, 0.001, 0.2), 6).tolist()      # 0.04 + 150^2 * 1e-6
    [[0.0625, 0.0], [0.0, 0.0625]]
    """
    lines = segment_lines(segments)
    v = np.asarray(vertex, dtype=float)
    r = np.sum(lines.direction * (v[..., None, :] - lines.centre), -1)
    var = np.asarray(offset_sigma, float) ** 2 + r * r * np.asarray(angle_sigma, float) ** 2
    n = lines.normal
    F = np.einsum("...k,...ki,...kj->...ij", 1.0 / var, n, n)
    return np.linalg.inv(F)


def propagate_cov(cov, jacobian):
    """First-order propagation J C J^T. cov: (..., n, n); jacobian: (..., m, n) -> (..., m, m).

    Into normalised image coordinates x = K^-1 (u, v, 1) the Jacobian is inv(K[:2, :2]):

    >>> K = np.array([[800.0, 0, 320], [0, 800, 240], [0, 0, 1]])
    >>> round(float(propagate_cov(np.eye(2) * 0.64, np.linalg.inv(K[:2, :2]))[0, 0]), 15)
    1e-06
    """
    J = np.asarray(jacobian, dtype=float)
    return J @ np.asarray(cov, dtype=float) @ np.swapaxes(J, -1, -2)


def floored_vertex_cov(cov_ideal, floor_px):
    """The vertex's covariance (2, 2) [undistorted px^2] with no variance under floor_px^2 / 2
    along any direction (floor_px: an sd of the vertex's distance [px], None or 0: none);
    None where it is already no narrower.

    >>> floored_vertex_cov(np.diag([0.01, 4.0]), 2.0).round(3).tolist()
    [[2.0, 0.0], [0.0, 4.0]]
    >>> floored_vertex_cov(np.diag([3.0, 4.0]), 2.0) is None
    True
    """
    if floor_px is None or not np.isfinite(floor_px) or floor_px <= 0:
        return None
    w, V = np.linalg.eigh(np.asarray(cov_ideal, float))
    if np.all(w >= 0.5 * floor_px**2):
        return None
    return (V * np.maximum(w, 0.5 * floor_px**2)) @ V.T
