"""The hand-made list of what each unmasked real frame shows: its structure, and that it covers
the real frames (tests/data/real_frames_truth.yaml, read by frames_truth.py).

Without ../shared/data only the file itself is checked; with it, every frame of each folder must
be listed (and nothing else) and every axis must lie inside its frame.
"""
from __future__ import annotations

import numpy as np
import pytest

from tests.conftest import data_dir
from tests.toolkit.detect.shaft.frames_truth import KINDS, SETS, TRUTH_PATH, load_real_frames_truth

EXTENSIONS = {"laparoscopy-hysterectomy-frames": ".jpg", "dvrk-lnd-phantom-sequence": ".png"}


@pytest.fixture(scope="module")
def truth():
    return load_real_frames_truth()


def _instruments(truth):
    for set_name, frames in truth.items():
        for frame, entry in frames.items():
            for k, inst in enumerate(entry["instruments"]):
                yield f"{set_name}/{frame}#{k}", inst


def test_sets_and_frame_entries(truth):
    assert sorted(truth) == sorted(SETS)
    assert len(truth["laparoscopy-hysterectomy-frames"]) == 24
    assert len(truth["dvrk-lnd-phantom-sequence"]) == 20
    for set_name, frames in truth.items():
        for frame, entry in frames.items():
            assert frame.endswith(EXTENSIONS[set_name]), frame
            assert isinstance(entry["notes"], str) and entry["notes"].strip(), frame
    # the phantom sequence shows its one instrument in every frame
    assert all(len(e["instruments"]) == 1 for e in truth["dvrk-lnd-phantom-sequence"].values())


def test_instrument_fields(truth):
    for where, inst in _instruments(truth):
        axis = inst["axis"]
        assert axis.shape == (4,) and np.isfinite(axis).all(), where
        length = np.hypot(axis[2] - axis[0], axis[3] - axis[1])
        assert 0 < inst["width_px"] < 500, where
        assert inst["kind"] in KINDS, where
        assert isinstance(inst["visible"], str) and inst["visible"].strip(), where
        assert isinstance(inst["uncertain"], bool), where
        # a "shaft" shows a straight part of at least 1.5 widths (the file's definition)
        if inst["kind"] == "shaft":
            assert length >= 1.5 * inst["width_px"], (where, length, inst["width_px"])
        else:
            assert length > 0, where


def test_loader_names_the_file_on_bad_entries(tmp_path):
    bad = tmp_path / "truth.yaml"
    bad.write_text("dvrk-lnd-phantom-sequence:\n  1.png:\n    instruments:\n      - axis: [0, 0, 1, 1]\n"
                   "        width_px: 5\n        kind: shaft\n    notes: x\n")
    with pytest.raises(ValueError, match="1.png: an instrument needs"):
        load_real_frames_truth(bad)
    bad.write_text("dvrk-lnd-phantom-sequence:\n  1.png:\n    instruments: []\n")
    with pytest.raises(ValueError, match="instruments and notes"):
        load_real_frames_truth(bad)


@pytest.mark.parametrize("set_name", SETS)
def test_every_frame_listed_and_axes_inside(truth, set_name):
    import cv2

    root = data_dir("real-instruments") / set_name
    files = sorted(p.name for p in root.iterdir() if p.suffix == EXTENSIONS[set_name])
    assert files, root
    assert sorted(truth[set_name]) == files, f"{TRUTH_PATH} and {root} list different frames"
    for frame, entry in truth[set_name].items():
        img = cv2.imread(str(root / frame), cv2.IMREAD_UNCHANGED)
        assert img is not None, root / frame
        h, w = img.shape[:2]
        for inst in entry["instruments"]:
            x = inst["axis"][[0, 2]]
            y = inst["axis"][[1, 3]]
            assert ((x >= -0.5) & (x <= w - 0.5) & (y >= -0.5) & (y <= h - 0.5)).all(), \
                (frame, inst["axis"], (w, h))
