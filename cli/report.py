"""`pencilcal report`: a validation.json as one self-contained HTML page or a PDF."""
from __future__ import annotations

import shlex
from pathlib import Path

import click

from pencilcal.validation.report import FORMATS, load_sensitivity, write_report
from pencilcal.validation.validation_file import load_validation

from .common import command, check_output, done, force_option, quiet_option, run


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
              help="Sample frames drawn with their overlays (0: none).")
@click.option("--title", default=None, help="Page title (default: 'Validation report: SEQUENCE').")
@click.option("--sensitivity", "sensitivity_path", type=click.Path(dir_okay=False), default=None,
              help="sensitivity.json: the plan next to the measured errors.")
@force_option
@quiet_option
@run
def report(validation, output, samples, title, sensitivity_path, force, quiet):
    """Turn a validation.json into a report a reviewer can read: HTML or PDF.

    \b
    Examples:
      pencilcal report validation.json -o report.html
      pencilcal report validation.json -o report.pdf --sensitivity plan.json

    The page opens with its answer: the verdict line, the few numbers that matter, then
    the evidence. The last line says the verdict too. In detail: docs/cli.md, docs/report.md.
    \f
    VALIDATION is the output of `pencilcal validate`. The report opens with its answer:
    one verdict line (what was measured, the headline figure with its unit and sigma, and
    whether it passes against its stated tolerance) and a small table of the numbers that
    matter; the comparison models of the book chapter are shown as comparisons, never as
    failed gates. A validation of a pivot (a `fulcrum` record) leads with the fulcrum: its
    image and 3-D point [mm] against the truth where known. Then the evidence: the gates
    on the honesty of every sigma, the summary table of every method (orient models, PnP
    methods, SfM), error against tilt with the Cramer-Rao bound and the calibration of the
    reported sigmas, per-frame tables, overlays on sample frames (--samples of them, spread
    over the reference tilt: pencil segments by spoke, vertex and its covariance, board
    axes at the reference pose, normals; the fulcrum drawn on as many, three at most),
    calibration quality, the reconstruction and a sensitivity plan (--sensitivity: a
    sensitivity.json of `pencilcal sensitivity`, its answer, heatmaps and the plan next to
    the measured errors) when present; versions, commands and input hashes.

    The HTML page is self-contained (styles inline, images embedded, nothing fetched from
    the network); the PDF has the same content on A4 pages. The format follows the
    suffix of -o.

    More examples:

        pencilcal simulate sim --scenario orbit --frames 30 --seed 1
        pencilcal validate sim --sfm -o validation.json
        pencilcal report validation.json -o report.html
    """
    if Path(output).suffix.lower() not in FORMATS:
        raise click.BadParameter(f"{output}: the suffix must be .html or .pdf", param_hint="-o/--output")
    check_output(output, force)
    data = load_validation(validation)
    sens = load_sensitivity(sensitivity_path) if sensitivity_path is not None else None
    rep = write_report(output, data, force=force, title=title, samples=samples, sensitivity=sens, source=validation,
                       report_command=_command(validation, output, samples, title, sensitivity_path, force, quiet),
                       sensitivity_path=sensitivity_path)
    verdict = rep.lead[0]
    done(f"{verdict.status}: {verdict.text}", output, quiet=quiet)
