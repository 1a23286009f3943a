"""Live frame sources: a camera, a URL, or a video file that is still being written.

`open_stream(spec)` is what `--source` opens, beside `images.open_images` (IMAGES):

- a camera index (``0``, ``1``) or a URL OpenCV opens (``rtsp://...``, ``http://...``):
  *live* mode. A reader thread takes every frame the source delivers and keeps the newest
  few; when the consumer is slower than the source the oldest waiting frame is dropped,
  so the results stay current. Every dropped frame is counted (`StreamSource.dropped`),
  and the frames' indices count them too (frame_000012 after frame_000009: two dropped).
- a file path: *follow* mode, for a recording that another program is still writing
  (a streamable container: MJPEG, MPEG-TS, Matroska or AVI as an endoscope recorder or
  ``ffmpeg`` writes them; an MP4 is readable only once finished). Every frame is read, in
  order, as it is written: at the current end the file is reopened when it has grown, and
  the frames already read are skipped (decoded again: a file being written has no index to
  seek by, so each reopening costs more as the recording grows; for a live feed of more
  than a few minutes give the camera or the URL instead). The stream ends when the file
  has not grown for `idle_s` seconds.

Either stream ends at the end of the source or on Ctrl-C (SIGINT): the frame in progress
is finished and the iteration stops, so the caller writes its results for the frames
done; a second Ctrl-C interrupts at once as usual.

Frames are `images.Frame` records (name ``frame_000123``, index, image BGR or grey);
`StreamSource` has the `ImageSource` attributes the commands use (`description`, `kind`
"stream", `paths`, `gray`, `max_pixels`, `fps`) and counts `read` and `dropped` frames.

Example
-------
>>> import tempfile, os, numpy as np, cv2
>>> path = os.path.join(tempfile.mkdtemp(), "rec.mjpeg")
>>> with open(path, "wb") as f:
...     for i in range(3):
...         _ = f.write(cv2.imencode(".jpg", np.full((24, 32, 3), 40 * i, np.uint8))[1].tobytes())
>>> src = open_stream(path, idle_s=0.2)
>>> [f.name for f in src], src.dropped
(['frame_000000', 'frame_000001', 'frame_000002'], 0)
"""
from __future__ import annotations

import collections
import contextlib
import os
import signal
import threading
import time
from pathlib import Path

from pencilcal.toolkit.errors import InputError
from pencilcal.toolkit.io.images import (DEFAULT_MAX_PIXELS, Frame, frame_size_error, quiet_c_stderr, read_ahead,
                                         with_grey)

__all__ = ["StreamSource", "open_stream", "is_stream_spec", "FOLLOW_IDLE_S", "LIVE_BUFFER", "LIVE_SILENCE_S"]

#: Follow mode ends when the file has not grown for this long [s].
FOLLOW_IDLE_S = 5.0
#: Live mode keeps at most this many frames waiting; an older one is dropped for a newer.
LIVE_BUFFER = 2
#: A live source that delivers nothing for this long has ended [s]: the run ends with the
#: frames read (a warning says so).
LIVE_SILENCE_S = 10.0
_POLL_S = 0.05


def is_stream_spec(spec):
    """Whether `spec` names a live source (a camera index or a URL) rather than a file."""
    s = str(spec).strip()
    return s.isdigit() or "://" in s


class StreamSource:
    """Frames of a camera, a URL or a growing video file, as they come (module docstring).

    spec: a camera index, a URL or a file path; mode: "live" or "follow" (default: live
    for a camera index or URL, follow for a file); gray: frames as one 8-bit channel
    (keep_colour: their colour images too, `images.Frame.colour`);
    idle_s: follow mode ends after the file stops growing for this long [s] (None:
    FOLLOW_IDLE_S); buffer: live
    mode's waiting frames at most.
    """

    kind = "stream"

    def __init__(self, spec, *, mode=None, gray=False, idle_s=None, buffer=LIVE_BUFFER,
                 max_pixels=DEFAULT_MAX_PIXELS, keep_colour=False):
        idle_s = FOLLOW_IDLE_S if idle_s is None else idle_s
        self.spec = str(spec).strip()
        if not self.spec:
            raise InputError("--source: empty (give a camera index, a URL or a video file)")
        self.mode = mode or ("live" if is_stream_spec(self.spec) else "follow")
        if self.mode not in ("live", "follow"):
            raise InputError(f"{self.spec}: unknown stream mode {self.mode!r} (live or follow)")
        if not idle_s > 0 or not int(buffer) >= 1:
            raise InputError(f"{self.spec}: idle_s must be positive and buffer at least 1")
        self.gray, self.max_pixels, self.idle_s, self.buffer = gray, max_pixels, float(idle_s), int(buffer)
        self.keep_colour = bool(gray and keep_colour)
        self.description = self.spec
        self.paths = [Path(self.spec)] if self.mode == "follow" else []
        self.read = 0
        self.dropped = 0
        self.fps = None
        self.interrupted = False
        self.stalled = False  # a live source that sent nothing for LIVE_SILENCE_S: the stream ended there
        self._stop = threading.Event()
        self._head = []
        if self.mode == "follow" and not Path(self.spec).is_file():
            raise InputError(f"{self.spec}: no such video file (--source takes a camera index, a URL or a file "
                             "being written)")
        if self.mode == "live":
            self._check_opens()

    def _target(self):
        return int(self.spec) if self.spec.isdigit() else self.spec

    def _check_opens(self):
        cap = _capture(self._target())
        try:
            if not cap.isOpened():
                what = "camera" if self.spec.isdigit() else "stream"
                raise InputError(f"{self.spec}: cannot open this {what}")
            self.fps = _fps(cap)
        finally:
            cap.release()

    def __len__(self):
        return 0  # unknown: a stream's length is known only at its end

    def head(self, k):
        """The first `k` frames' images (decoded ones), read now and yielded again by the
        iteration: what a sequence-level step (the valid region) sees before the run."""
        if not self._head:
            self._head, self._rest = read_ahead(iter(self), k)
        return [f.image for f in self._head if f.image is not None]

    def stop(self):
        """End the iteration after the current frame (what Ctrl-C does)."""
        self._stop.set()

    def refs(self):
        """The frames (a stream is decoded here, as a video is): for `parallel.map_frames`."""
        return iter(self)

    def __iter__(self):
        if self._head:
            head, self._head = self._head, []
            yield from head
            yield from self._rest
            return
        import cv2

        cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_SILENT)
        with _stop_on_sigint(self):
            frames = self._live() if self.mode == "live" else self._follow()
            for image, index in frames:
                image, colour = with_grey(image) if self.gray else (image, None)
                err = frame_size_error(image, self.max_pixels)
                image = None if err else image
                self.read += 1
                yield Frame(f"frame_{index:06d}", index, image, err, None,
                            None if err or not self.keep_colour else colour)
                if self._stop.is_set():
                    return

    def _follow(self):
        """(image, index) of every frame of a growing file, in order (module docstring).

        The newest frame read is held back until the next one is read or the file has
        stopped growing: at the end of a file being written it may be only partly there."""
        path = self.spec
        done, last_size, last_growth, next_open, grown = 0, -1, time.monotonic(), 0.0, False
        while not self._stop.is_set():
            size, now = _size(path), time.monotonic()
            if size != last_size:
                last_size, last_growth, grown = size, now, True
            final = now - last_growth > self.idle_s
            if (grown and now >= next_open) or final:
                grown = False
                t0 = time.monotonic()
                cap = _reopened(path, done)
                # reopening re-reads the frames done: not more often than it costs
                next_open = time.monotonic() + max(0.2, 2.0 * (time.monotonic() - t0))
                if cap is not None:
                    if self.fps is None:
                        self.fps = _fps(cap)
                    pending = None
                    try:
                        while not self._stop.is_set():
                            with quiet_c_stderr():  # FFmpeg's own lines about the partial last frame
                                ok, img = cap.read()
                            if not ok or img is None:
                                break
                            if pending is not None:
                                yield pending, done
                                done += 1
                            pending = img
                    finally:
                        cap.release()
                    if final and pending is not None:
                        yield pending, done
                        done += 1
            if final:
                return
            time.sleep(_POLL_S)

    def _live(self):
        """(image, index) of the newest frames of a camera or URL; a reader thread keeps at
        most `buffer` waiting and counts the ones it drops."""
        waiting = collections.deque()
        lock = threading.Condition()
        state = {"end": False, "error": None}

        def reader():
            cap = _capture(self._target())
            index, last = 0, time.monotonic()
            try:
                while not self._stop.is_set():
                    ok, img = cap.read()
                    if not ok or img is None:
                        if not cap.isOpened() or time.monotonic() - last > LIVE_SILENCE_S or not self.spec.isdigit():
                            break
                        time.sleep(_POLL_S)
                        continue
                    last = time.monotonic()
                    with lock:
                        if len(waiting) >= self.buffer:
                            waiting.popleft()
                            self.dropped += 1
                        waiting.append((img, index))
                        lock.notify()
                    index += 1
            except Exception as e:  # noqa: BLE001 - reported in the consumer's thread
                state["error"] = e
            finally:
                cap.release()
                with lock:
                    state["end"] = True
                    lock.notify()

        thread = threading.Thread(target=reader, name="pencilcal-stream", daemon=True)
        thread.start()
        last = time.monotonic()
        try:
            while True:
                with lock:
                    while not waiting and not state["end"] and not self._stop.is_set():
                        lock.wait(_POLL_S)
                        if time.monotonic() - last > LIVE_SILENCE_S:  # a source that stopped sending
                            self.stalled = True
                            self._stop.set()
                    if waiting:
                        item = waiting.popleft()
                    elif state["end"] or self._stop.is_set():
                        break
                    else:
                        continue
                last = time.monotonic()
                yield item
            if state["error"] is not None:
                raise InputError(f"{self.spec}: reading the stream failed: {state['error']}")
        finally:
            self._stop.set()
            thread.join(timeout=2.0)


def _capture(target):
    import cv2

    # a network source that stops sending ends a read after the silence (FFmpeg's own
    # default waits 30 s)
    ms = int(LIVE_SILENCE_S * 1000)
    timeouts = [cv2.CAP_PROP_OPEN_TIMEOUT_MSEC, ms, cv2.CAP_PROP_READ_TIMEOUT_MSEC, ms]
    with quiet_c_stderr():
        return cv2.VideoCapture(target, cv2.CAP_ANY, timeouts) if isinstance(target, str) else cv2.VideoCapture(target)


def _fps(cap):
    import cv2

    fps = float(cap.get(cv2.CAP_PROP_FPS))
    return fps if 0 < fps < 1000 else None


def _size(path):
    try:
        return os.path.getsize(path)
    except OSError:
        return -1


def _reopened(path, skip):
    """A capture of `path` past its first `skip` frames, or None when it cannot be opened
    yet (a header not written) or holds no more frames. Frames are skipped by grabbing
    them: a file still being written has no index to seek by."""
    cap = _capture(path)
    if not cap.isOpened():
        cap.release()
        return None
    with quiet_c_stderr():
        for _ in range(skip):
            if not cap.grab():
                cap.release()
                return None
    return cap


@contextlib.contextmanager
def _stop_on_sigint(source):
    """While iterating in the main thread: the first Ctrl-C stops `source` after the current
    frame (`source.interrupted` says so); the previous handler is back for a second one."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.getsignal(signal.SIGINT)

    def handler(signum, frame):
        source.interrupted = True
        source.stop()
        signal.signal(signal.SIGINT, previous)

    signal.signal(signal.SIGINT, handler)
    try:
        yield
    finally:
        if signal.getsignal(signal.SIGINT) is handler:
            signal.signal(signal.SIGINT, previous)


def open_stream(spec, *, mode=None, gray=False, idle_s=None, buffer=LIVE_BUFFER,
                max_pixels=DEFAULT_MAX_PIXELS, keep_colour=False):
    """Open `--source`: a camera index, a URL, or a video file still being written. See
    `StreamSource`."""
    return StreamSource(spec, mode=mode, gray=gray, idle_s=idle_s, buffer=buffer, max_pixels=max_pixels,
                        keep_colour=keep_colour)
