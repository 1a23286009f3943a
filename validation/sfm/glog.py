"""pycolmap's glog log: loading pycolmap so that its log lines are written through, and
routing the log into a file for the duration of a block.

`import_pycolmap` is the one place pencilcal's validation imports pycolmap: COLMAP logs
with glog, which reads its settings once, when pycolmap is loaded, and
`pencilcal.validation.sfm.progress` follows COLMAP's progress in glog's log file.

Example
-------
>>> import os, tempfile
>>> pycolmap = import_pycolmap()
>>> "GLOG_logbuflevel" in os.environ
True
>>> log = os.path.join(tempfile.mkdtemp(), "colmap.log")
>>> with colmap_logging(log):
...     pass
>>> glog_base(log).name
'colmap.log.'
"""
from __future__ import annotations

import contextlib
import os
from pathlib import Path

__all__ = ["import_pycolmap", "glog_base", "colmap_logging"]


def import_pycolmap():
    """The pycolmap module, loaded with glog writing each log line through.

    Every import of pycolmap in pencilcal.validation goes through here (the first one loads
    it). Raises ImportError when pycolmap is not installed.
    """
    # COLMAP (through pycolmap) logs with glog, which holds INFO lines of its log file in a
    # buffer for up to 30 s. pencilcal follows COLMAP's progress in that file
    # (validation/sfm/progress.py), so it asks glog to write each line through. glog reads this once,
    # when pycolmap is loaded; a value the user set is kept.
    os.environ.setdefault("GLOG_logbuflevel", "-1")
    import pycolmap

    return pycolmap


def glog_base(log_path):
    """glog names its file ``<base>YYYYmmdd-HHMMSS.pid``: the Path ``<log_path>.``, whose
    file `colmap_logging` renames to `log_path`."""
    return Path(log_path).with_name(Path(log_path).name + ".")


@contextlib.contextmanager
def colmap_logging(log_path=None, verbose=False):
    """Route pycolmap's glog output for the duration of the block.

    Without `verbose` nothing reaches stderr (glog's stderr threshold is raised to FATAL,
    which aborts anyway); with a `log_path` every message is written there (glog names
    its file ``<base>YYYYmmdd-HHMMSS.pid``; it is renamed to `log_path` at the end).
    glog's own log files under /tmp stay off afterwards; the other settings come back.
    """
    pycolmap = import_pycolmap()

    L = pycolmap.logging
    saved = {k: getattr(L, k) for k in ("minloglevel", "logtostderr", "alsologtostderr", "stderrthreshold")}
    levels = (L.Level.INFO, L.Level.WARNING, L.Level.ERROR, L.Level.FATAL)
    base = None
    try:
        # INFO's file receives every severity; the others would duplicate it
        for lv in levels:
            L.set_log_destination(lv, "")
        if log_path is not None:
            base = str(glog_base(log_path))
            L.set_log_destination(L.Level.INFO, base)
        L.logtostderr = False
        L.alsologtostderr = bool(verbose)
        L.stderrthreshold = 0 if verbose else 3
        L.minloglevel = 0 if (verbose or log_path is not None) else 2
        yield
    finally:
        # an empty destination closes (and so flushes) glog's file
        for lv in levels:
            L.set_log_destination(lv, "")
        for k, v in saved.items():
            setattr(L, k, v)
        if base is not None:
            made = sorted(Path(base).parent.glob(Path(base).name + "*"))
            if made:
                with contextlib.suppress(OSError):
                    os.replace(made[-1], log_path)
