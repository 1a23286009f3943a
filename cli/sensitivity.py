"""`pencilcal sensitivity`: expected orientation error over tilt, position, fan and noise."""
from __future__ import annotations

import math

import click
import numpy as np

from pencilcal.toolkit.errors import InputError
from pencilcal.toolkit.io.files import check_writable, write_json

from .common import (command, check_output, done, FiniteFloat, force_option, output_option, quiet_option, run)

MAP_CHOICES = ("tilt-offaxis", "spokes-spacing", "noise", "all")


def _offaxis_deg(spec, focal):
    """--offaxis in degrees, or in pixels from the principal point with a 'px' suffix."""
    from pencilcal.validation.sensitivity import parse_range

    s = spec.strip().lower()
    if s.endswith("px"):
        px = parse_range(s[:-2], "--offaxis")
        if np.any(px < 0):
            raise InputError(f"--offaxis: pixel distances must be >= 0, got {spec!r}")
        return np.degrees(np.arctan(px / focal))
    return parse_range(s.removesuffix("deg"), "--offaxis")


@command()
@output_option
@click.option("--focal", type=FiniteFloat(), default=800.0, show_default=True, metavar="PX",
              help="Focal length [px] (for --offaxis in px).")
@click.option("--spokes", type=int, default=8, show_default=True, help="Spokes of the fan.")
@click.option("--step-deg", type=FiniteFloat(), default=20.0, show_default=True, help="Angle between spokes [deg].")
@click.option("--sigma-deg", type=FiniteFloat(), default=0.1, show_default=True,
              help="Line-angle noise, sd [deg].")
@click.option("--tilts", default="0:80:2", show_default=True, metavar="RANGE",
              help="Tilts [deg]: start:stop:step, or a,b,c.")
@click.option("--offaxis", default="0:40:10", show_default=True, metavar="RANGE",
              help="Vertex off axis [deg], or [px] with a px suffix.")
@click.option("--trials", type=int, default=1000, show_default=True,
              help="Monte Carlo pencils per cell (0: the bound only).")
@click.option("--accuracy", type=FiniteFloat(), default=1.0, show_default=True, metavar="DEG",
              help="Accuracy asked of the normal [deg RMS].")
@click.option("--map", "maps", type=click.Choice(MAP_CHOICES), multiple=True,
              help="More maps (repeatable; tilt-offaxis always).")
@click.option("--spokes-grid", default="3,4,6,8,12,16", show_default=True, metavar="RANGE",
              help="Spoke counts of that map.")
@click.option("--step-grid", default="5,10,15,20,30,45", show_default=True, metavar="RANGE",
              help="Spacings [deg] of that map.")
@click.option("--sigma-grid", default="0.02,0.05,0.1,0.2,0.5,1", show_default=True, metavar="RANGE",
              help="Noise values [deg] of the noise map.")
@click.option("--tilt-ref", type=FiniteFloat(), default=30.0, show_default=True,
              help="Tilt [deg] of the spokes-spacing map.")
@click.option("--device", type=click.Choice(["cpu", "cuda"]), default="cpu", show_default=True,
              help="Where the torch fits run.")
@click.option("--dtype", type=click.Choice(["float64", "float32"]), default="float64", show_default=True,
              help="Precision of the torch fits.")
@click.option("--seed", type=int, default=0, show_default=True, help="Random seed.")
@click.option("--png", "png_prefix", default=None, metavar="PREFIX",
              help="Also the heatmaps as PREFIX_<map>.png.")
@force_option
@quiet_option
@run
def sensitivity(output, focal, spokes, step_deg, sigma_deg, tilts, offaxis, trials, accuracy, maps, spokes_grid,
                step_grid, sigma_grid, tilt_ref, device, dtype, seed, png_prefix, force, quiet):
    """Plan a set-up: from which tilt on is the orientation good to --accuracy deg?

    \b
    Examples:
      pencilcal sensitivity -o plan.json --accuracy 0.5 --png plan
      pencilcal sensitivity -o plan.json --sigma-deg 0.05 --offaxis 0:400:100px

    The Cramer-Rao bound and a Monte Carlo of the exact estimator over tilts and vertex
    positions, for your focal length, fan and noise. In detail: docs/cli.md.
    \f
    For your focal length (--focal [px], which also converts --offaxis given in pixels to
    angles), fan (--spokes, --step-deg), line noise (--sigma-deg: one standard deviation of
    a line's angle, the same in pixels and normalised coordinates) and the places where
    the vertex sits in the image (--offaxis: angles off the optical axis, or pixels from
    the principal point with a px suffix, 0:400:100px), computes the Cramer-Rao bound and a
    Monte Carlo of the exact estimator (--trials pencils per cell; 0: the bound only) over
    a grid of tilts (--tilts, start:stop:step or a list a,b,c): RMSE, median and 95th
    percentile of the tilt and normal errors, the rate at which the tilt is detectable
    (against the 2 sqrt(sigma) rule), and the minimum tilt for the requested accuracy
    (--accuracy, RMS of the normal). --map adds a spokes x spacing map (--spokes-grid,
    --step-grid, at the tilt --tilt-ref) and a noise x tilt map (--sigma-grid); the
    tilt x off-axis map is always computed. Runs batched in torch when it is installed
    (--device cuda needs torch with CUDA and a GPU; --dtype float32 is enough for planning
    and faster on GPUs), otherwise with the (slower) numpy estimator. Results are
    reproducible for a --seed. --png PREFIX also writes the heatmaps
    PREFIX_tilt-offaxis.png (and PREFIX_spokes-spacing.png, PREFIX_noise.png).

    More examples:

        pencilcal sensitivity -o sensitivity.json --spokes 8 --step-deg 20 --sigma-deg 0.1 --accuracy 0.5 --offaxis 0:400:100px --png plan
    """
    from pencilcal.toolkit.pencil import torch_backend as te
    from pencilcal.validation import sensitivity as sens

    if not (math.isfinite(focal) and focal > 0):
        raise click.BadParameter("must be positive", param_hint="--focal")
    if trials < 0:
        raise click.BadParameter("must be >= 0", param_hint="--trials")
    if not (math.isfinite(accuracy) and accuracy > 0):
        raise click.BadParameter("must be positive", param_hint="--accuracy")
    wanted = set(MAP_CHOICES[:3]) if "all" in maps else set(maps)
    wanted.add("tilt-offaxis")
    check_output(output, force)
    if png_prefix:
        for p in sens.heatmap_paths(png_prefix, wanted):
            check_writable(p, force)
    setup = sens.Setup(focal_px=focal, spokes=spokes, step_deg=step_deg, sigma_deg=sigma_deg)
    off = _offaxis_deg(offaxis, focal)
    # the grids are checked before any work starts
    sens.validate_grids(tilts, off, spokes_grid if "spokes-spacing" in wanted else None,
                        step_grid if "spokes-spacing" in wanted else None, sigma_grid if "noise" in wanted else None)
    if device != "cpu":
        te.require_torch(device)  # one-line error, exit 1, when torch or CUDA is missing
        backend = "torch"
    elif te.torch_available():
        backend = "torch"
    else:
        backend = "numpy"
        if not quiet:
            click.echo('pencilcal: note: torch is not installed, using the numpy estimator; '
                       'pip install -e ".[torch]" makes this much faster', err=True)
    log = None if quiet else (lambda msg: click.echo(f"pencilcal sensitivity: {msg}", err=True))
    result = sens.plan(setup, tilts_deg=tilts, offaxis_deg=off, trials=trials, accuracy_deg=accuracy,
                       maps=tuple(sorted(wanted)), spokes_grid=spokes_grid, steps_grid=step_grid,
                       sigmas_grid=sigma_grid, tilt_ref_deg=tilt_ref, backend=backend, device=device, dtype=dtype,
                       seed=seed, log=log)
    if png_prefix:
        result["png"] = sens.write_heatmaps(result, png_prefix, force=force)
    write_json(output, result, force=force)
    done(result["answer"]["text"], output, *(result.get("png") or []), quiet=quiet)
