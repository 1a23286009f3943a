"""Where pairs of edges will be in the next frame: a constant-velocity model with its noise.

A printed bar and an instrument shaft are each seen as two edges. In a video they move
between frames (a hand-held target, a moving instrument); `EdgeMotion` predicts where, and
how uncertain that is, so that each is searched where the prediction puts it, within its
predicted uncertainty (`bar_track.BarTracker`, `shaft.detector.ShaftTracker`).

The model: every end point of every edge moves with a constant velocity [px a frame], the
difference of its last two positions; or, for edges whose ends say little (a shaft's
silhouette, seen over more or less of its length from frame to frame: ``along=False``),
every edge's line turns and moves across itself at a constant rate (its angle and its
offset from the image origin, the differences of their last two values) and its end points
are carried onto the predicted line. The prediction's error is the motion's acceleration,
whose variance q [px^2] (the process noise) is estimated from the innovations, the
distances across the edges between where they were predicted and where they were found: an
exponential average over frames of their mean square (weight `Q_WEIGHT` for the newest).
An edge is searched within `K_SIGMA` predicted sd of its prediction, never less than
`MIN_SEARCH_PX` nor more than the model's largest search, and at most half the way to the
nearest other pair (`_spacing`: a search that reaches a neighbour's edge may take it). A pair
new in the view (matched to no predicted one: `match_pairs`) borrows the velocity of the
pairs near it, with their spread as its uncertainty (`_borrowed`); before any velocity is
known a pair may have moved as far as the model's motion prior. Matching keeps the
velocities across detections.

Pairs are (M, 2, 4) arrays of two edges ``[x1, y1, x2, y2]`` [px]: "polar" ones (a bar's
two edges, oriented by polarity, so they run in opposite directions) are matched edge to
edge by direction and never turned round; unsigned ones (a shaft's silhouette edges) by
position, each turned to run like the edge it continues.

Example
-------
>>> e = np.array([[[0.0, 0, 100, 0], [100, 6, 0, 6]]])      # a bar, 6 px wide
>>> m = EdgeMotion()
>>> for k in range(4):
...     m.update(e + [3.0 * k, 1.0 * k, 3.0 * k, 1.0 * k])   # 3 px right, 1 px down a frame
>>> pred, search = m.search()
>>> pred[0, 0].round(6).tolist(), search.tolist()
([12.0, 4.0, 112.0, 4.0], [3.0])
"""
from __future__ import annotations

import numpy as np

__all__ = ["EdgeMotion", "match_pairs", "midlines", "K_SIGMA", "MIN_SEARCH_PX", "MAX_SEARCH_PX", "MOTION_PRIOR_PX",
           "Q_WEIGHT"]

#: Each edge is searched within this many predicted sd of its prediction.
K_SIGMA = 4.0
#: The narrowest search around a predicted edge, and the widest by default [px].
MIN_SEARCH_PX, MAX_SEARCH_PX = 3.0, 32.0
#: How far an edge may move between two frames [px] before its velocity is known, by
#: default (a hand-held target at 30 fps: its centre ~8 px a frame, its bars' far ends more).
MOTION_PRIOR_PX = 16.0
#: The weight of the newest frame in the process noise's running estimate.
Q_WEIGHT = 0.5
_Q0 = 1.0  # [px^2] the process noise before any innovation is seen


def _directions(edges):
    """Unit directions (..., 2) of edges (..., 4)."""
    d = edges[..., 2:] - edges[..., :2]
    return d / np.maximum(np.linalg.norm(d, axis=-1, keepdims=True), 1e-12)


def _across(edges, points):
    """Distance [px] of points (..., K, 2) from the lines of edges (..., 4), across them."""
    u = _directions(edges)
    n = np.stack([-u[..., 1], u[..., 0]], -1)
    return np.abs(np.sum((points - edges[..., None, :2]) * n[..., None, :], -1))


def _turned(edges, flip):
    """Edges (..., 4) with those where `flip` (...) runs the other way round."""
    return np.where(flip[..., None], edges[..., [2, 3, 0, 1]], edges)


def midlines(pairs):
    """The midlines (M, 4) of pairs of edges (M, 2, 4): the mean of the first edge and the
    second one turned to run like it.

    >>> midlines(np.array([[[0.0, 0, 100, 0], [100, 4, 0, 4]]])).tolist()
    [[0.0, 2.0, 100.0, 2.0]]
    """
    P = np.asarray(pairs, float)
    flip = np.sum(_directions(P[:, 0]) * _directions(P[:, 1]), -1) < 0
    return 0.5 * (P[:, 0] + _turned(P[:, 1], flip))


def _aligned(pairs, reference, polar):
    """Pairs (M, 2, 4) with their edges in the order (and, unsigned, the direction) of the
    matching `reference` pairs (M, 2, 4) (module docstring)."""
    if polar:  # the edge that runs like the reference's first comes first
        swap = np.sum(_directions(pairs[:, 0]) * _directions(reference[:, 0]), -1) < 0
    else:  # the order whose edges lie nearer the reference's, across them
        ends = pairs.reshape(len(pairs), 2, 2, 2)
        keep = _across(reference, ends).sum((-1, -2))
        swap = _across(reference, ends[:, ::-1]).sum((-1, -2)) < keep
    out = np.where(swap[:, None, None], pairs[:, ::-1], pairs)
    if not polar:
        out = _turned(out, np.sum(_directions(out) * _directions(reference), -1) < 0)
    return out


def match_pairs(predicted, found, gate_px, max_deg=10.0):
    """Which predicted pair each found pair is: (M_found,) index into predicted, -1 for none.

    predicted, found: pairs of edges (M, 2, 4) [px]; gate_px: (M_pred,) or scalar, the
    farthest a found pair's midline may lie from a predicted one's (across it, at both of
    its ends) [px]; max_deg: the largest angle between the two midlines. Pairs closest
    first, each in one match at most.

    >>> e = np.array([[[0.0, 0, 100, 0], [100, 4, 0, 4]], [[0, 50, 100, 60], [100, 64, 0, 54]]])
    >>> match_pairs(e, e[::-1] + 2.0, 5.0).tolist()
    [1, 0]
    """
    P, F = np.asarray(predicted, float), np.asarray(found, float)
    out = np.full(len(F), -1)
    if len(P) == 0 or len(F) == 0:
        return out
    mp, mf = midlines(P), midlines(F)
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


def _spacing(pairs):
    """(M,) the distance [px] from the centre of each pair's midline (M, 2, 4) to the
    nearest other pair's midline segment (inf for a lone pair): at a fan's grazing tilt its
    spokes crowd."""
    mid = midlines(pairs)
    if len(mid) < 2:
        return np.full(len(mid), np.inf)
    c = 0.5 * (mid[:, :2] + mid[:, 2:])
    p, d = mid[:, :2], mid[:, 2:] - mid[:, :2]
    L2 = np.maximum(np.sum(d * d, -1), 1e-12)
    t = np.clip(np.sum((c[:, None] - p[None]) * d[None], -1) / L2[None], 0.0, 1.0)  # (M, M)
    dist = np.linalg.norm(c[:, None] - (p[None] + t[..., None] * d[None]), axis=-1)
    np.fill_diagonal(dist, np.inf)
    return dist.min(1)


def _lines(edges):
    """(angle [rad], offset [px]) (...,) of the lines of edges (..., 4): n(angle) . x =
    offset, n the unit normal (-d_y, d_x) of the edge's direction d."""
    u = _directions(edges)
    n = np.stack([-u[..., 1], u[..., 0]], -1)
    return np.arctan2(n[..., 1], n[..., 0]), np.sum(n * edges[..., :2], -1)


def _line_change(before, after):
    """(..., 2): the turn [rad] and the move across [px] of each edge's line from `before`
    (..., 4) to `after` (..., 4) (the same direction)."""
    a0, r0 = _lines(before)
    a1, r1 = _lines(after)
    return np.stack([np.angle(np.exp(1j * (a1 - a0))), r1 - r0], -1)


def _onto(edges, lines):
    """Edges (..., 4) with their end points carried onto the lines of `lines` (..., 4)."""
    u = _directions(lines)
    p = edges.reshape(edges.shape[:-1] + (2, 2))
    q = lines[..., None, :2]
    t = np.sum((p - q) * u[..., None, :], -1)
    return (q + t[..., None] * u[..., None, :]).reshape(edges.shape)


def _moved(edges, change):
    """Edges (..., 4) with their lines turned and moved by `change` (..., 2) (`_line_change`)
    and their end points carried onto the new lines (the foot of each)."""
    a, r = _lines(edges)
    a, r = a + change[..., 0], r + change[..., 1]
    n = np.stack([np.cos(a), np.sin(a)], -1)
    p = edges.reshape(edges.shape[:-1] + (2, 2))
    off = np.sum(p * n[..., None, :], -1) - r[..., None]
    return (p - off[..., None] * n[..., None, :]).reshape(edges.shape)


def _innovations(found, predicted):
    """(K,) the largest distance of a predicted edge's end points from the found edge's line
    [px], for each edge of the pairs found (K, 2, 4) and predicted (K, 2, 4)."""
    f, p = found.reshape(-1, 4), predicted.reshape(-1, 4)
    return _across(f, p.reshape(-1, 2, 2)).max(-1)


def _borrowed(pairs, others, velocity, prior_sd):
    """The velocities (K, 2, 4) of pairs (K, 2, 4) new in the view, and their sd (K,) [px a
    frame]: the mean velocity of the pairs `others` (N, 2, 4) whose velocities (N, 2, 4) are
    known, weighted by the inverse square distance of their centres (a target that turns
    moves its bars alike near each other), each end point's the same; its sd the weighted
    spread of theirs (at most `prior_sd`) plus `MIN_SEARCH_PX` / `K_SIGMA` (the new pair
    may move otherwise)."""
    c = pairs.reshape(len(pairs), -1, 2).mean(1)  # (K, 2)
    co = others.reshape(len(others), -1, 2).mean(1)
    v = velocity.reshape(len(velocity), -1, 2).mean(1)  # (N, 2): each pair's mean end point velocity
    w = 1.0 / (np.sum((c[:, None] - co[None]) ** 2, -1) + 1.0)  # (K, N)
    w /= w.sum(1, keepdims=True)
    mean = w @ v  # (K, 2)
    spread = np.sqrt(np.sum(w * np.sum((v[None] - mean[:, None]) ** 2, -1), 1))
    return np.tile(mean, 4).reshape(-1, 2, 4), np.minimum(spread, prior_sd) + MIN_SEARCH_PX / K_SIGMA


class EdgeMotion:
    """The constant-velocity model of pairs of edges (module docstring).

    Parameters: polar (bars' edges oriented by polarity; False: a shaft's unsigned edges),
    prior_px (how far a pair may move before its velocity is known, `MOTION_PRIOR_PX`),
    max_search_px (the widest search, `MAX_SEARCH_PX`), windows (searches rounded up to a
    few widths: a refit per width), along (end points' velocities; False: the lines').

    Attributes: ``edges`` (M, 2, 4) [px] where the pairs were last seen, ``velocity``
    (M, 2, 4) [px a frame] of their end points (along=False: (M, 2, 2), each edge's line's
    turn [rad] and move across [px] a frame), ``velocity_sd`` (M,) [px a frame] how
    uncertain each pair's velocity is (0 once seen in two frames), ``q`` [px^2] the process
    noise, ``age`` frames since the pairs were last seen.
    """

    def __init__(self, polar=True, prior_px=MOTION_PRIOR_PX, max_search_px=MAX_SEARCH_PX, windows=True, along=True):
        self.polar, self.prior_px, self.max_search_px = bool(polar), float(prior_px), float(max_search_px)
        self.windows, self.along = bool(windows), bool(along)
        self.edges = np.zeros((0, 2, 4))
        self.velocity = np.zeros((0, 2, 4 if along else 2))
        self.velocity_sd = np.zeros(0)
        self.q = _Q0
        self.age = 1

    def __len__(self):
        return len(self.edges)

    @property
    def known(self):
        """(M,) whether each pair's velocity was measured (seen in two frames)."""
        return self.velocity_sd == 0

    def predict(self):
        """(edges (M, 2, 4) [px], sd (M,) [px]) where the pairs are predicted in the next frame
        and the sd of that prediction across their edges."""
        a = self.age
        pred = self.edges + a * self.velocity if self.along else _moved(self.edges, a * self.velocity)
        return pred, a * np.sqrt(self.q + self.velocity_sd ** 2)

    def search(self):
        """(predicted edges (M, 2, 4), search half-width (M,) [px]): `K_SIGMA` sd, within
        [MIN_SEARCH_PX, max_search_px] and at most half the way to the nearest other pair,
        rounded up to a few widths (powers of 2 and their halves) where ``windows``."""
        pred, sd = self.predict()
        w = np.clip(np.minimum(K_SIGMA * sd, 0.5 * _spacing(pred)), MIN_SEARCH_PX, self.max_search_px)
        if self.windows:
            w = np.minimum(np.exp2(np.ceil(2 * np.log2(w / MIN_SEARCH_PX) - 1e-9) / 2) * MIN_SEARCH_PX,
                           self.max_search_px)
        return pred, w

    def update(self, pairs, keep_extent=False):
        """The pairs seen in this frame, (M', 2, 4) [px]: matched to the predicted ones, whose
        velocities they update (the innovations of those with a known velocity update q);
        the others borrow theirs from the matched ones (`_borrowed`) or, none matched, start
        with the motion prior as their velocity's uncertainty. keep_extent: a matched pair
        keeps its predicted extent, its end points carried onto the lines seen (a tracked
        shaft is measured over part of its length: the next search covers it all)."""
        pairs = np.asarray(pairs, float).reshape(-1, 2, 4).copy()
        vel = np.zeros(pairs.shape[:2] + self.velocity.shape[2:])
        vsd = np.full(len(pairs), self.prior_px / K_SIGMA)
        if len(self.edges) and len(pairs):
            pred, sd = self.predict()
            m = match_pairs(pred, pairs, np.clip(K_SIGMA * sd, MIN_SEARCH_PX, self.max_search_px) + 2.0)
            hit = np.flatnonzero(m >= 0)
            if hit.size:
                i = m[hit]
                got = _aligned(pairs[hit], pred[i], self.polar)
                if keep_extent:
                    got = _onto(pred[i], got)
                pairs[hit] = got
                vel[hit] = (got - self.edges[i] if self.along else _line_change(self.edges[i], got)) / self.age
                vsd[hit] = 0.0
                was = self.known[i]
                if was.any():
                    inn = _innovations(got[was], pred[i][was])
                    self.q = (1 - Q_WEIGHT) * self.q + Q_WEIGHT * float(np.mean(inn ** 2)) / self.age ** 2
                new = np.flatnonzero(m < 0)
                if new.size and self.along:
                    vel[new], vsd[new] = _borrowed(pairs[new], pairs[hit], vel[hit], self.prior_px / K_SIGMA)
        self.edges, self.velocity, self.velocity_sd, self.age = pairs, vel, vsd, 1

    def missed(self):
        """No pairs seen in this frame: the next prediction is one frame further ahead."""
        self.age += 1
