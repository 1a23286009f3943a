"""The lines of one frame (the lines.json record): the default shortest line."""
from __future__ import annotations

import numpy as np


def test_default_min_length_grows_with_the_frame():
    from pencilcal.toolkit.detect.lines import default_min_length, lines_record

    assert default_min_length((1080, 1920), bars=True) == 36.0
    assert default_min_length((480, 640), bars=True) == 20.0
    assert default_min_length((1080, 1920), bars=False) == 20.0
    # lines_record writes no bar shorter than that: a 30 px bar on a 1080p frame is not
    # written by default, and is with min_length=20
    img = np.full((1080, 1920), 220, np.uint8)
    img[500:506, 900:930] = 30
    img[600:606, 700:900] = 30
    assert len(lines_record("f", img, None, "fld", bars=True)["segments"]) == 1
    assert len(lines_record("f", img, None, "fld", bars=True, min_length=20.0, proposal_scale=1.0)["segments"]) == 2
