"""Plumbing shared by the commands: errors, progress, output paths.

Every command runs its body through `run`, which turns the errors pencilcal raises on
purpose (and the usual OS errors) into one line on stderr and exit status 1. Usage errors
are click's and exit with 2. Warnings about single frames go to stderr as one line each.
"""
from __future__ import annotations

import contextlib
import functools
import os
import signal
import sys
import threading
import warnings

import click

from pencilcal.toolkit.errors import InputError, PencilcalError
from pencilcal.toolkit.io.files import check_writable
from pencilcal.toolkit.io.images import DEFAULT_MAX_PIXELS

__all__ = ["CONTEXT_SETTINGS", "command", "Command", "Group", "OneLineUsageError", "run", "progress", "warn", "done",
           "output_option", "force_option", "quiet_option", "check_output",
           "camera_options", "StageBars", "workers_option", "run_frames", "images_argument", "max_pixels_option",
           "IMAGES_HELP", "SHARED_DETAILS", "FiniteFloat", "LabelledProgress", "mask_option", "jsonl_option", "overlay_option",
           "FrameOutputs", "detector_option", "endpoint_sigma_option", "source_option", "open_input", "frames_region", "stream_meta",
           "instrument_mask_options", "instrument_masks", "warn_masks", "camera_options_optional"]

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



# The signals that end a run: Ctrl-C, kill's default, a closed terminal. Exit status 128 + the
# signal's number, as shells report a command a signal ended (130, 143, 129).
STOP_SIGNALS = {signal.SIGINT: "interrupted", signal.SIGTERM: "terminated"}
if hasattr(signal, "SIGHUP"):
    STOP_SIGNALS[signal.SIGHUP] = "hung up"
_received = []  # the stop signals this process has received


class Stopped(BaseException):
    """A stop signal (`STOP_SIGNALS`), raised in the main thread so that clean-up runs on
    the way out (temporary files removed, workers stopped) as for any exception."""

    def __init__(self, signum):
        super().__init__(signum)
        self.signum = signum


def _on_signal(signum, frame):
    """The first stop signal raises `Stopped`; a second is ignored, so that the clean-up it
    starts is not cut short (it takes well under a second); a third ends the process at once."""
    _received.append(signum)
    if len(_received) == 1:
        raise Stopped(signum)
    if len(_received) >= 3:
        os._exit(128 + _received[0])


def install_signal_handlers():
    """Stop signals become `Stopped` (see `_on_signal`). A signal the command was started
    with ignored (a background job's Ctrl-C, nohup's SIGHUP) stays ignored."""
    _received.clear()
    for s in STOP_SIGNALS:
        if signal.getsignal(s) is not signal.SIG_IGN:
            signal.signal(s, _on_signal)


def release_signal_handlers():
    """Once the run's outcome is settled (its outputs written or not, its message said): a
    late signal changes nothing, and must not end the exit with a traceback."""
    for s in STOP_SIGNALS:
        signal.signal(s, signal.SIG_IGN)


def stopped_status(signum, since=None):
    """Say that a stop signal ended the run (and which outputs it had put in place after the
    first `since` of the process, `files.outputs_written`); the exit status, 128 + the
    signal's number."""
    from pencilcal.toolkit.io.files import outputs_written

    msg = f"{STOP_SIGNALS.get(signum, 'stopped')} ({signal.Signals(signum).name})"
    n, latest = outputs_written(since) if since is not None else (0, [])
    if n:
        names = ", ".join(str(p) for p in latest[:3])
        msg += f"; already written: {names}{f' and {n - 3} more' if n > 3 else ''}"
    return _fail(msg, status=128 + signum)


_shown_warnings = set()


def _show_warning(message, category, filename, lineno, file=None, line=None):
    """A Python warning (numpy's floating-point ones above all) as one pencilcal line, once
    per place. Inputs whose numbers would overflow are refused where they are read and frames
    without an estimate are written ok: false, so a warning that still arises is a flaw to
    report, not noise to ignore. ``--debug`` shows them as Python does."""
    key = (category, str(message), filename, lineno)
    if key in _shown_warnings:
        return
    _shown_warnings.add(key)
    warn(f"{category.__name__}: {' '.join(str(message).split())} ({os.path.basename(filename)}:{lineno}; please "
         "report this)")


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

    Every exception ends in one line on stderr, never a traceback: the errors pencilcal
    raises on purpose as they are; OS errors with the file they concern; running out of
    memory with the input; anything else as an internal error naming the command and its
    input (``pencilcal --debug`` shows the traceback instead); all with exit status 1. A
    stop signal (Ctrl-C, SIGTERM, SIGHUP) says so, and which outputs were already in place,
    with exit status 128 + its number (130, 143, 129). Usage errors stay click's (exit 2).
    Python warnings (numpy's floating-point ones) are said in one line each
    (`_show_warning`).
    """

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        from pencilcal.toolkit.io.files import outputs_written

        ctx = click.get_current_context(silent=True)
        mark = outputs_written()[0]
        _shown_warnings.clear()
        try:
            with warnings.catch_warnings():
                if not _debug(ctx):
                    warnings.showwarning = _show_warning
                return fn(*args, **kwargs)
        except (click.ClickException, click.exceptions.Exit, click.Abort):
            raise
        except Stopped as e:
            raise SystemExit(stopped_status(e.signum, mark))
        except KeyboardInterrupt:  # SIGINT where pencilcal's handlers are not installed (the API, tests)
            raise SystemExit(stopped_status(signal.SIGINT, mark))
        except Exception as e:  # noqa: BLE001 - the boundary: nothing escapes as a traceback
            if _received:
                # a stop signal whose `Stopped` was raised inside C code (a callback of a
                # builtin) comes back as another error: the run was still stopped by it
                raise SystemExit(stopped_status(_received[0], mark)) from None
            raise SystemExit(_failure(ctx, e)) from None

    return wrapper


def _failure(ctx, e):
    """The one line and exit status of an exception that ended a command (`run`)."""
    where = _inputs(ctx)
    if isinstance(e, PencilcalError):
        return _fail(str(e))
    if isinstance(e, MemoryError):
        return _fail(f"{where + ': ' if where else ''}out of memory (the inputs need more memory than this machine "
                     "has; use fewer or smaller frames)")
    if isinstance(e, OSError):
        name = getattr(e, "filename", None)
        reason = e.strerror or str(e)
        return _fail(f"{name}: {reason}" if name else reason)
    if isinstance(e, RecursionError):
        return _fail(f"{where + ': ' if where else ''}input nested too deeply to read")
    if _debug(ctx):
        raise e
    return _fail(_internal(ctx, e))


def _internal(ctx, e):
    """An unexpected exception's one line: the command, its input, the exception."""
    cmd = ctx.command_path if ctx is not None else "pencilcal"
    where = _inputs(ctx)
    what = f"{type(e).__name__}: {str(e).strip().splitlines()[0] if str(e).strip() else ''}".rstrip(": ")
    return (f"internal error in `{cmd}`{' on ' + where if where else ''}: {what} "
            "(please report this; `pencilcal --debug ...` shows the traceback)")


def _fail(msg, status=1):
    say(f"pencilcal: error: {msg.splitlines()[0] if msg else 'failed'}")
    return status


def say(line):
    """One line on stderr, whatever it holds: a file name that is not UTF-8 (its bytes kept
    as surrogates by Python) is written with those bytes escaped, never an encoding error."""
    text = line.encode("utf-8", "surrogateescape").decode("utf-8", "backslashreplace")
    click.echo(text, err=True)


def warn(msg):
    say(f"pencilcal: warning: {msg}")


def done(summary, *paths, quiet=False):
    """A command's last line on stderr (none with --quiet): its headline figure and the
    absolute paths of what it wrote ("SUMMARY -> /abs/out.json")."""
    import os

    if quiet:
        return
    where = ", ".join(os.path.abspath(str(p)) for p in paths if p is not None)
    say(f"{summary} -> {where}" if where else summary)


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
    "--edge-model": "How the shafts' silhouette edges are located: step, the gradient peak of the edge's "
                    "profile; limb, a profile model of a cylinder lit from the endoscope fitted across each edge "
                    "(background level and slope, diffuse and specular shading that darken towards the "
                    "silhouette, the optics' blur; docs/method.md): the step edge lies inside a shaded shaft's "
                    "limb, narrowing the band and putting its 3-D axis too far. limb costs seconds a frame.",
    "--jsonl": "Also write one JSON object per frame as each frame is done (- for standard output), for a live "
               "consumer (a ROS bridge, a dashboard); the output file is written at the end as usual.",
    "--overlay": "Also write the frames with the estimate drawn on them: a video (.mp4, .avi) or one PNG per "
                 "frame in a folder (a path ending with /).",
    "--overlay-scale": "The overlay's size over the frames' (each side to an even number of pixels, pixel areas "
                       "averaged; the estimates drawn at their places on the smaller frame). The default, half "
                       "size, keeps the overlay cheap: encoding a 1080p frame to mp4 costs more than decoding it "
                       "and finding its lines, half of each side a quarter of that (docs/performance.md); 1 "
                       "draws at full size.",
    "--max-pixels": "Refuse an image whose header claims more pixels than this, before decoding it (a "
                    "decompression bomb).",
    "--workers": "Process frames in this many worker processes; the results are the same, in the same order. "
                 "At most as many as the CPUs this process may use, and as the available memory holds at 512 MiB "
                 "a worker (a warning says when fewer are used than asked for).",
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
    """--gamma: the frames' encoding gamma, where shafts or a radial target's edges are detected
    (one option, one default, for every command that detects them: `detect.shafts.detect_shafts`,
    `detect.radial.detect_radial_edges`)."""
    from pencilcal.toolkit.detect.edges import DEFAULT_GAMMA

    return click.option(
        "--gamma", type=FiniteFloat(min=0.1, max=5), default=DEFAULT_GAMMA, show_default=True,
        help="Encoding gamma of shaft and radial edges (1: linear).")(fn)


def edge_model_option(fn):
    """--edge-model: how the shafts' silhouette edges are located (one option, one default, for
    every command that detects shafts: `detect.shaft.detector.detect_shafts`' edge_model)."""
    from pencilcal.toolkit.detect.shaft.detector import EDGE_MODELS

    return click.option(
        "--edge-model", type=click.Choice(EDGE_MODELS), default="step", show_default=True,
        help="Shaft edge model.")(fn)


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
#: The overlay's size over the frames' unless --overlay-scale says otherwise: encoding a
#: 1080p frame to mp4 costs more (~13 ms on the 2-core development machine) than decoding
#: it and running FLD on it (~9 ms); at half size it costs a quarter (~3.5 ms), and the
#: overlay keeps every line, label and ellipse legible (docs/performance.md).
OVERLAY_SCALE = 0.5


def overlay_option(fn):
    """--overlay OUT.mp4|DIR/ and --overlay-scale S: the commands get `overlay_path` and
    `overlay_scale` (`FrameOutputs`). --overlay-scale given without --overlay is a usage
    error, as every other "only with" option is, rather than silently ignored."""
    @functools.wraps(fn)
    def checked(*args, **kwargs):
        source = click.get_current_context().get_parameter_source("overlay_scale")
        if kwargs.get("overlay_path") is None and source not in (None, click.core.ParameterSource.DEFAULT):
            raise click.BadParameter("only with --overlay", param_hint="--overlay-scale")
        return command(*args, **kwargs)

    command, fn = fn, checked
    fn = click.option("--overlay-scale", type=FiniteFloat(min=0.1, max=1.0), default=OVERLAY_SCALE,
                      show_default=True, metavar="S", help="Its size over the frames' (1: full).")(fn)
    return click.option("--overlay", "overlay_path", default=None, metavar="OUT.mp4|DIR/",
                        help="Also draw the estimates: video or DIR/ PNGs.")(fn)


source_option = click.option(
    "--source", "source_spec", default=None, metavar="INDEX|URL|FILE",
    help="Instead of IMAGES: a camera index, a URL, or a video still being written.")


def open_input(images, source_spec, max_pixels, gray=False, keep_colour=False):
    """The frames of a per-frame command: IMAGES (`open_images`) or --source (`open_stream`),
    exactly one of them; gray, keep_colour: grey frames, with their colour images too
    (`io.images`)."""
    if (images is None) == (source_spec is None):
        raise click.UsageError("give IMAGES or --source (one of them)")
    if source_spec is not None:
        from pencilcal.toolkit.io.stream import open_stream

        return open_stream(source_spec, gray=gray, max_pixels=max_pixels, keep_colour=keep_colour)
    from pencilcal.toolkit.io.images import open_images

    return open_images(images, gray=gray, max_pixels=max_pixels, keep_colour=keep_colour)


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
    else the source's, else 25; its frames are drawn at `scale` of the frames' size
    (--overlay-scale: `drawing` hands it to the tasks, which draw at it).
    """

    def __init__(self, jsonl_path=None, overlay_path=None, force=False, fps=None, source=None, scale=1.0):
        from pencilcal.toolkit.draw.writer import OverlayWriter
        from pencilcal.toolkit.io.jsonl import open_jsonl

        self.source = source if getattr(source, "kind", None) == "stream" else None
        fps = fps or getattr(source, "fps", None) or 25.0
        self.jsonl = open_jsonl(jsonl_path, force) if jsonl_path else None
        # drawn and encoded in a thread of their own: the overlay overlaps the next frames' work
        self.overlay = OverlayWriter(overlay_path, fps=fps, force=force, background=True) if overlay_path else None
        self.scale = float(scale)

    @property
    def drawing(self):
        """None when no frame is drawn, else the scale to draw them at (0 < scale <= 1): the
        tasks then return the frame drawn at it (or a function that draws it)."""
        return self.scale if self.overlay is not None else None

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
            if getattr(src, "stalled", False):
                from pencilcal.toolkit.io.stream import LIVE_SILENCE_S

                warn(f"{src.description}: no frame for {LIVE_SILENCE_S:g} s, the source stopped sending; ending after "
                     f"{src.read} frames, writing what was done")
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

    # readable=False: an input the user may not read is an input error (exit 1, said by the
    # reader with what it is), not a usage error
    return click.argument("images", nargs=-1, required=required, type=click.Path(readable=False), callback=as_tuple)


mask_option = click.option(
    "--mask", "mask_path", type=click.Path(dir_okay=False, readable=False), default=None,
    help="Valid region (PNG, or .json/.yaml circle/polygon); default: detected.")

def instrument_mask_options(fn):
    """--instrument-mask MASKS (one segmentation mask per frame), --mask-label V (repeatable:
    an integer or B,G,R) and --mask-instances: the shafts from the masks' instruments
    (`detect.shaft.from_mask`); the command receives instrument_mask, mask_labels,
    mask_instances."""
    fn = click.option("--mask-instances", is_flag=True, help="Each mask value is one instrument.")(fn)
    fn = click.option("--mask-label", "mask_labels", multiple=True, metavar="V",
                      help="Instrument mask value or B,G,R; repeatable.")(fn)
    return click.option("--instrument-mask", "instrument_mask", default=None, metavar="MASKS",
                        help="Instrument masks, one per frame (folder, pattern): their shafts.")(fn)


def instrument_masks(source, spec, labels, instances):
    """The `io.instrument_masks.InstrumentMasks` of --instrument-mask for the frames of
    `source`, or None without it; usage errors for --mask-label and --mask-instances alone,
    and for a live --source."""
    if spec is None:
        if labels or instances:
            raise click.UsageError("--mask-label and --mask-instances go with --instrument-mask")
        return None
    if getattr(source, "kind", None) == "stream":
        raise click.UsageError("--instrument-mask pairs masks with IMAGES, not with --source")
    from pencilcal.toolkit.io.instrument_masks import source_masks

    return source_masks(source, spec, labels, instances)


def warn_masks(record):
    """A warning per shaft of a frame record whose mask and image disagree (its
    ``mask_warning``, `detect.shaft.from_mask.MaskShaft.disagreement`); an instrument
    region's (cue pixels, `--parts`) is no user's mask: its record keeps the note, unsaid."""
    for sh in record.get("shafts") or []:
        if sh.get("mask_warning") and sh.get("cue") != "pixels":
            warn(f"{record.get('image')}: {sh['mask_warning']}")


def _workers(ctx, param, value):
    """--workers: at most what the machine can hold (`parallel.worker_limit`: its CPUs and
    memory), said in a warning when the request is more."""
    from pencilcal.toolkit.io.parallel import worker_limit

    limit, why = worker_limit()
    if value is not None and value > limit:
        warn(f"--workers {value}: using {limit} ({why})")
        return limit
    return value


workers_option = click.option("--workers", type=click.IntRange(min=1), default=1, show_default=True,
                              callback=_workers, help="Worker processes (same results, in order).")


def camera_options(fn, required=True):
    """--camera (any supported format) and --camera-id (COLMAP files with several cameras)."""
    fn = click.option("--camera-id", type=int, default=None, help="The camera's id in a COLMAP file.")(fn)
    return click.option(
        "--camera", "camera_path", required=required, type=click.Path(readable=False),
        help="Camera file (pencilcal, OpenCV, mrcal or COLMAP)." + ("" if required else " Optional."),
    )(fn)


def camera_options_optional(fn):
    """`camera_options` where the camera may be left out (the command then works in raw
    pixels with a nominal pinhole)."""
    return camera_options(fn, required=False)


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


#: The interpreter's switch interval [s] while the frames run (Python's default: 5 ms). The
#: decoding and overlay threads hold the interpreter only between OpenCV calls, a few
#: microseconds at a time, dozens of times a frame; at 5 ms each such thread waits up to
#: 5 ms for the measuring thread to let go every time, falls behind, and the measuring
#: thread then waits for it. orient on a 1080p video with the overlay: 5.9-7.1 s at 1 ms
#: against 6.5-8.4 s at 5 ms (runs in turns, other jobs on both cores; docs/performance.md).
FRAME_SWITCH_INTERVAL_S = 0.001


def run_frames(source, task, context, workers, label, quiet):
    """Results of ``task(frame, context)`` for every frame of `source`, in order, behind a
    progress bar; with workers > 1 in a process pool (toolkit.parallel.map_frames). `task`
    must be a module-level function. Meanwhile the interpreter switches threads every
    `FRAME_SWITCH_INTERVAL_S`."""
    from pencilcal.toolkit.io.parallel import Sized, map_frames

    before = sys.getswitchinterval()
    sys.setswitchinterval(min(before, FRAME_SWITCH_INTERVAL_S))
    try:
        results = map_frames(task, source, context, workers)
        if getattr(source, "kind", None) == "stream":  # no length: no bar
            yield from results
            return
        with progress(Sized(results, len(source)), label, quiet) as it:
            yield from it
    finally:
        sys.setswitchinterval(before)
