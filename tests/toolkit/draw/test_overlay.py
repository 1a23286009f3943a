"""Overlays: the estimate lands where it is, and the writers leave whole files or nothing."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from pencilcal.toolkit.draw import OverlayWriter, draw_frame
from pencilcal.toolkit.draw.overlay import spoke_colour
from pencilcal.toolkit.errors import InputError
from pencilcal.toolkit.pencil.orient import orient_segments
from tests.helpers import fan, frame, hd_camera


def test_spokes_are_drawn_in_their_colour_where_they_are(rng):
    cam = hd_camera()
    pen = fan(radius=None)
    seg, R, t = frame(cam, pen, 30.0, 200.0, rng)
    o = orient_segments(cam, seg, pen)
    img = np.full((cam.height, cam.width), 128, np.uint8)
    out = draw_frame(img, orientation=o, segments=seg, camera=cam)
    assert out.shape == (cam.height, cam.width, 3)
    for s, k in zip(seg, o.spokes):
        m = np.round(0.5 * (s[:2] + s[2:])).astype(int)
        if 40 < m[0] < cam.width - 40 and 120 < m[1] < cam.height - 40:
            assert np.abs(out[m[1], m[0]].astype(int) - spoke_colour(int(k))).max() < 60


def test_a_failed_frame_says_why(rng):
    cam = hd_camera()
    o = orient_segments(cam, np.zeros((0, 4)), fan(radius=None), image="x.png")
    out = draw_frame(np.zeros((cam.height, cam.width), np.uint8), orientation=o)
    assert out[:60, :300].max() > 0  # the text box


def test_video_and_folder_writers(tmp_path):
    img = np.zeros((48, 64, 3), np.uint8)
    video = tmp_path / "o.mp4"
    with OverlayWriter(video, fps=5) as w:
        for i in range(4):
            w.write(f"{i:03d}", img)
    assert cv2.VideoCapture(str(video)).get(cv2.CAP_PROP_FRAME_COUNT) == 4
    assert sorted(p.name for p in tmp_path.iterdir()) == ["o.mp4"]  # no staging folder left
    with pytest.raises(InputError, match="already exists"):
        OverlayWriter(video)
    # an interrupted run leaves no video
    broken = tmp_path / "b.mp4"
    with pytest.raises(RuntimeError):
        with OverlayWriter(broken) as w:
            w.write("0", img)
            raise RuntimeError("interrupted")
    assert not broken.exists() and sorted(p.name for p in tmp_path.iterdir()) == ["o.mp4"]
    folder = tmp_path / "pngs"
    with OverlayWriter(str(folder) + "/") as w:
        w.write("a.png", img)
        w.write("b.jpg", img)
    assert sorted(p.name for p in folder.iterdir()) == ["a.png", "b.png"]
