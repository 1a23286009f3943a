"""The bands' width error that a shaft sequence shares, in its 3-D fulcrum's covariance.

Where a shaded shaft's silhouette is found depends on its material, its light and the
background beside it, which every frame of one sequence shares: the band-width error is one
error for the sequence, and the 3-D fulcrum's depth (fixed by the widths) carries it whole.
`point_width_cov` is its covariance term (docs/uncertainty.md); `defaults.EDGE_WIDTH_SD_PX`
its size in pixels.
"""
from __future__ import annotations

import numpy as np

from pencilcal.toolkit.errors import EstimationError, InputError
from pencilcal.toolkit.pencil.cylinder import fulcrum_3d, shaft_axis
from pencilcal.toolkit.pencil.defaults import EDGE_WIDTH_SD_PX

__all__ = ["widen_bands", "point_width_cov"]


def widen_bands(edges, px):
    """edges (N, 2, 4) [px] with each edge segment moved away from its partner by px / 2:
    every band px wider (negative: narrower)."""
    e = np.array(edges, float).reshape(-1, 2, 4)
    mid = 0.5 * (e[..., :2] + e[..., 2:])
    t = e[..., 2:] - e[..., :2]
    n = np.stack([-t[..., 1], t[..., 0]], -1) / np.linalg.norm(t, axis=-1, keepdims=True)
    n = n * np.sign(np.sum(n * (mid - mid[:, ::-1]), -1, keepdims=True))  # outward
    return e + 0.5 * float(px) * np.concatenate([n, n], -1)


def point_width_cov(K, edges, edge_cov, radius, width_sd_px=EDGE_WIDTH_SD_PX, step_px=0.1):
    """((3, 3), relative sd): the 3-D fulcrum's covariance term of a band-width error shared
    by every frame of the sequence (the shaft's material, its light and the background beside
    it are), or (None, 0.0) where it cannot be had.

    K: (3, 3); edges: (N, 2, 4) the used shafts' edges [undistorted px]; edge_cov (N, 2, 2,
    2); radius: the shafts' radius. Every band is widened by step_px either way, each axis
    found again (`cylinder.shaft_axis`) and the point fitted again to those axes
    (`cylinder.fulcrum_3d`, no outlier search: the same axes); the central difference g (3,)
    gives ``width_sd_px^2 g g^T``: a band read wider sees a thicker cylinder, nearer, so
    the point moves mostly along its line of sight (a common relative width error w scales
    every axis, and the point, about the camera centre by 1 / (1 + w)). One error for all the
    frames: this term is no smaller for more frames, unlike the noise's. The relative sd:
    width_sd_px |g| / |point|."""
    e, c = np.asarray(edges, float).reshape(-1, 2, 4), np.asarray(edge_cov, float).reshape(-1, 2, 2, 2)
    if len(e) < 2:
        return None, 0.0

    def point(px):
        ax = shaft_axis(np.asarray(K, float), widen_bands(e, px), float(radius), edge_cov=c)
        return np.asarray(fulcrum_3d(ax.axis_point, ax.axis_direction, ax.axis_cov, robust=False).point, float)

    try:
        P0, g = point(0.0), (point(step_px) - point(-step_px)) / (2.0 * step_px)
    except (EstimationError, InputError):
        return None, 0.0
    if not np.all(np.isfinite(g)):
        return None, 0.0
    return width_sd_px**2 * np.outer(g, g), float(width_sd_px * np.linalg.norm(g) / np.linalg.norm(P0))
