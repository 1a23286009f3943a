"""`pencilcal simulate`: synthetic sequences with exact ground truth."""
from __future__ import annotations

from pathlib import Path

import click

from .common import command, FiniteFloat, progress, quiet_option, run

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
              help="orbit: moving camera around the sheet on a textured table (for SfM); pivot: fixed camera, "
                   "a shaft pivoting about a fulcrum (writes angles.csv); tilt-sweep: the sheet tilted 0-80 deg.")
@click.option("--frames", type=click.IntRange(min=1, max=100000), default=30, show_default=True,
              help="Number of frames.")
@click.option("--seed", type=int, default=0, show_default=True, help="Seed of the path, the scene and the noise.")
@click.option("--size", default="1280x720", show_default=True,
              help="Image size WxH [pixels] of the built-in camera (ignored with --camera).")
@click.option("--model", type=click.Choice(MODELS), default="opencv", show_default=True,
              help="Lens model of the built-in camera (ignored with --camera).")
@click.option("--camera", "camera_path", type=click.Path(), default=None,
              help="Use these intrinsics (any camera file pencilcal reads) instead of the built-in camera.")
@click.option("--noise", type=FiniteFloat(min=0, max=255), default=5.0, show_default=True,
              help="Sensor noise: standard deviation at mid grey [grey levels]. The defaults of "
                   "--noise and --blur resemble endoscope video (the spokes' lines come out with "
                   "~0.03 deg of angle noise, a detection threshold of ~2.5 deg).")
@click.option("--blur", type=FiniteFloat(min=0, max=50), default=1.5, show_default=True,
              help="Gaussian blur of the optics, standard deviation [px].")
@click.option("--lighting", type=FiniteFloat(min=0, max=1), default=0.25, show_default=True,
              help="Strength of the uneven lighting (vignetting and a random gradient), 0 for none.")
@click.option("--gamma", type=FiniteFloat(min=0.1, max=5), default=2.2, show_default=True,
              help="Encoding gamma of the 8-bit images (1 = linear).")
@click.option("--color", is_flag=True, help="Colour (BGR) images instead of grey.")
@click.option("--background", type=click.Choice(["table", "plain", "tissue"]), default="table", show_default=True,
              help="table: textured table (and boxes for orbit) around the sheet; plain: uniform grey; tissue: "
                   "pink tissue with pale folds behind the instrument, no sheet (pivot).")
@click.option("--axis", type=FiniteFloat(), default=0.0, show_default=True,
              help="tilt-sweep: direction of the tilt axis in the sheet, from its x axis [deg].")
@click.option("--max-tilt", type=FiniteFloat(min=0, max=89), default=80.0, show_default=True,
              help="tilt-sweep: the last frame's tilt [deg].")
@click.option("--shaft-diameter", type=FiniteFloat(min=0.1, max=100), default=8.0, show_default=True,
              help="pivot: the instrument shaft's diameter [mm]; truth.json gives the 3-D fulcrum (fulcrum_cam) and "
                   "every frame's 3-D axis (axis_point_cam, axis_direction_cam).")
@click.option("--epochs", type=click.IntRange(min=1), default=1, show_default=True,
              help="pivot: the camera moves this many times less one, between even runs of frames (truth.json: "
                   "each frame's epoch, each epoch's fulcrum_px).")
@click.option("--spokes", type=click.IntRange(min=3), default=8, show_default=True,
              help="Spokes of the printed fan, 20 deg apart (as `pencilcal target --spokes`).")
@click.option("--spoke-width", type=FiniteFloat(min=0, min_open=True), default=1.0, show_default=True,
              help="Width of the printed spokes (dark bars) [mm].")
@click.option("--spoke-radius", type=(FiniteFloat(), FiniteFloat()), default=(15.0, 80.0), show_default=True,
              help="Inner and outer end of every spoke, from the vertex [mm] (wide spokes need a larger inner "
                   "radius, or they overlap).")
@click.option("--force", is_flag=True, help="Replace OUT if it holds an earlier simulate output.")
@quiet_option
@run
def simulate(out, scenario, frames, seed, size, model, camera_path, noise, blur, lighting, gamma, color,
             background, axis, max_tilt, shaft_diameter, epochs, spokes, spoke_width, spoke_radius, force, quiet):
    """Write a synthetic image sequence with exact ground truth to the folder OUT.

    OUT gets images/000.png..., camera.json and camera.yaml, board.yaml, pencil.yaml (what
    the simulated sheet has printed on it, as `pencilcal target` prints it) and truth.json:
    per frame R_cam_from_target, t_cam_from_target, normal, vertex_px, tilt_deg and more.
    The pivot scenario also writes angles.csv (image,angle_deg); its shaft has the diameter
    --shaft-diameter, and truth.json gives the 3-D fulcrum and every frame's 3-D axis. Frames are rendered with
    exact area anti-aliasing for the camera's own lens model, then blurred, lit unevenly
    and given sensor noise. OUT is written whole or not at all: a failed run leaves no
    partial folder. OUT must be absent or empty; --force replaces an earlier output.

    \b
    Example:
      pencilcal simulate runs/orbit --scenario orbit --frames 40 --seed 1
      pencilcal simulate runs/pivot --scenario pivot --frames 12 --model fisheye
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
        click.echo(f"{len(sc)} {scenario} frames (seed {seed}, {w}x{h}, {sc.camera.model}) -> {out_path}", err=True)
