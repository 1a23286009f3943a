"""`pencilcal report`: a validation.json as one self-contained HTML page or a PDF."""
from __future__ import annotations

import shlex
from pathlib import Path

import click

from pencilcal.validation.report import FORMATS, load_sensitivity, write_report
from pencilcal.validation.validation_file import load_validation

from .common import command, check_output, force_option, quiet_option, run


def _command(validation, output, samples, title, sensitivity, force, quiet):
    """The command line that reproduces this report (options as given)."""
    args = ["pencilcal", "report", str(validation), "-o", str(output)]
    if samples != 4:
        args += ["--samples", str(samples)]
    if title is not None:
        args += ["--title", title]
    if sensitivity is not None:
        args += ["--sensitivity", str(sensitivity)]
    if force:
        args.append("--force")
    if quiet:
        args.append("--quiet")
    return shlex.join(args)


@command()
@click.argument("validation", type=click.Path(dir_okay=False))
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False),
              help="Report file: .html (self-contained page) or .pdf (A4 pages).")
@click.option("--samples", type=click.IntRange(0, 50), default=4, show_default=True,
              help="Sample frames drawn with their overlays, spread over the reference tilt (0: none); the "
                   "fulcrum section, where there is one, draws the fulcrum on as many, three at most.")
@click.option("--title", default=None, help="Page title (default: 'Validation report: SEQUENCE').")
@click.option("--sensitivity", "sensitivity_path", type=click.Path(dir_okay=False), default=None,
              help="sensitivity.json of `pencilcal sensitivity`: adds its answer, heatmaps and the plan next to "
                   "the measured errors.")
@force_option
@quiet_option
@run
def report(validation, output, samples, title, sensitivity_path, force, quiet):
    """Turn a validation.json into a report a reviewer can read: HTML or PDF.

    VALIDATION is the output of `pencilcal validate`. The report holds, in order: what was
    validated and a verdict computed from the numbers (including what the file does not
    cover); a summary table of every method (orient models, PnP methods, SfM); error
    against tilt with the Cramer-Rao bound and the calibration of the reported sigmas;
    per-frame tables; overlays on sample frames (pencil segments by spoke, vertex and its
    covariance, board axes at the reference pose, normals); calibration quality, the
    reconstruction and a sensitivity plan when present; versions, commands and input hashes.

    The HTML page is self-contained (styles inline, images embedded, nothing fetched from
    the network); the PDF has the same content on A4 pages. The format follows the
    suffix of -o.

    \b
    Example:
      pencilcal simulate sim --scenario orbit --frames 30 --seed 1
      pencilcal validate sim --sfm -o validation.json
      pencilcal report validation.json -o report.html
      pencilcal report validation.json -o report.pdf --sensitivity sensitivity.json
    """
    if Path(output).suffix.lower() not in FORMATS:
        raise click.BadParameter(f"{output}: the suffix must be .html or .pdf", param_hint="-o/--output")
    check_output(output, force)
    data = load_validation(validation)
    sens = load_sensitivity(sensitivity_path) if sensitivity_path is not None else None
    rep = write_report(output, data, force=force, title=title, samples=samples, sensitivity=sens, source=validation,
                       report_command=_command(validation, output, samples, title, sensitivity_path, force, quiet),
                       sensitivity_path=sensitivity_path)
    if not quiet:
        n = len(data["frames"])
        click.echo(f"{rep.title}: {n} frames, {len(rep.sections)} sections -> {output}", err=True)
