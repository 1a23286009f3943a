"""Image sources: a folder of images, a glob pattern, or a video file.

Every command that reads images takes one IMAGES argument and goes through `open_images`,
so they all accept the same inputs and fail the same way:

- an empty folder, a pattern that matches nothing, a missing path or an unreadable video
  is an InputError (one line, exit 1);
- an unreadable or truncated image, or a corrupt video frame, is *not* fatal: the frame
  is yielded with ``image=None`` and an error string, and commands record it as
  ``ok: false`` and warn.

Frames are decoded once, in order. Images are read with OpenCV (BGR, 8 or 16 bit as
stored); ``gray=True`` converts to single-channel 8 bit.

Example
-------
>>> import tempfile, os, numpy as np, cv2
>>> d = tempfile.mkdtemp()
>>> _ = cv2.imwrite(os.path.join(d, "b.png"), np.zeros((4, 6), np.uint8))
>>> _ = open(os.path.join(d, "a.png"), "wb").write(b"\\x89PNG broken")
>>> src = open_images(d)
>>> [(f.name, f.image is None, f.error is not None) for f in src]
[('a.png', True, True), ('b.png', False, False)]
"""
from __future__ import annotations

import contextlib
import glob as _glob
import os
import sys
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pencilcal.toolkit.errors import InputError

__all__ = ["Frame", "ImageSource", "open_images", "IMAGE_EXTENSIONS", "VIDEO_EXTENSIONS", "check_image_size"]

IMAGE_EXTENSIONS = {".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".pgm", ".ppm", ".webp"}
VIDEO_EXTENSIONS = {".mp4", ".avi", ".mov", ".mkv", ".m4v", ".mpg", ".mpeg", ".wmv", ".webm"}


@dataclass(frozen=True)
class Frame:
    """One frame: `name` (file name, or frame_000123 for video), `index` in the sequence,
    `image` (H, W[, 3]) uint8/uint16 or None when it could not be decoded, `error`."""

    name: str
    index: int
    image: np.ndarray | None
    error: str | None = None
    path: str | None = None


@contextlib.contextmanager
def _quiet_c_stderr():
    """Silence what C libraries (libpng, libjpeg) print on stderr while decoding: pencilcal
    reports an undecodable frame in one line of its own. Only file descriptor 2 of this
    process, only around the decode call."""
    try:
        fd = sys.stderr.fileno()
    except (AttributeError, ValueError, OSError):  # no real stderr (e.g. captured in tests)
        yield
        return
    saved = os.dup(fd)
    try:
        with open(os.devnull, "w") as null:
            os.dup2(null.fileno(), fd)
            yield
    finally:
        os.dup2(saved, fd)
        os.close(saved)


def _natural_key(s):
    return [int(t) if t.isdigit() else t.lower() for t in re.split(r"(\d+)", s)]


class ImageSource:
    """An ordered, re-iterable sequence of frames from a folder, glob or video.

    Attributes: `description` (for messages), `count` (number of frames; for video the
    container's count, which may be approximate), `kind` ("images" or "video").
    """

    def __init__(self, spec, gray=False):
        self.spec = str(spec)
        self.gray = gray
        p = Path(self.spec)
        if p.is_dir():
            files = [q for q in p.iterdir() if q.is_file() and q.suffix.lower() in IMAGE_EXTENSIONS]
            if not files:
                raise InputError(f"{p}: no images in this folder (looked for {', '.join(sorted(IMAGE_EXTENSIONS))})")
            self.kind = "images"
            self.paths = sorted(files, key=lambda q: _natural_key(q.name))
        elif p.is_file() and p.suffix.lower() in VIDEO_EXTENSIONS:
            import cv2

            cap = cv2.VideoCapture(str(p))
            ok = cap.isOpened()
            n = int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) if ok else 0
            cap.release()
            if not ok:
                raise InputError(f"{p}: cannot open this video")
            self.kind = "video"
            self.paths = [p]
            self._video_count = max(n, 0)
        elif p.is_file() and p.suffix.lower() in IMAGE_EXTENSIONS:
            self.kind = "images"
            self.paths = [p]
        elif any(c in self.spec for c in "*?["):
            files = [Path(q) for q in _glob.glob(self.spec) if Path(q).is_file()]
            files = [q for q in files if q.suffix.lower() in IMAGE_EXTENSIONS]
            if not files:
                raise InputError(f"{self.spec}: the pattern matches no images")
            self.kind = "images"
            self.paths = sorted(files, key=lambda q: _natural_key(str(q)))
        elif p.exists():
            raise InputError(f"{p}: not a folder of images, an image or a video ({p.suffix or 'no extension'})")
        else:
            raise InputError(f"{p}: no such file or folder")
        self.description = self.spec

    @property
    def count(self):
        return self._video_count if self.kind == "video" else len(self.paths)

    def __len__(self):
        return self.count

    def __iter__(self):
        import cv2

        # OpenCV logs its own lines about broken files and streams on stderr; pencilcal
        # reports each undecodable frame once, in one line, itself
        cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_SILENT)
        if self.kind == "video":
            yield from self._iter_video()
        else:
            yield from self._iter_files()

    def _read(self, path):
        return self._read_path(path, self.gray)

    def refs(self):
        """The frames without decoding image files: Frame(name, index, image=None, path)
        (video frames are decoded, a stream has no random access). For `parallel.map_frames`."""
        if self.kind == "video":
            yield from self
            return
        for i, p in enumerate(self.paths):
            yield Frame(p.name, i, None, None, str(p))

    @staticmethod
    def _read_path(path, gray=False):
        import cv2

        flags = cv2.IMREAD_GRAYSCALE if gray else cv2.IMREAD_UNCHANGED
        try:
            data = np.fromfile(str(path), dtype=np.uint8)
        except OSError as e:
            return None, f"cannot read: {e.strerror}"
        if data.size == 0:
            return None, "empty file"
        with _quiet_c_stderr():
            img = cv2.imdecode(data, flags)
        if img is None:
            return None, "cannot decode the image (corrupt or truncated)"
        if img.ndim == 3 and img.shape[2] == 4:
            img = cv2.cvtColor(img, cv2.COLOR_BGRA2BGR)
        return img, None

    def _iter_files(self):
        for i, p in enumerate(self.paths):
            img, err = self._read(p)
            yield Frame(p.name, i, img, err, str(p))

    def _iter_video(self):
        import cv2

        cap = cv2.VideoCapture(str(self.paths[0]))
        try:
            i = 0
            misses = 0
            n = self._video_count
            while True:
                with _quiet_c_stderr():  # libavcodec reports corrupt frames itself
                    ok, img = cap.read()
                if not ok or img is None:
                    # a corrupt frame inside the stream: report it and try the next; stop
                    # at the end (or after many misses in a row)
                    if n and i < n and misses < 25:
                        yield Frame(f"frame_{i:06d}", i, None, "cannot decode this video frame")
                        i += 1
                        misses += 1
                        continue
                    break
                misses = 0
                if self.gray and img.ndim == 3:
                    img = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
                yield Frame(f"frame_{i:06d}", i, img, None, str(self.paths[0]))
                i += 1
        finally:
            cap.release()


def open_images(spec, gray=False):
    """Open IMAGES (folder, glob pattern, single image, or video). See the module doc."""
    return ImageSource(spec, gray=gray)


def check_image_size(frame, camera, source=None):
    """InputError when a decoded frame's size differs from the camera's image size."""
    if frame.image is None:
        return
    h, w = frame.image.shape[:2]
    if (w, h) != (camera.width, camera.height):
        where = source or frame.path or frame.name
        raise InputError(
            f"{where}: image is {w}x{h} but the camera was calibrated at {camera.width}x{camera.height}"
        )
