"""The shared thresholds are the quantiles and limits their comments say."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import chi2

from pencilcal.toolkit.pencil import defaults


def test_chi2_thresholds_are_the_quantiles():
    # closed form for 2 degrees of freedom: the same number as scipy's, to the bit
    assert defaults.CHI2_2_DETECTION == chi2.isf(defaults.DETECTION_LEVEL, 2)
    # the square of a normal quantile for 1 degree of freedom: scipy's to rounding
    assert defaults.CHI2_1_99 == pytest.approx(chi2.ppf(0.99, 1), rel=1e-15)


def test_geometry_limits():
    assert np.degrees(np.arctan(defaults.MAX_VERTEX)) == pytest.approx(89.0)
    assert np.degrees(np.arccos(defaults.MIN_COS)) == pytest.approx(89.5)
