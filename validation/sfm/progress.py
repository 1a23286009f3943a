"""Progress of COLMAP's extraction and matching, followed in its glog log file.

`extract_progress` and `match_progress` give context managers that call
``progress(stage, done, total)`` from a thread while pycolmap works: 0 on entry, each
advance of COLMAP's own progress lines (images written; image pairs matched and
verified), and ``total`` on a clean exit. Never from ``database.db`` (see `_LogProgress`).

Example
-------
>>> import tempfile
>>> from pathlib import Path
>>> from pencilcal.validation.sfm.glog import glog_base
>>> seen = []
>>> log = Path(tempfile.mkdtemp()) / "colmap.log"
>>> with extract_progress(glog_base(log), 3, lambda *a: seen.append(a)):
...     pass
>>> seen
[('extract', 0, 3), ('extract', 3, 3)]
>>> sequential_pair_count(5, 10), sequential_pair_count(30, 10)
(10, 245)
"""
from __future__ import annotations

import re
import threading
from pathlib import Path

from .options import SEQUENTIAL_OVERLAP

__all__ = ["sequential_pair_count", "extract_progress", "match_progress"]

# how often the log is read [s]
_POLL_S = 0.25


def sequential_pair_count(n, overlap, of=None):
    """Pairs COLMAP's sequential matcher visits without quadratic overlap or loops, for the
    first `n` images of `of` (default `n`) images, each with its next `overlap`."""
    of = n if of is None else of
    return sum(min(overlap, of - 1 - i) for i in range(n))


# COLMAP's own progress lines (glog, INFO): an image written to the database; the start of
# a sequential matcher's image; the start of an exhaustive matcher's block of pairs.
_EXTRACTED = re.compile(rb"Processed file \[(\d+)/(\d+)\]")
_SEQUENTIAL = re.compile(rb"Processing image \[(\d+)/(\d+)\]")
_BLOCK = re.compile(rb"Processing block \[(\d+)/(\d+), (\d+)/(\d+)\]")


class _LogProgress:
    """Follows a stage of COLMAP in its glog file while pycolmap works (it releases the
    GIL), for a progress bar on extraction and matching. Any error just stops reporting.

    `done_of(match)` turns the newest progress line of `pattern` into units done. The log,
    not the database: COLMAP keeps ``database.db`` in WAL mode with a memory-mapped index,
    and a second SQLite library in the process (Python's sqlite3) shares its POSIX locks,
    so opening and closing the file beside it can truncate that index under COLMAP: a bus
    error (https://www.sqlite.org/howtocorrupt.html, 2.2). glog writes each line through
    at once because `glog.import_pycolmap` sets GLOG_logbuflevel=-1 before pycolmap loads;
    where pycolmap was loaded otherwise first the lines arrive in 4 KiB blocks, the bar in
    steps. ``poll_s``: how often the log is read [s].
    """

    def __init__(self, log_base, pattern, done_of, stage, total, progress):
        self.log_base, self.pattern, self.done_of = Path(log_base), pattern, done_of
        self.stage, self.total, self.progress = stage, total, progress
        self._stop = threading.Event()
        self._thread = None
        self._file, self._offset, self._tail = None, 0, b""
        self.poll_s = _POLL_S

    def __enter__(self):
        if self.progress is not None:
            self.progress(self.stage, 0, self.total)
            self._thread = threading.Thread(target=self._run, daemon=True)
            self._thread.start()
        return self

    def _newest(self):
        """The units done by the newest progress line written since the last call, or None."""
        made = sorted(self.log_base.parent.glob(self.log_base.name + "*"))
        if not made:
            return None
        if made[-1] != self._file:  # glog opened its file (or a new one): read it whole
            self._file, self._offset, self._tail = made[-1], 0, b""
        with open(self._file, "rb") as f:
            f.seek(self._offset)
            chunk = f.read()
        self._offset += len(chunk)
        lines = (self._tail + chunk).split(b"\n")
        self._tail = lines.pop()  # a line still being written
        found = [m for m in map(self.pattern.search, lines) if m]
        return self.done_of(found[-1]) if found else None

    def _run(self):
        last = 0  # __enter__ reported 0
        while not self._stop.wait(self.poll_s):
            try:
                n = self._newest()
            except Exception:  # an unreadable log: stop reporting, never the work
                return
            if n is None:
                continue
            n = max(0, min(int(n), self.total))
            if n > last:
                last = n
                try:
                    self.progress(self.stage, n, self.total)
                except Exception:  # a broken progress display must not stop the work
                    return

    def __exit__(self, *exc):
        if self._thread is not None:
            self._stop.set()
            self._thread.join()
            if exc[0] is None:
                self.progress(self.stage, self.total, self.total)
        return False


def extract_progress(log_base, n_images, progress):
    """Progress of feature extraction in images written to the database.

    log_base: `glog_base` of the log; progress: the callback, or None (then nothing runs).
    """
    return _LogProgress(log_base, _EXTRACTED, lambda m: int(m[1]), "extract", n_images, progress)


def match_progress(log_base, mode, n_images, progress):
    """Progress of matching (``mode`` "exhaustive" or "sequential") in image pairs matched
    and verified.

    Sequential: COLMAP starts image k once the pairs of images 1..k-1 are done (exact).
    Exhaustive: it works through nb x nb blocks of about equally many pairs each (COLMAP
    spreads the pairs so), so the pairs done are estimated from the blocks done.
    """
    if mode == "exhaustive":
        total = n_images * (n_images - 1) // 2

        def done_of(m):
            a, nb, b = int(m[1]), int(m[2]), int(m[3])
            return total * ((a - 1) * nb + (b - 1)) // max(nb * nb, 1)

        return _LogProgress(log_base, _BLOCK, done_of, "match", total, progress)
    total = sequential_pair_count(n_images, SEQUENTIAL_OVERLAP)
    return _LogProgress(log_base, _SEQUENTIAL,
                        lambda m: sequential_pair_count(int(m[1]) - 1, SEQUENTIAL_OVERLAP, n_images),
                        "match", total, progress)
