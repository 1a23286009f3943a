"""A radial target's edges against their vertex: the offset they share beyond their sigmas,
and the turn of each edge it shows (`detect.radial`: the edges' offset sds, the gate through
the vertex, and a star's angle sds for the orientation's covariance).
"""
from __future__ import annotations

import numpy as np

__all__ = ["TURN_SHARE", "common_offset", "turned_sigma"]

#: The share of the frame's common offset (`common_offset`) taken as each star edge's turn
#: about its middle (`turned_sigma`): its variance half turn, half shift (the root of 1/2;
#: not tuned).
TURN_SHARE = float(np.sqrt(0.5))


def common_offset(segs, v, shared=True):
    """The sd [px] of the edges' distances from the vertex v (2,) they share beyond what
    their own sigmas allow (robust: from the medians of the squared distances and of their
    predicted variances, the median of chi-square(1) being 0.455): what the stations' scatter
    cannot show and every edge has, a gamma not quite the camera's, a raised wire beside a
    dartboard's boundary (seen obliquely, its side shows on one side of the line). 0 where
    the edges meet as their sigmas say.

    Without `shared`, what the edges do not share: their distances (signed by the side each
    edge is brighter on) less the least-squares fit of a distance g they all share towards
    their bright side and a shift of the vertex (an edge of bright-side normal n_k then
    passes g + n_k . dv from v). A print's dot gain (ink spread by a tenth of a millimetre)
    moves every edge of a star parallel to itself by g, towards the paper, and a vertex v a
    few tenths of a pixel from the edges' own intersection moves the two edges of a wedge
    opposite ways (their bright sides face apart): neither turns any edge (`turned_sigma`).
    Robust: the fit once more without the edges beyond 5 robust sds of the first.

    >>> from pencilcal.toolkit.detect.segments import Segments
    >>> a = np.radians(np.arange(0, 360, 30.0)); u = np.stack([np.cos(a), np.sin(a)], -1)
    >>> n = np.stack([-u[:, 1], u[:, 0]], -1)
    >>> ideal = np.concatenate([20 * u - 0.5 * n, 100 * u - 0.5 * n], -1)   # every edge 0.5 px off, on one side
    >>> z = np.zeros(12)
    >>> segs = Segments(segments=ideal, ideal=ideal, angle_sigma=z + 1e-4, offset_sigma=z + 0.01, length=z + 80,
    ...                 contrast=z + 50, residual_px=z, stations=z.astype(int) + 40)
    >>> off = np.array([1.0, -0.5])                                           # the vertex off too
    >>> round(common_offset(segs, off), 2), round(common_offset(segs, off, shared=False), 2)
    (0.88, 0.0)
    """
    if len(segs) < 4:
        return 0.0
    p1, p2 = segs.ideal[:, :2], segs.ideal[:, 2:]
    d = p2 - p1
    L = np.hypot(d[:, 0], d[:, 1])
    u = d / np.maximum(L, 1e-12)[:, None]
    c = 0.5 * (p1 + p2)
    dist = u[:, 0] * (v[1] - c[:, 1]) - u[:, 1] * (v[0] - c[:, 0])
    lever = np.sum((v - c) * u, -1)
    var = segs.offset_sigma**2 + (lever * segs.angle_sigma) ** 2
    if not shared:
        A = np.stack([np.ones_like(dist), -u[:, 1], u[:, 0]], -1)  # g, and dv along each edge's bright normal
        w = 1.0 / np.sqrt(var)
        keep = np.ones(dist.size, bool)
        for _ in range(2):
            coef = np.linalg.lstsq(A[keep] * w[keep, None], dist[keep] * w[keep], rcond=None)[0]
            rest = dist - A @ coef
            keep = np.abs(rest) <= 5.0 * 1.4826 * np.median(np.abs(rest)) + 1e-12
        dist = rest
    return float(np.sqrt(max(0.0, np.median(dist**2) / 0.455 - np.median(var))))


def turned_sigma(segs, v, common):
    """(M,) [rad] the angle sds of a star's edges `segs` (`Segments`) with the turn their
    common offset common [px] shows (`common_offset` without what they share: how far the
    edges pass from their vertex v (2,) [working px] beyond their sigmas, less a dot gain
    and the vertex's own offset): `TURN_SHARE` of it taken as each edge's
    miss at the vertex from a turn about its middle, over its lever (the middle's distance
    from the vertex [px]), added in quadrature. An edge turned by d misses the vertex by d
    times its lever; on a small star (under 30 % of the frame's height) the edges miss it
    by 0.1-0.9 px beyond their sigmas, turned by their blurred neighbours alike along
    neighbouring edges, an error their stations' scatter does not show. The labelling and
    the fit keep the stations' sds (seen by the labelling, these wider ones lost frames'
    labels): the orientation's covariance takes these (`orient_segments`'
    ``angle_sigma_error``).

    >>> from pencilcal.toolkit.detect.segments import Segments
    >>> ideal = np.array([[10.0, 0, 30, 0], [0, 100, 0, 300]])                  # levers 20 and 200 px
    >>> z = np.zeros(2)
    >>> segs = Segments(segments=ideal, ideal=ideal, angle_sigma=z + 1e-3, offset_sigma=z + 0.1, length=z + 20,
    ...                 contrast=z + 50, residual_px=z, stations=z.astype(int) + 10)
    >>> (turned_sigma(segs, np.zeros(2), 0.2 * np.sqrt(2)) * 1e3).round(3).tolist()   # hypot(1e-3, 0.2 / lever)
    [10.05, 1.414]
    """
    mid = 0.5 * (segs.ideal[:, :2] + segs.ideal[:, 2:])
    lever = np.maximum(np.hypot(*(mid - v).T), 1.0)
    return np.hypot(segs.angle_sigma, TURN_SHARE * common / lever)
