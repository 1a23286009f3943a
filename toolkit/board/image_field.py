"""A correlated corner error fixed in the image: the same smooth error field in every view.

The corner-noise model (`corner_noise`) gives each view a smooth correlated error of its
own. On some corners (ChArUco corners refined to their point of symmetry, say) that smooth
part is not each view's own: two corners of *different* views at nearby image places err
alike as much as two corners of one view do, so it is one error field over the image that
every view sees (a lens or sensor effect the corner finder turns into a bias). Counted once
per view, as the per-view model does, it averages out over the views: the intrinsics'
sigmas come out too small against the truth, and the two halves of a calibration's views
(`validation.calibration_checks`), which share it, differ by less than their covariances
say.

The model: the corners' errors are each view's own part (white, with the per-view model's
shape, plus the per-view correlated part times ``1 - share``) and one field ``f(u)`` over
the raw pixels u, both image axes alike and independent::

    Cov(f(u_a), f(u_b)) = tau^2 exp(-|u_a - u_b|^2 / (2 l^2))      [px^2] per axis

with tau^2 [px^2] and l [px] the field's variance and length; its share of the per-view
correlated part (c, the per-view ratio, of each corner's white variance sigma_w^2 d) leaves
each view's own part.

`estimate` measures the field on the residuals: each residual in its view's white level and
shape, the mean product of two corners of *different* views (between) and of two corners of
*one* view (within), both at image distances of l/2 to l (l the per-view model's length);
their ratio is the share read off directly, clipped to [0, 1] (0 where ``within`` is not
above zero). Its sigma is a jackknife over the views. The field is kept only where two tests
of "no field" fail (each one-sided at about 2.3 %): ``between`` exceeds twice its jackknife
sigma, which needs no model of the views' own errors, and the score test of the field's
variance (below) exceeds 2, whose null distribution is simulated through the fit from the
per-view model. Corners whose smooth error is each view's own keep the per-view model as it
is. A field the fit absorbs within each view can leave ``within`` at zero or below while
``between`` is resolved (weak fields, about one in six at 0.12 px against 0.25 px white
noise): it is kept, at a share of 0 (on top of each view's own part).

`fit_image_field` then fits tau^2 and l to the between-view products at several distances
(up to 0.3 of the image), each product's expectation taken through the fit: the views'
poses and the intrinsics absorb part of a field fixed in the image (it moves the principal
point and the distortion as much as it bends the corners), so the products, and the
per-view ratio read from them, are short of the field's variance, the more so the weaker
the field. The residuals the fit leaves of an error e are ``e - J (J^T W J)^-1 J^T W e``
(all poses and the global parameters, linearised at the solution); a unit field at each
length of a grid (random Fourier features of the kernel) and the views' own errors under
the per-view model go through it; tau^2 is the least-squares scale of the field's
predicted products to the measured ones less the own errors' (which the shared global
parameters leave slightly anticorrelated between views), the length that of least misfit.
The score test of tau^2 = 0 weighs the bins' products by their covariance with no field
(64 draws of the views' own errors through the fit, on the same pairs), at the per-view
model's length. A fitted length at the longest tried (twice the per-view model's) is a
field the fit absorbs almost whole, whose variance the products do not determine: not kept.

`gains` gives each view's part of d estimate / d field, with the field sampled on cells of
l/4 (a corner takes its cell's value: the kernel moves by at most 1.6 % over half a cell's
diagonal); `covariance_term` is ``G_a K G_b^T tau^2`` over the cells, as the printed
board's offsets are carried (`print_errors`): the calibration's covariance gains ``G K
G^T tau^2``, two halves' difference only ``(G_a - G_b) K (G_a - G_b)^T tau^2``.

Example
-------
>>> import numpy as np
>>> rng = np.random.default_rng(0)
>>> pts = [rng.uniform(0, 400, (60, 2)) for _ in range(20)]
>>> grid = rng.uniform(0, 400, (400, 2))
>>> from pencilcal.toolkit.board.corner_noise import kernel
>>> L = np.linalg.cholesky(kernel(grid, 80.0) + 1e-9 * np.eye(400))
>>> f = L @ rng.normal(size=(400, 2))          # one field, fixed in the image
>>> near = [np.argmin(((grid[None] - p[:, None]) ** 2).sum(-1), 1) for p in pts]
>>> z = [f[i] + rng.normal(0, 1.0, (60, 2)) for i in near]
>>> round(estimate(pts, z, 80.0).share, 2)
1.0
>>> own = [L[i] @ rng.normal(size=(400, 2)) + rng.normal(0, 1.0, (60, 2)) for i in near]   # each view's own
>>> estimate(pts, own, 80.0).share
0.0
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from pencilcal.toolkit.geometry.neighbours import pairs_within

__all__ = ["ImageField", "NONE", "estimate", "fit_image_field", "gains", "view_gains", "covariance_term",
           "cell_grid"]

# the band of image distances the products are compared over, relative to the length
_BAND = (0.5, 1.0)
# the field is kept when the between-view product exceeds this many of its sigmas
_KEEP_Z = 2.0
# the jackknife's groups of views
_JACKKNIFE_GROUPS = 20
# the cells the field is sampled on, relative to its length
_CELL = 0.25
# the fit of the field's variance and length: the between-view products' distance bins
# (relative to the image's larger extent of corners), the lengths tried (relative to the
# per-view model's, which sees the same kernel within each view: a length far beyond it is
# one the fit absorbs almost whole, and a scale fitted there runs away: 24 times the true
# variance once in 24 simulated runs of a 0.12 px field, at 0.39 of the image), the random
# Fourier features of a unit field, the draws of the views' own errors, the pairs per bin
# predicted
_FIT_EDGES = (0.0, 0.02, 0.05, 0.1, 0.15, 0.2, 0.3)
_FIT_LENGTHS = tuple(np.geomspace(0.5, 2.0, 7))
_FEATURES = 64
_OWN_DRAWS = 16
# the draws of the views' own errors that the keep test's null distribution is read from
_NULL_DRAWS = 64
# the ridge on the simulated covariance of the bins' products (relative to its mean variance)
_NULL_RIDGE = 1e-3
_PREDICTED_PAIRS = 3000


@dataclass(frozen=True)
class ImageField:
    """The image-fixed part of the corners' correlated error: its share of the per-view
    correlated variance (0 where not kept), the share's jackknife sigma, the mean products
    between and within views it was measured from (in the corners' white levels), the
    field's variance tau^2 [px^2 per axis] and length [px]."""

    share: float = 0.0
    share_std: float = 0.0
    between: float = 0.0
    between_std: float = 0.0
    within: float = 0.0
    variance_px2: float = 0.0
    length_px: float = 0.0
    score: float = 0.0

    @property
    def kept(self):
        """Whether the field is in the model."""
        return self.variance_px2 > 0

    def to_dict(self):
        """calib.json's ``image_field`` record (docs/formats.md)."""
        return {"share": self.share, "share_std": self.share_std, "between": self.between,
                "between_std": self.between_std, "within": self.within, "sigma_px": math.sqrt(self.variance_px2),
                "length_px": self.length_px, "score": self.score, "kept": self.kept}


#: No image-fixed field in the model.
NONE = ImageField()


def estimate(points, z, length_px, seed=0):
    """The field's share from per view raw corners points (K_v, 2) [px] and residuals z
    (K_v, 2) in their white levels (residual / sqrt(sigma_w^2 d)), the per-view model's
    length [px]. Returns `ImageField` without its variance (the module's docstring)."""
    U = np.concatenate([np.asarray(p, float) for p in points])
    Z = np.concatenate([np.asarray(r, float) for r in z])
    V = np.concatenate([np.full(np.asarray(p).shape[0], j) for j, p in enumerate(points)])
    lo, hi = _BAND[0] * float(length_px), _BAND[1] * float(length_px)
    pr = pairs_within(U, hi)
    if not pr.size:
        return NONE
    d = np.linalg.norm(U[pr[:, 0]] - U[pr[:, 1]], axis=1)
    pr = pr[d >= lo]
    prod = np.sum(Z[pr[:, 0]] * Z[pr[:, 1]], 1) / 2.0          # both axes alike
    other = V[pr[:, 0]] != V[pr[:, 1]]
    if other.sum() < 2 or (~other).sum() < 2:
        return NONE
    n_views = len(points)
    groups = np.random.default_rng(seed).permutation(n_views) % min(_JACKKNIFE_GROUPS, n_views)
    ga, gb = groups[V[pr[:, 0]]], groups[V[pr[:, 1]]]
    G = int(groups.max()) + 1

    def sums(mask):
        # the total and, per group, what leaving that group's views out removes
        s, n = float(prod[mask].sum()), int(mask.sum())
        sg = np.bincount(ga[mask], prod[mask], G) + np.bincount(gb[mask], prod[mask], G)
        ng = np.bincount(ga[mask], minlength=G) + np.bincount(gb[mask], minlength=G)
        both = mask & (ga == gb)                                 # counted twice above
        sg -= np.bincount(ga[both], prod[both], G)
        ng -= np.bincount(ga[both], minlength=G)
        return s, n, sg, ng

    sb, nb, sbg, nbg = sums(other)
    sw, nw, swg, nwg = sums(~other)
    between, within = sb / nb, sw / nw
    jb = (sb - sbg) / np.maximum(nb - nbg, 1)
    jw = (sw - swg) / np.maximum(nw - nwg, 1)
    js = jb / np.where(jw > 0, jw, np.nan)
    f = (G - 1) / G
    b_std = math.sqrt(f * float(np.sum((jb - jb.mean()) ** 2)))
    s_std = math.sqrt(f * float(np.nansum((js - np.nanmean(js)) ** 2))) if np.any(np.isfinite(js)) else math.inf
    share = min(max(between / within, 0.0), 1.0) if within > 0 else 0.0
    if not between > _KEEP_Z * b_std:
        share = 0.0
    return ImageField(float(share), float(s_std), float(between), float(b_std), float(within), 0.0,
                      float(length_px))


def fit_image_field(noise, points, jac, white, weights=None, prior=None):
    """The field on a calibration: per view the raw corners (K_v, 2) [px], its
    `bundle.view_jacobians` record (residuals (K_v, 2) [px], Jg (2K_v, G), Jp (2K_v, 6), ...),
    each corner's white variance (K_v,) [px^2] and the fit's weights (K_v,) (None: 1) under
    the corner-noise model `noise` (`corner_noise.CornerNoise`); prior (F, F): a splined
    model's penalty in the normal equations, None: none. No field where the model has no
    correlated part.

    The field's variance and length are fitted to the between-view products at several
    distances as the fit leaves them (`_fitted_field`: the poses and the intrinsics absorb
    part of a field fixed in the image, so the products read off directly are short of its
    variance and length). It is kept where the between-view product at l/2 to l exceeds
    `_KEEP_Z` of its jackknife sigmas, the variance's score test (`_fitted_field`, its null
    distribution simulated on the calibration itself) exceeds `_KEEP_Z` too, and the fitted
    length is short of the longest tried. Its share of each view's correlated part is the
    ratio of the products between and within views at l/2 to l (`estimate`; the fit shrinks
    both alike), 0 where the one within a view is not above zero (the field's term then
    comes on top of each view's own)."""
    if noise is None or noise.ratio <= 0:
        return NONE
    residuals = [j[0] for j in jac]
    z = [np.asarray(r, float) / np.sqrt(np.asarray(w, float))[:, None] for r, w in zip(residuals, white)]
    est = estimate(points, z, noise.length_px)
    if est == NONE:
        return NONE
    tau2, length, score = _fitted_field(noise, points, jac, white, weights, prior)
    share = min(max(est.between / est.within, 0.0), 1.0) if est.within > 0 else 0.0
    # both tests: the jackknife needs no model of the views' own errors, the score is the
    # more sensitive where that model holds (module docstring); and a length at the longest
    # tried is a field the fit absorbs almost whole, whose variance the products do not fix
    determined = length < 0.999 * _FIT_LENGTHS[-1] * float(noise.length_px)
    if not (est.between > _KEEP_Z * est.between_std and score > _KEEP_Z and tau2 > 0 and determined):
        return ImageField(0.0, est.share_std, est.between, est.between_std, est.within, 0.0, est.length_px, score)
    return ImageField(share, est.share_std, est.between, est.between_std, est.within, tau2, length, score)


def _between_bins(points, z, edges):
    """(pairs (P, 2), their distance bin (P,)) of corners of different views whose distance
    lies within `edges` (B + 1,) [px]; and the mean product (both axes alike) per bin (B,)."""
    U = np.concatenate([np.asarray(p, float) for p in points])
    Z = np.concatenate([np.asarray(r, float) for r in z])
    V = np.concatenate([np.full(np.asarray(p).shape[0], j) for j, p in enumerate(points)])
    pr = pairs_within(U, edges[-1])
    pr = pr[V[pr[:, 0]] != V[pr[:, 1]]]
    d = np.linalg.norm(U[pr[:, 0]] - U[pr[:, 1]], axis=1)
    b = np.searchsorted(edges, d, side="right") - 1
    ok = (b >= 0) & (b < len(edges) - 1)
    pr, b = pr[ok], b[ok]
    prod = np.sum(Z[pr[:, 0]] * Z[pr[:, 1]], 1) / 2.0
    n = np.bincount(b, minlength=len(edges) - 1)
    m = np.bincount(b, prod, len(edges) - 1) / np.maximum(n, 1)
    return pr, b, m, n


def _fit_response(points, jac, weights, prior):
    """A function of per view error columns (2K_v, M) [px] (rows u, v per corner) giving the
    residuals the weighted least-squares fit leaves of them (its linearisation at the
    solution: each view's pose and the global parameters re-estimated)."""
    from pencilcal.toolkit.board.print_errors import projected

    weights = [None] * len(jac) if weights is None else weights
    parts, poses = [], []
    for (_, Jg, Jp, _), w in zip(jac, weights):
        W = np.ones(Jg.shape[0]) if w is None else np.repeat(np.asarray(w, float), 2)
        Sv, PJw = projected(Jg, Jp, w)
        parts.append((Sv, PJw))
        poses.append(np.linalg.pinv(Jp.T @ (Jp * W[:, None])) @ (Jp.T * W[None, :]))
    S = sum(p[0] for p in parts)
    if prior is not None:
        S = S.copy()
        S[:prior.shape[0], :prior.shape[0]] += prior
    Si = np.linalg.pinv(S)

    def response(E):
        dg = Si @ sum(p[1].T @ e for p, e in zip(parts, E))
        out = []
        for (_, Jg, Jp, _), B, e in zip(jac, poses, E):
            x = e - Jg @ dg
            out.append(x - Jp @ (B @ x))
        return out

    return response


def _fitted_field(noise, points, jac, white, weights, prior):
    """(tau^2 [px^2 per axis], length [px], score) of the field that best predicts the
    between-view products of the residuals in their white levels over the distance bins
    `_FIT_EDGES`, each product's expectation taken through the fit (`_fit_response`): a field
    of unit variance at each length of `_FIT_LENGTHS` times the per-view model's (random
    Fourier features of the kernel) and the views' own errors under `noise` (white plus each
    view's correlated part), which the global parameters leave slightly anticorrelated between
    views. tau^2 by least squares per length (weighted by the bins' counts), the length of
    least misfit. score: the score test of tau^2 = 0 at the per-view model's length, its null
    distribution simulated on the calibration itself: the products per bin (B,) y on a sample
    of each bin's pairs, the field's predicted ones u at unit variance, their covariance S
    with no field from `_NULL_DRAWS` draws of the views' own errors through the fit on the same
    pairs; ``u^T S^-1 y / sqrt(u^T S^-1 u)``, a standard normal with no field. (0, 0, 0)
    where nothing is resolved."""
    side = max(float(np.max(np.concatenate([np.asarray(p, float) for p in points]))), 1.0)
    edges = np.asarray(_FIT_EDGES) * side
    sw = [np.sqrt(np.asarray(w, float)) for w in white]
    z = [np.asarray(j[0], float) / s[:, None] for j, s in zip(jac, sw)]
    pr, b, m, n = _between_bins(points, z, edges)
    if np.count_nonzero(n) < 3:
        return 0.0, 0.0, 0.0
    rng = np.random.default_rng(0)
    # the predicted products on a sample of each bin's pairs (their mean is smooth in them)
    pick = np.concatenate([rng.permutation(np.flatnonzero(b == i))[:_PREDICTED_PAIRS] for i in range(len(n))])
    pa, pb, bb = pr[pick, 0], pr[pick, 1], b[pick]
    n_pick = np.maximum(np.bincount(bb, minlength=len(n)), 1)
    sw_all = np.concatenate(sw)
    U = np.concatenate([np.asarray(p, float) for p in points])
    Z = np.concatenate(z)
    starts = np.cumsum([0] + [np.asarray(p).shape[0] for p in points])
    response = _fit_response(points, jac, weights, prior)

    def column_products(E):
        # mean product per bin and column of the fit's residuals of the error columns E (N, 2, M): (B, M)
        R = response([E[starts[v]:starts[v + 1]].reshape(-1, E.shape[-1]) for v in range(len(points))])
        R = np.concatenate([r.reshape(-1, 2, E.shape[-1]) for r in R]) / sw_all[:, None, None]
        prod = np.einsum("pam,pam->pm", R[pa], R[pb]) / 2.0
        return np.stack([np.bincount(bb, prod[:, c], len(n)) for c in range(E.shape[-1])], 1) / n_pick[:, None]

    own_prod = column_products(_own_errors(noise, points, sw, _OWN_DRAWS, rng))
    base = own_prod.mean(1)
    y = m - base
    # the observed products on the sampled pairs, as the null draws see them
    y_pick = np.bincount(bb, np.sum(Z[pa] * Z[pb], 1) / 2.0, len(n)) / n_pick - base
    w = n.astype(float)
    best, score = None, 0.0
    for frac in _FIT_LENGTHS:
        length = frac * float(noise.length_px)
        M = _FEATURES
        Wf = rng.normal(size=(M, 2)) / length
        ph = rng.uniform(0.0, 2.0 * np.pi, M)
        phi = math.sqrt(2.0) * np.cos(U @ Wf.T + ph)                # (N, M): unit variance, the kernel in mean
        E = np.zeros((U.shape[0], 2, 2 * M))
        E[:, 0, :M], E[:, 1, M:] = phi, phi
        # each column moves one axis: the mean over both axes of a field on both is twice it
        unit = column_products(E).mean(1) * 2.0
        norm = max(float(np.sum(w * unit * unit)), 1e-300)
        tau2 = max(float(np.sum(w * unit * y) / norm), 0.0)
        miss = float(np.sum(w * (y - tau2 * unit) ** 2))
        if best is None or miss < best[0]:
            best = (miss, tau2, length)
        if np.isclose(frac, 1.0):  # the per-view model's length: the score's
            unit_l = unit
    # the score of tau^2 = 0 against tau^2 > 0 at the per-view model's length: the bins'
    # products with no field scatter together (one draw's errors move every bin), so their
    # covariance, simulated, weighs them (a count-weighted scale missed 3 of 23 fields of
    # 0.12 px at z 2 whose between-view products the jackknife resolved)
    extra = _own_errors(noise, points, sw, _NULL_DRAWS - _OWN_DRAWS, rng)
    null = np.cov(np.concatenate([own_prod, column_products(extra)], 1))
    null = null + _NULL_RIDGE * np.trace(null) / null.shape[0] * np.eye(null.shape[0])
    a = np.linalg.solve(null, unit_l)
    score = float(a @ y_pick) / math.sqrt(max(float(a @ unit_l), 1e-300))
    return best[1], best[2], score


def _own_errors(noise, points, sw, draws, rng):
    """Draws (N, 2, draws) [px] of the views' own errors under `noise` (white and each view's
    correlated part, independent between views) at the corners `points` (K_v, 2) [px] of white
    sigmas sw (K_v,) [px]."""
    from pencilcal.toolkit.board.corner_noise import kernel

    out = []
    for p, s in zip(points, sw):
        u = np.asarray(p, float)
        L = np.linalg.cholesky(np.eye(u.shape[0]) + noise.ratio * kernel(u, noise.length_px)
                               + 1e-9 * np.eye(u.shape[0]))
        out.append(s[:, None, None] * np.einsum("kl,lam->kam", L, rng.normal(size=(u.shape[0], 2, draws))))
    return np.concatenate(out)


def cell_grid(image_size, length_px, points=None):
    """(cell centres (C, 2) [px], each of `points`' (K, 2) [px] cell (K,) or None): the
    cells the field is sampled on, row-major."""
    size = _CELL * float(length_px)
    nx, ny = (max(int(math.ceil(float(s) / size)), 1) for s in image_size)
    gx, gy = np.meshgrid((np.arange(nx) + 0.5) * size, (np.arange(ny) + 0.5) * size)
    if points is None:
        return np.stack([gx.ravel(), gy.ravel()], -1), None
    c = np.floor(np.asarray(points, float) / size).astype(int)
    cell = np.clip(c[:, 1], 0, ny - 1) * nx + np.clip(c[:, 0], 0, nx - 1)
    return np.stack([gx.ravel(), gy.ravel()], -1), cell


def gains(Jg, Jp, points, image_size, length_px, w=None):
    """One view's part of d estimate / d field: (its Schur block (G, G), d (the normal
    equations' right side) / d field (G, 2 C) over the `cell_grid` cells, rows cell-major,
    axis-minor), from the Jacobians of the predictions in the global parameters Jg (2K, G)
    and in the pose Jp (2K, 6), the raw corners (K, 2) [px] and their weights w (K,)
    (None: 1)."""
    from pencilcal.toolkit.board.print_errors import projected

    centres, cell = cell_grid(image_size, length_px, points)
    K = cell.size
    S, PJw = projected(Jg, Jp, w)
    H = np.zeros((Jg.shape[1], centres.shape[0], 2))
    np.add.at(H, (slice(None), cell), PJw.T.reshape(-1, K, 2))
    return S, H.reshape(Jg.shape[1], -1)


def view_gains(jac, points, image_size, length_px, weights=None):
    """`gains` of every view from `bundle.view_jacobians`'s records, the raw corners (K_v, 2)
    and the fit's weights (per view (K_v,), or None)."""
    weights = [None] * len(jac) if weights is None else weights
    return [gains(Jg, Jp, u, image_size, length_px, w) for (_, Jg, Jp, _), u, w in zip(jac, points, weights)]


def covariance_term(Ga, Gb, field, image_size):
    """Ga K Gb^T tau^2: the covariance the field gives two estimates with gains Ga, Gb
    (P, 2 C) (`print_errors.intrinsic_gain` of `gains`)."""
    from pencilcal.toolkit.board.corner_noise import kernel

    centres, _ = cell_grid(image_size, field.length_px)
    k = kernel(centres, field.length_px)
    A = Ga.reshape(Ga.shape[0], -1, 2)
    B = Gb.reshape(Gb.shape[0], -1, 2)
    return field.variance_px2 * sum(A[:, :, a] @ k @ B[:, :, a].T for a in range(2))
