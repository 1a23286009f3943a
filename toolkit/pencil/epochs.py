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
   a line, the drop ``D(k) = C(run) - C(before k) - C(from k)``. Under "one point" a split
   frees two parameters (the second point), so ``D / 2`` over the residual variance per
   degree of freedom of the two fits, ``s^2 = max(1, chi2 / nu)`` (nu: inliers of both
   minus 4), is F(2, nu) distributed: the test needs no trust in the lines' sigmas beyond
   their relative weights (the detector's sigmas on real frames are ~1.5x small), and is
   never more eager than the sigmas themselves (s^2 >= 1). The best k is a change point
   when its p-value times the number of frames tried (Bonferroni: the best of many) is
   below `alpha`;
3. *binary segmentation*: the whole sequence is tested, and each side of a change point in
   turn, until no run splits. A long run is tried on a grid of at most `MAX_POSITIONS`
   frames, then around the best of them.

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

from dataclasses import dataclass, field

import numpy as np

from pencilcal.toolkit.errors import EstimationError, InputError
from pencilcal.toolkit.geometry.quantiles import chi2_isf
from pencilcal.toolkit.pencil.vertex import intersect_lines

__all__ = ["ALPHA", "MIN_FRAMES", "MAX_POSITIONS", "ChangePoint", "Epochs", "split_epochs", "frame_epochs", "f2_sf"]

#: Significance of a change point (after the Bonferroni factor over the frames tried).
ALPHA = 0.01
#: Fewest frames with a line in an epoch: a point fitted to two lines has no residual, to
#: three one degree of freedom; four tell a moved fulcrum from noise.
MIN_FRAMES = 4
#: A run is tried at this many frames at most, then around the best.
MAX_POSITIONS = 32
_INLIER_CONFIDENCE = 0.999  # the fulcrum's own (`vertex.intersect_lines`)


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

    index: the first frame of the new epoch; start, stop: the run [start, stop) it split;
    drop: the MSAC cost's drop D of the split; scale: s^2, the residual variance per degree
    of freedom (at least 1); statistic: F = D / (2 s^2); dof: nu; p_value: F(2, nu)'s tail
    at F; positions: the frames tried; p_corrected: min(1, p_value * positions); vertices:
    (2, 2) [ideal px] the two runs' points (their least-squares vertices, possibly far
    outside the image)."""

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

    def to_dict(self, names=None) -> dict:
        """The record of fulcrum.json's ``change_points`` (docs/formats.md); names: the
        frames' image names, for ``before_image`` and ``after_image``."""
        out = {"index": self.index, "tested": [self.start, self.stop], "drop": self.drop, "scale": self.scale,
               "statistic": self.statistic, "dof": self.dof, "p_value": self.p_value, "positions": self.positions,
               "p_corrected": self.p_corrected,
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
    stop, p_corrected of its best split or None where it could not be split), what says why
    it stayed whole; alpha, min_frames: the test's settings."""

    bounds: list
    changes: list
    kept: list = field(default_factory=list)
    alpha: float = ALPHA
    min_frames: int = MIN_FRAMES

    def epoch_of(self, frame):
        """The index of the epoch holding `frame`."""
        for e, (a, b) in enumerate(self.bounds):
            if a <= frame < b:
                return e
        raise IndexError(f"frame {frame} is in no epoch")


class _Runs:
    """The cost of one common point for runs of frames, cached (module docstring, step 1);
    scale: the factor on the lines' sigmas."""

    def __init__(self, segments, angle_sigma, offset_sigma, frame_of, scale=1.0):
        self.s, self.st, self.sc, self.f = segments, angle_sigma * scale, offset_sigma * scale, frame_of
        self.t2 = chi2_isf(1.0 - _INLIER_CONFIDENCE, 1)
        self.cache = {}

    def scaled(self, scale):
        """The same runs with the lines' sigmas times `scale`."""
        return _Runs(self.s, self.st, self.sc, self.f, scale)

    def fit(self, a, b):
        """(MSAC cost, inlier chi2, inliers, vertex (2,) or None at infinity) of frames [a, b):
        the better of the finite point (`vertex.intersect_lines`) and the point at infinity
        (`_at_infinity`)."""
        key = (a, b)
        if key not in self.cache:
            idx = np.flatnonzero((self.f >= a) & (self.f < b))
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


def _best_split(runs, a, b, ks):
    """(k, drop, chi2, inliers) of the best split of [a, b) among the frames ks: a grid of at
    most `MAX_POSITIONS`, then every frame between the best one's grid neighbours."""
    C0 = runs.fit(a, b)[0]

    def drop(k):
        l, r = runs.fit(a, k), runs.fit(k, b)
        return C0 - l[0] - r[0], l[1] + r[1], l[2] + r[2]

    grid = ks if ks.size <= MAX_POSITIONS else ks[np.unique(np.linspace(0, ks.size - 1, MAX_POSITIONS).astype(int))]
    scored = {int(k): drop(int(k)) for k in grid}
    best = max(scored, key=lambda k: scored[k][0])
    if ks.size > MAX_POSITIONS:
        i = int(np.searchsorted(grid, best))
        lo = grid[max(i - 1, 0)]
        hi = grid[min(i + 1, grid.size - 1)]
        for k in ks[(ks > lo) & (ks < hi)]:
            if int(k) not in scored:
                scored[int(k)] = drop(int(k))
        best = max(scored, key=lambda k: scored[k][0])
    return (best, *scored[best])


def _test(runs, counts, a, b, min_frames):
    """The best split of [a, b) and its test (module docstring, step 2): a `ChangePoint`, or
    None where no frame can split it."""
    ks = _positions(counts, a, b, min_frames)
    if ks.size == 0:
        return None
    k, D, chi2, n_in = _best_split(runs, a, b, ks)
    nu = max(n_in - 4, 1)
    scale = max(1.0, chi2 / nu)
    if scale > 1.0:
        # the costs again with the sigmas the split's residuals show: their truncation at T
        # must be T of the lines' real noise, or lines beyond it move between the fits
        sr = runs.scaled(np.sqrt(scale))
        D = sr.fit(a, b)[0] - sr.fit(a, k)[0] - sr.fit(k, b)[0]
        l, r = sr.fit(a, k), sr.fit(k, b)
        nu = max(l[2] + r[2] - 4, 1)
    F = max(D, 0.0) / 2.0
    p = f2_sf(F, nu)
    return ChangePoint(index=int(k), start=a, stop=b, drop=float(D), scale=float(scale), statistic=float(F),
                       dof=int(nu), p_value=p, positions=int(ks.size), p_corrected=min(1.0, p * ks.size),
                       vertices=(runs.fit(a, k)[3], runs.fit(k, b)[3]))


def split_epochs(segments, angle_sigma, offset_sigma, frame_of, n_frames, *, alpha=ALPHA, min_frames=MIN_FRAMES):
    """The pivot epochs of a sequence from its instrument lines (module docstring).

    segments: (N, 4) [ideal px] the lines (undistorted); angle_sigma [rad], offset_sigma
    [px]: scalars or (N,), their noise model (`vertex.intersect_lines`); frame_of: (N,) int,
    each line's frame index in [0, n_frames), frames in their order; alpha: significance of
    a change point; min_frames: fewest frames with a line in an epoch (at least 3).

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
    runs = _Runs(s, st, sc, f)
    counts = np.bincount(f, minlength=n_frames)
    todo, changes, kept = [(0, int(n_frames))], [], []
    while todo:
        a, b = todo.pop()
        cp = _test(runs, counts, a, b, int(min_frames))
        if cp is not None and cp.p_corrected < alpha:
            changes.append(cp)
            todo += [(a, cp.index), (cp.index, b)]
        else:
            kept.append((a, b, None if cp is None else cp.p_corrected))
    changes.sort(key=lambda c: c.index)
    cuts = [0] + [c.index for c in changes] + [int(n_frames)]
    return Epochs(bounds=list(zip(cuts[:-1], cuts[1:])), changes=changes, kept=sorted(kept), alpha=float(alpha),
                  min_frames=int(min_frames))


def frame_epochs(camera, frames, endpoint_sigma_px=None, *, alpha=ALPHA, min_frames=MIN_FRAMES):
    """The pivot epochs (`Epochs`) of lines.json `frames` (in their order) from the lines the
    fulcrum fits (`fulcrum.sequence_lines`: shaft midlines where there are any, with their
    noise model)."""
    from pencilcal.toolkit.pencil.defaults import ENDPOINT_SIGMA_PX
    from pencilcal.toolkit.pencil.fulcrum import sequence_lines

    sl = sequence_lines(camera, frames, ENDPOINT_SIGMA_PX if endpoint_sigma_px is None else endpoint_sigma_px)
    f = np.array([o[0] for o in sl.owner], int).reshape(-1)
    g = sl.good
    return split_epochs(sl.ideal[g], sl.angle_sigma[g], sl.offset_sigma[g], f[g], len(frames), alpha=alpha,
                        min_frames=min_frames)
