"""A shaft's silhouette edges located by a profile model of the lit cylinder (the limb).

An endoscope lights what it sees from (almost) its own viewpoint, so a shaft's surface
turns away from the light where it turns away from the camera: its radiance falls to
nothing at the silhouette. A step-edge locator (the gradient peak of the blurred profile,
`shaft.silhouette`, `shaft.axis.measure_edge_pair`) then finds each edge inside the true
limb, where the darkening shaft meets the background most steeply: by some tenths of a
pixel, a few per cent of a narrow band's width, and the depth from the band's width (the
shaft's 3-D axis, `pencil.cylinder.shaft_axis`) inherits it.

The model. Across an edge, at distance d [px] inside the silhouette of a band of half-width
W [px], the surface's normal makes the angle with the viewing ray whose cosine is
``c(d) = k sqrt(1 - (1 - d / W)^2)`` (a cylinder seen nearly orthographically across its
width: exact at the limb, where it matters; k the sine of the angle between the viewing ray
and the axis, as an oblique shaft never faces the camera squarely). With the light at the
camera the shaft's radiance is a function of c alone that vanishes at c = 0: Lambert's
diffuse light ``kd c`` plus a microfacet specular lobe ``ks S_a(c)`` (`specular_lobe`: GGX
normals of roughness a, Smith's shadowing; as the light and the view coincide the half
vector is the view, and the lobe rises from the limb as c / pi over c < a, a thin bright
rim on polished metal, then peaks along the axis), both times the light's fall-off E
(the middle of the shaft is nearer the light than its limb, `limb_design`). The fit sees
0.7 W inside the edge (kept within 4-12 px), short of the central highlight, saturated
samples left out. Where the face clips the step edge may follow the shading pixels inside
the silhouette, beyond the window's outer reach: a profile still moving at the window's
outer end is followed out until it levels off on the background and the window moved
there (`_window`).
Beside the edge the background is ``b0 + b1 (t - e)`` (a level and a slope), and the
optics' blur a Gaussian of sd sigma (pixel area and sampling included). The profile, on
linear light (the frame's encoding gamma undone, `edges.linearised`), is

    y(t) = G_sigma * [ (b0 + b1 (t - e)) H(t - e) + E (kd c + ks S_a(c)) H(e - t) ]

with t the offset along the edge's outward normal, e the limb, H the step.

A lamp beside the camera (`LATERAL`). An endoscope's light guides sit beside its lens, and a
demo's or a lab's lamp further off: the light's direction then has a component across the
shaft, and Lambert's ``n . l`` holds, besides ``c``, the normal's component along the edge's
outward normal times that sideways part: ``cos psi`` (psi the surface's angle from the limb,
``d = W (1 - cos psi)``), positive on the lamp's side (a lit limb) and negative on the other
(the limb dark before the silhouette). The model takes it as a fifth linear term
``E kl cos psi`` (kl of either sign), in a bin whose profile the light at the camera alone
does not explain (`limb_explains`; where it does, the extra term moved narrow bands' limbs
out by a few hundredths of a pixel on renders lit from the camera): with it a dark shaft over
a brighter background whose shading rises inwards from a floor is fitted where the camera's
light alone fitted it worse than a step (the step edge then lay 0.15-0.2 px outside the
silhouette on such bands). The term stays where an edge's windows clip: the saturated
samples are left out of every fit, and on glossy and polished shafts lit from the side over
a green screen that clips (`validation.band_width_grid`'s ``green`` background), taking the
term away where the band clipped returned 2 of 12 bands to their step edges (0.4 % narrow
where the limb read within 0.1 %) and read none better.

It is linear in (b0, b1, kd, ks, kl) and fitted by variable projection: scipy's least squares over (e,
log sigma, log a), the linear coefficients solved at each step, from two starts (the step
edge and `_STARTS_PX` beyond it: where the shaft's rim meets the background at one level
the step edge may be pixels inside). The limb e is where the band ends.

The shading must be light. Unbounded, a real black shaft's profile (flat and dark inside, the
camera's sharpening darkening it just inside its edge) took a negative diffuse term in 84 % of
its bins, a dip below zero at the limb that let the limb move outwards. The fit stays
unbounded (held non-negative in the fit itself, a matte shaft's limb 140 mm away over a dark
background moved and its fulcrum read 3.6 mm off, not under 1 mm), but it is judged as light:
by its own residual where its shading is light as it stands (`is_light`: kd not negative, the
sum not negative anywhere; a clipping matte face's tone curve takes a negative lobe), else by
its residual with kd and ks held non-negative at its limb (`shading_lstsq`).

Which edges it locates. The limb model is used on an edge unless a blurred step with a level
and a slope on either side (`step_design`, `fit_step_profile`) explains its profiles
significantly better (`limb_explains`: by more than one parameter's information): first on
the whole edge's mean profile (one fit: an edge that fails keeps its step edge at that
cost), then in more than half its bins. Only the bins the limb explains place the edge's
line (`EXPLAINED_ONLY`): a bin over a printed square or clutter beside the shaft, which a
step explains better, says nothing of the limb. On the shaded renders the limb explains its bins as
well or better; on the real phantom's black shaft, judged as light, the step explains most
bins better, and the band keeps its step edges and its step class.

Per edge (`refine_edge`): the profiles across the step fit's line at stations 1 px apart,
linearised, averaged over bins of `BIN_PX` along the edge (a bin's mean profile has the
noise down by the square root of its stations), the model fitted to each bin's, and the
edge line refitted through the bins' limbs (weighted least squares, a bin far off the
others' line left out: `_gross_bins`), with the a-posteriori
variances of its offset and slope (the scatter of the bins about the line, at least the
fits' own). `limb_edges` refines both edges of a shaft, each bin's W from the other edge.
Where the profiles do not pin the limb down (the diffuse and specular terms trading off
against the limb's place on a glossy shaft over a darker background, a window that holds
no background) the bins' limbs scatter about the line by tenths of a pixel to pixels, and
the edge is off by more: `width_spread` gives a share of that scatter as the band's own
width sd (`Shaft.width_sd_px`), where a well-pinned band's bins lie within a few
hundredths to a tenth of a pixel of their lines.

Ideal pixels throughout (s along the edge, t along its outward normal), as
`shaft.silhouette.EdgeLine`.

Example
-------
>>> import numpy as np
>>> t = np.arange(-8.0, 6.0, 0.25)
>>> y = limb_design(t, 0.3, 1.0, 12.0, 0.2) @ [40.0, 0.0, 20.0, 200.0]   # a limb at t = 0.3
>>> fit = fit_limb_profile(t, y, 12.0, 0.0, 1.2)
>>> round(fit.edge, 4), round(fit.sigma, 4), round(fit.roughness, 3)
(0.3, 1.0, 0.2)
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import NamedTuple

import numpy as np

from pencilcal.toolkit.camera.model import mean_focal
from pencilcal.toolkit.detect.edges import linearised
from pencilcal.toolkit.detect.working import raw_frame

__all__ = ["BIN_PX", "SPREAD_SHARE", "LimbFit", "specular_lobe", "limb_design", "fit_limb_profile", "shading_lstsq",
           "step_design", "fit_step_profile", "limb_explains", "is_light", "refine_edge", "limb_edges", "width_spread"]

#: Whether the shading has a lamp's sideways term (module docstring, `limb_design`'s lateral
#: column); chosen on `pencilcal demo`'s pivot frames (seed 1) and `band_width_grid` seed 3.
LATERAL = True
#: Whether only the bins the limb explains (`limb_explains`) place the edge's line.
EXPLAINED_ONLY = True
#: Stations averaged per bin along an edge [px].
BIN_PX = 12.0
_STEP_PX = 0.25  # profile sample spacing [px]
_OUT_PX = 7.0  # the profile's reach beyond the step edge [px]
_IN_FRAC, _IN_MIN, _IN_MAX = 0.7, 4.0, 12.0  # its reach inside: this fraction of W, within [min, max] px
_CELLS = 240  # cells of the shaft's shading across the profile
_ROUGH_RANGE = (0.03, 1.0)  # the specular lobe's roughness's bounds
_SIGMA_RANGE = (0.3, 6.0)  # the blur sd's bounds [px]
_MIN_BINS = 3
_STARTS_PX = (0.0, 1.5)  # the limb fit's starts from the step edge, outwards [px]
_REACH_PX = 32.0  # how far beyond the window a profile still moving at its outer end is followed [px]
_FLAT_FRAC = 0.03  # a profile still moves at its outer end where its slope there exceeds this share of its range per px
_BACK_PX = 1.5  # a moved window ends this much short of `_OUT_PX` beyond where its profile levels off [px]
_GROSS_PX, _GROSS_SPREAD = 3.0, 5.0  # a bin's limb this far [px] and this many times the others' scatter off their line is gross


class LimbFit(NamedTuple):
    """One profile's limb model fit (`fit_limb_profile`): edge [px] the limb e; sigma [px]
    the blur; roughness the specular lobe's; coef (4,) (b0, b1, kd, ks); rms the residual's RMS; edge_var [px^2] e's
    variance (the fit's, from its residual); ok whether the fit converged to a limb."""

    edge: float
    sigma: float
    roughness: float
    coef: np.ndarray
    rms: float
    edge_var: float
    ok: bool


def specular_lobe(c, roughness):
    """The specular radiance (...) of a microfacet surface (GGX normals, Smith's shadowing,
    Fresnel 1) lit and seen from one point, at incidence cosine c (...):
    ``D(c) G1(c)^2 / (4 c)``, ``D = a^2 / (pi (c^2 (a^2 - 1) + 1)^2)``,
    ``G1 = 2 c / (c + sqrt(a^2 + (1 - a^2) c^2))``, a the roughness. It rises from 0 at the
    limb as c / pi over c < a (a bright rim as thin as the surface is smooth) and peaks at
    c = 1 (the highlight along the axis)."""
    c = np.asarray(c, float)
    a2 = roughness * roughness
    D = a2 / (np.pi * (c * c * (a2 - 1.0) + 1.0) ** 2)
    G1 = 2 * c / np.maximum(c + np.sqrt(a2 + (1 - a2) * c * c), 1e-300)
    return np.where(c > 0, D * G1 * G1 / (4 * np.maximum(c, 1e-300)), 0.0)


def limb_design(t, edge, sigma, half_width, roughness, sin_view=1.0, q=0.0, lateral=False):
    """(T, 4) the blurred model's columns at the offsets t (T,) [px] for the limb edge [px],
    the blur sd sigma [px], the band's half-width [px] and the specular lobe's roughness:
    sin_view: the sine of the angle between the viewing ray and the axis (c is that times
    the cross-section's cosine); q: the sine of the band's half-angle at the camera (its
    half-width over the focal length), for the light's fall-off: the surface point at
    cross-section cosine c' lies at ``z = rho (sqrt(1 - q^2 + q^2 c'^2) - q c')`` from the
    camera (rho the axis's distance), nearer than the limb, and its irradiance is
    ``(z_limb / z)^2`` that of the limb. The profile is this times (b0, b1, kd, ks) (module
    docstring). The background's columns
    in closed form; the shaft's as sums over `_CELLS` cells even in the surface's angle psi
    from the limb (d = W (1 - cos psi), c = sin psi: fine where the shading changes fast),
    each cell's integral times the Gaussian at its centre (smooth in every parameter, as
    the least squares need). lateral: a fifth column, the diffuse light of a lamp off the
    camera's axis (`LATERAL`): (T, 5)."""
    from scipy.special import ndtr

    t = np.asarray(t, float)
    z = (t - edge) / sigma
    phi = np.exp(-0.5 * z * z) / np.sqrt(2 * np.pi)
    deep = min(float(edge - t.min() + 6.0 * sigma), 2.0 * half_width)
    psi_max = float(np.arccos(np.clip(1.0 - max(deep, 0.1) / half_width, -1.0, 1.0)))
    dpsi = psi_max / _CELLS
    psi = (np.arange(_CELLS) + 0.5) * dpsi
    cs = np.sin(psi)  # the cross-section's cosine
    dd = half_width * cs * dpsi  # each cell's depth [px]
    c = sin_view * cs
    fall = (1.0 - q * q) / (np.sqrt(1.0 - q * q + q * q * cs * cs) - q * cs) ** 2
    dd = dd * fall
    x = edge - half_width * (1.0 - np.cos(psi))
    g = np.exp(-0.5 * ((t[:, None] - x) / sigma) ** 2) / (np.sqrt(2 * np.pi) * sigma)
    cols = [ndtr(z), sigma * (z * ndtr(z) + phi), g @ (c * dd), g @ (specular_lobe(c, roughness) * dd)]
    if lateral:
        # a lamp beside the camera: the normal's component along the edge's outward normal
        # (cos psi) times the lamp's sideways direction adds to Lambert's n . l (either sign)
        cols.append(g @ (np.cos(psi) * dd))
    return np.column_stack(cols)


def fit_limb_profile(t, y, half_width, edge0, sigma0, roughness0=0.3, sin_view=1.0, q=0.0, use=None, lateral=False):
    """The limb model fitted to one profile (`LimbFit`): samples y (T,) [linear light] at
    offsets t (T,) [px] along the outward normal, the band's half-width [px], starts for
    the edge [px], the blur sd [px] and the specular lobe's roughness; sin_view and q as
    `limb_design`; use (T,) bool: the samples fitted (default all; a saturated one is not
    what the model predicts); lateral: with the lamp's sideways term (`limb_design`, coef
    then (5,))."""
    from scipy.optimize import least_squares

    t = np.asarray(t, float)
    y = np.asarray(y, float)
    use = np.ones(t.shape, bool) if use is None else np.asarray(use, bool)

    def solve(p):
        A = limb_design(t, p[0], np.exp(p[1]), half_width, np.exp(p[2]), sin_view, q, lateral)[use]
        coef, *_ = np.linalg.lstsq(A, y[use], rcond=None)
        return A, coef

    def res(p):
        A, coef = solve(p)
        return A @ coef - y[use]

    lo = [t[0] + 1.0, np.log(_SIGMA_RANGE[0]), np.log(_ROUGH_RANGE[0])]
    hi = [t[-1] - 1.0, np.log(_SIGMA_RANGE[1]), np.log(_ROUGH_RANGE[1])]
    x0 = np.clip([float(edge0), np.log(sigma0), np.log(roughness0)], np.add(lo, 1e-6), np.subtract(hi, 1e-6))
    r = least_squares(res, x0, bounds=(lo, hi), x_scale=[0.1, 0.1, 0.3], diff_step=1e-4)
    A, coef = solve(r.x)
    resid = A @ coef - y[use]
    s2 = float(resid @ resid) / max(resid.size - 3 - A.shape[1], 1)
    # the edge's variance with the parameters at a bound held there: a roughness at its
    # bound (a matte coat's lobe, a mirror's) leaves its column flat, and the full normal
    # matrix singular, which would reject a good fit
    free = np.asarray(r.active_mask) == 0
    try:
        var = float(np.linalg.inv(r.jac[:, free].T @ r.jac[:, free])[0, 0] * s2) if free[0] else np.inf
    except np.linalg.LinAlgError:
        var = np.inf
    # the edge and the blur must not sit at a bound (the roughness may: a mirror, a matte coat)
    ok = bool(r.success and np.all(np.isfinite(r.x)) and lo[1] + 1e-3 < r.x[1] < hi[1] - 1e-3
              and lo[0] + 0.5 < r.x[0] < hi[0] - 0.5 and np.isfinite(var))
    return LimbFit(float(r.x[0]), float(np.exp(r.x[1])), float(np.exp(r.x[2])), coef,
                   float(np.sqrt(np.mean(resid ** 2))), var, ok)


def shading_lstsq(A, y):
    """(4,) the least squares (b0, b1, kd, ks) of y (T,) on the columns A (T, 4) (or (5,),
    (b0, b1, kd, ks, kl), on A (T, 5) with the lamp's sideways term, `LATERAL`: kl of
    either sign), the shading's two (kd, ks) not negative: a surface reflects no negative light. Unbounded,
    the diffuse term of a dark shaft's profile turns negative (the camera's sharpening
    darkens the shaft just inside its edge, below its own level) and its dip below zero at
    the limb lets the limb move outwards. Exact: each of the four sets of the two held at
    zero, the best feasible."""
    best, out = np.inf, None
    rest = tuple(range(4, A.shape[1]))  # the lamp's sideways term (`LATERAL`), of either sign
    for free in ((0, 1, 2, 3), (0, 1, 2), (0, 1, 3), (0, 1)):
        free = free + rest
        c = np.zeros(A.shape[1])
        c[list(free)] = np.linalg.lstsq(A[:, free], y, rcond=None)[0]
        if c[2] < 0 or c[3] < 0:
            continue
        r = A @ c - y
        rss = float(r @ r)
        if rss < best:
            best, out = rss, c
        if len(free) == A.shape[1]:
            break  # the unbounded solution is feasible: it is the best
    return out


def is_light(A, coef):
    """Whether the shading of a limb fit is light as it stands: its diffuse term kd not
    negative and its radiance ``kd c + ks S_a(c)``, blurred, not negative at any of the
    samples; A (T, 4) the fit's columns (`limb_design`), coef (4,) its (b0, b1, kd, ks). A
    matte face under an endoscope's tone curve, compressed towards its clipping level, takes
    a negative specular lobe (it flattens the diffuse rise) and stays light; a black shaft's
    negative diffuse term (the camera's sharpening, `shading_lstsq`) is not, whatever its
    lobe makes of the sum: the limb moves out on that dip.

    >>> A = np.column_stack([np.ones(3), np.zeros(3), [0.1, 0.5, 0.9], [0.05, 0.2, 0.3]])
    >>> is_light(A, [10, 0, 400, -300]), is_light(A, [10, 0, -40, 300])
    (True, False)
    """
    coef = np.asarray(coef, float)
    return bool(coef[2] >= 0.0 and np.min(A[:, 2:] @ coef[2:]) >= 0.0)


_SATURATED = 250.0  # an encoded level at least this is clipped, not measured [grey levels]


def _profiles(image, camera, pts, n, t):
    """Grey profiles (M, T) float32 of the image (mean of its channels) at the points pts
    (M, 2) [ideal px] along the ideal unit normal n (2,) at offsets t (T,) [px]; whether
    each sample is saturated in any channel (M, T); whether each sample lies in the
    image (M, T)."""
    import cv2

    nx = np.full((1, 1), n[0])
    ny = np.full((1, 1), n[1])
    rx, ry, jx, jy = raw_frame(camera, pts[None, :, 0], pts[None, :, 1], nx, ny)
    X = (rx[0, :, None] + jx[0, :, None] * t).astype(np.float32)
    Y = (ry[0, :, None] + jy[0, :, None] * t).astype(np.float32)
    img = np.asarray(image, np.float32)
    top = img.max(-1) if img.ndim == 3 else img
    grey = img.mean(-1) if img.ndim == 3 else img
    H, W = grey.shape
    inside = (X >= 0) & (X <= W - 1) & (Y >= 0) & (Y <= H - 1)
    prof = cv2.remap(np.ascontiguousarray(grey), X, Y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    sat = cv2.remap(np.ascontiguousarray(top), X, Y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return prof, sat >= _SATURATED, inside


def refine_edge(image, camera, edge, geometry, gamma=1.0, sigma0=1.2):
    """One silhouette edge located by the limb model (module docstring).

    image: the raw frame (H, W) or (H, W, 3); camera: its `Camera` or None; edge: the
    step fit, a `shaft.silhouette.EdgeLine` (ideal px, n outward); geometry: a callable
    giving, at the edge's points (M, 2) [ideal px], the band's half-width [px] (M,), the
    sine of the angle between the viewing ray and the axis (M,) and the sine of the band's
    half-angle (M,) (`limb_design`); gamma: the frame's
    encoding gamma; sigma0: the blur's start [px]. Returns a new `EdgeLine` (the refitted
    line, its variances, s_lo, s_hi, count the bins used, frac, rms), or None where fewer
    than 3 bins give a limb or a step explains the profiles better (`limb_explains`: the
    whole edge's mean profile, or more than half its bins).
    """
    L = edge.s_hi - edge.s_lo
    nb = int(np.clip(np.floor(L / BIN_PX), 0, 64))
    if nb < _MIN_BINS:
        return None
    edges_s = np.linspace(edge.s_lo, edge.s_hi, nb + 1)
    s_st = np.arange(edge.s_lo, edge.s_hi + 1e-9, 1.0)
    pts = np.stack([edge.point_at(s) for s in s_st])
    W_st, k_st, q_st = (np.asarray(v, float) for v in geometry(pts))
    Wm = float(np.median(W_st))
    if not (np.isfinite(Wm) and Wm > 1.0):
        return None
    inner = float(np.clip(_IN_FRAC * Wm, _IN_MIN, _IN_MAX))
    t_all = np.arange(-inner, _OUT_PX + _REACH_PX + 1e-9, _STEP_PX)
    n_win = int(np.sum(t_all <= _OUT_PX + 1e-9))
    prof_all, sat_all, in_all = _profiles(image, camera, pts, edge.n, t_all)
    prof_all = linearised(prof_all, gamma)
    inside = in_all[:, :n_win].all(-1)
    clips = bool(sat_all[inside, :n_win].any())

    def bin_fit(sel):
        """(limb fit, whether a step explains the bin's mean profile no better) of the
        stations sel, or None."""
        t, y, use, starts = _window(t_all, prof_all[sel].mean(0), ~sat_all[sel].any(0) & in_all[sel].all(0), n_win,
                                    clips)
        if t is None or use.sum() < 0.6 * t.size:
            return None
        W, k, q = float(np.median(W_st[sel])), float(np.median(k_st[sel])), float(np.median(q_st[sel]))
        step = fit_step_profile(t, y, starts[0], sigma0, use)
        got = None
        # the light at the camera first; the lamp's sideways term only where that does not
        # explain the bin (on renders lit from the camera it moved narrow bands' limbs out)
        for lateral in (False, True) if LATERAL else (False,):
            # from the step edge and from beyond it (the step edge lies inside the limb; where
            # the shaft's rim meets the background at one level the step edge may be pixels in)
            fits = [f for f in (fit_limb_profile(t, y, W, e0, sigma0, sin_view=k, q=q, use=use, lateral=lateral)
                                for e0 in starts) if f.ok]
            if not fits:
                continue
            fit = min(fits, key=lambda f: f.rms)
            # judged as light: the fit as it stands where its shading is light at every sample,
            # else the shading at the fit's limb held non-negative term by term
            A = limb_design(t, fit.edge, fit.sigma, W, fit.roughness, k, q, lateral)[use]
            c = fit.coef if is_light(A, fit.coef) else shading_lstsq(A, y[use])
            r = A @ c - y[use]
            got = fit, step is None or limb_explains(float(r @ r), step[2], int(use.sum()))
            if got[1]:
                break
        return got

    # the whole edge's mean profile first: an edge whose profile a step explains as well
    # (no shading to model) keeps its step edge, at the cost of one fit (one that gives no
    # limb, a long edge's profile blurred by its band's convergence, says nothing)
    whole = bin_fit(inside) if inside.sum() >= 3 else None
    if whole is not None and not whole[1]:
        return None
    sb, tb, vb, chosen, fitted = [], [], [], 0, 0
    for k in range(nb):
        sel = inside & (s_st >= edges_s[k]) & (s_st < edges_s[k + 1] + (k == nb - 1))
        got = bin_fit(sel) if sel.sum() >= 3 else None
        if got is None:
            continue
        fit, better = got
        chosen += better
        fitted += 1
        if not better and EXPLAINED_ONLY:
            continue
        s_c = float(s_st[sel].mean())
        sb.append(s_c)
        tb.append(edge.tm + edge.b * (s_c - edge.sm) + fit.edge)
        vb.append(fit.edge_var)
    # the limb unless a step explains more than half the edge's bins better
    if len(sb) < _MIN_BINS or 2 * chosen < fitted:
        return None
    return _line_through(edge, np.array(sb), np.array(tb), np.array(vb), nb)


def _window(t_all, y_all, use_all, n_win, clips=True):
    """A bin's profile window: offsets t (T,) [px], its mean profile y (T,) [linear light],
    the samples fitted use (T,) and the fit's starts [px]; Nones where the profile holds no
    background within reach. t_all (N,), y_all (N,), use_all (N,): the profile sampled from
    the window's inner end out to `_REACH_PX` beyond its outer end (use: neither saturated
    nor off the image); n_win: the window's samples; clips: whether the edge's windows hold
    saturated samples (only then is a window moved: beside a face that does not clip, a
    window moved out reached into sloping backgrounds on the renders).

    Where the face clips under the exposure the step edge may follow the shading pixels
    inside the silhouette, and a window ending `_OUT_PX` beyond it holds no background: the
    model, its background free to slope, then fits the shading and puts a limb on the face.
    So a profile still moving at the window's outer end (saturated there, or over its last
    2 px sloping by more than `_FLAT_FRAC` of its range per px) is followed outwards until it
    levels off (past the last unmeasured sample), and the window moved out to end `_OUT_PX`
    less `_BACK_PX` beyond that."""
    t, y, use = t_all[:n_win], y_all[:n_win], use_all[:n_win]
    m = int(round(2.0 / _STEP_PX))
    span = float(np.ptp(y[use])) if use.sum() > m else 0.0
    thr = _FLAT_FRAC * span
    if not clips:
        return t, y, use, _STARTS_PX
    if use[-m:].all():
        slope = float(np.polyfit(t[-m:], y[-m:], 1)[0])
        if span <= 0 or abs(slope) <= thr:
            return t, y, use, _STARTS_PX
    # levelled off: past the window's end and the last saturated sample, the local slope
    # (over a 1 px box, its samples all measured) small for 1 px on end (a rim darker than
    # the background on either side turns without levelling: the background lies beyond)
    box = np.ones(4) / 4
    g = np.abs(np.gradient(np.convolve(y_all, box, mode="same"), _STEP_PX))
    whole = np.convolve(use_all.astype(float), box, mode="same") > 1 - 1e-9
    flat = (g <= thr) & whole
    run = np.convolve(flat.astype(float), np.ones(4), mode="full")[3:] > 4 - 1e-9  # flat[i:i + 4] all
    clipped = np.nonzero(~use_all)[0]
    clipped = clipped[clipped < t_all.size - 2]
    first = max(n_win, int(clipped.max()) + 1 if clipped.size else 0)
    level = np.nonzero(run & (np.arange(t_all.size) >= first))[0]
    if level.size == 0:
        return None, None, None, None
    stop = float(t_all[level[0]])
    if stop + 3.0 > t_all[-1]:
        return None, None, None, None
    shift = max(stop - _BACK_PX, 0.0)
    keep = (t_all >= t[0] + shift - 1e-9) & (t_all <= t[-1] + shift + 1e-9)
    # started from the window's shift and 1.5 and 3 px beyond it (starts 2.5 px further in,
    # where a blurred limb would lie, read worse on the renders the shift was chosen on)
    return t_all[keep], y_all[keep], use_all[keep], tuple(shift + e for e in _STARTS_PX + (3.0,))


def step_design(t, edge, sigma):
    """(T, 4) the columns of a blurred step at the offsets t (T,) [px]: the edge [px], the
    blur sd sigma [px]; the background beside it a level and a slope (b0, b1) as in
    `limb_design`, the shaft's side likewise (a0, a1), all blurred by the Gaussian."""
    from scipy.special import ndtr

    t = np.asarray(t, float)
    z = (t - edge) / sigma
    out = sigma * (z * ndtr(z) + np.exp(-0.5 * z * z) / np.sqrt(2 * np.pi))
    return np.column_stack([ndtr(z), out, ndtr(-z), (t - edge) - out])


def fit_step_profile(t, y, edge0, sigma0, use=None):
    """(edge [px], sigma [px], rss) of a blurred step with sloping levels on either side
    (`step_design`) fitted to one profile y (T,) at offsets t (T,) [px]; None where it does
    not converge inside the window."""
    from scipy.optimize import least_squares

    t = np.asarray(t, float)
    y = np.asarray(y, float)
    use = np.ones(t.shape, bool) if use is None else np.asarray(use, bool)

    def res(p):
        A = step_design(t[use], p[0], np.exp(p[1]))
        return A @ np.linalg.lstsq(A, y[use], rcond=None)[0] - y[use]

    lo = [t[0] + 1.0, np.log(_SIGMA_RANGE[0])]
    hi = [t[-1] - 1.0, np.log(_SIGMA_RANGE[1])]
    x0 = np.clip([float(edge0), np.log(sigma0)], np.add(lo, 1e-6), np.subtract(hi, 1e-6))
    r = least_squares(res, x0, bounds=(lo, hi), x_scale=[0.1, 0.1], diff_step=1e-4)
    if not (r.success and lo[0] + 0.5 < r.x[0] < hi[0] - 0.5):
        return None
    return float(r.x[0]), float(np.exp(r.x[1])), float(2 * r.cost)


def limb_explains(limb_rss, step_rss, n):
    """Whether a lit cylinder explains a profile of n samples as well as the blurred step or
    better: limb_rss the residual sum of squares of the limb model judged as light (its fit's
    own where its shading is light, `is_light`, else with the shading held non-negative,
    `shading_lstsq`), step_rss the step's (`fit_step_profile`).
    The limb model is what a shaft lit from the camera shows, so it is kept unless the step
    explains the profile better by more than one parameter's information, ``m log(limb_rss
    / step_rss) > log m`` over the profile's m pixels (its samples, 4 a pixel, are
    interpolated from the same pixels). Where both explain it alike (a dark metal shaft
    over tissue: the step's sloping inside mimics the shading) the limb places the edge."""
    m = max(n * _STEP_PX, 2.0)
    return bool(m * np.log(max(limb_rss, 1e-300) / max(step_rss, 1e-300)) <= np.log(m))


def _wls_line(s, t, w):
    """(sm, tm, b, residuals (B,)) of the weighted least squares line t = tm + b (s - sm)
    through (s, t) (B,) [px], weights w (B,)."""
    W = w.sum()
    sm = float(np.sum(w * s) / W)
    ds = s - sm
    Sss = max(float(np.sum(w * ds * ds)), 1e-12)
    tm = float(np.sum(w * t) / W)
    b = float(np.sum(w * ds * (t - tm)) / Sss)
    return sm, tm, b, t - tm - b * ds


def _gross_bins(s, t, v):
    """(B,) bool: the bins kept, a gross one left out at a time while at least `_MIN_BINS`
    stay. The worst bin (its limb furthest off the line through the others, relative to
    their scatter about it) is gross where that is more than `_GROSS_PX` and `_GROSS_SPREAD`
    times their RMS scatter: a window moved out beyond a clipping part that levels off on
    a textured or bright background puts one bin's limb pixels out, and with its small
    variance it would tilt the whole edge (a glossy shaft over a green drape: one bin 32 px
    out of 8, the edge 10 deg off)."""
    keep = np.ones(len(s), bool)
    while keep.sum() > _MIN_BINS:
        idx = np.nonzero(keep)[0]
        worst, score = -1, 0.0
        for i in idx:
            o = idx[idx != i]
            w = 1.0 / np.maximum(v[o], 1e-8)
            sm, tm, b, r = _wls_line(s[o], t[o], w)
            off = abs(t[i] - tm - b * (s[i] - sm))
            spread = float(np.sqrt(np.mean(r * r)))
            if off > max(_GROSS_PX, _GROSS_SPREAD * spread) and off / max(spread, 1e-3) > score:
                worst, score = i, off / max(spread, 1e-3)
        if worst < 0:
            break
        keep[worst] = False
    return keep


def _line_through(edge, s, t, v, nb):
    """The `EdgeLine` through the bins' limbs (s, t) (B,) [px] of variances v (B,) [px^2],
    weighted least squares, gross bins left out (`_gross_bins`), the variances a-posteriori
    (at least the fits' own)."""
    keep = _gross_bins(s, t, v)
    s, t, v = s[keep], t[keep], v[keep]
    w = 1.0 / np.maximum(v, 1e-8)
    W = w.sum()
    sm, tm, b, r = _wls_line(s, t, w)
    Sss = max(float(np.sum(w * (s - sm) ** 2)), 1e-12)
    chi2 = float(np.sum(w * r * r)) / max(len(s) - 2, 1)
    scale = max(chi2, 1.0)
    return replace(edge, sm=sm, tm=tm, b=b, var_t=scale / W, var_b=scale / Sss, s_lo=float(s.min()),
                   s_hi=float(s.max()), count=int(len(s)), frac=len(s) / nb, rms=float(np.sqrt(np.mean(r * r))))


def limb_edges(image, camera, K, e1, e2, gamma=1.0):
    """Both silhouette edges of a shaft (`shaft.silhouette.EdgeLine`, ideal px, normals
    outward) located by the limb model (`refine_edge`); None where either gives no limb.

    K (3, 3): the camera matrix of the ideal pixels (`shaft.work.axis_matrix`). Each edge's
    half-width W is half its distance to the other's line, the sine of the band's
    half-angle W / f (f the focal length), and the axis direction (for the angle between
    each viewing ray and the axis) the cross product of the two silhouette planes' normals
    ``K^T l``."""
    K = np.asarray(K, float)
    Kinv = np.linalg.inv(K)
    f = mean_focal(K)
    nrm = [K.T @ e.line() for e in (e1, e2)]
    d = np.cross(nrm[0], nrm[1])
    d = d / max(np.linalg.norm(d), 1e-300)
    out = []
    for e, other in ((e1, e2), (e2, e1)):
        lo = other.line()

        def geometry(p, lo=lo):
            v = np.column_stack([p, np.ones(len(p))]) @ Kinv.T
            v = v / np.linalg.norm(v, axis=1, keepdims=True)
            w = 0.5 * np.abs(p @ lo[:2] + lo[2])
            return w, np.linalg.norm(np.cross(v, d), axis=1), np.clip(w / f, 0.0, 0.9)

        got = refine_edge(image, camera, e, geometry, gamma)
        if got is None:
            return None
        out.append(got)
    return tuple(out)


#: The share of its bins' scatter that a limb edge's error is taken to be (`width_spread`),
#: chosen on endoscope-like renders (`validation.band_width_grid --realism endoscope`, seeds
#: 12 and 14 at 40-150 mm, 10-11 at 20 mm: 43 limb bands; 0, 0.25, 0.5, 1 gave 74, 77, 88,
#: 95 % within 1 sd of the band's sd and 88, 95, 95, 95 % within 3).
SPREAD_SHARE = 0.25


def width_spread(e1, e2):
    """The sd [px] of a band's width error that its two limb edges (`refine_edge`'s
    `EdgeLine`) show themselves: `SPREAD_SHARE` of the root sum of squares of each edge's
    bins' RMS scatter about its line (``rms``). A bin's limb where the profile pins it down
    lies on the line within a few hundredths of a pixel; where the model finds no single
    limb (a profile whose shading and rim trade off, a window that holds no background)
    the bins scatter by tenths of a pixel to pixels, and the edge's error grows with
    them."""
    return float(SPREAD_SHARE * np.hypot(e1.rms, e2.rms))
