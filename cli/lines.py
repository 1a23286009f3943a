"""`pencilcal lines`: line segments per frame, with angle uncertainty (lines.json)."""
from __future__ import annotations

from functools import partial

import click
import numpy as np

from pencilcal.toolkit.camera.formats import read_camera
from pencilcal.toolkit.io.images import check_image_size
from pencilcal.toolkit.detect.edges import DEFAULT_GAMMA
from pencilcal.toolkit.detect.lines import lines_record
from pencilcal.toolkit.errors import InputError
from pencilcal.toolkit.io.lines_file import write_lines

from .common import (detector_option, edge_model_option, gamma_option, command, FiniteFloat, FrameOutputs, camera_options, check_output, force_option,
                     frames_region, images_argument, instrument_mask_options, instrument_masks, jsonl_option,
                     mask_option, max_pixels_option, open_input, output_option, overlay_option, quiet_option, run,
                     run_frames, source_option, stream_meta, warn, warn_masks, workers_option, done)


def with_axis(camera, shaft, diameter):
    """A shaft record with its 3-D axis keys (`cylinder.shaft_axis_record`) added, or with
    ``axis_error`` saying why there is none (edges that bound no cylinder)."""
    from pencilcal.toolkit.errors import EstimationError, InputError
    from pencilcal.toolkit.pencil.cylinder import shaft_axis_record

    if shaft.get("edges") is None:
        return {**shaft, "axis_error": "no silhouette edges (a distal part alone)"}
    if shaft.get("edge_cov") is None:
        # as the 3-D fulcrum does: an axis needs its edges' covariance
        return {**shaft, "axis_error": "silhouette edges without their covariance"}
    try:
        return {**shaft, **shaft_axis_record(camera, shaft["edges"], shaft["edge_cov"], diameter)}
    except (EstimationError, InputError) as e:
        return {**shaft, "axis_error": str(e)}


def _lines_task(frame, ctx):
    """One frame's lines.json record, and the frame drawn with them when the overlay is
    asked for (module level: runs in worker processes too)."""
    (camera, detector, bars, shaft, min_length, bar_width, region, drawing, diameter, gamma, masks, radial, priors,
     tracker, edge_model, radial_joint, segments, parts, pencil) = ctx
    if frame.image is None:
        return {"image": frame.name, "ok": False, "error": frame.error, "segments": [], "angle_sigma_deg": []}, None
    check_image_size(frame, camera)
    rec = lines_record(frame.name, frame.image, camera, detector, bars, shaft, min_length, bar_width,
                       valid_region=region, gamma=gamma, instrument_mask=None if masks is None else masks.of(frame),
                       radial=radial, axis_prior=None if priors is None else priors[1].get(frame.name, priors[0]),
                       shaft_tracker=tracker, edge_model=edge_model, radial_joint=radial_joint, segments=segments,
                       parts=parts, radial_pencil=pencil)
    if diameter is not None:
        rec["shafts"] = [with_axis(camera, s, diameter) for s in rec.get("shafts") or []]
    if not drawing:
        return rec, None
    from pencilcal.toolkit.draw.overlay import draw_frame

    # drawn by the overlay's own thread (`FrameOutputs`), or in the worker process
    return rec, partial(draw_frame, frame.image, segments=rec["segments"], shafts=rec.get("shafts"), text=[frame.name],
                        scale=drawing)


def _summary(records):
    """The last line: frames, segments and their median angle sigma, shafts."""
    n_ok = sum(r["ok"] for r in records)
    n_seg = sum(len(r["segments"]) for r in records)
    sig = [float(s) for r in records if r.get("angle_sigma_deg") is not None
           for s in np.ravel(np.asarray(r["angle_sigma_deg"], float)) if np.isfinite(s)]
    line = f"{n_ok}/{len(records)} frames, {n_seg} segments"
    if sig:
        line += f" (angle sigma {np.median(sig):.2g} deg median)"
    if any("shafts" in r for r in records):
        line += f", {sum(len(r.get('shafts') or []) for r in records)} shafts"
    return line


@command()
@images_argument(required=False)
@source_option
@camera_options
@output_option
@detector_option("OpenCV detector proposing the segments.")
@click.option("--bars", is_flag=True,
              help="Printed spokes: each dark bar's midline.")
@click.option("--bar-width", nargs=2, type=FiniteFloat(), default=None, metavar="MIN MAX",
              help="With --bars: bar widths accepted [px]; default 2.5 px to 1/8 image.")
@click.option("--radial", type=click.IntRange(min=0), default=None, metavar="EDGES",
              help="Edges of a radial target (star, dartboard) round its vertex; 0: any count.")
@click.option("--radial-joint", type=click.Choice(["crowded", "all"]), default="crowded", show_default=True,
              help="Edges located jointly.")
@click.option("--pencil", "pencil_path", type=click.Path(dir_okay=False), default=None, metavar="PENCIL",
              help="With --radial: trimmed at its spokes' ring.")
@click.option("--shaft", is_flag=True,
              help="Also instrument shafts, with sigmas.")
@click.option("--shaft-diameter", type=FiniteFloat(), default=None, metavar="D",
              help="Shaft diameter [mm]: the 3-D axes too.")
@click.option("--no-segments", "segments", flag_value=False, default=True,
              help="With --shaft: no edge segments.")
@click.option("--track/--no-track", default=True, show_default=True,
              help="With --shaft: where the last frames predict them.")
@gamma_option
@edge_model_option
@click.option("--parts", is_flag=True,
              help="Also instrument parts with no shaft.")
@click.option("--fulcrum-prior", "prior_path", type=click.Path(dir_okay=False), default=None, metavar="FILE",
              help="With --shaft: through its fulcrum image.")
@click.option("--min-length", type=FiniteFloat(), default=None,
              help="Shortest segment written [px]; default 20 (bars: 1/30 of the image).")
@instrument_mask_options
@mask_option
@jsonl_option
@overlay_option
@max_pixels_option
@workers_option
@force_option
@quiet_option
@run
def lines(images, source_spec, camera_path, camera_id, output, detector, bars, bar_width, radial, radial_joint,
          pencil_path, shaft, shaft_diameter, segments, track, gamma, edge_model, parts, prior_path, min_length,
          instrument_mask, mask_labels, mask_instances, mask_path, jsonl_path, overlay_path, overlay_scale, max_pixels,
          workers, force, quiet):
    """Line segments in every frame, refined to subpixel, with angle uncertainty.

    \b
    Examples:
      pencilcal lines frames/ --camera cam.yaml --bars -o lines.json
      pencilcal lines frames/ --camera c.yaml --shaft --shaft-diameter 8 -o l.json

    IMAGES: files, folders or globs in the order given, or a video; or --source.
    Each segment in raw pixels with its sigmas; --bars: the spokes' midlines;
    --shaft: instrument shafts. In detail: docs/cli.md.
    \f
    IMAGES is one or more image files, folders or glob patterns, in the order given (a
    folder's images sorted naturally), or one video; or --source, a camera or a video still
    being written, read as it comes. The chosen OpenCV detector proposes segments;
    collinear fragments are merged and every line is refitted to its edge pixels (straight
    in undistorted pixels, so lens distortion does not bend it). Each frame gets `segments`
    in raw (distorted) pixels [x1, y1, x2, y2] and, per segment, `angle_sigma_deg` (sd of
    its angle) and `offset_sigma_px` (sd of its position across, at its midpoint), which
    `pencilcal orient` uses to weight the lines. Segments are oriented with the darker side
    on the left on screen. Segments shorter than --min-length are dropped (default 20 px;
    with --bars, 20 or 1/30 of the image's smaller side, whichever is longer: 36 px at
    1080p). Nothing is found on the boundary of the frames' valid region (--mask, or
    detected once from up to 16 frames: an endoscope's circular field stop, letterbox
    bars), which lines.json records once, as `valid_region`.

    --bars finds the printed spokes: dark bars, each written as ONE segment, its midline
    (bisector of the bar's two edges) between its end caps, for widths within --bar-width
    (undistorted pixels; default 2.5 px to 1/8 of the image). Without it every straight
    edge is a segment (a bar gives two).

    With --radial EDGES the segments are the edges of a radial target through its vertex
    (a Siemens star of N wedges has 2N; 0: whatever the frame shows): a star's wedges, a
    dartboard's sector boundaries (`pencilcal orient` labels them by the pencil file's
    shape), each located on the profiles linearised with --gamma, from where it lies clear
    of its neighbours out to where it ends, and where its neighbours crowd it all along
    located jointly with their blurred edges; with --radial-joint all every edge is (as
    `pencilcal orient IMAGES` does for a pencil of wedges: by their derivative's peak a
    star's edges feel their neighbours' pull, alike for neighbouring edges);
    `circle_points` holds the edge points across rays between them, among them the images
    of circles about the vertex (a star's outline, a dartboard's rings), which `orient`
    fits. With --pencil PENCIL (the pencil file `orient` reads) each edge that runs on past
    the ring where the spokes end (a dartboard's double ring, found from a first
    orientation of the edges) is trimmed there, as `pencilcal orient IMAGES` trims them:
    beyond it a ring of numbers or a maker's print turns the fitted line; not with
    --radial-joint all, whose edges are all located jointly and none is trimmed.

    --shaft also finds instrument shafts (pairs of long converging edges) and writes them
    as `shafts`: midline (image of the axis), width_px, angle_sigma_deg, edge_cov. From
    frame to frame (--track, with --workers 1) each is looked for where the previous frames
    predict it, as `pencilcal fulcrum --track` does; `frames_tracked` says how often. With
    --fulcrum-prior FILE (a fulcrum.json, each epoch's prior for its images by name; or a
    file with ray and ray_cov) every frame's shaft is searched through the fulcrum's image:
    at most one a frame, tissue bands left out. With
    --shaft --instrument-mask MASKS the shafts are the masked instruments' axes refined on
    the image's edges, saying where mask and image disagree. With
    --shaft-diameter D (e.g. 8 for an 8 mm instrument) each shaft also gets its 3-D axis
    from the two silhouette edges (the band's width fixes the depth): axis_point (the axis
    point closest to the camera centre), axis_direction (unit, away from the camera),
    axis_distance, and their covariance axis_cov in the axis chart of docs/formats.md, with
    axis_direction_sigma_deg and axis_distance_sigma; lengths in D's unit.
    --shaft --parts also gives the instrument regions of the learned pixel map that
    have no shaft (a distal part alone: jaws, a hook) an axis, kind part, with the
    larger sigmas of its outline (docs/formats.md); off by default: on the masked
    sources left out it adds no instrument, and it costs 0.4-0.6 s of CPU a 1080p
    frame (docs/method.md).
    --shaft --no-segments writes the shafts alone (every frame's segments empty): on a
    textured scene the segments take most of the time, and a live video of an instrument
    does not need them.

    A frame that cannot be decoded is reported and written with ok: false. --jsonl streams
    each frame's record as it is done; --overlay draws the segments and shafts on the
    frames.

    More examples:

        pencilcal lines left/*.png --camera camera.yaml -o lines.json
        pencilcal lines star.png --camera camera.yaml --radial 128 --radial-joint all -o lines.json
        pencilcal lines board.jpg --camera camera.yaml --radial 20 --pencil dartboard.yaml -o lines.json
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
    if edge_model != "step" and not shaft:
        raise click.BadParameter("only with --shaft", param_hint="--edge-model")
    if gamma != DEFAULT_GAMMA and not shaft and radial is None:
        raise click.BadParameter("only with --shaft or --radial", param_hint="--gamma")
    if radial_joint != "crowded" and radial is None:
        raise click.BadParameter("only with --radial", param_hint="--radial-joint")
    if radial is not None and bars:
        raise click.UsageError("--radial and --bars find different spokes: give one of them")
    if pencil_path is not None and radial is None:
        raise click.BadParameter("only with --radial (the ring a radial target's edges end on)",
                                 param_hint="--pencil")
    if pencil_path is not None and radial_joint == "all":
        raise click.UsageError("--radial-joint all locates every edge jointly and none is trimmed: --pencil "
                               "would change nothing")
    if shaft_diameter is not None and not shaft_diameter > 0:
        raise click.BadParameter("must be positive", param_hint="--shaft-diameter")
    if not segments and (not shaft or bars or radial is not None):
        raise click.BadParameter("only with --shaft, without --bars or --radial (the shafts alone)",
                                 param_hint="--no-segments")
    if instrument_mask is not None and not shaft:
        raise click.BadParameter("only with --shaft", param_hint="--instrument-mask")
    if prior_path is not None and not shaft:
        raise click.BadParameter("only with --shaft", param_hint="--fulcrum-prior")
    if parts and not shaft:
        raise click.BadParameter("only with --shaft", param_hint="--parts")
    if parts and instrument_mask is not None:
        raise click.UsageError("--parts and --instrument-mask: the mask gives every instrument's axis, give one")
    if prior_path is not None and instrument_mask is not None:
        raise click.UsageError("--instrument-mask gives the shafts: --fulcrum-prior is for detecting them")
    check_output(output, force)
    camera = read_camera(camera_path, camera_id=camera_id)
    pencil = None
    if pencil_path is not None:
        from pencilcal.toolkit.pencil.spec import read_pencil

        pencil = read_pencil(pencil_path)
        if pencil.shape == "line":
            raise InputError(f"{pencil_path}: a pencil of lines (bars); --radial measures the edges of wedges or "
                             "sectors (shape wedge or edge, docs/formats.md)")
    priors = None
    if prior_path is not None:
        from pencilcal.toolkit.detect.shaft.prior import read_priors

        priors = read_priors(prior_path, camera)
    source = open_input(images, source_spec, max_pixels)
    masks = instrument_masks(source, instrument_mask, mask_labels, mask_instances)
    check_output(output, force, [*source.paths, camera_path, mask_path, prior_path, pencil_path,
                                 *(masks.paths.values() if masks else ())])
    region = frames_region(source, mask_path, shape=(camera.height, camera.width))
    records = []
    tracker = None
    if shaft and track and workers == 1 and masks is None and priors is None:
        from pencilcal.toolkit.detect.shaft.detector import ShaftTracker

        tracker = ShaftTracker(gamma=gamma, edge_model=edge_model)
    with FrameOutputs(jsonl_path, overlay_path, force, source=source, scale=overlay_scale) as live:
        ctx = (camera, detector, bars, shaft, min_length, bar_width, region, live.drawing, shaft_diameter, gamma, masks,
               radial, priors, tracker, edge_model, radial_joint, segments, parts, pencil)
        for rec, drawn in run_frames(source, _lines_task, ctx, workers, "lines", quiet):
            if not rec["ok"]:
                warn(f"{rec['image']}: {rec['error']}")
            warn_masks(rec)
            records.append(rec)
            live.emit(rec, drawn)
    meta = {"detector": detector, "mode": "bars" if bars else ("radial" if radial is not None else "edges"),
            "camera": str(camera_path),
            **stream_meta(source)}
    if shaft_diameter is not None:
        meta["shaft_diameter"] = shaft_diameter
    if shaft or radial is not None:
        meta["gamma"] = gamma
    if radial is not None:
        meta["radial_joint"] = radial_joint
    if pencil_path is not None:
        meta["pencil"] = str(pencil_path)
    if shaft:
        meta["edge_model"] = edge_model
        meta["segments"] = segments
    if parts:
        meta["parts"] = True
    if masks is not None:
        meta["instrument_mask"] = str(instrument_mask)
    if prior_path is not None:
        meta["fulcrum_prior"] = str(prior_path)
    if tracker is not None:
        meta["frames_tracked"] = tracker.tracked
    write_lines(output, records, force=force, meta=meta, valid_region=None if region is None else region.to_dict())
    done(_summary(records), output, quiet=quiet)
