"""`validation.pivot_renders`: a rendered stereo pivot like a da Vinci endoscope's run through
the three `pencilcal fulcrum` command lines a user runs, the figures of one short sequence
guarded (docs/method.md, rendered stereo pivots end to end)."""
import json

import numpy as np
import pytest

from pencilcal.validation.fulcrum_pivots import pivot_camera
from pencilcal.validation.pivot_renders import draw_sequence, eye_axis, in_view, run_sequence, write_sequence


def test_sequence_is_seeded_and_seen_by_both_eyes():
    a, b = draw_sequence(2690, frames=6), draw_sequence(2690, frames=6)
    assert np.array_equal(a["fulcrum"], b["fulcrum"]) and len(a["frames"]) == 6
    assert 40.0 <= a["fulcrum"][2] <= 120.0
    for f in a["frames"]:
        # the axis passes the port within its play, the instrument 30-100 mm inside
        off = f["A"] - a["fulcrum"]
        assert np.linalg.norm(off - (off @ f["d"]) * f["d"]) < 3.0 and 30.0 <= f["L"] <= 100.0
    # the rendered rig is off the stated calibration, by about its stated sd
    assert 0 < np.abs(a["R_right_from_left"] - a["R_cal"]).max() < 5e-3



def test_each_eye_sees_the_axis_the_rig_carries_and_its_tip_in_view():
    s, cam = draw_sequence(2690, frames=3), pivot_camera()
    for i, f in enumerate(s["frames"]):
        A, d = eye_axis(s, i, 0)
        assert np.array_equal(A, f["A"]) and np.array_equal(d, f["d"])   # the left eye is the reference
        Ar, dr = eye_axis(s, i, 1)
        R, t = s["R_right_from_left"], s["t_right_from_left"]
        assert np.allclose(Ar, R @ f["A"] + t) and np.allclose(dr, R @ f["d"])
        for Ae, de in ((A, d), (Ar, dr)):   # draw_sequence keeps frames whose tip both eyes see 30 px inside
            tip = (Ae + f["L"] * de)[None]
            assert in_view(tip, cam.project(tip), (cam.width, cam.height), 30.0)[0]
    # in view: in front (over 5 mm deep) and the margin inside the image, its edges included
    X = np.array([[0.0, 0.0, 50.0], [0.0, 0.0, 4.0], [0.0, 0.0, 50.0], [0.0, 0.0, 50.0]])
    p = np.array([[2.0, 2.0], [100.0, 100.0], [1.9, 100.0], [637.0, 477.0]])
    assert in_view(X, p, (640, 480), 2.0).tolist() == [True, False, False, True]


@pytest.mark.slow
def test_short_sequence_end_to_end(tmp_path):
    # measured: seed 2690 (a matte shaft, the port 100 mm deep beyond the view's bottom), 16
    # frames: error [mm] / sigmas left 0.86/0.48, right 1.02/0.29, axes 0.24/0.66,
    # combined 0.19/0.73, triangulated 0.39/0.79
    write_sequence(draw_sequence(2690, frames=16), tmp_path)
    truth = json.loads((tmp_path / "truth.json").read_text())
    assert sorted(p.name for p in (tmp_path / "left").iterdir())[0] == "frame_000.jpg"
    assert (tmp_path / "stereo.yaml").exists() and truth["fulcrum_left_mm"][2] > 0
    r = run_sequence(tmp_path)
    assert not r.get("errors"), r.get("errors")
    for name, limit in (("left", 2.0), ("right", 2.0), ("axes", 1.0), ("combined", 1.0), ("triangulated", 1.5)):
        assert r[name]["error_mm"] < limit and r[name]["sigmas"] < 2.0, (name, r[name])
