"""`pencilcal demo`: a simulated sequence validated end to end, as a report to look at."""
from __future__ import annotations

import os
import sys
from pathlib import Path

import click

from pencilcal.toolkit.errors import InputError

from .common import command, LabelledProgress, StageBars, progress, quiet_option, run, warn

# What makes a folder an earlier demo's (safe to replace with --force).
_DEMO_FILES = ("report.html", "validation.json", "sequence", "pivot", "pivot-validation.json", "pivot-report.html")


def _check_demo_folder(out, force):
    """InputError before any work if OUT holds anything but an earlier demo (that only with
    --force)."""
    parent = out.parent if str(out.parent) else Path(".")
    if not parent.is_dir():
        raise InputError(f"{out}: folder {parent} does not exist")
    if out.exists():
        if not out.is_dir():
            raise InputError(f"{out}: exists and is not a folder")
        entries = set(os.listdir(out))
        if entries and not force:
            raise InputError(f"{out}: folder is not empty; pass --force to replace an earlier demo")
        if entries - set(_DEMO_FILES):
            raise InputError(f"{out}: holds files a demo did not write ({', '.join(sorted(entries - set(_DEMO_FILES)))}); "
                             "not replacing them, even with --force")


@command()
@click.option("-o", "--output", "out", type=click.Path(file_okay=False), default="pencilcal-demo", show_default=True,
              help="Folder for the sequence, validation.json and report.html.")
@click.option("--frames", type=click.IntRange(min=6, max=60), default=16, show_default=True,
              help="Frames of the simulated sequence (more: a slower, steadier reconstruction).")
@click.option("--sfm/--no-sfm", default=True, show_default=True,
              help="Also reconstruct the sequence with pycolmap and compare it.")
@click.option("--pivot/--no-pivot", default=True, show_default=True,
              help="Also an instrument pivoting about its port: its fulcrum in 2-D and 3-D against the truth.")
@click.option("--seed", type=int, default=1, show_default=True, help="Seed of the simulated sequence.")
@click.option("--force", is_flag=True, help="Replace an earlier demo in the folder.")
@quiet_option
@run
def demo(out, frames, sfm, pivot, seed, force, quiet):
    """Simulate a sequence of the printed target and validate it end to end.

    A camera orbits the printed sheet (a ChArUco board with a fan of spokes beside it, as
    `pencilcal target` prints it) on a textured table. Every frame's orientation is
    estimated from the fan's image angles alone and compared with the exact truth, with
    board PnP by every method and (unless --no-sfm) with a pycolmap reconstruction; the
    report puts them side by side. Writes OUT/sequence/ (images, camera, board, pencil,
    truth), OUT/validation.json and OUT/report.html, and prints the report's path. Unless
    --no-pivot, an 8 mm instrument shaft pivoting about its port is simulated too
    (OUT/pivot/): its fulcrum, found from the shafts alone, in the image and in 3-D, against
    the truth, in OUT/pivot-report.html. About 1-2 minutes on two cores.

    \b
    Example:
      pencilcal demo
      pencilcal demo -o /tmp/demo --frames 30 --force
    """
    from pencilcal.toolkit.synth.folder import write_sequence
    from pencilcal.toolkit.synth.scenarios import make_scenario
    from pencilcal.validation.report import write_report
    from pencilcal.validation.validate import validate_path
    from pencilcal.validation.validation_file import write_validation

    out = Path(out)
    _check_demo_folder(out, force)
    out.mkdir(exist_ok=True)
    seq = out / "sequence"
    scenario = make_scenario("orbit", frames, seed, size=(960, 540))

    def bar(it):
        with progress(it, "simulate", quiet) as b:
            yield from b

    write_sequence(seq, scenario, noise=5.0, blur_px=1.5, camera_source="built-in opencv", progress=bar)
    stage_bars = StageBars() if (sfm and not quiet and sys.stderr.isatty()) else None
    try:
        data = validate_path(str(seq), sfm=sfm, warn=warn, quiet=quiet, sfm_progress=stage_bars,
                             progress=lambda it, label: LabelledProgress(it, label, quiet))
    finally:
        if stage_bars is not None:
            stage_bars.close()
    write_validation(out / "validation.json", data, force=True)
    report = write_report(out / "report.html", data, force=True, source=str(out / "validation.json"),
                          title="pencilcal demo: a simulated orbit of the printed target")
    if not quiet:
        click.echo(f"{len(data['frames'])} frames, {len(report.sections)} sections", err=True)
    click.echo(str(out / "report.html"))
    if pivot:
        _pivot_demo(out, seed, quiet)


def _pivot_demo(out, seed, quiet):
    """OUT/pivot/, OUT/pivot-validation.json and OUT/pivot-report.html: a simulated pivot
    sequence validated (the fulcrum record) and its report; prints the report's path."""
    from pencilcal.toolkit.synth.folder import write_sequence
    from pencilcal.toolkit.synth.scenarios import make_scenario
    from pencilcal.validation.report import write_report
    from pencilcal.validation.validate import validate_path
    from pencilcal.validation.validation_file import write_validation

    seq = out / "pivot"

    def bar(it):
        with progress(it, "simulate pivot", quiet) as b:
            yield from b

    write_sequence(seq, make_scenario("pivot", 12, seed, size=(960, 540), shaft_radius=4.0),
                   camera_source="built-in opencv", progress=bar)
    data = validate_path(str(seq), warn=warn, quiet=quiet,
                         progress=lambda it, label: LabelledProgress(it, label, quiet))
    write_validation(out / "pivot-validation.json", data, force=True)
    write_report(out / "pivot-report.html", data, force=True, source=str(out / "pivot-validation.json"),
                 title="pencilcal demo: an instrument pivoting about its port")
    click.echo(str(out / "pivot-report.html"))
