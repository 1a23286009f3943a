"""`pencilcal fulcrum`: the fulcrum of a pivoting instrument over a sequence."""
from __future__ import annotations

import click

from pencilcal.toolkit.camera_io import read_camera
from pencilcal.toolkit.errors import EstimationError, InputError
from pencilcal.toolkit.files import write_json
from pencilcal.toolkit.fulcrum import fulcrum_from_frames, read_angles
from pencilcal.toolkit.lines_io import read_lines

from .common import camera_options, check_output, force_option, output_option, progress, quiet_option, run, warn


def _shafts(images, camera, detector, quiet):
    """Instrument shafts of every frame of IMAGES, as lines.json frames."""
    import numpy as np

    from pencilcal.toolkit.images import check_image_size, open_images
    from pencilcal.toolkit.shafts import detect_shafts

    frames = []
    source = open_images(images)
    with progress(source, "shafts", quiet) as bar:
        for fr in bar:
            if fr.image is None:
                warn(f"{fr.name}: {fr.error}")
                frames.append({"image": fr.name, "ok": False, "segments": np.zeros((0, 4))})
                continue
            check_image_size(fr, camera)
            shafts = detect_shafts(fr.image, camera, detector=detector)
            if not shafts:
                warn(f"{fr.name}: no instrument shaft found")
            frames.append({"image": fr.name, "ok": True, "segments": np.zeros((0, 4)),
                           "shafts": [s.to_dict() for s in shafts]})
    return frames


@click.command()
@click.argument("images", required=False)
@click.option("--lines", "lines_path", type=click.Path(dir_okay=False), default=None,
              help="Lines per frame (lines.json; shaft midlines are used when present), instead of IMAGES.")
@camera_options
@click.option("--angles", "angles_path", type=click.Path(dir_okay=False), default=None,
              help="CSV of pivot angles (image,angle_deg, or one angle per frame): also fit the pivot plane.")
@click.option("--endpoint-sigma", type=float, default=0.5, show_default=True,
              help="End point noise [px] for segments without their own angle sigma.")
@click.option("--detector", type=click.Choice(["lsd", "fld", "edlines"]), default="lsd", show_default=True,
              help="Line detector for the shaft proposals, with IMAGES.")
@output_option
@force_option
@quiet_option
@run
def fulcrum(images, lines_path, camera_path, camera_id, angles_path, endpoint_sigma, detector, output, force, quiet):
    """The fulcrum of an instrument pivoting about its entry port.

    Every frame's instrument line passes through the fulcrum's image: their robust weighted
    intersection gives the fulcrum in pixels, its covariance and its viewing ray. From
    IMAGES (a folder, glob or video) the instrument shafts are detected in every frame
    (their midlines are the axis images); or the lines come from a lines file (--lines).
    With --angles (one pivot angle per frame) the lines form a pencil with known angles and
    the orientation of the pivot plane comes out too, with the keys of orientation.json.

    \b
    Examples:
      pencilcal fulcrum frames/ --camera camera.yaml -o fulcrum.json
      pencilcal fulcrum --lines lines.json --camera camera.yaml --angles angles.csv -o fulcrum.json
    """
    if endpoint_sigma <= 0:
        raise click.BadParameter("must be positive", param_hint="--endpoint-sigma")
    if (images is None) == (lines_path is None):
        raise click.UsageError("give IMAGES or --lines (one of them)")
    check_output(output, force)
    camera = read_camera(camera_path, camera_id=camera_id)
    if lines_path is not None:
        frames = read_lines(lines_path)
        if not frames:
            raise InputError(f"{lines_path}: no frames")
    else:
        frames = _shafts(images, camera, detector, quiet)
    angles = read_angles(angles_path, [f["image"] for f in frames]) if angles_path else None
    try:
        out = fulcrum_from_frames(camera, frames, angles=angles, endpoint_sigma_px=endpoint_sigma)
    except EstimationError as e:
        raise EstimationError(f"{lines_path or images}: {e}") from None
    out = {"camera": str(camera_path), "lines": None if lines_path is None else str(lines_path),
           "images": None if images is None else str(images), **out}
    write_json(output, out, force=force)
    if not quiet:
        u, v = out["vertex_px"]
        click.echo(f"fulcrum at ({u:.2f}, {v:.2f}) px from {out['lines_used']} lines -> {output}", err=True)
