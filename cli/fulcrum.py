"""`pencilcal fulcrum`: the fulcrum of a pivoting instrument over a sequence."""
from __future__ import annotations

import click

from pencilcal.toolkit.camera_io import read_camera
from pencilcal.toolkit.errors import EstimationError, InputError
from pencilcal.toolkit.files import write_json
from pencilcal.toolkit.fulcrum import fulcrum_from_frames, read_angles
from pencilcal.toolkit.lines_io import read_lines

from .common import camera_options, check_output, force_option, output_option, quiet_option, run


@click.command()
@click.option("--lines", "lines_path", required=True, type=click.Path(dir_okay=False),
              help="Lines per frame (lines.json); shaft midlines are used when present.")
@camera_options
@click.option("--angles", "angles_path", type=click.Path(dir_okay=False), default=None,
              help="CSV of pivot angles (image,angle_deg, or one angle per frame): also fit the pivot plane.")
@click.option("--endpoint-sigma", type=float, default=0.5, show_default=True,
              help="End point noise [px] for segments without their own angle sigma.")
@output_option
@force_option
@quiet_option
@run
def fulcrum(lines_path, camera_path, camera_id, angles_path, endpoint_sigma, output, force, quiet):
    """The fulcrum of an instrument pivoting about its entry port.

    Every frame's instrument line passes through the fulcrum's image: their robust weighted
    intersection gives the fulcrum in pixels, its covariance and its viewing ray. With
    --angles (one pivot angle per frame) the lines form a pencil with known angles and the
    orientation of the pivot plane comes out too, with the keys of orientation.json.

    \b
    Example:
      pencilcal fulcrum --lines lines.json --camera camera.yaml --angles angles.csv -o fulcrum.json
    """
    if endpoint_sigma <= 0:
        raise click.BadParameter("must be positive", param_hint="--endpoint-sigma")
    check_output(output, force)
    camera = read_camera(camera_path, camera_id=camera_id)
    frames = read_lines(lines_path)
    if not frames:
        raise InputError(f"{lines_path}: no frames")
    angles = read_angles(angles_path, [f["image"] for f in frames]) if angles_path else None
    try:
        out = fulcrum_from_frames(camera, frames, angles=angles, endpoint_sigma_px=endpoint_sigma)
    except EstimationError as e:
        raise EstimationError(f"{lines_path}: {e}") from None
    out = {"camera": str(camera_path), "lines": str(lines_path), **out}
    write_json(output, out, force=force)
    if not quiet:
        u, v = out["vertex_px"]
        click.echo(f"fulcrum at ({u:.2f}, {v:.2f}) px from {out['lines_used']} lines -> {output}", err=True)
