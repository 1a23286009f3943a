"""The printed sheet: the analytic board is OpenCV's, the layout fits the paper."""
from __future__ import annotations

import numpy as np
import pytest

from pencilcal.toolkit.board.spec import board_from_dict
from pencilcal.toolkit.errors import InputError
from pencilcal.toolkit.synth.raster import polygon_coverage
from pencilcal.toolkit.synth.sheet import layout_sheet, sheet_raster

SHEET = layout_sheet()


def test_sheet_raster_matches_opencv_board_image():
    """The analytic board (black squares, marker bits and orientation) is OpenCV's board:
    at 2 px/mm every edge falls on a pixel border and the images agree exactly."""
    for squares, legacy in (([5, 4], False), ([4, 4], True)):
        board = board_from_dict({"type": "charuco", "squares": squares, "square": 14.0, "marker": 7.0,
                                 "dictionary": "DICT_5X5_100", "legacy": legacy})
        sheet = layout_sheet(board, radius=(10.0, 30.0), paper="a4")
        polys = [(p * 2.0 - 0.5, s) for p, s in sheet.ink_polygons[:len(sheet.ink_polygons) - sheet.pencil.count]]
        W, H = squares[0] * 28, squares[1] * 28
        ours = np.rint(255 * (1 - np.clip(polygon_coverage(polys, W, H), 0, 1))).astype(np.uint8)
        ref = board.cv2_board().generateImage((W, H), marginSize=0, borderBits=1)
        assert np.array_equal(ours, ref)


def test_sheet_layout_and_ink():
    s = SHEET
    x0, y0, x1, y1 = s.content_bounds
    px0, py0 = s.paper_origin
    assert px0 + s.margin <= x0 and x1 <= px0 + s.paper_size[0] - s.margin
    assert py0 + s.margin <= y0 and y1 <= py0 + s.paper_size[1] - s.margin
    # the fan sits beside the board: no bar reaches x < board width
    assert min(b[:, 0].min() for b in s.bars) >= s.board.size[0] + 7.9
    # bar k's centre line runs from radius[0] to radius[1] along (cos, sin) of its angle
    v, (r0, r1) = s.pencil.vertex, s.pencil.radius
    for th, bar in zip(s.pencil.angles, s.bars):
        d = np.array([np.cos(th), np.sin(th)])
        mid = (bar[0] + bar[3]) / 2, (bar[1] + bar[2]) / 2
        assert np.allclose(mid[0], v + r0 * d) and np.allclose(mid[1], v + r1 * d)
        assert s.ink_at(v + (r0 + r1) / 2 * d) and not s.ink_at(v + (r0 + r1) / 2 * d + 0.6 * d[::-1] * [-1, 1])
    assert s.ink_at([12.5, 12.5]) and not s.ink_at([37.5, 1.0]) and not s.ink_at(v)
    with pytest.raises(InputError, match="does not fit"):
        layout_sheet(board_from_dict({"type": "charuco", "squares": [9, 7], "square": 30.0, "marker": 22.0,
                                      "dictionary": "DICT_5X5_100"}))
    with pytest.raises(InputError, match="overlap"):
        layout_sheet(radius=(1.0, 50.0), width=2.0)
    assert sheet_raster(s, 20).shape == (165, 234)
