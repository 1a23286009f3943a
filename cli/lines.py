"""`pencilcal lines`: line segments per frame, with angle uncertainty (lines.json)."""
from __future__ import annotations

import click
import numpy as np

from pencilcal.toolkit.camera_io import read_camera
from pencilcal.toolkit.images import check_image_size, open_images
from pencilcal.toolkit.lines import DETECTORS, lines_record
from pencilcal.toolkit.lines_io import write_lines

from .common import check_output, force_option, output_option, progress, quiet_option, run, warn


@click.command()
@click.argument("images")
@click.option("--camera", "camera_path", required=True, type=click.Path(),
              help="Camera file: .json, .yaml/.yml/.xml (OpenCV), .cameramodel (mrcal), COLMAP cameras.txt/.bin or model folder.")
@click.option("--camera-id", type=int, default=None, help="Camera id in a COLMAP file with several cameras.")
@output_option
@click.option("--detector", type=click.Choice(DETECTORS), default="lsd", show_default=True,
              help="OpenCV detector proposing the segments: LSD, FLD (fast line detector) or EDLines.")
@click.option("--bars", is_flag=True,
              help="Find the printed spokes: dark bars, each written as ONE segment, its midline "
                   "(bisector of the bar's two edges) between its end caps. Without it every "
                   "straight edge is a segment (a bar gives two).")
@click.option("--bar-width", nargs=2, type=float, default=None, metavar="MIN MAX",
              help="With --bars: accepted bar widths [px, undistorted]; default 2.5 px to 1/8 of the image.")
@click.option("--shaft", is_flag=True,
              help="Also find instrument shafts (pairs of long converging edges) and write them "
                   "as 'shafts': midline (image of the axis), width_px, angle_sigma_deg.")
@click.option("--min-length", type=float, default=20.0, show_default=True, help="Shortest segment written [px].")
@force_option
@quiet_option
@run
def lines(images, camera_path, camera_id, output, detector, bars, bar_width, shaft, min_length, force, quiet):
    """Line segments in every frame, refined to subpixel precision, with angle uncertainty.

    IMAGES is a folder of images, a glob pattern or a video. The chosen OpenCV detector
    proposes segments; collinear fragments are merged and every line is refitted to its
    edge pixels (straight in undistorted pixels, so lens distortion does not bend it).
    Each frame gets `segments` in raw (distorted) pixels [x1, y1, x2, y2] and, per segment,
    `angle_sigma_deg` (sd of its angle) and `offset_sigma_px` (sd of its position across,
    at its midpoint), which `pencilcal orient` uses to weight the lines. Segments are
    oriented with the darker side on the left on screen.

    A frame that cannot be decoded is reported and written with ok: false.

    \b
    Example:
      pencilcal lines frames/ --camera camera.yaml --bars -o lines.json
      pencilcal orient --lines lines.json --camera camera.yaml --pencil pencil.yaml -o orientation.json
    """
    if min_length <= 0:
        raise click.BadParameter("must be positive", param_hint="--min-length")
    if bar_width is not None and not (0 < bar_width[0] < bar_width[1]):
        raise click.BadParameter("needs 0 < MIN < MAX", param_hint="--bar-width")
    if bar_width is not None and not bars:
        raise click.BadParameter("only with --bars", param_hint="--bar-width")
    check_output(output, force)
    camera = read_camera(camera_path, camera_id=camera_id)
    source = open_images(images)
    records = []
    with progress(source, "lines", quiet) as frames:
        for fr in frames:
            if fr.image is None:
                warn(f"{fr.name}: {fr.error}")
                records.append({"image": fr.name, "ok": False, "error": fr.error, "segments": [],
                                "angle_sigma_deg": []})
                continue
            check_image_size(fr, camera)
            records.append(lines_record(fr.name, fr.image, camera, detector, bars, shaft, min_length, bar_width))
    meta = {"detector": detector, "mode": "bars" if bars else "edges", "camera": str(camera_path)}
    write_lines(output, records, force=force, meta=meta)
    if not quiet:
        n_ok = sum(r["ok"] for r in records)
        n_seg = sum(len(r["segments"]) for r in records)
        click.echo(f"{n_ok}/{len(records)} frames, {n_seg} segments -> {output}", err=True)
