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

from pencilcal.toolkit.errors import InputError, PencilcalError
from pencilcal.toolkit.io.files import check_writable
from pencilcal.toolkit.io.images import DEFAULT_MAX_PIXELS

__all__ = ["CONTEXT_SETTINGS", "command", "Command", "Group", "OneLineUsageError", "run", "progress", "warn", "done",
           "output_option", "force_option", "quiet_option", "check_output",
           "camera_options", "StageBars", "workers_option", "run_frames", "images_argument", "max_pixels_option",
           "IMAGES_HELP", "SHARED_DETAILS", "FiniteFloat", "LabelledProgress", "mask_option", "jsonl_option", "overlay_option",
           "FrameOutputs", "detector_option", "endpoint_sigma_option", "source_option", "open_input", "frames_region", "stream_meta"]

#: Every command's click context settings: -h as well as --help, the width of the help. Set on
#: each command (not only inherited from the group), so a command invoked on its own, as the
#: tests and the Python API do, prints the same help as `pencilcal COMMAND -h`.
CONTEXT_SETTINGS = {"help_option_names": ["-h", "--help"], "max_content_width": 100}


class OneLineUsageError(click.UsageError):
    """A usage error (a missing or malformed option or argument) said in one line on
    stderr, exit status 2 as click and OpenCV's tools have it: ``pencilcal: usage error:
    MESSAGE (see 'pencilcal CMD --help')``."""

    def show(self, file=None):
        where = self.ctx.command_path if self.ctx is not None else "pencilcal"
        msg = " ".join(self.format_message().split())
        click.echo(f"pencilcal: usage error: {msg} (see '{where} --help')", err=True)


def _one_line(e):
    """`e` as a `OneLineUsageError` (a group's help on no arguments stays as it is)."""
    if isinstance(e, (OneLineUsageError, click.exceptions.NoArgsIsHelpError)):
        return e
    return OneLineUsageError(e.format_message(), e.ctx)


class OneLineUsage:
    """Mixin of pencilcal's commands and groups: usage errors, raised while parsing or by
    the command itself (`click.UsageError`), are said in one line (`OneLineUsageError`)."""

    def make_context(self, *args, **kwargs):
        try:
            return super().make_context(*args, **kwargs)
        except click.UsageError as e:
            raise _one_line(e) from None

    def invoke(self, ctx):
        try:
            return super().invoke(ctx)
        except click.UsageError as e:
            raise _one_line(e) from None


class Command(OneLineUsage, click.Command):
    """A pencilcal command: `OneLineUsage`."""


class Group(OneLineUsage, click.Group):
    """A group of pencilcal commands: `OneLineUsage`, its commands `Command`s."""

    command_class = Command


def command(*args, **kwargs):
    """`click.command` with `CONTEXT_SETTINGS`, as a `Command`."""
    kwargs.setdefault("context_settings", CONTEXT_SETTINGS)
    kwargs.setdefault("cls", Command)
    return click.command(*args, **kwargs)



class Terminated(BaseException):
    """SIGTERM, raised in the main process so that clean-up runs as for Ctrl-C."""


def _on_sigterm(signum, frame):
    raise Terminated()


def install_signal_handlers():
    """SIGTERM becomes `Terminated` (temp files and folders are removed on the way out,
    worker pools stopped), as Ctrl-C becomes KeyboardInterrupt."""
    import signal

    signal.signal(signal.SIGTERM, _on_sigterm)


def _inputs(ctx):
    """What the command was working on, for an internal error's message."""
    p = ctx.params if ctx is not None else {}
    for key in ("images", "lines_path", "sequence", "validation_path", "camera", "path", "out"):
        v = p.get(key)
        if v:
            return " ".join(map(str, v)) if isinstance(v, (tuple, list)) else str(v)
    return None


def _debug(ctx):
    root = ctx.find_root() if ctx is not None else None
    return bool(root is not None and root.params.get("debug"))


def run(fn):
    """Decorator: the command's one error boundary.

    Every exception ends in one line on stderr and exit status 1, never a traceback: the
    errors pencilcal raises on purpose as they are; OS errors with the file they concern;
    running out of memory with the input; Ctrl-C and SIGTERM as "interrupted" /
    "terminated"; anything else as an internal error naming the command and its input
    (``pencilcal --debug`` shows the traceback instead). Usage errors stay click's (exit 2).
    """

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        ctx = click.get_current_context(silent=True)
        try:
            return fn(*args, **kwargs)
        except (click.ClickException, click.exceptions.Exit, click.Abort):
            raise
        except PencilcalError as e:
            raise SystemExit(_fail(str(e)))
        except KeyboardInterrupt:
            raise SystemExit(_fail("interrupted"))
        except Terminated:
            raise SystemExit(_fail("terminated", status=143))
        except MemoryError:
            where = _inputs(ctx)
            raise SystemExit(_fail(f"{where + ': ' if where else ''}out of memory (the inputs need more memory "
                                   "than this machine has; use fewer or smaller frames)"))
        except OSError as e:
            name = getattr(e, "filename", None)
            reason = e.strerror or str(e)
            raise SystemExit(_fail(f"{name}: {reason}" if name else reason))
        except RecursionError:
            where = _inputs(ctx)
            raise SystemExit(_fail(f"{where + ': ' if where else ''}input nested too deeply to read"))
        except Exception as e:  # noqa: BLE001 - the boundary: nothing escapes as a traceback
            if _debug(ctx):
                raise
            cmd = ctx.command_path if ctx is not None else "pencilcal"
            where = _inputs(ctx)
            what = f"{type(e).__name__}: {str(e).strip().splitlines()[0] if str(e).strip() else ''}".rstrip(": ")
            raise SystemExit(_fail(f"internal error in `{cmd}`{' on ' + where if where else ''}: {what} "
                                   "(please report this; `pencilcal --debug ...` shows the traceback)"))

    return wrapper


def _fail(msg, status=1):
    click.echo(f"pencilcal: error: {msg.splitlines()[0] if msg else 'failed'}", err=True)
    return status


def warn(msg):
    click.echo(f"pencilcal: warning: {msg}", err=True)


def done(summary, *paths, quiet=False):
    """A command's last line on stderr (none with --quiet): its headline figure and the
    absolute paths of what it wrote ("SUMMARY -> /abs/out.json")."""
    import os

    if quiet:
        return
    where = ", ".join(os.path.abspath(str(p)) for p in paths if p is not None)
    click.echo(f"{summary} -> {where}" if where else summary, err=True)


@contextlib.contextmanager
def progress(items, label, quiet):
    """A progress bar on stderr over `items` (silent with --quiet or when not a terminal)."""
    if quiet or not sys.stderr.isatty():
        yield items
        return
    with click.progressbar(items, label=label, file=sys.stderr, show_pos=True) as bar:
        yield bar


class LabelledProgress:
    """`progress` as a plain iterable with a length: the ``progress(items, label)``
    callback the library's sequence functions take (validate_path and the like)."""

    def __init__(self, it, label, quiet):
        self.it, self.label, self.quiet = it, label, quiet

    def __iter__(self):
        with progress(self.it, self.label, self.quiet) as bar:
            yield from bar

    def __len__(self):
        return len(self.it)


def check_output(path, force, inputs=()):
    """Fail before doing any work if the output exists (without --force), has no folder,
    cannot be written, or is one of the `inputs` (paths read by the command: even with
    --force an input is never overwritten by an output)."""
    import os

    check_writable(path, force)
    out = os.path.realpath(path)
    for p in inputs:
        if p is not None and os.path.realpath(str(p)) == out:
            raise InputError(f"{path}: is one of the inputs; choose another output")


#: The options several commands share, in detail: docs/cli.md (`helpdoc`) prints these after
#: the commands' --help, which keeps each option to one line.
SHARED_DETAILS = {
    "--camera": "Camera file: pencilcal `.json`, OpenCV `.yaml/.yml/.xml`, mrcal `.cameramodel`, COLMAP "
                "`cameras.txt`, `cameras.bin` or a sparse model folder (`--camera-id` picks one camera of a "
                "COLMAP file with several).",
    "IMAGES": "One or more image files, folders or glob patterns, taken in the order given (a folder's images "
              "sorted naturally: 2 before 10), or one video file.",
    "--source": "Instead of IMAGES: a camera index (0), a URL OpenCV opens (rtsp://...), or a video file still "
                "being written (followed until it stops growing for 5 s). Frames are read as they come; frames "
                "dropped because processing is slower than the source are counted (a warning, frames_dropped "
                "in --jsonl). Ctrl-C stops it and the output is written for the frames done.",
    "--mask": "Where the scene is in the frames: a PNG (nonzero = valid) or a .json/.yaml with "
              "{circle: [cx, cy, r]} or {polygon: [[x, y], ...]} [px] (a lines.json's valid_region too). "
              "Default: detected once per sequence from up to 16 frames (a circular field stop, letterbox "
              "bars); nothing is detected on its boundary.",
    "--detector": "The OpenCV detector proposing segments: LSD, FLD (fast line detector) or EDLines. auto: FLD "
                  "for printed bars on frames of 720 lines or more (proposed at half resolution: as sensitive "
                  "there as LSD, at a fraction of its cost), LSD on smaller frames and for edge segments and "
                  "shaft proposals.",
    "--gamma": "Encoding gamma of the frames: the shafts' silhouette edges are located on intensities "
               "linearised with it (blur acts on linear light; on encoded levels a blurred edge's gradient "
               "peak leans towards its dark side, the band comes out narrow and the 3-D axis too far). 2.2: "
               "8-bit video and JPEG (and `pencilcal simulate`'s default); 1: linear frames "
               "(`simulate --gamma 1`).",
    "--jsonl": "Also write one JSON object per frame as each frame is done (- for standard output), for a live "
               "consumer (a ROS bridge, a dashboard); the output file is written at the end as usual.",
    "--overlay": "Also write the frames with the estimate drawn on them: a video (.mp4, .avi) or one PNG per "
                 "frame in a folder (a path ending with /).",
    "--max-pixels": "Refuse an image whose header claims more pixels than this, before decoding it (a "
                    "decompression bomb).",
    "--workers": "Process frames in this many worker processes; the results are the same, in the same order.",
    "--force": "Overwrite the output if it exists; nothing the user has is overwritten without it, and an "
               "input is never overwritten by an output.",
    "-q, --quiet": "No progress bar and no summary line; errors and warnings are still said on stderr.",
}


output_option = click.option("-o", "--output", required=True, type=click.Path(dir_okay=False), help="Output file.")
force_option = click.option("--force", is_flag=True, help="Overwrite the output if it exists.")
quiet_option = click.option("-q", "--quiet", is_flag=True, help="No progress bar, no summary line.")
def _positive(ctx, param, value):
    if value is not None and not value > 0:
        raise click.BadParameter("must be positive")
    return value


def detector_option(help):
    """--detector: the OpenCV line detector proposing segments (one list, one default, for
    every command that detects lines); `help` says what it proposes there."""
    from pencilcal.toolkit.detect.segments import DETECTOR_CHOICES

    return click.option("--detector", type=click.Choice(DETECTOR_CHOICES), default="auto", show_default=True,
                        help=help + " auto: FLD for printed bars at 720 lines or more, else LSD.")


def gamma_option(fn):
    """--gamma: the frames' encoding gamma, where shafts are detected (one option, one
    default, for every command that detects them: `detect.shafts.detect_shafts`)."""
    from pencilcal.toolkit.detect.edges import DEFAULT_GAMMA

    return click.option(
        "--gamma", type=FiniteFloat(min=0.1, max=5), default=DEFAULT_GAMMA, show_default=True,
        help="Encoding gamma, for the shafts' edges (1: linear).")(fn)


def endpoint_sigma_option(help):
    """--endpoint-sigma [px]: the end point noise of segments without their own sigma, with
    the library's default (`pencil.defaults.ENDPOINT_SIGMA_PX`); positive and finite."""
    from pencilcal.toolkit.pencil.defaults import ENDPOINT_SIGMA_PX

    return click.option("--endpoint-sigma", type=FiniteFloat(), default=ENDPOINT_SIGMA_PX, show_default=True,
                        callback=_positive, help=help)


max_pixels_option = click.option(
    "--max-pixels", type=click.IntRange(min=1), default=DEFAULT_MAX_PIXELS, show_default=True,
    help="Refuse larger images (their header's size).")

IMAGES_HELP = ("IMAGES is one or more image files, folders or glob patterns, taken in the order given (a "
               "folder's images sorted naturally: 2 before 10), or one video file.")


class FiniteFloat(click.FloatRange):
    """A float option that must be finite (click's FloatRange lets nan and inf through:
    ``--min-length nan`` was accepted, ``simulate --blur inf`` crashed in OpenCV), with
    FloatRange's optional bounds."""

    name = "float"

    def _describe_range(self):
        # click writes an open range as "x<=None" in the help; no bounds: nothing to say
        return "" if self.min is None and self.max is None else super()._describe_range()

    def convert(self, value, param, ctx):
        import math

        v = click.FLOAT.convert(value, param, ctx) if not isinstance(value, float) else value
        if not math.isfinite(v):
            self.fail(f"{value!r} is not a finite number.", param, ctx)
        return super().convert(v, param, ctx)


jsonl_option = click.option(
    "--jsonl", "jsonl_path", default=None, metavar="PATH|-",
    help="Also stream one JSON object per frame as it is done (- for standard output).")
overlay_option = click.option(
    "--overlay", "overlay_path", default=None, metavar="OUT.mp4|DIR/",
    help="Also draw the estimates on the frames: a video (.mp4, .avi) or DIR/ of PNGs.")


source_option = click.option(
    "--source", "source_spec", default=None, metavar="INDEX|URL|FILE",
    help="Instead of IMAGES: a camera index, a URL, or a video still being written.")


def open_input(images, source_spec, max_pixels, gray=False):
    """The frames of a per-frame command: IMAGES (`open_images`) or --source (`open_stream`),
    exactly one of them."""
    if (images is None) == (source_spec is None):
        raise click.UsageError("give IMAGES or --source (one of them)")
    if source_spec is not None:
        from pencilcal.toolkit.io.stream import open_stream

        return open_stream(source_spec, gray=gray, max_pixels=max_pixels)
    from pencilcal.toolkit.io.images import open_images

    return open_images(images, gray=gray, max_pixels=max_pixels)


def frames_region(source, mask_path, shape):
    """The valid region of the frames (`region.detect.sequence_region`); for a stream from
    the mask file or from its first frames (read now, processed as usual afterwards)."""
    from pencilcal.toolkit.detect.region.detect import MAX_FRAMES, detect_valid_region, sequence_region

    if getattr(source, "kind", None) != "stream":
        return sequence_region(source, mask_path, shape=shape)
    if mask_path is not None:
        from pencilcal.toolkit.detect.region.valid import read_mask_file

        return read_mask_file(mask_path, shape)
    frames = [f for f in source.head(MAX_FRAMES) if f.shape[:2] == tuple(shape)]
    return detect_valid_region(frames) if frames else None


def stream_meta(source):
    """The output file's record of a stream: {source, frames_read, frames_dropped,
    interrupted}; {} for IMAGES."""
    if getattr(source, "kind", None) != "stream":
        return {}
    return {"source": source.description, "frames_read": source.read, "frames_dropped": source.dropped,
            "interrupted": bool(source.interrupted)}


class FrameOutputs:
    """The live outputs of a per-frame command: --jsonl (one object per frame, as it is
    done) and --overlay (the drawn frames). Used as a context manager around the frame
    loop; ``emit(record, drawn)`` per frame. A failure leaves no half-written video; a
    stream stopped by Ctrl-C keeps it.

    With a stream `source` each jsonl record also says ``frame_index`` and
    ``frames_dropped`` (so far), and at the end a warning says how many frames were
    dropped and whether Ctrl-C ended the stream. The overlay video's frame rate is `fps`,
    else the source's, else 25.
    """

    def __init__(self, jsonl_path=None, overlay_path=None, force=False, fps=None, source=None):
        from pencilcal.toolkit.draw.writer import OverlayWriter
        from pencilcal.toolkit.io.jsonl import open_jsonl

        self.source = source if getattr(source, "kind", None) == "stream" else None
        fps = fps or getattr(source, "fps", None) or 25.0
        self.jsonl = open_jsonl(jsonl_path, force) if jsonl_path else None
        # drawn and encoded in a thread of their own: the overlay overlaps the next frames' work
        self.overlay = OverlayWriter(overlay_path, fps=fps, force=force, background=True) if overlay_path else None

    @property
    def drawing(self):
        """Whether the frames must be drawn (the tasks then return the drawn frame)."""
        return self.overlay is not None

    def emit(self, record, drawn=None, name=None, extra=None):
        """One frame's record (a dict) to --jsonl, with `extra` keys for the stream only, and
        its drawn frame (an image, a function of no arguments that draws it, or None) to
        --overlay."""
        if self.jsonl is not None:
            if self.source is not None:
                extra = {**(extra or {}), "frame_index": _index(record), "frames_dropped": self.source.dropped}
            self.jsonl.write({**record, **extra} if extra else record)
        if self.overlay is not None and drawn is not None:
            self.overlay.write(name or str(record.get("image", f"{self.overlay.frames:06d}")), drawn)

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, tb):
        if self.overlay is not None:
            self.overlay.close(ok=exc_type is None)
        if self.jsonl is not None:
            self.jsonl.close()
        if exc_type is None and self.source is not None:
            src = self.source
            if src.dropped:
                warn(f"{src.description}: {src.dropped} of {src.read + src.dropped} frames dropped (processing was "
                     "slower than the source)")
            if src.interrupted:
                warn(f"{src.description}: stopped by Ctrl-C after {src.read} frames; writing what was done")
        return False


def _index(record):
    name = str(record.get("image", ""))
    tail = name.rsplit("_", 1)[-1]
    return int(tail) if tail.isdigit() else None


def images_argument(required=True):
    """IMAGES: one or more paths (files, folders, quoted or shell-expanded globs) or one
    video; the command receives them as a tuple (None when optional and absent)."""

    def as_tuple(ctx, param, value):
        return tuple(value) if value else None

    return click.argument("images", nargs=-1, required=required, type=click.Path(), callback=as_tuple)


mask_option = click.option(
    "--mask", "mask_path", type=click.Path(dir_okay=False), default=None,
    help="Valid region (PNG, or .json/.yaml circle/polygon); default: detected.")

workers_option = click.option("--workers", type=click.IntRange(min=1), default=1, show_default=True,
                              help="Worker processes (same results, in order).")


def camera_options(fn):
    """--camera (any supported format) and --camera-id (COLMAP files with several cameras)."""
    fn = click.option("--camera-id", type=int, default=None, help="The camera's id in a COLMAP file.")(fn)
    return click.option(
        "--camera", "camera_path", required=True, type=click.Path(),
        help="Camera file (pencilcal, OpenCV, mrcal or COLMAP).",
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
    if getattr(source, "kind", None) == "stream":  # no length: no bar
        yield from results
        return
    with progress(Sized(results, len(source)), label, quiet) as it:
        yield from it
