"""Plane polygons as (N, 2) vertex arrays: rectangles, orientation, overlap, inside, hulls.

The printed sheet (sheet.py), the rasteriser (raster.py) and the instrument's outline
(objects.py) all describe shapes as closed polygons whose vertices are the rows of an
(N, 2) array, the last vertex joined to the first. Coordinates are whatever the caller
works in (target millimetres, normalised image coordinates, pixels); the signed area is
positive for a counter-clockwise polygon in a frame with x right and y up, i.e. clockwise
on screen when y points down.

Example
-------
>>> sq = rect(0.0, 0.0, 2.0, 1.0)
>>> signed_area(sq), signed_area(oriented(sq, positive=False))
(2.0, -2.0)
>>> point_in_polygon(sq, np.array([[1.0, 0.5], [3.0, 0.5]])).tolist()
[1.0, 0.0]
"""
from __future__ import annotations

import numpy as np

__all__ = ["rect", "signed_area", "oriented", "convex_overlap", "point_in_polygon", "convex_hull", "arc",
           "annular_sector", "ARC_STEP"]

#: Arcs are polylines with vertices at most this far apart [rad]: a chord of 0.5 deg strays
#: from its arc by 1e-5 of the radius (7e-4 mm at 70 mm).
ARC_STEP = np.radians(0.5)


def rect(x0, y0, x1, y1):
    """(4, 2) corners of the axis-aligned rectangle [x0, x1] x [y0, y1], in the order
    (x0, y0), (x1, y0), (x1, y1), (x0, y1) (positive signed area when x0 < x1, y0 < y1)."""
    return np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], float)


def signed_area(p):
    """Signed area (float) of the polygon p (N, 2), by the shoelace formula; in the square of
    p's unit, positive when the vertices turn from +x towards +y."""
    q = np.roll(p, -1, axis=0)
    return 0.5 * float(np.sum(p[:, 0] * q[:, 1] - q[:, 0] * p[:, 1]))


def oriented(p, positive=True):
    """The polygon p (N, 2) with positive (or negative) signed area in its own coordinates
    (p itself, or a reversed copy)."""
    return p if (signed_area(p) > 0) == positive else p[::-1].copy()


def convex_overlap(a, b, tol=1e-9):
    """True if two convex polygons a (N, 2), b (M, 2) overlap with positive area (separating
    axes); touching within `tol` (in the polygons' unit, times an edge's length) is no overlap."""
    for poly in (a, b):
        e = np.roll(poly, -1, axis=0) - poly
        for nx, ny in np.stack([-e[:, 1], e[:, 0]], -1):
            pa = a @ [nx, ny]
            pb = b @ [nx, ny]
            if pa.max() <= pb.min() + tol or pb.max() <= pa.min() + tol:
                return False
    return True


def point_in_polygon(poly, pts):
    """Point in a (convex or not) polygon by crossing number.

    poly: (N, 2); pts: (M, 2) in the same unit. Returns (M,) float, 1.0 inside, 0.0 outside
    (a float so that signed polygons can be summed into a winding count).
    """
    x, y = pts[:, 0], pts[:, 1]
    inside = np.zeros(len(pts), bool)
    q = np.roll(poly, -1, axis=0)
    for (xa, ya), (xb, yb) in zip(poly, q):
        cond = (ya > y) != (yb > y)
        with np.errstate(divide="ignore", invalid="ignore"):
            xc = xa + (y - ya) * (xb - xa) / (yb - ya)
        inside ^= cond & (x < xc)
    return inside.astype(float)


def convex_hull(pts):
    """Convex hull (monotone chain) of points (N, 2): (M, 2) vertices, positive signed area.

    Fewer than three distinct points are returned as they are (sorted, duplicates removed).

    Example
    -------
    >>> convex_hull([[0, 0], [1, 0], [0.5, 0.2], [1, 1], [0, 1]]).tolist()
    [[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]]
    """
    p = np.unique(np.asarray(pts, float), axis=0)
    if len(p) < 3:
        return p

    def cross(o, a, b):
        return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])

    lower, upper = [], []
    for q in p:
        while len(lower) >= 2 and cross(lower[-2], lower[-1], q) <= 0:
            lower.pop()
        lower.append(q)
    for q in p[::-1]:
        while len(upper) >= 2 and cross(upper[-2], upper[-1], q) <= 0:
            upper.pop()
        upper.append(q)
    return np.array(lower[:-1] + upper[:-1])


def arc(r, a0, a1, centre=(0.0, 0.0)):
    """(K, 2) points on the circle of radius r about `centre` from angle a0 to a1 [rad], at
    most `ARC_STEP` apart (both ends included)."""
    n = max(2, int(np.ceil(abs(a1 - a0) / ARC_STEP)) + 1)
    a = np.linspace(a0, a1, n)
    return np.asarray(centre, float) + r * np.stack([np.cos(a), np.sin(a)], -1)


def annular_sector(r0, r1, a0, a1, centre=(0.0, 0.0)):
    """The polygon (K, 2) between radii r0 < r1 about `centre` and angles a0 < a1 [rad]: a
    wedge (its tip at the centre) when r0 is 0.

    >>> np.round(annular_sector(0.0, 1.0, 0.0, np.pi / 2)[[0, 1, -1]], 9).tolist()
    [[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]]
    """
    outer = arc(r1, a0, a1, centre)
    if r0 <= 0:
        return np.concatenate([np.asarray(centre, float)[None], outer])
    return np.concatenate([outer, arc(r0, a1, a0, centre)])
