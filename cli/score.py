"""`pencilcal score`: detected shafts scored against instrument masks (score.json, a contact sheet)."""
from __future__ import annotations

import click

from .common import (command, FiniteFloat, camera_options_optional, check_output, detector_option, done, force_option,
                     frames_region, gamma_option, images_argument, mask_option, max_pixels_option, open_input,
                     output_option, quiet_option, run, run_frames, warn, workers_option)


def _score_task(frame, ctx):
    """One frame's score record and, with the sheet, its overlay (module level: runs in worker
    processes too)."""
    from pencilcal.toolkit.detect.lines import shaft_records
    from pencilcal.toolkit.detect.shaft.work import axis_matrix
    from pencilcal.toolkit.io.images import check_image_size
    from pencilcal.validation.shaft_score import frame_references, score_frame, score_record

    camera, masks, region, detector, gamma, given, tol, sheet = ctx
    if frame.image is None:
        return {"image": frame.name, "ok": False, "error": frame.error}, None
    if camera is not None:
        check_image_size(frame, camera)
    shape = frame.image.shape[:2]
    m = masks.of(frame)
    valid = None if region is None else region.mask(shape)
    refs, inst, small = frame_references(m["mask"], m["labels"], m["instances"], valid,
                                         axis_matrix(camera, shape)[0])
    if given is None:
        dets = shaft_records(frame.image, camera, valid_region=region, gamma=gamma, detector=detector)
    else:
        dets = given.get(frame.name)
        if dets is None:
            return {"image": frame.name, "ok": False, "error": "not in the lines file"}, None
    fs = score_frame(dets, refs, tol, small)
    rec = {"image": frame.name, "ok": True, **score_record(fs, refs),
           "shafts": [{k: d[k] for k in ("midline", "width_px", "score", "cue") if k in d} for d in dets]}
    if not sheet:
        return rec, None
    from pencilcal.validation.shaft_sheet import overlay

    return rec, (overlay(frame.image, inst, refs, dets, fs), fs)


def _lines_shafts(path):
    """{image name: its shaft records} of a lines file (--lines)."""
    import numpy as np

    from pencilcal.toolkit.errors import InputError
    from pencilcal.toolkit.io.lines_file import read_lines

    out = {}
    for i, f in enumerate(read_lines(path)):
        shafts = f.get("shafts") or []
        for s in shafts:
            if not isinstance(s, dict) or np.asarray(s.get("midline", ()), float).size != 4:
                raise InputError(f"{path}: frame {i}: a shaft needs a midline [x1, y1, x2, y2]")
        out[str(f["image"])] = shafts
    return out


@command()
@images_argument()
@click.option("--masks", "masks_spec", required=True, metavar="MASKS",
              help="Instrument masks, one per frame (folder, pattern, files).")
@click.option("--mask-label", "mask_labels", multiple=True, metavar="V",
              help="Instrument mask value (or B,G,R); repeatable.")
@click.option("--mask-instances", is_flag=True, help="Each mask value is one instrument.")
@click.option("--lines", "lines_path", type=click.Path(exists=True, dir_okay=False), default=None,
              help="Score the shafts of this lines.json instead of detecting them.")
@camera_options_optional
@output_option
@click.option("--sheet", "sheet_path", type=click.Path(dir_okay=False), default=None,
              help="Also write the contact sheet (HTML) here.")
@click.option("--angle-tol", type=FiniteFloat(min=0.01, max=90), default=1.5, show_default=True,
              help="A shaft finds an instrument within this angle [deg].")
@click.option("--offset-tol", type=FiniteFloat(min=0.01), default=15.0, show_default=True,
              help="... and this distance from its axis' middle [px].")
@detector_option("OpenCV detector proposing the shafts' edges.")
@gamma_option
@mask_option
@max_pixels_option
@workers_option
@force_option
@quiet_option
@run
def score(images, masks_spec, mask_labels, mask_instances, lines_path, camera_path, camera_id, output, sheet_path,
          angle_tol, offset_tol, detector, gamma, mask_path, max_pixels, workers, force, quiet):
    """Score detected instrument shafts against instrument masks.

    \b
    Examples:
      pencilcal score frames/ --masks masks/ -o score.json --sheet sheet.html
      pencilcal score f/ --masks parts/ --mask-label 10 --lines l.json -o s.json

    Per frame: instruments found, missed, false detections, angle and offset errors against
    each mask's own axis; the totals on the last line. In detail: docs/cli.md.
    \f
    IMAGES are the frames (files, folders or globs in the order given, or a video); MASKS
    one mask per frame, paired by file name (frame007.jpg with frame007.png) or, as many as
    the frames, in order. A mask is binary (any non-zero value is instrument), a label
    image (--mask-label picks the values that are instrument, e.g. a part mask's shaft
    label), a colour mask (--mask-label B,G,R) or an instance image (--mask-instances: each
    value one instrument); otherwise each connected piece is one instrument (pieces within
    5 px joined). Each instrument's reference axis is the plane bisector of its outline's
    two straight stretches, or for a distal part alone (jaws, a hook) its principal axis.

    The shafts are detected as `lines --shaft` detects them (--detector, --gamma, --mask,
    --camera), or read from a lines file (--lines). A shaft finds an instrument within
    --angle-tol and --offset-tol of its axis (a distal part: 8 deg, half its width), one to
    one, best score first; a shaft that finds none is false, unless it lies on an instrument
    too small to score. score.json holds every frame's record (its instruments' axes, its
    shafts, matches with their errors, missed and false) and the summary. The contact sheet
    (--sheet) draws them on every frame. A lab validates the detector on its own annotated
    frames this way; docs/method.md gives the project's own table, each source scored with
    the detector's setting chosen on the others.
    """
    from pencilcal.toolkit.camera.formats import read_camera
    from pencilcal.toolkit.io.files import write_json
    from pencilcal.toolkit.io.instrument_masks import source_masks
    from pencilcal.validation.shaft_score import FrameScore, Tolerance, summarize

    if lines_path is not None and (camera_path is not None or mask_path is not None):
        raise click.UsageError("--lines gives the shafts: --camera and --mask are for detecting them")
    check_output(output, force)
    if sheet_path is not None:
        check_output(sheet_path, force)
    camera = None if camera_path is None else read_camera(camera_path, camera_id=camera_id)
    source = open_input(images, None, max_pixels)
    masks = source_masks(source, masks_spec, mask_labels, mask_instances)
    check_output(output, force, [*source.paths, camera_path, lines_path, *masks.paths.values()])
    region = frames_region(source, mask_path, shape=None if camera is None else (camera.height, camera.width))
    given = None if lines_path is None else _lines_shafts(lines_path)
    tol = Tolerance(angle_deg=angle_tol, offset_px=offset_tol)
    ctx = (camera, masks, region, detector, gamma, given, tol, sheet_path is not None)
    records, items = [], []
    for rec, drawn in run_frames(source, _score_task, ctx, workers, "score", quiet):
        if not rec["ok"]:
            warn(f"{rec['image']}: {rec['error']}")
        records.append(rec)
        if drawn is not None:
            items.append((rec["image"], *drawn))
    scored = [FrameScore.from_dict(r) for r in records if r["ok"]]
    summary = summarize(scored)
    write_json(output, {"masks": str(masks_spec), "labels": [str(v) for v in mask_labels], "instances": mask_instances,
                        "lines": lines_path, "tolerance": {"angle_deg": angle_tol, "offset_px": offset_tol},
                        "summary": summary, "frames": records}, force=force)
    written = [output]
    if sheet_path is not None:
        from pencilcal.toolkit.io.files import atomic_write
        from pencilcal.validation.shaft_sheet import contact_sheet

        atomic_write(sheet_path, contact_sheet(items, summary).encode("utf-8"), force=force)
        written.append(sheet_path)
    from pencilcal.validation.shaft_sheet import verdict_line

    done(verdict_line(summary), *written, quiet=quiet)
