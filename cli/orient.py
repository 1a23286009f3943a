"""`pencilcal orient`: angular-variation orientation per frame."""
from __future__ import annotations

from functools import partial

import numpy as np
import click

from pencilcal.toolkit.camera.formats import read_camera
from pencilcal.toolkit.errors import EstimationError, InputError
from pencilcal.toolkit.io.lines_file import read_lines
from pencilcal.toolkit.pencil.defaults import CHI2_2_DETECTION
from pencilcal.toolkit.pencil.orient import MAX_SEGMENTS, MODELS, orient_segments, resolve_twins_by_continuity
from pencilcal.toolkit.pencil.orientation import write_orientations
from pencilcal.toolkit.pencil.sequence_noise import orientations_with_noise
from pencilcal.toolkit.pencil.spec import read_pencil
from pencilcal.toolkit.pencil.shutter import camera_readout, orient_video_frame, seen_lines
from pencilcal.validation.radial_run import STAR_FALLBACK

from .common import (detector_option, endpoint_sigma_option, command, camera_options, check_output, FiniteFloat, force_option, FrameOutputs, images_argument,
                     frames_region, jsonl_option, mask_option, max_pixels_option, open_input, output_option,
                     overlay_option, progress, quiet_option, run, run_frames, source_option, stream_meta, warn,
                     workers_option, done)


def _orient_record(camera, pencil, fr, opts):
    """The orientation record of one lines.json frame."""
    if not fr["ok"]:
        rec = orient_segments(camera, np.zeros((0, 4)), pencil, model=opts["model"], image=fr["image"])
        return rec.replace(error=fr.get("error") or "no segments (frame marked not ok in the lines file)")
    sig = fr.get("angle_sigma_deg")
    if sig is None and opts["angle_sigma"] is not None:
        sig = opts["angle_sigma"]
    n, cap = len(fr["segments"]), opts["max_segments"]
    if n > cap and opts.get("warn", True):
        warn(f"{fr['image']}: {n} segments, more than --max-segments {cap}: the {cap} longest are used")
    kw = dict(model=opts["model"], endpoint_sigma_px=opts["endpoint_sigma"],
              angle_sigma=None if sig is None else np.radians(sig), prior=opts["priors"].get(fr["image"]),
              image=fr["image"], offset_sigma=fr.get("offset_sigma_px"), max_segments=cap,
              bar_width_px=fr.get("width_px"), circle_points=fr.get("circle_points"), ideal=fr.get("ideal"),
              keep_lines=opts.get("keep_lines", False))
    if fr.get("angle_sigma_error_deg") is not None and sig is not None:  # (the covariance's: a star's edges)
        kw["angle_sigma_error"] = np.radians(np.asarray(fr["angle_sigma_error_deg"], float))
    if fr.get("vertex_sd_px") is not None:  # (the covariance's: the point radial edges were located about)
        kw["vertex_floor_px"] = float(fr["vertex_sd_px"])
    state = opts.get("tracking")
    if state is None:
        return orient_segments(camera, fr["segments"], pencil, **kw)
    raw_ideal = kw.get("ideal")
    previous = state["previous"]
    seen = None if previous is None else state.get("seen", {}).get(previous.image)
    # frames in order in this process: the previous frame's estimate is the prior; a known
    # readout deskews the lines, an unknown one (None) widens the sigmas
    rec, tracked = orient_video_frame(camera, fr["segments"], pencil, previous, readout=opts.get("readout"),
                                      seen=seen, **kw)
    if rec.ok and rec.spokes is not None:
        # this frame's lines as seen, for the next frame's velocities (by name: a frame tried
        # again replaces its own, never its predecessor's)
        seen = state.setdefault("seen", {})
        seen[fr["image"]] = seen_lines(camera, fr["segments"], rec.spokes, raw_ideal)
        for k in list(seen)[:-2]:
            del seen[k]
    state["previous"] = rec if rec.ok else None
    state["tracked"] += bool(tracked)
    return rec


def _sequence_noise(records, frames, camera, pencil, opts, given):
    """(records, the orientation.json header's ``noise``): the sigmas with the noise the
    sequence shows (`sequence_noise.orientations_with_noise`), unless the user gave it
    (`given`). Lines of a lines file without their own sigmas: estimated, the frames run
    again with the estimate; lines with the detector's sigmas (IMAGES, or a lines file that
    has them): only ever inflated."""
    def run(sigma):
        o = dict(opts, endpoint_sigma=sigma, warn=False, tracking=None if opts["tracking"] is None else
                 {"previous": None, "tracked": 0})
        return [_orient_record(camera, pencil, fr, o) for fr in frames]

    estimable = frames is not None and not any(fr.get("angle_sigma_deg") is not None for fr in frames)
    out, noise, message = orientations_with_noise(
        records, run, opts["endpoint_sigma"], given=given, estimable=estimable, angle_sigma=opts["angle_sigma"],
        fix_hint="give --endpoint-sigma to fix the noise")
    if message:
        warn(message)
    return out, noise


def _orient_image_task(frame, ctx):
    """Lines (as `pencilcal lines` finds them) and orientation of one decoded frame, and the
    frame drawn with them when the overlay is asked for (None otherwise); module level, so it
    runs in worker processes too."""
    from pencilcal.toolkit.io.images import check_image_size
    from pencilcal.toolkit.detect.lines import fan_line_options, lines_record, radial_edge_count, radial_joint_mode
    from pencilcal.validation.radial_run import as_star_frame, radial_frame, wants_star

    camera, pencil, detector, opts, edges, region, drawing = ctx
    if frame.image is None:
        fr = {"image": frame.name, "ok": False, "segments": np.zeros((0, 4)), "error": frame.error}
        rec = _orient_record(camera, pencil, fr, opts)
    else:
        check_image_size(frame, camera)
        bars, polarity = fan_line_options(pencil.width, edges)
        radial = None if edges else radial_edge_count(pencil)
        state = opts.get("tracking")
        tracker = state["bars"] if state is not None and bars and radial is None else None
        lines_kw = dict(bars=bars, valid_region=region, bar_polarity=polarity, bar_tracker=tracker, radial=radial,
                        radial_joint=radial_joint_mode(pencil), ideal=True)

        def detected():
            fr = lines_record(frame.name, frame.image, camera, detector, **lines_kw)
            return fr, _orient_record(camera, pencil, fr, opts)

        def orient(pen, fr, keep_lines):
            return _orient_record(camera, pen, fr, dict(opts, keep_lines=keep_lines))

        if radial is not None:
            fr, rec = radial_frame(frame.name, frame.image, camera, pencil, detector, lines_kw, orient, state)
        else:
            before = None if state is None else dict(state)
            fr, rec = detected() if tracker is None else _tracked_bars_frame(detected, tracker, state)
            if not edges and wants_star(rec, pencil):
                fr, rec = as_star_frame(frame.name, frame.image, camera, pencil, detector, lines_kw, orient,
                                        (fr, rec), state, before)
    # drawn by the overlay's own thread (`FrameOutputs`), or in the worker process
    return rec, partial(_drawn, frame, rec, fr["segments"], camera, drawing) if drawing else None


def _tracked_bars_frame(detected, tracker, state):
    """A frame whose bars the tracker found where it predicted them (`bar_track`): kept
    when its orientation is ok and uses as many spokes as the last detection, less one,
    and four at least where that had four or more (three lines fit any orientation: a
    wrong bar among them would pass unseen); else detected in the region around the
    prediction, then in the whole frame, and fitted again each time (the orientation's own
    tracking state as before the first try). Returns (lines record, orientation)."""
    before = dict(state)
    while True:
        fr, rec = detected()
        used = tracker.full_used or 3
        need = max(min(used, 4), used - 1, 3)
        good = rec.ok and (tracker.last_mode == "full" or rec.lines_used >= need)
        if good or not tracker.lost():
            break
        state.update(previous=before["previous"], tracked=before["tracked"])
    if good:
        tracker.keep(np.asarray(rec.spokes) >= 0, used=rec.lines_used)
    return fr, rec


def _drawn(frame, rec, segments, camera, scale):
    """The frame with its orientation drawn (labelled spokes, vertex ellipse, normal, tilt
    +- sigma) at `scale` of its size, or None for a frame that did not decode."""
    if frame.image is None:
        return None
    from pencilcal.toolkit.draw.overlay import draw_orientation

    return draw_orientation(frame.drawable, rec, segments, camera, scale=scale)


def _tracking_meta(state):
    """The output file's record of tracking: frames_tracked (labelled by the previous
    frame's orientation), bars_tracked (bars found from the previous frame's, with IMAGES)."""
    if state is None:
        return {}
    return {"frames_tracked": state["tracked"], **({"bars_tracked": state["bars"].tracked} if "bars" in state else {})}


def _warn_frame(rec, pencil=None):
    if not rec.ok:
        warn(f"{rec.image}: {rec.error}")
    elif rec.normal_ambiguous:
        warn(f"{rec.image}: the normal is ambiguous: other labellings of its {rec.lines_used} lines fit "
             "about as well and put it elsewhere (normal_alternatives)")
    elif (pencil is not None and pencil.shape == "line" and pencil.width is None and pencil.full_circle
          and rec.spokes_used is not None and rec.spokes_used < STAR_FALLBACK * pencil.count):
        # a star's wedges or a dartboard's sectors measured as bars: their edges are the lines
        warn(f"{rec.image}: {rec.spokes_used} of the {pencil.count} spokes all round the vertex used; if they are "
             "a star's wedges or the boundaries between sectors, the pencil file says so (shape: wedge or edge, "
             "docs/formats.md) and their edges are measured")
    if rec.ok and rec.circle_consistent is False:
        # kept, not refused: on renders right frames of every spoke disagree as much (the
        # circles' sigma, or the lines', too small there), and their normals still hold
        warn(f"{rec.image}: the lines' normal and the circles' (circle_normal) lie {rec.circle_angle_deg:.2f} deg "
             f"apart, beyond their sigmas (circle_chi2 {rec.circle_chi2:.1f} > {CHI2_2_DETECTION:.2f}): one of the two "
             "is further off than its sigma says; the lines' normal is reported")


def _summary(records):
    """The last line: frames oriented, the tilt and its sigma (medians), and how the twin
    was chosen (what resolves the frames left ambiguous)."""
    from collections import Counter

    ok = [r for r in records if r.ok]
    line = f"{len(ok)}/{len(records)} frames oriented"
    if not ok:
        return line
    n_amb = sum(bool(r.normal_ambiguous) for r in ok)
    line += (f": tilt {np.median([r.tilt_deg for r in ok]):.2f} deg median (sigma "
             f"{np.median([r.tilt_sigma_deg for r in ok]):.2g} deg), detectable in {sum(bool(r.detectable) for r in ok)}")
    twin = sum(bool(r.ambiguous) for r in ok)
    by = Counter(r.resolved_by for r in ok if not r.ambiguous)
    how = ", ".join(f"{c} by {'the spoke radii' if k == 'radius' else k}" for k, c in by.most_common())
    line += f"; twin resolved in {len(ok) - twin}" + (f" ({how})" if how else "")
    if twin:
        line += f", ambiguous in {twin} (spoke radii, --prior or --continuity from a resolved frame choose it)"
    return line + (f" ({n_amb} with an ambiguous normal)" if n_amb else "")


def _prior_rotations(path):
    """R_cam_from_target per image name from a poses.json (pencilcal pnp) file."""
    from pencilcal.toolkit.io.files import load_frames

    _, frames = load_frames(path, "poses file")
    out = {}
    for i, (f, where) in enumerate(frames):
        if f.get("ok", True) and f.get("R_cam_from_target") is not None:
            try:
                R = np.asarray(f["R_cam_from_target"], float)
            except (TypeError, ValueError):
                raise InputError(f"{where}: R_cam_from_target must be a 3x3 matrix of numbers") from None
            if R.shape != (3, 3) or not np.all(np.isfinite(R)):
                raise InputError(f"{where}: R_cam_from_target must be a finite 3x3 matrix")
            # a prior that is no rotation would pick twins by a meaningless distance
            if np.max(np.abs(R.T @ R - np.eye(3))) > 1e-6 or np.linalg.det(R) < 0:
                raise InputError(f"{where}: R_cam_from_target is not a rotation (R^T R != I or det < 0)")
            out[str(f.get("image", i))] = R
    if not out:
        raise InputError(f"{path}: no frame with a pose to use as a prior")
    return out


def _check_priors_match(priors, names, path):
    """A prior is used by image name: one whose names match none of the frames would
    silently do nothing."""
    if priors and names is not None and not set(priors) & set(names):
        some = ", ".join(sorted(priors)[:2])
        raise InputError(f"{path}: none of its {len(priors)} image names ({some}, ...) is a frame of this run")


@command()
@images_argument(required=False)
@click.option("--lines", "lines_path", type=click.Path(dir_okay=False), default=None,
              help="lines.json (raw pixels), instead of IMAGES.")
@camera_options
@click.option("--pencil", "pencil_path", required=True, type=click.Path(dir_okay=False),
              help="Pencil file (.yaml/.json): spoke angles, optional vertex and radius.")
@output_option
@click.option("--model", type=click.Choice(MODELS), default="exact", show_default=True,
              help="exact; general, aligned: the chapter's models, for comparison.")
@endpoint_sigma_option("End point noise [px]; not given: estimated from the sequence.")
@click.option("--angle-sigma", type=FiniteFloat(), default=None,
              help="Every segment's angle noise [deg], instead.")
@click.option("--prior", "prior_path", type=click.Path(dir_okay=False), default=None,
              help="poses.json (pencilcal pnp): the twin closer to each frame's pose.")
@click.option("--continuity/--no-continuity", default=True, show_default=True,
              help="Carry twin choices along the sequence to ambiguous frames.")
@click.option("--track/--no-track", default=True, show_default=True,
              help="Find the spokes where the last frame has them (--workers 1).")
@click.option("--readout", type=click.FloatRange(0.0, 1.0), default=None,
              help="Rolling shutter's readout / frame interval (0: global); default: "
                   "the camera file's, else sigmas widened.")
@detector_option("Line detector, with IMAGES.")
@click.option("--edges", is_flag=True, help="With IMAGES: plain edge segments, not the spokes' midlines.")
@mask_option
@click.option("--max-segments", type=click.IntRange(min=3), default=MAX_SEGMENTS, show_default=True,
              help="The longest segments used per frame, at most.")
@source_option
@jsonl_option
@overlay_option
@max_pixels_option
@workers_option
@force_option
@quiet_option
@run
def orient(images, lines_path, camera_path, camera_id, pencil_path, output, model, endpoint_sigma, angle_sigma,
           prior_path, continuity, track, readout, detector, edges, mask_path, max_segments, source_spec, jsonl_path, overlay_path,
           overlay_scale, max_pixels, workers, force, quiet):
    """Orientation of the pencil in every frame, from its image angles alone.

    \b
    Examples:
      pencilcal orient frames/ --camera cam.yaml --pencil pencil.yaml -o o.json
      pencilcal orient --lines l.json --camera cam.yaml --pencil p.yaml -o o.json

    Lines from IMAGES (files, folders or globs in the order given, or a video), --source
    or --lines. Per frame: tilt, normal, rotation, their sigmas and the twin, chosen where
    the spoke radii, circles, --prior or continuity can. In detail: docs/cli.md.
    \f
    From IMAGES or --source (a camera, a URL, a video file being written) the lines are
    detected first: the midlines of the printed spokes, at whatever width they are seen
    (dark bars when the pencil file gives their width; else dark or light, whichever the
    frame shows); for wedges and sector boundaries (the pencil file's shape: a Siemens
    star, a dartboard) their edges all round the vertex, as `pencilcal lines --radial`
    finds them, with the edge points of the circles about it (a dartboard's boundaries,
    which end on one of the pencil file's circles, found again with each edge trimmed at
    that ring's image, from a first orientation); or with --edges plain edge
    segments (as `pencilcal lines`), never on the boundary of the frames' valid region
    (--mask, or detected once from up to 16 frames); or they come from a lines file
    (--lines). Segments are undistorted, the vertex found, the segments labelled with
    spokes (missing spokes and spurious segments are tolerated) and the plane's
    orientation fitted with its uncertainty. Both twin solutions are written; the twin is
    chosen where the spoke radii (pencil file), the images of circles about the vertex
    (their pole-polar relation gives the plane a second time, written beside the lines'
    with whether the two agree), a prior pose (--prior: the twin closer to each frame's
    board pose in a poses.json of `pencilcal pnp`) or continuity (--continuity: the
    choices of resolved frames carried along the sequence to the ambiguous ones) tell them
    apart. Midlines of bars (with their width, as found from images or in a lines file)
    are then moved onto the images of the bars' printed centre lines under the fitted
    plane, which under perspective they miss by w^2 / (4 V) (w the width, V the distance
    to the horizon), and the frame is fitted again. --max-segments: at most this many
    segments per frame are used, the longest; a warning says when a frame has more.

    From frame to frame (--track, with --workers 1) each spoke is looked for where a
    constant-velocity model of its edges predicts it, within that prediction's uncertainty
    (then measured as a full detection measures it); where the tracked frame's fit fails or
    loses more than one spoke, the spokes are detected in the region around the prediction,
    then in the whole frame (and on the first frame, the second, and every 30th). The
    previous frame's orientation labels the lines (the full search where that fails) and
    the twin is kept where a frame alone cannot choose. In detail: docs/live.md.

    Unless the noise is given (--endpoint-sigma: the noise of each segment end point [px],
    which sets the angle and offset uncertainty; --angle-sigma: every segment's angle noise
    [deg]) the sigmas hold the noise the sequence shows: the frames' pooled residuals give a
    variance factor (outlier frames left out) by which every covariance is scaled, starting
    from the default end point noise for lines without their own sigmas; detected lines'
    own sigmas are only ever inflated. The output's `noise` says what was found.

    --jsonl streams each frame's record as it is done (the twin and the noise as known
    then: continuity and the sequence's noise are applied to the output file only);
    --overlay draws the labelled spokes, the vertex and its 3-sigma ellipse, the normal and
    tilt +- sigma on the frames, at --overlay-scale of their size (half by default: encoding
    a full-size 1080p overlay costs more than decoding and measuring the frame).
    """
    if angle_sigma is not None and angle_sigma <= 0:
        raise click.BadParameter("must be positive", param_hint="--angle-sigma")
    if sum(x is not None for x in (images, lines_path, source_spec)) != 1:
        raise click.UsageError("give IMAGES, --source or --lines (one of them)")
    if lines_path is not None and (edges or mask_path is not None):
        raise click.UsageError("--edges and --mask are for IMAGES (a lines file's lines are already found)")
    if lines_path is not None and overlay_path is not None:
        raise click.UsageError("--overlay draws on the frames: it needs IMAGES or --source, not --lines")
    check_output(output, force, [lines_path, camera_path, pencil_path, prior_path, mask_path])
    camera = read_camera(camera_path, camera_id=camera_id)
    pencil = read_pencil(pencil_path)
    priors = _prior_rotations(prior_path) if prior_path else {}
    if readout and not (track and workers == 1):
        raise click.UsageError("--readout needs the frames tracked in order: --track and --workers 1")
    if readout is None:
        readout = camera_readout(camera, camera_path)
        if readout and not (track and workers == 1):
            warn(f"{camera_path}: the rolling shutter's readout is not undone without --track and --workers 1")
            readout = 0.0
    opts = dict(model=model, endpoint_sigma=endpoint_sigma, angle_sigma=angle_sigma, priors=priors,
                max_segments=max_segments, readout=readout,
                tracking={"previous": None, "tracked": 0} if track and workers == 1 else None)
    records, source = [], None
    if lines_path is not None:
        frames = read_lines(lines_path)
        if not frames:
            raise InputError(f"{lines_path}: no frames")
        _check_priors_match(priors, [fr["image"] for fr in frames], prior_path)
        with FrameOutputs(jsonl_path, None, force) as live, progress(frames, "orient", quiet) as bar:
            for fr in bar:
                rec = _orient_record(camera, pencil, fr, opts)
                _warn_frame(rec, pencil)
                records.append(rec)
                live.emit(rec.to_dict())
    else:
        # the lines are found on grey frames, converted in the decoding thread; the overlay
        # draws on the colour frames, kept beside them
        source = open_input(images, source_spec, max_pixels, gray=True, keep_colour=overlay_path is not None)
        check_output(output, force, [*source.paths, mask_path])
        if opts["tracking"] is not None:
            from pencilcal.toolkit.detect.bar_track import BarTracker

            opts["tracking"]["bars"] = BarTracker()
        region = frames_region(source, mask_path, shape=(camera.height, camera.width))
        if source.kind != "stream":
            names = [p.name for p in source.paths] if source.kind == "images" else \
                [f"frame_{i:06d}" for i in range(source.count)]
            _check_priors_match(priors, names, prior_path)
        with FrameOutputs(jsonl_path, overlay_path, force, source=source, scale=overlay_scale) as live:
            ctx = (camera, pencil, detector, opts, edges, region, live.drawing)
            for rec, drawn in run_frames(source, _orient_image_task, ctx, workers, "orient", quiet):
                _warn_frame(rec, pencil)
                records.append(rec)
                live.emit(rec.to_dict(), drawn, name=rec.image)
    if not any(r.ok for r in records):
        # a run with no estimate at all failed: say so and leave nothing that looks like a result
        raise EstimationError(f"{lines_path or source.description}: no frame gave an orientation"
                              + (f" ({len(records)} frames)" if source_spec else ""))
    given = angle_sigma is not None or \
        click.get_current_context().get_parameter_source("endpoint_sigma") != click.core.ParameterSource.DEFAULT
    records, noise = _sequence_noise(records, frames if lines_path is not None else None, camera, pencil, opts, given)
    if continuity:
        records = resolve_twins_by_continuity(records)
    write_orientations(output, records, force=force, model=model, camera=str(camera_path), pencil=str(pencil_path),
                       noise=noise,
                       lines=None if lines_path is None else str(lines_path),
                       images=None if images is None else source.description, **stream_meta(source),
                       **_tracking_meta(opts["tracking"]))
    done(_summary(records), output, quiet=quiet)
