"""Radial targets on rendered webcam frames with exact truth (`validation.radial_renders`):
spokes used, the twin, the normal's error against its bound and its sigma.

A Monte Carlo of 25 frames: five each of Siemens stars of 16, 32, 64 and 128 wedges and of
dartboards, dark on light and the reverse, tilts 15-60 deg, blur 0.6-1.5 px, noise, uneven
light, gamma 2.2, JPEG 70-95, k1 down to -0.3. The bounds below hold for this sample with
room for its size (a coverage of 25 frames scatters by 9 %); docs/method.md gives a 200-frame
run against the issue's figures. Measured on this sample, a star's edges all located jointly
with their neighbours and the blur fitted with them: every spoke used, 25 of 25 twins rightly
resolved, RMSE / bound 0.72, coverage 76 % (the 128-wedge stars' 3 of 5; before a negative
lag-1 correlation of the stations was believed in their sigmas, `radial_joint._MIN_RHO`: 0.69,
80 %; before their edges' outer ends were left out, `radial_joint.END_WINDOWS`: 0.74, 84 %, 2 of
5), the circles' normal RMSE 0.008 deg (with the blur measured and held: 0.69, 76 %, 0.007 deg)."""
from __future__ import annotations

import numpy as np
import pytest

from pencilcal.validation.radial_renders import ideal_lines_trial, radial_conditions, radial_summary, radial_trial


@pytest.fixture(scope="module")
def trials():
    return [radial_trial(c) for c in radial_conditions(25, seed=3)]


def test_spokes_and_twin(trials):
    s = radial_summary(trials)
    assert s["ok"] == 25
    assert s["spokes_used"] >= 0.95
    assert s["twin_right"] >= 0.92 and s["twin_right"] == s["resolved"]  # resolved only ever rightly
    for t in trials:
        # a 128-wedge star's far side at a steep tilt: its edges, located jointly with their
        # neighbours, are found, but the labelling may leave a few out (docs/method.md)
        assert t.spokes_used >= (0.85 if t.kind == "star128" else 1.0) * t.spokes, (t.kind, t.conditions)


def test_normal_against_its_bound_and_sigma(trials):
    s = radial_summary(trials)
    assert s["ratio"] <= 1.3
    assert 0.45 <= s["coverage"] <= 0.9
    # the circles' own normal: within a few hundredths of a degree
    assert s["circle_rmse_deg"] < 0.05


def test_the_estimator_covers_independent_lines():
    """The estimator alone (`ideal_lines_trial`): a 128-wedge star of this sample detected once,
    its lines replaced 200 times by the exact lines with independent noise at the sigmas the
    detector reported. Its normal's chi2 is then as the covariance says: coverage within the
    binomial 95 % interval of 68.3 % for 200 draws (61-75 %), mean chi2 near 2 (its sd 0.14).
    Measured: 67.0 %, mean 2.00, 253 lines (the frame's detected lines: chi2 3.16, before
    their edges' outer ends were left out). The detected lines' excess on such stars came
    from those ends (docs/method.md)."""
    cond = next(c for c in radial_conditions(25, seed=3) if c["kind"] == "star128")
    r = ideal_lines_trial(cond, 200)
    assert r["lines"] >= 0.9 * 256
    cover = float(np.mean(r["chi2"] <= -2.0 * np.log(1.0 - 0.6827)))
    assert 0.58 <= cover <= 0.78, cover
    assert 1.6 <= float(np.mean(r["chi2"])) <= 2.5


@pytest.mark.parametrize("seed, polarity, least", [(9332, "dark", 124), (9340, "dark", 120)])
def test_an_edge_the_joint_fit_left_short_is_located_again(seed, polarity, least):
    """128-wedge stars whose edges were clear over 20-30 px: the joint fit from there dropped
    the outer end's stations and weak steps and kept under 20 px, and the edge was lost, with
    its spoke where both of a wedge's edges were (spokes used 114 and 96 of 128). Located
    again from JOINT_SIGMAS apart, as the crowded edges are: 127 and 123."""
    cond = radial_conditions(1, seed=seed, kinds=("star128",))[0]
    cond["polarity"] = polarity
    t = radial_trial(cond)
    assert t.ok and t.twin_right
    assert t.spokes_used >= least, t.spokes_used
