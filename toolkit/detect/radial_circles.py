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

Working (undistorted) pixels throughout, raw pixels out.
"""
from __future__ import annotations

import warnings

import numpy as np

from pencilcal.toolkit.detect.edges import derivative_kernel, linearised
from pencilcal.toolkit.detect.working import to_raw_points

__all__ = ["circle_points"]

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
