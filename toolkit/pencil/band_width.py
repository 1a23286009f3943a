"""The bands' width error that a shaft sequence shares, in its 3-D fulcrum's covariance.

Where a shaded shaft's silhouette is found depends on its material, its light and the
background beside it, which every frame of one sequence shares: the band-width error is one
error for the sequence, and the 3-D fulcrum's depth (fixed by the widths) carries it whole.
`point_width_cov` is its covariance term (docs/uncertainty.md); `band_width_sd` its size in
pixels for each band, from what the detector measured on it (`band_class`: its edge model,
its polarity and its width; the sds `defaults.EDGE_WIDTH_SD_PX`, measured on shaded renders:
`validation.band_width_grid`) and, for a band the limb model located, what its own fit
shows (``width_sd_px``: a limb the profiles do not pin down scatters along the edge).
"""
from __future__ import annotations

import numpy as np

from pencilcal.toolkit.errors import EstimationError, InputError
from pencilcal.toolkit.pencil.cylinder import fulcrum_3d, shaft_axis
from pencilcal.toolkit.pencil.defaults import EDGE_WIDTH_SD_PX, NARROW_BAND_PX

__all__ = ["band_class", "band_width_sd", "widen_bands", "point_width_cov"]


def band_class(shaft):
    """The band's class, "MODEL-POLARITY-SIZE", of a shaft record (a lines.json shaft: its
    ``edge_model`` (default "step"), ``polarity`` ("dark": the shaft darker than its
    surround, "bright"; another or none: "any") and ``width_px``): SIZE "narrow" below
    `defaults.NARROW_BAND_PX`, else "wide"."""
    model = shaft.get("edge_model") or "step"
    pol = shaft.get("polarity") if shaft.get("polarity") in ("dark", "bright") else "any"
    w = shaft.get("width_px")
    size = "narrow" if w is None or not np.isfinite(w) or float(w) < NARROW_BAND_PX else "wide"
    return f"{model}-{pol}-{size}"


def band_width_sd(shaft):
    """The sd [px] of a band's width error shared by its sequence (`defaults.EDGE_WIDTH_SD_PX`
    of its `band_class`; a class not there (an unknown polarity) takes the largest of its
    edge model's and size's), and with the band's own ``width_sd_px`` (what its limb fit
    shows: `detect.shaft.limb.width_spread`) the root sum of squares of the two. shaft: a
    lines.json shaft record.

    >>> band_width_sd({"edge_model": "limb", "polarity": "bright", "width_px": 100.0})
    0.2
    >>> round(band_width_sd({"edge_model": "limb", "polarity": "bright", "width_px": 100.0, "width_sd_px": 0.6}), 3)
    0.632
    """
    cls = band_class(shaft)
    if cls in EDGE_WIDTH_SD_PX:
        sd = float(EDGE_WIDTH_SD_PX[cls])
    else:
        model, _, size = cls.split("-")
        sd = float(max(EDGE_WIDTH_SD_PX[f"{model}-{p}-{size}"] for p in ("dark", "bright")))
    own = shaft.get("width_sd_px")
    if own is not None and np.isfinite(own):
        sd = float(np.hypot(sd, own))
    return sd


def widen_bands(edges, px):
    """edges (N, 2, 4) [px] with each edge segment moved away from its partner by px / 2:
    every band px wider (negative: narrower)."""
    e = np.array(edges, float).reshape(-1, 2, 4)
    mid = 0.5 * (e[..., :2] + e[..., 2:])
    t = e[..., 2:] - e[..., :2]
    n = np.stack([-t[..., 1], t[..., 0]], -1) / np.linalg.norm(t, axis=-1, keepdims=True)
    n = n * np.sign(np.sum(n * (mid - mid[:, ::-1]), -1, keepdims=True))  # outward
    return e + 0.5 * float(px) * np.concatenate([n, n], -1)


def point_width_cov(K, edges, edge_cov, radius, width_sd_px, step=0.05):
    """((3, 3), relative sd): the 3-D fulcrum's covariance term of a band-width error shared
    by every frame of the sequence (the shaft's material, its light and the background beside
    it are), or (None, 0.0) where it cannot be had.

    K: (3, 3); edges: (N, 2, 4) the used shafts' edges [undistorted px]; edge_cov (N, 2, 2,
    2); radius: the shafts' radius; width_sd_px: (N,) or one for all: each band's width sd
    [px] (`band_width_sd`). Every band is widened by step times its sd either way, each axis
    found again (`cylinder.shaft_axis`) and the point fitted again to those axes
    (`cylinder.fulcrum_3d`, no outlier search: the same axes); the central difference g (3,)
    per sd gives ``g g^T``: a band read wider sees a thicker cylinder, nearer, so the point
    moves mostly along its line of sight. The bands' errors move together (one light, one
    shading, one background for the sequence), each by its own sd. One error for all the
    frames: this term is no smaller for more frames, unlike the noise's. The relative sd:
    |g| / |point|."""
    e, c = np.asarray(edges, float).reshape(-1, 2, 4), np.asarray(edge_cov, float).reshape(-1, 2, 2, 2)
    sd = np.broadcast_to(np.asarray(width_sd_px, float), (len(e),))
    if len(e) < 2 or not np.any(sd > 0):
        return None, 0.0

    def point(t):
        widened = np.array([widen_bands(b, t * s)[0] for b, s in zip(e, sd)])
        ax = shaft_axis(np.asarray(K, float), widened, float(radius), edge_cov=c)
        return np.asarray(fulcrum_3d(ax.axis_point, ax.axis_direction, ax.axis_cov, robust=False).point, float)

    try:
        P0, g = point(0.0), (point(step) - point(-step)) / (2.0 * step)
    except (EstimationError, InputError):
        return None, 0.0
    if not np.all(np.isfinite(g)):
        return None, 0.0
    return np.outer(g, g), float(np.linalg.norm(g) / np.linalg.norm(P0))
