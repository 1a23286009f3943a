"""Pivot epochs: where a sequence's fulcrum moves, found by a change-point test on its lines.

Within an epoch every frame's instrument line passes through one image point, the
fulcrum's image; where the arm is re-set, the port slips or the camera moves, that point
moves and the lines of the frames after the move pass through another. `split_epochs`
splits the frames, in their order, into runs (epochs) each with its own point:

1. *the cost of a run*: the robust fit of one common point to its lines
   (`vertex.intersect_lines`, the fulcrum's estimator, the point free to lie far outside
   the image), its MSAC cost ``C = sum_k min(e_k^2, T^2)`` over the run's lines (e_k the
   normalised residuals of the fulcrum's noise model, T^2 the inliers' chi-square(1)
   quantile at 0.999: a misdetected line costs T^2 whatever the split, so outliers do not
   make epochs);
2. *the test of a split*: for every frame k where both sides keep `min_frames` frames with
   a line, the drop ``D(k) = C(run) - C(before k) - C(from k)``; and, since an arm re-set
   and set back, or a camera moved and moved back, leaves the frames before and after a
   segment with one point, for every segment [i, j) with `min_frames` frames inside and
   around it, ``D(i, j) = C(run) - C(segment) - C(the rest)`` (the circular alternative of
   circular binary segmentation). Under "one point" either frees two parameters (the
   second point), so ``D / 2`` over the residual variance per degree of freedom of the two
   fits, ``s^2 = max(1, chi2 / nu)`` (nu: inliers of both minus 4; where above 1 the costs
   are taken again with the sigmas times s, so that the truncation at T is T of the lines'
   real noise), is F(2, nu) distributed: the test needs no trust in the lines' sigmas
   beyond their relative weights (the detector's sigmas on real frames are ~1.5x small),
   and is never more eager than the sigmas themselves (s^2 >= 1). The best alternative of
   each kind is a change when its p-value times the number of alternatives of its kind
   tried, times 2 (the two kinds; Bonferroni: the best of many), is below `alpha`;
3. *binary segmentation*: the whole sequence is tested, and each run between change points
   in turn, until no run splits. A long run is tried on a grid of at most `MAX_POSITIONS`
   frames (segments: half as many ends), then around the best;
4. *merging*: binary segmentation may first split between two changes close together, then
   again at each; so every change is tested once more on its two neighbouring epochs alone,
   at its own frame (no multiplicity), and the least significant is removed while its
   p-value is alpha or more.

The engine (steps 2-4, `segment_runs`) takes any cost of runs of frames: the shafts' 3-D
axes of a moving camera use it too (`axis_epochs`; a point and a scale, four parameters,
F(4, nu) by `f_sf`).

F(2, nu) has the closed-form survival function ``(1 + 2 F / nu)^(-nu / 2)``; Monte Carlo
on lines with the fulcrum's noise model (tests/toolkit/pencil/test_epochs.py) gives the
false split rate below `alpha` and the detected moves.

Example
-------
>>> import numpy as np
>>> rng = np.random.default_rng(0)
>>> def spokes(v, n):
...     a = rng.uniform(0.2, 1.2, n)
...     d = np.stack([np.cos(a), np.sin(a)], -1)
...     return np.concatenate([v + 200 * d, v + 500 * d], -1) + rng.normal(0, 0.3, (n, 4))
>>> segs = np.concatenate([spokes(np.array([100.0, 50.0]), 10), spokes(np.array([180.0, 20.0]), 10)])
>>> ep = split_epochs(segs, np.radians(0.1), 0.3, np.arange(20), 20)
>>> ep.bounds, ep.changes[0].index
([(0, 10), (10, 20)], 10)
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from pencilcal.toolkit.errors import EstimationError, InputError
from pencilcal.toolkit.geometry.quantiles import chi2_isf
from pencilcal.toolkit.pencil.sequence_noise import inflation
from pencilcal.toolkit.pencil.vertex import intersect_lines

__all__ = ["ALPHA", "MIN_FRAMES", "MAX_POSITIONS", "ChangePoint", "Epochs", "split_epochs", "frame_epochs", "distinct_lines",
           "f2_sf", "f_sf", "segment_runs"]

#: Significance of a change point (after the Bonferroni factor over the frames tried).
ALPHA = 0.01
#: Fewest frames with a line in an epoch: a point fitted to two lines has no residual, to
#: three one degree of freedom; four tell a moved fulcrum from noise.
MIN_FRAMES = 4
#: A run is tried at this many frames at most, then around the best.
MAX_POSITIONS = 32
_INLIER_CONFIDENCE = 0.999  # the fulcrum's own (`vertex.intersect_lines`)


def f_sf(f, k, nu):
    """P(F > f) for F distributed F(k, nu), k even: with ``x = nu / (nu + k f)`` and ``a =
    nu / 2``, ``x^a sum_{j < k/2} (a)_j / j! (1 - x)^j`` (the regularised incomplete beta
    function of an integer second argument); k = 2 is `f2_sf`.

    >>> round(f_sf(3.32, 4, 1e9), 4)        # nu -> inf: chi2(4) / 4 above 13.28
    0.01
    """
    if int(k) != k or k < 2 or k % 2:
        raise InputError(f"f_sf: k must be an even integer >= 2, got {k!r}")
    x = nu / (nu + k * max(float(f), 0.0))
    a, term, total = nu / 2.0, 1.0, 1.0
    for j in range(int(k) // 2 - 1):
        term *= (a + j) / (j + 1) * (1.0 - x)
        total += term
    return float(min(1.0, x**a * total))


def f2_sf(f, nu):
    """P(F > f) for F distributed F(2, nu): ``(1 + 2 f / nu)^(-nu / 2)``.

    >>> round(f2_sf(4.6, 1e9), 4)          # nu -> inf: chi2(2) / 2, exp(-f)
    0.0101
    """
    f = max(float(f), 0.0)
    return float(np.exp(-0.5 * nu * np.log1p(2.0 * f / nu)))


@dataclass(frozen=True)
class ChangePoint:
    """One change point (`split_epochs`): the fulcrum moved before frame `index`.

    index: the first frame of the new epoch; start, stop: the run [start, stop) the test
    split; partner: for a segment that differs from the run around it (module docstring,
    step 2), the other end of that segment (its first frame, or the first frame after it),
    else None; drop: the MSAC cost's drop D of the split; scale: s^2, the residual variance
    per degree of freedom (at least 1); statistic: F = D / (2 s^2); dof: nu; p_value:
    F(2, nu)'s tail at F; positions: the alternatives tried (frames, or pairs of frames);
    p_corrected: min(1, 2 p_value positions), compared with alpha (Bonferroni over the
    alternatives and the two kinds of test); vertices: the two point fits' vertices [ideal
    px] (None at infinity): before and after the split, or the segment's and the rest's."""

    index: int
    start: int
    stop: int
    drop: float
    scale: float
    statistic: float
    dof: int
    p_value: float
    positions: int
    p_corrected: float
    vertices: tuple
    partner: int | None = None

    def to_dict(self, names=None) -> dict:
        """The record of fulcrum.json's ``change_points`` (docs/formats.md); names: the
        frames' image names, for ``last_image_before`` and ``first_image_after``."""
        out = {"index": self.index, "tested": [self.start, self.stop - 1], "partner": self.partner,
               "drop": self.drop, "scale": self.scale, "statistic": self.statistic, "dof": self.dof,
               "p_value": self.p_value, "positions": self.positions, "p_corrected": self.p_corrected,
               "vertices_ideal_px": [None if v is None else [float(x) for x in v] for v in self.vertices]}
        if names is not None:
            out["last_image_before"] = names[self.index - 1]
            out["first_image_after"] = names[self.index]
        return out


@dataclass(frozen=True)
class Epochs:
    """The epochs of a sequence (`split_epochs`): bounds [(start, stop)] of each epoch in
    frame indices (all frames, those without a line included, in order); changes: the
    `ChangePoint` between consecutive epochs; kept: per run tested without a split, (start,
    stop, p_corrected of its best alternative or None where it could not be split), what
    says why it stayed whole; merged: (frame, p-value) of the changes removed again (step 4);
    alpha, min_frames: the test's settings."""

    bounds: list
    changes: list
    kept: list = field(default_factory=list)
    alpha: float = ALPHA
    min_frames: int = MIN_FRAMES
    merged: list = field(default_factory=list)

    def epoch_of(self, frame):
        """The index of the epoch holding `frame`."""
        for e, (a, b) in enumerate(self.bounds):
            if a <= frame < b:
                return e
        raise IndexError(f"frame {frame} is in no epoch")


class _Runs:
    """The cost of one common point for sets of runs of frames, cached (module docstring,
    step 1); scale: the factor on the lines' sigmas. The engine (`segment_runs`) asks any
    such cost for: ``fit(*runs)`` (MSAC cost, inlier chi2, inliers, the point or None),
    ``scaled(s)``, ``params`` (the parameters of one point: its alternative frees as many)
    and ``residuals(n)`` (the residuals of n inliers)."""

    params = 2

    @staticmethod
    def residuals(n):
        """One residual a line."""
        return n

    def __init__(self, segments, angle_sigma, offset_sigma, frame_of, scale=1.0):
        self.s, self.st, self.sc, self.f = segments, angle_sigma * scale, offset_sigma * scale, frame_of
        self.t2 = chi2_isf(1.0 - _INLIER_CONFIDENCE, 1)
        self.cache = {}

    def scaled(self, scale):
        """The same runs with the lines' sigmas times `scale`."""
        return _Runs(self.s, self.st, self.sc, self.f, scale)

    def fit(self, *runs):
        """(MSAC cost, inlier chi2, inliers, vertex (2,) or None at infinity) of the frames
        of the runs (start, stop): the better of the finite point (`vertex.intersect_lines`)
        and the point at infinity (`_at_infinity`)."""
        key = tuple(runs)
        if key not in self.cache:
            sel = np.zeros(self.f.shape, bool)
            for a, b in runs:
                sel |= (self.f >= a) & (self.f < b)
            idx = np.flatnonzero(sel)
            m = idx.size
            best = _at_infinity(self.s[idx], self.st[idx], self.t2)
            try:
                # the point may lie anywhere: no condition or infinity test
                v = intersect_lines(self.s[idx], angle_sigma=self.st[idx], offset_sigma=self.sc[idx], robust=True,
                                    inlier_confidence=_INLIER_CONFIDENCE, infinity_confidence=1e-12,
                                    max_condition=np.inf)
                if m * self.t2 - v.gain < best[0]:
                    best = (m * self.t2 - v.gain, v.chi2, v.lines_used, v.vertex)
            except EstimationError:
                pass
            self.cache[key] = best
        return self.cache[key]


def _at_infinity(segments, angle_sigma, t2):
    """(MSAC cost, inlier chi2, inliers, None) of the best point at infinity of lines (N, 4):
    a common direction u, each line's normalised residual ``sin(phi_k - u) / sigma_k``
    (what `vertex.intersect_lines`' residual tends to as the point runs off along u), its
    MSAC cost minimised over the lines' own directions, then refined on the inliers (their
    weighted mean direction, doubled angles) until they do not change."""
    d = segments[:, 2:] - segments[:, :2]
    phi = np.arctan2(d[:, 1], d[:, 0])
    w = 1.0 / np.maximum(np.asarray(angle_sigma, float), 1e-12) ** 2

    def cost(u):
        e2 = np.sin(phi - u) ** 2 * w
        return float(np.sum(np.minimum(e2, t2))), e2

    if phi.size == 0:
        return 0.0, 0.0, 0, None
    u = min(phi, key=lambda v: cost(v)[0])
    for _ in range(10):
        c, e2 = cost(u)
        inl = e2 < t2
        u_new = 0.5 * np.angle(np.sum(w[inl] * np.exp(2j * phi[inl]))) if inl.any() else u
        if cost(u_new)[0] >= c - 1e-12:
            break
        u = u_new
    c, e2 = cost(u)
    inl = e2 < t2
    return c, float(np.sum(e2[inl])), int(inl.sum()), None


def _positions(counts, a, b, min_frames):
    """Frames k in (a, b) with a line, and at least min_frames frames with a line on either
    side (an epoch starts at a frame with a line: those without stay with the frames
    before)."""
    c = np.cumsum(np.r_[0, counts[a:b] > 0])
    k = np.arange(a + 1, b)
    left = c[k - a]
    return k[(left >= min_frames) & (c[-1] - left >= min_frames) & (counts[k] > 0)]


def _grid(ks, n):
    """At most n of the positions ks, evenly."""
    return ks if ks.size <= n else ks[np.unique(np.linspace(0, ks.size - 1, n).astype(int))]


def _near(ks, grid, g):
    """The positions of ks between the grid neighbours of g."""
    i = int(np.searchsorted(grid, g))
    return ks[(ks > grid[max(i - 1, 0)]) & (ks < grid[min(i + 1, grid.size - 1)])]


def _alternatives(counts, a, b, min_frames):
    """The alternatives to one point on [a, b) (module docstring, step 2): single splits k
    and segments (i, j) with min_frames frames with a line inside and around them; and
    their numbers (the Bonferroni factors)."""
    ks = _positions(counts, a, b, min_frames)
    c = np.cumsum(np.r_[0, counts > 0])
    pairs = [(int(i), int(j)) for i in ks for j in ks
             if j > i and c[j] - c[i] >= min_frames and (c[i] - c[a]) + (c[b] - c[j]) >= min_frames]
    return ks, pairs


def _hypotheses(ks, pairs):
    """The alternatives tried first: single splits on a grid of `MAX_POSITIONS`, segments
    with both ends on a grid of half as many."""
    gk = _grid(ks, MAX_POSITIONS)
    gp = set(int(v) for v in _grid(ks, MAX_POSITIONS // 2))
    return [("split", int(k)) for k in gk] + [("segment", p) for p in pairs if p[0] in gp and p[1] in gp]


def _runs_of(h, a, b):
    """The runs of the two point fits of an alternative h on [a, b)."""
    kind, v = h
    if kind == "split":
        return ((a, v),), ((v, b),)
    i, j = v
    return ((i, j),), ((a, i), (j, b))


def _best(runs, a, b, ks, pairs):
    """(alternative, drop, inlier chi2, inliers) of the best alternative on [a, b) by the
    cost's drop, refined around the best of each kind's grid."""
    C0 = runs.fit((a, b))[0]

    def drop(h):
        l, r = (runs.fit(*rr) for rr in _runs_of(h, a, b))
        return C0 - l[0] - r[0], l[1] + r[1], l[2] + r[2]

    scored = {h: drop(h) for h in _hypotheses(ks, pairs)}
    best = {}
    for kind in ("split", "segment"):
        mine = [h for h in scored if h[0] == kind]
        if not mine:
            continue
        top = max(mine, key=lambda h: scored[h][0])
        gk = _grid(ks, MAX_POSITIONS if kind == "split" else MAX_POSITIONS // 2)
        if kind == "split":
            more = [("split", int(k)) for k in _near(ks, gk, top[1])]
        else:
            ii, jj = _near(ks, gk, top[1][0]), _near(ks, gk, top[1][1])
            ok = set(pairs)
            more = [("segment", (int(i), int(j))) for i in np.r_[ii, top[1][0]] for j in np.r_[jj, top[1][1]]
                    if (int(i), int(j)) in ok]
        for h in more:
            if h not in scored:
                scored[h] = drop(h)
        best[kind] = max((h for h in scored if h[0] == kind), key=lambda h: scored[h][0])
    return {kind: (h, *scored[h]) for kind, h in best.items()}


def _stat(runs, a, b, h, D, chi2, n_in, positions):
    """The test of alternative h on [a, b) (module docstring, step 2): (p_corrected,
    `ChangePoint` list)."""
    k = runs.params
    nu = max(runs.residuals(n_in) - 2 * k, 1)
    scale = inflation(chi2, nu)
    (rl, rr) = _runs_of(h, a, b)
    if scale > 1.0:
        # the costs again with the sigmas the residuals show: their truncation at T must be
        # T of the lines' real noise, or lines beyond it move between the fits
        sr = runs.scaled(np.sqrt(scale))
        l, r = sr.fit(*rl), sr.fit(*rr)
        D = sr.fit((a, b))[0] - l[0] - r[0]
        nu = max(runs.residuals(l[2] + r[2]) - 2 * k, 1)
    F = max(D, 0.0) / k
    p = f_sf(F, k, nu)
    pc = min(1.0, 2.0 * p * positions)
    verts = (runs.fit(*rl)[3], runs.fit(*rr)[3])
    common = dict(start=a, stop=b, drop=float(D), scale=float(scale), statistic=float(F), dof=int(nu), p_value=p,
                  positions=int(positions), p_corrected=pc, vertices=verts)
    if h[0] == "split":
        return pc, [ChangePoint(index=int(h[1]), **common)]
    i, j = h[1]
    return pc, [ChangePoint(index=i, partner=j, **common), ChangePoint(index=j, partner=i, **common)]


def _test(runs, counts, a, b, min_frames):
    """The best alternative on [a, b) and its test: (p_corrected, its change points), or
    None where no frame can split the run."""
    ks, pairs = _alternatives(counts, a, b, min_frames)
    if ks.size == 0:
        return None
    tests = [_stat(runs, a, b, h, D, chi2, n_in, ks.size if h[0] == "split" else len(pairs))
             for h, D, chi2, n_in in _best(runs, a, b, ks, pairs).values()]
    return min(tests, key=lambda t: t[0])


def _merged(runs, changes, n_frames, alpha):
    """(the change points without those between two epochs that one point explains, [(frame,
    p-value)] of those removed) (module docstring, step 4): the split at each change tested on
    its two neighbouring epochs alone, at that frame only; the least significant removed
    while its p-value is alpha or more."""
    changes, removed = list(changes), []
    while changes:
        cuts = [0] + [c.index for c in changes] + [n_frames]
        tests = [_stat(runs, cuts[k], cuts[k + 2], ("split", cuts[k + 1]), *_drop(runs, cuts[k], cuts[k + 1],
                                                                                    cuts[k + 2]), 1)
                 for k in range(len(changes))]
        k = int(np.argmax([t[0] for t in tests]))
        if tests[k][0] < alpha:
            break
        removed.append((changes[k].index, float(tests[k][0])))
        del changes[k]
    gone = {k for k, _ in removed}
    return [replace(c, partner=None) if c.partner in gone else c for c in changes], removed


def _drop(runs, a, k, b):
    """(drop, inlier chi2, inliers) of splitting [a, b) at k."""
    l, r = runs.fit((a, k)), runs.fit((k, b))
    return runs.fit((a, b))[0] - l[0] - r[0], l[1] + r[1], l[2] + r[2]


def split_epochs(segments, angle_sigma, offset_sigma, frame_of, n_frames, *, alpha=ALPHA, min_frames=MIN_FRAMES):
    """The pivot epochs of a sequence from its instrument lines (module docstring).

    segments: (N, 4) [ideal px] the lines (undistorted); angle_sigma [rad], offset_sigma
    [px]: scalars or (N,), their noise model (`vertex.intersect_lines`); frame_of: (N,) int,
    each line's frame index in [0, n_frames), frames in their order; alpha: significance of
    a change (family-wise over one run's alternatives); min_frames: fewest frames with a
    line in an epoch (at least 3).

    Returns `Epochs` covering frames [0, n_frames); a frame without a line belongs to the
    epoch around it (before a change point it stays with the frames before).
    """
    s = np.asarray(segments, float).reshape(-1, 4)
    n = s.shape[0]
    f = np.asarray(frame_of, int).reshape(-1)
    if f.shape[0] != n or (n and (f.min() < 0 or f.max() >= n_frames)):
        raise InputError(f"frame_of: expected {n} frame indices in [0, {n_frames})")
    if int(min_frames) < 3:
        raise InputError(f"min_frames must be at least 3, got {min_frames!r}")
    if not 0 < float(alpha) < 1:
        raise InputError(f"alpha must be in (0, 1), got {alpha!r}")
    st = np.broadcast_to(np.asarray(angle_sigma, float), (n,))
    sc = np.broadcast_to(np.asarray(offset_sigma, float), (n,))
    return segment_runs(_Runs(s, st, sc, f), np.bincount(f, minlength=n_frames), alpha=alpha, min_frames=min_frames)


def segment_runs(runs, counts, *, alpha=ALPHA, min_frames=MIN_FRAMES):
    """`Epochs` of frames [0, len(counts)) by binary segmentation and merging (module
    docstring, steps 2-4) of a cost of runs of frames (`_Runs` says what it must give: the
    lines' here, `axis_epochs.axis_epochs`' of 3-D axes); counts: (n_frames,) the
    observations of each frame."""
    counts = np.asarray(counts, int)
    n_frames = counts.size
    todo, changes, kept = [(0, int(n_frames))], [], []
    while todo:
        a, b = todo.pop()
        t = _test(runs, counts, a, b, int(min_frames))
        if t is not None and t[0] < alpha:
            changes += t[1]
            cuts = sorted({a, b, *(c.index for c in t[1])})
            todo += list(zip(cuts[:-1], cuts[1:]))
        else:
            kept.append((a, b, None if t is None else t[0]))
    changes, removed = _merged(runs, sorted(changes, key=lambda c: c.index), int(n_frames), float(alpha))
    cuts = [0] + [c.index for c in changes] + [int(n_frames)]
    return Epochs(bounds=list(zip(cuts[:-1], cuts[1:])), changes=changes, kept=sorted(kept), alpha=float(alpha),
                  min_frames=int(min_frames), merged=removed)


def distinct_lines(segments, angle_sigma, offset_sigma, frame_of, tol=3.0):
    """(N,) bool: one of each set of lines that repeat from frame to frame (the first).

    A line seen again in other frames within `tol` sd of angle and of offset (each at the
    other's centre, the two lines' sigmas added) carries no more about their common point
    than once: an instrument held still, or a band of tissue that stays while the
    instrument moves, which, counted in every frame, would pull the point onto itself (a
    static line passes through every point on it). segments: (N, 4) [ideal px];
    angle_sigma [rad], offset_sigma [px]: (N,) or scalars; frame_of: (N,) frame indices.

    >>> segs = np.array([[0, 0, 100, 0], [0, 0.2, 100, 0.1], [0, 0, 100, 30.0]])
    >>> distinct_lines(segs, 0.01, 0.5, [0, 1, 2]).tolist()
    [True, False, True]
    """
    s = np.asarray(segments, float).reshape(-1, 4)
    n = s.shape[0]
    f = np.asarray(frame_of).reshape(-1)
    st = np.broadcast_to(np.asarray(angle_sigma, float), (n,))
    sc = np.broadcast_to(np.asarray(offset_sigma, float), (n,))
    d = s[:, 2:] - s[:, :2]
    u = d / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12)
    nrm = np.stack([-u[:, 1], u[:, 0]], -1)
    c = 0.5 * (s[:, :2] + s[:, 2:])
    ang = np.abs(np.clip(np.abs(u @ u.T), 0.0, 1.0))  # cos of the angle between them
    da = np.arccos(ang)
    # the offset of each line i at line j's centre, and the reverse
    off = np.abs(np.einsum("id,jd->ij", nrm, c) - np.sum(nrm * c, -1)[:, None])
    sa = np.sqrt(st[:, None] ** 2 + st[None, :] ** 2)
    so = np.sqrt(sc[:, None] ** 2 + sc[None, :] ** 2)
    same = (da <= tol * sa) & (off <= tol * so) & (off.T <= tol * so) & (f[:, None] != f[None, :])
    keep = np.ones(n, bool)
    for i in range(n):
        if keep[i]:
            j = np.flatnonzero(same[i])
            keep[j[j > i]] = False
    return keep


def frame_epochs(camera, frames, endpoint_sigma_px=None, *, alpha=ALPHA, min_frames=MIN_FRAMES):
    """The pivot epochs (`Epochs`) of lines.json `frames` (in their order) from the lines the
    fulcrum fits (`fulcrum.sequence_lines`: shaft midlines where there are any, with their
    noise model), each repeated line once (`distinct_lines`)."""
    from pencilcal.toolkit.pencil.defaults import ENDPOINT_SIGMA_PX
    from pencilcal.toolkit.pencil.fulcrum import sequence_lines

    sl = sequence_lines(camera, frames, ENDPOINT_SIGMA_PX if endpoint_sigma_px is None else endpoint_sigma_px)
    f = np.array([o[0] for o in sl.owner], int).reshape(-1)
    g = np.flatnonzero(sl.good)
    g = g[distinct_lines(sl.ideal[g], sl.angle_sigma[g], sl.offset_sigma[g], f[g])]
    return split_epochs(sl.ideal[g], sl.angle_sigma[g], sl.offset_sigma[g], f[g], len(frames), alpha=alpha,
                        min_frames=min_frames)
