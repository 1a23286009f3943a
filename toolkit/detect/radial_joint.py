"""A dense radial target's edges located jointly with their neighbours' blurred edges.

Where a Siemens star's edges lie a few blur sds apart (many wedges, the far side of a tilted
star), the profile across one edge holds its neighbours' blurred edges too: the peak of its
derivative is pulled towards the nearer one, more on one side than the other under
perspective, and the edge turns. Instead of leaving those stretches out, each station's
profile is modelled as what it is, the sum of the blurred steps of every edge that crosses
it (`joint_refit`):

    y(tau) = a + b tau + c sum_k s_k Phi((tau - tau_k) g_k / sigma)

on linear light (blur acts there), tau [px] along the profile towards larger angles about
the vertex, s_k = +-1 each edge's polarity (+1: brighter towards larger angles), tau_k where
edge k crosses the profile and g_k the cosine of its angle with the profile's normal, sigma
the edges' blur, a, b the local level and slope (uneven light), c the step. The neighbours'
crossings come from their current lines; the edge's own, t, is fitted (Gauss-Newton, the
linear a, b, c projected out at each step). The blur is fitted too, one sd in raw pixels
shared by every edge and station (the lens map turns it into working pixels across each
edge, `working.blur_scale`), its step from all stations with their own parameters projected
out: the neighbours' modelled steps hang on it, and a blur a few per cent off moves every
edge of a dense star the same way about the vertex. Measured on the image instead
(`radial._edge_blur`, the second moment of the edges' derivative), it was 3-26 % off the sd
this model fits on 128-wedge renders; fitted, it is within 1-2 % of the render's blur,
pixel and bilinear sampling together (sqrt(blur^2 + 1/4)).
Each station's weight is its information about t (the model's derivative in t after
projecting out a, b, c): low where the neighbours crowd it. The stations give a line as in
the edge-profile engine (`edges.reject_outliers`, `edges.weighted_line`,
`edges.fit_variances`: its sigmas from the stations' own scatter), and the lines are fitted
again with their neighbours' new positions.

Example
-------
>>> from pencilcal.toolkit.camera.model import Camera
>>> from pencilcal.toolkit.detect.image import GrayImage
>>> from pencilcal.toolkit.pencil.spec import pencil_from_dict
>>> from pencilcal.toolkit.synth.radial import radial_pose, render_layers, star_layers
>>> star = pencil_from_dict({"start_deg": 0, "step_deg": 360 / 64, "count": 64, "shape": "wedge",
...                          "radius": [0, 60]})
>>> cam = Camera("pinhole", 480, 360, [[400.0, 0, 239.5], [0, 400.0, 179.5], [0, 0, 1]])
>>> R, t = radial_pose(cam, (240, 180), 0.0, 60.0, fill=0.9)
>>> img = GrayImage(render_layers(cam, R, t, star_layers(star), blur_px=1.0, noise=0.5, rng=0))
>>> a = np.arange(128) * np.pi / 64 - np.pi / 128          # the true edges (frontal: image = plane)
>>> sign = np.where(np.arange(128) % 2 == 0, -1.0, 1.0)    # dark wedges
>>> u = np.stack([np.cos(a + 0.002), np.sin(a + 0.002)], -1)    # a little off
>>> v = np.array([240.0, 180.0])
>>> fit, blur = joint_refit(img, None, np.concatenate([v + 0 * u, v + 100 * u], -1), v, sign, 1.2,
...                   np.full(128, 25.0), np.full(128, 150.0))
>>> err = np.angle(np.exp(1j * (np.arctan2(*(fit.p2 - fit.p1)[:, ::-1].T) - np.where(sign > 0, a, a + np.pi))))
>>> bool(fit.ok.all()), bool(np.abs(err).max() < 3e-4)        # edges 2.5 px apart at r = 25 px
(True, True)
"""
from __future__ import annotations

import numpy as np
from scipy.special import erf

from pencilcal.toolkit.detect.edges import (
    MIN_STATIONS,
    SAMPLE_STEP_PX,
    fit_variances,
    masked_median,
    reject_outliers,
    relative_weights,
    weighted_line,
)
from pencilcal.toolkit.detect.refit import EdgeFit
from pencilcal.toolkit.detect.working import blur_scale, raw_frame

__all__ = ["joint_refit", "NEIGHBOURS", "FREE_SIGMAS", "END_WINDOWS"]

#: Neighbours modelled on each side of an edge (in angle order): enough that any edge
#: crossing a profile is in the model where neighbours lie 1.5 blur sds apart.
NEIGHBOURS = 5
#: A neighbour is fitted with the edge (its position free) where it crosses the profile
#: within this many blur sds beyond the window's end: a neighbour's step held at a position
#: a little off moves the edge (through the level and slope fitted across the window) by a
#: third of that even 5 sds away; free, it does not. 2.0 of the once biased blur, 2.1 of the
#: unbiased one (seed 7).
FREE_SIGMAS = 2.1
_STEP_PX = 2.0  # station spacing along an edge [px]
_MAX_STATIONS = 300
_ITERATIONS = 6
_FLOOR_PX = 0.1  # the robust line fit's smallest rejection threshold [px]
_MAX_GAP_PX = 30.0
_PRIOR = 0.01  # holds a free neighbour near its line where the window barely shows it
_REL_STEP = 0.4  # a station's fitted step must reach this fraction of the edge's median
_BLUR_STEP = 0.1  # the shared blur's Gauss-Newton step: at most this fraction of it
_MIN_BLUR_STATIONS = 50  # fewer stations: the blur is held as given
#: the lowest lag-1 correlation of an edge's station errors its sigmas believe (`edges.fit_variances`):
#: a star's stations alternate slightly (rho -0.05 to -0.12 on 16-wedge renders), and clipped
#: at 0 their sigmas were 8-9 % too large; the batch means still bound them from below
_MIN_RHO = -0.9
_CLUTTER = 3.0  # a station whose residual rms exceeds this many times the median's fits no blur
#: Stations within this many profile half-windows of an edge's outer end (its outermost station
#: whose step reaches half the edge's median) are left out: there the window reaches where the
#: wedge ends (a star's wedges end on an arc, seen obliquely under a tilt), the profile is no
#: longer a straight edge's, and a light star's edges came 0.06-0.3 px towards the wedge in the
#: last 4 % of its radius, every noise draw alike (seed 5, 128 wedges). One half-window, not
#: two: as well covered on seed 5's 128-wedge stars, 1 % more of their spokes kept.
END_WINDOWS = 1.0


def _cross(a, b):
    return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]


def _phi(z):
    """The standard normal distribution function."""
    return 0.5 * (1.0 + erf(z / np.sqrt(2.0)))


def _pdf(z):
    """The standard normal density."""
    return np.exp(-0.5 * z * z) / np.sqrt(2.0 * np.pi)


def _edge_frames(lines, v):
    """Each line (E, 4) [px] as (foot (E, 2): the point nearest the vertex v (2,), u (E, 2):
    its unit direction away from v)."""
    p1, p2 = lines[:, :2], lines[:, 2:]
    d = p2 - p1
    u = d / np.maximum(np.hypot(d[:, 0], d[:, 1]), 1e-12)[:, None]
    u = np.where((np.sum((0.5 * (p1 + p2) - v) * u, -1) < 0)[:, None], -u, u)
    foot = p1 + np.sum((v - p1) * u, -1)[:, None] * u
    return foot, u


def joint_refit(img, camera, lines, v, sign, sigma, r_lo, r_hi, *, rows=None, search=1.0, rounds=2, fit_blur=True,
                significance=False):
    """The edges through a radial target's vertex, each located jointly with its neighbours'
    blurred edges (module docstring).

    Parameters
    ----------
    img : GrayImage
        Linear light (`edges.linearised`: a frame's encoding undone before it is sampled).
    camera : Camera or None
        Lens model: lines in undistorted (working) pixels, profiles sampled in the raw image.
    lines : (E, 4) [working px]
        The edges' current lines, in the order of their angle about the vertex (cyclic).
    v : (2,) [working px]
        The vertex.
    sign : (E,)
        Each edge's polarity: +1 brighter towards larger angles about v, -1 darker.
    sigma : float [raw px]
        The sd of the edges' blur (as sampled: blur, pixel and resampling together), across
        an edge in the raw image (`working.blur_scale` gives it in working pixels at each
        station); with fit_blur, where the fit starts.
    r_lo, r_hi : (E,) [px]
        Distances from v along each edge between which it is measured.
    rows : (K,) int, optional
        The edges to fit (all when None); the others are the neighbours' lines as given.
    search : float [px]
        How far an edge may lie from its current line.
    rounds : int
        Fits of the edges, each with the neighbours' lines of the one before.
    fit_blur : bool
        Fit the blur too, one sd shared by every edge (`_solve_stations`), instead of holding
        it at sigma.
    significance : bool
        Also return each edge's step over its sd per unit of image noise (`_step_strength`):
        divided by the noise of `img` [linear grey levels], the z of its step.

    Returns
    -------
    fit : EdgeFit
        K rows (the edges `rows`, in that order), oriented brighter along n = (-d_y, d_x);
        ``contrast`` the median fitted step in linear grey levels.
    sigma : float [raw px]
        The blur the edges were located with (fitted with fit_blur).
    strength : (K,) [1 / noise], with significance only
        The step's weighted mean over the edge's stations over its sd for a unit noise.
    """
    lines = np.array(lines, float)
    sign = np.asarray(sign, float)
    rows = np.arange(lines.shape[0]) if rows is None else np.asarray(rows, int)
    fit, sigma0, strength = None, sigma, None
    for _ in range(rounds):
        fit, sigma, strength = _fit_round(img, camera, lines, v, sign, sigma, r_lo[rows], r_hi[rows], search, rows,
                                          fit_blur)
        sigma = float(np.clip(sigma, 0.5 * sigma0, 2.0 * sigma0))  # a misfit (clutter) does not run away
        lines[rows] = np.where(fit.ok[:, None], fit.lines(), lines[rows])
    return (fit, sigma, strength) if significance else (fit, sigma)


def _stations(foot, u, r_lo, r_hi, v):
    """Stations s (E, S) [px along u from the foot] between r_lo and r_hi from v, and valid (E, S)."""
    along = np.sum((foot - v) * u, -1)  # ~0: the foot is the point nearest v
    lo, hi = r_lo - along, r_hi - along
    cnt = np.clip(np.round((hi - lo) / _STEP_PX).astype(int) + 1, 0, _MAX_STATIONS)
    S = max(int(cnt.max()), 1)
    j = np.arange(S)
    valid = j[None, :] < cnt[:, None]
    step = (hi - lo) / np.maximum(cnt - 1, 1)
    return lo[:, None] + j[None, :] * step[:, None], valid & (hi > lo)[:, None]


def _fit_round(img, camera, lines, v, sign, sigma, r_lo, r_hi, search, rows, fit_blur):
    """One joint fit of the edges `rows` (`joint_refit`) with the neighbours at `lines`:
    (EdgeFit, the blur sd [raw px], the steps' strength (`_step_strength`))."""
    E = lines.shape[0]
    foot_all, u_all = _edge_frames(lines, v)
    foot, u = foot_all[rows], u_all[rows]
    e = np.stack([-u[:, 1], u[:, 0]], -1)  # towards larger angles (image y down: clockwise)
    s, valid = _stations(foot, u, r_lo, r_hi, v)
    x = foot[:, None, :] + s[..., None] * u[:, None, :]  # (E, S, 2)
    # (E, S); bounded where a lens model is far outside what it holds (its map folds back)
    scale = np.clip(blur_scale(camera, x[..., 0], x[..., 1], e[:, 0, None], e[:, 1, None]), 0.5, 2.0)
    sig = sigma * scale  # the blur [working px] at each station, across its edge
    half = search + 3.0 * float(np.max(np.where(valid, sig, 0.0))) * (1.1 if fit_blur else 1.0)
    nt = int(np.ceil(half / SAMPLE_STEP_PX))
    tau = np.arange(-nt, nt + 1) * SAMPLE_STEP_PX  # (T,)
    rx, ry, jx, jy = raw_frame(camera, x[..., 0], x[..., 1], e[:, 0, None], e[:, 1, None])
    X = rx[..., None] + jx[..., None] * tau
    Y = ry[..., None] + jy[..., None] * tau
    H, W = img.shape
    inside = valid & np.all((X >= 0) & (X <= W - 1) & (Y >= 0) & (Y <= H - 1), -1)
    if getattr(img, "region", None) is not None:
        inside &= img.in_region(X[..., 0], Y[..., 0]) & img.in_region(X[..., -1], Y[..., -1])
    y = img.sample(np.where(inside[..., None], X, 0).astype(np.float32),
                   np.where(inside[..., None], Y, 0).astype(np.float32)).astype(float)
    # the neighbours' blurred edges, where they cross each station's profile: those within
    # reach of the window fitted with the edge (their positions free), the others fixed
    # (their steps, and the steps' derivative in the blur sd, summed)
    fixed, dfixed = np.zeros(y.shape), np.zeros(y.shape)
    near = []
    for k in range(1, NEIGHBOURS + 1):
        for j in (rows - k) % E, (rows + k) % E:
            den = _cross(e, u_all[j])  # (K,): the profile's direction against edge j's
            tk = _cross(foot_all[j][:, None, :] - x, u_all[j][:, None, :]) / np.where(np.abs(den) > 1e-6, den, 1e-6)[:, None]
            g = np.broadcast_to(np.maximum(np.abs(den), 0.2)[:, None], tk.shape)
            free = (np.abs(tk) < half + FREE_SIGMAS * sig) & (np.abs(den) > 0.2)[:, None]
            sk = np.broadcast_to(sign[j][:, None], tk.shape)
            if free.any():
                near.append((tk, g, sk, free))
            held = ~(free | (np.abs(den) <= 0.2)[:, None])
            zk = (tau - tk[..., None]) * g[..., None] / sig[..., None]
            fixed += np.where(held[..., None], sk[..., None] * _phi(zk), 0.0)
            if fit_blur:
                dfixed -= np.where(held[..., None], sk[..., None] * _pdf(zk) * zk / sigma, 0.0)
    t, c, info, ok, sigma, c_var = _solve_stations(y, tau, (fixed, dfixed), near,
                                                   np.broadcast_to(sign[rows, None], s.shape), (sigma, scale),
                                                   search, inside if fit_blur else None)
    fit = _lines_from_stations(foot, u, e, s, t, c, info, inside & ok, sign[rows], END_WINDOWS * half)
    return fit, sigma, _step_strength(c, c_var, inside & ok)


def _step_strength(c, c_var, use):
    """Each edge's step, the inverse-variance mean of its stations' steps c (E, S) over
    `use` (E, S), over that mean's sd for a unit noise (c_var (E, S): each station's step
    variance per unit noise, the model's other parameters projected out): (E,) [1 / noise],
    0 where no station is used. Divided by the image noise, the z of the step: whether an
    edge is there at all, where its neighbours crowd it or the blur merges it with them."""
    w = np.where(use & (c_var > 0) & np.isfinite(c_var), 1.0 / np.where(c_var > 0, c_var, 1.0), 0.0)
    W = w.sum(-1)
    with np.errstate(all="ignore"):
        return np.where(W > 0, np.sum(w * np.nan_to_num(c), -1) / np.sqrt(np.maximum(W, 1e-300)), 0.0)


def _blur_step(A, N, r, rhs, col, use):
    """The Gauss-Newton step of the blur sd shared by all stations, each station's own
    parameters projected out (its normal equations N (E, S, P, P) and right-hand side rhs
    (E, S, P), its model's columns A (E, S, T, P), residuals r (E, S, T), the blur's column
    col (E, S, T)), summed over the stations `use` (E, S): the Schur complement of the joint
    normal equations. Returns the step d and the stations' own steps with it (E, S, P),
    N^-1 (rhs - A^T col d). Stations whose residuals are far above the typical (clutter)
    are left out of d."""
    b = (np.swapaxes(A, -1, -2) @ col[..., None])[..., 0]  # (E, S, P)
    X = np.linalg.solve(N, np.stack([rhs, b], -1))  # one factorisation for both
    Nrhs, Nb = X[..., 0], X[..., 1]
    rr = np.sqrt(np.mean(r * r, -1))
    if use.any():
        use = use & (rr <= _CLUTTER * np.median(rr[use]))
    m = np.sum(np.where(use, np.sum(col * col, -1) - np.sum(b * Nb, -1), 0.0))
    g = np.sum(np.where(use, np.sum(col * r, -1) - np.sum(Nb * rhs, -1), 0.0))
    if use.sum() < _MIN_BLUR_STATIONS or not m > 0:
        return 0.0, Nrhs
    d = g / m
    return d, Nrhs - Nb * d


def _solve_stations(y, tau, fixed, near, sgn, blur, search, fit_blur):
    """Gauss-Newton at each station for its own edge t (E, S) [px] in the profiles y
    (E, S, T) = a + b tau + c (fixed + sgn Phi((tau - t) / sigma) + the free neighbours'
    steps, their positions fitted too: a weak prior, `_PRIOR` of the edge's own information,
    holds each near its line where the window barely shows it); returns t, c, the
    information about t per unit noise (the other parameters projected out), ok
    (converged, c > 0), the blur sd [raw px] and the variance of c per unit noise (E, S).
    near: per neighbour, (tau_k, g_k, s_k, free), each (E, S); fixed: the held neighbours'
    steps (E, S, T) and their derivative in the blur sd; blur: (sd [raw px], its scale to
    working px at each station (E, S)); fit_blur: None, or the stations (E, S) whose
    profiles also fit one blur sd shared by all (`_blur_step`; the held neighbours' steps
    follow it to first order)."""
    shape = y.shape[:2]
    P = 4 + len(near)
    p = np.zeros(shape + (P,))  # a, b, c, t, and the neighbours' shifts
    tt = np.broadcast_to(tau, y.shape)
    pin = np.stack([np.zeros(shape)] * 4 + [~nb[3] for nb in near], -1)  # held at 0
    prior = np.stack([np.zeros(shape)] * 4 + [nb[3].astype(float) for nb in near], -1)
    sigma0, scale = blur
    sigma = sigma0
    for it in range(_ITERATIONS + 1):
        a, b, c, t = (p[..., i] for i in range(4))
        sig = (sigma * scale)[..., None]
        z = (tau - t[..., None]) / sig
        bracket = fixed[0] + (sigma - sigma0) * fixed[1] + sgn[..., None] * _phi(z)
        dsig = fixed[1] - sgn[..., None] * _pdf(z) * z / sigma  # the bracket's derivative in the blur sd
        cols = [np.ones_like(y), tt, None, -c[..., None] * sgn[..., None] * _pdf(z) / sig]
        for i, (tk, g, sk, free) in enumerate(near):
            # evaluated only where the neighbour is free (elsewhere its step and column are 0):
            # most of a dense star's stations have few free neighbours
            sf = sig[free]
            zk = (tau - tk[free][:, None] - p[..., 4 + i][free][:, None]) * g[free][:, None] / sf
            step_k, col_k = np.zeros(y.shape), np.zeros(y.shape)
            step_k[free] = sk[free][:, None] * _phi(zk)
            col_k[free] = -c[free][:, None] * sk[free][:, None] * _pdf(zk) * g[free][:, None] / sf
            if fit_blur is not None:
                dsig[free] -= sk[free][:, None] * _pdf(zk) * zk / sigma
            bracket = bracket + step_k
            cols.append(col_k)
        cols[2] = bracket
        A = np.stack(cols, -1)  # (E, S, T, P)
        r = y - a[..., None] - b[..., None] * tau - c[..., None] * bracket
        At = np.swapaxes(A, -1, -2)
        N = At @ A  # batched matmul: several times faster than einsum's loop here
        scale_n = np.maximum(np.einsum("...ii->...i", N), 1e-12)
        ridge = 1e-9 * scale_n + pin * scale_n + _PRIOR * prior * N[..., 3, 3, None]
        rhs = (At @ r[..., None])[..., 0] - _PRIOR * prior * N[..., 3, 3, None] * p
        N = N + np.eye(P) * ridge[..., None, :]
        if it == 0:  # the first step finds the levels and the step only
            N = N + np.eye(P) * (np.arange(P) >= 3) * 1e12
        if it > 0 and fit_blur is not None:
            # the stations take their full joint step; the blur's is bounded (a far start)
            d, step = _blur_step(A, N, r, rhs, c[..., None] * dsig, fit_blur)
            sigma += float(np.clip(d, -_BLUR_STEP * sigma, _BLUR_STEP * sigma))
        else:
            step = np.linalg.solve(N, rhs[..., None])[..., 0]
        step[..., 3:] = np.clip(step[..., 3:], -0.5, 0.5)
        p = p + step
        p[..., 3] = np.clip(p[..., 3], -search - 0.5, search + 0.5)
    t, c = p[..., 3], p[..., 2]
    with np.errstate(all="ignore"):
        Ni = np.linalg.inv(N)
        info = 1.0 / Ni[..., 3, 3]
    ok = (c > 0) & (np.abs(t) <= search) & (info > 0) & np.isfinite(t) & np.all(np.abs(p[..., 4:]) < 1.0, -1)
    return t, c, info, ok, sigma, Ni[..., 2, 2]


def _lines_from_stations(foot, u, e, s, t, c, info, base, sign, end_px=0.0):
    """The lines (`EdgeFit`) through the stations' edges t (E, S) [px along e] at s (E, S)
    [px along u from foot], weighted by their information, without the stations within end_px
    of each edge's outer end (`END_WINDOWS`); robust as the edge-profile engine."""
    med = masked_median(c, base)
    s_end = np.max(np.where(base & (c >= 0.5 * med[:, None]), s, -np.inf), -1)
    base = base & (c >= _REL_STEP * med[:, None]) & (s <= s_end[:, None] - end_px)
    w = relative_weights(np.sqrt(np.maximum(info, 0.0)), base)
    inl = reject_outliers(s, t, w, base, base, _FLOOR_PX, _MAX_GAP_PX, iters=4)
    sm, tm, b, Sss, Wt = weighted_line(s, t, w, inl)
    res = t - tm[:, None] - b[:, None] * (s - sm[:, None])
    count = inl.sum(-1)
    ok = count >= MIN_STATIONS
    var_b, var_a = fit_variances(res, w, inl, Sss, Wt, min_rho=_MIN_RHO)
    s_first = np.where(ok, np.min(np.where(inl, s, np.inf), -1), 0.0)
    s_last = np.where(ok, np.max(np.where(inl, s, -np.inf), -1), 0.0)

    def at(sv):
        return foot + sv[:, None] * u + (tm + b * (sv - sm))[:, None] * e

    inner, outer = at(s_first), at(s_last)
    p1 = np.where(sign[:, None] > 0, inner, outer)  # brighter along n = (-d_y, d_x)
    p2 = np.where(sign[:, None] > 0, outer, inner)
    return EdgeFit(ok=ok, p1=p1, p2=p2, centroid=at(sm), angle_sigma=np.sqrt(var_b) / (1.0 + b * b),
                   centre_sigma=np.sqrt(var_a), contrast=np.nan_to_num(masked_median(c, inl)),
                   residual=np.sqrt(np.sum(np.where(inl, res * res, 0.0), -1) / np.maximum(count, 1)), count=count)
