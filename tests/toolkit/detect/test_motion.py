"""The constant-velocity model of pairs of edges (`detect.motion`)."""
from __future__ import annotations

import numpy as np

from pencilcal.toolkit.detect.motion import MIN_SEARCH_PX, MOTION_PRIOR_PX, EdgeMotion, match_pairs


def _moving(edges, v, k):
    """Bars' edges (M, 2, 4) moved by k times the velocity v (2,) [px a frame]."""
    return edges + k * np.tile(v, 2)


def test_the_motion_model_predicts_a_constant_velocity_and_learns_its_noise():
    e = np.array([[[0.0, 0, 100, 0], [100, 4, 0, 4]], [[0, 50, 100, 60], [100, 64, 0, 54]]])
    m = EdgeMotion()
    m.update(e)
    pred, search = m.search()
    # velocity unknown: searched as far as a hand-held target moves between two frames
    assert np.array_equal(pred, e) and np.all(search >= MOTION_PRIOR_PX)
    rng = np.random.default_rng(0)
    v = np.array([7.0, -3.0])
    for k in range(1, 12):
        m.update(_moving(e, v, k) + rng.normal(0, 0.3, e.shape))
    pred, search = m.search()
    assert np.abs(pred - _moving(e, v, 12)).max() < 2.0
    # the innovations (~1 px: the noise of three positions) make the search narrow
    assert np.sqrt(m.q) < 1.5 and np.all(search <= 4.5)
    # a jolt widens it
    m.update(_moving(e, v, 12) + 6.0)
    assert np.all(m.search()[1] >= 8.0)
    # a frame without the bars: the next prediction is two frames ahead, twice as uncertain
    sd1 = m.predict()[1]
    m.missed()
    pred2, sd2 = m.predict()
    assert np.allclose(sd2, 2 * sd1) and np.allclose(pred2, m.edges + 2 * m.velocity)




def test_unsigned_pairs_are_matched_by_position_and_turned_to_run_on():
    # a shaft's two edges, both running the same way; found the other way round and swapped
    e = np.array([[[0.0, 0, 300, 20], [0, 40, 300, 50]]])
    m = EdgeMotion(polar=False, prior_px=100.0, max_search_px=100.0)
    m.update(e)
    moved = e + [5.0, 2.0, 5.0, 2.0]
    m.update(moved[:, ::-1][..., [2, 3, 0, 1]])
    assert np.allclose(m.edges, moved) and np.allclose(m.velocity, [5.0, 2.0, 5.0, 2.0])
    pred, search = m.search()
    assert np.allclose(pred, e + 2 * np.array([5.0, 2.0, 5.0, 2.0]))
    # two pairs far apart, found in the other order
    two = np.concatenate([e, e + [0.0, 400, 0, 400]])
    assert match_pairs(two, two[::-1] + 3.0, 10.0).tolist() == [1, 0]
