"""The lines file's reader: every numeric field of a frame and of a shaft is checked, and a
wrong one is refused with the file, the frame (and shaft) and the key, never a traceback."""
from __future__ import annotations

import json

import numpy as np
import pytest

from pencilcal.toolkit.errors import InputError
from pencilcal.toolkit.io.lines_file import LineFrame, read_lines

SEG = [[0.0, 0.0, 10.0, 0.0], [0.0, 0.0, 0.0, 10.0]]
SHAFT = {"midline": [1.0, 2.0, 30.0, 40.0], "width_px": 12.0, "angle_sigma_deg": 0.2, "offset_sigma_px": 0.3,
         "edges": [[0.0, 2.0, 29.0, 40.0], [2.0, 2.0, 31.0, 40.0]], "convergence_deg": 0.5, "score": 3.0,
         "polarity": "dark", "cue": "edge"}


def _write(tmp_path, frame):
    p = tmp_path / "lines.json"
    p.write_text(json.dumps({"frames": [{"image": "ok.png", "segments": SEG}, frame]}))
    return p


def test_a_good_frame_and_shaft_read_back(tmp_path):
    p = _write(tmp_path, {"image": "a.png", "segments": SEG, "angle_sigma_deg": [0.1, 0.2],
                          "offset_sigma_px": [0.3, 0.4], "width_px": [2.0, 3.0], "shafts": [SHAFT]})
    fr = read_lines(p)[1]
    assert fr["angle_sigma_deg"].tolist() == [0.1, 0.2] and fr["shafts"][0]["width_px"] == 12.0
    assert fr["shafts"][0]["polarity"] == "dark"
    assert LineFrame.from_dict(fr).width_px.tolist() == [2.0, 3.0]


BAD_FRAMES = [
    ({"segments": [[0, 0, "10", 0]]}, "'segments' must contain only numbers"),
    ({"segments": [[0, 0, True, 0]]}, "'segments' must contain only numbers"),
    ({"segments": [[0, 0, None, 0]]}, "'segments' must contain only numbers"),
    ({"segments": "0 0 10 0"}, "'segments' must be a list"),
    ({"segments": SEG, "angle_sigma_deg": ["0.1", 0.2]}, "'angle_sigma_deg' must be a list of numbers"),
    ({"segments": SEG, "angle_sigma_deg": 0.1}, "'angle_sigma_deg' must be a list of numbers"),
    ({"segments": SEG, "angle_sigma_deg": [0.1]}, "'angle_sigma_deg' has 1 values for 2 segments"),
    ({"segments": SEG, "angle_sigma_deg": [0.1, float("nan")]}, "'angle_sigma_deg' must be finite and > 0"),
    ({"segments": SEG, "angle_sigma_deg": [0.1, -1.0]}, "'angle_sigma_deg' must be finite and > 0"),
    ({"segments": SEG, "offset_sigma_px": [float("inf"), 0.1]}, "'offset_sigma_px' must be finite and > 0"),
    ({"segments": SEG, "width_px": [1.0, "2"]}, "'width_px' must be a list of numbers"),
    ({"segments": SEG, "width_px": [1.0, float("nan")]}, "'width_px' must be finite and > 0"),
    ({"segments": SEG, "angle_sigma_error_deg": [0.1]}, "'angle_sigma_error_deg' has 1 values for 2 segments"),
    ({"segments": SEG, "angle_sigma_error_deg": [0.1, -0.2]}, "'angle_sigma_error_deg' must be finite and > 0"),
    ({"segments": SEG, "ok": "false"}, "'ok' must be true or false"),
    ({"segments": SEG, "shafts": {"midline": [0, 0, 1, 1]}}, "'shafts' must be a list"),
]
BAD_SHAFTS = [
    ({"midline": [0, 0, 10]}, "'midline' must be \\[x1, y1, x2, y2\\]"),
    ({"midline": "0 0 10 10"}, "'midline' must be"),
    ({"midline": [0, 0, "10", 10]}, "'midline' must contain only numbers"),
    ({"midline": [0, 0, float("nan"), 10]}, "'midline' must be finite"),
    ({"width_px": 84.0}, "needs a 'midline'"),
]
for key in ("width_px", "angle_sigma_deg", "offset_sigma_px"):
    BAD_SHAFTS += [({**SHAFT, key: "0.2"}, f"'{key}' must be a finite number > 0, got '0.2'"),
                   ({**SHAFT, key: [0.2]}, f"'{key}' must be a finite number > 0"),
                   ({**SHAFT, key: float("nan")}, f"'{key}' must be a finite number > 0, got nan"),
                   ({**SHAFT, key: float("inf")}, f"'{key}' must be a finite number > 0, got inf"),
                   ({**SHAFT, key: 0}, f"'{key}' must be a finite number > 0, got 0")]
# a limb band's own width sd (`band_width.band_width_sd` adds it): a number >= 0
BAD_SHAFTS += [({**SHAFT, "width_sd_px": v}, f"'width_sd_px' must be a finite number >= 0, got {v!r}")
               for v in ("0.2", float("nan"), -0.1)]
for key in ("convergence_deg", "score"):
    BAD_SHAFTS += [({**SHAFT, key: "1"}, f"'{key}' must be a finite number"),
                   ({**SHAFT, key: float("nan")}, f"'{key}' must be a finite number")]
BAD_SHAFTS += [({**SHAFT, "edges": [[0, 0, "1", 1]]}, "'edges' must contain only numbers"),
               ({**SHAFT, "edges": [[0, 0, float("inf"), 1]]}, "'edges' must be finite")]


@pytest.mark.parametrize("frame,msg", BAD_FRAMES, ids=[m for _, m in BAD_FRAMES])
def test_a_bad_frame_field_names_file_frame_and_key(tmp_path, frame, msg):
    p = _write(tmp_path, frame)
    with pytest.raises(InputError, match=msg) as e:
        read_lines(p)
    assert str(e.value).startswith(f"{p}: frame 1: ") and "\n" not in str(e.value)


@pytest.mark.parametrize("shaft,msg", BAD_SHAFTS, ids=[m for _, m in BAD_SHAFTS])
def test_a_bad_shaft_field_names_file_frame_shaft_and_key(tmp_path, shaft, msg):
    p = _write(tmp_path, {"segments": SEG, "shafts": [SHAFT, shaft]})
    with pytest.raises(InputError, match=msg) as e:
        read_lines(p)
    assert str(e.value).startswith(f"{p}: frame 1 shaft 1: ")


def test_non_finite_segment_coordinates_are_kept_for_the_estimators(tmp_path):
    """A NaN end point is the estimators' to report per frame (they drop the segment)."""
    p = _write(tmp_path, {"segments": [[0, 0, float("nan"), 0], [0, 0, 0, 10]]})
    assert np.isnan(read_lines(p)[1]["segments"][0, 2])
