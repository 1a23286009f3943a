"""`validation.pivot_renders`: a rendered stereo pivot like a da Vinci endoscope's run through
the three `pencilcal fulcrum` command lines a user runs, the figures of one short sequence
guarded (docs/method.md, rendered stereo pivots end to end)."""
import json

import numpy as np
import pytest

from pencilcal.validation.pivot_renders import draw_sequence, run_sequence, write_sequence


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
