"""Defaults and thresholds shared by pencilcal's estimators and detectors: the one home of each.

Values that are quantiles of a distribution are derived from it, never written as literals.
"""
from __future__ import annotations

__all__ = ["ENDPOINT_SIGMA_PX"]

# Noise of a line segment's end point, per coordinate [px], when nothing better is known:
# the default of orient, fulcrum and the plain segment detector. A segment of length L then
# has angle sd sqrt(2) * 0.5 / L and offset sd 0.5 / sqrt(2) at its centre.
ENDPOINT_SIGMA_PX = 0.5
