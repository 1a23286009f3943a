"""Defaults and thresholds shared by pencilcal's estimators and detectors: the one home of each.

Values that are quantiles of a distribution are derived from it, never written as literals.
"""
from __future__ import annotations

from statistics import NormalDist

import numpy as np

__all__ = ["ENDPOINT_SIGMA_PX", "MIN_ENDPOINT_SIGMA_PX", "EDGE_WIDTH_SD_PX", "NARROW_BAND_PX", "DETECTION_LEVEL", "CHI2_2_DETECTION", "CHI2_1_99", "MAX_VERTEX", "MIN_COS"]

# Noise of a line segment's end point, per coordinate [px], when nothing better is known:
# the default of orient, fulcrum and the plain segment detector. A segment of length L then
# has angle sd sqrt(2) * 0.5 / L and offset sd 0.5 / sqrt(2) at its centre.
ENDPOINT_SIGMA_PX = 0.5
#: The smallest end point noise [px] an estimate from the residuals may give: sub-pixel
#: line detectors do not localise better, and exact (synthetic) lines would otherwise get
#: sigmas of zero (`sequence_noise`).
MIN_ENDPOINT_SIGMA_PX = 0.01
#: The sd [px] of a shaft band's width error that the edges' own covariances do not hold, per
#: band class (`band_width.band_class`: edge model, polarity, size): the silhouette's place on
#: a shaded limb depends on the shaft's material, its light and the background beside it,
#: which one sequence shares, so the error is one for all its frames and does not average
#: out. Each is the larger of its class's RMS width error on two sets of shaded single-shaft
#: renders (four materials, bright, dark and tissue backgrounds, 40, 80 and 150 mm; a band
#: read more than 25 % off left out as a detection failure, not a limb's shift), rounded up
#: to 0.05 px: 36 plain renders (`validation.band_width_grid` seed 1: flat light, no JPEG) and
#: 72 endoscope-like ones (seeds 10-11, ``--realism endoscope``: light falling off with
#: distance, a wrist, uneven light, JPEG 80-95), which raised the brighter bands' sds (step
#: 2.85/2.55 -> 4.30/4.10 px, limb 0.35/0.10 -> 0.85/0.20 px) and the darker wide limb's
#: (0.10 -> 0.25 px); checked on fresh seeds (docs/uncertainty.md). Step edges of a shaft
#: brighter than its surround land on the shading inside its darkened rim (-2 to -10 px); the
#: limb model finds the rim itself. A band the limb model located adds its own sd, what its
#: fit shows (``width_sd_px``, `band_width.band_width_sd`). The 3-D fulcrum's depth scales
#: with it (`band_width.point_width_cov`).
EDGE_WIDTH_SD_PX = {
    "step-dark-narrow": 0.70, "step-dark-wide": 0.35, "step-bright-narrow": 4.30, "step-bright-wide": 4.10,
    "limb-dark-narrow": 0.10, "limb-dark-wide": 0.25, "limb-bright-narrow": 0.85, "limb-bright-wide": 0.20,
}
#: The width [px] below which a band is narrow (`band_width.band_class`).
NARROW_BAND_PX = 60.0

# --------------------------------------------------------------- the exact estimator's tests
#: Level of the frontal likelihood-ratio test: a pencil's tilt is declared detectable when
#: the fit beats the best frontal pencil by more than the chi-square(2) quantile at
#: 1 - DETECTION_LEVEL (estimator.fit_pencil, estimator_torch.fit_pencils_torch).
DETECTION_LEVEL = 0.01
#: That quantile, 9.21 for the 1 % level; chi-square with 2 degrees of freedom has survival
#: exp(-x / 2), so it is -2 log(level) in closed form (equal to the bit to
#: scipy.stats.chi2.isf(DETECTION_LEVEL, 2)). assign_spokes and orient also use it to call
#: two labellings equally good.
CHI2_2_DETECTION = -2.0 * np.log(DETECTION_LEVEL)
#: 99 % quantile of chi-square with 1 degree of freedom, 6.63: what assign_spokes and orient
#: charge a rejected line when they compare labellings that use different numbers of lines.
#: chi-square(1) is the square of a standard normal: the square of its 99.5 % quantile.
CHI2_1_99 = NormalDist().inv_cdf(1.0 - 0.01 / 2.0) ** 2

# ------------------------------------------------------------------- geometry limits
#: Largest normalised radius of a vertex: one whose viewing ray is more than 89 deg off the
#: optical axis (radius tan 89 deg ~ 57) is, for every lens here, a vertex at infinity (the
#: lines are parallel in the image), and the estimators refuse it.
MAX_VERTEX = np.tan(np.radians(89.0))
#: Smallest cos(tilt) the closed-form start returns: below it (tilt beyond 89.5 deg) the
#: pencil is treated as edge-on and the Levenberg-Marquardt refinement takes over.
MIN_COS = np.cos(np.radians(89.5))
