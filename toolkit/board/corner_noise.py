"""Correlated corner errors: a per-view model fitted to the residuals, and what it does to a pose.

Detected corners are not independent on real frames: blur, compression and interlaced
fields move neighbouring corners together. The model here gives the corner errors of one
view, both image axes alike and independent of each other, the covariance::

    Cov(e_a, e_b) = sigma_w^2 (delta_ab + c exp(-|u_a - u_b|^2 / (2 l^2)))     per axis

with u the corners' raw pixels, ``sigma_w`` the white part (free per view), ``c`` the
correlated part relative to it and ``l`` its length [px] (one pair (c, l) for a camera).
A smooth common error moves the pose far more than white noise of the same size, yet the
pose absorbs most of it, so the residuals show only a little of it. The fit accounts for
that: it is restricted maximum likelihood (REML) of the residuals, i.e. the likelihood of
their part orthogonal to each view's pose Jacobian, with ``sigma_w`` profiled out per
view, on a grid of (c, l) refined by golden sections (`fit_corner_noise`).

A least-squares pose with Jacobian J then has the covariance (the sandwich)
``sigma_w^2 (J^T J)^-1 J^T S J (J^T J)^-1`` with ``S = (I + c k) (x) I_2``
(`correlated_covariance`), instead of ``sigma^2 (J^T J)^-1``.

The white level also varies within a view (heteroscedastic errors): a corner seen on
smaller or foreshortened squares, or nearer the image's edge, is noisier. Each corner's
white variance is ``sigma_w^2 d`` with::

    log d = -a log(s / s_view) + b rho^2

s the board's local scale at the corner [px per board unit] (the square root of the
determinant of d pixel / d board (x, y)), s_view its median over the view, rho the corner's
distance from the principal point over ``radius_px`` (half the image's diagonal). The
covariance is then ``sigma_w^2 D^1/2 (I + c k) D^1/2`` per axis, D = diag(d). The fit
alternates: (a, b) with white errors, (c, l) on the residuals whitened by D, (a, b) again
under (c, l), each by REML; (a, b) are kept only when they explain the residuals better
at the 1 % level, and carry their sigmas (the restricted likelihood's curvature).
`variance_factor` gives d, the weights of a weighted fit are ``1 / (sigma_w^2 d)``.

Measured (docs/method.md): on the da Vinci frames c = 0.2-0.25 at l = 200-210 px, left and
right alike; docs/calibration.md gives (a, b) on every shared set.

Example
-------
>>> import numpy as np
>>> rng = np.random.default_rng(0)
>>> u = rng.uniform(0, 400, (30, 2))
>>> J = np.c_[np.kron(np.ones((30, 1)), np.eye(2)), rng.normal(size=(60, 4))]
>>> noise = CornerNoise(ratio=0.5, length_px=100.0)
>>> cov, s = correlated_covariance(J, rng.normal(0, 0.3, (30, 2)), u, noise)
>>> cov.shape, bool(s > 0)
((6, 6), True)
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from pencilcal.toolkit.errors import InputError
from pencilcal.toolkit.geometry.quantiles import chi2_isf

__all__ = ["CornerNoise", "WHITE", "CornerView", "fit_corner_noise", "correlated_covariance", "kernel",
           "restricted_nll", "white_variance", "variance_factor", "corner_features"]

# views with fewer corners do not enter the fit (their residuals say little about the
# correlation and their white level is poorly known)
_MIN_FIT_CORNERS = 8
# the fit uses at most this many corners of a view, spread evenly over its corner list: the
# restricted likelihood of a subset is exact for that subset (its part orthogonal to the
# subset's Jacobian does not depend on the fit), and the eigen decompositions stay small
_MAX_FIT_CORNERS = 128
# the grid of the fit: lengths relative to the larger image side, ratios
_LENGTH_GRID = np.geomspace(0.01, 2.0, 8)
_LENGTH_GRID.flags.writeable = False
_RATIO_GRID = np.r_[0.0, np.geomspace(1e-3, 10.0, 81)]
_RATIO_GRID.flags.writeable = False
_GOLDEN_STEPS = 6
# the correlated part is kept only when it explains the residuals better than white errors
# at this level (likelihood ratio, chi-square with the model's two parameters): where it
# does not, the long lengths (a field the poses absorb whole) leave the ratio undetermined
_EVIDENCE_LEVEL = 0.01
_MIN_GAIN = 0.5 * chi2_isf(_EVIDENCE_LEVEL, 2)
_KERNEL = "squared_exponential"
# the heteroscedastic shape's search box (a: the power of the local scale, b: the growth
# towards the edge) and the step of the curvature that gives their sigmas
_SHAPE_BOUNDS = ((-6.0, 6.0), (-6.0, 6.0))
_SHAPE_STEP = 0.05
_SHAPE_ITERATIONS = 8


@dataclass(frozen=True)
class CornerNoise:
    """The correlated part of a camera's corner errors.

    ratio : float
        c, the correlated variance relative to the white one (0: white errors).
    length_px : float
        l, the correlation length [px] (squared-exponential kernel over raw pixels).
    views, corners : int
        What it was fitted on (0 when given).
    log_likelihood_gain : float
        REML log-likelihood of the correlated part minus that of white errors at the same
        heteroscedastic shape (evidence; 0 when given).
    scale_power, edge : float
        a and b of the heteroscedastic shape (the module's docstring): the white variance
        goes as (local scale / view median)^-a and as exp(b rho^2). 0, 0: one level per view.
    scale_power_std, edge_std : float
        Their sigmas (REML curvature; 0 when given or not fitted).
    radius_px : float
        rho's unit [px]: half the image's diagonal where fitted.
    shape_gain : float
        REML log-likelihood of the shape minus that of one level per view (evidence).
    """

    ratio: float
    length_px: float
    views: int = 0
    corners: int = 0
    log_likelihood_gain: float = 0.0
    scale_power: float = 0.0
    edge: float = 0.0
    scale_power_std: float = 0.0
    edge_std: float = 0.0
    radius_px: float = 1.0
    shape_gain: float = 0.0

    def __post_init__(self):
        if not (math.isfinite(self.ratio) and self.ratio >= 0):
            raise InputError(f"corner noise ratio must be a finite number >= 0, got {self.ratio!r}")
        if not (math.isfinite(self.length_px) and self.length_px > 0):
            raise InputError(f"corner noise length must be a positive number of pixels, got {self.length_px!r}")
        if not (math.isfinite(self.scale_power) and math.isfinite(self.edge)):
            raise InputError("corner noise scale_power and edge must be finite numbers")
        if not (math.isfinite(self.radius_px) and self.radius_px > 0):
            raise InputError(f"corner noise radius must be a positive number of pixels, got {self.radius_px!r}")

    @property
    def heteroscedastic(self):
        """Whether the white level varies within a view (a or b not 0)."""
        return bool(self.scale_power or self.edge)

    def to_dict(self):
        """The record of the camera file's statistics and the calibration report."""
        return {"kernel": _KERNEL, "ratio": float(self.ratio), "length_px": float(self.length_px),
                "views": int(self.views), "corners": int(self.corners),
                "log_likelihood_gain": float(self.log_likelihood_gain),
                "scale_power": float(self.scale_power), "scale_power_std": float(self.scale_power_std),
                "edge": float(self.edge), "edge_std": float(self.edge_std), "radius_px": float(self.radius_px),
                "shape_gain": float(self.shape_gain)}

    @classmethod
    def from_dict(cls, d, source="camera"):
        """From `to_dict`'s record; InputError naming `source` for anything else."""
        if not isinstance(d, dict) or d.get("kernel", _KERNEL) != _KERNEL:
            raise InputError(f"{source}: 'corner_noise' must be an object with kernel {_KERNEL!r}")
        try:
            return cls(float(d["ratio"]), float(d["length_px"]), int(d.get("views", 0)), int(d.get("corners", 0)),
                       float(d.get("log_likelihood_gain", 0.0)), float(d.get("scale_power", 0.0)),
                       float(d.get("edge", 0.0)), float(d.get("scale_power_std", 0.0)),
                       float(d.get("edge_std", 0.0)), float(d.get("radius_px", 1.0)),
                       float(d.get("shape_gain", 0.0)))
        except (KeyError, TypeError, ValueError):
            raise InputError(f"{source}: 'corner_noise' needs numbers 'ratio' and 'length_px'") from None


#: White corner errors (no correlated part).
WHITE = CornerNoise(0.0, 1.0)


@dataclass(frozen=True, eq=False)
class CornerView:
    """One view's data for the fit: raw pixels u (K, 2) [px], residuals r (K, 2) [px] and
    the Jacobian J (2K, P) of the residuals (rows u, v per corner) in the parameters the
    view's fit estimated (its pose); for the heteroscedastic shape also the board's local
    scale at each corner (K,) [px per board unit] and the principal point (2,) [px]."""

    points: np.ndarray
    residuals: np.ndarray
    jacobian: np.ndarray
    scale: np.ndarray | None = None
    centre: np.ndarray | None = None


def corner_features(points, scale, centre, radius_px):
    """(K, 2): log(scale / its median) and rho^2 (distance from `centre` over `radius_px`,
    squared) of one view's corners; points (K, 2) [px], scale (K,) [px per board unit]."""
    s = np.asarray(scale, float)
    u = (np.asarray(points, float) - np.asarray(centre, float)) / float(radius_px)
    return np.stack([np.log(s / np.median(s)), np.sum(u * u, -1)], -1)


def variance_factor(noise, points, scale, centre):
    """d (K,): each corner's white variance relative to its view's level under `noise`
    (ones for a model without a heteroscedastic shape).

    >>> n = CornerNoise(0.0, 1.0, scale_power=2.0, radius_px=100.0)
    >>> variance_factor(n, np.zeros((3, 2)), np.array([1.0, 2.0, 4.0]), np.zeros(2)).tolist()
    [4.0, 1.0, 0.25]
    """
    K = np.asarray(points).shape[0]
    if not noise.heteroscedastic or scale is None:
        return np.ones(K)
    f = corner_features(points, scale, centre, noise.radius_px)
    return np.exp(-noise.scale_power * f[:, 0] + noise.edge * f[:, 1])


def _whitened(view, d):
    """The view with residuals and Jacobian divided by sqrt(d) (its corners' relative
    variances): errors of one level per view, as the correlated model takes them."""
    g = 1.0 / np.sqrt(np.asarray(d, float))
    K = view.points.shape[0]
    J = (view.jacobian.reshape(K, 2, -1) * g[:, None, None]).reshape(2 * K, -1)
    return CornerView(view.points, np.asarray(view.residuals, float) * g[:, None], J, view.scale, view.centre)


def kernel(points, length_px):
    """(K, K) squared-exponential correlation exp(-|u_a - u_b|^2 / (2 l^2)) of points (K, 2) [px]."""
    return np.exp(-0.5 * _squared_distances(points) / float(length_px) ** 2)


def _squared_distances(points):
    u = np.asarray(points, float)
    u = u - u.mean(0)
    n = np.sum(u * u, -1)
    return np.maximum(n[:, None] + n[None, :] - 2.0 * (u @ u.T), 0.0)


class _Spectral:
    """One view at one length: the kernel's eigenbasis applied to residuals and Jacobian,
    reduced to per-eigenvector sums, so that the restricted likelihood is cheap for many
    ratios at once."""

    def __init__(self, view, length_px, d2=None, logdet_JtJ=None):
        d2 = _squared_distances(view.points) if d2 is None else d2
        lam, U = np.linalg.eigh(np.exp(-0.5 / float(length_px) ** 2 * d2))
        self.lam = np.clip(lam, 0.0, None)
        K = view.points.shape[0]
        P = view.jacobian.shape[1]
        r = U.T @ np.asarray(view.residuals, float).reshape(K, 2)                      # (K, 2)
        J = (U.T @ view.jacobian.reshape(K, 2 * P)).reshape(K, 2, P)                  # (K, 2, P)
        self.JJ = (J.transpose(0, 2, 1) @ J).reshape(K, P * P)
        self.Jr = (J.transpose(0, 2, 1) @ r[..., None])[..., 0]
        self.rr = np.sum(r * r, -1)
        self.P = P
        self.n = 2 * K - P
        self.logdet_JtJ = np.linalg.slogdet(view.jacobian.T @ view.jacobian)[1] if logdet_JtJ is None else logdet_JtJ

    def nll(self, ratios):
        """(nll (R,), sigma_w^2 (R,)) for ratios (R,): -log restricted likelihood (constants
        dropped) with sigma_w profiled."""
        c = np.atleast_1d(np.asarray(ratios, float))
        w = 1.0 / (1.0 + c[:, None] * self.lam[None, :])                              # (R, K)
        JtSJ = (w @ self.JJ).reshape(-1, self.P, self.P)
        JtSr = w @ self.Jr
        rSr = w @ self.rr
        q = rSr - np.einsum("rp,rp->r", JtSr, np.linalg.solve(JtSJ, JtSr[..., None])[..., 0])
        s2 = np.maximum(q, 1e-300) / self.n
        logdet_S = -2.0 * np.sum(np.log(w), -1)
        nll = 0.5 * (self.n * np.log(s2) + logdet_S + np.linalg.slogdet(JtSJ)[1] - self.logdet_JtJ)
        return nll, s2


def white_variance(view, noise, k=None):
    """sigma_w^2 [px^2 per axis] of one CornerView under `noise` (REML: the generalised
    least-squares residual of the view's Jacobian under the model's correlation, over
    2K - P degrees of freedom; what `fit_corner_noise` profiles). k : the view's
    `kernel` at the noise's length, when already at hand."""
    r = np.asarray(view.residuals, float).reshape(-1, 2)
    K = r.shape[0]
    J = view.jacobian.reshape(K, 2, -1)
    if noise.ratio > 0:
        k = kernel(view.points, noise.length_px) if k is None else k
        L = np.linalg.cholesky(np.eye(K) + noise.ratio * k)
        r = np.linalg.solve(L, r)
        J = np.linalg.solve(L, J.reshape(K, -1)).reshape(K, 2, -1)
    J = J.reshape(2 * K, -1)
    r = r.reshape(-1)
    q = r - J @ np.linalg.lstsq(J, r, rcond=None)[0]
    return float(q @ q) / (2 * K - J.shape[1])


def restricted_nll(views, noise):
    """Sum over views of the restricted negative log-likelihood of `noise` (constants dropped;
    sigma_w profiled per view). views: CornerView list."""
    return float(sum(_Spectral(v, noise.length_px).nll(noise.ratio)[0][0] for v in views))


def _best_ratio(spectra):
    """(nll, ratio): the best ratio for these views at one length (the grid's best, refined
    by a parabola through its neighbours in log ratio)."""
    tot = sum(s.nll(_RATIO_GRID)[0] for s in spectra)
    i = int(np.argmin(tot))
    if 1 < i < len(_RATIO_GRID) - 1:
        x = np.log(_RATIO_GRID[i - 1:i + 2])
        y = tot[i - 1:i + 2]
        den = (x[0] - x[1]) * (x[0] - x[2]) * (x[1] - x[2])
        a = (x[2] * (y[1] - y[0]) + x[1] * (y[0] - y[2]) + x[0] * (y[2] - y[1])) / den
        b = (x[2] ** 2 * (y[0] - y[1]) + x[1] ** 2 * (y[2] - y[0]) + x[0] ** 2 * (y[1] - y[2])) / den
        if a > 0:
            c = math.exp(min(max(-b / (2 * a), x[0]), x[2]))
            f = float(sum(s.nll(c)[0][0] for s in spectra))
            if f < tot[i]:
                return f, c
    return float(tot[i]), float(_RATIO_GRID[i])


def _golden(f, a, b, steps=_GOLDEN_STEPS):
    """(x, f(x)): golden-section minimum of f on [a, b]."""
    g = (math.sqrt(5.0) - 1.0) / 2.0
    c, d = b - g * (b - a), a + g * (b - a)
    fc, fd = f(c), f(d)
    for _ in range(steps):
        if fc < fd:
            b, d, fd = d, c, fc
            c = b - g * (b - a)
            fc = f(c)
        else:
            a, c, fc = c, d, fd
            d = a + g * (b - a)
            fd = f(d)
    return (c, fc) if fc < fd else (d, fd)


def _subset(view):
    """The view with at most `_MAX_FIT_CORNERS` corners, evenly spread over its list."""
    K = view.points.shape[0]
    if K <= _MAX_FIT_CORNERS:
        return view
    keep = np.unique(np.round(np.linspace(0, K - 1, _MAX_FIT_CORNERS)).astype(int))
    rows = np.stack([2 * keep, 2 * keep + 1], 1).ravel()
    return CornerView(view.points[keep], view.residuals[keep], view.jacobian[rows],
                      None if view.scale is None else np.asarray(view.scale)[keep], view.centre)


def _fit_correlation(views, side):
    """(ratio, length [px], views, corners, gain) of the correlated part on views whose
    residuals have one level per view (REML; the module's docstring)."""
    corners = int(sum(v.points.shape[0] for v in views))
    white = float(sum(_Spectral(v, side).nll(0.0)[0][0] for v in views))
    cache = {}
    d2 = [_squared_distances(v.points) for v in views]
    logdets = [np.linalg.slogdet(v.jacobian.T @ v.jacobian)[1] for v in views]

    def profile(log_l):
        if log_l not in cache:
            spectra = [_Spectral(v, math.exp(log_l), d, ld) for v, d, ld in zip(views, d2, logdets)]
            cache[log_l] = _best_ratio(spectra)
        return cache[log_l][0]

    grid = [math.log(side * s) for s in _LENGTH_GRID]
    vals = [profile(g) for g in grid]
    i = int(np.argmin(vals))
    a, b = grid[max(i - 1, 0)], grid[min(i + 1, len(grid) - 1)]
    _golden(profile, a, b)
    best = min(cache, key=lambda k: cache[k][0])
    nll, ratio = cache[best]
    gain = white - nll
    if ratio <= 0 or gain < _MIN_GAIN:
        return 0.0, math.exp(best), len(views), corners, float(max(gain, 0.0))
    return float(ratio), float(math.exp(best)), len(views), corners, float(gain)


def _shape_nll(views, feats, whiten, ab):
    """The restricted negative log-likelihood (constants dropped, each view's level
    profiled) of the heteroscedastic shape ab = (a, b) under the correlation whose inverse
    Cholesky factors (K, K) are `whiten` (None: white)."""
    tot = 0.0
    for v, f, W in zip(views, feats, whiten):
        logd = -ab[0] * f[:, 0] + ab[1] * f[:, 1]
        g = np.exp(-0.5 * logd)
        K = v.points.shape[0]
        r = np.asarray(v.residuals, float) * g[:, None]
        J = v.jacobian.reshape(K, 2, -1) * g[:, None, None]
        P = J.shape[-1]
        if W is not None:
            r = W @ r
            J = (W @ J.reshape(K, 2 * P)).reshape(K, 2, P)
        J2, r2 = J.reshape(2 * K, P), r.reshape(-1)
        H = J2.T @ J2
        Jr = J2.T @ r2
        q = float(r2 @ r2 - Jr @ np.linalg.solve(H, Jr))
        n = 2 * K - P
        tot += 0.5 * (n * math.log(max(q, 1e-300) / n) + 2.0 * float(np.sum(logd)) + np.linalg.slogdet(H)[1])
    return tot


def _fit_shape(views, feats, whiten, start):
    """((a, b), nll, (sigma_a, sigma_b)): the shape of least `_shape_nll` in the search box,
    by damped Newton steps from `start` on central differences (the likelihood is smooth
    and nearly quadratic in (a, b): 2-4 steps), its sigmas from the curvature there."""
    lo = np.array([b[0] for b in _SHAPE_BOUNDS])
    hi = np.array([b[1] for b in _SHAPE_BOUNDS])

    def f(x):
        return _shape_nll(views, feats, whiten, np.clip(x, lo, hi))

    x = np.clip(np.asarray(start, float), lo, hi)
    fx = f(x)
    grad, H = _derivatives(f, x, fx)
    for _ in range(_SHAPE_ITERATIONS):
        w, V = np.linalg.eigh(H)
        # a Newton step on the curvature made positive (the step stays downhill)
        step = -V @ ((V.T @ grad) / np.maximum(np.abs(w), 1e-6))
        t = 1.0
        while t > 1e-3:
            x2 = np.clip(x + t * step, lo, hi)
            f2 = f(x2)
            if f2 < fx:
                break
            t *= 0.5
        else:
            break
        done = np.max(np.abs(x2 - x)) < 1e-3
        x, fx = x2, f2
        grad, H = _derivatives(f, x, fx)
        if done:
            break
    try:
        C = np.linalg.inv(H)
        sd = np.where(np.diag(C) > 0, np.sqrt(np.abs(np.diag(C))), np.inf)
    except np.linalg.LinAlgError:
        sd = np.full(2, np.inf)
    return x, float(fx), sd


def _derivatives(f, x, f0, h=_SHAPE_STEP):
    """(gradient (2,), Hessian (2, 2)) of f at x by central differences (f0 = f(x))."""
    e = np.eye(2) * h
    fp = [f(x + e[i]) for i in range(2)]
    fm = [f(x - e[i]) for i in range(2)]
    g = np.array([(fp[i] - fm[i]) / (2 * h) for i in range(2)])
    H = np.diag([(fp[i] - 2 * f0 + fm[i]) / h ** 2 for i in range(2)])
    H[0, 1] = H[1, 0] = (f(x + e[0] + e[1]) - f(x + e[0] - e[1]) - f(x - e[0] + e[1]) + f(x - e[0] - e[1])) / (4 * h * h)
    return g, H


def _whiteners(views, ratio, length_px):
    """Per view the inverse Cholesky factor of I + c k (None for white errors)."""
    if ratio <= 0:
        return [None] * len(views)
    out = []
    for v in views:
        L = np.linalg.cholesky(np.eye(v.points.shape[0]) + ratio * kernel(v.points, length_px))
        out.append(np.linalg.solve(L, np.eye(L.shape[0])))
    return out


def fit_corner_noise(views, image_size, heteroscedastic=True):
    """Fit the corner-error model to the residuals of many views (REML).

    Parameters
    ----------
    views : sequence of CornerView
        Each view's raw corners, residuals and Jacobian of its own parameters (its pose);
        views with fewer than 8 corners are left out, and of a view with more than 128
        only 128, spread evenly over its corner list, enter (the restricted likelihood of the
        subset is exact for it; the corners counted are those used).
    image_size : (width, height)
        [px]; the lengths searched are 0.01-2 times the larger side, rho's unit is half the
        diagonal.
    heteroscedastic : bool
        Also fit the white level's shape within a view (the module's docstring); needs
        every view's ``scale`` and ``centre``.

    Returns
    -------
    CornerNoise
        The (ratio, length) of highest restricted likelihood, with the views and corners
        used and the log-likelihood gain over white errors; (a, b) with their sigmas and
        gain over one level per view. Ratio 0 (white errors) when no view has enough
        corners or the gain is not significant at the 1 % level (twice the gain under
        chi-square(2): 4.6); a = b = 0 likewise.

    Example
    -------
    >>> fit_corner_noise([], (640, 480)) == WHITE
    True
    """
    views = [_subset(v) for v in views if v.points.shape[0] >= _MIN_FIT_CORNERS]
    if not views:
        return WHITE
    side = float(max(image_size))
    radius = 0.5 * math.hypot(float(image_size[0]), float(image_size[1]))
    if not heteroscedastic or any(v.scale is None or v.centre is None for v in views):
        return CornerNoise(*_fit_correlation(views, side), radius_px=radius)
    feats = [corner_features(v.points, v.scale, v.centre, radius) for v in views]
    # alternate: the shape under white errors, the correlation on the views whitened by
    # it, the shape again under that correlation
    ab, _, _ = _fit_shape(views, feats, [None] * len(views), (0.0, 0.0))
    corr = _fit_correlation([_whitened(v, np.exp(-ab[0] * f[:, 0] + ab[1] * f[:, 1])) for v, f in zip(views, feats)],
                            side)
    whiten = _whiteners(views, corr[0], corr[1])
    ab, nll, sd = _fit_shape(views, feats, whiten, ab)
    gain = _shape_nll(views, feats, whiten, (0.0, 0.0)) - nll
    if gain < _MIN_GAIN:
        return CornerNoise(*_fit_correlation(views, side), radius_px=radius, shape_gain=float(max(gain, 0.0)))
    return CornerNoise(*corr, scale_power=float(ab[0]), edge=float(ab[1]), scale_power_std=float(sd[0]),
                       edge_std=float(sd[1]), radius_px=radius, shape_gain=float(gain))


def correlated_covariance(J, residuals, points, noise):
    """The covariance of a least-squares estimate under correlated corner errors.

    Parameters
    ----------
    J : (2K, P) array_like
        Jacobian of the residuals (rows u, v per corner) at the optimum.
    residuals : (K, 2) array_like
        [px] at the optimum.
    points : (K, 2) array_like
        The corners' raw pixels [px].
    noise : CornerNoise

    Returns
    -------
    cov : (P, P) ndarray
        ``sigma_w^2 H^-1 J^T S J H^-1`` with ``H = J^T J`` and S the model's correlation
        (the sandwich: the estimate is the ordinary least-squares one).
    sigma_w : float
        The view's white corner noise [px] under the model (REML, 2K - P dof).
    """
    J = np.asarray(J, float)
    view = CornerView(np.asarray(points, float), np.asarray(residuals, float), J)
    s2 = white_variance(view, noise)
    K = view.points.shape[0]
    Hinv = np.linalg.inv(J.T @ J)
    k = kernel(view.points, noise.length_px)
    J3 = J.reshape(K, 2, -1)
    JtSJ = J.T @ J + noise.ratio * np.einsum("kbp,kl,lbq->pq", J3, k, J3)
    cov = s2 * Hinv @ JtSJ @ Hinv
    return 0.5 * (cov + cov.T), math.sqrt(s2)
