"""`pencilcal sfm`: a pycolmap reconstruction with the calibrated intrinsics held fixed."""
from __future__ import annotations

import sys
from pathlib import Path

import click

from pencilcal.toolkit.camera.formats import read_camera
from pencilcal.toolkit.errors import InputError
from pencilcal.toolkit.io.files import atomic_folder, check_folder_writable
from pencilcal.toolkit.io.images import open_images
from pencilcal.validation.sfm import (
    DEFAULT_MAX_FEATURES,
    DEFAULT_MIN_REGISTERED,
    EXHAUSTIVE_MAX_IMAGES,
    MATCHING_MODES,
    SEQUENTIAL_OVERLAP,
    reconstruct,
    write_poses,
)

from .common import (command, StageBars, camera_options, done, force_option, images_argument, max_pixels_option,
                     quiet_option, run, warn)

# what a folder must hold (one of) for --force to replace it: never a folder of other things
_SFM_MARKERS = ("poses.json", "sparse", "database.db")


def _check_output_folder(out: Path, force: bool, source):
    """Fail before any work: a file in the way, a non-empty folder without --force, a
    folder that is not an earlier sfm output (never replaced), or the input inside it."""
    check_folder_writable(out)
    if out.exists() and not out.is_dir():
        raise InputError(f"{out}: exists and is not a folder")
    if not out.is_dir() or not any(out.iterdir()):
        return
    if not force:
        raise InputError(f"{out}: already exists and is not empty; pass --force to replace it")
    if not any((out / m).exists() for m in _SFM_MARKERS):
        raise InputError(f"{out}: is not an sfm output folder (no poses.json, sparse/ or database.db); "
                         "refusing to replace it")
    real = out.resolve()
    cwd = Path.cwd().resolve()
    inside = [p for p in source.paths if real in Path(p).resolve().parents]
    if inside or cwd == real or real in cwd.parents:
        raise InputError(f"{out}: holds the input images or the working folder; choose another output")


@command()
@images_argument()
@camera_options
@click.option("-o", "--output", required=True, type=click.Path(file_okay=False),
              help="Output folder (COLMAP layout, poses.json).")
@click.option("--matching", type=click.Choice(MATCHING_MODES), default="auto", show_default=True,
              help=f"Pairs: all, or the next {SEQUENTIAL_OVERLAP} (video); auto: all up to {EXHAUSTIVE_MAX_IMAGES} images.")
@click.option("--max-features", type=int, default=DEFAULT_MAX_FEATURES, show_default=True,
              help="SIFT features per image.")
@click.option("--min-registered", type=int, default=DEFAULT_MIN_REGISTERED, show_default=True,
              help="Fail when fewer frames get a pose (at least 2).")
@click.option("--seed", type=int, default=0, show_default=True,
              help="Seed of COLMAP's RANSAC and mapper (-1: random).")
@click.option("--keep-frames", is_flag=True,
              help="Keep the frames or image links in OUTPUT/images.")
@click.option("--verbose", is_flag=True, help="pycolmap's log on stderr too.")
@max_pixels_option
@force_option
@quiet_option
@run
def sfm(images, camera_path, camera_id, output, matching, max_features, min_registered, seed, keep_frames, verbose,
        max_pixels, force, quiet):
    """Structure from motion (pycolmap) with the intrinsics held fixed.

    \b
    Examples:
      pencilcal sfm frames/ --camera camera.yaml -o sfm/
      pencilcal sfm clip.mp4 --camera camera.json --matching sequential -o sfm/

    IMAGES: files, folders or globs in the order given, or a video. Writes a COLMAP
    project and OUTPUT/poses.json. In detail: docs/cli.md.
    \f
    IMAGES is one or more image files, folders or glob patterns, in the order given, or one
    video. SIFT features on the CPU (--max-features per image), exhaustive or sequential
    matching (--matching), then COLMAP's incremental mapper with one shared camera whose
    focal length, principal point and distortion are those of CAM and are never refined
    (checked bit for bit afterwards). Writes a COLMAP project in OUTPUT (sparse/0: the
    largest model, binary and text; database.db; colmap.log, pycolmap's own log, also on
    stderr with --verbose) and OUTPUT/poses.json: per frame image, registered,
    R_cam_from_world, t_cam_from_world and camera_center, in the reconstruction's own world
    frame and scale. It fails when fewer than --min-registered frames get a pose. --seed
    seeds COLMAP's RANSAC and mapper, for repeatable runs (-1: random). --keep-frames keeps
    the decoded frames (video input) or image links under OUTPUT/images. The output is
    built beside OUTPUT and moved into place when complete.
    """
    if max_features < 1:
        raise click.BadParameter("must be a positive number of features", param_hint="--max-features")
    if min_registered < 2:
        raise click.BadParameter("must be at least 2 (a reconstruction starts from a pair)",
                                 param_hint="--min-registered")
    out = Path(output)
    source = open_images(images, max_pixels=max_pixels)
    _check_output_folder(out, force, source)
    camera = read_camera(camera_path, camera_id=camera_id)
    bars = StageBars() if not quiet and sys.stderr.isatty() else None
    # built beside OUTPUT and put in place whole; errors name OUTPUT, never the staging folder
    with atomic_folder(out) as tmp:
        try:
            res = reconstruct(source, camera, tmp, matching=matching, max_features=max_features,
                              min_registered=min_registered, seed=seed, keep_frames=keep_frames, quiet=quiet,
                              verbose=verbose, progress=bars)
        finally:
            if bars is not None:
                bars.close()
        for f in res.frames:
            if f.error and not f.error.startswith("not registered"):
                warn(f"{f.image}: {f.error}")
        for w in res.warnings:
            warn(w)
        write_poses(tmp / "poses.json", res, images=source.description, camera_file=str(camera_path),
                    camera_id=camera_id, seed=seed, min_registered=min_registered)
    if not quiet:
        done(f"{res.n_registered}/{res.n_frames} frames registered, {res.n_points3D} points, "
             f"mean reprojection error {res.mean_reprojection_error_px:.3f} px ({res.matching} matching, "
             f"{res.timings['total']:.1f} s)", out)
