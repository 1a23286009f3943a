"""Geometry of pairs of edges: the bisector, the overlap along it, the width across it.

The two long edges of a printed bar (`bars`) or of an instrument shaft (`shaft.detector`) are two
oriented lines ``[x1, y1, x2, y2]`` [working px] running in opposite directions.
`pair_geometry` describes K such pairs (a, b) at once: the bisector of the two lines
(unit normal N, offset C with N . x + C = 0, direction D along a, foot point O = -C N),
the extents of the two edges projected on it, and the distance between the two lines
across it. Positions along the bisector ("along") are measured from O along D [px].

Example
-------
>>> import numpy as np
>>> pr = pair_geometry(np.array([[0.0, 0.0, 100.0, 0.0], [100.0, 6.0, 0.0, 6.0]]), [0], [1])
>>> float(pr.N[0, 1]), float(pr.C[0]), float(pr.width[0]), (float(pr.lo[0]), float(pr.hi[0]))
(1.0, -3.0, 6.0, (0.0, 100.0))
"""
from __future__ import annotations

from dataclasses import dataclass, fields, replace

import numpy as np

__all__ = ["EdgePairs", "pair_geometry", "antiparallel_pairs"]


@dataclass(frozen=True, eq=False)
class EdgePairs:
    """Geometry of K candidate edge pairs (a, b), working pixels; arrays have leading
    shape (K,).

    b is taken reversed (its direction then runs along a's). Bisector: unit normal `N`
    (K, 2) and offset `C` (K,) with N . x + C = 0, direction `D` along a. `lo`, `hi`: extent of
    the overlap of the two edges along D from the foot point `O` (K, 2); `span_lo`, `span_hi`
    the union; `a_lo`, `a_hi`, `b_lo`, `b_hi` each edge's own. `width` across the bisector
    at the overlap centre; `conv` the angle between the edges [rad]; `side_a`, `side_b` the
    signed distance of the other edge's centre from each edge (negative: on its dark side).
    `n_a`, `c_a`, `n_b`, `c_b`: the two edge lines n . x + c = 0 (n_b for b reversed).
    """

    a: np.ndarray
    b: np.ndarray
    N: np.ndarray
    C: np.ndarray
    D: np.ndarray
    O: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    span_lo: np.ndarray
    span_hi: np.ndarray
    a_lo: np.ndarray
    a_hi: np.ndarray
    b_lo: np.ndarray
    b_hi: np.ndarray
    width: np.ndarray
    conv: np.ndarray
    side_a: np.ndarray
    side_b: np.ndarray
    n_a: np.ndarray
    c_a: np.ndarray
    n_b: np.ndarray
    c_b: np.ndarray

    @property
    def edge_lines(self):
        """(n_a, c_a, n_b, c_b): the two edge lines n . x + c = 0 of every pair."""
        return self.n_a, self.c_a, self.n_b, self.c_b

    def take(self, idx):
        """The pairs `idx` (bool (K,) or indices) selects."""
        return EdgePairs(**{f.name: getattr(self, f.name)[idx] for f in fields(self)})

    def point(self, along):
        """Points on the bisectors at `along` [px]: (K,) -> (K, 2), (K, S) -> (K, S, 2)."""
        return self.O + along[..., None] * self.D if np.ndim(along) == 1 else \
            self.O[:, None, :] + along[..., None] * self.D[:, None, :]

    def width_at(self, along):
        """Distance [px] (K,) between the two edge lines across the bisector at `along` (K,)."""
        lam_a, lam_b = _offsets(self, self.point(along))
        return np.abs(lam_a - lam_b)

    def signed_width_at(self, along):
        """The width at `along` (K,) [px], signed: it changes sign where the edges cross."""
        lam_a, lam_b = _offsets(self, self.point(along))
        return lam_b - lam_a

    def edge_points(self, along):
        """Where the normal to the bisector at `along` (K, S) [px] meets each edge.

        Returns (A, B, w): the points (K, S, 2) on edges a and b [working px] and the signed
        width (K, S) [px] between them."""
        m = self.point(along)
        lam_a, lam_b = _offsets(self, m)
        N = self.N[:, None, :]
        return m + lam_a[..., None] * N, m + lam_b[..., None] * N, lam_b - lam_a


def _offsets(pr, m):
    """Offsets (K,) or (K, S) along N from points m ((K, 2) or (K, S, 2)) to the two edge
    lines: m + lam_a N lies on edge a, m + lam_b N on edge b."""
    ext = (slice(None),) + (None,) * (m.ndim - 2)
    lam_a = -(np.sum(pr.n_a[ext] * m, -1) + pr.c_a[ext]) / np.sum(pr.n_a * pr.N, -1)[ext]
    lam_b = -(np.sum(pr.n_b[ext] * m, -1) + pr.c_b[ext]) / np.sum(pr.n_b * pr.N, -1)[ext]
    return lam_a, lam_b


def pair_geometry(lines, a, b):
    """`EdgePairs` for the oriented lines (M, 4) [working px] and pair indices a, b (K,)
    (the two edges of each pair run in opposite directions)."""
    P = np.asarray(lines, float)
    pa1, pa2 = P[a, :2], P[a, 2:]
    pb1, pb2 = P[b, 2:], P[b, :2]  # b reversed
    ua = pa2 - pa1
    ua /= np.linalg.norm(ua, axis=-1, keepdims=True)
    ub = pb2 - pb1
    ub /= np.linalg.norm(ub, axis=-1, keepdims=True)
    na = np.stack([-ua[:, 1], ua[:, 0]], -1)
    nb = np.stack([-ub[:, 1], ub[:, 0]], -1)  # = -(b's own normal)
    ca = -np.sum(na * pa1, -1)
    cb = -np.sum(nb * pb1, -1)
    Nn = na + nb
    norm = np.linalg.norm(Nn, axis=-1)
    N = Nn / norm[:, None]
    C = (ca + cb) / norm
    D = np.stack([N[:, 1], -N[:, 0]], -1)
    O = -C[:, None] * N
    al = [np.sum((q - O) * D, -1) for q in (pa1, pa2, pb1, pb2)]
    a_lo, a_hi = np.minimum(al[0], al[1]), np.maximum(al[0], al[1])
    b_lo, b_hi = np.minimum(al[2], al[3]), np.maximum(al[2], al[3])
    lo, hi = np.maximum(a_lo, b_lo), np.minimum(a_hi, b_hi)
    conv = np.abs(np.arctan2(ua[:, 0] * ub[:, 1] - ua[:, 1] * ub[:, 0], np.sum(ua * ub, -1)))
    cen_a, cen_b = 0.5 * (pa1 + pa2), 0.5 * (pb1 + pb2)
    # b's own normal is -nb: its dark side is +nb
    side_a = np.sum(na * cen_b, -1) + ca
    side_b = -(np.sum(nb * cen_a, -1) + cb)
    pr = EdgePairs(a=np.asarray(a), b=np.asarray(b), N=N, C=C, D=D, O=O, lo=lo, hi=hi,
                   span_lo=np.minimum(a_lo, b_lo), span_hi=np.maximum(a_hi, b_hi), a_lo=a_lo, a_hi=a_hi,
                   b_lo=b_lo, b_hi=b_hi, width=np.zeros(len(a)), conv=conv, side_a=side_a, side_b=side_b,
                   n_a=na, c_a=ca, n_b=nb, c_b=cb)
    return replace(pr, width=pr.width_at(0.5 * (lo + hi)))


def antiparallel_pairs(E, a, b):
    """(lines, a, b') for `pair_geometry` from pairs (a, b) of unsigned lines E (M, 4): the
    two edges of a pair must run in opposite directions, so b' indexes b reversed (rows
    M.. of the returned lines (2M, 4)) where b runs along a.

    >>> E = np.array([[0.0, 0.0, 10.0, 0.0], [0.0, 4.0, 10.0, 4.0]])
    >>> L, a, b = antiparallel_pairs(E, np.array([0]), np.array([1])); b.tolist(), L[b[0]].tolist()
    ([3], [10.0, 4.0, 0.0, 4.0])
    """
    M = E.shape[0]
    E2 = np.concatenate([E, E[:, [2, 3, 0, 1]]])
    da, db = E[a, 2:] - E[a, :2], E[b, 2:] - E[b, :2]
    same = np.sum(da * db, -1) > 0
    return E2, a, np.where(same, b + M, b)
