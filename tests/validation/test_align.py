"""Alignment of a reconstruction to the board frame."""
from __future__ import annotations

import numpy as np
import pytest

from pencilcal.toolkit.errors import EstimationError
from pencilcal.toolkit.geometry.frames import rotation_angle, rotation_from_rotvec
from pencilcal.validation.align import align_rotations, align_similarity, l1_rotation_mean, umeyama
from pencilcal.validation.metrics import coverage, summary


def test_l1_mean_ignores_outliers(rng):
    R0 = rotation_from_rotvec([0.2, 0.1, -0.4])
    noise = rotation_from_rotvec(rng.normal(scale=np.radians(0.2), size=(40, 3)))
    Rs = noise @ R0
    Rs[:8] = rotation_from_rotvec(rng.normal(size=(8, 3)))  # 20% wild votes
    M = l1_rotation_mean(Rs)
    assert np.degrees(rotation_angle(M, R0)) < 0.15


def test_align_rotations_exact(rng):
    R_wt = rotation_from_rotvec([1.0, 0.5, -0.3])
    R_cw = rotation_from_rotvec(rng.normal(size=(15, 3)))
    M, inl = align_rotations(R_cw, R_cw @ R_wt)
    assert np.degrees(rotation_angle(M, R_wt)) < 1e-9 and inl.all()


def test_similarity_with_outliers(rng):
    R = rotation_from_rotvec([0.3, -0.8, 0.2])
    s, t = 37.5, np.array([10.0, -4.0, 300.0])
    cw = rng.normal(size=(30, 3))
    ct = s * cw @ R.T + t
    ct[:5] += rng.normal(scale=50.0, size=(5, 3))
    S, inl = align_similarity(cw, ct)
    assert not inl[:5].any() and inl[5:].all()
    assert S.scale == pytest.approx(s, rel=1e-9)
    np.testing.assert_allclose(S.R_target_from_world, R, atol=1e-9)
    np.testing.assert_allclose(S.apply(cw[5:]), ct[5:], atol=1e-6)


def test_degenerate():
    with pytest.raises(EstimationError):
        umeyama(np.zeros((4, 3)), np.ones((4, 3)))
    with pytest.raises(EstimationError, match="three"):
        align_similarity(np.zeros((2, 3)), np.zeros((2, 3)))


def test_summary_and_coverage(rng):
    e = rng.normal(size=20000)
    s = summary(e)
    assert s["rmse"] == pytest.approx(1.0, rel=0.03) and s["median"] == pytest.approx(0.674, rel=0.05)
    c = coverage(e, np.ones_like(e))
    assert abs(c["fraction"] - c["expected"]) < 0.02
    assert summary([None, np.nan])["count"] == 0
