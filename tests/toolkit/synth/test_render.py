"""Rendering: the 8-bit frames keep exact edges, detect as they project, repeat with a seed."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from pencilcal.toolkit.board.detect import detect_board
from pencilcal.toolkit.errors import InputError
from pencilcal.toolkit.geometry.frames import rotation_about_axis
from pencilcal.toolkit.synth.objects import Backdrop
from pencilcal.toolkit.synth.render import REFLECTANCE, render_frame
from pencilcal.toolkit.synth.sheet import layout_sheet
from tests.toolkit.synth.helpers import area_edge, board_pose, small_camera, true_edge_x

SHEET = layout_sheet()


def test_rendered_image_edges_within_005_px():
    """The same check on the 8-bit image render_frame writes: the left edge of the board's
    first column (paper to the left, black squares to the right), opencv lens, no blur or
    noise, linear gamma."""
    cam = small_camera("opencv")
    R, t = board_pose(30.0, 330.0, spin=0.05)
    img = render_frame(cam, R, t, SHEET, background="plain").astype(float)
    white = 255 * REFLECTANCE["paper"]
    black = 255 * REFLECTANCE["ink"]
    errs = []
    for j in (0, 2, 4):  # black squares in column 0
        y0, y1 = j * 25.0 + 3.0, j * 25.0 + 22.0
        p0 = cam.project(R @ [0.0, y0, 0.0] + t)
        p1 = cam.project(R @ [0.0, y1, 0.0] + t)
        rows = np.arange(int(np.ceil(min(p0[1], p1[1]))) + 1, int(max(p0[1], p1[1])) - 1)
        xt = true_edge_x(cam, R, t, rows, [0.0, 0.0, 0.0], [0.0, 1.0, 0.0])
        for v, x in zip(rows, xt):
            a = int(np.floor(x)) - 4
            dark = np.clip((white - img[v, a:a + 9]) / (white - black), 0, 1)
            errs.append(area_edge(dark, a) - x)
    assert len(errs) > 50
    assert np.max(np.abs(errs)) < 0.05


@pytest.mark.parametrize("model", ["opencv", "fisheye"])
def test_charuco_detection_on_renders_matches_projection(model):
    """detect_board on a rendered board finds every corner where cam.project puts it
    (to the corner detector's own accuracy, ~0.05 px rms): validates the whole chain."""
    cam = small_camera(model)
    R, t = board_pose(35.0, 330.0 if model == "opencv" else 170.0)
    img = render_frame(cam, R, t, SHEET, background="plain", blur_px=0.8)
    det = detect_board(img, SHEET.board)
    assert det.count == SHEET.board.corner_count
    pred = cam.project(SHEET.board.object_points()[det.ids] @ R.T + t)
    err = np.linalg.norm(det.corners - pred, axis=1)
    assert np.sqrt(np.mean(err ** 2)) < 0.08
    assert err.max() < 0.2


def test_realistic_render_on_the_table_is_still_accurate():
    cam = small_camera("opencv")
    R, t = board_pose(25.0, 330.0)
    img = render_frame(cam, R, t, SHEET, background="table", blur_px=0.6, noise=2.0, lighting=0.3, gamma=2.2,
                       color=True, rng=5)
    assert img.shape == (480, 640, 3) and img.dtype == np.uint8
    det = detect_board(img, SHEET.board)
    assert det.count == SHEET.board.corner_count
    pred = cam.project(SHEET.board.object_points()[det.ids] @ R.T + t)
    assert np.sqrt(np.mean(np.sum((det.corners - pred) ** 2, 1))) < 0.15
    # the table is textured: plenty of features off the sheet
    gray = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
    corners = cv2.goodFeaturesToTrack(gray, 500, 0.01, 5)
    assert corners is not None and len(corners) > 100


def test_determinism_with_a_seed():
    cam = small_camera("pinhole")
    R, t = board_pose(20.0, 330.0)
    kw = dict(blur_px=0.5, noise=3.0, lighting=0.3, gamma=2.2, background=Backdrop.around(SHEET, seed=2))
    a = render_frame(cam, R, t, SHEET, rng=7, **kw)
    b = render_frame(cam, R, t, SHEET, rng=np.random.default_rng(7), **kw)
    c = render_frame(cam, R, t, SHEET, rng=8, **kw)
    assert np.array_equal(a, b)
    assert not np.array_equal(a, c)


def test_camera_behind_the_sheet_is_an_error():
    cam = small_camera("pinhole")
    R, t = board_pose(0.0, 330.0)
    flipped = rotation_about_axis([0, 1.0, 0], np.pi) @ R  # sees the back of the sheet
    with pytest.raises(InputError, match="behind the sheet"):
        render_frame(cam, flipped, t, SHEET)
