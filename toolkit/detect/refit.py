"""Refit of oriented lines to their edges with subpixel precision and honest uncertainty.

Used by `segments` and `bars`. A line ``[x1, y1, x2, y2]`` [working px] is oriented: the
image gets brighter along its normal n = (-d_y, d_x). A *pass* (`EdgeRefit`) samples
stations every `step_px` along the line, from `extend` px before its first end to
`extend` beyond its second, and finds the edge across each (`edges.edge_profiles`, the
peak of the Gaussian-derivative response within +-search). Stations with a weak edge
(under `min_gradient` or `rel_gradient` times the line's median) are left out; a weighted
line fit (weights: squared edge strength) rejects stations beyond 3 robust sd or
`floor_px` and keeps the best run of stations with gaps <= `max_gap_px`; it is trimmed by
2 sigma + 1 px at each end (where a corner's blur pulls the edge) and its ends are moved to
where the edge response falls to half (the end of a blurred edge). A line whose fit strayed
more than search / 2 from the line sampled, or whose edge runs on past the stations
looked at, is sampled again from its new fit, up to 4 passes in all.

The result (`EdgeFit`) holds the lines in working pixels with the sd of their angle [rad]
and of their perpendicular position [px] at the stations' weighted centroid
(`edges.fit_variances`).

Example
-------
>>> import numpy as np
>>> from pencilcal.toolkit.detect.image import GrayImage
>>> img = GrayImage(np.where(np.arange(60)[None, :] >= 30, 200, 10).repeat(50, 0).astype(np.uint8))
>>> fit = refit_lines(img, [[30.5, 40.0, 30.5, 10.0]])          # brighter on the right: n = +x
>>> bool(fit.ok[0]), round(float(fit.p1[0, 0]), 2), round(float(fit.p2[0, 0]), 2)   # the edge at x = 29.5
(True, 29.5, 29.5)
"""
from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from pencilcal.toolkit.detect.edges import (
    MIN_STATIONS,
    derivative_kernel,
    edge_profiles,
    fit_variances,
    masked_median,
    reject_outliers,
    relative_weights,
    station_counts,
    stations,
    weighted_line,
)
from pencilcal.toolkit.errors import InputError

__all__ = ["RefitOptions", "EdgeFit", "EdgeRefit", "refit_lines"]

_MAX_STATIONS = 400  # per line: long lines get sparser stations, the cost stays bounded


@dataclass(frozen=True)
class RefitOptions:
    """Settings of a refit (see the module docstring); lengths in working pixels.

    search: half-width of the edge search across the line; extend: how far the first pass
    looks beyond each end; sigma_px: sd of the Gaussian-derivative kernel (~ the edge blur);
    step_px: spacing of the stations; max_gap_px: longest gap in one line's stations;
    min_gradient [grey levels / px] and rel_gradient (of the line's median): weakest edge
    a station may have; floor_px: smallest rejection threshold of the robust fit; gamma: the
    frames' encoding gamma, the edge located on the profiles linearised with it
    (`edges.edge_profiles`; 1: as sampled).
    """

    search: float = 2.0
    extend: float = 8.0
    sigma_px: float = 1.0
    step_px: float = 2.0
    max_gap_px: float = 30.0
    min_gradient: float = 2.0
    rel_gradient: float = 0.3
    floor_px: float = 0.1
    gamma: float = 1.0

    def __post_init__(self):
        if not (self.search > 0 and self.sigma_px > 0 and self.step_px > 0):
            raise InputError("search_px, sigma_px and step_px must be positive")


@dataclass(frozen=True, eq=False)
class EdgeFit:
    """Refitted lines in working pixels, M of them; arrays have leading shape (M,).

    Attributes
    ----------
    ok : (M,) bool
        The line was refitted (enough stations with an edge).
    p1, p2 : (M, 2) [px]
        End points on the fitted line, oriented as the input.
    centroid : (M, 2) [px]
        Weighted centroid of the inlier stations (the pivot of angle errors).
    angle_sigma : (M,) [rad]
        sd of the line's angle.
    centre_sigma : (M,) [px]
        sd of its perpendicular position at the centroid.
    contrast : (M,) [grey levels]
        Median step across the edge (bright side minus dark side).
    residual : (M,) [px]
        RMS distance of the inlier station edges from the line.
    count : (M,) int
        Inlier stations.
    """

    ok: np.ndarray
    p1: np.ndarray
    p2: np.ndarray
    centroid: np.ndarray
    angle_sigma: np.ndarray
    centre_sigma: np.ndarray
    contrast: np.ndarray
    residual: np.ndarray
    count: np.ndarray

    def offset_sigma_at(self, q):
        """Perpendicular sd [px] (M,) of each line at points q (M, 2) (lever arm from the
        centroid)."""
        u = self.p2 - self.p1
        u = u / np.maximum(np.linalg.norm(u, axis=-1, keepdims=True), 1e-12)
        r = np.sum((q - self.centroid) * u, -1)
        return np.sqrt(self.centre_sigma**2 + (r * self.angle_sigma) ** 2)

    def take(self, idx):
        """The lines `idx` (bool (M,) or indices) selects."""
        return EdgeFit(**{f.name: getattr(self, f.name)[idx] for f in fields(EdgeFit)})

    def lines(self):
        """(M, 4) [px] ``[x1, y1, x2, y2]`` of every line."""
        return np.concatenate([self.p1, self.p2], -1)


@dataclass(frozen=True, eq=False)
class _PassFit(EdgeFit):
    """One pass's result (its arrays updated in place by further passes): an `EdgeFit` and
    what decides on a further pass, per line: touch (the edge runs on past the stations
    looked at), dev [px] (how far the fit strayed from the line sampled)."""

    touch: np.ndarray
    dev: np.ndarray

    @classmethod
    def empty(cls):
        z = np.zeros(0)
        return cls(ok=np.zeros(0, bool), p1=np.zeros((0, 2)), p2=np.zeros((0, 2)), centroid=np.zeros((0, 2)),
                   angle_sigma=z, centre_sigma=z.copy(), contrast=z.copy(), residual=z.copy(),
                   count=np.zeros(0, int), touch=np.zeros(0, bool), dev=z.copy())

    def fit(self):
        return EdgeFit(**{f.name: getattr(self, f.name).copy() for f in fields(EdgeFit)})


def _by_length(img, camera, P1, P2, opts, kernel, grow_frac, cnt, measure=True):
    """`_refit_pass` over lines of very different lengths, in groups of similar length:
    padding every line to the longest would waste most of the work."""
    M = P1.shape[0]
    group = np.digitize(cnt, [24, 96])
    outs = [(idx, _refit_pass(img, camera, P1[idx], P2[idx], opts, kernel, grow_frac, measure, split=idx.size < M))
            for idx in (np.flatnonzero(group == g_) for g_ in np.unique(group))]
    first = outs[0][1]
    res = _PassFit(**{f.name: np.zeros((M,) + getattr(first, f.name).shape[1:], getattr(first, f.name).dtype)
                      for f in fields(_PassFit)})
    for idx, o in outs:
        for f in fields(_PassFit):
            getattr(res, f.name)[idx] = getattr(o, f.name)
    return res


def _trim_ends(s, inl, sigma_px):
    """The inliers without the stations within 2 sd of the blur + 1 px of either end of
    their run, where that leaves enough of them: near its ends an edge usually meets another
    (a corner, a junction) whose blur pulls the gradient peak off the line by a fraction of
    a pixel, on one side only. Returns (inl, k1, k2): k1, k2 the first and last station of
    the run before the trim."""
    S = s.shape[1]
    rows = np.arange(s.shape[0])
    k1 = np.argmax(inl, 1)
    k2 = S - 1 - np.argmax(inl[:, ::-1], 1)
    s_first, s_last = s[rows, k1], s[rows, k2]
    margin = 2.0 * sigma_px + 1.0
    core = inl & (s >= (s_first + margin)[:, None]) & (s <= (s_last - margin)[:, None])
    use_core = core.sum(-1) >= MIN_STATIONS
    return np.where(use_core[:, None], core, inl), k1, k2


def _half_response_ends(s, g0, gv, inl, k1, k2, cnt, ok):
    """The ends (M,) [px along] of each line where the edge response falls to half its
    median: the response along a blurred edge that stops is a blurred step, so its half point
    is the end of the edge (stations alone would quantise the ends to step_px). g0: the
    response at each station, gv: the same where valid (0 elsewhere); k1, k2 the first and
    last inlier stations."""
    S = s.shape[1]
    rows = np.arange(s.shape[0])
    gh = 0.5 * masked_median(g0, inl)
    ends = []
    for k, kout in ((k1, k1 - 1), (k2, k2 + 1)):
        kin = np.clip(kout, 0, S - 1)
        exists = (kout >= 0) & (kout < cnt) & ok
        gi, go = g0[rows, k], gv[rows, kin]
        cross = exists & (go < gh) & (gi >= gh)
        frac = np.where(cross, (gi - gh) / np.where(cross, gi - go, 1.0), 0.0)
        ends.append(np.where(cross, s[rows, k] + frac * (s[rows, kin] - s[rows, k]), s[rows, k]))
    return ends


def _refit_pass(img, camera, P1, P2, opts, kernel, grow_frac=0.0, measure=True, split=True):
    """One pass of the refit over lines P1 -> P2 (M, 2) [working px]; returns a `_PassFit`.
    With grow_frac > 0 the stations reach max(extend, grow_frac L) beyond the ends. With
    measure False only the lines (ok, ends, centroid, count and what decides on a further
    pass): their sigmas, contrast and residual NaN (a coarse search whose lines are refitted
    again skips their cost). With split False the lines are not grouped by length (`_by_length`:
    all of them in one group already; grouped again, a group of over 350 similar lines
    recursed without end)."""
    M = P1.shape[0]
    d = P2 - P1
    L = np.hypot(d[:, 0], d[:, 1])
    ok = np.isfinite(L) & (L > 1e-6)
    L = np.where(ok, L, 1.0)
    u = d / L[:, None]
    e = np.minimum(np.maximum(opts.extend, grow_frac * L), 0.5 * L + 2.0)
    lo, hi = -e, L + e
    cnt = station_counts(lo, hi, opts.step_px, _MAX_STATIONS)
    if split and M >= 32 and M * int(cnt.max()) > 3 * int(cnt.sum()) + 8000:
        return _by_length(img, camera, P1, P2, opts, kernel, grow_frac, cnt, measure)
    s, st_valid = stations(lo, hi, cnt)
    p = edge_profiles(img, camera, P1, u, s, opts.search, kernel, opts.sigma_px, gamma=opts.gamma)
    g0, tk = p.strength, p.t
    base = st_valid & p.inside & p.found & ok[:, None]
    med = masked_median(g0, base)
    base &= (g0 >= opts.min_gradient) & (g0 >= opts.rel_gradient * med[:, None])
    w = relative_weights(g0, base)
    inl = reject_outliers(s, tk, w, base, base, opts.floor_px, opts.max_gap_px, iters=4)
    inl, k1, k2 = _trim_ends(s, inl, opts.sigma_px)
    sm, tm, b, Sss, Wt = weighted_line(s, tk, w, inl)
    res = tk - tm[:, None] - b[:, None] * (s - sm[:, None])
    count = inl.sum(-1)
    ok &= count >= MIN_STATIONS
    gv = np.where(p.found & p.inside & st_valid, np.maximum(g0, 0.0), 0.0)
    s_first, s_last = _half_response_ends(s, g0, gv, inl, k1, k2, cnt, ok)
    # the edge runs on beyond the stations looked at: worth growing the line
    touch = ok & ((k1 == 0) | (k2 == cnt - 1))
    dev = np.maximum(np.abs(tm + b * (s_first - sm)), np.abs(tm + b * (s_last - sm)))

    ux, uy, nx, ny = u[:, 0], u[:, 1], -u[:, 1], u[:, 0]

    def at(sv):
        tv = tm + b * (sv - sm)
        return np.stack([P1[:, 0] + sv * ux + tv * nx, P1[:, 1] + sv * uy + tv * ny], -1)

    if not measure:
        nan = np.full(M, np.nan)
        return _PassFit(ok=ok, p1=at(s_first), p2=at(s_last), centroid=at(sm), angle_sigma=nan, centre_sigma=nan.copy(),
                        contrast=nan.copy(), residual=nan.copy(), count=count, touch=touch, dev=dev)
    var_b, var_a = fit_variances(res, w, inl, Sss, Wt)
    prof = p.profiles
    cst = masked_median(prof[..., -3:].mean(-1) - prof[..., :3].mean(-1), inl)
    return _PassFit(
        ok=ok, p1=at(s_first), p2=at(s_last), centroid=at(sm),
        angle_sigma=np.sqrt(var_b) / (1.0 + b * b), centre_sigma=np.sqrt(var_a),
        contrast=np.nan_to_num(cst), residual=np.sqrt(np.sum(np.where(inl, res * res, 0.0), -1) / np.maximum(count, 1)),
        count=count, touch=touch, dev=dev,
    )


class EdgeRefit:
    """A refit in progress: the first pass over lines (M, 4) [working px] on construction,
    further passes over chosen lines with `more`, the result so far with `fit`.

    Parameters
    ----------
    img : GrayImage
        The raw image.
    lines : (M, 4) [working px]
        Oriented lines (brighter along n), each within ~search of its edge.
    camera : Camera, optional
        Lens model: the working pixels are undistorted, the profiles are sampled in the raw
        image through it.
    options : RefitOptions
    measure : bool
        False: the lines only, their sigmas, contrast and residual NaN (`_refit_pass`).
    """

    def __init__(self, img, lines, camera=None, options=RefitOptions(), measure=True):
        lines = np.asarray(lines, float).reshape(-1, 4)
        self.img, self.camera, self.options, self._measure = img, camera, options, measure
        self._kernel = derivative_kernel(options.sigma_px)
        if lines.shape[0] == 0:
            self._res = _PassFit.empty()
        else:
            self._res = _refit_pass(img, camera, lines[:, :2], lines[:, 2:], options, self._kernel, measure=measure)

    def more(self, idx=None, *, grow=True, max_passes=4):
        """Further passes over the lines `idx` (all when None), in place: while a line's fit
        strayed more than search / 2 from the line sampled or, with `grow`, its edge runs on
        past the stations (then it looks a quarter of its length further each time); at
        most max_passes - 1."""
        res = self._res
        sel = np.arange(res.ok.shape[0]) if idx is None else np.asarray(idx, int)
        for _ in range(max_passes - 1):
            need = sel[res.ok[sel] & ((res.dev[sel] > 0.5 * self.options.search) | (grow & res.touch[sel]))]
            if need.size == 0:
                break
            new = _refit_pass(self.img, self.camera, res.p1[need], res.p2[need], self.options, self._kernel,
                              grow_frac=0.25 if grow else 0.0, measure=self._measure)
            good = new.ok
            for f in fields(_PassFit):
                getattr(res, f.name)[need[good]] = getattr(new, f.name)[good]
            # a line that grew is looked at again only if it still touches the end
            res.touch[need[~good]] = False
            res.dev[need[~good]] = 0.0

    def fit(self):
        """The `EdgeFit` so far (a copy)."""
        return self._res.fit()


def refit_lines(img, lines, camera=None, options=RefitOptions(), *, grow=True, max_passes=4, measure=True):
    """Refit oriented lines (M, 4) [working px] to the edges of `img` (a `GrayImage` of the
    raw image): the first pass and up to max_passes - 1 more (`EdgeRefit`). Returns an
    `EdgeFit` (M rows, input order; ``ok`` False where a line could not be refitted; with
    measure False the lines only, `EdgeRefit`)."""
    st = EdgeRefit(img, lines, camera, options, measure)
    st.more(None, grow=grow, max_passes=max_passes)
    return st.fit()

