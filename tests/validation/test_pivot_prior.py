"""`validation.pivot_prior`: the fulcrum prior's angle search scored per frame on rendered
pivots against each frame's true axis image."""
from types import SimpleNamespace

import numpy as np
import pytest

from pencilcal.validation.fulcrum_pivots import pivot_camera
from pencilcal.validation.pivot_prior import OFFSET_PX, prior_of, score_sequence, truth_axis
from pencilcal.validation.pivot_renders import DIAMETER_MM, draw_sequence, write_sequence


def test_truth_axis_is_the_axis_image():
    s = draw_sequence(2690, frames=4)
    K = pivot_camera().K
    for i, f in enumerate(s["frames"]):
        ln, c, w = truth_axis(s, i)
        for X in (f["A"], f["A"] + f["L"] * f["d"]):  # the port's axis point and the tip project onto it
            x = K @ X
            assert abs(ln[:2] @ (x[:2] / x[2]) + ln[2]) < 1e-6
        assert abs(ln[:2] @ c + ln[2]) < 1e-9 and 0 <= c[0] <= 639 and 0 <= c[1] <= 479
        assert 520.0 * DIAMETER_MM / 200.0 < w < 520.0 * DIAMETER_MM / 20.0
    # the right eye's axis is another line
    assert not np.allclose(truth_axis(s, 0, 1)[0], truth_axis(s, 0)[0])


def test_prior_is_the_fulcrum_image():
    s = draw_sequence(2690, frames=1)
    x = pivot_camera().K @ s["fulcrum"]
    p = prior_of(s)
    assert np.allclose(p.point[:2] / p.point[2], x[:2] / x[2])
    assert 1.0 < float(p.offset_sigma(np.array([1.0, 0.0]))) < 5.0  # the play 0.35 mm at 40-120 mm


@pytest.fixture(scope="module")
def short(tmp_path_factory):
    s = draw_sequence(2690, frames=2)
    folder = tmp_path_factory.mktemp("pivot")
    write_sequence(s, folder)
    return s, folder


def _shaft(ln, c, shift):
    """A stand-in `Shaft` whose midline is the line (3,) through c (2,) moved by shift [px] across it."""
    d = np.array([ln[1], -ln[0]])
    p = c + shift * ln[:2]
    return SimpleNamespace(ideal_midline=np.array([p - 50 * d, p + 50 * d]), score=1.0)


@pytest.mark.slow
def test_found_false_and_missed(short):
    s, folder = short
    truth = [truth_axis(s, i) for i in range(2)]

    calls = []

    def near(img, cam, prior):
        # frame 0 gets its axis 5 px off (found), frame 1 three tolerances off (false)
        k = len(calls)
        calls.append(img.shape)
        ln, c, w = truth[k]
        return [_shaft(ln, c, 5.0 if k == 0 else 3.0 * max(OFFSET_PX, 0.5 * w))]

    rows = score_sequence(folder, s, detect=near)
    assert calls == [(480, 640, 3)] * 2
    assert [(r["found"], r["false"]) for r in rows] == [(1, 0), (0, 1)]
    assert abs(rows[0]["offset_err_px"] - 5.0) < 1e-6 and rows[1]["angle_err_deg"] is None
    rows = score_sequence(folder, s, frames=[1], detect=lambda img, cam, prior: [])
    assert rows == [{"frame": 1, "found": 0, "false": 0, "angle_err_deg": None, "offset_err_px": None}]


@pytest.mark.slow
def test_the_search_through_the_true_fulcrum(short):
    # measured: seed 2690 (a matte shaft, its port beyond the view's bottom), both frames
    # found within 0.2 deg and 1 px of the true axis, none false
    s, folder = short
    rows = score_sequence(folder, s)
    assert sum(r["found"] for r in rows) == 2 and sum(r["false"] for r in rows) == 0
