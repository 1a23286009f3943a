"""The printed board's own corner errors: each corner off its nominal place, the same in every view.

A printed or machined board is not its file: each corner sits off the nominal grid by a few
hundredths of a millimetre (printer dots, paper stretch, the cut of a marker). Unlike the
warp (`bundle`: two smooth parabolas) these offsets have no shape; unlike the corner
detector's noise they repeat in every view of the board. The model gives each corner an
offset ``e_j`` in the board's plane, independent between corners and axes,::

    e_j ~ N(0, diag(var_x, var_y))      [board unit^2]

shared by all views, so it does not average out over views as the detector's noise does,
and two halves of the views see the same offsets.

`estimate` measures (var_x, var_y) from all views: each residual is carried into the board's
plane (``e = A^-1 r``, A = d pixel / d board (x, y) at the corner), and for every corner the
products of its board-plane residuals in two different views are averaged (their
expectation is the offset's variance: the detector's errors of two views are independent),
each residual weighted by its inverse variance under the corner-noise model. The sigma is a
jackknife over groups of corners. An axis's variance is kept when it exceeds twice its
sigma.

`gains` gives, per view, what the offsets do to a weighted least-squares estimate: its
Schur block and d (normal equations' right side) / d offsets; `intrinsic_gain` sums them
over a subset of views into d intrinsics / d offsets (P, 2 J), linearised at one solution.
`calibrate` adds ``G diag(var) G^T`` to the intrinsics' covariance, and takes the offsets'
share out of each view's white level there (`bundle.covariance`'s ``shared``: the residuals
show them as each view's own white noise; counted twice, simulated halves came out at
chi-square per dof 0.75); the two-halves check (`validation.calibration_checks`) adds each
half's own term and their covariance ``G_a diag(var) G_b^T``: the difference of two halves
holds only ``(G_a - G_b) diag(var) (G_a - G_b)^T``.

Example
-------
>>> import numpy as np
>>> rng = np.random.default_rng(0)
>>> offsets = rng.normal(0, 0.05, (40, 2))
>>> views = [(np.arange(40), offsets + rng.normal(0, 0.02, (40, 2)), np.full((40, 2), 0.02 ** 2))
...          for _ in range(12)]
>>> est = estimate(views, 40)
>>> bool(np.all(np.abs(np.sqrt(est.variance) - 0.05) < 0.015)), est.corners
(True, 40)
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["PrintErrors", "NONE", "estimate", "board_residuals", "gains", "intrinsic_gain", "covariance_term",
           "fit_print_errors", "view_gains", "projected"]

# an axis's variance is kept when it exceeds this many of its sigmas (a one-sided 2.3 % test)
_KEEP_Z = 2.0
# the jackknife's groups of corners
_JACKKNIFE_GROUPS = 20
# a view's pose parameters
_POSE_DOF = 6


@dataclass(frozen=True)
class PrintErrors:
    """The printed board's corner offsets: variance (2,) per board axis [board unit^2] (zero
    where not kept), its jackknife sigma, the variance measured before the keep test, and
    the corners seen in two or more views."""

    variance: tuple = (0.0, 0.0)
    variance_std: tuple = (0.0, 0.0)
    measured: tuple = (0.0, 0.0)
    corners: int = 0

    @property
    def kept(self):
        """Whether any axis's variance is in the model."""
        return bool(any(v > 0 for v in self.variance))

    def to_dict(self):
        """calib.json's ``board_corners`` record (docs/formats.md)."""
        return {"sigma": [math.sqrt(v) for v in self.variance], "variance": list(self.variance),
                "variance_std": list(self.variance_std), "measured_variance": list(self.measured),
                "corners": int(self.corners), "kept": self.kept}


#: No corner offsets in the model.
NONE = PrintErrors()


def board_residuals(residuals, A, variance):
    """A view's residuals carried into the board's plane: (e (K, 2) [board unit], their
    variance per board axis (K, 2)) from the pixel residuals (K, 2) (observed - projected),
    A (K, 2, 2) = d pixel / d board (x, y) and the corners' white variance per image axis
    (K,) [px^2].

    >>> e, v = board_residuals(np.array([[2.0, 1.0]]), np.array([[[10.0, 0], [0, 5.0]]]), np.array([1.0]))
    >>> e.round(6).tolist(), v.round(6).tolist()
    ([[0.2, 0.2]], [[0.01, 0.04]])
    """
    Ai = np.linalg.inv(np.asarray(A, float))
    e = np.einsum("kij,kj->ki", Ai, np.asarray(residuals, float))
    return e, np.asarray(variance, float)[:, None] * np.sum(Ai * Ai, -1)


def estimate(views, n_corners, seed=0):
    """The offsets' variance from views given as (corner ids (K,), board-plane residuals
    (K, 2) [board unit], their variances (K, 2)) (`board_residuals`); n_corners : the
    board's corner count. Returns `PrintErrors` (the module's docstring)."""
    S, Q, W, W2 = (np.zeros((int(n_corners), 2)) for _ in range(4))
    for ids, e, v in views:
        w = 1.0 / np.asarray(v, float)
        ids = np.asarray(ids, int)
        np.add.at(S, ids, w * e)
        np.add.at(Q, ids, (w * e) ** 2)
        np.add.at(W, ids, w)
        np.add.at(W2, ids, w * w)
    # per corner: the sum over ordered pairs of different views of w_v w_u e_v e_u, and of w_v w_u
    num, den = S * S - Q, W * W - W2
    seen = np.flatnonzero(den[:, 0] > 0)
    if seen.size < 2:
        return PrintErrors(corners=int(seen.size))
    est = num[seen].sum(0) / den[seen].sum(0)
    groups = np.array_split(np.random.default_rng(seed).permutation(seen), min(_JACKKNIFE_GROUPS, seen.size))
    reps = np.array([(num[seen].sum(0) - num[g].sum(0)) / (den[seen].sum(0) - den[g].sum(0)) for g in groups])
    n = len(groups)
    se = np.sqrt((n - 1) / n * np.sum((reps - reps.mean(0)) ** 2, 0))
    kept = np.where(est > _KEEP_Z * se, est, 0.0)
    return PrintErrors(tuple(float(x) for x in kept), tuple(float(x) for x in se), tuple(float(x) for x in est),
                       int(seen.size))


def gains(Jg, Jp, A, ids, n_corners, w=None):
    """One view's part of d estimate / d offsets: (its Schur block Jg^T P Jg (G, G), d (the
    normal equations' right side) / d offsets (G, 2 n_corners)), from the Jacobians of the
    predictions in the global parameters Jg (2K, G) and in the pose Jp (2K, 6), A (K, 2, 2)
    = d pixel / d board (x, y), the corners' ids (K,) and weights w (K,) (None: 1). The pose
    is projected out as in `bundle.covariance`."""
    K = A.shape[0]
    S, PJw = projected(Jg, Jp, w)
    # the residual moves by A e: the right side by PJ^T (sw A e), corner by corner
    h = np.einsum("kag,kab->gkb", PJw.reshape(K, 2, -1), np.asarray(A, float))
    H = np.zeros((Jg.shape[1], int(n_corners), 2))
    np.add.at(H, (slice(None), np.asarray(ids, int)), h)
    return S, H.reshape(Jg.shape[1], -1)


def projected(Jg, Jp, w=None):
    """(the view's Schur block Jg^T P Jg (G, G), d (the normal equations' right side) / d
    (the corners' pixel errors) transposed (2K, G)) of a weighted least-squares fit with
    the pose projected out: Jg (2K, G), Jp (2K, 6) the predictions' Jacobians, w (K,) the
    corners' weights (None: 1)."""
    K2 = Jg.shape[0]
    sw = np.ones(K2) if w is None else np.repeat(np.sqrt(np.asarray(w, float)), 2)
    Jg, Jp = Jg * sw[:, None], Jp * sw[:, None]
    PJ = Jg - Jp @ (np.linalg.pinv(Jp.T @ Jp) @ (Jp.T @ Jg))
    return Jg.T @ PJ, PJ * sw[:, None]


def intrinsic_gain(parts, subset, T, prior=None):
    """d (full intrinsics, warp) / d offsets ((P + W), 2 J) of the fit to the views `subset`,
    from `gains`'s (S_v, H_v) per view; T (P, F): `Layout.transform` (the free intrinsics
    first in the global parameters, the warp's W after them); prior (F, F): a splined
    model's penalty in the normal equations (`bundle.penalty_normal`), None: none."""
    S = sum(parts[j][0] for j in subset)
    H = sum(parts[j][1] for j in subset)
    if prior is not None:
        S = S.copy()
        S[:prior.shape[0], :prior.shape[0]] += prior
    Gg = np.linalg.solve(S, H)
    F = T.shape[1]
    return np.vstack([T @ Gg[:F], Gg[F:]])


def covariance_term(Ga, Gb, errors):
    """Ga diag(var) Gb^T: the covariance the offsets give two estimates with gains Ga, Gb
    (P, 2 J) (`intrinsic_gain`)."""
    var = np.tile(np.asarray(errors.variance, float), Ga.shape[1] // 2)
    return (Ga * var) @ Gb.T


def _white(noise, img, A, theta, sigma_w):
    """(K,) each corner's white variance per image axis [px^2] under the corner-noise model."""
    from pencilcal.toolkit.board.corner_noise import variance_factor

    if noise is None:
        return np.full(img.shape[0], float(sigma_w) ** 2)
    scale = np.sqrt(np.abs(np.linalg.det(A)))
    return float(sigma_w) ** 2 * variance_factor(noise, img, scale, theta[2:4])


def fit_print_errors(layout, solution, objs, imgs, bases, ids, n_corners, sigma_w, noise=None):
    """`estimate` on a calibration: the views' residuals at `solution` (`bundle.Solution`),
    each corner's white variance from the views' levels sigma_w (V,) [px] and the
    corner-noise model's shape (`noise`, None: one level per view); ids : per view the
    corners' ids (K_v,). Returns (PrintErrors, the views' `bundle.view_jacobians`, per view
    each corner's white variance (K_v,) [px^2])."""
    from pencilcal.toolkit.board.bundle import view_jacobians

    jac = view_jacobians(layout, solution, objs, imgs, bases if layout.warp else None)
    white = [_white(noise, np.asarray(img, float), A, solution.theta, s)
             for (_, _, _, A), img, s in zip(jac, imgs, sigma_w)]
    views = []
    for (r, _, _, A), i, w in zip(jac, ids, white):
        e, v = board_residuals(r, A, w)
        # each view's pose absorbs 6 of its 2K residual dimensions: the offsets' share of a
        # residual is (1 - 6 / 2K) of theirs on average (the leverage); the Monte Carlo of
        # tests/toolkit/board/test_print_errors.py measured the variance 6 % low without this
        views.append((i, e / (1.0 - _POSE_DOF / max(r.size, _POSE_DOF + 1)), v))
    return estimate(views, n_corners), jac, white


def view_gains(jac, ids, n_corners, weights=None):
    """`gains` of every view from `bundle.view_jacobians`'s records, the corners' ids and the
    fit's weights (per view (K_v,), or None)."""
    weights = [None] * len(jac) if weights is None else weights
    return [gains(Jg, Jp, A, i, n_corners, w) for (_, Jg, Jp, A), i, w in zip(jac, ids, weights)]
