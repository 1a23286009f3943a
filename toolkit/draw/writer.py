"""Drawn frames out: one video (OpenCV's VideoWriter) or one PNG per frame in a folder.

`OverlayWriter(path)` writes to a video when `path` has a video suffix (.mp4, .avi, .mkv,
.mov) and to a folder of PNGs when it ends with a slash or is a folder. The video is
written beside its target and renamed over it when closed without error (an interrupted
run leaves no half-written video); PNGs are written one by one, each atomically.

With ``background=True`` the frames are drawn and encoded in a thread of their own, in the
order given: `write` takes the drawn frame or a function that draws it, and returns at once
unless `BACKGROUND_FRAMES` frames are already waiting (then it waits: a live source drops,
and counts, the frames it cannot hand over, `io.stream`). OpenCV's drawing and encoding
release the interpreter, so on two cores the overlay costs little beyond the measurement.
An error of the thread (a full disk) is raised by the next `write` or by `close`.

Example
-------
>>> import tempfile, os, numpy as np
>>> d = os.path.join(tempfile.mkdtemp(), "overlay") + os.sep
>>> with OverlayWriter(d) as w:
...     w.write("000.png", np.zeros((24, 32, 3), np.uint8))
>>> os.listdir(d)
['000.png']
"""
from __future__ import annotations

import os
import queue
import threading
from pathlib import Path

from pencilcal.toolkit.errors import InputError
from pencilcal.toolkit.io.files import atomic_write, check_writable, put_in_place, staging_folder

__all__ = ["OverlayWriter", "VIDEO_SUFFIXES", "BACKGROUND_FRAMES"]

VIDEO_SUFFIXES = {".mp4": "mp4v", ".m4v": "mp4v", ".mov": "mp4v", ".avi": "MJPG", ".mkv": "MJPG"}
#: With background=True, at most this many frames wait for the writing thread.
BACKGROUND_FRAMES = 3


class OverlayWriter:
    """Write drawn frames (BGR uint8, all the same size) to a video or a folder of PNGs.

    path: the video file, or the folder (absent, empty, or with --force an earlier one);
    fps: the video's frame rate; force: replace an existing video / write into a folder
    that already holds files; background: draw and write in a thread (module docstring).
    """

    def __init__(self, path, fps=25.0, force=False, background=False):
        self.path = Path(path)
        self.fps = float(fps)
        self.force = force
        self._video = None
        self._tmp = None
        self.frames = 0
        self._queue = self._thread = self._error = None
        self._raised = False
        if background:
            self._queue = queue.Queue(BACKGROUND_FRAMES)
        suffix = self.path.suffix.lower()
        self.kind = "video" if suffix in VIDEO_SUFFIXES and not str(path).endswith(os.sep) else "folder"
        if self.kind == "video":
            check_writable(self.path, force)
        else:
            if self.path.exists() and not self.path.is_dir():
                raise InputError(f"{self.path}: exists and is not a folder (give a folder/ or a .mp4 / .avi file)")
            if self.path.is_dir() and any(self.path.iterdir()) and not force:
                raise InputError(f"{self.path}: folder is not empty; pass --force to write the overlays into it")
            parent = self.path.parent if str(self.path.parent) else Path(".")
            if not parent.is_dir():
                raise InputError(f"{self.path}: folder {parent} does not exist")

    def __enter__(self):
        return self

    def write(self, name, frame):
        """Add one drawn frame (BGR uint8), or a function of no arguments that returns it
        (called in the writing thread with background=True); `name` names its PNG in folder
        mode."""
        if self._queue is None:
            self._write(name, frame() if callable(frame) else frame)
            return
        self._raise_error()
        if self._thread is None:
            self._thread = threading.Thread(target=self._drain, name="pencilcal-overlay", daemon=True)
            self._thread.start()
        self._queue.put((name, frame))
        self.frames += 1

    def _drain(self):
        """The writing thread: the frames in order until None; after an error it only empties
        the queue (the error is raised in the caller)."""
        while True:
            item = self._queue.get()
            if item is None:
                return
            if self._error is None:
                try:
                    name, frame = item
                    self._write(name, frame() if callable(frame) else frame, count=False)
                except BaseException as e:  # noqa: BLE001 - raised in the caller's thread
                    self._error = e

    def _raise_error(self):
        """Raise the writing thread's error, once."""
        if self._error is not None and not self._raised:
            self._raised = True
            raise self._error

    def _write(self, name, frame, count=True):
        import cv2

        if self.kind == "folder":
            self.path.mkdir(exist_ok=True)
            ok, buf = cv2.imencode(".png", frame)
            if not ok:
                raise InputError(f"{self.path / name}: cannot encode the overlay")
            atomic_write(self.path / (Path(name).stem + ".png"), buf.tobytes(), force=True)
        else:
            if self._video is None:
                self._open(frame.shape[1], frame.shape[0])
            self._video.write(frame)
        self.frames += count

    def _open(self, width, height):
        import cv2

        self._tmp = staging_folder(self.path) / ("overlay" + self.path.suffix)
        fourcc = cv2.VideoWriter_fourcc(*VIDEO_SUFFIXES[self.path.suffix.lower()])
        self._video = cv2.VideoWriter(str(self._tmp), fourcc, self.fps, (int(width), int(height)))
        if not self._video.isOpened():
            raise InputError(f"{self.path}: OpenCV cannot write this video format here")

    def close(self, ok=True):
        """Finish (the frames waiting written first): the video is renamed into place when
        `ok`, else removed; an error of the writing thread is raised here when `ok`."""
        if self._thread is not None:
            self._queue.put(None)
            self._thread.join()
            self._thread = None
        failed = self._error is not None
        self._close_video(ok and not failed)
        if ok and failed:
            self._raise_error()

    def _close_video(self, ok):
        import shutil

        if self._video is not None:
            self._video.release()
            self._video = None
            try:
                if ok:
                    self._check_whole()
                    put_in_place(self._tmp, self.path, force=self.force)
            finally:
                shutil.rmtree(self._tmp.parent, ignore_errors=True)

    def _check_whole(self):
        """InputError unless the finished video holds every frame written: OpenCV's writer
        drops frames without a word when the disk fills up."""
        import cv2

        cap = cv2.VideoCapture(str(self._tmp))
        try:
            held = int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) if cap.isOpened() else 0
        finally:
            cap.release()
        if held != self.frames:
            st = os.statvfs(self._tmp.parent)
            why = "no space left on device (the disk is full)" if st.f_bavail * st.f_frsize < (1 << 20) else \
                "OpenCV's video writer failed"
            raise InputError(f"{self.path}: cannot write: {why}: the video holds {held} of the {self.frames} frames; "
                             + ("the earlier one is kept" if self.path.exists() else "nothing was written"))

    def __exit__(self, exc_type, exc, tb):
        self.close(ok=exc_type is None)
        return False
