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


@pytest.mark.parametrize("scale", [0.5, 0.37])
def test_at_a_smaller_scale_the_estimates_land_where_they_are_on_the_smaller_frame(rng, scale):
    cam = hd_camera()
    pen = fan(radius=None)
    seg, R, t = frame(cam, pen, 30.0, 200.0, rng)
    o = orient_segments(cam, seg, pen)
    # a frame with a sharp, bright pixel block: where it lands on the canvas says the mapping
    img = np.full((cam.height, cam.width), 128, np.uint8)
    img[500:508, 700:708] = 255
    full = draw_frame(img, orientation=o, segments=seg, camera=cam)
    out = draw_frame(img, orientation=o, segments=seg, camera=cam, scale=scale)
    h, w = out.shape[:2]
    assert (h % 2, w % 2) == (0, 0) and abs(w - scale * cam.width) <= 1 and abs(h - scale * cam.height) <= 1
    sx, sy = w / cam.width, h / cam.height
    ys, xs = np.nonzero(out[..., 1] > 200)
    near = (abs(xs - 703.5 * sx) < 8) & (abs(ys - 503.5 * sy) < 8)  # the block's centre (703.5, 503.5)
    assert abs(xs[near].mean() - ((703.5 + 0.5) * sx - 0.5)) < 0.3
    assert abs(ys[near].mean() - ((503.5 + 0.5) * sy - 0.5)) < 0.3
    for s, k in zip(seg, o.spokes):
        m = 0.5 * (s[:2] + s[2:])
        c = np.round((m + 0.5) * [sx, sy] - 0.5).astype(int)
        if 40 < m[0] < cam.width - 40 and 120 < m[1] < cam.height - 40:
            patch = out[c[1] - 1:c[1] + 2, c[0] - 1:c[0] + 2].reshape(-1, 3).astype(int)
            assert np.abs(patch - spoke_colour(int(k))).max(axis=1).min() < 60
    # the text box drawn on the smaller frame too, at its top left
    assert out[:80, :300].max() == 255 and full[:150, :600].max() == 255


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


def test_the_background_writer_draws_in_order_and_raises_its_errors(tmp_path):
    import threading

    video = tmp_path / "o.avi"
    drawn_in = []

    def draw(i):
        drawn_in.append((i, threading.current_thread().name))
        return np.full((48, 64, 3), 40 * i, np.uint8)

    with OverlayWriter(video, fps=5, background=True) as w:
        for i in range(5):
            w.write(f"{i:03d}", lambda i=i: draw(i))
    # drawn in the writer's own thread, in the order given, every frame in the video
    assert [i for i, _ in drawn_in] == list(range(5)) and {n for _, n in drawn_in} == {"pencilcal-overlay"}
    cap = cv2.VideoCapture(str(video))
    levels = [cap.read()[1].mean() for _ in range(5)]
    assert np.allclose(levels, [0, 40, 80, 120, 160], atol=2)  # MJPEG
    # an error of the thread is raised by the next write or by close, and leaves no video
    bad = tmp_path / "bad.avi"
    w = OverlayWriter(bad, background=True)
    w.write("0", lambda: np.zeros((48, 64, 3), np.uint8))
    w.write("1", lambda: 1 / 0)
    with pytest.raises(ZeroDivisionError):
        for i in range(50):
            w.write(str(i), np.zeros((48, 64, 3), np.uint8))
        w.close()
    w.close(ok=False)
    assert not bad.exists()
