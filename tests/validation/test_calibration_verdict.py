"""The verdict warns when the lens model's coefficients are not determined by the views."""
from __future__ import annotations

from pencilcal.validation.calibration_verdict import judge

GEOMETRY = {"tilt_deg": [30, 35, 40, 45, 20, 25, 30, 50], "distance": [300, 310, 320, 330, 400, 420, 440, 460],
            "area_fraction": [0.2] * 8}
HALVES = {"odd_even": {"chi2_per_dof": 0.5, "projection_ratio": 0.9, "p_value": 0.6},
          "pooled": {"chi2_per_dof": 0.9, "projection_ratio": 0.1}}


def _umap(departure):
    return {"covered_fraction": 0.8, "median_covered_px": 0.2, "max_covered_px": 0.4, "linear_departure": departure}


def test_a_projection_far_from_its_linearisation_is_warned_about():
    # the rational model on real endoscope views: a one-sigma step moves the projection 36 x
    # as far from the linear response as that response; the halves' 0.1 x ratio is then no
    # sign of agreement
    v = judge(8, HALVES, _umap(36.0), GEOMETRY)
    assert any("not determined by these views" in w for w in v.warnings), v.warnings
    assert v.figures["linear_departure"] == 36.0
    assert judge(8, HALVES, _umap("inf"), GEOMETRY).warnings
    for fine in (0.002, 0.8, None):
        assert not any("not determined" in w for w in judge(8, HALVES, _umap(fine), GEOMETRY).warnings)
