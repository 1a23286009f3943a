"""Live sources: a video file still being written (follow mode), a live source that drops
frames when the consumer is slower, Ctrl-C, bad sources."""
from __future__ import annotations

import threading
import time

import cv2
import numpy as np
import pytest

from pencilcal.toolkit.errors import InputError
from pencilcal.toolkit.io.stream import is_stream_spec, open_stream


def _jpeg(i, shape=(48, 64)):
    """A frame whose grey level tells its number."""
    return cv2.imencode(".jpg", np.full((*shape, 3), 5 * i, np.uint8))[1].tobytes()


def _number(img):
    return int(round(float(img[..., 0].mean()) / 5))


def write_progressively(path, frames, pause=0.02, started=None):
    """Append `frames` JPEG frames to `path` (an MJPEG recording), each in two writes, as a
    recorder does; returns the thread."""

    def run():
        with open(path, "ab", buffering=0) as f:
            for i in range(frames):
                b = _jpeg(i)
                f.write(b[: len(b) // 2])
                time.sleep(pause / 2)
                f.write(b[len(b) // 2:])
                time.sleep(pause / 2)

    path.write_bytes(b"")
    th = threading.Thread(target=run, daemon=True)
    th.start()
    return th


def test_follow_reads_every_frame_of_a_growing_file_in_order(tmp_path):
    path = tmp_path / "rec.mjpeg"
    writer = write_progressively(path, 30)
    src = open_stream(path, idle_s=0.5)
    assert src.mode == "follow" and src.paths == [path]
    got = [(f.index, _number(f.image)) for f in src]
    writer.join()
    assert got == [(i, i) for i in range(30)]
    assert src.read == 30 and src.dropped == 0 and not src.interrupted


def test_frames_come_while_the_file_is_still_written(tmp_path):
    path = tmp_path / "rec.mjpeg"
    writer = write_progressively(path, 40, pause=0.03)
    first = next(iter(open_stream(path, idle_s=0.5)))
    assert writer.is_alive() and first.index == 0  # the first frame before the recording ends
    writer.join()


def test_a_live_source_drops_the_frames_a_slow_consumer_cannot_take(tmp_path):
    path = tmp_path / "rec.mjpeg"
    path.write_bytes(b"".join(_jpeg(i) for i in range(40)))
    src = open_stream(path, mode="live", buffer=1)
    frames = []
    for f in src:
        frames.append(f)
        time.sleep(0.02)
    assert src.read == len(frames) and src.read + src.dropped == 40 and src.dropped > 0
    idx = [f.index for f in frames]
    assert idx == sorted(idx) and all(_number(f.image) == f.index for f in frames)  # indices count the drops


def test_stop_ends_the_stream_after_the_current_frame(tmp_path):
    path = tmp_path / "rec.mjpeg"
    path.write_bytes(b"".join(_jpeg(i) for i in range(20)))
    src = open_stream(path, idle_s=5.0)
    got = []
    for f in src:
        got.append(f.index)
        if len(got) == 3:
            src.stop()
    assert got == [0, 1, 2]


def test_head_is_read_first_and_yielded_again(tmp_path):
    path = tmp_path / "rec.mjpeg"
    path.write_bytes(b"".join(_jpeg(i) for i in range(6)))
    src = open_stream(path, idle_s=0.2, gray=True)
    head = src.head(3)
    assert len(head) == 3 and head[0].ndim == 2
    assert [f.index for f in src] == list(range(6))


def test_bad_sources_are_one_line_errors(tmp_path):
    with pytest.raises(InputError, match="no such video file"):
        open_stream(tmp_path / "absent.mjpeg")
    with pytest.raises(InputError, match="cannot open this camera"):
        open_stream("97")
    with pytest.raises(InputError, match="empty"):
        open_stream(" ")
    assert is_stream_spec("0") and is_stream_spec("rtsp://host/x") and not is_stream_spec("a.mp4")
