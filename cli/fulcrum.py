"""`pencilcal fulcrum`: the fulcrum of a pivoting instrument over a sequence."""
from __future__ import annotations

import click
import numpy as np

from pencilcal.toolkit.camera.formats import read_camera
from pencilcal.toolkit.camera.stereo import read_stereo
from pencilcal.toolkit.errors import EstimationError, InputError
from pencilcal.toolkit.io.files import write_json
from pencilcal.toolkit.pencil.fulcrum import fulcrum_from_frames, read_angles, stereo_fulcrum
from pencilcal.toolkit.io.lines_file import read_lines
from pencilcal.toolkit.pencil.sequence_noise import fulcrum_with_noise
from pencilcal.validation.fulcrum_run import fulcrum_with_sigmas

from .common import (detector_option, endpoint_sigma_option, gamma_option, command, camera_options, check_output, FiniteFloat, force_option, FrameOutputs, frames_region,
                     images_argument, jsonl_option, mask_option, max_pixels_option, open_input, output_option,
                     overlay_option, quiet_option, run, run_frames, source_option, stream_meta, warn, workers_option,
                     done)



def _shaft_task(frame, ctx):
    """The shafts of one frame as a lines.json frame (module level: runs in workers too)."""
    import numpy as np

    from pencilcal.toolkit.io.images import check_image_size
    from pencilcal.toolkit.detect.shaft.detector import detect_shafts

    camera, options, region, drawing, tracker = ctx
    if frame.image is None:
        return {"image": frame.name, "ok": False, "segments": np.zeros((0, 4)), "error": frame.error}, None
    check_image_size(frame, camera)
    found = (detect_shafts(frame.image, camera, valid_region=region, **options) if tracker is None
             else tracker(frame.image, camera, valid_region=region))
    shafts = [s.to_dict() for s in found]
    rec = {"image": frame.name, "ok": True, "segments": np.zeros((0, 4)), "shafts": shafts,
           "error": None if shafts else "no instrument shaft found"}
    if not drawing:
        return rec, None
    from functools import partial

    from pencilcal.toolkit.draw.overlay import draw_frame

    # drawn by the overlay's own thread (`FrameOutputs`), or in the worker process
    return rec, partial(draw_frame, frame.image, shafts=shafts, text=[frame.name])


def _shafts(source, camera, options, quiet, workers, mask_path, live, tracker=None):
    """Instrument shafts of every frame of an image source, as lines.json frames, within the
    sequence's valid region (the mask file's, or detected: `region.detect.sequence_region`);
    each frame's shafts to the live outputs as they are found (the fulcrum is known only at
    the end). options: keywords of `shaft.detector.detect_shafts` (detector, gamma); tracker: a
    `shaft.detector.ShaftTracker` (frames in order, --workers 1), or None."""
    region = frames_region(source, mask_path, shape=(camera.height, camera.width))
    frames = []
    ctx = (camera, options, region, live.drawing, tracker)
    for f, drawn in run_frames(source, _shaft_task, ctx, workers, "shafts", quiet):
        if f["error"]:
            warn(f"{f['image']}: {f['error']}")
        frames.append(f)
        live.emit({k: v for k, v in f.items() if k != "segments"}, drawn, name=f["image"])
    return frames


def _with_noise(res, run, frames, sigma, given):
    """(Fulcrum, the fulcrum.json ``noise`` record): the sigmas with the noise the lines'
    residuals show (`sequence_noise.fulcrum_with_noise`) unless the user gave it; segments
    without their own sigmas are estimated (the fit run again with the estimate), the
    detector's sigmas (shaft midlines, a lines file's angle sigmas) only inflated."""
    out, noise, message = fulcrum_with_noise(res, run, sigma, frames, given=given)
    if message:
        warn(message)
    return out, noise


def _is_lines_file(path):
    """Whether --right names a lines file (a .json file: `pencilcal lines`'s output) rather
    than frames (image files, folders, patterns, a video)."""
    from pathlib import Path

    return Path(path).suffix.lower() == ".json" and not Path(path).is_dir()


def _right_frames(right, camera_right, options, max_pixels, workers, quiet, force):
    """(lines.json frames of the right view, the record's key and value saying where they
    came from): read from a lines file, else its shafts detected in its own frames (its
    valid region detected on them)."""
    if _is_lines_file(right):
        frames = read_lines(right)
        if not frames:
            raise InputError(f"{right}: no frames")
        return frames, ("lines", str(right))
    source = open_input((right,), None, max_pixels)
    with FrameOutputs(None, None, force) as live:
        return _shafts(source, camera_right, options, quiet, workers, None, live), ("images", source.description)


def _summary(out, off_axis, shaft_diameter, n_frames):
    """The last line: the fulcrum (3-D [mm] where measured, its image [px]) with sigmas,
    from how many lines and of how many frames (`n_frames`), the outliers."""
    where = ("its image ({:.2f}, {:.2f}) px".format(*out["vertex_px"]) if out["vertex_px"] is not None
             else f"its ray {off_axis:.1f} deg off axis")
    cov = out.get("vertex_cov_px2")
    if out["vertex_px"] is not None and cov is not None:
        where += f" +- {float(np.sqrt(np.trace(np.asarray(cov, float)))):.2g} px"
    line = f"fulcrum: {where} from {out['lines_used']} lines in {out.get('frames_used', '?')} of {n_frames} frames"
    if shaft_diameter is not None and out.get("point") is not None:
        bad = ", ".join(str(o["image"]) for o in out.get("point_outliers") or [])
        line = ("3-D fulcrum ({:.1f}, {:.1f}, {:.1f}) mm +- {:.2g} mm (RMS, camera frame) from {} axes{}; ".format(
            *out["point"], out["point_sigma"], out["point_axes_used"], f" (outliers: {bad})" if bad else "")
            + line.removeprefix("fulcrum: "))
    return line


def _stereo(left, right_images, camera_right, camera_right_path, rig, options, endpoint_sigma, given, max_pixels,
            workers, quiet, force):
    """fulcrum.json's ``stereo`` record: the right view's fulcrum from its own shafts (a lines
    file's, or detected in its frames), the noise as for the left view, then
    `fulcrum.stereo_fulcrum` with the left's."""
    frames, (key, where) = _right_frames(right_images, camera_right, options, max_pixels, workers, quiet, force)

    def run(sigma):
        try:
            return fulcrum_from_frames(camera_right, frames, endpoint_sigma_px=sigma)
        except EstimationError as e:
            raise EstimationError(f"{right_images} (right view): {e}") from None

    right, noise = _with_noise(run(endpoint_sigma), run, frames, endpoint_sigma, given)
    for w in right.warnings:
        warn(f"right view: {w}")
    try:
        st = stereo_fulcrum(left, right, rig)
    except EstimationError as e:
        raise EstimationError(f"{rig.source}: {e}") from None
    rec = st.to_dict()
    rec["right"] = {key: where, "camera": str(camera_right_path), "noise": noise, **rec["right"]}
    if "agreement" in rec and not rec["agreement"]["consistent"]:
        warn("the diameter-based and the triangulated 3-D fulcrum disagree beyond their sigmas (chi2 {:.1f}, {} dof, "
             "p {:.2g}): check the shaft diameter and the stereo file's unit".format(
                 rec["agreement"]["chi2"], rec["agreement"]["dof"], rec["agreement"]["p_value"]))
    return rec


@command()
@images_argument(required=False)
@source_option
@click.option("--lines", "lines_path", type=click.Path(dir_okay=False), default=None,
              help="lines.json (its shaft midlines where present), instead of IMAGES.")
@camera_options
@click.option("--angles", "angles_path", type=click.Path(dir_okay=False), default=None,
              help="CSV of pivot angles per frame: also the pivot plane.")
@click.option("--shaft-diameter", type=FiniteFloat(), default=None, metavar="D",
              help="The shaft's diameter [mm]: also the 3-D fulcrum, in mm.")
@click.option("--right", "right_images", default=None, metavar="IMAGES|LINES",
              help="A stereo pair's right view (frames or lines.json): the fulcrum triangulated.")
@click.option("--camera-right", "camera_right_path", type=click.Path(dir_okay=False), default=None,
              help="Camera file of the --right view.")
@click.option("--right-from-left", "stereo_path", type=click.Path(dir_okay=False), default=None, metavar="FILE",
              help="Stereo calibration (OpenCV's R and T, e.g. extrinsics.yml).")
@endpoint_sigma_option("End point noise [px] of segments without their own sigma.")
@detector_option("Shaft proposals' detector.")
@gamma_option
@click.option("--track/--no-track", default=True, show_default=True,
              help="Find the shafts where the previous frames predict them (--workers 1).")
@mask_option
@jsonl_option
@overlay_option
@max_pixels_option
@workers_option
@output_option
@force_option
@quiet_option
@run
def fulcrum(images, source_spec, lines_path, camera_path, camera_id, angles_path, shaft_diameter, right_images,
            camera_right_path, stereo_path, endpoint_sigma, detector, gamma, track, mask_path, jsonl_path, overlay_path,
            max_pixels, workers, output, force, quiet):
    """The fulcrum of an instrument pivoting about its entry port.

    \b
    Examples:
      pencilcal fulcrum frames/ --camera cam.yaml --shaft-diameter 8 -o f.json
      pencilcal fulcrum --lines l.json --camera cam.yaml --angles a.csv -o f.json

    Shafts from IMAGES (files, folders or globs in the order given, or a video), --source
    or --lines. The fulcrum's image and ray with sigmas; with --shaft-diameter its 3-D point
    [mm]; with --right a stereo pair's. In detail: docs/cli.md.
    \f
    Every frame's instrument line passes through the fulcrum's image: their robust weighted
    intersection gives the fulcrum's viewing ray and, where the lens model reaches it (a
    port far off axis may lie beyond), its raw pixel and covariance. From IMAGES the
    instrument shafts are detected in every frame (their midlines are the axis images),
    never on the boundary of the frames' valid region (--mask, or detected once from up to
    16 frames); or the lines come from a lines file (--lines; its shaft midlines are used
    when present). With --angles (a CSV of image,angle_deg, or one pivot angle per frame)
    the lines form a pencil with known angles and the orientation of the pivot plane comes
    out too, with the keys of orientation.json.

    With --shaft-diameter D (e.g. 8 for an 8 mm instrument; lengths then come out in D's
    unit, mm as the board and pencil files have them) every shaft's two silhouette edges
    give its 3-D axis (the band's width fixes its depth), and the fulcrum is also the
    robust weighted least-squares point closest to all the axes: point [x, y, z] (camera
    frame), point_cov, point_sigma (the RMS 3-D error its covariance predicts; with the
    intrinsics' covariance in the camera file also point_cov_total and point_sigma_total),
    and the axes that pass far from it named in point_outliers. Its lines must be shafts
    with their edges' covariance (lines --shaft).

    With --right IMAGES (frames of a second camera rigidly fixed to the first: a stereo
    endoscope's right view), --camera-right and --right-from-left (OpenCV's R and T of
    cv2.stereoCalibrate, e.g. extrinsics.yml, or R_right_from_left and t_right_from_left;
    T in the unit of --shaft-diameter) the right view's fulcrum is found from its own
    frames (or from its lines file: --right LINES.json, written by `pencilcal lines
    --shaft`), and the two fulcrum rays meet at the 3-D fulcrum: `stereo.triangulated`
    (left camera frame, the unit of the stereo file's T; no diameter needed). Where the
    camera files carry the intrinsics' covariance it holds their term too, in
    point_cov_total and point_sigma_total (point_cov: the noise alone). With
    --shaft-diameter too, `stereo.agreement` says whether the diameter-based point and the
    triangulated one agree within their sigmas (chi2, its dof and p; the left view's ray,
    which both hold, counted once) and `stereo.combined` is their fusion.

    Unless --endpoint-sigma is given, the sigmas hold the noise the lines show: the
    intersection's chi-square per degree of freedom scales them (segments without their
    own sigmas: estimated; shaft midlines: only ever inflated); `noise` says what was
    found. With 8 frames or more each is left out once (`jackknife`): where the fulcrum
    moves between frames far more than its sigmas say, they are raised to the jackknife's,
    with a warning. --source reads a camera or a growing video; --jsonl streams each
    frame's shafts as they are found and --overlay draws them (the fulcrum is known at the
    end only).

    From frame to frame (--track, with --workers 1) each shaft is looked for where a
    constant-velocity model of its edges predicts it, within that prediction's uncertainty,
    without the detector's proposals (one the colour found, by its colour; a full detection
    where it is not found again, and every 30th frame: an instrument entering the view):
    the same shafts, measured alike, several times faster on video; `frames_tracked` counts
    the frames tracked.

    More examples:

        pencilcal fulcrum frames/ --camera camera.yaml -o fulcrum.json
        pencilcal fulcrum left/ --camera l.yaml --right right/ --camera-right r.yaml --right-from-left extrinsics.yml -o f.json
        pencilcal fulcrum --lines l.json --camera l.yaml --right r.json --camera-right r.yaml --right-from-left s.yml -o f.json
    """
    if shaft_diameter is not None and not shaft_diameter > 0:
        raise click.BadParameter("must be positive", param_hint="--shaft-diameter")
    if sum(x is not None for x in (images, source_spec, lines_path)) != 1:
        raise click.UsageError("give IMAGES, --source or --lines (one of them)")
    if lines_path is not None and (mask_path is not None or overlay_path is not None):
        raise click.UsageError("--mask and --overlay are for frames (a lines file's lines are already found)")
    stereo = (right_images, camera_right_path, stereo_path)
    if any(x is not None for x in stereo) and not all(x is not None for x in stereo):
        raise click.UsageError("--right, --camera-right and --right-from-left go together")
    right_lines = right_images if right_images is not None and _is_lines_file(right_images) else None
    check_output(output, force, [lines_path, camera_path, angles_path, mask_path, camera_right_path, stereo_path,
                                 right_lines])
    camera = read_camera(camera_path, camera_id=camera_id)
    rig = None if stereo_path is None else read_stereo(stereo_path)
    camera_right = None if camera_right_path is None else read_camera(camera_right_path)
    source = tracker = None
    options = {"detector": detector, "gamma": gamma}
    if lines_path is not None:
        frames = read_lines(lines_path)
        if not frames:
            raise InputError(f"{lines_path}: no frames")
        with FrameOutputs(jsonl_path, None, force) as live:
            for f in frames:
                live.emit({k: v for k, v in f.items() if k != "segments"})
    else:
        source = open_input(images, source_spec, max_pixels)
        check_output(output, force, source.paths)
        from pencilcal.toolkit.detect.shaft.detector import ShaftTracker

        tracker = ShaftTracker(**options) if track and workers == 1 else None
        with FrameOutputs(jsonl_path, overlay_path, force, source=source) as live:
            frames = _shafts(source, camera, options, quiet, workers, mask_path, live, tracker)
    where = lines_path or source.description
    angles = read_angles(angles_path, [f["image"] for f in frames]) if angles_path else None

    given = click.get_current_context().get_parameter_source("endpoint_sigma") != click.core.ParameterSource.DEFAULT
    res = fulcrum_with_sigmas(camera, frames, angles, endpoint_sigma_px=endpoint_sigma if given else None,
                              shaft_diameter=shaft_diameter, where=where)
    for w in res.warnings:
        warn(w)
    out = {"camera": str(camera_path), "lines": None if lines_path is None else str(lines_path),
           "images": None if images is None else source.description, **stream_meta(source), **res.to_dict()}
    if tracker is not None:
        out["frames_tracked"] = tracker.tracked
    if rig is not None:
        out["stereo"] = _stereo(res, right_images, camera_right, camera_right_path, rig, options, endpoint_sigma,
                                given, max_pixels, workers, quiet, force)
    write_json(output, out, force=force)
    off_axis = float(np.degrees(np.arccos(np.clip(out["ray"][2], -1.0, 1.0))))
    if out["vertex_px"] is None:
        warn(f"the fulcrum lies {off_axis:.1f} deg off the optical axis, beyond the part of the field the lens "
             "model maps to pixels: fulcrum.json gives its ray, vertex_px is null")
    if not quiet:
        if rig is not None:
            st = out["stereo"]
            tri = st["triangulated"]
            views = " and ".join(tri.get("intrinsics_views", ()))
            total = f" ({tri['point_sigma_total']:.2f} with the intrinsics of the {views} camera)" \
                if "point_sigma_total" in tri else ""
            click.echo("stereo fulcrum ({:.2f}, {:.2f}, {:.2f}) +- {:.2f} (rms){}, triangulated from the right view's "
                       "{} lines".format(*tri["point"], tri["point_sigma"], total, st["right"]["lines_used"]), err=True)
            if "agreement" in st:
                a = st["agreement"]
                click.echo("diameter and stereo {}: chi2 {:.2f} ({} dof, p {:.3f}); combined ({:.2f}, {:.2f}, "
                           "{:.2f}) +- {:.2f}".format("agree" if a["consistent"] else "DISAGREE", a["chi2"], a["dof"],
                                                       a["p_value"], *st["combined"]["point"],
                                                       st["combined"]["point_sigma"]), err=True)
    done(_summary(out, off_axis, shaft_diameter, len(frames)), output, quiet=quiet)
