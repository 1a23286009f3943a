"""`pencilcal validate`: orient, PnP (every method) and optionally SfM on the same frames, compared."""
from __future__ import annotations

import sys
from pathlib import Path

import click

from pencilcal.toolkit.boards import read_board
from pencilcal.toolkit.camera_io import camera_to_dict, read_camera
from pencilcal.toolkit.errors import InputError
from pencilcal.toolkit.files import load_frames, load_structured, write_json
from pencilcal.toolkit.grid_pencil import GridPencil
from pencilcal.toolkit.images import open_images
from pencilcal.toolkit.orient import MODELS
from pencilcal.toolkit.pencil import read_pencil
from pencilcal.validation.pnp import METHODS
from pencilcal.validation.validate import FanLines, GridLines, reproducibility, validate_sequence

from .common import StageBars, check_output, force_option, output_option, progress, quiet_option, run, warn


def _sequence_files(sequence):
    """A `pencilcal simulate` folder: its images/ and the files beside them."""
    p = Path(sequence)
    if p.is_dir() and (p / "images").is_dir():
        found = {k: p / n for k, n in (("camera", "camera.json"), ("board", "board.yaml"), ("pencil", "pencil.yaml"),
                                        ("truth", "truth.json")) if (p / n).is_file()}
        return p / "images", found
    return p, {}


def _truth(path):
    _, frames = load_frames(path, "truth file", ("image", "R_cam_from_target", "t_cam_from_target"))
    return {str(f["image"]): f for f, _ in frames}


def _split(value, allowed, what):
    items = [v.strip() for v in value.split(",") if v.strip()]
    bad = [v for v in items if v not in allowed]
    if bad or not items:
        raise click.BadParameter(f"expected a comma-separated subset of {', '.join(allowed)}", param_hint=what)
    return tuple(items)


@click.command()
@click.argument("sequence")
@click.option("--camera", "camera_path", type=click.Path(), default=None,
              help="Camera file (any supported format); default: camera.json of a simulate folder.")
@click.option("--camera-id", type=int, default=None, help="Camera id in a COLMAP file with several cameras.")
@click.option("--board", "board_path", type=click.Path(dir_okay=False), default=None,
              help="Board file; default: board.yaml of a simulate folder.")
@click.option("--pencil", "pencil_path", type=click.Path(dir_okay=False), default=None,
              help="Pencil file of the printed fan; default: pencil.yaml of a simulate folder.")
@click.option("--grid-pencil", default=None, metavar="auto|I,J",
              help="Use the board's grid lines through one inner corner as the pencil (no fan printed): "
                   "'auto' picks the best detected corner per frame.")
@click.option("--truth", "truth_path", type=click.Path(dir_okay=False), default=None,
              help="truth.json with exact poses (default: that of a simulate folder); else PnP is the reference.")
@click.option("--models", default=",".join(MODELS), show_default=True, help="Orientation models to run.")
@click.option("--methods", default=",".join(METHODS), show_default=True, help="PnP methods to run.")
@click.option("--sfm", is_flag=True, help="Also reconstruct with pycolmap and compare after alignment.")
@click.option("--sfm-dir", type=click.Path(file_okay=False), default=None, help="Keep the reconstruction here.")
@click.option("--detector", type=click.Choice(["lsd", "fld", "edlines"]), default="lsd", show_default=True,
              help="Line detector for the fan.")
@click.option("--calibration", "calib_path", type=click.Path(dir_okay=False), default=None,
              help="calib.json of `pencilcal calibrate --report`, shown in the report.")
@output_option
@force_option
@quiet_option
@run
def validate(sequence, camera_path, camera_id, board_path, pencil_path, grid_pencil, truth_path, models, methods,
             sfm, sfm_dir, detector, calib_path, output, force, quiet):
    """Compare the angular-variation estimate with PnP (and a reconstruction) on the same frames.

    SEQUENCE is a folder of images, a glob or a video, or a `pencilcal simulate` folder
    (then its images, camera, board, pencil and truth are used unless given). Every frame
    is decoded and detected once: the pencil's lines give the orientation (exact estimator
    and the chapter's general and aligned models), the board's corners give the pose by
    every PnP method, and with --sfm a pycolmap reconstruction (intrinsics fixed) is aligned
    to the board frame. Errors are measured against the truth when there is one, else
    against the PnP pose. `pencilcal report` turns the output into a page.

    \b
    Examples:
      pencilcal simulate sim --scenario orbit --frames 30 --seed 1
      pencilcal validate sim --sfm -o validation.json
      pencilcal validate left/ --camera cam.yaml --board board.yaml --grid-pencil auto -o v.json
    """
    models_t = _split(models, MODELS, "--models")
    methods_t = _split(methods, METHODS, "--methods")
    check_output(output, force)
    images, found = _sequence_files(sequence)
    camera_path = camera_path or found.get("camera")
    board_path = board_path or found.get("board")
    truth_path = truth_path or found.get("truth")
    if camera_path is None:
        raise click.UsageError("--camera is required (SEQUENCE is not a simulate folder)")
    if board_path is None:
        raise click.UsageError("--board is required (SEQUENCE is not a simulate folder)")
    if grid_pencil is not None and pencil_path is not None:
        raise click.UsageError("give either --pencil or --grid-pencil")
    camera = read_camera(camera_path, camera_id=camera_id)
    board = read_board(board_path)
    if grid_pencil is not None:
        if grid_pencil == "auto":
            vertex = None
        else:
            try:
                vertex = tuple(int(v) for v in grid_pencil.split(","))
                assert len(vertex) == 2
            except (ValueError, AssertionError):
                raise click.BadParameter("expected 'auto' or two integers I,J", param_hint="--grid-pencil") from None
        lines = GridLines(GridPencil(board, vertex))
        pencil_desc = {"grid": grid_pencil, "angles_deg": [float(a) for a in __import__("numpy").degrees(lines.grid.angles)]}
    else:
        pencil_path = pencil_path or found.get("pencil")
        if pencil_path is None:
            raise click.UsageError("--pencil or --grid-pencil is required (SEQUENCE is not a simulate folder)")
        pencil = read_pencil(pencil_path)
        lines = FanLines(pencil, detector)
        pencil_desc = pencil.to_dict()
    truth = _truth(truth_path) if truth_path else None
    source = open_images(images)
    calib = load_structured(calib_path, "calibration report") if calib_path else None
    stage_bars = StageBars() if (sfm and not quiet and sys.stderr.isatty()) else None
    try:
        result = validate_sequence(
            source, camera, board, lines, truth=truth, models=models_t, methods=methods_t, sfm=sfm,
            sfm_workdir=sfm_dir, progress=lambda it, label: _bar(it, label, quiet), warn=warn, quiet=quiet,
            sfm_progress=stage_bars,
        )
    finally:
        if stage_bars is not None:
            stage_bars.close()
    inputs = [camera_path, board_path, pencil_path, truth_path, calib_path] + [getattr(p, "path", None) for p in []]
    image_files = list(getattr(source, "paths", []))
    out = {
        "sequence": str(sequence),
        "images": str(images),
        "camera_file": str(camera_path),
        "camera": camera_to_dict(camera),
        "board": board.to_dict(),
        "pencil": pencil_desc,
        "calibration": calib if calib is not None else (camera.meta or None),
        **result,
        "reproducibility": reproducibility([p for p in inputs if p] + [str(p) for p in image_files]),
    }
    write_json(output, out, force=force)
    if not quiet:
        s = result["summary"].get("orient:exact", {})
        n = s.get("normal_closer", {}).get("median")
        click.echo(f"{sum(f['ok'] for f in result['frames'])}/{len(result['frames'])} frames validated"
                   + (f"; orient (exact) normal error median {n:.3f} deg" if n is not None else "") + f" -> {output}", err=True)


class _bar:
    """progress() as a plain iterable wrapper (the context manager closes with the loop)."""

    def __init__(self, it, label, quiet):
        self.it, self.label, self.quiet = it, label, quiet

    def __iter__(self):
        with progress(self.it, self.label, self.quiet) as bar:
            yield from bar
