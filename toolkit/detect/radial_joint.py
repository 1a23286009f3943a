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
Where every edge of a star is modelled and `DIRECTIONAL_BLUR` is set (it is not by
default), the blur is a Gaussian of any covariance C instead
(`_blur_model`): across an edge whose normal n lies at phi in the raw image its variance is
n^T C n = q0 + q1 cos 2 phi + q2 sin 2 phi, each neighbour with its own; a motion of length m
along phi_m adds about m^2 / 12 cos^2(phi - phi_m), most where the edge's normal lies along
the motion. q0, q1, q2 are fitted as the one sd is (their step from all stations).
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
_DIR_RIDGE = 1e-3  # the directional blur terms' ridge, relative to the mean variance's information
#: the lowest lag-1 correlation of an edge's station errors its sigmas believe (`edges.fit_variances`):
#: a star's stations alternate slightly (rho -0.05 to -0.12 on 16-wedge renders), and clipped
#: at 0 their sigmas were 8-9 % too large; the batch means still bound them from below
_MIN_RHO = -0.9
_CLUTTER = 3.0  # a station whose residual rms exceeds this many times the median's fits no blur
#: Fit the blur as a Gaussian of any covariance (its sd across an edge depends on the edge's
#: direction: motion blur, astigmatism) instead of one sd for every edge (`_blur_model`).
#: Off: on photographed stars under 30 % of the frame's height it oriented as many frames,
#: rescued two with 1.8-2 px of motion blur and lost one with none, and its normals were no
#: closer nor its sigmas truer (docs/method.md, "A directional blur").
DIRECTIONAL_BLUR = False
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
                significance=False, directional=True):
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
    directional : bool
        With fit_blur, fit the blur as a Gaussian of any covariance, its sd across an edge
        depending on the edge's direction (`_blur_model`: motion blur), where
        `DIRECTIONAL_BLUR` allows; otherwise one sd for every direction.
    significance : bool
        Also return each edge's step over its sd per unit of image noise (`_step_strength`):
        divided by the noise of `img` [linear grey levels], the z of its step.

    Returns
    -------
    fit : EdgeFit
        K rows (the edges `rows`, in that order), oriented brighter along n = (-d_y, d_x);
        ``contrast`` the median fitted step in linear grey levels.
    sigma : float [raw px]
        The blur the edges were located with (fitted with fit_blur; a directional blur's
        sd averaged in variance over the directions, sqrt(q0)).
    strength : (K,) [1 / noise], with significance only
        The step's weighted mean over the edge's stations over its sd for a unit noise.
    """
    lines = np.array(lines, float)
    sign = np.asarray(sign, float)
    rows = np.arange(lines.shape[0]) if rows is None else np.asarray(rows, int)
    fit, sigma0, strength = None, sigma, None
    blur = np.array([sigma * sigma, 0.0, 0.0]) if directional and fit_blur and DIRECTIONAL_BLUR else np.array([sigma])
    for _ in range(rounds):
        fit, blur, strength = _fit_round(img, camera, lines, v, sign, blur, r_lo[rows], r_hi[rows], search, rows,
                                         fit_blur)
        blur = _bounded_blur(blur, sigma0)  # a misfit (clutter) does not run away
        lines[rows] = np.where(fit.ok[:, None], fit.lines(), lines[rows])
    sigma = float(np.sqrt(blur[0]) if blur.size == 3 else blur[0])
    return (fit, sigma, strength) if significance else (fit, sigma)


def _bounded_blur(blur, sigma0):
    """The blur parameters (`_blur_model`) with its sd in every direction within 0.5-2 times
    sigma0 [raw px]."""
    if blur.size == 1:
        return np.clip(blur, 0.5 * sigma0, 2.0 * sigma0)
    lo, hi = (0.5 * sigma0) ** 2, (2.0 * sigma0) ** 2
    r = np.hypot(blur[1], blur[2])
    q0 = np.clip(blur[0], lo, hi)
    r_max = min(q0 - lo, hi - q0)
    return np.array([q0, *(blur[1:] * (min(r, r_max) / r if r > 0 else 0.0))])


def _blur_model(blur, basis):
    """The blur's sd [raw px] across each station's edge and its derivative in the blur's
    parameters: (sd (E, S), d sd / d blur (E, S, Q)). blur (1,): one sd shared by every
    direction; (3,): q0, q1, q2 [raw px^2], the variance across an edge whose normal lies at
    phi in the raw image q0 + q1 cos 2 phi + q2 sin 2 phi, i.e. n^T C n of a Gaussian blur of
    covariance C (motion blur's variance grows along the motion). basis (E, S, 3):
    (1, cos 2 phi, sin 2 phi)."""
    if blur.size == 1:
        sd = np.full(basis.shape[:-1], float(blur[0]))
        return sd, np.ones(basis.shape[:-1] + (1,))
    var = np.maximum(basis @ blur, 1e-4)
    sd = np.sqrt(var)
    return sd, basis / (2.0 * sd[..., None])


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


def _fit_round(img, camera, lines, v, sign, blur, r_lo, r_hi, search, rows, fit_blur):
    """One joint fit of the edges `rows` (`joint_refit`) with the neighbours at `lines`:
    (EdgeFit, the blur's parameters (`_blur_model`), the steps' strength (`_step_strength`))."""
    E = lines.shape[0]
    foot_all, u_all = _edge_frames(lines, v)
    foot, u = foot_all[rows], u_all[rows]
    e = np.stack([-u[:, 1], u[:, 0]], -1)  # towards larger angles (image y down: clockwise)
    s, valid = _stations(foot, u, r_lo, r_hi, v)
    x = foot[:, None, :] + s[..., None] * u[:, None, :]  # (E, S, 2)
    # (E, S); bounded where a lens model is far outside what it holds (its map folds back)
    scale = np.clip(blur_scale(camera, x[..., 0], x[..., 1], e[:, 0, None], e[:, 1, None]), 0.5, 2.0)
    rx, ry, jx, jy = raw_frame(camera, x[..., 0], x[..., 1], e[:, 0, None], e[:, 1, None])
    jn = np.maximum(jx * jx + jy * jy, 1e-12)  # the profile's direction in the raw image: the blur's
    basis = np.stack([np.ones(jn.shape), (jx * jx - jy * jy) / jn, 2.0 * jx * jy / jn], -1)
    sig_raw, _ = _blur_model(blur, basis)
    sig = sig_raw * scale  # the blur [working px] at each station, across its edge
    half = search + 3.0 * float(np.max(np.where(valid, sig, 0.0))) * (1.1 if fit_blur else 1.0)
    nt = int(np.ceil(half / SAMPLE_STEP_PX))
    tau = np.arange(-nt, nt + 1) * SAMPLE_STEP_PX  # (T,)
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
    fixed, dfixed = np.zeros(y.shape), np.zeros(y.shape + (blur.size,))
    near = []
    for k in range(1, NEIGHBOURS + 1):
        for j in (rows - k) % E, (rows + k) % E:
            den = _cross(e, u_all[j])  # (K,): the profile's direction against edge j's
            tk = _cross(foot_all[j][:, None, :] - x, u_all[j][:, None, :]) / np.where(np.abs(den) > 1e-6, den, 1e-6)[:, None]
            g = np.broadcast_to(np.maximum(np.abs(den), 0.2)[:, None], tk.shape)
            # edge j's own blur, across its own normal: the profile's direction turned by the
            # angle between the two edges (the lens map's shear over it neglected)
            dphi = np.arctan2(_cross(u, u_all[j]), np.sum(u * u_all[j], -1))[:, None]
            c2, s2 = np.cos(2 * dphi), np.sin(2 * dphi)
            basis_k = np.stack([basis[..., 0], basis[..., 1] * c2 - basis[..., 2] * s2,
                                basis[..., 2] * c2 + basis[..., 1] * s2], -1)
            sd_k, jac_k = _blur_model(blur, basis_k)
            sig_k = sd_k * scale
            free = (np.abs(tk) < half + FREE_SIGMAS * sig_k) & (np.abs(den) > 0.2)[:, None]
            sk = np.broadcast_to(sign[j][:, None], tk.shape)
            if free.any():
                near.append((tk, g, sk, free, basis_k))
            held = ~(free | (np.abs(den) <= 0.2)[:, None])
            zk = (tau - tk[..., None]) * g[..., None] / sig_k[..., None]
            fixed += np.where(held[..., None], sk[..., None] * _phi(zk), 0.0)
            if fit_blur:  # the held steps' derivative in the blur's parameters
                dfixed -= np.where(held[..., None, None], (sk[..., None] * _pdf(zk) * zk / sd_k[..., None])[..., None]
                                   * jac_k[..., None, :], 0.0)
    t, c, info, ok, blur, c_var = _solve_stations(y, tau, (fixed, dfixed), near,
                                                  np.broadcast_to(sign[rows, None], s.shape), (blur, basis, scale),
                                                  search, inside if fit_blur else None)
    fit = _lines_from_stations(foot, u, e, s, t, c, info, inside & ok, sign[rows], END_WINDOWS * half)
    return fit, blur, _step_strength(c, c_var, inside & ok)


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
    """The Gauss-Newton step of the blur's Q parameters shared by all stations, each
    station's own parameters projected out (its normal equations N (E, S, P, P) and
    right-hand side rhs (E, S, P), its model's columns A (E, S, T, P), residuals r (E, S, T),
    the blur's columns col (E, S, T, Q)), summed over the stations `use` (E, S): the Schur
    complement of the joint normal equations. Returns the step d (Q,) and the stations' own
    steps with it (E, S, P), N^-1 (rhs - A^T col d). Stations whose residuals are far above
    the typical (clutter) are left out of d."""
    Q = col.shape[-1]
    b = np.swapaxes(A, -1, -2) @ col  # (E, S, P, Q)
    X = np.linalg.solve(N, np.concatenate([rhs[..., None], b], -1))  # one factorisation for all
    Nrhs, Nb = X[..., 0], X[..., 1:]
    rr = np.sqrt(np.mean(r * r, -1))
    if use.any():
        use = use & (rr <= _CLUTTER * np.median(rr[use]))
    w = use[..., None, None]
    m = np.sum(np.where(w, np.swapaxes(col, -1, -2) @ col - np.swapaxes(b, -1, -2) @ Nb, 0.0), (0, 1))
    g = np.sum(np.where(use[..., None], np.einsum("estq,est->esq", col, r) - np.einsum("espq,esp->esq", Nb, rhs),
                        0.0), (0, 1))
    if use.sum() < _MIN_BLUR_STATIONS or not m[0, 0] > 0:
        return np.zeros(Q), Nrhs
    # the direction's terms weakly held at 0: a few edges all one way do not tell them from q0
    m = m + np.diag(np.r_[0.0, np.full(Q - 1, _DIR_RIDGE * m[0, 0])])
    d = np.linalg.solve(m, g)
    return d, Nrhs - Nb @ d


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
    theta, basis, scale = blur
    theta0 = theta
    for it in range(_ITERATIONS + 1):
        a, b, c, t = (p[..., i] for i in range(4))
        sd, jac = _blur_model(theta, basis)
        sig = (sd * scale)[..., None]
        z = (tau - t[..., None]) / sig
        bracket = fixed[0] + fixed[1] @ (theta - theta0) + sgn[..., None] * _phi(z)
        # the bracket's derivative in the blur's parameters (E, S, T, Q)
        dsig = fixed[1] - (sgn[..., None] * _pdf(z) * z / sd[..., None])[..., None] * jac[..., None, :]
        cols = [np.ones_like(y), tt, None, -c[..., None] * sgn[..., None] * _pdf(z) / sig]
        for i, (tk, g, sk, free, basis_k) in enumerate(near):
            # evaluated only where the neighbour is free (elsewhere its step and column are 0):
            # most of a dense star's stations have few free neighbours; its blur its own
            sd_k, jac_k = _blur_model(theta, basis_k[free])
            sf = (sd_k * scale[free])[:, None]
            zk = (tau - tk[free][:, None] - p[..., 4 + i][free][:, None]) * g[free][:, None] / sf
            step_k, col_k = np.zeros(y.shape), np.zeros(y.shape)
            step_k[free] = sk[free][:, None] * _phi(zk)
            col_k[free] = -c[free][:, None] * sk[free][:, None] * _pdf(zk) * g[free][:, None] / sf
            if fit_blur is not None:
                dsig[free] -= (sk[free][:, None] * _pdf(zk) * zk / sd_k[:, None])[..., None] * jac_k[:, None, :]
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
            d, step = _blur_step(A, N, r, rhs, c[..., None, None] * dsig, fit_blur)
            theta = _blur_update(theta, d)
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
    return t, c, info, ok, theta, Ni[..., 2, 2]


def _blur_update(theta, d):
    """The blur's parameters (`_blur_model`) after the Gauss-Newton step d, bounded (a far
    start): the sd by `_BLUR_STEP` of itself, the variances by twice that of the mean one,
    and no direction's variance below a tenth of the mean."""
    if theta.size == 1:
        return theta + np.clip(d, -_BLUR_STEP * theta, _BLUR_STEP * theta)
    lim = 2.0 * _BLUR_STEP * theta[0]
    d = d * min(1.0, lim / max(abs(d[0]), np.hypot(d[1], d[2]), 1e-300))
    q = theta + d
    r = np.hypot(q[1], q[2])
    if r > 0.9 * q[0]:
        q[1:] *= 0.9 * q[0] / r
    return q


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
