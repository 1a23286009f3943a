"""Edge points of the circles about a radial target's vertex.

A circle printed about the vertex (a Siemens star's outline, a dartboard's rings) images as
an ellipse that surrounds the vertex's image: along every ray from the vertex it is crossed
once, at a radius that changes smoothly with the ray's direction. `circle_points` samples
the grey levels along rays between the spokes' edges (where no spoke runs along the ray),
finds the edges across each ray (peaks of the Gaussian-derivative response above the ray's
noise and a fraction of the ray's strongest, either sign: a dartboard's ring is lighter than
a black sector and darker than a cream one) and keeps those that continue on the neighbouring rays at about the same radius
(isolated peaks are texture). Which of them lie on one circle is decided with the plane's
orientation (`pencil.circle`): nested rings a few pixels apart, whose edges change sign at
every sector, are told apart there by their radius on the plane.

`spokes_end_ring` finds one ring on the image instead, about a first orientation: the ring a
sector target's boundaries end on (a dartboard's double ring), its outer edge told from its
inner edge by their polarities in the dark sectors.

Working (undistorted) pixels throughout, raw pixels out.
"""
from __future__ import annotations

import warnings

import numpy as np

from pencilcal.toolkit.detect.edges import derivative_kernel, linearised
from pencilcal.toolkit.errors import EstimationError
from pencilcal.toolkit.geometry.conic import fit_ellipse, sampson_distances
from pencilcal.toolkit.detect.working import to_raw_points

__all__ = ["circle_points", "spokes_end_ring"]

_RAY_STEP_DEG = 1.0  # rays at most this far apart
_SAMPLE_PX = 0.5  # along a ray
_KERNEL_PX = 1.0  # sd of the derivative kernel along a ray
_PEAK_NOISE = 6.0  # an edge along a ray: at least this many sds of the ray's derivative noise
_PEAK_REL = 0.15  # and this fraction of its strongest edge (JPEG's ringing beside a strong edge is no edge)
_LINK_PX = 1.5  # a point continues on a neighbouring ray within this, plus 1 % of its radius per degree
_MIN_RUN = 3  # points linked from ray to ray at least


def circle_points(img, camera, v, edge_lines, reach, gamma=1.0):
    """Edge points (K, 2) [raw px] across rays from v (2,) [working px] between the spoke
    edges edge_lines (E, 4) [working px], from 0.2 to 2 reach [px] from v: those that run
    on over at least `_MIN_RUN` neighbouring rays. gamma: the frames' encoding gamma, the
    profiles linearised with it (`edges.linearised`: a blurred step's gradient peaks on its
    dark side on encoded levels, and a star's outline, dark inside, would shrink)."""
    psi = _ray_directions(v, edge_lines)
    if psi.size < 12:
        return np.zeros((0, 2))
    r = np.arange(0.2 * reach, 2.0 * reach, _SAMPLE_PX)
    pts = v + r[None, :, None] * np.stack([np.cos(psi), np.sin(psi)], -1)[:, None, :]  # (P, S, 2)
    raw = to_raw_points(camera, pts)
    inside = img.in_region(raw[..., 0], raw[..., 1])
    prof = linearised(img.sample(np.where(inside, raw[..., 0], 0), np.where(inside, raw[..., 1], 0)), gamma)
    prof = prof.astype(float)
    kern, kr = derivative_kernel(_KERNEL_PX)
    g = np.zeros_like(prof)
    for q in range(kern.size):
        g[:, kr:-kr] += kern[q] * prof[:, q:q + prof.shape[1] - 2 * kr]
    valid = inside.copy()
    valid[:, :kr] = valid[:, -kr:] = False
    for s in range(1, kr + 1):  # the kernel must see only samples inside
        valid[:, s:] &= inside[:, :-s]
        valid[:, :-s] &= inside[:, s:]
    a = np.where(valid, np.abs(g), 0.0)
    peak = (a > np.roll(a, 1, 1)) & (a >= np.roll(a, -1, 1)) & valid
    # the noise of the derivative along each ray, from its median (most of a ray is flat)
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # a ray wholly outside: NaN, no edges
        noise = 1.4826 * np.nanmedian(np.where(valid, a, np.nan), 1, keepdims=True)
    peak &= a >= np.maximum(_PEAK_NOISE * np.nan_to_num(noise, nan=np.inf), _PEAK_REL * a.max(1, keepdims=True))
    ray, j = np.nonzero(peak)
    # sub-sample radius by a parabola through the peak
    am, a0, ap = a[ray, j - 1], a[ray, j], a[ray, j + 1]
    den = am - 2 * a0 + ap
    off = np.where(den < 0, 0.5 * (am - ap) / np.where(den < 0, den, -1.0), 0.0)
    rad = r[j] + np.clip(off, -0.5, 0.5) * _SAMPLE_PX
    keep = _runs(psi, ray, rad) >= _MIN_RUN
    q = v + rad[keep, None] * np.stack([np.cos(psi[ray[keep]]), np.sin(psi[ray[keep]])], -1)
    return to_raw_points(camera, q)


def _ray_directions(v, lines):
    """Ray directions (P,) [rad] from v between the lines' directions: the middle of every
    gap between neighbouring spoke edges, and more at most `_RAY_STEP_DEG` apart in its
    central half where the gap is wide."""
    mid = 0.5 * (lines[:, :2] + lines[:, 2:])
    phi = np.sort(np.arctan2(mid[:, 1] - v[1], mid[:, 0] - v[0]))
    if phi.size == 0:
        return np.radians(np.arange(0.0, 360.0, _RAY_STEP_DEG))
    gaps = np.diff(np.r_[phi, phi[0] + 2 * np.pi])
    out = []
    for a, g in zip(phi, gaps):
        n = max(1, int(np.floor(0.5 * g / np.radians(_RAY_STEP_DEG))))
        out.append(a + g * (0.5 + 0.5 * (np.arange(n) - (n - 1) / 2.0) / max(n, 1)))
    return np.concatenate(out)


def _runs(psi, ray, rad):
    """For each edge point (ray index (Q,), radius (Q,)), the number of points of its run:
    points on neighbouring rays (up to 4 rays and 12 deg on: a star's outline shows on every
    other ray, its wedges'; psi (P,) in increasing order,
    the last next to the first) within `_LINK_PX` plus 1 % of the radius per degree (an
    ellipse of axes 2:1 about its centre changes its radius by at most 0.6 % per degree),
    mutually nearest, are one run."""
    P = psi.size
    by_ray = [np.flatnonzero(ray == k) for k in range(P)]
    parent = np.arange(ray.size)

    def find(i):
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for k in range(P):
        here = by_ray[k]
        if here.size == 0:
            continue
        linked = np.zeros(here.size, bool)
        for step in range(1, 5):
            nxt = by_ray[(k + step) % P]
            dpsi = np.degrees(np.remainder(psi[(k + step) % P] - psi[k], 2 * np.pi))
            if nxt.size == 0 or dpsi > 12.0:
                continue
            d = np.abs(rad[here][:, None] - rad[nxt][None, :])
            tol = _LINK_PX + 0.01 * rad[here][:, None] * dpsi
            best = np.argmin(d, 1)
            back = np.argmin(d, 0)
            for i in np.flatnonzero(~linked):
                b = best[i]
                if d[i, b] <= tol[i, 0] and back[b] == i:
                    parent[find(here[i])] = find(nxt[b])
                    linked[i] = True
    roots = np.array([find(i) for i in range(ray.size)], int)
    return np.bincount(roots, minlength=ray.size)[roots] if ray.size else np.zeros(0, int)


_RING_LOG_SPAN = np.log(1.6)  # the ring is looked for within this factor of the spokes' median outer end
_RING_LOG_STEP = 0.002  # radial sampling [log radius on the plane]
_RING_ARC_DEG = 0.5  # angular sampling on the plane
_RING_WIRE_DEG = 2.0  # samples this close to a sector boundary (its wire, a label a little off) are not used
_RING_SMOOTH = 2.0  # sd [samples] of the derivative kernel along the radius
_RING_FROM = 0.75  # searched outwards from this fraction of the spokes' median end (a dartboard's treble lies at 0.63 of its double)
_RING_REJECT = 3.0  # ellipse points beyond this many robust sds of its Sampson distances are left out


def spokes_end_ring(img, camera, R, x, boundaries, rho_end, ratio, gamma=1.0):
    """(3, 3) the image conic [working px] of the outer edge of the ring where a sector
    target's boundaries end (a dartboard's double ring, 162-170 mm), or None.

    The image is resampled on polar coordinates of the plane under the rotation R (3, 3)
    (R_cam_from_target) about the vertex's image x (2,) [normalised], radii within
    `_RING_LOG_SPAN` of rho_end (the labelled edges' median outer end, in units of the
    vertex's depth), and linearised with gamma. The sectors of the two shades lie between
    the boundaries' directions `boundaries` (B,) [rad] in the target frame (alternating; B
    even); along a dark sector's direction the ring is a lighter band whose inner edge rises
    and whose outer edge falls at `ratio` times its radius (170 / 162: a ratio the first
    orientation's errors do not change, where they bend the plane's radii by a few per cent
    over a turn); along a light sector's both fall, the inner the more, so only the dark
    directions are searched. The rise must lie where the shades still differ (by half their
    most) within one ring's width (`ratio`) inside it: the ring of numbers beyond is one
    shade, and its digits are lighter bands of about the ring's width. Each dark direction gives the fall
    where the pair is steepest (the smaller of the two slopes), from `_RING_FROM` of rho_end
    out; an ellipse is fitted to those points in working pixels, robustly
    (`_robust_ellipse`): the ring's own image.
    img: a `GrayImage`; camera: the working pixels' camera (None: x in pixels).

    >>> from pencilcal.toolkit.detect.image import GrayImage
    >>> yy, xx = np.mgrid[0:200, 0:200] - 100.0
    >>> r, a = np.hypot(xx, yy), np.arctan2(yy, xx)
    >>> dark = (np.floor(np.remainder(a, 2 * np.pi) / (np.pi / 4)) % 2) == 0
    >>> frame = np.where(r < 60, np.where(dark, 20.0, 230.0), np.where(r < 63, np.where(dark, 120.0, 90.0), 20.0))
    >>> C = spokes_end_ring(GrayImage(frame), None, np.eye(3), [100.0, 100.0], np.arange(8) * np.pi / 4, 60.0, 63 / 60)
    >>> bool(abs(np.sqrt(-np.linalg.det(C) / (C[0, 0] * np.linalg.det(C[:2, :2]))) - 63.0) < 1.0)
    True
    """
    b = np.sort(np.remainder(np.asarray(boundaries, float), 2 * np.pi))
    if b.size < 4 or b.size % 2 or not np.isfinite(rho_end) or rho_end <= 0:
        return None
    lr = np.log(rho_end) + np.arange(-_RING_LOG_SPAN, _RING_LOG_SPAN, _RING_LOG_STEP)
    a = np.radians(np.arange(0.0, 360.0, _RING_ARC_DEG))
    k = np.searchsorted(b, a) % b.size  # the sector each direction lies in, by its boundary
    near = np.degrees(np.min(np.abs(np.angle(np.exp(1j * (a[:, None] - b[None, :])))), 1))
    keep = near >= _RING_WIRE_DEG
    a, shade = a[keep], k[keep] % 2
    u = np.exp(lr)[None, :, None] * np.stack([np.cos(a), np.sin(a)], -1)[:, None, :]  # (P, S, 2) on the plane
    X = np.r_[np.asarray(x, float), 1.0] + u @ np.asarray(R, float)[:, :2].T
    with np.errstate(all="ignore"):
        xn = X[..., :2] / X[..., 2:]
    K = np.eye(3) if camera is None else np.asarray(camera.K, float)
    wp = xn @ K[:2, :2].T + K[:2, 2]
    ok = (X[..., 2] > 0) & np.all(np.isfinite(wp), -1)
    raw = to_raw_points(camera, np.where(ok[..., None], wp, 0.0))
    ok &= np.all(np.isfinite(raw), -1) & img.in_region(raw[..., 0], raw[..., 1])
    prof = linearised(img.sample(np.where(ok, raw[..., 0], 0), np.where(ok, raw[..., 1], 0)), gamma).astype(float)
    prof[~ok] = np.nan
    g = _smooth_derivative(prof)
    # the dark shade: the sectors darker inside the ring (its first half of the radii)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # a shade seen nowhere: NaN
        level = [np.nanmedian(prof[shade == s, :lr.size // 2]) for s in (0, 1)]
    if not np.all(np.isfinite(level)):
        return None
    dark = shade == int(np.argmin(level))
    # where the sectors still show (the shades' medians apart by half their most), within a
    # ring's width inside its inner edge: the ring of numbers beyond the double ring is one
    # shade, and its white digits and outline are lighter bands of about the same width
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        med = np.stack([np.nanmedian(prof[shade == s], 0) for s in (0, 1)])
    contrast = np.nan_to_num(np.abs(med[0] - med[1]))
    sectors = contrast >= 0.5 * contrast.max()
    # in a dark sector's direction the ring is a lighter band: its inner edge rises, its
    # outer edge falls at `ratio` times the inner's radius (a ratio the first orientation's
    # errors do not change); the outer edge where both are steepest together
    i_in = int(round(np.log(ratio) / _RING_LOG_STEP))
    lo = max(int(round((_RING_LOG_SPAN - np.log(1 / _RING_FROM)) / _RING_LOG_STEP)), i_in)
    both = np.full_like(g, -np.inf)
    both[:, lo:] = np.minimum(g[:, lo - i_in:g.shape[1] - i_in], -g[:, lo:])
    both[~dark] = -np.inf
    lit = np.array([sectors[max(i - 2 * i_in, 0):max(i - i_in + 1, 0)].any() for i in range(lr.size)])
    both[:, ~lit] = -np.inf
    both = np.where(np.isfinite(both), both, -np.inf)
    j = np.argmax(both, 1)
    has = both[np.arange(a.size), j] > 0
    # the ring is one circle of the plane: a direction's pair of steps farther from the
    # directions' median log radius than `_RING_REJECT` robust sds of them (never nearer than
    # the ring's own width, `ratio`: the first orientation bends the plane's radii) is
    # something else, left out before the fit, which would bend towards such points taken
    # together (a maker's print in the numbers' ring: in a dark sector's linear light its
    # steps are far stronger than the ring's)
    if has.any():
        dev = np.abs(lr[j] - np.median(lr[j[has]]))
        has &= dev <= max(_RING_REJECT * 1.4826 * np.median(dev[has]), np.log(ratio))
    if has.sum() < 12:
        return None
    rows = np.flatnonzero(has)
    got = _robust_ellipse(wp[rows, j[rows]])
    if got is None:
        return None
    C, use = got
    # the points lie on one circle of the first orientation's plane, within the ring's own
    # width (a first orientation far off finds some lighter band, on no circle of its plane)
    spread = 1.4826 * np.median(np.abs(lr[j[rows[use]]] - np.median(lr[j[rows[use]]])))
    return C if spread <= np.log(ratio) else None


def _smooth_derivative(prof):
    """d prof / d sample (P, S) along each row with a Gaussian derivative of sd `_RING_SMOOTH`
    samples; NaN where the kernel reaches a NaN."""
    kr = int(np.ceil(3 * _RING_SMOOTH))
    t = np.arange(-kr, kr + 1, dtype=float)
    kern = t * np.exp(-0.5 * (t / _RING_SMOOTH) ** 2)
    kern /= np.sum(t * kern)  # a ramp of slope 1 gives 1
    out = np.full_like(prof, np.nan)
    S = prof.shape[1]
    acc = np.zeros((prof.shape[0], S - 2 * kr))
    for q in range(kern.size):  # sum over t of kern(t) prof(i + t)
        acc += kern[q] * prof[:, q:S - 2 * kr + q]
    out[:, kr:S - kr] = acc
    return out


def _robust_ellipse(pts):
    """(the conic (3, 3) of the ellipse fitted to points (K, 2), the points kept (K,) bool),
    those beyond `_RING_REJECT` robust sds of its Sampson distances left out (three rounds);
    None when none fits or it keeps under half of the points."""
    use = np.ones(len(pts), bool)
    C = None
    for _ in range(3):
        if use.sum() < max(12, 0.5 * len(pts)):
            return None
        try:
            fit = fit_ellipse(pts[use])
        except EstimationError:
            return None
        C = fit.conic
        r = np.abs(sampson_distances(C, pts))
        s = 1.4826 * np.median(r[use])
        use = r <= max(_RING_REJECT * s, 0.25)
    return (C, use) if use.sum() >= 0.5 * len(pts) else None
