"""Frames of one sequence in parallel: `--workers N` of every per-frame command.

`map_frames(fn, source, context, workers)` yields ``fn(frame, context)`` for every frame of
an ImageSource, **in order**, with the same results whatever `workers` is. With workers > 1
the frames go to a pool of processes started with *spawn* (OpenCV's and torch's thread
pools do not survive a fork reliably). Image files are decoded in the workers (only paths
travel), video frames are decoded here and sent as arrays; at most ``2 * workers`` frames
are in flight, so a long video is never held in memory at once. Each worker runs OpenCV
single-threaded: the pool is the parallelism.

`fn` must be a module-level function and `context` picklable (cameras, boards, pencils and
the like are).

Example
-------
>>> from pencilcal.toolkit.io.parallel import map_frames
>>> def size(frame, ctx):                                  # doctest: +SKIP
...     return frame.name, None if frame.image is None else frame.image.shape
>>> list(map_frames(size, open_images("frames/"), None, workers=2))  # doctest: +SKIP
"""
from __future__ import annotations

import collections
import multiprocessing
import signal
import threading

from pencilcal.toolkit.io.images import Frame, decode_image

__all__ = ["map_frames", "Sized"]


def _init_worker():
    import cv2

    # Ctrl-C goes to the whole process group: the parent alone handles it (and stops the
    # pool), so that no worker dies half-way through a frame with a traceback of its own
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)  # the parent's "raise Terminated" is not theirs
    cv2.setNumThreads(1)
    cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_SILENT)


def _decode(gray, max_pixels, frame):
    """The frame with its image (decoded here, in the worker, when only its path came)."""
    if frame.image is not None or frame.error is not None or frame.path is None:
        return frame
    img, err = decode_image(frame.path, gray=gray, max_pixels=max_pixels)
    return Frame(frame.name, frame.index, img, err, frame.path)


def _call(fn, context, gray, max_pixels, frame):
    return fn(_decode(gray, max_pixels, frame), context)


def map_frames(fn, source, context, workers=1):
    """Ordered ``fn(frame, context)`` over the frames of `source` (an ImageSource).

    An exception or an interrupt (Ctrl-C, SIGTERM raised as an exception in the main
    process) while results are awaited terminates the workers at once: the caller's
    clean-up runs and the process exits within a moment, instead of waiting on frames
    in flight.
    """
    if workers is None or workers <= 1:
        for frame in source:
            yield fn(frame, context)
        return
    refs = source.refs()
    ctx = multiprocessing.get_context("spawn")
    window = 2 * workers
    # Workers start with SIGINT ignored (an ignored signal stays ignored across exec, and
    # Python then leaves it so): a Ctrl-C while they import must not kill them half-way,
    # with a traceback of their own; the parent alone handles it and stops them.
    main = threading.current_thread() is threading.main_thread()  # signals belong to it alone
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN) if main else None
    try:
        pool = ctx.Pool(processes=workers, initializer=_init_worker)
    finally:
        if main:
            signal.signal(signal.SIGINT, previous)
    try:
        pending = collections.deque()
        for ref in refs:
            pending.append(pool.apply_async(_call, (fn, context, source.gray, source.max_pixels, ref)))
            if len(pending) >= window:
                yield pending.popleft().get()
        while pending:
            yield pending.popleft().get()
        pool.close()
        pool.join()
    finally:
        # after close/join this does nothing; on any other way out it stops the workers now
        pool.terminate()


class Sized:
    """An iterable with a known length, for progress bars over `map_frames` results."""

    def __init__(self, it, n):
        self.it, self.n = it, n

    def __iter__(self):
        return iter(self.it)

    def __len__(self):
        return self.n
