"""The 3-D axes a sequence's own scatter keeps, before the 3-D fulcrum's noise and play fit.

Every shaft axis's covariance holds the detector's edge floor, far above what clean edges
scatter (on rendered pivots the good axes' median chi2 at the true fulcrum is 0.06, against
chi2(2)'s 1.39). At that size a near shaft whose edges run on along its narrower wrist (the
edge's far end 5-9 px inside the silhouette; its axis tilted by 4-15 deg and read a few mm
too far) passes the 99 % gate, and several such, misread alike, pull the point by 5-12 mm.
`scatter_inliers` gates the axes at their own scatter (`cylinder.fulcrum_3d`'s
``scatter_gate``); with `fulcrum.fulcrum_point(..., scatter_gate=True)` (its default)
`fulcrum._point_with_noise` fits the kept ones and `over_all_axes` puts the left-out ones
back as outliers (docs/method.md, "The gate at the axes' own scatter"). It applies only
where all the axes, at their robust point, scatter well inside their covariances
(`own_scale` below `SCATTER_LIMIT`): real edges noisier than stated (the phantom's axes
scatter 2-5 times their stated variance) keep the stated gate, and the noise fit may take
back, at its factor, the axes that gate left out.

>>> import numpy as np
>>> d = np.array([[1.0, 0, 0], [0, 1, 0], [0.6, 0.8, 0], [0.8, 0, 0.6], [0, 0.6, 0.8], [0.6, 0, 0.8]])
>>> P = np.array([0.0, 0, 100]) - 20 * d + [[0.1, 0, 0.2], [0.2, 0, -0.1], [0, 0, 0.2], [0, -0.2, 0],
...                                         [0.2, 0, 0], [0, 3.0, 0]]   # the last 3 mm off
>>> C = np.broadcast_to(np.diag([1e-4, 1e-4, 4.0, 4.0]), (6, 4, 4))      # 2 mm sd: all pass 99 %
>>> fulcrum_3d(P, d, C).inliers.tolist(), scatter_inliers(P, d, C).tolist()
([True, True, True, True, True, True], [True, True, True, True, True, False])
"""
from __future__ import annotations

import dataclasses

import numpy as np

from pencilcal.toolkit.errors import EstimationError
from pencilcal.toolkit.pencil.cylinder import axis_frame, axis_offsets, fulcrum_3d, offset_chi2, scatter_scale

__all__ = ["SCATTER_LIMIT", "own_scale", "scatter_inliers", "over_all_axes"]

#: The axes' own scale (`own_scale`) below which their own scatter gates them: the stated
#: covariances at least 1 / SCATTER_LIMIT times what the axes scatter (an edge floor).
SCATTER_LIMIT = 0.5


def own_scale(fit):
    """The axes' own scale of their covariances at a `cylinder.Fulcrum3D` fit of all of them:
    the median chi2 (N,) of every axis at its point over chi2(2)'s median (2 ln 2), a robust
    (MAD-like) variance factor that fewer than half of the axes misread cannot move
    (`cylinder.scatter_scale`, unclipped).

    >>> import types
    >>> round(own_scale(types.SimpleNamespace(chi2=np.array([0.1, 2 * np.log(2), 40.0]))), 6)
    1.0
    """
    return float(scatter_scale(fit.chi2, clip=False)[0])


def scatter_inliers(points, dirs, covs, limit=SCATTER_LIMIT):
    """(N,) bool: the axes (points, dirs (N, 3), covs (N, 4, 4) as `cylinder.fulcrum_3d`
    takes them) that the gate at their own scatter keeps; all where all of them scatter at
    their robust point as much as `limit` times their covariances or more (`own_scale`), or
    where the gate keeps fewer than three or half of them or fewer, finds no point, or the
    kept axes scatter as much as their covariances say (median chi2 at least chi2(2)'s)."""
    every = np.ones(len(points), bool)
    try:
        # axes noisier than stated: a subset fixed at the stated gate would keep the noise
        # fit from taking back, at its factor, the axes it left out, and each leave-one-out
        # fit then keeps another subset (the phantom's jackknife over its sigma went 1.07 -> 3.49)
        if own_scale(fulcrum_3d(points, dirs, covs)) >= limit:
            return every
        fit = fulcrum_3d(points, dirs, covs, scatter_gate=True)
    except EstimationError:
        return every
    keep = np.asarray(fit.inliers, bool)
    # axes that scatter as much as stated or more (the edges' noise, the port's play) are
    # the noise and play fit's to read, and a gate that leaves out half the axes or more reads
    # no few misread ones but the sequence's own scatter (a fulcrum that moved: the jackknife's)
    few = 3 <= keep.sum() and 2 * keep.sum() > len(keep)
    return keep if few and scatter_scale(fit.chi2[keep])[0] < 1.0 else every


def over_all_axes(fit, keep, points, dirs, covs):
    """fit (a `cylinder.Fulcrum3D` of the axes keep (N,) bool) over all N axes: the ones left
    out its outliers, with their distances, chi2 (at their own covs) and along at its point."""
    r, S, t = axis_offsets(np.asarray(fit.point, float), points, dirs, axis_frame(points, dirs), covs)
    c2, dist, inl = offset_chi2(r, S), np.linalg.norm(r, axis=-1), np.zeros(len(points), bool)
    inl[keep], c2[keep], t[keep], dist[keep] = fit.inliers, fit.chi2, fit.along, fit.distances
    return dataclasses.replace(fit, inliers=inl, chi2=c2, along=t, distances=dist)
