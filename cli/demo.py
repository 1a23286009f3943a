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


def default_folder(cwd=None):
    """Where the demo writes by default: ./pencilcal-demo, or, when the current folder is
    inside a git checkout (the source's own, say: its files must not fill it),
    pencilcal-demo in the system's temporary folder."""
    import tempfile

    cwd = Path(cwd or os.getcwd()).resolve()
    inside = any((d / ".git").exists() for d in (cwd, *cwd.parents))
    return (Path(tempfile.gettempdir()) if inside else cwd) / "pencilcal-demo"


@command()
@click.option("-o", "--output", "out", type=click.Path(file_okay=False), default=None,
              help="Folder to write; default: ./pencilcal-demo, or in the temporary folder inside a checkout.")
@click.option("--frames", type=click.IntRange(min=6, max=60), default=16, show_default=True,
              help="Frames of the simulated orbit.")
@click.option("--sfm/--no-sfm", default=True, show_default=True,
              help="Also reconstruct the orbit with pycolmap and compare.")
@click.option("--pivot/--no-pivot", default=True, show_default=True,
              help="Also a pivoting instrument: its fulcrum against the truth.")
@click.option("--seed", type=int, default=1, show_default=True, help="Seed of the simulated sequences.")
@click.option("--force", is_flag=True, help="Replace an earlier demo in the folder.")
@quiet_option
@run
def demo(out, frames, sfm, pivot, seed, force, quiet):
    """Simulate a sequence of the printed target and validate it end to end.

    \b
    Examples:
      pencilcal demo
      pencilcal demo -o /tmp/demo --frames 30 --force

    Writes OUT/report.html (the orientation against truth, PnP and SfM) and
    OUT/pivot-report.html (a pivoting instrument's fulcrum), each with every file it used,
    and prints their verdicts and absolute paths. About a minute. In detail: docs/cli.md.
    \f
    A camera orbits the printed sheet (a ChArUco board with a fan of spokes beside it, as
    `pencilcal target` prints it) on a textured table. Every frame's orientation is
    estimated from the fan's image angles alone and compared with the exact truth, with
    board PnP by every method and (unless --no-sfm) with a pycolmap reconstruction; the
    report puts them side by side. Writes OUT/sequence/ (images, camera, board, pencil,
    truth), OUT/validation.json and OUT/report.html. Unless --no-pivot, an 8 mm instrument
    shaft pivoting about its port is simulated too (OUT/pivot/), the camera fixed above the
    sheet: its fulcrum, found from the shafts alone, in the image and in 3-D, against the
    truth, in OUT/pivot-report.html. In both, the twin of frames the spoke radii leave
    ambiguous is resolved by continuity along the sequence (`validate --continuity`), and
    the verdict says how many frames each resolved.

    The default OUT is pencilcal-demo in the current folder, or in the system's temporary
    folder when the current folder is inside a git checkout (the source's own, say), so
    that a demo never fills a clone with untracked files; the repository ignores
    pencilcal-demo/ too. Each report's verdict line and its absolute path end the output
    (the paths alone, on standard output, with --quiet). An earlier demo in OUT is replaced
    only with --force; a folder holding anything else never is.
    """
    from pencilcal.toolkit.synth.folder import write_sequence
    from pencilcal.toolkit.synth.scenarios import make_scenario
    from pencilcal.validation.report import write_report
    from pencilcal.validation.validate import validate_path
    from pencilcal.validation.validation_file import write_validation

    out = Path(out) if out is not None else default_folder()
    out = out.absolute()
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
    _said(report, out / "report.html", quiet)
    if pivot:
        _pivot_demo(out, seed, quiet)


def _said(report, path, quiet):
    """A report's verdict line on stderr (not with --quiet), its absolute path on stdout."""
    v = report.lead[0]
    if not quiet:
        click.echo(f"{v.status}: {v.text}", err=True)
    click.echo(str(Path(path).absolute()))


def _pivot_demo(out, seed, quiet):
    """OUT/pivot/, OUT/pivot-validation.json and OUT/pivot-report.html: a simulated pivot
    sequence validated (the fulcrum record) and its report; says its verdict and path."""
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
    report = write_report(out / "pivot-report.html", data, force=True, source=str(out / "pivot-validation.json"),
                          title="pencilcal demo: an instrument pivoting about its port")
    _said(report, out / "pivot-report.html", quiet)
