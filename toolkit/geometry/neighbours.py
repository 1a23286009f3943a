"""Fixed-radius neighbours in numpy: the pairs of points within a distance of each other.

The detectors ask this of a few hundred to a few thousand points per frame (fragments'
sample points, line centres, doubled line angles). `scipy.spatial.cKDTree` answers it, but
importing scipy.spatial (with scipy.sparse and scipy.linalg behind it) costs a command
0.3-0.6 s of start-up before its first frame, more than these queries cost over a whole
video. numpy answers the same question exactly: for one radius a uniform grid of cells one
radius wide (two points within r of each other lie in the same or in adjacent cells of
their first two coordinates), for a radius per point a sweep along x; every candidate is
then tested on the full distance.

- `pairs_within(points, r)`: every unordered pair closer than r (as
  ``cKDTree(points).query_pairs(r, output_type="ndarray")``, rows sorted).
- `neighbours_within(points, radii)`: for each point i, the points j with
  ``|p_j - p_i| <= radii[i]`` (as ``cKDTree(points).query_ball_point(points, radii)``),
  as two flat index arrays.

>>> p = np.array([[0.0, 0.0], [0.5, 0.0], [3.0, 0.0], [3.0, 0.9]])
>>> pairs_within(p, 1.0).tolist()
[[0, 1], [2, 3]]
>>> i, j = neighbours_within(p, np.array([3.0, 0.1, 0.1, 0.1]))
>>> [(int(a), int(b)) for a, b in zip(i, j) if a != b]
[(0, 1), (0, 2)]
"""
from __future__ import annotations

import numpy as np

__all__ = ["pairs_within", "neighbours_within"]


def _adjacent(xy, size):
    """Candidate pairs (i, j) of points xy (N, 2) whose cells on a grid of `size` are the
    same or adjacent (a superset of every pair within `size`): each pair of adjacent cells
    once (the cell itself and the four ahead of it), within one cell i < j only."""
    c = np.floor((xy - xy.min(0)) / size).astype(np.int64) + 1
    W = int(c[:, 0].max()) + 2
    key = c[:, 1] * W + c[:, 0]
    order = np.argsort(key, kind="stable")
    skey = key[order]
    ii, jj = [], []
    for off in (0, 1, W - 1, W, W + 1):
        a = np.searchsorted(skey, key + off, "left")
        cnt = np.searchsorted(skey, key + off, "right") - a
        if not cnt.any():
            continue
        i = np.repeat(np.arange(key.size), cnt)
        start = np.cumsum(cnt) - cnt
        j = order[np.repeat(a - start, cnt) + np.arange(i.size)]
        if off == 0:
            i, j = i[i < j], j[i < j]
        ii.append(i)
        jj.append(j)
    if not ii:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    return np.concatenate(ii), np.concatenate(jj)


def _sq_dist(P, i, j):
    """|P[i] - P[j]|^2 (K,) from the differences (the expanded form loses the last bits)."""
    d = P[i] - P[j]
    return np.einsum("ij,ij->i", d, d)


def pairs_within(points, r):
    """Every unordered pair of points closer than or exactly r.

    points: (N, D) with D >= 2 (the grid is on the first two coordinates, the distance on
    all D); r: the distance (> 0, in the points' unit). Returns (P, 2) int, i < j in each
    row, rows in lexicographic order. Exact (the same set as scipy's ``query_pairs``);
    the work is about N times the number of points within ~2r of one, so it suits points
    spread over a plane, not thousands piled in one cell.

    >>> pairs_within(np.array([[0.0, 0.0], [1.0, 0.0], [2.5, 0.0]]), 1.5).tolist()
    [[0, 1], [1, 2]]
    """
    P = np.asarray(points, float)
    if P.shape[0] < 2 or not r > 0:
        return np.zeros((0, 2), np.int64)
    i, j = _adjacent(P[:, :2], float(r))
    near = _sq_dist(P, i, j) <= r * r
    pp = np.sort(np.stack([i[near], j[near]], -1), axis=1)
    return pp[np.lexsort((pp[:, 1], pp[:, 0]))]


def neighbours_within(points, radii):
    """For each point i, every point j (i itself included) with |p_j - p_i| <= radii[i].

    points: (N, D) (the distance on all D); radii: (N,) or a scalar >= 0 (in the points'
    unit). Returns the index arrays i, j (K,) int, sorted by i and then j. A sweep along the
    first coordinate: each point's candidates are those within its radius in x (two
    searchsorted on the sorted x), so radii that differ by orders of magnitude (each line's
    reach, from its length) cost what they reach.

    >>> i, j = neighbours_within(np.array([[0.0, 0], [1, 0], [5, 0]]), np.array([1.0, 0.5, 4.0]))
    >>> list(zip(i.tolist(), j.tolist()))
    [(0, 0), (0, 1), (1, 1), (2, 1), (2, 2)]
    """
    P = np.asarray(points, float)
    N = P.shape[0]
    R = np.broadcast_to(np.asarray(radii, float), (N,))
    if N == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    order = np.argsort(P[:, 0], kind="stable")
    x = P[order, 0]
    lo = np.searchsorted(x, P[:, 0] - R, "left")
    cnt = np.searchsorted(x, P[:, 0] + R, "right") - lo
    i = np.repeat(np.arange(N), cnt)
    start = np.cumsum(cnt) - cnt
    j = order[np.repeat(lo - start, cnt) + np.arange(i.size)]
    near = _sq_dist(P, i, j) <= R[i] ** 2
    i, j = i[near], j[near]
    o = np.lexsort((j, i))
    return i[o], j[o]
