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

Measured (docs/method.md): on the da Vinci frames c = 0.2-0.25 at l = 200-210 px, left and
right alike.

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
           "restricted_nll", "white_variance"]

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
        REML log-likelihood of the fit minus that of white errors (evidence; 0 when given).
    """

    ratio: float
    length_px: float
    views: int = 0
    corners: int = 0
    log_likelihood_gain: float = 0.0

    def __post_init__(self):
        if not (math.isfinite(self.ratio) and self.ratio >= 0):
            raise InputError(f"corner noise ratio must be a finite number >= 0, got {self.ratio!r}")
        if not (math.isfinite(self.length_px) and self.length_px > 0):
            raise InputError(f"corner noise length must be a positive number of pixels, got {self.length_px!r}")

    def to_dict(self):
        """The record of the camera file's statistics and the calibration report."""
        return {"kernel": _KERNEL, "ratio": float(self.ratio), "length_px": float(self.length_px),
                "views": int(self.views), "corners": int(self.corners),
                "log_likelihood_gain": float(self.log_likelihood_gain)}

    @classmethod
    def from_dict(cls, d, source="camera"):
        """From `to_dict`'s record; InputError naming `source` for anything else."""
        if not isinstance(d, dict) or d.get("kernel", _KERNEL) != _KERNEL:
            raise InputError(f"{source}: 'corner_noise' must be an object with kernel {_KERNEL!r}")
        try:
            return cls(float(d["ratio"]), float(d["length_px"]), int(d.get("views", 0)), int(d.get("corners", 0)),
                       float(d.get("log_likelihood_gain", 0.0)))
        except (KeyError, TypeError, ValueError):
            raise InputError(f"{source}: 'corner_noise' needs numbers 'ratio' and 'length_px'") from None


#: White corner errors (no correlated part).
WHITE = CornerNoise(0.0, 1.0)


@dataclass(frozen=True, eq=False)
class CornerView:
    """One view's data for the fit: raw pixels u (K, 2) [px], residuals r (K, 2) [px] and
    the Jacobian J (2K, P) of the residuals (rows u, v per corner) in the parameters the
    view's fit estimated (its pose)."""

    points: np.ndarray
    residuals: np.ndarray
    jacobian: np.ndarray


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
    return CornerView(view.points[keep], view.residuals[keep], view.jacobian[rows])


def fit_corner_noise(views, image_size):
    """Fit the correlated corner-error model to the residuals of many views (REML).

    Parameters
    ----------
    views : sequence of CornerView
        Each view's raw corners, residuals and Jacobian of its own parameters (its pose);
        views with fewer than 8 corners are left out, and of a view with more than 128
        only 128, spread evenly over its corner list, enter (the restricted likelihood of the
        subset is exact for it; the corners counted are those used).
    image_size : (width, height)
        [px]; the lengths searched are 0.01-2 times the larger side.

    Returns
    -------
    CornerNoise
        The (ratio, length) of highest restricted likelihood, with the views and corners
        used and the log-likelihood gain over white errors. Ratio 0 (white errors) when no
        view has enough corners or the gain is not significant at the 1 % level (twice the
        gain under chi-square(2): 4.6).
    """
    views = [_subset(v) for v in views if v.points.shape[0] >= _MIN_FIT_CORNERS]
    if not views:
        return WHITE
    side = float(max(image_size))
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
    x, _ = _golden(profile, a, b)
    best = min(cache, key=lambda k: cache[k][0])
    nll, ratio = cache[best]
    gain = white - nll
    if ratio <= 0 or gain < _MIN_GAIN:
        return CornerNoise(0.0, math.exp(best), len(views), corners, float(max(gain, 0.0)))
    return CornerNoise(float(ratio), float(math.exp(best)), len(views), corners, float(gain))


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
