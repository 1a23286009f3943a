"""Printed bars from frame to frame: each bar looked for where a motion model predicts it.

A full bar detection (`bars.detect_bars`) proposes lines over the whole frame (a line
detector on the reduced image, merging, rough pairing, partners for lone edges) and then
refits the candidates; on a 1080p frame the proposals are most of its cost. In a video the
target moves between frames, so `BarTracker` predicts where each bar's edges are in this
frame and gives them to `bars.find_bars` as its candidates, each searched within its
predicted uncertainty, and measures them exactly as a full detection does (refit, pairing,
neighbours, caps): a tracked bar is the same measurement of the same edge, from other
stations along it.

The motion model (`EdgeMotion`): every end point of every edge moves with a constant
velocity (raw px a frame), the difference of its last two positions; the prediction's error
is the hand's acceleration, whose variance q [px^2] (the process noise) is estimated from
the innovations, the distances across the edges between where they were predicted and where
they were found (an exponential average over frames of their mean square, weighted
`Q_WEIGHT` for the newest). An edge is searched within ``K_SIGMA`` predicted sd of its
prediction, never less than `MIN_SEARCH_PX` nor more than `MAX_SEARCH_PX`. A bar new in the
view (found by a detection, matched to no predicted bar: `match_bars`) borrows the velocity
of the bars near it, with their spread as its uncertainty (`_borrowed`); before any
velocity is known (the frame after the first) the bars are detected in the region around
where they were instead. Matching keeps the velocities across detections (after a lost
track, or the periodic one).

The prior is checked, never trusted: the caller judges the frame by what it is for (the
orientation: `orient` falls back when the tracked frame's fit fails or uses fewer spokes
than the last detection, less one) and calls `BarTracker.lost`; the next call then detects
the bars in the region around their prediction (`region_of`, the line detector on that part
of the frame only), and if that fails too, in the whole frame. The first frame, a frame of
another size and every `REDETECT_FRAMES`-th frame (a spoke that came into view) are
detected too: the periodic one in the region around the prediction.

Example
-------
>>> tracker = BarTracker()                                      # doctest: +SKIP
>>> for frame in frames:                                        # doctest: +SKIP
...     bars, tracked = tracker(frame.image, camera=cam, min_length=30.0)
...     rec = orient_segments(cam, bars.segments, pencil)
...     tracker.keep(rec.spokes >= 0) if rec.ok else tracker.lost()
"""
from __future__ import annotations

import numpy as np

from pencilcal.toolkit.detect.bars import find_bars

__all__ = ["BarTracker", "EdgeMotion", "match_bars", "region_of", "REDETECT_FRAMES", "K_SIGMA", "MIN_SEARCH_PX",
           "MAX_SEARCH_PX", "MOTION_PRIOR_PX", "Q_WEIGHT", "REGION_MARGIN"]

#: A detection at least every this many frames (a second at 30 fps), whatever the prior.
REDETECT_FRAMES = 30
#: Each edge is searched within this many predicted sd of its prediction.
K_SIGMA = 4.0
#: The narrowest and the widest search around a predicted edge [px].
MIN_SEARCH_PX, MAX_SEARCH_PX = 3.0, 32.0
#: The largest motion of an edge between two frames [px] expected before its velocity is
#: known (a hand-held target at 30 fps: its centre ~8 px a frame, its spokes' far ends more).
MOTION_PRIOR_PX = 16.0
#: The weight of the newest frame in the process noise's running estimate.
Q_WEIGHT = 0.5
#: The region around a lost track's prediction: its bars' bounding box grown by this
#: fraction of its size on every side (plus the search), within the frame.
REGION_MARGIN = 0.5
_Q0 = 1.0  # [px^2] the process noise before any innovation is seen
_WINDOWS = np.array([3.0, 4.0, 6.0, 8.0, 12.0, 16.0, 24.0, 32.0])  # searches rounded up to these


def _directions(edges):
    """Unit directions (..., 2) of edges (..., 4)."""
    d = edges[..., 2:] - edges[..., :2]
    return d / np.maximum(np.linalg.norm(d, axis=-1, keepdims=True), 1e-12)


def _aligned(edges, reference):
    """Bars' edges (M, 2, 4) ordered like `reference` (M, 2, 4): a bar's two edges run in
    opposite directions (oriented by polarity), so its edge that runs like the reference's
    first one comes first."""
    swap = np.sum(_directions(edges[:, 0]) * _directions(reference[:, 0]), -1) < 0
    out = edges.copy()
    out[swap] = edges[swap][:, ::-1]
    return out


def _across(edges, points):
    """Distance [px] of points (..., K, 2) from the lines of edges (..., 4), across them."""
    u = _directions(edges)
    n = np.stack([-u[..., 1], u[..., 0]], -1)
    return np.abs(np.sum((points - edges[..., None, :2]) * n[..., None, :], -1))


def match_bars(predicted, found, gate_px, max_deg=10.0):
    """Which predicted bar each found bar is: (M_found,) index into predicted, -1 for none.

    predicted, found: bars' edges (M, 2, 4) [raw px]; gate_px: (M_pred,) or scalar, the
    farthest a found bar's midline may lie from a predicted one's (across it, at both of
    its ends) [px]; max_deg: the largest angle between the two midlines. Pairs closest
    first, each bar in one pair at most.

    >>> e = np.array([[[0.0, 0, 100, 0], [100, 4, 0, 4]], [[0, 50, 100, 60], [100, 64, 0, 54]]])
    >>> match_bars(e, e[::-1] + 2.0, 5.0).tolist()
    [1, 0]
    """
    P, F = np.asarray(predicted, float), np.asarray(found, float)
    out = np.full(len(F), -1)
    if len(P) == 0 or len(F) == 0:
        return out
    mp = 0.5 * (P[:, 0] + P[:, 1, [2, 3, 0, 1]])  # midlines (M, 4), running like edge 0
    mf = 0.5 * (F[:, 0] + F[:, 1, [2, 3, 0, 1]])
    cos = np.abs(_directions(mp) @ _directions(mf).T)  # (P, F)
    ends = mf.reshape(-1, 2, 2)  # (F, 2, 2)
    dist = _across(mp[:, None, :], np.broadcast_to(ends[None], (len(P),) + ends.shape)).max(-1)  # (P, F)
    ok = (cos >= np.cos(np.radians(max_deg))) & (dist <= np.broadcast_to(gate_px, (len(P),))[:, None])
    used = np.zeros(len(P), bool)
    for k in np.argsort(np.where(ok, dist, np.inf), axis=None, kind="stable"):
        i, j = divmod(int(k), len(F))
        if not ok[i, j]:
            break
        if not used[i] and out[j] < 0:
            used[i], out[j] = True, i
    return out


def region_of(edges, shape, margin=REGION_MARGIN, pad_px=0.0):
    """The region (x0, y0, x1, y1) [raw px, ints, x1 and y1 excluded] around bars' edges
    (M, 2, 4): their bounding box grown by `margin` of its size and `pad_px` on every side,
    within an image of `shape` (H, W); None when the edges are none or not finite.

    >>> region_of(np.array([[[100.0, 100, 200, 100], [200, 110, 100, 110]]]), (480, 640), 0.25, 4.0)
    (71, 93, 230, 118)
    """
    p = np.asarray(edges, float).reshape(-1, 2)
    if p.size == 0 or not np.all(np.isfinite(p)):
        return None
    lo, hi = p.min(0), p.max(0)
    grow = margin * (hi - lo) + pad_px
    H, W = shape
    x0, y0 = np.floor(np.maximum(lo - grow, 0)).astype(int)
    x1, y1 = np.ceil(np.minimum(hi + grow + 1, [W, H])).astype(int)
    return (int(x0), int(y0), int(x1), int(y1)) if x1 > x0 and y1 > y0 else None


class EdgeMotion:
    """The constant-velocity model of the bars' edges (module docstring).

    Attributes: ``edges`` (M, 2, 4) [raw px] where the bars were last seen, ``velocity``
    (M, 2, 4) [px a frame] of their end points, ``velocity_sd`` (M,) [px a frame] how
    uncertain each bar's velocity is (0 for one seen in two frames; for a bar new in the
    view, the spread of the velocities of the bars it borrows its own from, or
    `MOTION_PRIOR_PX` / `K_SIGMA` when no bar's velocity is known), ``q`` [px^2] the
    process noise, ``age`` frames since the bars were last seen.
    """

    def __init__(self):
        self.edges = np.zeros((0, 2, 4))
        self.velocity = np.zeros((0, 2, 4))
        self.velocity_sd = np.zeros(0)
        self.q = _Q0
        self.age = 1

    def __len__(self):
        return len(self.edges)

    @property
    def known(self):
        """(M,) whether each bar's velocity was measured (seen in two frames)."""
        return self.velocity_sd == 0

    def predict(self):
        """(edges (M, 2, 4) [raw px], sd (M,) [px]) where the bars are predicted in the next
        frame and the sd of that prediction across their edges."""
        a = self.age
        return self.edges + a * self.velocity, a * np.sqrt(self.q + self.velocity_sd ** 2)

    def search(self):
        """(predicted edges (M, 2, 4), search half-width (M,) [px]): K_SIGMA sd, within
        [MIN_SEARCH_PX, MAX_SEARCH_PX] and at most half the way to the nearest other bar
        (`_spacing`: a search that reaches a neighbour's edge may take it), rounded up to a
        few widths (a refit per width)."""
        pred, sd = self.predict()
        w = np.clip(np.minimum(K_SIGMA * sd, 0.5 * _spacing(pred)), MIN_SEARCH_PX, MAX_SEARCH_PX)
        return pred, _WINDOWS[np.minimum(np.searchsorted(_WINDOWS, w - 1e-9), len(_WINDOWS) - 1)]

    def update(self, edges):
        """The bars seen in this frame, (M', 2, 4) [raw px]: matched to the predicted ones,
        whose velocities they update (the innovations of those with a known velocity update
        q); the others borrow theirs from the matched ones (`_borrowed`)."""
        edges = np.asarray(edges, float).reshape(-1, 2, 4).copy()
        vel = np.zeros_like(edges)
        vsd = np.full(len(edges), MOTION_PRIOR_PX / K_SIGMA)
        if len(self.edges) and len(edges):
            pred, sd = self.predict()
            m = match_bars(pred, edges, np.clip(K_SIGMA * sd, MIN_SEARCH_PX, MAX_SEARCH_PX) + 2.0)
            hit = np.flatnonzero(m >= 0)
            if hit.size:
                i = m[hit]
                got = _aligned(edges[hit], pred[i])
                edges[hit] = got
                vel[hit] = (got - self.edges[i]) / self.age
                vsd[hit] = 0.0
                was = self.known[i]
                if was.any():
                    inn = _innovations(got[was], pred[i][was])
                    self.q = (1 - Q_WEIGHT) * self.q + Q_WEIGHT * float(np.mean(inn ** 2)) / self.age ** 2
                new = np.flatnonzero(m < 0)
                if new.size:
                    vel[new], vsd[new] = _borrowed(edges[new], edges[hit], vel[hit])
        self.edges, self.velocity, self.velocity_sd, self.age = edges, vel, vsd, 1

    def missed(self):
        """No bars seen in this frame: the next prediction is one frame further ahead."""
        self.age += 1


def _spacing(edges):
    """(M,) the distance [px] from the centre of each bar (M, 2, 4) to the nearest other
    bar's midline segment (inf for a lone bar): at a fan's grazing tilt its spokes crowd."""
    mid = 0.5 * (edges[:, 0] + edges[:, 1, [2, 3, 0, 1]])  # (M, 4)
    c = 0.5 * (mid[:, :2] + mid[:, 2:])
    p, d = mid[:, :2], mid[:, 2:] - mid[:, :2]
    L2 = np.maximum(np.sum(d * d, -1), 1e-12)
    t = np.clip(np.sum((c[:, None] - p[None]) * d[None], -1) / L2[None], 0.0, 1.0)  # (M, M)
    dist = np.linalg.norm(c[:, None] - (p[None] + t[..., None] * d[None]), axis=-1)
    np.fill_diagonal(dist, np.inf)
    return dist.min(1) if len(edges) > 1 else np.full(len(edges), np.inf)


def _innovations(found, predicted):
    """(K,) the largest distance of a predicted edge's end points from the found edge's line
    [px], for each edge of the bars found (K, 2, 4) and predicted (K, 2, 4)."""
    f, p = found.reshape(-1, 4), predicted.reshape(-1, 4)
    return _across(f, p.reshape(-1, 2, 2)).max(-1)


def _borrowed(edges, others, velocity):
    """The velocities (K, 2, 4) of bars (K, 2, 4) new in the view, and their sd (K,) [px a
    frame]: the mean velocity of the bars (N, 2, 4) whose velocities (N, 2, 4) are known,
    weighted by the inverse square distance of their centres (a target that turns moves its
    bars alike near each other), each end point's the same; its sd the weighted spread of
    theirs (at most `MOTION_PRIOR_PX` / `K_SIGMA`) plus `MIN_SEARCH_PX` / `K_SIGMA` (the
    new bar may move otherwise)."""
    c = edges.reshape(len(edges), -1, 2).mean(1)  # (K, 2)
    co = others.reshape(len(others), -1, 2).mean(1)
    v = velocity.reshape(len(velocity), -1, 2).mean(1)  # (N, 2): each bar's mean end point velocity
    w = 1.0 / (np.sum((c[:, None] - co[None]) ** 2, -1) + 1.0)  # (K, N)
    w /= w.sum(1, keepdims=True)
    mean = w @ v  # (K, 2)
    spread = np.sqrt(np.sum(w * np.sum((v[None] - mean[:, None]) ** 2, -1), 1))
    return np.tile(mean, 4).reshape(-1, 2, 4), np.minimum(spread, MOTION_PRIOR_PX / K_SIGMA) + MIN_SEARCH_PX / K_SIGMA


class BarTracker:
    """Bars frame after frame (module docstring). Call it on the frames in order.

    Attributes: ``tracked`` (frames whose bars came from the prediction and were kept),
    ``regional`` (frames detected in the region around the prediction), ``full_used``
    (what the caller kept of the last detection, e.g. its number of spokes; None before),
    ``motion`` (the `EdgeMotion`), ``last_mode`` ("track", "region" or "full": how the
    latest call found its bars).
    """

    def __init__(self, redetect_frames=REDETECT_FRAMES):
        self.redetect_frames = int(redetect_frames)
        self.tracked = 0
        self.regional = 0
        self.full_used = None
        self.motion = EdgeMotion()
        self.last_mode = None
        self._polarity = None
        self._shape = None
        self._since_full = 0
        self._next = "full"  # how the next call finds its bars
        self._last = None  # the latest call's bars

    def __call__(self, image, detector="auto", *, polarity="dark", **options):
        """This frame's bars and whether they were tracked: (Bars, bool). The keywords are
        `bars.detect_bars`' (detector, camera, min_length, width_px_range, valid_region, ...);
        give the same ones every frame."""
        shape = np.shape(image)[:2]
        mode = self._next
        if shape != self._shape or len(self.motion) < 2:
            mode = "full"
        elif mode == "track" and not self.motion.known.any():
            mode = "region"  # no velocity known yet: nothing to predict by
        elif mode == "track" and self._since_full + 1 >= self.redetect_frames:
            mode = "region"
        roi = None
        if mode == "track":
            pred, search = self.motion.search()
            bars, _ = find_bars(image, detector, polarity=self._polarity, prior=pred, prior_search=search, **options)
            self._since_full += 1
        else:
            if mode == "region":
                pred, search = self.motion.search()
                roi = region_of(pred, shape, pad_px=float(np.max(search)))
            bars, self._polarity = find_bars(image, detector, polarity=self._polarity if roi is not None else polarity,
                                             roi=roi, **options)
            self._since_full = 0
            mode = "region" if roi is not None else "full"
        self._shape = shape
        self._last = bars
        self.last_mode = mode
        self._next = "track"
        return bars, mode == "track"

    @property
    def last_tracked(self):
        """Whether the latest call's bars came from the prediction."""
        return self.last_mode == "track"

    def keep(self, mask=None, used=None):
        """The latest call's bars did (the caller's judgement). After a detection only the
        bars `mask` (bool (M,) over its bars, e.g. the spokes the orientation used) are
        followed in the next frames, and `used` is remembered (`full_used`, e.g. that number
        of spokes). After a tracked call every bar found is followed: each was a spoke when
        last detected, and one that this frame's fit left out (an outlier this once) may be
        back in the next."""
        bars = self._last
        edges = bars.edges
        if self.last_mode == "track":
            self.tracked += 1
        else:
            self.regional += self.last_mode == "region"
            if mask is not None:
                edges = edges[np.asarray(mask, bool)]
            self.full_used = used
        self.motion.update(edges)

    def lost(self):
        """The latest call's bars did not do (the caller's judgement): the next call detects
        them in the region around their prediction after a tracked call, in the whole frame
        after a detection. Returns whether another detection is worth trying on this frame."""
        again = self.last_mode != "full"
        self._next = "region" if self.last_mode == "track" else "full"
        if not again:
            self.motion.missed()
        return again
