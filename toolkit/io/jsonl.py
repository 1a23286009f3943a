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

import contextlib
import json
import os
import sys
from pathlib import Path

from pencilcal.toolkit.errors import InputError
from pencilcal.toolkit.io.files import check_writable, to_jsonable, write_error

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


class _LineFile:
    """A file written one whole line at a time: a line that cannot be written in full (a
    full disk) is cut off again, so the file always ends with a complete line, and the
    error names the file and how many lines it holds."""

    def __init__(self, path):
        self.path = Path(path)
        self.fd = os.open(self.path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o666)
        self.size, self.lines = 0, 0

    def write(self, text):
        data = text.encode("utf-8", "surrogateescape")
        try:
            view = memoryview(data)
            while view:
                view = view[os.write(self.fd, view):]
        except OSError as e:
            with contextlib.suppress(OSError):
                os.ftruncate(self.fd, self.size)
            err = write_error([self.path], e)
            raise InputError(f"{str(err).split('; ')[0]}; it holds the first {self.lines} frames, each line whole") \
                from None
        self.size += len(data)
        self.lines += 1

    def flush(self):
        pass  # every line went to the file whole, at once

    def close(self):
        os.close(self.fd)


def open_jsonl(path, force=False):
    """A JsonlWriter on `path` ("-": standard output). An existing file is replaced only
    with `force`, when the run starts: the file is a stream, written as frames are done
    (and kept as far as it got when a run fails or is stopped, each line whole)."""
    if str(path) == "-":
        return JsonlWriter(sys.stdout)
    p = Path(path)
    check_writable(p, force)
    try:
        return JsonlWriter(_LineFile(p), close=True)
    except OSError as e:
        raise write_error([p], e) from None
