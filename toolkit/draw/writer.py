"""Drawn frames out: one video (OpenCV's VideoWriter) or one PNG per frame in a folder.

`OverlayWriter(path)` writes to a video when `path` has a video suffix (.mp4, .avi, .mkv,
.mov) and to a folder of PNGs when it ends with a slash or is a folder. The video is
written beside its target and renamed over it when closed without error (an interrupted
run leaves no half-written video); PNGs are written one by one, each atomically.

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
from pathlib import Path

from pencilcal.toolkit.errors import InputError
from pencilcal.toolkit.io.files import atomic_write, check_writable, put_in_place, staging_folder

__all__ = ["OverlayWriter", "VIDEO_SUFFIXES"]

VIDEO_SUFFIXES = {".mp4": "mp4v", ".m4v": "mp4v", ".mov": "mp4v", ".avi": "MJPG", ".mkv": "MJPG"}


class OverlayWriter:
    """Write drawn frames (BGR uint8, all the same size) to a video or a folder of PNGs.

    path: the video file, or the folder (absent, empty, or with --force an earlier one);
    fps: the video's frame rate; force: replace an existing video / write into a folder
    that already holds files.
    """

    def __init__(self, path, fps=25.0, force=False):
        self.path = Path(path)
        self.fps = float(fps)
        self.force = force
        self._video = None
        self._tmp = None
        self.frames = 0
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
        """Add one drawn frame; `name` names its PNG in folder mode."""
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
        self.frames += 1

    def _open(self, width, height):
        import cv2

        self._tmp = staging_folder(self.path) / ("overlay" + self.path.suffix)
        fourcc = cv2.VideoWriter_fourcc(*VIDEO_SUFFIXES[self.path.suffix.lower()])
        self._video = cv2.VideoWriter(str(self._tmp), fourcc, self.fps, (int(width), int(height)))
        if not self._video.isOpened():
            raise InputError(f"{self.path}: OpenCV cannot write this video format here")

    def close(self, ok=True):
        """Finish: the video is renamed into place when `ok`, else removed."""
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
