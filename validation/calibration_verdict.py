"""Is a calibration good enough, and where in the image: the verdict and the advice.

`judge` reads what the checks measured (`validation.calibration_checks`) and says one of

- **usable**: the projection is known to `USABLE_PX` (the worst direction's 1-sigma) over
  at least `USABLE_SHARE` of the image, and the calibration passes its own cross-validation;
- **usable within this region**: the same, but only over part of the image (the region the
  views cover and where the uncertainty is below `USABLE_PX`; outside it the lens is
  extrapolated, not measured);
- **not usable**, with the reason: too few views to check it (`MIN_VIEWS`), views that are
  all nearly fronto-parallel (the focal length is then confounded with the distance: fewer
  than `MIN_TILTED_VIEWS` views tilted by `TILTED_DEG` or more), a board that covers too
  little of the image (the usable region under `MIN_REGION_SHARE`), or two halves of the
  views that disagree beyond chance (pooled chi-square per dof or projection ratio above
  `DISAGREE`, or the odd-even chi-square's p-value under `DISAGREE_P`): the model does not
  describe the views.

The halves must agree within `CONSISTENT_CHI2` (pooled chi-square per degree of freedom)
and `CONSISTENT_RATIO` (pooled projection difference over its prediction) for the sigmas to
be trusted as they are; between those bounds and `DISAGREE` the verdict stands with a
warning that says by how much the sigmas look small. Each view's own focal scale must
scatter as its corner noise says (`calibration_checks.view_focal_scales`): a p-value under
`DISAGREE_P` warns that the focus, zoom or board changed between the views.

The advice names what to add: views where the image is thin (`coverage_regions`), tilted
views, views at other distances, more views, a board that fills more of the image.

Example
-------
>>> v = judge(views_used=4, halves={"error": "two halves need at least 6 views, got 4"},
...           umap={"covered_fraction": 0.3, "median_covered_px": 0.2, "max_covered_px": 0.4},
...           geometry={"tilt_deg": [30, 35, 40, 45], "distance": [300, 310, 320, 330],
...                     "area_fraction": [0.2, 0.2, 0.2, 0.2]})
>>> v.status, v.reasons[0].startswith("too few views")
('not usable', True)
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from pencilcal.toolkit.camera.projection_uncertainty import LINEAR_DEPARTURE

__all__ = ["Verdict", "judge", "USABLE_PX", "USABLE_SHARE", "MIN_REGION_SHARE", "MIN_VIEWS", "TILTED_DEG",
           "MIN_TILTED_VIEWS", "CONSISTENT_CHI2", "CONSISTENT_RATIO", "DISAGREE", "DISAGREE_P", "coverage_regions",
           "halves_state", "STATUSES"]

#: The verdicts, best first.
STATUSES = ("usable", "usable within this region", "not usable")
#: Projection uncertainty (worst direction, 1 sigma) up to which a pixel counts as known [px].
USABLE_PX = 1.0
#: Share of the image the usable region must reach for "usable" (else "within this region").
USABLE_SHARE = 0.75
#: Below this share of the image the calibration is not usable at all.
MIN_REGION_SHARE = 0.15
#: Fewer views cannot be split into two halves that each calibrate the camera.
MIN_VIEWS = 6
#: A view counts as tilted from this angle between the board's normal and the line of sight.
TILTED_DEG = 15.0
#: Fewer tilted views than this: the views are all nearly fronto-parallel.
MIN_TILTED_VIEWS = 3
#: The halves agree as their sigmas say within these (pooled over the splits).
CONSISTENT_CHI2 = 1.5
CONSISTENT_RATIO = 1.3
#: Beyond this (either figure), or an odd-even p-value under DISAGREE_P, they disagree.
DISAGREE = 2.0
DISAGREE_P = 1e-3
# advice thresholds: tilted views wanted, distance spread (max / min), views wanted, and the
# board's share of the image below which it should come closer
_GOOD_TILT_DEG = 30.0
_GOOD_TILTED_VIEWS = 5
_DISTANCE_SPREAD = 1.3
_GOOD_VIEWS = 15
_SMALL_BOARD = 0.05

_REGIONS = {(0, 0): "top-left corner", (1, 0): "top edge", (2, 0): "top-right corner",
            (0, 1): "left edge", (1, 1): "centre", (2, 1): "right edge",
            (0, 2): "bottom-left corner", (1, 2): "bottom edge", (2, 2): "bottom-right corner"}


@dataclass
class Verdict:
    """The answer first: ``status`` (one of `STATUSES`), ``headline`` (one line with the
    headline figure and its unit), ``reasons`` (why, for a calibration that is not fully
    usable), ``warnings``, ``advice`` (what to add), ``region`` (the usable region: its
    share of the image, its bounding box [u0, v0, u1, v1] px, the threshold) and
    ``figures`` (what the verdict read)."""

    status: str
    headline: str
    reasons: list = field(default_factory=list)
    warnings: list = field(default_factory=list)
    advice: list = field(default_factory=list)
    region: dict = field(default_factory=dict)
    figures: dict = field(default_factory=dict)

    def to_dict(self):
        return {"status": self.status, "headline": self.headline, "reasons": list(self.reasons),
                "warnings": list(self.warnings), "advice": list(self.advice), "region": dict(self.region),
                "figures": dict(self.figures)}


def coverage_regions(cells, share=0.5):
    """The names of the nine parts of the image (corners, edges, centre) that a grid's
    cells (ny, nx; True where usable) leave thin: under `share` of their cells usable."""
    m = np.asarray(cells, bool)
    ny, nx = m.shape
    thin = []
    for (ri, rj), name in _REGIONS.items():
        sub = m[rj * ny // 3:(rj + 1) * ny // 3, ri * nx // 3:(ri + 1) * nx // 3]
        if sub.size == 0 or sub.mean() < share:
            thin.append(name)
    return thin


def _usable_region(umap, usable_px):
    """(share of the image, bbox px or None, mask) of the cells covered and known to usable_px."""
    sigma = umap.get("sigma_px")
    if sigma is None:
        return float(umap.get("covered_fraction") or 0.0), None, None
    s = np.array([[np.nan if v is None else v for v in row] for row in sigma], float)
    mask = np.asarray(umap["covered"], bool) & np.isfinite(s) & (s <= usable_px)
    if not mask.any():
        return 0.0, None, mask
    step = float(umap["step_px"])
    jj, ii = np.nonzero(mask)
    bbox = [round(ii.min() * step, 1), round(jj.min() * step, 1), round((ii.max() + 1) * step - 1, 1),
            round((jj.max() + 1) * step - 1, 1)]
    return float(mask.mean()), bbox, mask


def halves_state(halves):
    """("ok" | "loose" | "disagree" | "unchecked", chi2/dof, ratio, odd-even p, why)."""
    if not halves or halves.get("error"):
        return "unchecked", None, None, None, (halves or {}).get("error", "not run")
    pooled = halves.get("pooled") or {}
    chi2 = pooled.get("chi2_per_dof", halves["odd_even"].get("chi2_per_dof"))
    ratio = pooled.get("projection_ratio", halves["odd_even"].get("projection_ratio"))
    p = halves["odd_even"].get("p_value")
    if (chi2 is not None and chi2 > DISAGREE) or (ratio is not None and ratio > DISAGREE) or \
            (p is not None and p < DISAGREE_P):
        return "disagree", chi2, ratio, p, None
    if (chi2 is not None and chi2 > CONSISTENT_CHI2) or (ratio is not None and ratio > CONSISTENT_RATIO):
        return "loose", chi2, ratio, p, None
    return "ok", chi2, ratio, p, None


def _geometry_reasons(views_used, geometry, region_share, umap, noise):
    tilt = np.asarray(geometry.get("tilt_deg", []), float)
    area = np.asarray(geometry.get("area_fraction", []), float)
    reasons = []
    if views_used < MIN_VIEWS:
        reasons.append(f"too few views: {views_used} used, at least {MIN_VIEWS} are needed to check the calibration "
                       f"against itself ({_GOOD_VIEWS} or more recommended)")
    tilted = int(np.sum(tilt >= TILTED_DEG))
    if tilt.size and tilted < MIN_TILTED_VIEWS:
        reasons.append(f"the views are nearly fronto-parallel: {tilted} of {tilt.size} tilted by {TILTED_DEG:.0f} deg "
                       f"or more (largest {tilt.max():.0f} deg), so the focal length is confounded with the distance")
    cov = float(umap.get("covered_fraction") or 0.0)
    if cov < MIN_REGION_SHARE:
        big = f", the largest view's board {100 * area.max():.0f}% of it" if area.size else ""
        reasons.append(f"the board covers too little of the image: the views cover {100 * cov:.0f}% of it{big} (at "
                       f"least {100 * MIN_REGION_SHARE:.0f}% needed)")
    elif region_share < MIN_REGION_SHARE:
        med = umap.get("median_covered_px")
        if area.size and float(np.median(area)) < _SMALL_BOARD:
            why = f"the board is small in the image ({100 * np.median(area):.1f}% of it in the median view)"
        elif views_used < _GOOD_VIEWS:
            why = f"there are few views ({views_used})"
        else:
            why = "the corners are noisy"
            if noise:
                why += (f" ({noise.get('rms_px', float('nan')):.2f} px RMS, correlated part "
                        f"{noise.get('ratio', 0.0):.2g} x the white one over {noise.get('length_px', 0.0):.0f} px)")
        reasons.append(f"the projection is known to {USABLE_PX:g} px over only {100 * region_share:.0f}% of the image "
                       f"(median {med:.2f} px over the {100 * cov:.0f}% the views cover): {why}")
    return reasons


def _advice(views_used, geometry, usable, state):
    tilt = np.asarray(geometry.get("tilt_deg", []), float)
    dist = np.asarray(geometry.get("distance", []), float)
    area = np.asarray(geometry.get("area_fraction", []), float)
    out = []
    if usable is not None:
        thin = coverage_regions(usable)
        if len(thin) == 9:
            out.append("Add views that put the board all over the image: no part of it is well covered.")
        elif thin:
            out.append(f"Add views with the board at the {', '.join(thin)} of the image: the lens there is "
                       "extrapolated, not measured.")
    if tilt.size and np.sum(tilt >= _GOOD_TILT_DEG) < _GOOD_TILTED_VIEWS:
        out.append(f"Add tilted views: the board turned {_GOOD_TILT_DEG:.0f}-50 deg about its horizontal and its "
                   f"vertical axis ({int(np.sum(tilt >= _GOOD_TILT_DEG))} views are tilted that much).")
    if dist.size >= 2 and dist.max() < _DISTANCE_SPREAD * dist.min():
        out.append(f"Add views nearer and farther: the board was seen between {dist.min():.3g} and {dist.max():.3g} "
                   "board units only.")
    if area.size and float(np.median(area)) < _SMALL_BOARD:
        out.append(f"Bring the board closer or use a larger one: it fills {100 * np.median(area):.1f}% of the image in "
                   "the median view.")
    if views_used < _GOOD_VIEWS:
        out.append(f"Add views: {views_used} were used; {_GOOD_VIEWS} or more make the check of the calibration "
                   "against itself meaningful.")
    if state == "disagree":
        out.append("Check that the board is rigid and flat and was still in every view (blur, a bending sheet), and "
                   "try --model auto: the two halves of the views do not describe one camera.")
    return out or ["Nothing to add: the views cover the image, tilted, at several distances."]


def judge(views_used, halves, umap, geometry, usable_px=USABLE_PX, noise=None):
    """The `Verdict` on a calibration.

    views_used : views in the fit; halves : `calibration_halves`'s record (or ``{"error":
    why}``); umap : `uncertainty_map`'s record; geometry : `toolkit.board.coverage.
    view_geometry`'s arrays (lists are fine); usable_px : the projection uncertainty up to
    which a pixel counts as known [px]; noise : the corners' ``rms_px``, and the correlated
    part's ``ratio`` and ``length_px`` (for the reason when the uncertainty is too large).
    """
    share, bbox, usable = _usable_region(umap, usable_px)
    state, chi2, ratio, p, why = halves_state(halves)
    reasons = _geometry_reasons(int(views_used), geometry, share, umap, noise)
    warnings = []
    if state == "disagree":
        reasons.append(f"the two halves of the views disagree beyond chance (chi2/dof {chi2:.2f}, projection "
                       f"differences {ratio:.2f} x the predicted): the model does not describe these views")
    elif state == "loose":
        warnings.append(f"the two halves agree only loosely (chi2/dof {chi2:.2f}, projection differences "
                        f"{ratio:.2f} x the predicted): the sigmas may be up to {max(ratio, chi2 ** 0.5):.1f} x "
                        "too small")
    elif state == "unchecked" and not reasons:
        reasons.append(f"the calibration could not be checked against itself ({why})")
    scales = (halves or {}).get("view_focal_scale") or {}
    if scales.get("p_value") is not None and scales["p_value"] < DISAGREE_P:
        warnings.append(f"the views disagree on the focal scale beyond their corner noise (scatter "
                        f"{scales['chi2_per_dof']:.2f} x the expected over {scales['views']} views, p "
                        f"{scales['p_value']:.1g}; {100 * scales['tau']:.2g} % per view beyond it), as when a focus "
                        "or zoom changed between the views or the board bent differently in each; the focal length's "
                        "sigma leaves that scatter out")
    dep = umap.get("linear_departure")
    if dep is not None and not float(dep) <= LINEAR_DEPARTURE:
        warnings.append(f"the lens model's coefficients are not determined by these views: a one-sigma change of them "
                        f"moves the projection {float(dep):.2g} x as far from its linear response as that response, so "
                        "their sigmas (and the halves' chi-square on them) are not to be read as they stand; a model "
                        "with fewer coefficients (--model auto refuses such a model) gives sigmas that hold")
    med, worst = umap.get("median_covered_px"), umap.get("max_covered_px")
    figures = {"usable_share": share, "covered_share": umap.get("covered_fraction"), "median_covered_px": med,
               "max_covered_px": worst, "halves_chi2_per_dof": chi2, "halves_projection_ratio": ratio,
               "halves_odd_even_p": p, "views_used": int(views_used),
               "linear_departure": dep, "view_focal_scale_p": scales.get("p_value")}
    region = {"share": share, "bbox_px": bbox, "threshold_px": usable_px}
    fig = (f"projection uncertainty {med:.2f} px (median, worst {worst:.2f} px) over the covered "
           f"{100 * (umap.get('covered_fraction') or 0):.0f}% of the image") if med is not None else \
        "no projection uncertainty"
    if reasons:
        status = "not usable"
        headline = f"Not usable: {reasons[0]}."
    elif share >= USABLE_SHARE:
        status = "usable"
        headline = f"Usable: {fig}; the halves agree (chi2/dof {chi2:.2f})."
    else:
        status = "usable within this region"
        where = f"u {bbox[0]:.0f}-{bbox[2]:.0f}, v {bbox[1]:.0f}-{bbox[3]:.0f} px" if bbox else "no region"
        headline = (f"Usable within this region ({100 * share:.0f}% of the image, {where}): {fig}; known to "
                    f"{usable_px:g} px there.")
    return Verdict(status, headline, reasons, warnings, _advice(int(views_used), geometry, usable, state), region,
                   figures)
