"""`pencilcal bench`: speed and accuracy side by side with the OpenCV and pycolmap baselines."""
from __future__ import annotations

import json

import click

from pencilcal.toolkit.io.files import to_jsonable, write_json
from pencilcal.validation.bench import format_table, run_bench

from .common import command, check_output, done, run

SECTIONS = ("orient", "shafts", "pnp", "sfm", "estimator", "orient_video", "shafts_video", "orient_motion",
            "shafts_motion", "calibrate")


@command()
@click.option("--json", "as_json", is_flag=True, help="Print the figures as one JSON object instead of a table.")
@click.option("--quick", is_flag=True, help="Fewer frames and repeats (noisier, a few times faster).")
@click.option("--sections", default=",".join(SECTIONS), show_default=True,
              help="Which benchmarks to run (comma-separated).")
@click.option("--seed", type=int, default=0, show_default=True, help="Seed of the rendered frames.")
@click.option("-o", "--output", type=click.Path(dir_okay=False), default=None, help="Also write the JSON here.")
@click.option("--force", is_flag=True, help="Overwrite --output if it exists.")
@click.option("-q", "--quiet", is_flag=True, help="No progress lines on stderr.")
@run
def bench(as_json, quick, sections, seed, output, force, quiet):
    """Timings and accuracy, as ratios against OpenCV and pycolmap run in this process.

    \b
    Examples:
      pencilcal bench
      pencilcal bench --json --quick --sections orient,estimator

    Ratios of pencilcal against the bare library calls on the same inputs: they mean the
    same on any machine. In detail: docs/cli.md, docs/performance.md.
    \f
    Renders frames with exact truth once, then times pencilcal and the bare library calls
    on the same inputs: image -> orientation over FLD detection on 1920x1080 frames
    (orient_vs_fld_1080p), decoding and instrument-shaft detection over decoding and FLD on
    1920x1080 frames (shafts_vs_fld_1080p: the shared real laparoscopy frames when present,
    else rendered ones; shafts_frames says which), pnp over CharucoDetector + solvePnP
    (pnp_vs_opencv), the reconstruction over bare pycolmap (sfm_vs_pycolmap), batched over
    looped fits (batch_speedup, fits_per_minute_batched) and the Monte Carlo RMSE over the
    Cramer-Rao bound at 20 deg of tilt (crlb_ratio_tilt20); a whole `pencilcal orient` /
    `fulcrum` process on a 1080p video over decoding it plus FLD on every frame
    (orient_video_vs_decode_fld_1080p, shafts_video_vs_decode_fld_1080p, with the start-up
    and the per-frame time beside them; shafts_video_point_vs_decode_fld_1080p: `fulcrum` with
    --shaft-diameter, the 3-D point and its jackknife too); on a moving camera (a hand-held fan at the speeds
    of a hand and twice them, with and without --overlay, at its default half size and at
    full size; a moving instrument over a tissue-like texture) both sides as whole
    processes, with the fraction of frames tracked and, for the fan, of tilts within 0.5
    deg of the truth, and the CPU seconds over the floor's beside the wall-time ratios
    (orient_motion_*, orient_motion2x_*, shafts_motion_*). Ratios mean the same on any
    machine.
    """
    chosen = tuple(s.strip() for s in sections.split(",") if s.strip())
    bad = [s for s in chosen if s not in SECTIONS]
    if bad or not chosen:
        raise click.BadParameter(f"expected a comma-separated subset of {', '.join(SECTIONS)}", param_hint="--sections")
    if output:
        check_output(output, force)
    log = None if quiet else (lambda m: click.echo(m, err=True))
    res = run_bench(quick=quick, seed=seed, sections=chosen, log=log)
    if output:
        write_json(output, res, force=force)
    if as_json:
        click.echo(json.dumps(to_jsonable(res), indent=1))
    else:
        click.echo(format_table(res))
    if output:
        done("bench: the figures above, as JSON", output, quiet=quiet)
