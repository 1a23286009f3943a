"""The material cue's selection (`shaft.material_cue.select`): a strip lit beside an
instrument is no second instrument.

Beside a bright shaft the tissue lit by it, between the shaft's silhouette and a shadow,
is a band with two straight boundaries whose inside lies between its sides in lightness
(dark | mid | white). Beside a better shaft it is that shaft's halo and is dropped; the
same strip darker than both sides (a dark instrument lying beside the shaft), or one
between its sides but nowhere near a better shaft, is kept. The shafts here are built from
their two edge lines (`shaft.axis.midline_from_edges`) with a nominal camera; only the
selection is tested.
"""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from pencilcal.toolkit.detect.shaft.axis import midline_from_edges
from pencilcal.toolkit.detect.shaft.material_cue import MaterialShaft, select
from pencilcal.toolkit.detect.shaft.silhouette import EdgeLine

K = np.array([[640.0, 0, 320], [0, 640.0, 240], [0, 0, 1]])


def edge(y0, y1, out):
    """An edge from (100, y0) to (600, y1) [px], its normal out of the shaft up (-1) or down (+1)."""
    p0, p1 = np.array([100.0, y0]), np.array([600.0, y1])
    u = (p1 - p0) / np.linalg.norm(p1 - p0)
    n = out * np.array([-u[1], u[0]]) * np.sign(u[0])
    L = float(np.linalg.norm(p1 - p0))
    return EdgeLine(p0, u, n, 0.5 * L, 0.0, 0.0, 0.01, 1e-6, 0.0, L, 100, 1.0, 0.3)


def shaft(top, bottom, score, y_in, y_sides):
    """A `MaterialShaft` between edges at heights top and bottom (y at x = 100 and 600)."""
    m = midline_from_edges(K, edge(*top, -1.0), edge(*bottom, 1.0))
    # its run inside the view (the border cuts none: `shaft.distal` has no band to read beyond)
    band = SimpleNamespace(y_in=y_in, y_sides=y_sides, run_len=500.0, width_run=40.0, reach_run=False)
    poly = np.array([[100, top[0]], [600, top[1]], [600, bottom[1]], [100, bottom[0]]], np.float32)
    return MaterialShaft(midline=m, score=score, polarity="bright", band=band, poly_run=poly, poly_ext=poly)


def test_strip_lit_beside_a_bright_shaft_is_dropped():
    white = shaft((200.0, 180.0), (300.0, 280.0), 400.0, 220.0, (90.0, 60.0))
    # 6 px above the shaft's upper edge, 40 px wide, converging by 1 deg on it
    strip = shaft((150.0, 126.0), (194.0, 174.0), 150.0, 90.0, (40.0, 220.0))
    got = select([strip, white], 4)
    assert [s.score for s in got] == [400.0]


def test_dark_band_beside_a_bright_shaft_is_kept():
    white = shaft((200.0, 180.0), (300.0, 280.0), 400.0, 220.0, (90.0, 60.0))
    dark = shaft((150.0, 126.0), (194.0, 174.0), 150.0, 30.0, (40.0, 220.0))   # darker than both sides
    assert [s.score for s in select([dark, white], 4)] == [400.0, 150.0]


def test_strip_away_from_any_better_shaft_is_kept():
    white = shaft((200.0, 180.0), (300.0, 280.0), 400.0, 220.0, (90.0, 60.0))
    strip = shaft((20.0, 10.0), (60.0, 50.0), 150.0, 90.0, (40.0, 220.0))      # 120 px away: 3 of its widths
    assert [s.score for s in select([strip, white], 4)] == [400.0, 150.0]


def test_better_strip_keeps_the_worse_shaft():
    """Only a better shaft makes a strip its halo: the order is the score's."""
    white = shaft((200.0, 180.0), (300.0, 280.0), 100.0, 220.0, (90.0, 60.0))
    strip = shaft((150.0, 126.0), (194.0, 174.0), 150.0, 90.0, (40.0, 220.0))
    assert [s.score for s in select([strip, white], 4)] == [150.0, 100.0]
