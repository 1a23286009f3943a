"""`pencilcal calibrate`: intrinsic calibration from ChArUco or chessboard views."""
from __future__ import annotations

import os
import tempfile
from pathlib import Path

import click
import numpy as np

from pencilcal.toolkit.board.spec import read_board
from pencilcal.toolkit.board.calibrate import AUTO, MODELS
from pencilcal.toolkit.board.calibration_file import write_calibration_file
from pencilcal.toolkit.board.model_choice import CANDIDATES, SPLINED
from pencilcal.toolkit.camera.model import Camera
from pencilcal.toolkit.camera.splined import splined_name
from pencilcal.toolkit.camera.formats import camera_format, write_camera
from pencilcal.toolkit.board.corners_cache import check_image_name, write_corners_vnl
from pencilcal.toolkit.board.detect import detect_board
from pencilcal.toolkit.errors import InputError
from pencilcal.toolkit.io.files import atomic_paths
from pencilcal.toolkit.io.images import open_images
from pencilcal.validation.calibration_report import write_calibration_report
from pencilcal.validation.calibration_checks import RANDOM_HALVES
from pencilcal.validation.calibration_run import calibrate_checked

from .common import (command, check_output, done, force_option, images_argument, max_pixels_option, quiet_option, run,
                     run_frames, warn, workers_option)

_CAMERA_SUFFIXES = (".json", ".yaml", ".yml", ".xml", ".cameramodel", ".txt", ".bin")


def _probe_camera_format(path, model, coefficients):
    """Fail before any work if the camera file format cannot hold this model (e.g. a
    fisheye as .cameramodel, 14 coefficients as COLMAP): write a dummy camera of the same
    kind to a scratch file with the same name."""
    p = Path(path)
    if p.suffix.lower() not in _CAMERA_SUFFIXES:
        raise InputError(f"{p}: unknown camera file type {p.suffix or '(none)'!r}; expected "
                         f"{', '.join(_CAMERA_SUFFIXES)} (.txt/.bin: COLMAP cameras file)")
    camera_format(p)
    if model == SPLINED:
        model, coefficients = splined_name(4, 4, 90), 32
    n = {"pinhole": 0, "fisheye": 4}.get(model, coefficients)
    dummy = Camera(model, 640, 480, [[500.0, 0, 319.5], [0, 500.0, 239.5], [0, 0, 1]], np.zeros(n))
    with tempfile.TemporaryDirectory(prefix="pencilcal-probe-") as d:
        try:
            write_camera(Path(d) / p.name, dummy)
        except InputError as e:
            msg = str(e).split(": ", 1)[-1]
            raise InputError(f"{p}: {msg}") from None


def _vnl_name(path, name, corners_path, kind):
    """The image name mrcal should find: its path relative to the folder of corners.vnl
    (video frames keep their frame name)."""
    if kind != "images" or not path:
        return name
    base = Path(corners_path).resolve().parent
    return Path(os.path.relpath(Path(path).resolve(), base)).as_posix()


def _detect_task(frame, ctx):
    """(frame without its image, (width, height) or None, detection) for one frame; ctx:
    (board, symmetric); module level, so it runs in worker processes too, and images never
    travel back."""
    from pencilcal.toolkit.io.images import Frame

    light = Frame(frame.name, frame.index, None, frame.error, frame.path)
    if frame.image is None:
        return light, None, None
    h, w = frame.image.shape[:2]
    board, symmetric = ctx
    return light, (w, h), detect_board(frame.image, board, symmetric)


def _check_outputs(output, report_path, corners_path, force):
    """The output paths, each given once and writable (before any work)."""
    outputs = [("-o/--output", output)] + [(name, p) for name, p in (("--report", report_path),
                                                                         ("--corners", corners_path)) if p]
    resolved = {}
    for name, p in outputs:
        key = Path(p).resolve()
        if key in resolved:
            raise InputError(f"{p}: given for both {resolved[key]} and {name}")
        resolved[key] = name
        check_output(p, force)
    return [p for _, p in outputs]


def _detect_all(source, board, symmetric, workers, quiet):
    """Board detections of every frame: (frames [(frame, record, detection or None)],
    detections of the decoded frames, their indices into frames, image size (w, h))."""
    frames = []      # per frame: (frame, dict(image, decoded, error, corners), detection)
    detections = []  # per decoded frame
    decoded_index = []
    first = None
    for frame, size, det in run_frames(source, _detect_task, (board, symmetric), workers, "detect", quiet):
        rec = {"image": frame.name, "path": frame.path, "decoded": size is not None, "error": frame.error, "corners": 0}
        if size is None:
            warn(f"{frame.path or frame.name}: {frame.error}; skipped")
            frames.append((frame, rec, None))
            continue
        if first is None:
            first = (frame.path or frame.name, size)
        elif size != first[1]:
            raise InputError(f"{frame.path or frame.name}: image is {size[0]}x{size[1]} but {first[0]} is "
                             f"{first[1][0]}x{first[1][1]}; all images must have the same size")
        rec["corners"] = det.count
        decoded_index.append(len(frames))
        detections.append(det)
        frames.append((frame, rec, det))
    if not frames:
        raise InputError(f"{source.description}: no frames")
    if first is None:
        raise InputError(f"{source.description}: none of the {len(frames)} image(s) could be decoded")
    return frames, detections, decoded_index, first[1]


def _candidates(output, fix_aspect):
    """The lens models --model auto may choose: those the output's format can hold."""
    out = []
    for model, n in CANDIDATES:
        if model in ("fisheye", SPLINED) and fix_aspect:
            continue
        try:
            _probe_camera_format(output, model, n)
        except InputError:
            continue
        out.append((model, n))
    if not out:
        raise InputError(f"{output}: this camera format holds none of the lens models --model auto compares")
    return tuple(out)


def _report(result, frames, decoded_index, source, board_path, image_size, fix_aspect, output, corners_path):
    """The --report record: the result's own (`CalibrationResult.to_dict`: camera, sigmas,
    warp, model choice, verdict, cross-validation, maps) with every frame, readable or not,
    its rejections named by image, and the command's inputs and outputs."""
    names = [frames[i][0].name for i in decoded_index]
    rec = result.to_dict(names)
    views, rejected = [], []
    by_frame = {idx: j for j, idx in enumerate(decoded_index)}
    for idx, (frame, info, det) in enumerate(frames):
        v = dict(info)
        if det is None:
            v.update(used=False, rms_px=None, reason=f"unreadable: {info['error']}")
            rejected.append({"image": frame.name, "stage": "unreadable", "reason": info["error"]})
        else:
            j = by_frame[idx]
            v.update({k: val for k, val in rec["views"][j].items() if k != "view"})
            if v.get("reason") is None and not v["used"]:
                v["reason"] = "not used"
            rejected += [{"image": frame.name, **{k: val for k, val in r.items() if k != "view"}}
                         for r in result.rejected if r["view"] == j]
        v["index"] = idx
        views.append(v)
    detected = [d for _, _, d in frames if d is not None]
    rec["counts"].update(images=len(frames), unreadable=sum(1 for _, info, _ in frames if not info["decoded"]),
                         views_with_corners=sum(1 for d in detected if d.count > 0),
                         corners_detected=int(sum(d.count for d in detected)))
    rec.update(command="calibrate", images=source.description, board_file=str(board_path),
               board=result.camera.meta["calibration"]["board"], image_size=list(image_size),
               fix_aspect=bool(fix_aspect), views=views, rejected=rejected,
               outputs={"camera": str(output), "corners": str(corners_path) if corners_path else None})
    return rec


@command()
@images_argument()
@click.option("--board", "board_path", required=True, type=click.Path(dir_okay=False),
              help="Board file (.yaml/.json): charuco or chessboard.")
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False),
              help="Camera file (.json, OpenCV .yaml, mrcal, COLMAP).")
@click.option("--model", type=click.Choice([*MODELS, SPLINED, AUTO]), default="opencv", show_default=True,
              help="Lens model; splined: mrcal's splined stereographic; auto: chosen on held-out views.")
@click.option("--coefficients", type=click.Choice(["4", "5", "8", "12", "14"]), default=None,
              help="opencv only: distortion coefficients.  [default: 5]")
@click.option("--fix-aspect", is_flag=True, help="Hold fx = fy (square pixels); not with --model fisheye.")
@click.option("--min-corners", type=int, default=6, show_default=True,
              help="Views with fewer corners are skipped.")
@click.option("--report", "report_path", type=click.Path(dir_okay=False), default=None,
              help="Also a report: .json, or an .html page.")
@click.option("--corners", "corners_path", type=click.Path(dir_okay=False), default=None,
              help="Also mrcal's corner cache (corners.vnl).")
@click.option("--halves", type=click.IntRange(0, 1000), default=RANDOM_HALVES, show_default=True,
              help="Random halves of the views calibrated apart as a check, besides odd/even.")
@click.option("--symmetric-corners", is_flag=True,
              help="ChArUco: refine corners to their point of symmetry (chessboards: always).")
@max_pixels_option
@workers_option
@force_option
@quiet_option
@run
def calibrate(images, board_path, output, model, coefficients, fix_aspect, min_corners, report_path, corners_path,
              halves, symmetric_corners, max_pixels, workers, force, quiet):
    """Calibrate a camera from views of a board, and say whether it is good enough.

    \b
    Examples:
      pencilcal calibrate calib/*.png --board b.yaml -o cam.yaml --report c.html
      pencilcal calibrate v.mp4 --board b.yaml -o c.json --model auto

    IMAGES: files, folders or globs in the order given, or a video. Prints the verdict:
    usable, usable within a region, or not usable and why. In detail: docs/calibration.md.
    \f
    Views without a usable board are skipped, outlier views and corners rejected (with
    their reasons in --report); the board's warp is estimated (its twist too, where
    held-out views keep it) and the sigmas hold the corner errors seen, correlated ones too. Two halves of the views are calibrated apart
    as a check (odd/even and --halves random ones, pooled; on a small set more halves read
    the pooled figures more precisely). --report writes .json (everything measured) or .html (the verdict, the
    projection-uncertainty and cross-validation maps, advice on what views to add).
    --model splined fits mrcal's splined stereographic model (a B-spline correction on a
    grid of knots covering the image; .cameramodel holds it as mrcal's, COLMAP cannot);
    --model auto compares the lens models on held-out views, the splined one among them.
    --corners writes mrcal's
    corner cache (corners.vnl, for mrcal-calibrate-cameras --corners-cache).
    --symmetric-corners refines each ChArUco corner, after CharucoDetector, to the point
    about which the image is symmetric (chessboard corners always are): on the real da
    Vinci views the RMS falls 0.56 -> 0.25 px, but the corner-noise model then counts an
    error the views share as each view's own (sigmas about 1.5 x too large); off by default.
    The camera file records the choice, and `pencilcal pnp` and `validate` with it detect
    the board's corners the same way.
    """
    if coefficients is not None and model != "opencv":
        raise click.BadParameter(f"applies to --model opencv only (the {model} model has a fixed set)",
                                 param_hint="--coefficients")
    if fix_aspect and model in ("fisheye", SPLINED):
        raise click.BadParameter(f"is not available with --model {model}", param_hint="--fix-aspect")
    if min_corners < 4:
        raise click.BadParameter("must be at least 4", param_hint="--min-corners")
    n_coef = int(coefficients) if coefficients is not None else MODELS.get(model, (None,))[0]

    outputs = _check_outputs(output, report_path, corners_path, force)
    if model != AUTO:
        _probe_camera_format(output, model, n_coef)
    board = read_board(board_path)
    source = open_images(images, gray=True, max_pixels=max_pixels)
    for p in outputs:
        check_output(p, force, [*source.paths, board_path])
    if corners_path and source.kind == "images":
        # a name vnlog cannot hold is found now, not after the work
        for path in source.paths:
            check_image_name(_vnl_name(str(path), path.name, corners_path, source.kind))

    frames, detections, decoded_index, image_size = _detect_all(source, board, symmetric_corners, workers, quiet)
    candidates = _candidates(output, fix_aspect) if model == AUTO else CANDIDATES
    result = calibrate_checked(detections, board, image_size, model=model,
                               coefficients=None if model == AUTO else n_coef, fix_aspect=fix_aspect,
                               min_corners=min_corners, candidates=candidates, repeats=halves)
    camera = result.camera
    report = _report(result, frames, decoded_index, source, board_path, image_size, fix_aspect, output,
                     corners_path)

    # --- outputs, all or nothing
    todo = []
    if corners_path:
        records = [(_vnl_name(frame.path, frame.name, corners_path, source.kind), det) for frame, _, det in frames]
        todo.append((corners_path, lambda tmp: write_corners_vnl(tmp, records, board, force=True)))
    if report_path and Path(report_path).suffix.lower() in (".html", ".htm"):
        todo.append((report_path, lambda tmp: write_calibration_report(tmp, report, force=True)))
    elif report_path:
        todo.append((report_path, lambda tmp: write_calibration_file(tmp, report, force=True)))
    todo.append((output, lambda tmp: write_camera(tmp, camera, force=True)))
    with atomic_paths([path for path, _ in todo], force) as tmps:
        for (_, writer), tmp in zip(todo, tmps):
            writer(tmp)

    n_outlier_views, n_outlier_corners = report["counts"]["views_rejected"], report["counts"]["corners_rejected"]
    if not quiet:
        extra = ""
        if n_outlier_views or n_outlier_corners:
            extra = f" ({n_outlier_views} outlier view(s), {n_outlier_corners} outlier corner(s) rejected)"
        chosen = f"{result.model} {result.coefficients}, " if model == AUTO else ""
        done(f"{result.checks.verdict.headline}; {result.views_used}/{len(frames)} views used{extra}, {chosen}"
             f"RMS {result.rms_px:.3f} px: fx {camera.fx:.2f} fy {camera.fy:.2f} cx {camera.cx:.2f} cy {camera.cy:.2f}",
             output, *[p for p in (report_path, corners_path) if p])
