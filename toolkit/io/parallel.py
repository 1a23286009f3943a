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
from concurrent.futures import ProcessPoolExecutor

from pencilcal.toolkit.io.images import Frame

__all__ = ["map_frames", "Sized"]


def _init_worker():
    import cv2

    cv2.setNumThreads(1)
    cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_SILENT)


def _decode(source_spec, gray, frame):
    """The frame with its image (decoded here, in the worker, when only its path came)."""
    if frame.image is not None or frame.error is not None or frame.path is None:
        return frame
    from pencilcal.toolkit.io.images import ImageSource

    img, err = ImageSource._read_path(frame.path, gray)
    return Frame(frame.name, frame.index, img, err, frame.path)


def _call(fn, context, source_spec, gray, frame):
    return fn(_decode(source_spec, gray, frame), context)


def map_frames(fn, source, context, workers=1):
    """Ordered ``fn(frame, context)`` over the frames of `source` (an ImageSource)."""
    if workers is None or workers <= 1:
        for frame in source:
            yield fn(frame, context)
        return
    refs = source.refs()
    ctx = multiprocessing.get_context("spawn")
    window = 2 * workers
    with ProcessPoolExecutor(max_workers=workers, mp_context=ctx, initializer=_init_worker) as pool:
        pending = collections.deque()
        for ref in refs:
            pending.append(pool.submit(_call, fn, context, source.spec, source.gray, ref))
            if len(pending) >= window:
                yield pending.popleft().result()
        while pending:
            yield pending.popleft().result()


class Sized:
    """An iterable with a known length, for progress bars over `map_frames` results."""

    def __init__(self, it, n):
        self.it, self.n = it, n

    def __iter__(self):
        return iter(self.it)

    def __len__(self):
        return self.n
