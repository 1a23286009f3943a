"""Defaults and thresholds shared by pencilcal's estimators and detectors: the one home of each.

Values that are quantiles of a distribution are derived from it, never written as literals.
"""
from __future__ import annotations

from statistics import NormalDist

import numpy as np

__all__ = ["ENDPOINT_SIGMA_PX", "MIN_ENDPOINT_SIGMA_PX", "DETECTION_LEVEL", "CHI2_2_DETECTION", "CHI2_1_99", "MAX_VERTEX", "MIN_COS"]

# Noise of a line segment's end point, per coordinate [px], when nothing better is known:
# the default of orient, fulcrum and the plain segment detector. A segment of length L then
# has angle sd sqrt(2) * 0.5 / L and offset sd 0.5 / sqrt(2) at its centre.
ENDPOINT_SIGMA_PX = 0.5
#: The smallest end point noise [px] an estimate from the residuals may give: sub-pixel
#: line detectors do not localise better, and exact (synthetic) lines would otherwise get
#: sigmas of zero (`sequence_noise`).
MIN_ENDPOINT_SIGMA_PX = 0.01

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
