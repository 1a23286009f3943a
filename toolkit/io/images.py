"""Image sources: image files, folders and glob patterns, or a video file.

Every command that reads images takes IMAGES (one or more paths, in order) and goes
through `open_images`, so they all accept the same inputs and fail the same way:

- an empty folder, a pattern that matches nothing, a missing path or an unreadable video
  is an InputError (one line, exit 1);
- an unreadable or truncated image, or a corrupt video frame, is *not* fatal: the frame
  is yielded with ``image=None`` and an error string, and commands record it as
  ``ok: false`` and warn.

Frames are decoded once, in order, by `decode_image` (OpenCV; BGR, 8 or 16 bit as stored,
EXIF orientation applied); ``gray=True`` converts to single-channel 8 bit, and with
``keep_colour=True`` as well each frame keeps its colour image beside the grey one
(`Frame.colour`: an overlay drawn in colour, the lines found on grey), the grey one then
converted from it as a detector converts a colour frame (`with_grey`). A video's frames are
decoded in a thread of their own, a few frames ahead of the command (`prefetched`): the
decoder and the conversion release the interpreter while they work, so they overlap the
processing of the previous frame.

Example
-------
>>> import tempfile, os, numpy as np, cv2
>>> d = tempfile.mkdtemp()
>>> _ = cv2.imwrite(os.path.join(d, "b.png"), np.zeros((16, 24), np.uint8))
>>> _ = open(os.path.join(d, "a.png"), "wb").write(b"\\x89PNG broken")
>>> src = open_images(d)
>>> [(f.name, f.image is None, f.error is not None) for f in src]
[('a.png', True, True), ('b.png', False, False)]
"""
from __future__ import annotations

import contextlib
import errno
import glob as _glob
import os
import queue
import re
import stat
import sys
import threading
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pencilcal.toolkit.errors import InputError

__all__ = ["with_grey", "read_frame", "Frame", "ImageSource", "read_ahead", "prefetched", "open_images", "decode_image",
           "IMAGE_EXTENSIONS", "VIDEO_EXTENSIONS", "DEFAULT_MAX_PIXELS", "MIN_SIDE_PX", "MAX_BYTES_PER_PIXEL",
           "check_image_size", "quiet_c_stderr", "frame_size_error"]

# FFmpeg (OpenCV's video backend) logs its complaints about corrupt frames on stderr; pencilcal
# reports an undecodable frame in one line itself. Its own log level, read when OpenCV starts
# the backend, silences it in whichever thread decodes (a user's own setting is kept); the
# file-descriptor swap of `quiet_c_stderr` would silence every thread's stderr meanwhile.
os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "-8")

# frames a video's decoding thread runs ahead of the command (a 1080p BGR frame: 6 MB)
PREFETCH_FRAMES = 4

IMAGE_EXTENSIONS = {".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".pgm", ".ppm", ".webp"}
VIDEO_EXTENSIONS = {".mp4", ".avi", ".mov", ".mkv", ".m4v", ".mpg", ".mpeg", ".wmv", ".webm"}


@dataclass(frozen=True)
class Frame:
    """One frame: `name` (file name, or frame_000123 for video), `index` in the sequence,
    `image` (H, W[, 3]) uint8/uint16 or None when it could not be decoded, `error`; `colour`
    (H, W, 3) the colour image of a grey `image` when the source keeps it (`keep_colour`),
    else None."""

    name: str
    index: int
    image: np.ndarray | None
    error: str | None = None
    path: str | None = None
    colour: np.ndarray | None = None

    @property
    def drawable(self):
        """The image to draw an overlay on: the colour one when kept, else `image`."""
        return self.image if self.colour is None or self.image is None else self.colour


def with_grey(image):
    """(grey, colour): a colour image (H, W, 3) as one grey channel in its own dtype
    (OpenCV's BGR to grey weights, as `detect.image` converts a colour frame) and itself; a
    grey image (or None) as itself and None.

    >>> g, c = with_grey(np.full((2, 2, 3), (10, 20, 30), np.uint8))
    >>> g.tolist(), c.shape, with_grey(g)[1] is None
    ([[22, 22], [22, 22]], (2, 2, 3), True)
    """
    import cv2

    if image is None or image.ndim != 3:
        return image, None
    return cv2.cvtColor(image, cv2.COLOR_BGR2GRAY), image


@contextlib.contextmanager
def quiet_c_stderr():
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


# Frames larger than this are refused before they are decoded (a 1 kB PNG can claim
# 100000 x 100000 pixels): 8K video is 33 MP. Raise it with `max_pixels`.
DEFAULT_MAX_PIXELS = 100_000_000
#: An image file larger than this many bytes a pixel of `max_pixels` is refused before it is
#: read (16: four 32-bit float channels, uncompressed; real files are far smaller).
MAX_BYTES_PER_PIXEL = 16
#: Frames with a side under this many pixels are refused: too small for any detector (a
#: printed bar is 2.5 px to 1/8 of the image; a 1x1 frame divided by empty slices).
MIN_SIDE_PX = 16


def frame_size_error(image, max_pixels=DEFAULT_MAX_PIXELS):
    """Why a decoded frame is refused for its size (more than `max_pixels`, or a side under
    MIN_SIDE_PX), or None.

    >>> frame_size_error(np.zeros((1, 1), np.uint8))
    'the image is 1x1 pixels, under the minimum of 16 a side'
    """
    h, w = image.shape[:2]
    if h * w > max_pixels:
        return f"the frame has over {max_pixels:,} pixels (--max-pixels raises it)"
    if min(h, w) < MIN_SIDE_PX:
        return f"the image is {w}x{h} pixels, under the minimum of {MIN_SIDE_PX} a side"
    return None


def read_ahead(frames, k):
    """The first `k` frames (a list of `Frame`) of the iterator `frames`, read now, and the
    iterator of the rest: a source's `head` keeps both for its next iteration to yield the
    read-ahead frames first (`ImageSource.head`, `stream.StreamSource.head`)."""
    head = []
    for frame in frames:
        head.append(frame)
        if len(head) >= k:
            break
    return head, frames


def prefetched(make_iter, depth=PREFETCH_FRAMES):
    """The items of the iterator `make_iter()`, produced in a thread of their own at most
    `depth` ahead of the consumer: decoding (which releases the interpreter) overlaps what
    the consumer does with the previous frame. The iterator is created, advanced and closed
    in that thread; an exception it raises is raised here, in order. A consumer that stops
    early (break, an error, Ctrl-C) stops the thread after the item it is producing.

    >>> [x * x for x in prefetched(lambda: iter(range(5)))]
    [0, 1, 4, 9, 16]
    """
    q = queue.Queue(max(1, int(depth)))
    stop = threading.Event()

    def put(item):
        while not stop.is_set():
            try:
                q.put(item, timeout=0.05)
                return True
            except queue.Full:
                continue
        return False

    def produce():
        it = None
        try:
            it = make_iter()
            for item in it:
                if not put(("item", item)):
                    break
        except BaseException as e:  # noqa: BLE001 - handed to the consumer, raised there
            put(("error", e))
        finally:
            close = getattr(it, "close", None)
            if close is not None:
                close()
            put(("done", None))

    worker = threading.Thread(target=produce, name="pencilcal-decode", daemon=True)
    worker.start()
    try:
        while True:
            kind, value = q.get()
            if kind == "item":
                yield value
            elif kind == "error":
                raise value
            else:
                return
    finally:
        stop.set()
        worker.join(timeout=5.0)


def _reason(e):
    """An OSError's reason in words, a symlink to nowhere or in a loop named as such."""
    if e.errno == errno.ELOOP:
        return "a symbolic link in a loop"
    if e.errno == errno.ENOENT:
        return "a symbolic link to nothing"
    return (e.strerror or str(e)).lower()


class ImageSource:
    """An ordered, re-iterable sequence of frames from IMAGES: one or more image files,
    folders and glob patterns, taken in the order given, or one video file.

    A folder's images and a pattern's matches are sorted naturally (frame2 before
    frame10). The same image given twice, or a video together with anything else, is an
    InputError. Attributes: `description` (the IMAGES as given, for messages and
    outputs), `count` (number of frames; for video the container's count, which may be
    approximate), `kind` ("images" or "video"), `paths`, `fps` (a video's frame rate [Hz] as
    its container gives it, None for images or when unknown). gray, keep_colour: module
    docstring.
    """

    def __init__(self, spec, gray=False, max_pixels=DEFAULT_MAX_PIXELS, keep_colour=False):
        specs = [str(spec)] if isinstance(spec, (str, os.PathLike)) else [str(s) for s in spec]
        if not specs:
            raise InputError("no images given (IMAGES: files, folders, glob patterns or one video)")
        self.spec = specs[0] if len(specs) == 1 else " ".join(specs)
        self.gray = gray
        self.keep_colour = bool(gray and keep_colour)
        self.max_pixels = max_pixels
        resolved = [self._resolve(s) for s in specs]
        videos = [s for s, r in zip(specs, resolved) if r[0] == "video"]
        if videos and len(specs) > 1:
            raise InputError(f"{videos[0]}: a video must be the only IMAGES argument "
                             f"(got {len(specs)}: {self.spec})")
        self.fps = None
        if videos:
            self.kind, self.paths, self._video_count, self.fps = resolved[0]
        else:
            self.kind = "images"
            self.paths = [q for _, files in resolved for q in files]
            seen = {}
            for q, s in ((q, s) for s, (_, files) in zip(specs, resolved) for q in files):
                key = os.path.realpath(q)
                if key in seen:
                    also = "" if seen[key] == s else f" (by {seen[key]} and by {s})"
                    raise InputError(f"{q}: given twice{also}; each image may appear once in IMAGES")
                seen[key] = s
        self.description = self.spec
        self._head, self._rest = [], None  # frames read ahead by `head`

    @staticmethod
    def _resolve(spec):
        """("video", [path], frame count, frame rate [Hz] or None) or ("images", [paths]) for one
        IMAGES argument."""
        p = Path(spec)
        if p.is_dir():
            # every entry named as an image is a frame, even one that cannot be read (a
            # symlink loop or to nowhere, no permission): it is reported when decoded
            # (ok: false with the reason), never silently left out
            try:
                files = [q for q in p.iterdir() if q.suffix.lower() in IMAGE_EXTENSIONS and not q.is_dir()]
            except OSError as e:
                raise InputError(f"{p}: cannot list this folder ({_reason(e)})") from None
            if not files:
                raise InputError(f"{p}: no images in this folder (looked for {', '.join(sorted(IMAGE_EXTENSIONS))})")
            return "images", sorted(files, key=lambda q: _natural_key(q.name))
        if p.is_file() and p.suffix.lower() in VIDEO_EXTENSIONS:
            import cv2

            # FFmpeg logs its own complaints about a broken file on stderr, before
            # pencilcal's one line: silenced, as for decoding
            cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_SILENT)
            with quiet_c_stderr():
                cap = cv2.VideoCapture(str(p))
                ok = cap.isOpened()
                n = int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) if ok else 0
                fps = float(cap.get(cv2.CAP_PROP_FPS)) if ok else 0.0
                # the container's count can be missing or wrong: a video without one frame
                # that decodes is no input (it used to end the command with exit 0 and nothing)
                first = ok and cap.read()[0]
                cap.release()
            if not ok:
                hint = (" (an MP4 or MOV cut short has no index: was the recording stopped before it was finished?)"
                        if p.suffix.lower() in (".mp4", ".mov", ".m4v") else "")
                raise InputError(f"{p}: cannot open this video{hint}")
            if not first and n <= 0:
                raise InputError(f"{p}: the video holds no frames")
            return "video", [p], max(n, 0), (fps if 0 < fps < 1000 else None)
        if p.is_file() and p.suffix.lower() in IMAGE_EXTENSIONS:
            return "images", [p]
        if any(c in spec for c in "*?["):
            files = [Path(q) for q in _glob.glob(spec) if Path(q).is_file()]
            files = [q for q in files if q.suffix.lower() in IMAGE_EXTENSIONS]
            if not files:
                raise InputError(f"{spec}: the pattern matches no images")
            return "images", sorted(files, key=lambda q: _natural_key(str(q)))
        if p.exists():
            raise InputError(f"{p}: not a folder of images, an image or a video ({p.suffix or 'no extension'})")
        try:
            os.stat(p)
        except OSError as e:
            if e.errno != errno.ENOENT or p.is_symlink():
                raise InputError(f"{p}: cannot read ({_reason(e)})") from None
        raise InputError(f"{p}: no such file or folder")

    @property
    def count(self):
        return self._video_count if self.kind == "video" else len(self.paths)

    def __len__(self):
        return self.count

    def head(self, k):
        """A video's first `k` frames' images (the decoded ones), read now and yielded again
        by the next iteration, so that a sequence-level step (the valid region) costs no
        second decoding of the video. Image files need no read-ahead (they are read by path)."""
        if self.kind != "video":
            raise ValueError("head: only a video source reads ahead")
        if not self._head:
            self._head, self._rest = read_ahead(prefetched(self._iter_video), k)
        return [f.image for f in self._head if f.image is not None]

    def __iter__(self):
        import cv2

        # OpenCV logs its own lines about broken files and streams on stderr; pencilcal
        # reports each undecodable frame once, in one line, itself
        cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_SILENT)
        if self._head:
            head, rest, self._head, self._rest = self._head, self._rest, [], None
            yield from head
            yield from rest
        elif self.kind == "video":
            yield from prefetched(self._iter_video)
        else:
            yield from self._iter_files()

    def _read(self, path):
        return decode_image(path, gray=self.gray, max_pixels=self.max_pixels)

    def refs(self):
        """The frames without decoding image files: Frame(name, index, image=None, path)
        (video frames are decoded, a stream has no random access). For `parallel.map_frames`."""
        if self.kind == "video":
            yield from self
            return
        for i, p in enumerate(self.paths):
            yield Frame(p.name, i, None, None, str(p))

    def _iter_files(self):
        for i, p in enumerate(self.paths):
            yield read_frame(Frame(p.name, i, None, None, str(p)), self.gray, self.max_pixels, self.keep_colour)

    def _iter_video(self):
        """The video's frames, decoded in order (run in the decoding thread, `prefetched`:
        nothing here may touch file descriptor 2, which the main thread writes on)."""
        import cv2

        cap = cv2.VideoCapture(str(self.paths[0]))
        try:
            i, n, missed = 0, self._video_count, []
            while True:
                ok, img = cap.read()
                if not ok or img is None:
                    # a corrupt frame inside the stream, or its end: which, the next frames say
                    if n and i < n and len(missed) < 25:
                        missed.append(i)
                        i += 1
                        continue
                    break
                for k in missed:  # frames in the middle that did not decode
                    yield Frame(f"frame_{k:06d}", k, None, "cannot decode this video frame")
                missed = []
                img, colour = with_grey(img) if self.gray else (img, None)
                err = frame_size_error(img, self.max_pixels)
                yield Frame(f"frame_{i:06d}", i, None if err else img, err, str(self.paths[0]),
                            None if err or not self.keep_colour else colour)
                i += 1
            if missed:  # nothing decoded after them: the file ends early, said once
                k = missed[0]
                yield Frame(f"frame_{k:06d}", k, None, f"the video ends here, after {k} of the {n} frames its "
                                                       "header announces (cut short?)")
        finally:
            cap.release()


def _header_size(data):
    """(width, height) an image file's header claims, read without decoding the pixels;
    None when the format is not one Pillow can identify (OpenCV may still decode it)."""
    import io

    try:
        from PIL import Image
    except ImportError:  # pragma: no cover - Pillow comes with matplotlib
        return None
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)  # judged below, by our limit
            with Image.open(io.BytesIO(data)) as im:
                return im.size
    except Image.DecompressionBombError as e:
        # Pillow refuses to open over twice its own limit, saying the pixel count it read
        said = re.search(r"\((\d+) pixels\)", str(e))
        return (int(said.group(1)), 1) if said else (2 * int(Image.MAX_IMAGE_PIXELS or 0) + 1, 1)
    except Exception:  # noqa: BLE001 - any reason Pillow cannot identify it: let OpenCV try
        return None


def decode_image(path, gray=False, max_pixels=DEFAULT_MAX_PIXELS, min_side=MIN_SIDE_PX):
    """Decode one image file: (image, None) or (None, why).

    The one image decoder of pencilcal: every command reads its images through it, so a
    frame means the same to calibrate, pnp, lines and orient. Colour images come as BGR
    (alpha dropped), grey ones as one channel, 8 or 16 bit as stored (``gray=True``: one
    8-bit channel). The EXIF orientation of a JPEG is applied, as OpenCV's imread does by
    default, so a camera calibrated from phone pictures fits the same pictures in every
    command. A header that claims more than `max_pixels` pixels is refused before any
    pixel is decoded, and a frame with a side under `min_side` (MIN_SIDE_PX; a mask file,
    which is not a frame, passes 1) is refused after.
    """
    import cv2

    try:
        st = os.stat(path)
        if not stat.S_ISREG(st.st_mode):  # a pipe would block the read for ever, a device never end
            return None, "not a regular file (a pipe, a device or a socket)"
        with open(path, "rb") as f:
            head = f.read(1 << 20)
        if not head:
            return None, "empty file"
        size = _header_size(head)
        if size is not None and size[0] * size[1] > max_pixels:
            claim = f"{size[0]}x{size[1]}" if size[1] > 1 else f"{size[0]:,}"
            return None, (f"the image claims {claim} pixels, over the limit of {max_pixels:,} "
                          "(--max-pixels raises it)")
        limit = MAX_BYTES_PER_PIXEL * max_pixels
        if st.st_size > limit:
            return None, (f"the file is {st.st_size:,} bytes, over the limit of {limit:,} ({MAX_BYTES_PER_PIXEL} "
                          "bytes a pixel of --max-pixels)")
        data = np.fromfile(str(path), dtype=np.uint8)
    except OSError as e:
        gone = e.errno == errno.ENOENT and not os.path.islink(path)
        return None, f"cannot read: {'the file is gone (removed during the run?)' if gone else _reason(e)}"
    if data.size == 0:
        return None, "empty file"
    # ANYDEPTH | ANYCOLOR: as stored, like IMREAD_UNCHANGED, but with the EXIF orientation
    # applied (IMREAD_UNCHANGED ignores it; IMREAD_GRAYSCALE applies it)
    flags = cv2.IMREAD_GRAYSCALE if gray else (cv2.IMREAD_ANYDEPTH | cv2.IMREAD_ANYCOLOR)
    try:
        with quiet_c_stderr():
            img = cv2.imdecode(data, flags)
    except cv2.error as e:
        return None, f"cannot decode the image: {str(e).strip().splitlines()[-1]}"
    if img is None:
        return None, "cannot decode the image (corrupt or truncated)"
    if min(img.shape[:2]) < min_side:
        return None, frame_size_error(img, max_pixels)
    if img.ndim == 3 and img.shape[2] == 4:
        img = cv2.cvtColor(img, cv2.COLOR_BGRA2BGR)
    return img, None


def read_frame(frame, gray=False, max_pixels=DEFAULT_MAX_PIXELS, keep_colour=False):
    """`frame` (a Frame with only its file's `path`) with its image decoded (`decode_image`);
    with gray and keep_colour, a colour file's grey image and its colour one (`with_grey`)."""
    if gray and keep_colour:
        img, err = decode_image(frame.path, max_pixels=max_pixels)
        grey, colour = with_grey(img)
    else:
        (grey, err), colour = decode_image(frame.path, gray=gray, max_pixels=max_pixels), None
    return Frame(frame.name, frame.index, grey, err, frame.path, colour)


def open_images(spec, gray=False, max_pixels=DEFAULT_MAX_PIXELS, keep_colour=False):
    """Open IMAGES: one path or pattern, or a sequence of them (files, folders, glob
    patterns, or one video). See `ImageSource`."""
    return ImageSource(spec, gray=gray, max_pixels=max_pixels, keep_colour=keep_colour)


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
