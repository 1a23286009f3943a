"""The rasteriser: exact area coverage, and edges on the projected truth for every lens model."""
from __future__ import annotations

import numpy as np
import pytest

from pencilcal.toolkit.geometry.frames import rotation_about_axis
from pencilcal.toolkit.synth.raster import coverage, polygon_coverage, target_coverage
from tests.toolkit.synth.helpers import area_edge, small_camera, true_edge_x


def test_coverage_is_exact_area_for_random_boxes(rng):
    W, H = 40, 30
    for _ in range(20):
        x0, x1 = np.sort(rng.uniform(-5, W + 5, 2))
        y0, y1 = np.sort(rng.uniform(-5, H + 5, 2))
        quad = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]])
        sign = rng.choice([-1, 1])
        cov = polygon_coverage([(quad if sign > 0 else quad[::-1], 1)], W, H)
        u, v = np.arange(W), np.arange(H)
        ox = np.clip(np.minimum(u + 0.5, x1) - np.maximum(u - 0.5, x0), 0, None)
        oy = np.clip(np.minimum(v + 0.5, y1) - np.maximum(v - 0.5, y0), 0, None)
        assert np.abs(cov - oy[:, None] * ox[None, :]).max() < 1e-12


def test_coverage_triangle_area_and_holes():
    tri = np.array([[1.2, 0.7], [17.9, 3.3], [6.1, 12.4]])
    cov = polygon_coverage([(tri, 1)], 20, 15)
    e1, e2 = tri[1] - tri[0], tri[2] - tri[0]
    area = 0.5 * abs(e1[0] * e2[1] - e1[1] * e2[0])
    assert cov.sum() == pytest.approx(area, abs=1e-9)
    hole = np.array([[4.0, 3.0], [8.0, 3.0], [8.0, 6.0], [4.0, 6.0]])
    cov2 = polygon_coverage([(tri, 1), (hole, -1)], 20, 15)
    assert cov2.sum() == pytest.approx(area - 12.0, abs=1e-9)
    assert cov2.min() > -1e-12 and cov2.max() < 1 + 1e-12
    # the edge list form: order does not matter
    a, b = tri, np.roll(tri, -1, 0)
    direct = coverage(a[::-1, 0], a[::-1, 1], b[::-1, 0], b[::-1, 1], np.ones(3), 20, 15)
    assert np.abs(direct - cov).max() < 1e-12


@pytest.mark.parametrize("model", ["pinhole", "opencv", "fisheye"])
@pytest.mark.parametrize("spin_deg", [0.0, 25.0, 50.0])
def test_edges_land_on_the_projected_truth(model, spin_deg):
    """A half-plane edge under a strongly distorting lens: every row's edge position (the
    50 % crossing of the pixel-integrated profile) matches the projected edge curve."""
    cam = small_camera(model)
    R = rotation_about_axis([0.2, 1.0, 0.0], np.radians(35)) @ rotation_about_axis([0, 0, 1.0], np.radians(spin_deg))
    t = np.array([20.0, 10.0, 300.0 if model != "fisheye" else 150.0])
    half = np.array([[0.0, -1e5], [1e5, -1e5], [1e5, 1e5], [0.0, 1e5]])  # x > 0 of the target
    cov = target_coverage(cam, R, t, [(half, 1)])
    rows = np.arange(12, cam.height - 12, 5)
    xt = true_edge_x(cam, R, t, rows, [0.0, 0.0, 0.0], [0.0, 1.0, 0.0])
    slope = np.abs(np.gradient(xt, rows))
    with np.errstate(invalid="ignore"):
        keep = (xt > 20) & (xt < cam.width - 20) & (slope < 3.0)  # the row crosses the edge cleanly
    assert keep.sum() > 40
    errs = []
    for v, x in zip(rows[keep], xt[keep]):
        a = int(np.floor(x)) - 10
        row = cov[v, a:a + 21]
        if row[0] > 0.5:  # dark on the left: measure the bright side
            row = 1.0 - row
        if abs(row[0]) > 1e-9 or abs(row[-1] - 1.0) > 1e-9:
            continue  # another edge in the window: the plane's horizon, seen by the fisheye
        errs.append(area_edge(row, a) - x)
    assert len(errs) > 40
    assert np.max(np.abs(errs)) < 0.01  # measured ~1e-4 px
