"""`pencilcal lines`: line segments per frame, with angle uncertainty (lines.json)."""
from __future__ import annotations

import click

from pencilcal.toolkit.camera.formats import read_camera
from pencilcal.toolkit.io.images import check_image_size
from pencilcal.toolkit.detect.edges import DEFAULT_GAMMA
from pencilcal.toolkit.detect.lines import lines_record
from pencilcal.toolkit.io.lines_file import write_lines

from .common import (detector_option, gamma_option, command, FiniteFloat, FrameOutputs, camera_options, check_output, force_option, frames_region,
                     images_argument, jsonl_option, mask_option, max_pixels_option, open_input, output_option,
                     overlay_option, quiet_option, run, run_frames, source_option, stream_meta, warn, workers_option)


def with_axis(camera, shaft, diameter):
    """A shaft record with its 3-D axis keys (`cylinder.shaft_axis_record`) added, or with
    ``axis_error`` saying why there is none (edges that bound no cylinder)."""
    from pencilcal.toolkit.errors import EstimationError, InputError
    from pencilcal.toolkit.pencil.cylinder import shaft_axis_record

    try:
        return {**shaft, **shaft_axis_record(camera, shaft["edges"], shaft["edge_cov"], diameter)}
    except (EstimationError, InputError) as e:
        return {**shaft, "axis_error": str(e)}


def _lines_task(frame, ctx):
    """One frame's lines.json record, and the frame drawn with them when the overlay is
    asked for (module level: runs in worker processes too)."""
    camera, detector, bars, shaft, min_length, bar_width, region, drawing, diameter, gamma, priors = ctx
    if frame.image is None:
        return {"image": frame.name, "ok": False, "error": frame.error, "segments": [], "angle_sigma_deg": []}, None
    check_image_size(frame, camera)
    rec = lines_record(frame.name, frame.image, camera, detector, bars, shaft, min_length, bar_width,
                       valid_region=region, gamma=gamma,
                       axis_prior=None if priors is None else priors[1].get(frame.name, priors[0]))
    if diameter is not None:
        rec["shafts"] = [with_axis(camera, s, diameter) for s in rec.get("shafts") or []]
    if not drawing:
        return rec, None
    from pencilcal.toolkit.draw.overlay import draw_frame

    return rec, draw_frame(frame.image, segments=rec["segments"], shafts=rec.get("shafts"), text=[frame.name])


@command()
@images_argument(required=False)
@source_option
@camera_options
@output_option
@detector_option("OpenCV detector proposing the segments: LSD, FLD (fast line detector) or EDLines.")
@click.option("--bars", is_flag=True,
              help="Find the printed spokes: dark bars, each written as ONE segment, its midline "
                   "(bisector of the bar's two edges) between its end caps. Without it every "
                   "straight edge is a segment (a bar gives two).")
@click.option("--bar-width", nargs=2, type=FiniteFloat(), default=None, metavar="MIN MAX",
              help="With --bars: accepted bar widths [px, undistorted]; default 2.5 px to 1/8 of the image.")
@click.option("--shaft", is_flag=True,
              help="Also find instrument shafts (pairs of long converging edges) and write them "
                   "as 'shafts': midline (image of the axis), width_px, angle_sigma_deg, edge_cov.")
@click.option("--shaft-diameter", type=FiniteFloat(), default=None, metavar="D",
              help="With --shaft: the shafts' diameter (e.g. 8 for an 8 mm instrument); each shaft also gets "
                   "its 3-D axis in the camera frame, in D's unit: axis_point, axis_direction, axis_distance, "
                   "axis_cov, axis_direction_sigma_deg, axis_distance_sigma.")
@gamma_option
@click.option("--fulcrum-prior", "prior_path", type=click.Path(dir_okay=False), default=None, metavar="FILE",
              help="With --shaft: each frame's shaft through the fulcrum's image of FILE (fulcrum.json, its epochs' "
                   "by image name; or ray and ray_cov): at most one shaft a frame, tissue bands left out.")
@click.option("--min-length", type=FiniteFloat(), default=None,
              help="Shortest segment written [px]. Default 20; with --bars, 20 or 1/30 of the image's "
                   "smaller side, whichever is longer (36 px at 1080p).")
@mask_option
@jsonl_option
@overlay_option
@max_pixels_option
@workers_option
@force_option
@quiet_option
@run
def lines(images, source_spec, camera_path, camera_id, output, detector, bars, bar_width, shaft, shaft_diameter, gamma,
          prior_path, min_length,
          mask_path, jsonl_path, overlay_path, max_pixels, workers, force, quiet):
    """Line segments in every frame, refined to subpixel precision, with angle uncertainty.

    IMAGES is one or more image files, folders or glob patterns, in the order given (a
    folder's images sorted naturally), or one video; or --source, a camera or a video still
    being written, read as it comes. The chosen OpenCV detector proposes
    segments; collinear fragments are merged and every line is refitted to its
    edge pixels (straight in undistorted pixels, so lens distortion does not bend it).
    Each frame gets `segments` in raw (distorted) pixels [x1, y1, x2, y2] and, per segment,
    `angle_sigma_deg` (sd of its angle) and `offset_sigma_px` (sd of its position across,
    at its midpoint), which `pencilcal orient` uses to weight the lines. Segments are
    oriented with the darker side on the left on screen. Nothing is found on the boundary
    of the frames' valid region (--mask, or detected once from up to 16 frames: an
    endoscope's circular field stop, letterbox bars), which lines.json records once, as
    `valid_region`.

    With --shaft --shaft-diameter D each shaft also gets its 3-D axis from the two silhouette
    edges (the band's width fixes the depth): axis_point (the axis point closest to the
    camera centre), axis_direction (unit, away from the camera), axis_distance, and their
    covariance axis_cov in the axis chart of docs/formats.md, with axis_direction_sigma_deg
    and axis_distance_sigma; lengths in D's unit.

    A frame that cannot be decoded is reported and written with ok: false. --jsonl streams
    each frame's record as it is done; --overlay draws the segments and shafts on the frames.

    \b
    Example:
      pencilcal lines frames/ --camera camera.yaml --bars -o lines.json
      pencilcal lines left/*.png --camera camera.yaml -o lines.json
      pencilcal lines frames/ --camera camera.yaml --shaft --shaft-diameter 8 -o lines.json
      pencilcal orient --lines lines.json --camera camera.yaml --pencil pencil.yaml -o orientation.json
    """
    if min_length is not None and min_length <= 0:
        raise click.BadParameter("must be positive", param_hint="--min-length")
    if bar_width is not None and not (0 < bar_width[0] < bar_width[1]):
        raise click.BadParameter("needs 0 < MIN < MAX", param_hint="--bar-width")
    if bar_width is not None and not bars:
        raise click.BadParameter("only with --bars", param_hint="--bar-width")
    if shaft_diameter is not None and not shaft:
        raise click.BadParameter("only with --shaft", param_hint="--shaft-diameter")
    if gamma != DEFAULT_GAMMA and not shaft:
        raise click.BadParameter("only with --shaft", param_hint="--gamma")
    if shaft_diameter is not None and not shaft_diameter > 0:
        raise click.BadParameter("must be positive", param_hint="--shaft-diameter")
    if prior_path is not None and not shaft:
        raise click.BadParameter("only with --shaft", param_hint="--fulcrum-prior")
    check_output(output, force)
    camera = read_camera(camera_path, camera_id=camera_id)
    priors = None
    if prior_path is not None:
        from pencilcal.toolkit.detect.shaft.prior import read_priors

        priors = read_priors(prior_path, camera)
    source = open_input(images, source_spec, max_pixels)
    check_output(output, force, [*source.paths, camera_path, mask_path, prior_path])
    region = frames_region(source, mask_path, shape=(camera.height, camera.width))
    records = []
    with FrameOutputs(jsonl_path, overlay_path, force, source=source) as live:
        ctx = (camera, detector, bars, shaft, min_length, bar_width, region, live.drawing, shaft_diameter, gamma,
               priors)
        for rec, drawn in run_frames(source, _lines_task, ctx, workers, "lines", quiet):
            if not rec["ok"]:
                warn(f"{rec['image']}: {rec['error']}")
            records.append(rec)
            live.emit(rec, drawn)
    meta = {"detector": detector, "mode": "bars" if bars else "edges", "camera": str(camera_path),
            **stream_meta(source)}
    if shaft_diameter is not None:
        meta["shaft_diameter"] = shaft_diameter
    if shaft:
        meta["gamma"] = gamma
    if prior_path is not None:
        meta["fulcrum_prior"] = str(prior_path)
    write_lines(output, records, force=force, meta=meta, valid_region=None if region is None else region.to_dict())
    if not quiet:
        n_ok = sum(r["ok"] for r in records)
        n_seg = sum(len(r["segments"]) for r in records)
        click.echo(f"{n_ok}/{len(records)} frames, {n_seg} segments -> {output}", err=True)
