"""A dense regular pencil labelled at once from the phase of all its lines together.

A Siemens star of N wedges has 2N edges: those of one polarity lie every 2 pi / N about
the vertex in the target plane, at one phase c, those of the other at another. Seen in
an image, the plane's angle theta of a line through the vertex and the image angle a of
its image are tied by a 1-D homography, (cos a, sin a) ~ M (cos theta, sin theta), M a 2x2
matrix of positive determinant (the pencil seen from its front keeps its cyclic order),
which up to scale is M = Rot(alpha) diag(1, c) Rot(beta), 0 < c <= 1: three parameters.
For the right alpha and c, every line's plane angle theta = psi(a; alpha, c) - beta,
psi = atan2(sin(a - alpha) / c, cos(a - alpha)), puts N (theta - c_kind) on a multiple of
2 pi, whatever beta: the lines' phases exp(i N (psi - c_kind)) all agree, and their sum's
length |S| is about the number of lines. For a wrong (alpha, c) the phases wrap round
the circle and |S| is that of a random walk, sqrt(M). The angle of S gives beta (up to
a whole wedge: the star's own symmetry) and with it every line's edge at once.

A small dense star's lines scatter 0.17-0.27 deg against edges 1.4 deg apart (128
wedges): three neighbouring lines predict the next ones too loosely to label them
(`assign`'s screen and refinement), but a hundred lines' phases together fix (alpha, c)
to a hundredth of their scatter. `periodic_labels` searches (alpha, log 1/c) on a grid
fine enough for N (coarse, then about the best cells), accepts the best only where
Rayleigh's test puts its |S| beyond chance over all the hypotheses tried
(`DETECTION_LEVEL` shared among them), and labels each line whose phase lies within
`PHASE_WINDOW` of its edge's.

All angles are radians in normalised image coordinates, lines oriented from the vertex.
"""
from __future__ import annotations

import numpy as np

from pencilcal.toolkit.pencil.defaults import DETECTION_LEVEL

__all__ = ["regular_kinds", "periodic_labels", "PERIODIC_LEAST_EDGES", "PERIODIC_MOST_EDGES", "PHASE_WINDOW"]

#: Only pencils with at least this many edges of each kind all round the vertex are labelled
#: by their phase (a Siemens star of 16 wedges or more); fewer are labelled as well by
#: `assign`'s screen.
PERIODIC_LEAST_EDGES = 16
#: nor more than this many: the grid of hypotheses grows as the square of the count (70 000
#: for a star of 128 wedges, a third of a second); a pencil file of more spokes is left to
#: `assign`'s screen, whose work is bounded
PERIODIC_MOST_EDGES = 256
#: A line is given its edge where its phase, N (theta - c_kind), lies within this of a
#: multiple of 2 pi [rad]: a fifth of the period, so a line is never given the edge of the
#: other polarity between (half the period away) nor a neighbour of its own.
PHASE_WINDOW = 0.2 * 2 * np.pi
_LOG_C_MAX = 1.6  # c down to 0.2: a tilt of 78 deg, or less under a strong perspective
_STEP = 1.2  # grid steps: the phase's error at a cell's centre at most about _STEP / 2 rad
_FINE = 4  # the fine grid's steps per coarse step, about the best coarse cells
_KEEP = 12  # coarse cells refined
_BLOCK = 1 << 21  # phases per block of hypotheses


def regular_kinds(spoke_angles, kinds, period=2 * np.pi):
    """(n, offsets) where the spokes of each kind lie every period / n at one offset each
    (`offsets`: {kind: c [rad]}), the same n for every kind; None where they do not.

    >>> th = np.radians(np.r_[np.arange(0, 360, 10.0) - 2.5, np.arange(0, 360, 10.0) + 2.5])
    >>> n, off = regular_kinds(th, np.r_[np.full(36, -1), np.full(36, 1)])
    >>> n, np.degrees([off[-1], off[1]]).round(3).tolist()
    (36, [7.5, 2.5])
    """
    th = np.asarray(spoke_angles, float).reshape(-1)
    kinds = np.zeros(th.size, int) if kinds is None else np.asarray(kinds, int).reshape(-1)
    out, n = {}, None
    for k in np.unique(kinds):
        t = th[kinds == k]
        if n is None:
            n = t.size
        step = period / t.size
        ph = np.remainder(t, step)
        c = float(ph[0])
        d = np.remainder(ph - c + 0.5 * step, step) - 0.5 * step
        if t.size != n or np.max(np.abs(d)) > 1e-6 or np.unique(np.round(np.remainder(t, period) / step)).size != n:
            return None
        out[int(k)] = c
    return (n, out) if n else None


def _psi(a, alpha, q):
    """The plane's angle (before beta) of image angles a (M,) under hypotheses alpha, q (K,)
    (c = exp(-q)): (K, M) [rad]."""
    d = a[None, :] - alpha[:, None]
    return np.arctan2(np.sin(d) * np.exp(q)[:, None], np.cos(d))


def _scores(a, off, n, alpha, q):
    """|S| and S (K,) of hypotheses alpha, q (K,) for lines a (M,) with phase offsets off (M,)."""
    S = np.zeros(alpha.size, complex)
    block = max(1, _BLOCK // max(a.size, 1))
    for s in range(0, alpha.size, block):
        ph = n * (_psi(a, alpha[s:s + block], q[s:s + block]) - off[None, :])
        S[s:s + block] = np.exp(1j * ph).sum(-1)
    return np.abs(S), S


def periodic_labels(line_angles, spoke_angles, line_kind=None, spoke_kind=None, level=DETECTION_LEVEL):
    """Every line labelled with its edge from the phase of all lines together (module
    docstring), or None where the pencil is not dense and regular (`PERIODIC_LEAST_EDGES` to
    `PERIODIC_MOST_EDGES` of each kind) or no hypothesis's phases agree beyond chance.

    line_angles: (M,) [rad] oriented image angles; spoke_angles: (E,) [rad] the edges in the
    target plane; line_kind (M,), spoke_kind (E,): polarities, or None. level: the chance
    that the best of all the hypotheses tried agrees so well among random lines.
    Returns (labels (M,) index into spoke_angles or -1, c, coherence |S| / M) or None.

    >>> from pencilcal.toolkit.geometry.frames import rotation_from_rotvec
    >>> from pencilcal.toolkit.pencil.spec import image_angles
    >>> th = np.radians(np.r_[np.arange(128) * 2.8125 - 0.703125, np.arange(128) * 2.8125 + 0.703125])
    >>> kind = np.r_[np.full(128, -1), np.full(128, 1)]
    >>> R = rotation_from_rotvec([0.7, 0.2, 0.1]); x = np.array([0.05, -0.1])
    >>> rng = np.random.default_rng(0); seen = rng.choice(256, 90, replace=False)
    >>> a = image_angles(R, x, th[seen]) + np.radians(0.2) * rng.standard_normal(90)
    >>> lab, c, coh = periodic_labels(a, th, kind[seen], kind)
    >>> d = np.remainder(lab - seen, 128)        # right up to a whole wedge
    >>> bool(np.all(lab >= 0)), np.unique(d).size
    (True, 1)
    """
    a = np.asarray(line_angles, float).reshape(-1)
    M = a.size
    reg = regular_kinds(spoke_angles, spoke_kind)
    if reg is None or not PERIODIC_LEAST_EDGES <= reg[0] <= PERIODIC_MOST_EDGES or M < 3:
        return None
    n, offsets = reg
    lk = np.zeros(M, int) if line_kind is None or spoke_kind is None else np.asarray(line_kind, int).reshape(-1)
    known = np.isin(lk, list(offsets))
    if known.sum() < 3:
        return None
    a, idx = a[known], np.flatnonzero(known)
    off = np.array([offsets[int(k)] for k in lk[known]])
    # grid: d psi / d q <= 1/2 and d psi / d alpha <= 1/c, so these steps keep the phase's
    # error at a cell's centre about _STEP / 2 rad or less
    dq = 2 * _STEP / n
    qs = np.arange(0.5 * dq, _LOG_C_MAX, dq)
    cells_a, cells_q = [], []
    for q in qs:
        da = _STEP * np.exp(-q) / n
        al = np.arange(0.5 * da, np.pi, da)
        cells_a.append(al), cells_q.append(np.full(al.size, q))
    alpha, q = np.concatenate(cells_a), np.concatenate(cells_q)
    mag, _ = _scores(a, off, n, alpha, q)
    best = np.argsort(mag)[-_KEEP:]
    # about the best cells, a grid _FINE times finer over one coarse step either way
    u = (np.arange(-_FINE, _FINE + 1) / _FINE)
    fa = (alpha[best][:, None, None] + u[None, :, None] * (_STEP * np.exp(-q[best]) / n)[:, None, None]
          + 0 * u[None, None, :]).ravel()
    fq = (q[best][:, None, None] + 0 * u[None, :, None] + u[None, None, :] * dq).ravel()
    fq = np.clip(fq, 0.0, None)
    fmag, fS = _scores(a, off, n, fa, fq)
    b = int(np.argmax(fmag))
    hyps = alpha.size + fa.size
    # Rayleigh: among m random phases P(|S|^2 / m > z) = exp(-z); over all hypotheses tried
    if fmag[b] ** 2 / a.size < np.log(hyps / level):
        return None
    beta = np.angle(fS[b]) / n
    theta = _psi(a, np.array([fa[b]]), np.array([fq[b]]))[0] - beta  # each line's plane angle
    th = np.asarray(spoke_angles, float).reshape(-1)
    sk = np.zeros(th.size, int) if spoke_kind is None or line_kind is None else np.asarray(spoke_kind, int).reshape(-1)
    res = np.remainder(theta[:, None] - th[None, :] + np.pi, 2 * np.pi) - np.pi  # (m, E)
    res = np.where(lk[known][:, None] == sk[None, :], res, np.pi)
    k = np.argmin(np.abs(res), -1)
    r = np.abs(res[np.arange(a.size), k]) * n
    labels = np.full(M, -1)
    labels[idx] = np.where(r < PHASE_WINDOW, k, -1)
    return labels, float(np.exp(-fq[b])), float(fmag[b] / a.size)
