"""The plane from the images of circles centred on a pencil's vertex: a second orientation,
and the twin.

A circle in the plane images as a conic C; the image of its centre and the image of the
plane's line at infinity (the horizon) are pole and polar with respect to it, as they are
for the circle itself (a projective map keeps poles and polars). In normalised camera
coordinates the horizon of a plane with unit normal n is the line n, so

    n ~ C x_v,      x_v = (x, y, 1) the image of the centre (the pencil's vertex),

with n . x_v > 0 (the plane in front of the camera). Every circle about the vertex gives
the same n, whatever its radius, and there is no twin: the lines of the pencil fit two
normals equally (Rot(ray, 180 deg) turns one into the other), a circle about the vertex
only one of them. The circle's normal shares only the vertex with the lines' orientation:
a second, nearly independent measurement of the plane.

Which edge points are the circle's is told with the lines' orientation (`circle_estimate`):
under the right rotation, the points of one circle all lie at one radius on the plane (in
units of the vertex depth), nested rings a few pixels apart at different radii. The points
are grouped by that radius under each twin, an ellipse fitted to each group (points beyond
3 sd of it left out), its normal taken from the vertex's polar, and the normals of all the
circles combined by their covariances (their consistency a chi2). With the circles' radii
given (the pencil file's ``circles``), only groups whose radii stand in the ratios of the
listed ones are used, and the vertex's depth follows. The twin whose circles fix the normal
better (the smaller trace of its covariance from the conics) is the one grouped by: the
other smears every circle over a range of radii, while points on no circle (lines of print,
a sheet's edge) still fill loose groups about it, at times more points than the one tight
ring about the right plane. That grouping is free to pick, from rings smeared over a range of
radii (by the wrong twin's plane, or by the vertex's error), the points that make circles about
the twin it groups by; so the points are also chained on the image alone (`_chains`): a group's
circle counts only where it lies along the chains it takes points from, not across them
(`_takes_chains_whole`), and where the chains that go all round (whole rings) lie nearer the
other twin, their estimate is taken (`circle_estimate`). Points that fill rings about any plane
(edge points on the spokes, one per edge at every radius) make circles about either twin, each
grouped by its own: where the twin grouped by fixes its plane hardly better than the other fixes
its own, the groups choose no twin (`_about_any_plane`, `circle_choice`).

Example
-------
>>> from pencilcal.toolkit.geometry.frames import rotation_from_rotvec
>>> R = rotation_from_rotvec([0.5, 0.2, 0.1]); x = np.array([0.05, -0.02])
>>> a = np.linspace(0, 2 * np.pi, 90, endpoint=False)
>>> pts = []
>>> for rho in (0.2, 0.3):                       # two circles about the vertex, depth 1
...     X = R @ np.stack([rho * np.cos(a), rho * np.sin(a), 0 * a]) + np.r_[x, 1.0][:, None]
...     pts.append((X[:2] / X[2]).T)
>>> est = circle_estimate(np.concatenate(pts), x, np.zeros((2, 2)), R, R, scale=1000.0)
>>> est.circles, round(float(np.degrees(np.arccos(est.normal @ R[:, 2]))), 9)
(2, 0.0)
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from pencilcal.toolkit.errors import EstimationError
from pencilcal.toolkit.geometry.conic import conic_matrix, fit_ellipse, sampson_distances

__all__ = ["CircleEstimate", "circle_estimate", "conic_normal", "plane_radii", "normal_agreement", "circle_choice",
           "circle_record", "line_normal_cov", "circular_points", "DECISIVE_CHI2", "spokes_end"]

#: Points of one circle's image follow one another round the vertex (`_chains`): the next one
#: within LINK_DEG of direction (a 64-wedge star's outline shows on every other ray, a
#: dartboard's rings across its wires) and LINK_PX plus LINK_REL of the radius per degree of
#: it (an ellipse of axes 2:1 about its centre changes its radius by at most 0.6 % per degree);
#: a dartboard's nested rings lie 5 % apart.
LINK_DEG, LINK_PX, LINK_REL = 12.0, 1.5, 0.01
#: Points of one circle lie within this of each other in log radius on the plane (under the
#: right rotation): 1 px of scatter at 100 px is 1 %; rings of a dartboard differ by 5 %.
GROUP_LOG_RADIUS = 0.01
MIN_POINTS = 12  # a circle needs at least this many points
DECISIVE_POINTS = 2 * MIN_POINTS  # the circles choose a twin only with one circle this well sampled
MAX_RMS_PX = 1.5  # and its ellipse must fit them this well [px]
#: And they lie round the vertex: no gap between their directions wider [deg] (an arc of 240 deg
#: fixes an ellipse; a circle near the image's border is cut by it).
MAX_GAP_DEG = 120.0
_RADIUS_MATCH = 0.01  # a group matches a listed radius within 1 %


@dataclass(frozen=True, eq=False)
class CircleEstimate:
    """The plane's normal from circles about the vertex.

    normal: (3,) unit, camera frame, away from the camera; cov: (3, 3) its covariance
    (the conics' and the vertex's); sigma_deg: RMS angle of its error [deg]; circles: how
    many circles; chi2, dof: their normals' consistency with one another; grouped_by: 0 or
    1, the twin whose radii grouped the points; radii: (C,) each circle's radius on the
    plane in units of the vertex depth; points: (C,) points each ellipse used; rms_px: (C,)
    their scatter about it [px]; depth: the vertex depth from the listed radii, or None;
    conics: (C, 3, 3) the circles' images (normalised coordinates, unit norm);
    cov_conics: (3, 3) the normal's covariance from the conics alone (the vertex held);
    jac_vertex: (3, 2) how the normal moves with the vertex's image (normalised);
    rings: (3,) the normal of the whole rings alone (`circle_estimate`), or None;
    any_plane: whether the points made circles as tight about the other twin's plane, grouped
    by its radii (`_about_any_plane`): then they choose no twin (`circle_choice`).
    """

    normal: np.ndarray
    cov: np.ndarray
    sigma_deg: float
    circles: int
    chi2: float
    dof: int
    grouped_by: int
    radii: np.ndarray
    points: np.ndarray
    rms_px: np.ndarray
    depth: float | None = None
    conics: np.ndarray | None = None
    cov_conics: np.ndarray | None = None
    jac_vertex: np.ndarray | None = None
    rings: np.ndarray | None = None
    any_plane: bool = False


def conic_normal(C, x):
    """The plane normal (3,) from the image conic C (3, 3) of a circle about the point whose
    image is x (2,) (normalised coordinates): the polar of x, pointing away from the camera;
    and its Jacobians (3, 6) by the conic's vector (`geometry.conic.conic_vector`) and (3, 2)
    by x."""
    xh = np.r_[np.asarray(x, float), 1.0]
    ell = np.asarray(C, float) @ xh
    norm = np.linalg.norm(ell)
    s = 1.0 if ell @ xh > 0 else -1.0
    n = s * ell / norm
    P = s * (np.eye(3) - np.outer(n, n)) / norm
    Jq = np.stack([P @ (conic_matrix(e) @ xh) for e in np.eye(6)], -1)
    Jx = P @ np.asarray(C, float)[:, :2]
    return n, Jq, Jx


def plane_radii(points, x, R):
    """Radius (K,) and direction (K,) [rad] on the plane of image points (K, 2) (normalised)
    about the vertex imaged at x (2,), for the rotation R (3, 3), in units of the vertex's
    depth; NaN for points beyond the plane's horizon."""
    n = R[:, 2]
    P0 = np.r_[x, 1.0]
    d = np.concatenate([points, np.ones((points.shape[0], 1))], -1)
    with np.errstate(all="ignore"):
        t = (n @ P0) / (d @ n)
        u = (d * t[:, None] - P0) @ R
        rho = np.where(t > 0, np.hypot(u[:, 0], u[:, 1]), np.nan)
    return rho, np.arctan2(u[:, 1], u[:, 0])


def _chains(points, x, scale):
    """Index arrays of the points (K, 2) (normalised) that follow one another round the
    vertex's image x (2,) as one curve, whatever the plane: each point is linked to the point
    after it in direction about x (within `LINK_DEG`) whose distance from x is nearest its
    own (within `LINK_PX` plus `LINK_REL` of it per degree, scale: pixels per normalised
    unit), where that point's nearest before it is this one; the linked points are one chain.
    Nested rings a few pixels apart are separate chains; a line of print is a chain that does
    not go round."""
    d = np.asarray(points, float) - np.asarray(x, float)
    r = np.hypot(d[:, 0], d[:, 1]) * scale
    phi = np.arctan2(d[:, 1], d[:, 0])
    K = r.size
    order = np.argsort(phi, kind="stable")
    ph, rr = phi[order], r[order]
    ph2 = np.r_[ph, ph + 2 * np.pi]  # once more round: the last links to the first
    rr2 = np.r_[rr, rr]
    after = np.full(K, -1)
    cost = np.full(K, np.inf)
    for i in range(K):
        hi = min(int(np.searchsorted(ph2, ph[i] + np.radians(LINK_DEG), side="right")), i + K)
        if hi <= i + 1:
            continue
        step = np.degrees(ph2[i + 1:hi] - ph[i])
        tol = LINK_PX + LINK_REL * rr[i] * step
        dr = np.abs(rr2[i + 1:hi] - rr[i])
        # the nearest in radius for its step, the next direction preferred among equals
        c = np.where((step > 0) & (dr <= tol), dr / tol + step / LINK_DEG, np.inf)
        j = int(np.argmin(c))
        if np.isfinite(c[j]):
            after[i], cost[i] = (i + 1 + j) % K, c[j]
    before = np.full(K, -1)
    best = np.full(K, np.inf)
    for i in np.argsort(cost, kind="stable"):
        j = after[i]
        if j >= 0 and cost[i] < best[j]:
            before[j], best[j] = i, cost[i]
    nxt = np.where((after >= 0) & (before[np.maximum(after, 0)] == np.arange(K)), after, -1)
    # every point has one link out at most and one in: the chains are paths, or rings closed
    # on themselves, each walked from its first point (any of a ring's)
    has_in = np.zeros(K, bool)
    has_in[nxt[nxt >= 0]] = True
    roots = np.full(K, -1)
    for start in np.r_[np.flatnonzero(~has_in), np.arange(K)]:
        i = start
        while i >= 0 and roots[i] < 0:
            roots[i] = start
            i = nxt[i]
    roots = roots[np.argsort(order)]  # back to the points' order
    return [np.flatnonzero(roots == k) for k in np.unique(roots)]


def _groups(rho, ang):
    """Index arrays of the points whose radii (K,) gather at one radius: the peaks of their
    density in log radius (a kernel of `GROUP_LOG_RADIUS` / 4), each with the points within
    `GROUP_LOG_RADIUS` of it not taken by a denser one, where they number `MIN_POINTS` or
    more and lie all round (directions ang (K,) [rad] with no gap over `MAX_GAP_DEG`)."""
    ok = np.flatnonzero(np.isfinite(rho) & (rho > 0))
    if ok.size < MIN_POINTS:
        return []
    lr = np.log(rho[ok])
    h = GROUP_LOG_RADIUS / 4.0
    grid = np.arange(lr.min() - 3 * h, lr.max() + 3 * h, h / 2)
    dens = np.histogram(lr, np.r_[grid, grid[-1] + h / 2])[0].astype(float)
    taps = np.exp(-0.5 * (np.arange(-6, 7) / 2.0) ** 2)
    dens = np.convolve(dens, taps, "same")
    peaks = np.flatnonzero((dens >= np.roll(dens, 1)) & (dens > np.roll(dens, -1)) & (dens >= 0.5 * MIN_POINTS))
    taken = np.zeros(ok.size, bool)
    out = []
    for pk in peaks[np.argsort(-dens[peaks], kind="stable")]:
        g = ~taken & (np.abs(lr - grid[pk]) <= GROUP_LOG_RADIUS)
        if g.sum() >= MIN_POINTS and _around(ang[ok[g]]):
            out.append(ok[g])
            taken |= g
    return out


def _around(ang):
    """No gap between the directions ang (K,) [rad] wider than `MAX_GAP_DEG`."""
    a = np.sort(np.remainder(ang, 2 * np.pi))
    return bool(np.degrees(np.max(np.diff(np.r_[a, a[0] + 2 * np.pi]))) <= MAX_GAP_DEG)


def _circle(points, idx, scale):
    """The ellipse through points[idx] (normalised), points beyond 3 sd of it (at least
    0.3 px) left out (three rounds): (fit, the indices kept) or None where it fits worse than
    `MAX_RMS_PX` or keeps too few."""
    keep = idx
    fit = None
    for _ in range(3):
        if keep.size < MIN_POINTS:
            return None
        try:
            fit = fit_ellipse(points[keep])
        except EstimationError:
            return None
        d = np.abs(sampson_distances(fit.conic, points[idx])) * scale
        new = idx[d <= max(3.0 * fit.rms * scale, 0.3)]
        if np.array_equal(new, keep):
            break
        keep = new
    if fit is None or keep.size < MIN_POINTS or fit.rms * scale > MAX_RMS_PX:
        return None
    return fit, keep


def _combine(normals, covs):
    """Information-weighted mean of unit normals (C, 3) with covariances (C, 3, 3) on the
    tangent plane at their first: (normal (3,), cov (3, 3), chi2 of their scatter, dof)."""
    n0 = normals[0]
    B = np.linalg.svd(np.eye(3) - np.outer(n0, n0))[0][:, :2]  # (3, 2) basis across n0
    e = normals @ B
    W = [np.linalg.pinv(B.T @ c @ B) for c in covs]
    info = np.sum(W, 0)
    cov2 = np.linalg.inv(info)
    mean = cov2 @ np.sum([w @ ei for w, ei in zip(W, e)], 0)
    chi2 = float(sum((ei - mean) @ w @ (ei - mean) for w, ei in zip(W, e)))
    n = n0 + B @ mean
    n /= np.linalg.norm(n)
    return n, B @ cov2 @ B.T, chi2, 2 * (len(normals) - 1)


def _matched_radii(radii, listed):
    """Which of the groups' radii (C,) (in units of the vertex depth) are listed radii
    (L,) seen from one depth: (mask (C,), depth or None). The depth is the one that puts
    the most groups within `_RADIUS_MATCH` of a listed radius (ties: the smaller spread);
    it is given only where it is unique: two groups or more in the listed ratios, or one
    group found (one listed radius fits any single group, and with two groups either)."""
    if listed is None or radii.size == 0:
        return np.ones(radii.size, bool), None
    best = (0, np.inf, None, None)
    for z in (np.asarray(listed, float)[None, :] / radii[:, None]).ravel():
        rel = np.abs(np.asarray(listed, float)[None, :] / z / radii[:, None] - 1.0)
        match = np.min(rel, 1) <= _RADIUS_MATCH
        spread = float(np.sum(np.min(rel, 1)[match]))
        if (match.sum(), -spread) > (best[0], -best[1]):
            best = (int(match.sum()), spread, match, z)
    if best[2] is None:
        return np.zeros(radii.size, bool), None
    mask, z = best[2], best[3]
    if best[0] < 2 and radii.size > 1:
        return np.ones(radii.size, bool), None  # no ratio to go by: every group, no depth
    # the depth from every matched group, not just the one that proposed it
    ratio = np.array([np.asarray(listed, float)[np.argmin(np.abs(np.asarray(listed) / z / r - 1))] / r
                      for r in radii[mask]])
    return mask, float(np.median(ratio))


def circle_estimate(points, x, x_cov, R, R_twin, *, scale, radii=None):
    """The plane's normal from the images of circles about the vertex, or None.

    points: (K, 2) edge points (normalised coordinates, undistorted), some of them on the
        images of circles centred on the vertex; x: (2,) the vertex's image, x_cov (2, 2) its
        covariance (normalised); R, R_twin: (3, 3) the lines' two rotations (the points are
        grouped by their radius on the plane under each); scale: pixels per normalised unit
        (the camera's focal length), for the thresholds in pixels; radii: (L,) the circles'
        radii when known (the pencil file's ``circles``): only groups in their ratios count.

    The points are grouped by their radius on each twin's plane, and the twin whose circles
    fix the plane better kept (module docstring); the points are also grouped on the image
    alone (`_chains`), and the chains that go round the vertex and fit an ellipse (whole
    rings) give the circles' normal without reference to either twin. Where that normal lies
    nearer the other twin than the grouped one does, the rings' estimate is returned: grouped
    by a twin's radii, points of two nested rings that the twin's plane and the vertex's
    error smear over one radius make loose circles about that twin's plane, which then chose
    it (a small star tilted 17 deg, the vertex 2 px off: 7 such circles of 15-42 points, 34
    deg from the truth, where its two rings are chains of 148 and 102 points 0.1 px about
    their ellipses, 7 deg from it). Elsewhere the grouped estimate: a dartboard's rings,
    broken at every sector boundary where their edges change sign, are arcs on the image
    that only their radii group.

    Returns a `CircleEstimate` (``rings`` the whole rings' normal (3,) or None), None when no
    group of points makes a circle.
    """
    points = np.asarray(points, float).reshape(-1, 2)
    x = np.asarray(x, float)
    grouped = _grouped(points, x, x_cov, R, R_twin, scale, radii)
    rings = _rings(points, x, x_cov, R, R_twin, scale, radii)
    if rings is None:
        return grouped
    if grouped is None or _nearer_twin(grouped.normal, R, R_twin) != _nearer_twin(rings.normal, R, R_twin):
        return replace(rings, rings=rings.normal)
    # whole rings chained on the image alone lie nearer the twin grouped by: they choose it
    return replace(grouped, rings=rings.normal, any_plane=False)


def _nearer_twin(n, R, R_twin):
    """0 or 1: the rotation of R, R_twin (3, 3) whose normal lies nearer the unit normal n (3,)."""
    return int(abs(n @ np.asarray(R_twin, float)[:, 2]) > abs(n @ np.asarray(R, float)[:, 2]))


def _grouped(points, x, x_cov, R, R_twin, scale, radii):
    """`circle_estimate` of the points grouped by their radius on each twin's plane, each
    group's circle kept where it lies along the chains it takes points from
    (`_takes_chains_whole`), the twin whose circles fix the plane better kept; or None."""
    per_twin = []
    chain = np.empty(points.shape[0], int)
    for k, g in enumerate(_chains(points, x, scale)):
        chain[g] = k
    for which, Rk in enumerate((R, R_twin)):
        rho, ang = plane_radii(points, x, Rk)
        fits = []
        for g in _groups(rho, ang):
            got = _circle(points, g, scale)
            if got is not None and _takes_chains_whole(points, got, chain, scale):
                fits.append((got[0], got[1], float(np.median(rho[got[1]]))))
        mask, depth = _matched_radii(np.array([f[2] for f in fits]), radii)
        fits = [f for f, m in zip(fits, mask) if m]
        if not fits:
            continue
        normals, covs = _normals(fits, x)
        n, cov_c, chi2, dof = _combine(normals, covs)
        # the twin whose circles fix the plane better: under the wrong one, points off any
        # circle (a printed line of text, the sheet's edge, a star's outline smeared over a
        # range of radii) still fill loose groups, more points in all than the one tight
        # ring
        info = 1.0 / max(float(np.trace(cov_c)), 1e-300)
        own = _nearer_twin(n, R, R_twin) == which
        per_twin.append((info, which, fits, depth, covs, n, cov_c, chi2, dof, own))
    if not per_twin:
        return None
    per_twin.sort(key=lambda b: -b[0])
    best = per_twin[0]
    return replace(_estimate(x, x_cov, scale, *best[1:-1]), any_plane=_about_any_plane(per_twin))


#: The circles grouped by one twin's radii choose it only where they fix the plane at least
#: this many times better (information: 1 / trace of the normal's covariance) than the
#: circles grouped by the other twin's radii fix that other twin's plane.
GROUPING_INFO_RATIO = 4.0


def _about_any_plane(per_twin):
    """Whether the points make circles about whichever plane groups them: each twin's groups
    (per_twin: [(information, twin, ..., their normal nearer that twin)], most informative
    first) give circles about that twin's own plane, about as tightly (within
    `GROUPING_INFO_RATIO`). Points that lie on the spokes' edges (rays from a misplaced
    vertex cross a star's wedges at every radius) fill a ring at any radius on any plane,
    one point per edge: grouped by a plane they confirm it, and so choose no twin."""
    if len(per_twin) < 2 or not (per_twin[0][-1] and per_twin[1][-1]):
        return False
    return per_twin[0][0] < GROUPING_INFO_RATIO * per_twin[1][0]


#: A circle grouped by a twin's radii has at least this share of the points of the chains it
#: takes points from on its ellipse (`_takes_chains_whole`): a fifth, the least that left every
#: circle of the shared dartboard photos as it was (a half dropped some of their rings).
WHOLE_CHAINS = 0.2


def _takes_chains_whole(points, got, chain, scale):
    """Whether the circle got = (ellipse fit, indices kept) of points grouped by a twin's
    radii lies along the chains (`_chains`; chain (K,) each point's) it takes three points or
    more from: `WHOLE_CHAINS` of their points or more within max(3 sd, 0.3 px) of its
    ellipse. A group cut out of rings that the twin's plane smears over its radius crosses
    them, and most of their points lie off it."""
    fit, keep = got
    ids, n = np.unique(chain[keep], return_counts=True)
    touched = np.isin(chain, ids[n >= 3])
    if not touched.any():
        return True
    d = np.abs(sampson_distances(fit.conic, points[touched])) * scale
    return bool(np.count_nonzero(d <= max(3.0 * fit.rms * scale, 0.3)) >= WHOLE_CHAINS * touched.sum())


def _rings(points, x, x_cov, R, R_twin, scale, radii):
    """`circle_estimate` of the chains of points that go round the vertex and fit an
    ellipse (`_chains`: grouped on the image alone), their radii and the vertex's depth
    given on the plane of the twin their normal lies nearer; or None."""
    fits = []
    for g in _chains(points, x, scale):
        d = points[g] - x
        if g.size >= MIN_POINTS and _around(np.arctan2(d[:, 1], d[:, 0])):
            got = _circle(points, g, scale)
            if got is not None:
                fits.append(got)
    if not fits:
        return None
    # listed radii's ratios hold on either twin's plane alike (in each direction the twins'
    # radii differ by one factor for every circle about the vertex): the twin that matches
    # more of them says which count
    rho = [np.array([np.median(plane_radii(points[keep], x, Rk)[0]) for _, keep in fits]) for Rk in (R, R_twin)]
    matched = [_matched_radii(r, radii)[0] for r in rho]
    mask = matched[0] if matched[0].sum() >= matched[1].sum() else matched[1]
    if not mask.any():
        return None
    normals, covs = _normals([f for f, m in zip(fits, mask) if m], x)
    n, cov_c, chi2, dof = _combine(normals, covs)
    which = _nearer_twin(n, R, R_twin)
    fits = [(f, keep, r) for (f, keep), r, m in zip(fits, rho[which], mask) if m]
    depth = _matched_radii(np.array([f[2] for f in fits]), radii)[1]
    return _estimate(x, x_cov, scale, which, fits, depth, covs, n, cov_c, chi2, dof)


def _estimate(x, x_cov, scale, which, fits, depth, covs, n, cov_c, chi2, dof):
    """The `CircleEstimate` of circles fits [(ellipse fit, indices kept, radius on the plane)]
    grouped by (or lying about) the twin `which`, their combined normal n (3,) and its
    covariance from the conics cov_c (3, 3)."""
    # the vertex moves every circle's normal together: its term on the combination
    Jx = _combined_jacobian(fits, x, covs)
    cov = cov_c + Jx @ np.asarray(x_cov, float) @ Jx.T
    sigma = float(np.degrees(np.sqrt(max(np.trace(cov), 0.0))))
    return CircleEstimate(n, 0.5 * (cov + cov.T), sigma, len(fits), chi2, dof, which,
                          np.array([f[2] for f in fits]), np.array([f[1].size for f in fits]),
                          np.array([f[0].rms * scale for f in fits]), depth, np.array([f[0].conic for f in fits]),
                          0.5 * (cov_c + cov_c.T), Jx)


def _normals(fits, x):
    """The circles' normals (C, 3) and their covariances (C, 3, 3) from their conics' fits."""
    normals, covs = [], []
    for fit, *_ in fits:
        n, Jq, _ = conic_normal(fit.conic, x)
        normals.append(n), covs.append(Jq @ fit.cov @ Jq.T)
    return np.array(normals), np.array(covs)


def _combined_jacobian(fits, x, covs, h=1e-7):
    """d (combined normal) / d x (3, 2) by central differences, the conics fixed."""
    cols = []
    for e in np.eye(2):
        ns = []
        for sgn in (1.0, -1.0):
            nn = np.array([conic_normal(f[0].conic, x + sgn * h * e)[0] for f in fits])
            ns.append(_combine(nn, covs)[0])
        cols.append((ns[0] - ns[1]) / (2 * h))
    return np.stack(cols, -1)


def normal_agreement(n_a, cov_a, n_b, cov_b):
    """How two estimates of one unit normal agree: (angle between them [deg], chi2 of their
    difference with the sum of their covariances, 2 dof)."""
    n_a, n_b = np.asarray(n_a, float), np.asarray(n_b, float)
    B = np.linalg.svd(np.eye(3) - np.outer(n_a, n_a))[0][:, :2]
    d = B.T @ (n_b - n_a)
    C = B.T @ (np.asarray(cov_a, float) + np.asarray(cov_b, float)) @ B
    ang = float(np.degrees(np.arccos(np.clip(n_a @ n_b, -1.0, 1.0))))
    return ang, float(d @ np.linalg.solve(C, d))


#: The circles choose a twin when the other's chi2 against them exceeds the chosen one's by
#: this much (as the spoke radii do, `orient._metric_choice`).
DECISIVE_CHI2 = 25.0


def line_normal_cov(fit):
    """(3, 3) covariances of a PencilFit's normal and of its twin's: the rotation's left
    perturbation (cov, camera frame) moves the normal by delta x n; the twin is that turned
    by 180 deg about the vertex ray."""
    n = np.asarray(fit.normal, float)
    K = np.array([[0, -n[2], n[1]], [n[2], 0, -n[0]], [-n[1], n[0], 0]])
    c = K @ np.asarray(fit.cov, float) @ K.T
    v = np.asarray(fit.ray, float)
    Q = 2 * np.outer(v, v) - np.eye(3)
    return c, Q @ c @ Q.T


def circle_choice(fit, est):
    """How the circles' normal `est` (a `CircleEstimate`) judges the lines' twins: (which,
    decisive, chi2 of the normal, chi2 of the twin); which is True when the twin agrees
    better. Decisive when the other's chi2 exceeds it by `DECISIVE_CHI2` and the chosen one
    lies nearer the circles' normal than half the twins' separation, and one of the circles
    holds `DECISIVE_POINTS` points or more: a small star's few short noisy arcs (4-5 groups of
    14-21 points, 0.5-0.9 px rms) made circles about the wrong twin's plane, consistent among
    themselves, where every right choice had a circle of 40 points or more. Never decisive
    where the points make circles about either twin's plane alike (``est.any_plane``)."""
    c, ct = line_normal_cov(fit)
    a, chi = normal_agreement(fit.normal, c, est.normal, est.cov)
    at, chit = normal_agreement(fit.normal_twin, ct, est.normal, est.cov)
    which = chit < chi
    sep = float(np.degrees(np.arccos(np.clip(np.asarray(fit.normal) @ np.asarray(fit.normal_twin), -1, 1))))
    decisive = abs(chit - chi) > DECISIVE_CHI2 and min(a, at) < 0.5 * sep and \
        int(np.max(est.points)) >= DECISIVE_POINTS and not est.any_plane
    return bool(which), bool(decisive), chi, chit


def circle_record(fit, est, lines_own=None, vertex_cov=None, shared=None):
    """The orientation record's circle keys for the chosen rotation of `fit` (a PencilFit)
    and the circles' estimate `est`: circle_normal, circle_normal_sigma_deg, circle_tilt_deg,
    circles_used, circle_angle_deg, circle_chi2 and circle_consistent (the chi2 of the two
    normals' difference, 2 dof, within its 99 % quantile).

    The two normals share the vertex, which moves both: with lines_own = (the lines'
    normal's covariance with the vertex held (3, 3), how their normal moves with the vertex
    (3, 2)) and the vertex's covariance vertex_cov (2, 2) (normalised), the difference's
    covariance is their own parts plus the vertex's term on the difference; without, the
    two covariances are added as if independent. shared: None or (the difference's
    covariance (3, 3), the circles' normal's share (3, 3)) [rad^2] from an error both see
    (a printed sheet's bend: `orient._bend_on_circles`), added to the difference's and to the
    circles' sigma."""
    from pencilcal.toolkit.pencil.defaults import CHI2_2_DETECTION

    if lines_own is None or vertex_cov is None:
        c, _ = line_normal_cov(fit)
        ang, chi2 = normal_agreement(fit.normal, c, est.normal, est.cov)
    else:
        dJ = est.jac_vertex - lines_own[1]
        ang, chi2 = normal_agreement(fit.normal, lines_own[0], est.normal,
                                     est.cov_conics + dJ @ np.asarray(vertex_cov, float) @ dJ.T
                                     + (0.0 if shared is None else np.asarray(shared[0], float)))
    tilt = float(np.degrees(np.arccos(np.clip(est.normal @ np.asarray(fit.ray, float), -1.0, 1.0))))
    sigma = est.sigma_deg if shared is None else \
        float(np.sqrt(est.sigma_deg**2 + np.degrees(np.sqrt(max(np.trace(shared[1]), 0.0))) ** 2))
    return dict(circle_normal=est.normal, circle_normal_sigma_deg=sigma, circle_tilt_deg=tilt,
                circles_used=int(est.circles), circle_angle_deg=ang, circle_chi2=chi2,
                circle_consistent=bool(chi2 <= CHI2_2_DETECTION))


def circular_points(C, x):
    """The images (2,) complex of the plane's circular points: where the horizon (the polar
    of x (2,), the image of the circle's centre) meets the circle's image C (3, 3); a pair
    of complex conjugates, the first returned. In normalised coordinates of the right
    camera they lie on the image of the absolute conic, I_x^2 + I_y^2 + 1 = 0: with an
    assumed focal length f0, a circle's image gives the true one as f0 sqrt(-(I_x^2 + I_y^2)).

    >>> from pencilcal.toolkit.geometry.frames import rotation_from_rotvec
    >>> R = rotation_from_rotvec([0.6, 0.1, 0.0]); x = np.array([0.02, 0.05])
    >>> a = np.linspace(0, 2 * np.pi, 40, endpoint=False)
    >>> X = R @ np.stack([0.3 * np.cos(a), 0.3 * np.sin(a), 0 * a]) + np.r_[x, 1.0][:, None]
    >>> from pencilcal.toolkit.geometry.conic import fit_ellipse
    >>> I = circular_points(fit_ellipse((X[:2] / X[2]).T).conic, x)
    >>> bool(abs(I[0] ** 2 + I[1] ** 2 + 1) < 1e-9)        # on the absolute conic's image
    True
    """
    C = np.asarray(C, float)
    ell = C @ np.r_[np.asarray(x, float), 1.0]
    # a point on the horizon and its direction
    d = np.array([-ell[1], ell[0], 0.0])
    p0 = -ell[2] * ell / max(ell[0] ** 2 + ell[1] ** 2, 1e-300)
    p0[2] = 1.0
    a, b, c = d @ C @ d, p0 @ C @ d, p0 @ C @ p0
    t = (-b + np.sqrt(complex(b * b - a * c))) / a
    return p0[:2] + t * d[:2]



def spokes_end(camera, orientation, segments, pencil):
    """(rho_end, ratio) where the pencil's spokes end on a printed circle (the outer
    ``radius`` is one of its ``circles``: a dartboard's boundaries end at the double ring's
    outer edge, beyond it the ring of numbers, whose print runs on along some of them), or
    None: rho_end the labelled edges' median outer end on the plane under the orientation
    [units of the vertex's depth], where to look for that ring, and ratio the spokes' end
    over the listed circle just inside it (170 / 162 mm: the ring's own width), or None
    where none is listed. The ring itself is found on the image
    (`detect.radial_circles.spokes_end_ring`).
    orientation: an `Orientation` with ``lines`` (``keep_lines``); segments (M, 4) [raw px]
    those it was fitted to.
    """
    if (pencil.radius is None or pencil.circles is None or not orientation.ok or orientation.lines is None
            or not np.any(np.abs(np.asarray(pencil.circles) / pencil.radius[1] - 1.0) <= _RADIUS_MATCH)):
        return None
    lines = orientation.lines
    R = np.asarray(orientation.R_cam_from_target, float)
    seg = np.asarray(segments, float)[np.asarray(lines["segment"], int)]
    rho, _ = plane_radii(camera.normalized_from_pixels(seg.reshape(-1, 2)), np.asarray(lines["vertex"], float), R)
    outer_end = np.nanmax(rho.reshape(-1, 2), 1)
    if not np.isfinite(outer_end).any():
        return None
    listed = np.sort(np.asarray(pencil.circles, float))
    inner = listed[listed < pencil.radius[1] * (1 - _RADIUS_MATCH)]
    if not inner.size:
        return None
    return float(np.nanmedian(outer_end)), float(pencil.radius[1] / inner[-1])
