"""Plumbing shared by the commands: errors, progress, output paths.

Every command runs its body through `run`, which turns the errors pencilcal raises on
purpose (and the usual OS errors) into one line on stderr and exit status 1. Usage errors
are click's and exit with 2. Warnings about single frames go to stderr as one line each.
"""
from __future__ import annotations

import contextlib
import functools
import sys

import click

from pencilcal.toolkit.errors import PencilcalError
from pencilcal.toolkit.files import check_writable

__all__ = ["run", "progress", "warn", "output_option", "force_option", "quiet_option", "check_output",
           "camera_options"]


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


def camera_options(fn):
    """--camera (any supported format) and --camera-id (COLMAP files with several cameras)."""
    fn = click.option("--camera-id", type=int, default=None, help="Camera id in a COLMAP file with several cameras.")(fn)
    return click.option(
        "--camera", "camera_path", required=True, type=click.Path(),
        help="Camera file: .json, .yaml/.yml/.xml (OpenCV), .cameramodel (mrcal), COLMAP cameras.txt/.bin or model folder.",
    )(fn)
