"""`pencilcal convert`: a camera file in another format, and what the conversion changed."""
from __future__ import annotations

import os

import click

from pencilcal.toolkit.camera.convert import EXACT_PX, convert_camera, describe_camera, projection_difference
from pathlib import Path

from pencilcal.toolkit.camera.formats import camera_format, read_camera, write_camera
from pencilcal.toolkit.errors import InputError

from .common import command, check_output, force_option, run


def _check_output(output, force):
    """Fail before any work if the output exists (without --force); a COLMAP model folder
    is checked here for existence only (check_output takes files)."""
    if camera_format(output) != "colmap_folder":
        check_output(output, force)
    elif Path(output).exists() and not force:
        raise InputError(f"{output}: already exists; pass --force to overwrite it")


@command()
@click.argument("cam", type=click.Path())
@click.option("-o", "--output", required=True, type=click.Path(),
              help="Output camera file, format by extension (a path without one: a COLMAP model folder).")
@click.option("--camera-id", type=int, default=None, help="Camera id in a COLMAP file with several cameras.")
@click.option("--approximate", is_flag=True,
              help=f"Where the output format cannot hold the lens model within {EXACT_PX:g} px, fit the "
                   "nearest model it holds and write that.")
@force_option
@run
def convert(cam, output, camera_id, approximate, force):
    """Convert the camera file CAM to another format, and say what that changed.

    \b
    Examples:
      pencilcal convert camera.json -o cameras.txt
      pencilcal convert sparse/0 --camera-id 2 -o camera.yaml

    The format follows the extension. The last line gives the largest reprojection
    difference the conversion causes [px]. In detail: docs/cli.md.
    \f
    Formats follow the extension: .json (pencilcal), .yaml/.yml/.xml (OpenCV
    FileStorage), .cameramodel (mrcal), COLMAP cameras.txt/cameras.bin or a model folder
    (a path without an extension). COLMAP's principal point is pencilcal's + 0.5 px; the
    conversion applies it.

    The output is read back and compared with CAM where they project a dense grid of
    rays covering the whole image, both ways; the largest difference [px] goes to stderr
    (~1e-9 px for a lossless conversion). A camera the output format cannot hold within
    0.01 px (12 or 14 opencv coefficients or skew in COLMAP, fisheye or 14 coefficients
    in mrcal) is refused with the difference it would cause, unless --approximate: then
    the nearest model the format holds is fitted to CAM's projection over the image
    (least squares) and written, and its max and RMS difference are printed:

        pencilcal convert camera12.json -o cameras.txt --approximate
    """
    _check_output(output, force)
    camera = read_camera(cam, camera_id=camera_id)
    conv = convert_camera(camera, output, approximate=approximate)
    write_camera(output, conv.camera, force=force)
    back = read_camera(output)
    diff = conv.difference if back == conv.stored else projection_difference(camera, back)
    cam, output = os.path.abspath(cam), os.path.abspath(output)
    if conv.fitted:
        click.echo(f"{cam} -> {output}: {conv.reason}; fitted {describe_camera(back)}: reprojection difference "
                   f"over the image max {diff.max_px:.3g} px, RMS {diff.rms_px:.3g} px", err=True)
    else:
        what = describe_camera(back)
        if conv.reason:
            what = (f"{conv.reason}; written as {what}, the dropped terms move no pixel by more than "
                    f"{EXACT_PX:g} px")
        click.echo(f"{cam} -> {output}: {what}; largest reprojection difference over the image "
                   f"{diff.max_px:.2g} px (RMS {diff.rms_px:.2g} px)", err=True)
