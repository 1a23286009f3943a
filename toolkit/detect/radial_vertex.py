"""A radial target's vertex as its edge locator (`detect.radial`) finds it: the point crossed by
edge segments of the most directions (`rough_vertex`), the point the refitted edges meet at
(`vertex_of`), which of two such points the edges are located about (`better_vertex`), and
whether jointly located edges meet at another, surer point than the one they were located
about (`walked`). Points and lines in working pixels."""
from __future__ import annotations

import numpy as np

from pencilcal.toolkit.errors import EstimationError
from pencilcal.toolkit.pencil.vertex import intersect_lines, lines_through

__all__ = ["rough_vertex", "vertex_of", "better_vertex", "walked", "floored_sigmas", "VERTEX_FLOOR_DEG",
           "VERTEX_FLOOR_PX"]

VERTEX_FLOOR_DEG, VERTEX_FLOOR_PX = 0.05, 0.5  # the rough vertex: a floor under the segments' noise
_DIRECTION_BIN_DEG = 6.0  # the rough vertex counts the directions crossing it in bins this wide
_ROUGH_LINES = 96  # the longest segments it looks at


def rough_vertex(segs):
    """(vertex (2,) [working px], reach [px], its sd [px]): the point crossed by edge
    segments of the most directions (`_DIRECTION_BIN_DEG` bins; ties: the most length),
    refined as their robust intersection, how far from it they reach (their far ends' 90th
    percentile) and its sd (`vertex_sd`).

    A radial target's vertex is crossed by edges from every direction; a chessboard's
    corner beside it by whole rows of collinear square edges, from two.
    """
    if len(segs) < 3:
        raise EstimationError("fewer than three edge segments")
    L = segs.length
    top = np.argsort(-L, kind="stable")[:_ROUGH_LINES]
    lines = segs.ideal[top]
    p, d = lines[:, :2], lines[:, 2:] - lines[:, :2]
    u = d / np.maximum(np.hypot(d[:, 0], d[:, 1]), 1e-12)[:, None]
    n = np.stack([-u[:, 1], u[:, 0]], -1)
    c = -np.sum(n * p, -1)
    i, j = np.triu_indices(len(lines), 1)
    cross = u[i, 0] * u[j, 1] - u[i, 1] * u[j, 0]
    ok = np.abs(cross) > np.sin(np.radians(_DIRECTION_BIN_DEG))
    i, j, cross = i[ok], j[ok], cross[ok]
    if i.size == 0:
        raise EstimationError("the edge segments are parallel")
    cand = np.stack([(n[i, 1] * c[j] - n[j, 1] * c[i]), (n[j, 0] * c[i] - n[i, 0] * c[j])], -1) / cross[:, None]
    mid = 0.5 * (lines[:, :2] + lines[:, 2:])
    bins = np.floor(np.degrees(np.arctan2(u[:, 1], u[:, 0])) % 180.0 / _DIRECTION_BIN_DEG).astype(int)
    onehot = np.zeros((len(lines), int(180 / _DIRECTION_BIN_DEG) + 1), np.int32)
    onehot[np.arange(len(lines)), bins] = 1
    best, score = None, (-1, -1.0)
    for k in range(0, cand.shape[0], 4096):  # blocks of candidates x lines
        q = cand[k:k + 4096]
        dist = np.abs(q @ n.T + c)
        reach = np.linalg.norm(q[:, None, :] - mid[None], axis=-1)
        through = dist <= 2.0 + 0.005 * reach
        ndir = ((through.astype(np.int32) @ onehot) > 0).sum(-1)
        total = through @ L[top]
        b = int(np.lexsort((total, ndir))[-1])
        if (int(ndir[b]), float(total[b])) > score:
            best, score = q[b], (int(ndir[b]), float(total[b]))
    # the lines through it, intersected with their noise (and floors)
    ang, off = floored_sigmas(segs)
    _, through = lines_through(best, segs.ideal, ang, np.maximum(off, 1.0))
    if through.sum() < 3:
        raise EstimationError("fewer than three edge segments meet")
    vf = intersect_lines(segs.ideal[through], angle_sigma=ang[through], offset_sigma=off[through], robust=True)
    return vf.vertex, reach_of(segs.ideal[through][vf.inliers], vf.vertex), vertex_sd(vf)


def floored_sigmas(segs):
    """(angle sds (M,) [rad], offset sds (M,) [px]) of edge segments (`Segments`) for their
    vertex: their own, floored at `VERTEX_FLOOR_DEG` and `VERTEX_FLOOR_PX`."""
    return (np.maximum(segs.angle_sigma, np.radians(VERTEX_FLOOR_DEG)),
            np.maximum(segs.offset_sigma, VERTEX_FLOOR_PX))


def vertex_sd(vf):
    """A vertex fit's (`intersect_lines`) sd [px]: its covariance's, scaled by the residuals'
    rms where they exceed their sigmas (edges measured where their neighbours pull them)."""
    return float(np.sqrt(np.trace(vf.cov)) * max(1.0, vf.rms))


def reach_of(lines, v):
    """How far from v (2,) the lines (K, 4) reach: their far ends' 90th percentile [px]."""
    far = np.maximum(np.hypot(*(lines[:, :2] - v).T), np.hypot(*(lines[:, 2:] - v).T))
    return float(np.percentile(far, 90))


def vertex_of(fit, reach):
    """The vertex of refitted edges (`EdgeFit`), their reach and the vertex's sd
    (`vertex_sd`), from their own sigmas.

    The reach is that of every refitted edge, not only the intersection's inliers: with a
    dartboard's raised wires the robust intersection keeps a third of the edges or fewer,
    which ones changing with the clearance, and the reach of those few, which places the
    next angular bands, jumped by 15 % (`CLEAR_SIGMAS`)."""
    ok = np.flatnonzero(fit.ok)
    if ok.size < 3:
        raise EstimationError("fewer than three edges were refitted")
    lines = fit.lines()[ok]
    mid = 0.5 * (fit.p1[ok] + fit.p2[ok])
    vf = intersect_lines(lines, angle_sigma=np.maximum(fit.angle_sigma[ok], 1e-6),
                         offset_sigma=np.maximum(fit.take(ok).offset_sigma_at(mid), 0.02), robust=True)
    return vf.vertex, max(reach_of(lines, vf.vertex), 0.5 * reach), vertex_sd(vf)


def better_vertex(fit, v, reach, sd, compare=True):
    """(vertex, reach, sd): the refitted edges' (`vertex_of`) where they lie within 3 sds of
    the vertex v (2,) [px] they were refitted about (sd [px], `vertex_sd`) or fix it at
    least as well, else v with its reach (also where they give none). A small star's edges are clear of their
    neighbours only near its rim, if at all (128 edges 5 px apart there): a few short
    stretches intersected 3-15 px from the vertex the frame's segments had found to 0.02 px,
    and the next round, about that point, found fewer than three edges (photographs of stars
    under 30 % of the frame's height). Without `compare` theirs wherever there is one (a
    dartboard's, whose segments hold its raised wires' sides too: compared, the shared
    photographs' boundaries' planes moved from the rings' by +0.15 and -0.05 deg, which
    nothing here tells right or wrong).
    """
    try:
        v1, reach1, sd1 = vertex_of(fit, reach)
    except EstimationError:
        return v, reach, sd
    # within 3 sds of the last it is the same vertex, measured on the refitted edges
    same = _beyond(v1, sd1, v, sd) <= 0.0
    return (v1, reach1, sd1) if same or sd1 <= sd or not compare else (v, reach, sd)


def walked(v1, sd1, v, sd):
    """Whether the vertex v1 (2,) [px] of sd1 [px] where jointly located edges meet is
    another point than v (2,) of sd [px] they were located about and fixes it better:
    beyond 3 of the two sds added (`better_vertex`'s same vertex) and sd1 < sd."""
    return bool(sd1 < sd and _beyond(v1, sd1, v, sd) > 0.0)


def _beyond(v1, sd1, v, sd):
    """How far [px] two vertices (2,) of sds sd1, sd [px] lie apart beyond 3 of their sds
    added: at most 0 where they are one vertex."""
    return float(np.hypot(*(np.asarray(v1) - v)) - 3.0 * np.hypot(sd, sd1))
