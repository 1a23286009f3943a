"""`pencilcal experiment`: the book chapter's experiments on a validation.json.

One subcommand per experiment (validation/experiments/): ``single-angle`` (Figs. 8-9),
``distribution`` (Figs. 10-11) and ``threshold``. Each reads what `pencilcal validate`
wrote, synthetic (exact truth) or real (the board's PnP pose as the reference), writes a
JSON result and, with --png, figures. Where the data cannot support part of an experiment
(no spoke on the tilt axis, no frame near zero tilt, ...) that part says
``"status": "insufficient data"`` with the reason, a warning goes to stderr and the command
still exits 0 with what could be computed; it exits 1 (one line on stderr) when the input
cannot be read or no frame has both the exact model's lines and a reference pose.
"""
from __future__ import annotations

import functools

import click

from pencilcal.toolkit.io.files import check_writable, write_json

from .common import (CONTEXT_SETTINGS, check_output, done, FiniteFloat, force_option, Group, output_option, run, warn)

__all__ = ["experiment"]


def _common(fn):
    """VALIDATION, -o, --png, --force, --quiet and the error handling, for every subcommand."""
    fn = run(fn)
    fn = click.option("-q", "--quiet", is_flag=True, help="No summary line on stderr (warnings are still shown).")(fn)
    fn = force_option(fn)
    fn = click.option("--png", "png_prefix", default=None, metavar="PREFIX",
                      help="Also write the figures as PREFIX_<figure>.png.")(fn)
    fn = output_option(fn)
    fn = click.argument("validation_path", metavar="VALIDATION", type=click.Path(dir_okay=False))(fn)
    return fn


def _execute(name, compute, validation_path, output, png_prefix, force, quiet, line):
    """Check the outputs, run `compute(v)`, write figures and JSON, report on stderr."""
    from pencilcal.validation import experiments as ex

    check_output(output, force)
    pngs = ex.figure_paths(name, png_prefix) if png_prefix else []
    for p in pngs:
        check_writable(p, force)
    v = ex.load_validation(validation_path)
    result = compute(v)
    result["input"] = str(validation_path)
    if pngs:
        result["figures"] = ex.write_figures(result, png_prefix, force=force)
    write_json(output, result, force=force)
    for item in result.get("insufficient", []):
        warn(f"{name}: {item['section']}: insufficient data: {item['reason']}")
    done(f"pencilcal experiment {name}: {line(result)}", output, quiet=quiet)
    return result


def _fmt(x, spec=".3g"):
    return "-" if x is None else format(x, spec)


@click.group(cls=Group, context_settings=CONTEXT_SETTINGS)
def experiment():
    """The book chapter's experiments on a validation.json (of `pencilcal validate`).

    \b
    Examples:
      pencilcal experiment single-angle ts.json -o single.json --png figs/ts
      pencilcal experiment threshold ts8.json -o threshold.json

    Each writes a JSON result (-o) and with --png the figures. In detail: docs/cli.md.
    \f
    Each works on synthetic sequences (errors against the exact truth) and real ones
    (against the board's PnP pose). A tilt sweep to run them on:

        pencilcal simulate ts --scenario tilt-sweep --frames 41 --seed 1 --axis 30
        pencilcal validate ts --models exact --methods sqpnp -o ts.json
        pencilcal experiment single-angle ts.json -o single.json --png figs/ts
    """


def _single_line(r):
    parts = []
    for case in ("on_line", "known", "unknown"):
        s = r.get(case, {})
        if s.get("status") != "ok":
            parts.append(f"{case}: insufficient data")
            continue
        c = ", ".join(f"{v} {k.replace('_', ' ')}" for k, v in s["counts"].items())
        u = s.get("unique")
        if u:
            c += f"; unique error median {_fmt(u['error_median_abs_deg'])} deg, median |z| {_fmt(u['z_median_abs'], '.2f')}"
        parts.append(f"{case}: {c}")
    return " | ".join(parts)


@experiment.command("single-angle",
                    short_help="Tilt from two spokes a known angle apart, error vs rotation (Figs. 8-9).")
@_common
@click.option("--pairs", type=click.Choice(["adjacent", "all"]), default="adjacent", show_default=True,
              help="Spoke pairs of the known-axis and unknown-axis cases: neighbouring spokes, or every pair.")
@click.option("--on-axis-tol", type=FiniteFloat(min=0, max=10), default=0.05, show_default=True,
              metavar="DEG", help="A spoke within this angle of the reference tilt axis counts as on it (on_line case).")
def single_angle_cmd(validation_path, output, png_prefix, force, quiet, pairs, on_axis_tol):
    """Chapter Figs. 8-9: the tilt from two spokes with a known 3D angle, error vs rotation.

    \b
    Examples:
      pencilcal experiment single-angle ts.json -o single.json --png figs/ts
      pencilcal experiment single-angle ts.json -o single.json --pairs all

    Per frame and spoke pair, the tilt from the two lines alone, against the reference.
    In detail: docs/cli.md.
    \f
    Per frame, the tilt axis comes from the reference pose (its image through the
    vertex by exact projection); every line is moved into the plane orthogonal to the
    vertex ray, where tan(alpha) = tan(theta) cos(gamma) holds exactly. Cases: on_line (a
    spoke lies on the axis, within --on-axis-tol of it: its measured line is the axis
    image), known (axis image from the reference, neither line on it) and unknown (no
    axis: only a lower bound); --pairs takes neighbouring spokes or every pair. Each
    pair's status (unique, two_roots, lower_bound, inconsistent) is reported as it is,
    with the sd at the reference tilt and, for on_line, the chapter's curve
    sd(g) = sigma (1 + cos^2 g tan^2 theta) / (tan theta sin g). On a tilt sweep --axis 30
    puts a spoke of the default fan on the axis.
    """
    from pencilcal.validation import experiments as ex

    _execute("single-angle", functools.partial(ex.single_angle, pairs=pairs, on_axis_tol_deg=on_axis_tol),
             validation_path, output, png_prefix, force, quiet, _single_line)


def _parse_strides(text):
    try:
        vals = tuple(int(v) for v in text.split(",") if v.strip())
    except ValueError:
        raise click.BadParameter(f"expected comma-separated positive integers such as 1,2,3, got {text!r}",
                                 param_hint="--strides") from None
    if not vals or any(v < 1 for v in vals):
        raise click.BadParameter(f"expected comma-separated positive integers such as 1,2,3, got {text!r}",
                                 param_hint="--strides")
    return vals


def _dist_line(r):
    a = r.get("angles", {})
    out = []
    if a.get("status") == "ok":
        out.append(f"line residual RMS {_fmt(a['residual_rms_deg'])} deg (z RMS {_fmt(a['z_rms'], '.2f')}, "
                   f"sigma scale {_fmt(a['sigma_scale'], '.2f')})")
    s = r.get("spacing", {})
    if s.get("status") == "ok":
        rows = [f"every {p['stride']} ({p['spacing_deg']:.0f} deg): normal RMS {_fmt(p.get('normal_error_rms_deg'))} deg, "
                f"bound {_fmt(p.get('normal_crlb_rms_deg'))}" for p in s["strides"] if p.get("status") == "ok"]
        out.append("; ".join(rows))
    return " | ".join(out) or "insufficient data"


@experiment.command("distribution",
                    short_help="Image angles vs rotation; error by spoke spacing with the bound (Figs. 10-11).")
@_common
@click.option("--strides", default="1,2,3", show_default=True, metavar="M,M,...",
              help="Spoke subsets: every M-th spoke in angle order (all offsets), for each M.")
def distribution_cmd(validation_path, output, png_prefix, force, quiet, strides):
    """Chapter Figs. 10-11: image angles vs rotation, and the error of sparser fans.

    \b
    Examples:
      pencilcal experiment distribution ts.json -o dist.json --png figs/ts
      pencilcal experiment distribution ts.json -o dist.json --strides 1,2,3

    Every line's image angle against exact projection, and the orientation from sparser
    subsets of the spokes with their bounds. In detail: docs/cli.md.
    \f
    (a) Every labelled line's image angle against exact projection at the reference pose
    (residual and residual / sigma), and its angular variation: the angle in the plane
    orthogonal to the vertex ray from the tilt axis minus the 3D angle, measured and
    predicted. (b) The orientation refitted from subsets of the spokes (every spoke,
    every 2nd, every 3rd, ...: 20/40/60 deg apart for the default 8-spoke fan; --strides),
    with the Cramer-Rao bound of each subset at the reference pose.
    """
    from pencilcal.validation import experiments as ex

    st = _parse_strides(strides)
    _execute("distribution", functools.partial(ex.distribution, strides=st), validation_path, output, png_prefix,
             force, quiet, _dist_line)


def _thr_line(r):
    t = r["theory"]
    out = []
    d = r.get("detection", {})
    if d.get("status") == "ok":
        out.append(f"50% detectable at {d['tilt50_deg']:.3g} deg [{d['interval_deg'][0]:.3g}, {d['interval_deg'][1]:.3g}]")
    else:
        out.append(f"detection: {d.get('reason')}")
    out.append(f"2 sqrt(sigma) {t['two_sqrt_sigma_deg']:.3g} deg, predicted {_fmt(t['predicted_detect50_deg'])} deg")
    n = r.get("noise_level", {})
    if n.get("status") == "ok":
        out.append(f"error noise-level below {n['tilt50_deg']:.3g} deg")
    f = r.get("frontal", {})
    if f.get("status") == "ok":
        out.append(f"frontal-ish median tilt {f['measured_median_deg']:.3g} deg (n={f['count']}; noise floor scaled "
                   f"{f['geometry']['median_deg']:.3g}, Monte Carlo {f['monte_carlo']['median_deg']:.3g})")
    return "; ".join(out)


@experiment.command("threshold",
                    short_help="The detection threshold measured vs 2 sqrt(sigma) and the noise floor.")
@_common
@click.option("--bootstrap", "n_boot", type=click.IntRange(min=100, max=100000), default=2000, show_default=True,
              help="Bootstrap resamples of the frames for the intervals.")
@click.option("--trials", type=click.IntRange(min=50, max=100000), default=500, show_default=True,
              help="Monte Carlo copies of each frontal-ish frame's lines.")
@click.option("--seed", type=int, default=0, show_default=True, help="Random seed (results are reproducible).")
def threshold_cmd(validation_path, output, png_prefix, force, quiet, n_boot, trials, seed):
    """The detection threshold measured on the data, against 2 sqrt(sigma).

    \b
    Examples:
      pencilcal experiment threshold ts8.json -o threshold.json --png figs/ts8
      pencilcal experiment threshold ts8.json -o threshold.json --bootstrap 5000

    The tilt at which the tilt becomes detectable, with its interval, against theory.
    Needs frames near zero tilt. In detail: docs/cli.md.
    \f
    From the frames: the tilt at which the estimator's `detectable` flag is on for half of
    them (monotone fit, bootstrap interval widened to the sampled tilts), the tilt below
    which the tilt error reaches half the tilt, and the estimated tilt of frontal-ish
    frames. Compared with 2 sqrt(sigma), estimator.detection_threshold(sigma) and the
    likelihood-ratio test's predicted 50% point for the measured line sigma, and with
    the noise floor of a frontal pencil (median 3.75 deg at sigma = 0.1 deg, scaled by
    sqrt(sigma)) and a Monte Carlo of the same lines. Needs frames near zero tilt: a sweep
    from 0 deg (--max-tilt 8 samples the transition finely):

        pencilcal simulate ts8 --scenario tilt-sweep --frames 41 --max-tilt 8 --seed 2
        pencilcal validate ts8 --models exact --methods sqpnp -o ts8.json
        pencilcal experiment threshold ts8.json -o threshold.json --png figs/ts8
    """
    from pencilcal.validation import experiments as ex

    _execute("threshold", functools.partial(ex.threshold, n_boot=n_boot, trials=trials, seed=seed),
             validation_path, output, png_prefix, force, quiet, _thr_line)
