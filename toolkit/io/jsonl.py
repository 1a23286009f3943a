"""JSON Lines out: one object per frame, written and flushed as each frame is done.

For a ROS bridge, an OpenIGTLink sender or a dashboard reading `pencilcal orient --jsonl -`:
every line is one complete JSON object (numpy arrays as lists, NaN and inf as null, as in
every pencilcal file), so a reader never sees half a frame. ``-`` is standard output; a
file is written as it goes (it is a stream, not a finished result: the final JSON file of
the command is still written atomically at the end).

Example
-------
>>> import io, numpy as np
>>> buf = io.StringIO()
>>> w = JsonlWriter(buf)
>>> w.write({"image": "000.png", "tilt_deg": np.float64(12.5), "normal": np.array([0.0, 0.0, 1.0])})
>>> buf.getvalue()
'{"image": "000.png", "tilt_deg": 12.5, "normal": [0.0, 0.0, 1.0]}\\n'
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

from pencilcal.toolkit.errors import InputError
from pencilcal.toolkit.io.files import check_writable, to_jsonable

__all__ = ["JsonlWriter", "open_jsonl"]


class JsonlWriter:
    """Write one JSON object per line to a text stream, flushing after each."""

    def __init__(self, stream, close=False):
        self.stream = stream
        self._close = close
        self.lines = 0

    def write(self, record):
        """One record (a dict of JSON-able values, numpy included) as one line.

        A reader that goes away (a closed pipe) ends the stream, not the run: the command
        still writes its output file."""
        if self.stream is None:
            return
        try:
            self.stream.write(json.dumps(to_jsonable(record), allow_nan=False) + "\n")
            self.stream.flush()
        except BrokenPipeError:
            self._drop_stream()
            return
        self.lines += 1

    def _drop_stream(self):
        import os

        if self.stream is sys.stdout:
            # later flushes of stdout (at exit too) must not fail on the closed pipe
            devnull = os.open(os.devnull, os.O_WRONLY)
            os.dup2(devnull, sys.stdout.fileno())
            os.close(devnull)
        self.stream = None

    def close(self):
        if self._close and self.stream is not None:
            self.stream.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False


def open_jsonl(path, force=False):
    """A JsonlWriter on `path` ("-": standard output). An existing file is replaced only
    with `force`."""
    if str(path) == "-":
        return JsonlWriter(sys.stdout)
    p = Path(path)
    check_writable(p, force)
    try:
        return JsonlWriter(open(p, "w", encoding="utf-8", buffering=1), close=True)
    except OSError as e:
        raise InputError(f"{p}: cannot write: {e.strerror}") from None
