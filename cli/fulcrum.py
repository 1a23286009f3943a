"""`pencilcal fulcrum`: the fulcrum of a pivoting instrument over a sequence."""
from __future__ import annotations

import click
import numpy as np

from pencilcal.toolkit.camera.formats import read_camera
from pencilcal.toolkit.errors import EstimationError, InputError
from pencilcal.toolkit.io.files import write_json
from pencilcal.toolkit.pencil.fulcrum import fulcrum_from_frames, read_angles
from pencilcal.toolkit.io.images import open_images
from pencilcal.toolkit.io.lines_file import read_lines

from .common import (command, camera_options, check_output, FiniteFloat, force_option, images_argument, mask_option,
                     max_pixels_option, output_option, quiet_option, run, run_frames, warn, workers_option)


def _shaft_task(frame, ctx):
    """The shafts of one frame as a lines.json frame (module level: runs in workers too)."""
    import numpy as np

    from pencilcal.toolkit.io.images import check_image_size
    from pencilcal.toolkit.detect.shafts import detect_shafts

    camera, detector, region = ctx
    if frame.image is None:
        return {"image": frame.name, "ok": False, "segments": np.zeros((0, 4)), "error": frame.error}
    check_image_size(frame, camera)
    shafts = detect_shafts(frame.image, camera, detector=detector, valid_region=region)
    return {"image": frame.name, "ok": True, "segments": np.zeros((0, 4)), "shafts": [s.to_dict() for s in shafts],
            "error": None if shafts else "no instrument shaft found"}


def _shafts(source, camera, detector, quiet, workers, mask_path=None):
    """Instrument shafts of every frame of an image source, as lines.json frames, within the
    sequence's valid region (the mask file's, or detected: `region_detect.sequence_region`)."""
    from pencilcal.toolkit.detect.region_detect import sequence_region

    region = sequence_region(source, mask_path, shape=(camera.height, camera.width))
    frames = list(run_frames(source, _shaft_task, (camera, detector, region), workers, "shafts", quiet))
    for f in frames:
        if f["error"]:
            warn(f"{f['image']}: {f['error']}")
    return frames


@command()
@images_argument(required=False)
@click.option("--lines", "lines_path", type=click.Path(dir_okay=False), default=None,
              help="Lines per frame (lines.json; shaft midlines are used when present), instead of IMAGES.")
@camera_options
@click.option("--angles", "angles_path", type=click.Path(dir_okay=False), default=None,
              help="CSV of pivot angles (image,angle_deg, or one angle per frame): also fit the pivot plane.")
@click.option("--shaft-diameter", type=FiniteFloat(), default=None, metavar="D",
              help="The instrument shaft's diameter (e.g. 8 for 8 mm): also the 3-D fulcrum, point [x, y, z] in the "
                   "camera frame with point_cov and point_sigma, in D's unit, from every shaft's 3-D axis.")
@click.option("--endpoint-sigma", type=FiniteFloat(), default=0.5, show_default=True,
              help="End point noise [px] for segments without their own angle sigma.")
@click.option("--detector", type=click.Choice(["lsd", "fld", "edlines"]), default="lsd", show_default=True,
              help="Line detector for the shaft proposals, with IMAGES.")
@mask_option
@max_pixels_option
@workers_option
@output_option
@force_option
@quiet_option
@run
def fulcrum(images, lines_path, camera_path, camera_id, angles_path, shaft_diameter, endpoint_sigma, detector, mask_path,
            max_pixels, workers, output, force, quiet):
    """The fulcrum of an instrument pivoting about its entry port.

    Every frame's instrument line passes through the fulcrum's image: their robust weighted
    intersection gives the fulcrum's viewing ray and, where the lens model reaches it (a
    port far off axis may lie beyond), its raw pixel and covariance. From
    IMAGES (image files, folders or glob patterns in the order given, or one video) the
    instrument shafts are detected in every frame
    (their midlines are the axis images), never on the boundary of the frames' valid region
    (--mask, or detected once from up to 16 frames); or the lines come from a lines file
    (--lines).
    With --angles (one pivot angle per frame) the lines form a pencil with known angles and
    the orientation of the pivot plane comes out too, with the keys of orientation.json.
    With --shaft-diameter D every shaft's two silhouette edges give its 3-D axis (the band's
    width fixes its depth), and the fulcrum is also the robust weighted least-squares point
    closest to all the axes: point [x, y, z] (camera frame, D's unit), point_cov, point_sigma
    (the RMS 3-D error its covariance predicts), and the axes that pass far from it named in
    point_outliers. Its lines must be shafts with their edges' covariance (lines --shaft).

    \b
    Examples:
      pencilcal fulcrum frames/ --camera camera.yaml -o fulcrum.json
      pencilcal fulcrum --lines lines.json --camera camera.yaml --angles angles.csv -o fulcrum.json
      pencilcal fulcrum frames/ --camera camera.yaml --shaft-diameter 8 -o fulcrum.json
    """
    if endpoint_sigma <= 0:
        raise click.BadParameter("must be positive", param_hint="--endpoint-sigma")
    if shaft_diameter is not None and not shaft_diameter > 0:
        raise click.BadParameter("must be positive", param_hint="--shaft-diameter")
    if (images is None) == (lines_path is None):
        raise click.UsageError("give IMAGES or --lines (one of them)")
    if lines_path is not None and mask_path is not None:
        raise click.UsageError("--mask is for IMAGES (a lines file's lines are already found)")
    check_output(output, force, [lines_path, camera_path, angles_path, mask_path])
    camera = read_camera(camera_path, camera_id=camera_id)
    if lines_path is not None:
        frames = read_lines(lines_path)
        if not frames:
            raise InputError(f"{lines_path}: no frames")
    else:
        source = open_images(images, max_pixels=max_pixels)
        check_output(output, force, source.paths)
        frames = _shafts(source, camera, detector, quiet, workers, mask_path)
    angles = read_angles(angles_path, [f["image"] for f in frames]) if angles_path else None
    try:
        res = fulcrum_from_frames(camera, frames, angles=angles, endpoint_sigma_px=endpoint_sigma,
                                  shaft_diameter=shaft_diameter)
    except EstimationError as e:
        raise EstimationError(f"{lines_path or source.description}: {e}") from None
    for w in res.warnings:
        warn(w)
    out = {"camera": str(camera_path), "lines": None if lines_path is None else str(lines_path),
           "images": None if images is None else source.description, **res.to_dict()}
    write_json(output, out, force=force)
    off_axis = float(np.degrees(np.arccos(np.clip(out["ray"][2], -1.0, 1.0))))
    if out["vertex_px"] is None:
        warn(f"the fulcrum lies {off_axis:.1f} deg off the optical axis, beyond the part of the field the lens "
             "model maps to pixels: fulcrum.json gives its ray, vertex_px is null")
    if not quiet:
        where = ("at ({:.2f}, {:.2f}) px".format(*out["vertex_px"]) if out["vertex_px"] is not None
                 else f"on the ray {off_axis:.1f} deg off axis")
        click.echo(f"fulcrum {where} from {out['lines_used']} lines -> {output}", err=True)
        if shaft_diameter is not None:
            bad = ", ".join(f"{o['image']}" for o in out["point_outliers"]) or "none"
            click.echo("3-D fulcrum ({:.2f}, {:.2f}, {:.2f}) +- {:.2f} (rms) from {} axes; outliers: {}".format(
                *out["point"], out["point_sigma"], out["point_axes_used"], bad), err=True)
