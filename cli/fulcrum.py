"""`pencilcal fulcrum`: the fulcrum of a pivoting instrument over a sequence."""
from __future__ import annotations

import click
import numpy as np

from pencilcal.toolkit.camera.formats import read_camera
from pencilcal.toolkit.camera.stereo import pair_frames, read_stereo
from pencilcal.toolkit.errors import EstimationError, InputError
from pencilcal.toolkit.io.files import write_json
from pencilcal.toolkit.detect.shaft.prior import epoch_priors
from pencilcal.toolkit.pencil.epochs import frame_epochs
from pencilcal.toolkit.pencil.fulcrum import read_angles
from pencilcal.toolkit.pencil.stereo_fulcrum import stereo_fulcrum
from pencilcal.toolkit.io.lines_file import read_lines
from pencilcal.validation.fulcrum_run import fulcrum_with_sigmas

from .common import (detector_option, edge_model_option, endpoint_sigma_option, gamma_option, command, camera_options, check_output, FiniteFloat, force_option, FrameOutputs, frames_region,
                     images_argument, instrument_mask_options, instrument_masks, jsonl_option, mask_option,
                     max_pixels_option, open_input, output_option, overlay_option, quiet_option, run, run_frames,
                     source_option, stream_meta, warn, warn_masks, workers_option, done)



#: The least side vote (`hand_eye.HandEye.twin_vote`) that decides a planar pivot's twin
#: without a warning: three frames in four agree.
TWIN_VOTE = 0.5

#: Passes through the epochs' priors --fulcrum-prior auto makes after its first.
AUTO_PASSES = 2


def _shaft_task(frame, ctx):
    """The shafts of one frame as a lines.json frame (module level: runs in workers too)."""
    import numpy as np

    from pencilcal.toolkit.io.images import check_image_size
    from pencilcal.toolkit.detect.lines import shaft_records
    from pencilcal.toolkit.detect.shaft.detector import detect_through

    camera, options, region, drawing, tracker, masks, priors = ctx
    if frame.image is None:
        return {"image": frame.name, "ok": False, "segments": np.zeros((0, 4)), "error": frame.error}, None
    check_image_size(frame, camera)
    if masks is not None:
        shafts = shaft_records(frame.image, camera, region, instrument_mask=masks.of(frame), **options)
    elif tracker is not None:
        shafts = [s.to_dict() for s in tracker(frame.image, camera, valid_region=region)]
    else:
        prior = None if priors is None else priors[1].get(frame.name, priors[0])
        shafts = [s.to_dict() for s in detect_through(frame.image, camera, prior if isinstance(prior, list) else [prior],
                                                      valid_region=region, **options)]
    rec = {"image": frame.name, "ok": True, "segments": np.zeros((0, 4)), "shafts": shafts,
           "error": None if shafts else "no instrument shaft found"}
    if not drawing:
        return rec, None
    from functools import partial

    from pencilcal.toolkit.draw.overlay import draw_frame

    # drawn by the overlay's own thread (`FrameOutputs`), or in the worker process
    return rec, partial(draw_frame, frame.image, shafts=shafts, text=[frame.name], scale=drawing)


def _shafts(source, camera, options, quiet, workers, mask_path, live, tracker=None, masks=None, priors=None):
    """Instrument shafts of every frame of an image source, as lines.json frames, within the
    sequence's valid region (the mask file's, or detected: `region.detect.sequence_region`);
    each frame's shafts to the live outputs as they are found (the fulcrum is known only at
    the end). options: keywords of `shaft.detector.detect_shafts` (detector, gamma); tracker: a
    `shaft.detector.ShaftTracker` (frames in order, --workers 1), or None; masks: the
    `io.instrument_masks.InstrumentMasks`, or None: the shafts are their instruments';
    priors: (default `shaft.prior.AxisPrior` or None, {image name: a prior, or a list of
    them to try in turn}) or None (`shaft.prior.read_priors`, `shaft.prior.epoch_priors`)."""
    region = frames_region(source, mask_path, shape=(camera.height, camera.width))
    frames = []
    ctx = (camera, options, region, live.drawing, tracker, masks, priors)
    for f, drawn in run_frames(source, _shaft_task, ctx, workers, "shafts", quiet):
        if f["error"]:
            warn(f"{f['image']}: {f['error']}")
        warn_masks(f)
        frames.append(f)
        live.emit({k: v for k, v in f.items() if k != "segments"}, drawn, name=f["image"])
    return frames


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
            workers, quiet, force, left_view, poses=None):
    """fulcrum.json's ``stereo`` record: the right view's fulcrum from its own shafts (a lines
    file's, or detected in its frames), its sigmas as the left view's (the noise, the jackknife), then
    `stereo_fulcrum.stereo_fulcrum` with the left's; and ``axes``, the fulcrum of the shafts' axes
    triangulated from both eyes' silhouettes (`stereo_axes.stereo_axes_from_frames`; left_view:
    (camera, frames, shaft diameter) of the left view); with `poses` (--kinematics) also
    ``robot``, the hand-eye from those axes (`hand_eye.robot_from_frames`)."""
    frames, (key, where) = _right_frames(right_images, camera_right, options, max_pixels, workers, quiet, force)

    # the right view's sigmas as the left's (the noise, the jackknife): the stereo points read both
    right = fulcrum_with_sigmas(camera_right, frames, endpoint_sigma_px=endpoint_sigma if given else None,
                                where=f"{right_images} (right view)")
    for w in right.warnings:
        warn(f"right view: {w}")
    try:  # the frames each eye took together, by their names (in order where the names say nothing)
        pairs = pair_frames([f.get("image") for f in left_view[1]], [f.get("image") for f in frames])
    except InputError as e:
        raise InputError(f"{right_images}: {e}") from None
    try:
        st = stereo_fulcrum(left, right, rig, pairs=pairs)
    except EstimationError as e:
        raise EstimationError(f"{rig.source}: {e}") from None
    rec = st.to_dict()
    rec["right"] = {key: where, "camera": str(camera_right_path), "noise": right.noise, "jackknife": right.jackknife,
                    **rec["right"]}
    from pencilcal.toolkit.pencil.stereo_axes import stereo_axes_from_frames

    try:
        rec["axes"] = stereo_axes_from_frames(left_view[0], left_view[1], camera_right, frames, rig, left_view[2],
                                              0.0 if left.point is None else left.point.width_sd)
    except EstimationError as e:
        warn(f"no fulcrum from the stereo axes: {e}")
    if poses is not None:
        from pencilcal.toolkit.pencil.hand_eye import robot_from_frames

        try:
            rec["robot"] = robot_from_frames(left_view[0], left_view[1], poses, left_view[2], stereo=(
                camera_right, frames, rig), near=rec.get("axes", {}).get("point")).to_dict()
        except EstimationError as e:
            warn(f"no hand-eye from the stereo axes: {e}")
    if "agreement" in rec and not rec["agreement"]["consistent"]:
        warn("the diameter-based and the triangulated 3-D fulcrum disagree beyond their sigmas (chi2 {:.1f}, {} dof, "
             "p {:.2g}): check the shaft diameter and the stereo file's unit".format(
                 rec["agreement"]["chi2"], rec["agreement"]["dof"], rec["agreement"]["p_value"]))
    return rec


def _robot(camera, frames, poses, shaft_diameter, point):
    """fulcrum.json's ``robot`` record (`hand_eye.robot_from_frames`), with warnings for
    raised sigmas and a disagreement."""
    from pencilcal.toolkit.pencil.hand_eye import robot_from_frames

    rec = robot_from_frames(camera, frames, poses, shaft_diameter, near=point).to_dict()
    if rec["frames_without_axis"]:
        warn(f"{poses.source}: {rec['frames_without_axis']} frame(s) with a tool pose have no shaft with a 3-D axis")
    if rec["variance_factor"] > 1.0:
        warn(f"the hand-eye's residuals are {rec['chi2_dof']:.3g} times what the axes' sigmas say (the axes' or the "
             "kinematics' errors are larger): its covariance is raised by that factor")
    left = [r["image"] for r in rec["residuals"] if not r["used"]]
    if left:
        warn(f"the hand-eye left out {len(left)} frame(s) whose shaft does not match the tool pose: "
             + ", ".join(map(str, left[:5])) + (" ..." if len(left) > 5 else ""))
    if rec["twin_by"] == "sides" and not rec["twin_vote"] >= TWIN_VOTE:
        warn(f"the shaft's axes lie in one plane: the transform and its mirror image (a half turn about the plane's "
             f"normal) fit alike, and the side of the fulcrum the camera sees the shaft on decides it only weakly "
             f"(vote {rec['twin_vote']:.2f} of 1): pivot the tool out of that plane too")
    a = rec["agreement"]
    if not a["consistent"]:
        warn(f"the robot's remote centre of motion and the camera's fulcrum disagree by {a['distance']:.3g} mm (chi2 "
             f"{a['chi2']:.1f}, {a['dof']} dof, p {a['p_value']:.2g}): the tool axis, the pairing of poses and "
             "frames, or the shaft diameter")
    return rec


def _epoch_robots(camera, frames, poses, shaft_diameter, epochs):
    """Each pivot epoch's ``robot`` record (the camera or the arm moved between epochs: each
    has its own transform), or ``{"ok": false, "error"}`` where its frames do not fix one."""
    from pencilcal.toolkit.pencil.hand_eye import robot_from_frames

    if len(epochs) < 2:
        return
    for ep in epochs:
        try:
            ep["robot"] = robot_from_frames(camera, frames[ep["first"]:ep["last"] + 1], poses, shaft_diameter,
                                            near=ep.get("point"), first=ep["first"]).to_dict()
        except EstimationError as e:
            ep["robot"] = {"ok": False, "error": str(e)}


def _robot_line(rec):
    """The summary line of the ``robot`` record."""
    a = rec["agreement"]
    verdict = ("is the camera's fulcrum (the transform is fixed by it: no check left)" if a["dof"] == 0 else
               "{} the camera's fulcrum".format("agrees with" if a["consistent"] else "DISAGREES with"))
    return ("robot: remote centre ({:.1f}, {:.1f}, {:.1f}) +- {:.2g} mm (base frame); camera from base +- {:.2g} deg, "
            "{:.2g} mm from {} of {} frames; in the camera frame it {} ({:.2g} mm, chi2 {:.1f}, {} dof)").format(
        *rec["fulcrum_base_mm"], rec["fulcrum_base_sigma_mm"], rec["rotation_sigma_deg"], rec["translation_sigma_mm"],
        rec["frames_used"], rec["frames_paired"], verdict, a["distance"], a["chi2"], a["dof"])


def _auto_priors(source, camera, options, quiet, workers, mask_path, tracker, force):
    """(priors, frames) of --fulcrum-prior auto: a first pass without a prior, its pivot
    epochs and each one's prior (`shaft.prior.epoch_priors`), then `AUTO_PASSES` passes,
    each through the epochs and priors of the shafts the one before found (their lines are
    the better ones): the last pass's priors, (None, {image name: [priors to try in
    turn]}), and its frames."""
    with FrameOutputs(None, None, force) as silent:
        frames = _shafts(source, camera, options, quiet, workers, mask_path, silent, tracker)
    for _ in range(AUTO_PASSES):
        priors = (None, epoch_priors(camera, frames, frame_epochs(camera, frames).bounds))
        if all(p == [None] for p in priors[1].values()):
            raise EstimationError(f"{source.description}: --fulcrum-prior auto: no pivot epoch of the frames has a "
                                  "fulcrum to search the shafts by")
        with FrameOutputs(None, None, force) as silent:
            frames = _shafts(source, camera, options, quiet, workers, mask_path, silent, None, priors=priors)
    return priors, frames


def _epochs(camera, frames, angles, endpoint_sigma, shaft_diameter):
    """fulcrum.json's ``epoch_test`` and ``epochs`` (when the fulcrum moved) records, with a
    warning naming the epochs (`fulcrum_run.fulcrum_epochs`); each epoch's ``axis_prior``
    estimated from its frames (`shaft.prior.fulcrum_prior`)."""
    from pencilcal.toolkit.detect.shaft.prior import fulcrum_prior
    from pencilcal.validation.fulcrum_run import epochs_record, fulcrum_epochs

    ep, results = fulcrum_epochs(camera, frames, angles, endpoint_sigma_px=endpoint_sigma,
                                 shaft_diameter=shaft_diameter)
    names = [f["image"] for f in frames]
    used = None
    if len(ep.bounds) > 1:
        used = [fulcrum_prior(camera, frames[a:b]) for a, b in ep.bounds]
        spans = ", ".join(f"{names[a]}-{names[b - 1]}" for a, b in ep.bounds)
        warn(f"the fulcrum moved: {len(ep.bounds)} pivot epochs ({spans}; change points " + ", ".join(
            f"at {names[c.index]} (F {c.statistic:.1f}, p {c.p_corrected:.2g})" for c in ep.changes)
             + "): each epoch's fulcrum is in 'epochs', the one of all frames at the top")
    return epochs_record(ep, results, names, used)


def _check_usage(o):
    """Usage errors of the fulcrum command's options (o: its keyword arguments by name)."""
    if o["shaft_diameter"] is not None and not o["shaft_diameter"] > 0:
        raise click.BadParameter("must be positive", param_hint="--shaft-diameter")
    if o["kinematics_path"] is not None and o["shaft_diameter"] is None:
        raise click.UsageError("--kinematics needs --shaft-diameter (the shaft's 3-D axes)")
    if sum(o[k] is not None for k in ("images", "source_spec", "lines_path")) != 1:
        raise click.UsageError("give IMAGES, --source or --lines (one of them)")
    if o["lines_path"] is not None and any(o[k] is not None for k in ("mask_path", "overlay_path", "instrument_mask",
                                                                        "prior_spec")):
        raise click.UsageError("--mask, --instrument-mask, --overlay and --fulcrum-prior are for frames (a lines "
                               "file's lines are already found)")
    if o["stabilize"] and (o["images"] is None or o["right_images"] is not None):
        raise click.UsageError("--stabilize measures the camera's motion on IMAGES (not --source or --lines), one "
                               "view (not --right)")
    if o["instrument_mask"] is not None and o["prior_spec"] is not None:
        raise click.UsageError("--instrument-mask gives the shafts: --fulcrum-prior is for detecting them")
    if o["prior_spec"] == "auto" and o["source_spec"] is not None:
        raise click.UsageError("--fulcrum-prior auto reads the frames twice: give IMAGES, not --source")
    stereo = (o["right_images"], o["camera_right_path"], o["stereo_path"])
    if any(x is not None for x in stereo) and not all(x is not None for x in stereo):
        raise click.UsageError("--right, --camera-right and --right-from-left go together")


#: Above this departure from a turn (`background_motion.FrameMotion.non_rotation`) the 3-D
#: axes of --stabilize are warned about where no 3-D pose carries them.
TURN_ONLY = 0.05


def _point_epochs(camera, frames, shaft_diameter):
    """fulcrum.json's ``point_epoch_test`` (and ``point_epochs`` where the 3-D fulcrum moved)
    of --stabilize with poses (`fulcrum_run.point_epochs_record`), with a warning naming
    the 3-D epochs."""
    from pencilcal.validation.fulcrum_run import point_epochs_record

    names = [f["image"] for f in frames]
    try:
        test, epochs = point_epochs_record(camera, frames, shaft_diameter, names)
    except EstimationError as e:
        warn(f"--stabilize: no change-point test on the 3-D axes: {e}")
        return {}
    if test is None:
        return {}
    if epochs:
        warn(f"the 3-D fulcrum moved: {len(epochs)} epochs of the carried axes ("
             + ", ".join(f"{e['images'][0]}-{e['images'][-1]}" for e in epochs)
             + "): each one's 3-D fulcrum is in 'point_epochs', the one of all frames at the top")
    return {"point_epoch_test": test, **({"point_epochs": epochs} if epochs else {})}


def _stabilized(source, camera, frames, mask_path, shaft_diameter):
    """(frames with their lines in the reference frame, fulcrum.json's ``stabilize``
    record) of --stabilize: the background's homography of every frame to the middle one
    (`background_motion.background_motion`), the shafts mapped by it
    (`background_motion.stabilize_frames`); with `shaft_diameter` every frame's 3-D pose in
    the middle one's camera too (`background_motion.background_motion_3d`), by which the
    3-D axes are carried; a warning for the frames it could not measure."""
    from pencilcal.toolkit.detect.background_motion import (background_motion, background_motion_3d,
                                                            stabilize_frames)

    shape = (camera.height, camera.width)
    region = frames_region(source, mask_path, shape=shape)
    valid = None if region is None else region.mask(shape)
    names = [f["image"] for f in frames]

    def images():  # read again in the order the shafts were found: only their features are kept
        for fr, name in zip(source, names):
            if fr.name != name:
                raise InputError(f"{source.description}: the frames changed while read ({fr.name}, was {name})")
            yield fr.image

    shafts = [f.get("shafts") or [] for f in frames]
    model = anchor = None
    if shaft_diameter is None:
        ref, motions = background_motion(images(), shafts, camera, valid)
    else:
        ref, motions, model, anchor = background_motion_3d(images(), shafts, camera, valid)
    bad = [n for n, m in zip(names, motions) if not m.ok]
    if bad:
        warn(f"--stabilize: the camera's motion is not measured in {len(bad)} frame(s), their lines left out: "
             + ", ".join(map(str, bad[:5])) + (" ..." if len(bad) > 5 else ""))
    ok = [m for m in motions if m.ok]
    unposed = [n for n, m in zip(names, motions) if m.ok and m.pose is None]
    if model is not None and unposed:
        warn(f"--stabilize: the camera's 3-D pose is not measured in {len(unposed)} frame(s), their shafts give no "
             "3-D axis: " + ", ".join(map(str, unposed[:5])) + (" ..." if len(unposed) > 5 else ""))
    worst = max([m.non_rotation for m in ok] or [0.0])
    if model == "rotation" and worst > TURN_ONLY:
        warn(f"--stabilize: the camera moved by more than a turn (its homography departs up to {worst:.2f} from "
             "one) but no frame saw the background with the parallax to measure it: the 3-D axes are only turned "
             "into the reference frame, the 3-D fulcrum is not exact")
    rec = {"model": "homography", "reference": names[ref], "frames_measured": len(ok),
           "median_rms_px": float(np.median([m.rms_px for m in ok if m is not motions[ref]] or [0.0])),
           "max_shift_px": float(max([m.shift_px for m in ok] or [0.0])),
           "frames": [{**m.to_dict(), "image": n, **({} if m.via is None else {"via": names[m.via]})}
                      for n, m in zip(names, motions)]}
    if model is not None:
        rec.update(pose_model=model, pose_anchor=None if anchor is None else names[anchor],
                   frames_posed=sum(1 for m in ok if m.pose is not None))
    return stabilize_frames(camera, frames, motions), rec


@command()
@images_argument(required=False)
@source_option
@click.option("--lines", "lines_path", type=click.Path(dir_okay=False), default=None,
              help="lines.json, instead of IMAGES.")
@camera_options
@click.option("--angles", "angles_path", type=click.Path(dir_okay=False), default=None,
              help="Pivot angles (CSV): the pivot plane too.")
@click.option("--shaft-diameter", type=FiniteFloat(), default=None, metavar="D",
              help="Shaft diameter [mm]: the 3-D fulcrum too.")
@click.option("--kinematics", "kinematics_path", type=click.Path(dir_okay=False), default=None, metavar="CSV",
              help="Robot tool poses: the hand-eye too.")
@click.option("--right", "right_images", default=None, metavar="IMAGES|LINES",
              help="Stereo right view (frames or lines.json).")
@click.option("--camera-right", "camera_right_path", type=click.Path(dir_okay=False), default=None,
              help="Camera file of the --right view.")
@click.option("--right-from-left", "stereo_path", type=click.Path(dir_okay=False), default=None, metavar="FILE",
              help="Stereo calibration (OpenCV's R, T).")
@endpoint_sigma_option("End point noise [px] of segments without their own sigma.")
@detector_option("Shaft proposals' detector.")
@gamma_option
@edge_model_option
@click.option("--fulcrum-prior", "prior_spec", default=None, metavar="FILE|auto",
              help="Shafts through the fulcrum's image: FILE (fulcrum.json, ray); auto: estimated.")
@click.option("--stabilize", is_flag=True,
              help="Lines freed of the camera's motion.")
@click.option("--track/--no-track", default=True, show_default=True,
              help="Find the shafts where the previous frames predict them (--workers 1).")
@instrument_mask_options
@mask_option
@jsonl_option
@overlay_option
@max_pixels_option
@workers_option
@output_option
@force_option
@quiet_option
@run
def fulcrum(images, source_spec, lines_path, camera_path, camera_id, angles_path, shaft_diameter, kinematics_path,
            right_images,
            camera_right_path, stereo_path, endpoint_sigma, detector, gamma, edge_model, prior_spec, stabilize, track,
            instrument_mask,
            mask_labels, mask_instances, mask_path, jsonl_path, overlay_path, overlay_scale, max_pixels, workers, output,
            force, quiet):
    """The fulcrum of an instrument pivoting about its entry port.

    \b
    Examples:
      pencilcal fulcrum frames/ --camera cam.yaml --shaft-diameter 8 -o f.json
      pencilcal fulcrum --lines l.json --camera cam.yaml --angles a.csv -o f.json

    Shafts from IMAGES (files, folders, globs in the order given, a video),
    --source or --lines: the fulcrum's image and ray; its 3-D point [mm] with
    --shaft-diameter. In detail: docs/cli.md.
    \f
    Every frame's instrument line passes through the fulcrum's image: their robust weighted
    intersection gives the fulcrum's viewing ray and, where the lens model reaches it (a
    port far off axis may lie beyond), its raw pixel and covariance. From IMAGES the
    instrument shafts are detected in every frame (their midlines are the axis images),
    never on the boundary of the frames' valid region (--mask, or detected once from up to
    16 frames); or, with --instrument-mask MASKS, they are the axes of the masks'
    instruments refined on the image (as `lines --shaft --instrument-mask`); or the lines
    come from a lines file (--lines; its shaft midlines are used when present). With
    --angles (a CSV of image,angle_deg, or one pivot angle per frame) the lines form a
    pencil with known angles and the orientation of the pivot plane comes out too, with the
    keys of orientation.json.

    With --shaft-diameter D (e.g. 8 for an 8 mm instrument; lengths then come out in D's
    unit, mm as the board and pencil files have them) every shaft's two silhouette edges
    give its 3-D axis (the band's width fixes its depth), and the fulcrum is also the
    robust weighted least-squares point closest to all the axes: point [x, y, z] (camera
    frame), point_cov, point_sigma (the RMS 3-D error its covariance predicts, the edges'
    width error that one sequence shares included: point_width_sd, its relative sd of the
    depth; with the intrinsics' covariance in the camera file also point_cov_total and
    point_sigma_total), and the axes that pass far from it named in point_outliers. Its lines must be shafts
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
    triangulated one agree within their sigmas (chi2, its dof and p; across the line of
    sight both hold the left view's ray: one error) and `stereo.combined` is their
    fusion, as sure as either point or surer unless they disagree. And every frame's
    shafts are matched between the two views (frames paired by image name, else in order)
    and each shaft's 3-D axis triangulated from its four silhouette edges, two per view
    (each edge's plane touches the cylinder: axis and radius by least squares, the radius
    held to --shaft-diameter where given): `stereo.axes` is the fulcrum of those axes
    (point, point_cov, point_sigma, the axes used of those matched, the radius), its
    covariance widened by noise_factor and play_sigma where the axes miss one point by more
    than their sigmas say (edges noisier than said, the port's play), with the rig's error in it where the stereo file gives
    cov_right_from_left (6x6: the rotation vector's error [rad], then the translation's).

    --edge-model limb locates each shaft's two edges by a profile model of a cylinder lit
    from the endoscope (it darkens towards its silhouette, so the step edge of the default
    lies inside it, narrowing the band and putting the 3-D axis too far): background level
    and slope, diffuse and specular shading of the angle to the camera, the optics' blur,
    fitted across each edge (docs/method.md). It costs seconds a frame.

    Unless --endpoint-sigma is given, the sigmas hold the noise the lines show: the
    intersection's chi-square per degree of freedom scales them (segments without their
    own sigmas: estimated; shaft midlines: only ever inflated); `noise` says what was
    found; the 3-D point's covariance likewise takes its axes' chi2 per degree of freedom
    (``point_variance_factor``). With 8 frames or more each is left out once
    (`jackknife`): where the fulcrum moves between frames far more than its sigmas say,
    they are raised to the jackknife's, with a warning (not judged for a 3-D point that
    uses the axes of fewer than 4 frames). --source reads a camera or a growing video; --jsonl streams each
    frame's shafts as they are found and --overlay draws them (the fulcrum is known at the
    end only).

    With --kinematics CSV, the tool's pose in the robot base per frame as the dVRK
    publishes it (docs/formats.md; with --shaft-diameter), every frame's shaft axis is
    paired with the robot's (the tool frame's z axis through its origin), and ``robot`` holds the
    camera-to-robot transform (hand-eye: R_cam_from_base, t_cam_from_base_mm and the
    inverse, each with its 6x6 covariance), the remote centre of motion in the base frame
    (fulcrum_base_mm, its covariance) and whether it agrees, carried into the camera frame,
    with the camera's own fulcrum within their sigmas (docs/method.md); each pivot
    epoch's in ``epochs`` too; with --right also ``stereo.robot`` from the axes both eyes
    triangulate.

    Where the fulcrum moved (the arm re-set, the port slipped, the camera moved), a
    change-point test on the lines splits the frames into pivot epochs: ``epoch_test`` says
    where and why, ``epochs`` holds each one's fulcrum (docs/method.md). --fulcrum-prior
    searches every frame's shaft through its epoch's fulcrum image, at most one a frame:
    FILE a fulcrum.json (each epoch's prior for its images) or a file with ray and ray_cov
    (robot kinematics) or vertex_px and vertex_cov_px2; auto: a first pass, then two
    through its epochs' priors.

    Where the camera moves (--stabilize; IMAGES, one view), its motion is measured on the
    background: per frame a homography to the middle frame from SIFT matches off the
    instrument (RANSAC, then least squares with its covariance), exact for a camera turning
    about its centre or a flat background; each frame's shafts are mapped into the middle
    frame's image, their sigmas with the homography's, before the fulcrum and the epochs
    are fitted; ``stabilize`` holds each frame's homography, its covariance and residual
    (docs/method.md). A frame whose motion is not measured gives no line. With
    --shaft-diameter each frame's 3-D pose in the middle frame's camera is measured from
    the same matches too (a map of the background, PnP, a bundle adjustment with its
    covariance; ``stabilize.frames[].pose``) and every frame's 3-D axis is carried into
    the middle frame's camera by it, the translations' unit fitted with the 3-D fulcrum
    (``point_camera_motion``): the 3-D point is then in the middle frame's camera, and a
    change-point test on the carried 3-D axes (``point_epoch_test``) splits the frames
    where the 3-D fulcrum moved (``point_epochs``: each one's 3-D fulcrum).

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
    _check_usage(locals())
    right_lines = right_images if right_images is not None and _is_lines_file(right_images) else None
    prior_file = prior_spec if prior_spec not in (None, "auto") else None
    check_output(output, force, [lines_path, camera_path, angles_path, mask_path, camera_right_path, stereo_path,
                                 right_lines, prior_file, kinematics_path])
    camera = read_camera(camera_path, camera_id=camera_id)
    poses = None
    if kinematics_path is not None:
        from pencilcal.toolkit.io.tool_poses import read_tool_poses

        poses = read_tool_poses(kinematics_path)
    priors = None
    if prior_file is not None:
        from pencilcal.toolkit.detect.shaft.prior import read_priors

        priors = read_priors(prior_file, camera)
    rig = None if stereo_path is None else read_stereo(stereo_path)
    camera_right = None if camera_right_path is None else read_camera(camera_right_path)
    source = tracker = None
    options = {"detector": detector, "gamma": gamma, "edge_model": edge_model}
    if lines_path is not None:
        frames = read_lines(lines_path)
        if not frames:
            raise InputError(f"{lines_path}: no frames")
        with FrameOutputs(jsonl_path, None, force) as live:
            for f in frames:
                live.emit({k: v for k, v in f.items() if k != "segments"})
    else:
        source = open_input(images, source_spec, max_pixels)
        masks = instrument_masks(source, instrument_mask, mask_labels, mask_instances)
        check_output(output, force, [*source.paths, *(masks.paths.values() if masks else ())])
        from pencilcal.toolkit.detect.shaft.detector import ShaftTracker

        tracker = ShaftTracker(**options) if track and workers == 1 and masks is None and priors is None else None
        frames = None
        if prior_spec == "auto":
            priors, frames = _auto_priors(source, camera, options, quiet, workers, mask_path, tracker, force)
            tracker = None
        if frames is None or jsonl_path is not None or overlay_path is not None:
            with FrameOutputs(jsonl_path, overlay_path, force, source=source, scale=overlay_scale) as live:
                frames = _shafts(source, camera, options, quiet, workers, mask_path, live, tracker, masks, priors)
    where = lines_path or source.description
    motion = None
    if stabilize:
        frames, motion = _stabilized(source, camera, frames, mask_path, shaft_diameter)
    angles = read_angles(angles_path, [f["image"] for f in frames]) if angles_path else None

    given = click.get_current_context().get_parameter_source("endpoint_sigma") != click.core.ParameterSource.DEFAULT
    res = fulcrum_with_sigmas(camera, frames, angles, endpoint_sigma_px=endpoint_sigma if given else None,
                              shaft_diameter=shaft_diameter, where=where)
    epoch_test, epochs = _epochs(camera, frames, angles, endpoint_sigma if given else None, shaft_diameter)
    for w in res.warnings:
        warn(w)
    out = {"camera": str(camera_path), "lines": None if lines_path is None else str(lines_path),
           "images": None if images is None else source.description, **stream_meta(source), **res.to_dict()}
    if instrument_mask is not None:
        out["instrument_mask"] = str(instrument_mask)
    if tracker is not None:
        out["frames_tracked"] = tracker.tracked
    from pencilcal.toolkit.detect.shaft.prior import fulcrum_prior, prior_record

    whole = fulcrum_prior(camera, frames, endpoint_sigma if given else None)
    if whole is not None:
        out["axis_prior"] = prior_record(whole)
    out["epoch_test"] = epoch_test
    if len(epochs) > 1:
        out["epochs"] = epochs
    if priors is not None:
        out["fulcrum_prior"] = prior_spec
    if motion is not None:
        out["stabilize"] = motion
        if shaft_diameter is not None and motion.get("pose_model") == "map":
            out.update(_point_epochs(camera, frames, shaft_diameter))
    if rig is not None:
        out["stereo"] = _stereo(res, right_images, camera_right, camera_right_path, rig, options, endpoint_sigma,
                                given, max_pixels, workers, quiet, force, (camera, frames, shaft_diameter), poses)
    if poses is not None:
        out["robot"] = _robot(camera, frames, poses, shaft_diameter, out.get("point"))
        _epoch_robots(camera, frames, poses, shaft_diameter, epochs)
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
            if "axes" in st:
                ax = st["axes"]
                click.echo("stereo axes fulcrum ({:.2f}, {:.2f}, {:.2f}) +- {:.2f} (rms{}) from {} of {} shafts matched "
                           "between the eyes in {} frame pairs, radius {:.3f} +- {:.3f}".format(
                               *ax["point"], ax["point_sigma"], ", the rig's covariance in" if ax["rig_used"] else "",
                               ax["axes_used"], ax["axes"], ax["frames"], ax["radius"], ax["radius_sigma"]), err=True)
            if "robot" in st:
                click.echo("stereo axes' " + _robot_line(st["robot"]), err=True)
            if "agreement" in st:
                a = st["agreement"]
                click.echo("diameter and stereo {}: chi2 {:.2f} ({} dof, p {:.3f}); combined ({:.2f}, {:.2f}, "
                           "{:.2f}) +- {:.2f}".format("agree" if a["consistent"] else "DISAGREE", a["chi2"], a["dof"],
                                                       a["p_value"], *st["combined"]["point"],
                                                       st["combined"]["point_sigma"]), err=True)
        if "robot" in out:
            click.echo(_robot_line(out["robot"]), err=True)
    done(_summary(out, off_axis, shaft_diameter, len(frames)), output, quiet=quiet)
