"""`pencilcal pnp`: board pose per frame, refined in raw pixels, with covariance."""
from __future__ import annotations

import click
import numpy as np

from pencilcal.toolkit.board.calibration_file import camera_with_report, read_calibration_file, \
    symmetric_corners_of, uncertainty_record
from pencilcal.toolkit.board.spec import read_board
from pencilcal.toolkit.camera.formats import read_camera
from pencilcal.toolkit.board.detect import detect_board
from pencilcal.toolkit.errors import EstimationError
from pencilcal.toolkit.io.images import check_image_size
from pencilcal.validation.pnp import (
    DEFAULT_MAX_RMS_PX,
    DEFAULT_METHOD,
    METHODS,
    best_method,
    board_points,
    empty_frame_record,
    estimate_all,
    estimate_pose,
    frame_record,
    write_poses,
)

from .common import (command, FiniteFloat, FrameOutputs, camera_options, check_output, force_option, images_argument,
                     jsonl_option, max_pixels_option, open_input, output_option, overlay_option, quiet_option, run,
                     run_frames, source_option, stream_meta, warn, workers_option, done)

_MIN_CORNERS_FLOOR = 4


def _pnp_task(frame, ctx):
    """(poses.json record, warnings, the frame drawn or None) of one frame (module level:
    runs in worker processes too; the warnings are printed by the parent, in frame order)."""
    camera, board, method, refine, corner_sigma, max_rms, min_corners, drawing = ctx
    rec, warnings, det = _pnp_frame(frame, camera, board, method, refine, corner_sigma, max_rms, min_corners)
    if not drawing or frame.image is None:
        return rec, warnings, None
    from functools import partial

    from pencilcal.toolkit.draw.overlay import draw_pose

    length = 3.0 * board.square
    # drawn by the overlay's own thread (`FrameOutputs`), or in the worker process
    drawn = partial(draw_pose, frame.image, camera, rec.get("R_cam_from_target") if rec["ok"] else None,
                    rec.get("t_cam_from_target"), length, None if det is None else det.corners, scale=drawing)
    return rec, warnings, drawn


def _pnp_frame(frame, camera, board, method, refine, corner_sigma, max_rms, min_corners):
    """(record, warnings, board detection or None) of one frame."""
    label = "all" if method == "all" else method
    if frame.image is None:
        return empty_frame_record(frame.name, frame.error, method=label), [f"{frame.name}: {frame.error}"], None
    check_image_size(frame, camera)
    # the corners found as the camera's calibration found them (its corner-noise model's)
    det = detect_board(frame.image, board, symmetric_corners_of(camera))
    if det.count < min_corners:
        err = "no board corners found" if det.count == 0 else \
            f"only {det.count} board corners found (--min-corners {min_corners})"
        return (empty_frame_record(frame.name, err, method=label, corners=det.count, ids=det.ids),
                [f"{frame.name}: {err}"], det)
    X, warp = board_points(board, camera, det.ids)
    warnings = []
    if method == "all":
        results = estimate_all(X, det.corners, camera, refine=refine, corner_sigma_px=corner_sigma,
                               max_rms_px=max_rms, board_warp=warp)
        best = best_method(results)
        rec = frame_record(frame.name, results[best or DEFAULT_METHOD], ids=det.ids, methods=results)
        if best is None:
            rec["error"] = "no method gave a pose: " + "; ".join(r.error for r in results.values())
        else:
            warnings += [f"{frame.name}: {r.error}" for r in results.values() if not r.ok]
    else:
        res = estimate_pose(X, det.corners, camera, method, refine=refine, corner_sigma_px=corner_sigma,
                            max_rms_px=max_rms, board_warp=warp)
        rec = frame_record(frame.name, res, ids=det.ids)
    if not rec["ok"]:
        warnings.append(f"{frame.name}: {rec['error']}")
    return rec, warnings, det


@command()
@images_argument(required=False)
@camera_options
@click.option("--board", "board_path", required=True, type=click.Path(dir_okay=False),
              help="Board file (.yaml/.json): charuco or chessboard; its unit is the output's.")
@output_option
@click.option("--method", type=click.Choice(METHODS + ("all",)), default=DEFAULT_METHOD, show_default=True,
              help="PnP initialiser, refined in raw pixels; all: every method.")
@click.option("--corner-sigma", type=FiniteFloat(), default=None,
              help="Corner noise [px]; default: from each frame's residuals.")
@click.option("--min-corners", type=int, default=6, show_default=True,
              help="Frames with fewer corners get no pose (at least 4).")
@click.option("--max-rms", type=FiniteFloat(), default=DEFAULT_MAX_RMS_PX, show_default=True,
              help="Reject a pose whose reprojection RMS exceeds this [px].")
@click.option("--refine/--no-refine", default=True, show_default=True,
              help="Refine every method's pose on the raw-pixel error.")
@click.option("--calibration", "calib_path", type=click.Path(dir_okay=False), default=None,
              help="calib.json (calibrate --report): the intrinsics' share of cov_total.")
@source_option
@max_pixels_option
@jsonl_option
@overlay_option
@workers_option
@force_option
@quiet_option
@run
def pnp(images, camera_path, camera_id, board_path, output, method, corner_sigma, min_corners, max_rms, refine,
        calib_path, source_spec, max_pixels, jsonl_path, overlay_path, overlay_scale, workers, force, quiet):
    """Pose of a calibration board in every frame (poses.json).

    \b
    Examples:
      pencilcal pnp images/ --camera cam.yaml --board board.yaml -o poses.json
      pencilcal pnp 'shots/*.png' --camera c.json --board b.yaml --method all

    IMAGES: files, folders or globs in the order given, or a video; or --source. Per
    frame R_cam_from_target, t_cam_from_target and their 6x6 covariance. In detail:
    docs/cli.md.
    \f
    IMAGES is one or more image files, folders or glob patterns, in the order given, or
    one video; or --source: a camera, a URL, a video file being written. Detects the
    board's corners (ChArUco or chessboard; ChArUco corners refined to their point of
    symmetry where the camera file records a calibration made so, `calibrate
    --symmetric-corners`), estimates R_cam_from_target and t_cam_from_target (length unit
    of the board file) with the chosen method, refines it
    (Levenberg-Marquardt, unless --no-refine) on the reprojection error in raw pixels under
    the full lens model, and writes the 6x6 covariance (rotation first: rad about the
    camera axes, left perturbation; then translation). --method all runs every method and
    keeps each under `methods` (the frame-level pose is sqpnp's unless another reached a
    lower RMS). The covariance holds the corner noise (--corner-sigma, or estimated from
    each frame's residuals); with --calibration (calib.json of `pencilcal calibrate
    --report`; default: what the camera file carries, if anything) also the intrinsics'
    covariance and the correlated corner-noise model, in cov_total. Where the camera
    file records the warp its calibration measured on this same board, the poses are of
    the warped board and cov_total holds the warp's sigma. A pose whose RMS
    exceeds --max-rms (a wrong local minimum or a wrong camera) is rejected. Frames that
    cannot be decoded or show too little of the board (fewer than --min-corners corners)
    are written with ok: false and a warning.
    """
    if corner_sigma is not None and not corner_sigma > 0:
        raise click.BadParameter("must be a positive number of pixels", param_hint="--corner-sigma")
    if min_corners < _MIN_CORNERS_FLOOR:
        raise click.BadParameter(f"must be at least {_MIN_CORNERS_FLOOR}", param_hint="--min-corners")
    if not max_rms > 0:
        raise click.BadParameter("must be a positive number of pixels", param_hint="--max-rms")
    check_output(output, force)
    camera = read_camera(camera_path, camera_id=camera_id)
    if calib_path:
        camera = camera_with_report(camera, read_calibration_file(calib_path), str(camera_path))
    board = read_board(board_path)
    source = open_input(images, source_spec, max_pixels)
    check_output(output, force, [*source.paths, camera_path, board_path])
    label = "all" if method == "all" else method
    records = []
    with FrameOutputs(jsonl_path, overlay_path, force, source=source, scale=overlay_scale) as live:
        ctx = (camera, board, method, refine, corner_sigma, max_rms, min_corners, live.drawing)
        for rec, warnings, drawn in run_frames(source, _pnp_task, ctx, workers, "pnp", quiet):
            for w in warnings:
                warn(w)
            records.append(rec)
            live.emit(rec, drawn)
    meta = {
        "method": label,
        "methods": list(METHODS) if method == "all" else [method],
        "refine": bool(refine),
        "images": source.description,
        "camera": str(camera_path),
        "camera_model": camera.model,
        "image_size": [camera.width, camera.height],
        "board": str(board_path),
        "board_spec": board.to_dict(),
        "symmetric_corners": symmetric_corners_of(camera),
        "corner_sigma_px": corner_sigma,
        "min_corners": min_corners,
        "max_rms_px": max_rms,
        **uncertainty_record(camera, calib_path or camera_path),
        **stream_meta(source),
    }
    n_ok = sum(r["ok"] for r in records)
    if n_ok == 0:
        # a run with no pose at all failed: say so and leave nothing that looks like a result
        raise EstimationError(f"{source.description}: no frame gave a pose (is the board file right for these images?)")
    write_poses(output, records, force=force, **meta)
    rms = [r.get("reproj_rms_px") for r in records if r.get("ok") and r.get("reproj_rms_px") is not None]
    sig = [r.get("normal_sigma_deg") for r in records if r.get("ok") and r.get("normal_sigma_deg") is not None]
    done(f"{n_ok}/{len(records)} frames with a pose" + (f": reprojection RMS {np.median(rms):.2g} px median" if rms else "")
         + (f", normal sigma {np.median(sig):.2g} deg median" if sig else ""), output, quiet=quiet)
