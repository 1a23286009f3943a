"""Fixed-radius neighbours in numpy against scipy's KD-tree: the same pairs exactly."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from pencilcal.toolkit.geometry.neighbours import neighbours_within, pairs_within


def _sets(seed):
    rng = np.random.default_rng(seed)
    for trial in range(60):
        n = int(rng.integers(0, 600))
        pts = rng.uniform(-50, rng.uniform(1, 400), (n, int(rng.choice([2, 3, 4]))))
        if trial % 4 == 0:
            pts = np.round(pts)  # duplicates and lattice points: distances exactly at r
        yield rng, pts


@pytest.mark.parametrize("seed", [0, 1])
def test_pairs_within_is_query_pairs(seed):
    for rng, pts in _sets(seed):
        r = float(rng.choice([1.0, 2.0, rng.uniform(0.05, 60)]))
        want = cKDTree(pts).query_pairs(r, output_type="ndarray") if len(pts) else np.zeros((0, 2), int)
        want = want[np.lexsort((want[:, 1], want[:, 0]))]
        got = pairs_within(pts, r)
        assert got.shape == want.shape and np.array_equal(got, want)


@pytest.mark.parametrize("seed", [0, 1])
def test_neighbours_within_is_query_ball_point(seed):
    for rng, pts in _sets(seed):
        if not len(pts):
            assert all(a.size == 0 for a in neighbours_within(pts, 1.0))
            continue
        radii = rng.uniform(0, 1, len(pts)) ** 3 * 200  # from a fraction of a px to the whole set
        if rng.uniform() < 0.3:
            radii = np.round(radii)
        nb = cKDTree(pts).query_ball_point(pts, radii)
        i = np.repeat(np.arange(len(pts)), [len(x) for x in nb])
        j = np.concatenate([sorted(x) for x in nb]).astype(int)
        gi, gj = neighbours_within(pts, radii)
        assert np.array_equal(gi, i) and np.array_equal(gj, j)


def test_a_point_is_never_its_own_pair():
    pts = np.zeros((5, 2))
    assert pairs_within(pts, 1.0).tolist() == [[0, 1], [0, 2], [0, 3], [0, 4], [1, 2], [1, 3], [1, 4],
                                                [2, 3], [2, 4], [3, 4]]
