"""Plumbing shared by the commands: errors, progress, output paths.

Every command runs its body through `run`, which turns the errors pencilcal raises on
purpose (and the usual OS errors) into one line on stderr and exit status 1. Usage errors
are click's and exit with 2. Warnings about single frames go to stderr as one line each.
"""
from __future__ import annotations

import contextlib
import functools
import sys
import threading

import click

from pencilcal.toolkit.errors import PencilcalError
from pencilcal.toolkit.io.files import check_writable

__all__ = ["run", "progress", "warn", "output_option", "force_option", "quiet_option", "check_output",
           "camera_options", "StageBars", "workers_option", "run_frames"]


def run(fn):
    """Decorator: one-line message and exit 1 on a processing failure, never a traceback."""

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        try:
            return fn(*args, **kwargs)
        except PencilcalError as e:
            raise SystemExit(_fail(str(e)))
        except (OSError, MemoryError) as e:
            name = getattr(e, "filename", None)
            msg = f"{name}: {e.strerror}" if name and getattr(e, "strerror", None) else str(e)
            raise SystemExit(_fail(msg))
        except KeyboardInterrupt:
            raise SystemExit(_fail("interrupted"))

    return wrapper


def _fail(msg):
    click.echo(f"pencilcal: error: {msg.splitlines()[0] if msg else 'failed'}", err=True)
    return 1


def warn(msg):
    click.echo(f"pencilcal: warning: {msg}", err=True)


@contextlib.contextmanager
def progress(items, label, quiet):
    """A progress bar on stderr over `items` (silent with --quiet or when not a terminal)."""
    if quiet or not sys.stderr.isatty():
        yield items
        return
    with click.progressbar(items, label=label, file=sys.stderr, show_pos=True) as bar:
        yield bar


def check_output(path, force):
    """Fail before doing any work if the output exists (without --force) or has no folder."""
    check_writable(path, force)


output_option = click.option("-o", "--output", required=True, type=click.Path(dir_okay=False), help="Output file.")
force_option = click.option("--force", is_flag=True, help="Overwrite the output if it exists.")
quiet_option = click.option("-q", "--quiet", is_flag=True, help="No progress bar.")
workers_option = click.option("--workers", type=click.IntRange(min=1), default=1, show_default=True,
                              help="Process frames in this many worker processes (same results, in order).")


def camera_options(fn):
    """--camera (any supported format) and --camera-id (COLMAP files with several cameras)."""
    fn = click.option("--camera-id", type=int, default=None, help="Camera id in a COLMAP file with several cameras.")(fn)
    return click.option(
        "--camera", "camera_path", required=True, type=click.Path(),
        help="Camera file: .json, .yaml/.yml/.xml (OpenCV), .cameramodel (mrcal), COLMAP cameras.txt/.bin or model folder.",
    )(fn)


_SFM_LABELS = {"prepare": "frames  ", "extract": "features", "match": "matching", "map": "mapping "}


class StageBars:
    """One click progress bar per stage on stderr, fed by reconstruct's progress callback
    (from a worker thread during extraction and matching, hence the lock)."""

    def __init__(self):
        self._lock = threading.Lock()
        self._bar = None
        self._stage = None
        self._done = 0

    def __call__(self, stage, done, total):
        with self._lock:
            if stage not in _SFM_LABELS:
                self._close()
                return
            if stage != self._stage:
                self._close()
                self._bar = click.progressbar(length=max(int(total), 1), label=_SFM_LABELS[stage], file=sys.stderr,
                                              show_pos=True)
                self._bar.__enter__()
                self._stage, self._done = stage, 0
            if total > self._bar.length:  # a video's frame count is the container's guess
                self._bar.length = int(total)
            if done > self._done:
                self._bar.update(done - self._done)
                self._done = done

    def _close(self):
        if self._bar is not None:
            self._bar.__exit__(None, None, None)
            self._bar = None
            self._stage = None

    def close(self):
        with self._lock:
            self._close()


def run_frames(source, task, context, workers, label, quiet):
    """Results of ``task(frame, context)`` for every frame of `source`, in order, behind a
    progress bar; with workers > 1 in a process pool (toolkit.parallel.map_frames). `task`
    must be a module-level function."""
    from pencilcal.toolkit.io.parallel import Sized, map_frames

    results = map_frames(task, source, context, workers)
    with progress(Sized(results, len(source)), label, quiet) as it:
        yield from it
