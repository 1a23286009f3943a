"""The vertex of a pencil of detected bars: spurious segments rejected, raw arrays and
results alike, errors. Scenes: tests/toolkit/detect/scenes.py."""
from __future__ import annotations

import numpy as np
import pytest

from pencilcal.toolkit.errors import EstimationError, InputError
from pencilcal.toolkit.detect.assemble import assemble_pencil
from pencilcal.toolkit.detect.bars import detect_bars
from tests.toolkit.detect.scenes import fan_scene, line_errors


def test_assemble_pencil_rejects_spurious_segments(hd):
    """The fan plus two spurious bars that miss the vertex: both rejected, the vertex within
    3 sd of the truth."""
    rng = np.random.default_rng(8)
    spurious = [np.array([[15.0, 30.0], [55.0, 34.0], [55.0, 35.5], [15.0, 31.5]]),
                np.array([[-40.0, 10.0], [-38.5, 10.0], [-30.0, 45.0], [-31.5, 45.0]])]
    img, pen, R, t, truth = fan_scene(hd, rng, extra=spurious)
    bars = detect_bars(img, "fld", camera=hd)
    assert len(bars) == 10
    fit, inl = assemble_pencil(bars, camera=hd)
    assert inl.sum() == 8
    good = [e[0] for e in line_errors(bars.ideal[inl], truth)]
    assert sorted(good) == list(range(8))
    v_true = hd.undistort_pixels(hd.project(t))
    d = fit.vertex - v_true
    assert d @ np.linalg.solve(fit.cov, d) < 3.0**2 * 2
    # raw arrays work the same (undistorted through the camera)
    fit2, inl2 = assemble_pencil(bars.segments, bars.angle_sigma, hd, offset_sigma=bars.offset_sigma)
    assert np.allclose(fit2.vertex, fit.vertex, atol=1e-6) and np.array_equal(inl, inl2)


def test_assemble_pencil_errors():
    with pytest.raises(EstimationError):
        assemble_pencil(np.array([[0.0, 0, 100, 0]]))
    with pytest.raises(InputError):
        assemble_pencil(np.zeros((3, 3)))
