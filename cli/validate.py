"""`pencilcal validate`: orient, PnP (every method) and optionally SfM on the same frames, compared."""
from __future__ import annotations

import sys

import click

from pencilcal.toolkit.pencil.orient import MODELS
from pencilcal.validation.pnp import METHODS
from pencilcal.validation.validate import find_sequences, sequence_files, validate_many, validate_path
from pencilcal.validation.validation_file import write_validation

from .common import (detector_option, gamma_option, command, LabelledProgress, StageBars, check_output, done, force_option,
                     instrument_mask_options, mask_option, output_option, quiet_option, run, warn, workers_option)


def _split(value, allowed, what):
    items = [v.strip() for v in value.split(",") if v.strip()]
    bad = [v for v in items if v not in allowed]
    if bad or not items:
        raise click.BadParameter(f"expected a comma-separated subset of {', '.join(allowed)}", param_hint=what)
    return tuple(items)


def _grid(value):
    if value is None or value == "auto":
        return value
    try:
        ij = tuple(int(v) for v in value.split(","))
    except ValueError:
        ij = ()
    if len(ij) != 2:
        raise click.BadParameter("expected 'auto' or two integers I,J", param_hint="--grid-pencil")
    return ij


@command()
@click.argument("sequence", nargs=-1, required=True, type=click.Path())
@click.option("--camera", "camera_path", type=click.Path(), default=None,
              help="Camera file; default: a simulate folder's.")
@click.option("--camera-id", type=int, default=None, help="The camera's id in a COLMAP file.")
@click.option("--board", "board_path", type=click.Path(dir_okay=False), default=None,
              help="Board file; default: a simulate folder's.")
@click.option("--pencil", "pencil_path", type=click.Path(dir_okay=False), default=None,
              help="Pencil file; default: a simulate folder's.")
@click.option("--grid-pencil", default=None, metavar="auto|I,J",
              help="The board's grid lines through one corner as the pencil.")
@click.option("--truth", "truth_path", type=click.Path(dir_okay=False), default=None,
              help="truth.json; default: a simulate folder's.")
@click.option("--models", default=",".join(MODELS), show_default=True, help="Orientation models to run.")
@click.option("--methods", default=",".join(METHODS), show_default=True, help="PnP methods to run.")
@click.option("--sfm", is_flag=True, help="Also reconstruct with pycolmap and compare.")
@click.option("--sfm-dir", type=click.Path(file_okay=False), default=None, help="Keep the reconstruction here.")
@detector_option("Line detector for the fan.")
@click.option("--edges", is_flag=True, help="The fan's edge segments, not its spokes' midlines.")
@click.option("--continuity/--no-continuity", default=True, show_default=True,
              help="Carry twin choices along the sequence, as orient does.")
@mask_option
@click.option("--calibration", "calib_path", type=click.Path(dir_okay=False), default=None,
              help="This camera's calib.json (calibrate --report).")
@click.option("--right", "right_images", default=None, metavar="IMAGES",
              help="A stereo pair's right view (rig check).")
@click.option("--right-camera", "right_camera", type=click.Path(), default=None,
              help="Camera file of the --right view.")
@click.option("--right-calibration", "right_calib_path", type=click.Path(dir_okay=False), default=None,
              help="calib.json of the --right view.")
@click.option("--fulcrum/--no-fulcrum", "fulcrum", default=None,
              help="Also a pivoting instrument's fulcrum (default: for a pivot folder).")
@click.option("--shaft-diameter", type=float, default=None, metavar="D",
              help="The shaft's diameter [mm], for the 3-D fulcrum.")
@gamma_option
@instrument_mask_options
@click.option("--dask", "dask_address", default=None, metavar="ADDRESS",
              help="Folders of sequences: each to this Dask scheduler.")
@workers_option
@output_option
@force_option
@quiet_option
@run
def validate(sequence, camera_path, camera_id, board_path, pencil_path, grid_pencil, truth_path, models, methods,
             sfm, sfm_dir, detector, edges, continuity, mask_path, calib_path, right_images, right_camera, right_calib_path,
             fulcrum, shaft_diameter, gamma, instrument_mask, mask_labels, mask_instances, dask_address, workers, output,
             force, quiet):
    """Compare the angular-variation estimate with PnP (and a reconstruction) on the same frames.

    \b
    Examples:
      pencilcal validate sim --sfm -o validation.json
      pencilcal validate f/ --camera c.yml --board b.yml --pencil p.yml -o v.json

    SEQUENCE: files, folders or globs in the order given, a video, or a `pencilcal
    simulate` folder. Errors against the truth, else PnP; `pencilcal report` makes the
    page. In detail: docs/cli.md.
    \f
    SEQUENCE is one or more image files, folders or glob patterns (in the order given), a
    video, or a `pencilcal simulate` folder (then its images, camera, board, pencil and
    truth are used unless given). Every frame is decoded and detected once: the pencil's
    lines give the orientation (exact estimator and the chapter's general and aligned
    models), the board's corners give the pose by every PnP method, and with --sfm a
    pycolmap reconstruction (intrinsics fixed; kept in --sfm-dir) is aligned to the board
    frame. Errors are measured against the truth when there is one (--truth), else against
    the PnP pose. `pencilcal report` turns the output into a page.

    The pencil is the printed fan of --pencil (its spokes' midlines, or with --edges its
    plain edge segments), or with --grid-pencil the board's grid lines through one inner
    corner (I,J, or auto: the best detected corner per frame), for a board without a fan.
    The twin is chosen by the pencil's own information only, never by the pose it is
    compared with: the spoke radii where they tell the twins apart, then (unless
    --no-continuity) continuity along the sequence, as `pencilcal orient` does by default:
    the choices of the frames the radii resolved are carried to the ambiguous ones.

    Truth-free checks go under `checks`: with --calibration (a calib.json of this camera)
    its two halves of the views calibrated apart, and its intrinsics' covariance and
    corner-noise model in the PnP totals (cov_total); with --right and --right-camera (a
    stereo pair, frames paired by image name; --right-calibration for the right camera's
    calib.json) the rigid-rig check: whether R_right R_left^T is one rotation within the
    PnP covariances (checks.rig).

    With --fulcrum (the default for a `simulate --scenario pivot` folder) the instrument's
    shafts are detected in every frame and `fulcrum` holds the fulcrum as `pencilcal
    fulcrum` finds it, each frame's axis residual, its error against the truth and, with
    --shaft-diameter (a pivot folder's own by default; mm, the board's unit), the 3-D point
    in the camera and the board frame; the shafts' edges are located on levels linearised
    with --gamma. With --instrument-mask the shafts are the masked instruments' axes refined
    on the image.

    SEQUENCE may also be a folder of sequence folders: each is validated (one after the
    other, or each as a task on a Dask cluster with --dask tcp://host:8786) and the output
    holds them all with a summary pooled over every frame. --workers spreads one sequence's
    frames over processes. The results are the same in every case.

    More examples:

        pencilcal simulate sim --scenario orbit --frames 30 --seed 1
        pencilcal validate sim --sfm -o validation.json
        pencilcal validate left/ --camera cam.yaml --board board.yaml --grid-pencil auto -o v.json
        pencilcal validate runs/ --dask tcp://scheduler:8786 -o all.json
    """
    models_t = _split(models, MODELS, "--models")
    methods_t = _split(methods, METHODS, "--methods")
    grid = _grid(grid_pencil)
    if grid is not None and pencil_path is not None:
        raise click.UsageError("give either --pencil or --grid-pencil")
    subs = find_sequences(sequence)
    if subs is None:
        if dask_address:
            raise click.UsageError("--dask needs SEQUENCE to be a folder of sequence folders")
        _, found = sequence_files(sequence)
        if camera_path is None and "camera" not in found:
            raise click.UsageError("--camera is required (SEQUENCE is not a simulate folder)")
        if board_path is None and "board" not in found:
            raise click.UsageError("--board is required (SEQUENCE is not a simulate folder)")
        if pencil_path is None and grid is None and "pencil" not in found:
            raise click.UsageError("--pencil or --grid-pencil is required (SEQUENCE is not a simulate folder)")
    if instrument_mask is None and (mask_labels or mask_instances):
        raise click.UsageError("--mask-label and --mask-instances go with --instrument-mask")
    if instrument_mask is not None and subs is not None:
        raise click.UsageError("--instrument-mask pairs masks with one sequence's frames: not with a folder of sequences")
    check_output(output, force)
    options = dict(camera=camera_path, camera_id=camera_id, board=board_path, pencil=pencil_path, grid_pencil=grid,
                   truth=truth_path, models=models_t, methods=methods_t, sfm=sfm, detector=detector,
                   calibration=calib_path, workers=workers, edges=edges, mask=mask_path, fulcrum=fulcrum,
                   shaft_diameter=shaft_diameter, gamma=gamma, continuity=continuity, instrument_mask=instrument_mask,
                   mask_labels=mask_labels, mask_instances=mask_instances)
    if shaft_diameter is not None and not shaft_diameter > 0:
        raise click.BadParameter("must be positive", param_hint="--shaft-diameter")
    if right_images is not None or right_camera is not None:
        if right_images is None or right_camera is None:
            raise click.UsageError("--right and --right-camera go together")
        if subs is not None:
            raise click.UsageError("--right checks one stereo pair: not with a folder of sequences")
        options.update(right=right_images, right_camera=right_camera, right_calibration=right_calib_path)
    if subs is not None:
        if sfm_dir:
            raise click.UsageError("--sfm-dir keeps one reconstruction: not with a folder of sequences")
        out = _many(subs, options, dask_address, quiet)
    else:
        stage_bars = StageBars() if (sfm and not quiet and sys.stderr.isatty()) else None
        try:
            out = validate_path(sequence, **options, sfm_dir=sfm_dir, progress=lambda it, label: LabelledProgress(it, label, quiet),
                                warn=warn, quiet=quiet, sfm_progress=stage_bars)
        finally:
            if stage_bars is not None:
                stage_bars.close()
    write_validation(output, out, force=force)
    if subs is not None:
        s = out["summary"].get("orient:exact", {})
        n = s.get("normal_closer", {}).get("median")
        done(f"{sum(r['ok'] for r in out['sequences'])}/{len(out['sequences'])} sequences validated"
             + (f"; orient (exact) normal error median {n:.3f} deg" if n is not None else ""), output, quiet=quiet)
    else:
        from pencilcal.toolkit.io.files import to_jsonable
        from pencilcal.validation.report.headline import headline

        done(headline(to_jsonable(out)).line, output, quiet=quiet)


def _many(subs, options, dask_address, quiet):
    bar = None
    if not quiet and sys.stderr.isatty():
        bar = click.progressbar(length=len(subs), label="sequences", file=sys.stderr, show_pos=True)
        bar.__enter__()
    try:
        def tick(done, total):
            if bar is not None:
                bar.update(done - bar.pos)

        out = validate_many(subs, options, dask=dask_address, progress=tick)
    finally:
        if bar is not None:
            bar.__exit__(None, None, None)
    for r in out["sequences"]:
        if not r["ok"]:
            warn(f"{r['name']}: {r['error']}")
    return out
