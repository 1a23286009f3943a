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

with l the per-view model's length and ``tau^2 = share c mean(sigma_w^2 d)`` the share of
the per-view correlated variance that the field takes (c the per-view ratio, sigma_w^2 d
each corner's white variance).

`estimate` measures the share on the residuals: each residual in its view's white level and
shape, the mean product of two corners of *different* views (between) and of two corners of
*one* view (within), both at image distances of l/2 to l; share = between / within, clipped
to [0, 1]. Both products are shrunk alike by the views' poses, which absorb a smooth error
in part, so their ratio is the share. Its sigma is a jackknife over the views; the field is
kept only where ``between`` exceeds twice its sigma (a one-sided 2.3 % test): corners
whose smooth error is each view's own keep the per-view model as it is.

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

    @property
    def kept(self):
        """Whether the field is in the model."""
        return self.share > 0 and self.variance_px2 > 0

    def to_dict(self):
        """calib.json's ``image_field`` record (docs/formats.md)."""
        return {"share": self.share, "share_std": self.share_std, "between": self.between,
                "between_std": self.between_std, "within": self.within, "sigma_px": math.sqrt(self.variance_px2),
                "length_px": self.length_px, "kept": self.kept}


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


def fit_image_field(noise, points, residuals, white):
    """`estimate` on a calibration and the field's variance: per view the raw corners
    (K_v, 2) [px], residuals (K_v, 2) [px] and each corner's white variance (K_v,) [px^2]
    under the corner-noise model `noise` (`corner_noise.CornerNoise`). No field where the
    model has no correlated part."""
    if noise is None or noise.ratio <= 0:
        return NONE
    z = [np.asarray(r, float) / np.sqrt(np.asarray(w, float))[:, None] for r, w in zip(residuals, white)]
    est = estimate(points, z, noise.length_px)
    if est.share <= 0:
        return est
    tau2 = est.share * noise.ratio * float(np.mean(np.concatenate([np.asarray(w, float) for w in white])))
    return ImageField(est.share, est.share_std, est.between, est.between_std, est.within, tau2, est.length_px)


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
