"""A dense regular pencil (a Siemens star's edges) labelled from all its lines' phase at once."""
from __future__ import annotations

import numpy as np

from pencilcal.toolkit.geometry.frames import normalize, rotation_about_axis, rotation_to_z
from pencilcal.toolkit.pencil.assign import assign_spokes
from pencilcal.toolkit.pencil.periodic import periodic_labels, regular_kinds
from pencilcal.toolkit.pencil.spec import image_angles, pencil_from_dict


def _star(n):
    return pencil_from_dict({"start_deg": 0, "step_deg": 360.0 / n, "count": n, "shape": "wedge",
                             "radius": [12, 70]}).edge_angles()


def _pose(rng, x, tilt_deg):
    z = [0, 0, 1.0]
    return (rotation_to_z(normalize(np.r_[x, 1.0])).T @ rotation_about_axis(z, rng.uniform(0, 2 * np.pi))
            @ rotation_about_axis([1.0, 0, 0], np.radians(tilt_deg)) @ rotation_about_axis(z, rng.uniform(0, 2 * np.pi)))


def _seen(rng, th, kind, tilt, count, sd_deg):
    """A 128-wedge star's `count` edges seen at `tilt`, scattered by sd_deg: (angles, seen, x, R)."""
    x = rng.uniform(-0.2, 0.2, 2)
    R = _pose(rng, x, tilt)
    seen = np.sort(rng.choice(th.size, count, replace=False))
    return image_angles(R, x, th[seen]) + np.radians(sd_deg) * rng.standard_normal(count), seen, x, R


def test_a_small_dense_stars_scattered_lines_labelled_all_at_once(rng):
    """Lines scattering 0.25 deg against edges 1.4 deg apart (a small 128-wedge star): the
    screen's three-line windows labelled 11-13 of them; their common phase labels nearly
    all, each with its own edge up to one whole wedge (the star's symmetry)."""
    th, _, kind = _star(128)
    for tilt in (15, 35, 55):
        a, seen, x, _ = _seen(rng, th, kind, tilt, 120, 0.25)
        res = assign_spokes(a, th, x, np.radians(0.25), line_kind=kind[seen], spoke_kind=kind)
        u = res.spoke >= 0
        assert u.sum() >= 100, (tilt, u.sum())
        assert np.unique(np.remainder(res.spoke[u] - seen[u], 128)).size == 1


def test_clutter_lines_are_not_given_edges_and_random_lines_nothing(rng):
    """60 edges and 40 random lines: the edges are labelled right and the normal stays right;
    a random line within the fit's gate of an edge of its kind cannot be told from it (about
    a third of them, 12 here), the rest are left out; random lines alone are labelled nothing
    (Rayleigh's test)."""
    th, _, kind = _star(128)
    a, seen, x, R = _seen(rng, th, kind, 40, 60, 0.2)
    a = np.r_[a, rng.uniform(-np.pi, np.pi, 40)]
    lk = np.r_[kind[seen], rng.choice([-1, 1], 40)]
    res = assign_spokes(a, th, x, np.radians(0.2), line_kind=lk, spoke_kind=kind)
    u = res.spoke[:60] >= 0
    assert u.sum() >= 50
    assert np.unique(np.remainder(res.spoke[:60][u] - seen[u], 128)).size == 1
    assert np.count_nonzero(res.spoke[60:] >= 0) <= 16
    cos = max(abs(float(np.asarray(n) @ R[:, 2])) for n in (res.fit.normal, res.fit.normal_twin))  # either twin
    assert np.degrees(np.arccos(min(cos, 1.0))) < 1.0
    for _ in range(20):
        assert periodic_labels(rng.uniform(-np.pi, np.pi, 80), th, rng.choice([-1, 1], 80), kind) is None


def test_only_dense_regular_pencils():
    """A dartboard's 20 sector edges (10 of each kind) and an uneven fan are left to the screen."""
    dart = pencil_from_dict({"start_deg": 9, "step_deg": 18, "count": 20, "shape": "edge", "polarity": "dark"})
    th, _, kind = dart.edge_angles()
    assert regular_kinds(th, kind) == (10, {-1: regular_kinds(th, kind)[1][-1], 1: regular_kinds(th, kind)[1][1]})
    assert periodic_labels(th, th, kind, kind) is None
    uneven = np.radians(np.r_[np.arange(40) * 9.0, 1.0])
    assert regular_kinds(uneven, None) is None


def test_a_pencil_of_very_many_spokes_is_left_to_the_screen():
    """1000 spokes: the grid would hold millions of hypotheses; left to `assign`'s bounded
    screen (tests/toolkit/pencil/test_assign.py's memory test)."""
    th = np.radians(np.arange(1000) * 0.36)
    assert regular_kinds(th, None)[0] == 1000
    assert periodic_labels(th[::40], th) is None
