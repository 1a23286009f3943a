"""`pencilcal simulate`: synthetic sequences with exact ground truth."""
from __future__ import annotations

from pathlib import Path

import click

from .common import command, done, FiniteFloat, progress, quiet_option, run

MODELS = ("opencv", "fisheye", "pinhole")


def _parse_size(text):
    try:
        w, h = (int(v) for v in text.lower().replace(",", "x").split("x"))
    except ValueError:
        raise click.BadParameter(f"expected WxH such as 1280x720, got {text!r}", param_hint="--size") from None
    if not (16 <= w <= 16384 and 16 <= h <= 16384):
        raise click.BadParameter(f"width and height must be 16..16384 pixels, got {w}x{h}", param_hint="--size")
    return w, h


@command()
@click.argument("out", type=click.Path(file_okay=False))
@click.option("--scenario", type=click.Choice(["orbit", "pivot", "tilt-sweep"]), required=True,
              help="orbit: a moving camera; pivot: a shaft pivoting; tilt-sweep.")
@click.option("--frames", type=click.IntRange(min=1, max=100000), default=30, show_default=True,
              help="Frames.")
@click.option("--seed", type=int, default=0, show_default=True, help="Seed of the path, scene and noise.")
@click.option("--size", default="1280x720", show_default=True,
              help="Image size WxH [px] of the built-in camera.")
@click.option("--model", type=click.Choice(MODELS), default="opencv", show_default=True,
              help="Lens model of the built-in camera.")
@click.option("--camera", "camera_path", type=click.Path(), default=None,
              help="These intrinsics instead of the built-in camera.")
@click.option("--noise", type=FiniteFloat(min=0, max=255), default=5.0, show_default=True,
              help="Sensor noise at mid grey [grey levels].")
@click.option("--blur", type=FiniteFloat(min=0, max=50), default=1.5, show_default=True,
              help="Blur of the optics, Gaussian sd [px].")
@click.option("--lighting", type=FiniteFloat(min=0, max=1), default=0.25, show_default=True,
              help="Uneven lighting's strength (0: none).")
@click.option("--gamma", type=FiniteFloat(min=0.1, max=5), default=2.2, show_default=True,
              help="Encoding gamma of the images (1: linear).")
@click.option("--color", is_flag=True, help="Colour (BGR) images instead of grey.")
@click.option("--background", type=click.Choice(["table", "plain", "tissue"]), default="table", show_default=True,
              help="Around the sheet: table, plain grey; tissue: folds, no sheet (pivot).")
@click.option("--axis", type=FiniteFloat(), default=0.0, show_default=True,
              help="tilt-sweep: the tilt axis from the sheet's x [deg].")
@click.option("--max-tilt", type=FiniteFloat(min=0, max=89), default=80.0, show_default=True,
              help="tilt-sweep: the last tilt [deg].")
@click.option("--shaft-diameter", type=FiniteFloat(min=0.1, max=100), default=8.0, show_default=True,
              help="pivot: the shaft's diameter [mm].")
@click.option("--epochs", type=click.IntRange(min=1), default=1, show_default=True,
              help="pivot: the camera moves between this many runs of frames.")
@click.option("--spokes", type=click.IntRange(min=3), default=8, show_default=True,
              help="Spokes of the printed fan, 20 deg apart.")
@click.option("--spoke-width", type=FiniteFloat(min=0, min_open=True), default=1.0, show_default=True,
              help="Width of the printed spokes [mm].")
@click.option("--spoke-radius", type=(FiniteFloat(), FiniteFloat()), default=(15.0, 80.0), show_default=True,
              help="Inner and outer end of the spokes [mm].")
@click.option("--force", is_flag=True, help="Replace an earlier simulate output in OUT.")
@quiet_option
@run
def simulate(out, scenario, frames, seed, size, model, camera_path, noise, blur, lighting, gamma, color,
             background, axis, max_tilt, shaft_diameter, epochs, spokes, spoke_width, spoke_radius, force, quiet):
    """Write a synthetic image sequence with exact ground truth to the folder OUT.

    \b
    Examples:
      pencilcal simulate runs/orbit --scenario orbit --frames 40 --seed 1
      pencilcal simulate runs/pivot --scenario pivot --frames 12 --model fisheye

    OUT gets images/, camera, board and pencil files, and truth.json (every frame's pose).
    In detail: docs/cli.md.
    \f
    OUT gets images/000.png..., camera.json and camera.yaml, board.yaml, pencil.yaml (what
    the simulated sheet has printed on it, as `pencilcal target` prints it) and truth.json:
    per frame R_cam_from_target, t_cam_from_target, normal, vertex_px, tilt_deg and more.
    Scenarios: orbit, a camera moving around the sheet on a textured table (for SfM);
    pivot, a fixed camera and an instrument shaft pivoting about a fulcrum; tilt-sweep, the
    sheet tilted from 0 to --max-tilt deg about the axis --axis (from the sheet's x axis).
    The pivot scenario also writes angles.csv (image,angle_deg); its shaft has the diameter
    --shaft-diameter [mm], and truth.json gives the 3-D fulcrum (fulcrum_cam) and every
    frame's 3-D axis (axis_point_cam, axis_direction_cam). The built-in camera has --size
    and --model (both ignored with --camera, whose intrinsics are used instead). The sheet
    has --spokes spokes 20 deg apart (as `pencilcal target --spokes`), --spoke-width wide,
    from --spoke-radius inner to outer [mm] (wide spokes need a larger inner radius, or
    they overlap).

    Frames are rendered with exact area anti-aliasing for the camera's own lens model, then
    blurred (--blur, the optics' Gaussian sd [px]), lit unevenly (--lighting: vignetting
    and a random gradient; 0 for none), given sensor noise (--noise, the sd at mid grey
    [grey levels]) and encoded with --gamma. The defaults of --noise and --blur resemble
    endoscope video (the spokes' lines come out with ~0.03 deg of angle noise, a detection
    threshold of ~2.5 deg). --background table puts a textured table (and boxes for orbit)
    around the sheet; plain, a uniform grey. OUT is written whole or not at all: a failed
    run leaves no partial folder. OUT must be absent or empty; --force replaces an earlier
    output.

    More examples:

        pencilcal simulate runs/thin --scenario tilt-sweep --frames 11 --spokes 9 --spoke-width 1.2
    """
    from pencilcal.toolkit.camera.formats import read_camera
    from pencilcal.toolkit.synth.folder import check_sequence_output, write_sequence
    from pencilcal.toolkit.synth.scenarios import make_scenario
    from pencilcal.toolkit.synth.sheet import layout_sheet

    w, h = _parse_size(size)
    out_path = Path(out)
    check_sequence_output(out_path, force)
    camera = read_camera(camera_path) if camera_path else None
    options = {"axis_deg": axis, "max_tilt_deg": max_tilt} if scenario == "tilt-sweep" else {}
    if scenario == "pivot":
        options = {"shaft_radius": shaft_diameter / 2.0, "epochs": epochs}
    elif epochs != 1 or background == "tissue":
        raise click.UsageError("--epochs and --background tissue are for the pivot scenario")
    sheet = layout_sheet(spokes=spokes, width=spoke_width, radius=spoke_radius)
    sc = make_scenario(scenario, frames, seed, camera=camera, sheet=sheet, size=(w, h), model=model, **options)

    def bar(frames):
        with progress(frames, "simulate", quiet) as it:
            yield from it

    write_sequence(out_path, sc, noise=noise, blur_px=blur, lighting=lighting, gamma=gamma, color=color,
                   background=background, camera_source=str(camera_path) if camera_path else f"built-in {model}",
                   progress=bar)
    if not quiet:
        done(f"{len(sc)} {scenario} frames (seed {seed}, {w}x{h}, {sc.camera.model}) with exact truth", out_path)
