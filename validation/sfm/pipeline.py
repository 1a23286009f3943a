"""`reconstruct`: COLMAP's incremental pipeline with the intrinsics held fixed, in named
steps (frames, camera, SIFT, matching, mapping, the kept model), and `bare_pycolmap`, the
same reconstruction as the bare pycolmap calls (the benchmark's baseline). The pipeline,
the output layout and the logging are described in `pencilcal.validation.sfm`.

Example
-------
>>> res = reconstruct("frames/", camera, "work/", matching="sequential")  # doctest: +SKIP
>>> res.n_registered, res.camera_unchanged                              # doctest: +SKIP
(12, True)
"""
from __future__ import annotations

import contextlib
import re
import shutil
import time
from pathlib import Path

import numpy as np

from pencilcal.toolkit.camera.formats import camera_to_colmap
from pencilcal.toolkit.camera.model import Camera
from pencilcal.toolkit.errors import EstimationError, InputError

from .glog import colmap_logging, glog_base, import_pycolmap
from .options import (
    COLMAP_READS,
    DEFAULT_MAX_FEATURES,
    DEFAULT_MIN_REGISTERED,
    MATCHING_MODES,
    MIN_FEATURES,
    choose_matching,
    pycolmap_options,
    write_camera_db,
)
from .prepare import prepare_frames
from .progress import extract_progress, match_progress
from .result import SfmFrame, SfmResult

__all__ = ["reconstruct", "bare_pycolmap"]


def reconstruct(images, camera, workdir, *, matching="auto", max_features=DEFAULT_MAX_FEATURES,
                min_registered=DEFAULT_MIN_REGISTERED, seed=0, num_threads=-1, keep_frames=False,
                quiet=True, verbose=False, progress=None):
    """Reconstruct camera poses from a sequence with the intrinsics held fixed.

    Parameters
    ----------
    images : str, Path, ImageSource, or list of Frame / path / ndarray
        A folder, glob or video (toolkit/io/images.py), or frames in order (arrays are named
        000000, 000001, ... in the results).
    camera : Camera
        The calibrated camera; any model COLMAP holds exactly (`toolkit.camera.formats.camera_to_colmap`:
        pinhole, opencv with 4/5/8 coefficients, fisheye). Image size must match.
    workdir : str or Path
        Folder for COLMAP's project (`pencilcal.validation.sfm`); created if missing. It must not
        hold a ``database.db`` or ``sparse`` already.
    matching : {"auto", "sequential", "exhaustive"}
    max_features : int
        SIFT features per image (COLMAP's default 8192).
    min_registered : int
        Fewer registered frames is an EstimationError (>= 2).
    seed : int
        Seeds COLMAP's RANSAC and mapper (-1: random), for repeatable runs; this also
        seeds pycolmap's global generator (``pycolmap.set_random_seed``).
    num_threads : int
        Threads for every stage (-1: all cores).
    keep_frames : bool
        Keep ``workdir/images`` (decoded frames and links) when one was needed.
    quiet : bool
        Unused here (no output of its own); kept for symmetry with the commands.
    verbose : bool
        pycolmap's log on stderr too.
    progress : callable, optional
        ``progress(stage, done, total)`` with stage in `STAGES`; called from a worker
        thread during extraction and matching.

    Returns
    -------
    SfmResult

    Raises
    ------
    InputError
        Unknown matching mode, fewer decodable images than ``max(2, min_registered)``, an
        image whose size is not the camera's, a camera COLMAP cannot hold, a used workdir.
    EstimationError
        Too few features (textureless images), no matched pair, no initial pair, fewer
        than `min_registered` frames registered, or COLMAP changed the camera.

    Example
    -------
    >>> res = reconstruct("frames/", camera, "work/", matching="sequential")  # doctest: +SKIP
    >>> names, R_cam_from_world = res.rotations()                             # doctest: +SKIP
    """
    pycolmap = import_pycolmap()
    _check_arguments(camera, matching, max_features, min_registered)
    colmap_cam = camera_to_colmap(camera, 1, source="camera")
    colmap_cam.has_prior_focal_length = True
    want_params = np.array(colmap_cam.params, dtype=float)
    workdir = _new_workdir(workdir)
    db_path = workdir / "database.db"
    timings = {}
    warnings = []
    t_start = time.perf_counter()

    # ---- 1. frames
    t0 = time.perf_counter()
    items, image_path, names, mode, staged = prepare_frames(images, camera, workdir, matching, min_registered,
                                                            progress)
    timings["prepare"] = time.perf_counter() - t0

    log_base = glog_base(workdir / "colmap.log")
    with colmap_logging(workdir / "colmap.log", verbose):
        if seed is not None and seed >= 0:
            pycolmap.set_random_seed(int(seed))
        # ---- 2. the camera, then 3. SIFT
        t0 = time.perf_counter()
        options = _extract(db_path, colmap_cam, image_path, names, max_features, num_threads, seed, log_base,
                           progress)
        timings["extract"] = time.perf_counter() - t0
        n_img = _count_features(db_path, items)
        # ---- 4. matching
        t0 = time.perf_counter()
        _match(db_path, mode, n_img, options, log_base, progress)
        timings["match"] = time.perf_counter() - t0
        _check_verified(db_path)
        # ---- 5. incremental mapping, intrinsics fixed
        t0 = time.perf_counter()
        models = _map(db_path, image_path, workdir / ".mapper", options[5], n_img, progress)
        timings["map"] = time.perf_counter() - t0
        if progress is not None:
            progress("map", n_img, n_img)
    if not models:
        # COLMAP relaxes its start (100 inliers, 16 deg) twice, down to 25 inliers and 4 deg
        raise EstimationError(
            f"no initial image pair found: no two of the {n_img} images have enough inlier matches and "
            "parallax to start a reconstruction (the camera must translate between views, not only rotate)")

    # ---- 6. keep the largest model
    t0 = time.perf_counter()
    recs = _models_by_size(models, warnings)
    rec = recs[0]
    _check_camera_unchanged(rec, colmap_cam, want_params, camera)
    frames = _frames_of_model(items, rec)
    n_reg = _check_registered(frames, min_registered, warnings)
    _write_models(recs, workdir / "sparse")
    if staged and not keep_frames:
        shutil.rmtree(workdir / "images", ignore_errors=True)
        image_path = None
    timings["write"] = time.perf_counter() - t0
    timings["total"] = time.perf_counter() - t_start
    if progress is not None:
        progress("write", 1, 1)

    return SfmResult(
        frames=frames, camera=camera, n_registered=int(n_reg), n_points3D=int(rec.num_points3D()),
        mean_reprojection_error_px=float(rec.compute_mean_reprojection_error()), matching=mode,
        max_features=int(max_features), n_models=len(recs), model_sizes=[int(r.num_reg_images()) for r in recs],
        workdir=workdir, model_path=workdir / "sparse" / "0", database_path=db_path, image_path=image_path,
        timings=timings, camera_unchanged=True, pycolmap_version=str(pycolmap.__version__), warnings=warnings,
        reconstruction=rec)


# --------------------------------------------------------------------------- reconstruct's steps
def _check_arguments(camera, matching, max_features, min_registered):
    """TypeError / InputError for arguments `reconstruct` cannot use."""
    if not isinstance(camera, Camera):
        raise TypeError(f"expected a Camera, got {type(camera).__name__}")
    if matching not in MATCHING_MODES:
        raise InputError(f"unknown matching mode {matching!r}; expected one of {', '.join(MATCHING_MODES)}")
    if isinstance(max_features, bool) or not isinstance(max_features, (int, np.integer)) or max_features < 1:
        raise InputError(f"max_features must be a positive integer, got {max_features!r}")
    if isinstance(min_registered, bool) or not isinstance(min_registered, (int, np.integer)) or min_registered < 2:
        raise InputError(f"min_registered must be an integer >= 2, got {min_registered!r}")


def _new_workdir(workdir):
    """The work folder as a Path, created if missing; InputError for a file in the way or a
    folder that holds an earlier reconstruction."""
    workdir = Path(workdir)
    if workdir.exists() and not workdir.is_dir():
        raise InputError(f"{workdir}: exists and is not a folder")
    for used in ("database.db", "sparse"):
        if (workdir / used).exists():
            raise InputError(f"{workdir}: already holds {used} (a previous reconstruction)")
    workdir.mkdir(parents=True, exist_ok=True)
    return workdir


def _extract(db_path, colmap_cam, image_path, names, max_features, num_threads, seed, log_base, progress):
    """Write the camera into a new database, then extract SIFT features of `names` (read
    from `image_path`). Returns the `pycolmap_options` tuple. EstimationError on failure."""
    pycolmap = import_pycolmap()
    try:
        cam_id = write_camera_db(db_path, colmap_cam)
        options = pycolmap_options(cam_id, max_features, num_threads, seed)
        reader, extraction = options[0], options[1]
        with extract_progress(log_base, len(names), progress):
            pycolmap.extract_features(str(db_path), image_path, image_names=names,
                                      camera_mode=pycolmap.CameraMode.SINGLE, reader_options=reader,
                                      extraction_options=extraction, device=pycolmap.Device.cpu)
    except Exception as e:  # pycolmap raises several types for C++ check failures
        raise EstimationError(f"feature extraction failed: {_one_line(e)}") from None
    return options


def _count_features(db_path, items):
    """Set each item's ``num_features`` (or ``error`` for an image COLMAP could not read)
    from the database; returns the number of images in it. EstimationError when fewer
    than two images have `MIN_FEATURES` features (textureless images)."""
    pycolmap = import_pycolmap()
    by_colmap = {x.colmap_name: x for x in items if x.colmap_name is not None}
    with contextlib.closing(pycolmap.Database.open(str(db_path))) as db:
        ids = {}
        for im in db.read_all_images():
            ids[im.name] = im.image_id
        for n, x in by_colmap.items():
            if n not in ids:
                x.error = "COLMAP could not read this image"
                continue
            x.num_features = int(db.num_keypoints_for_image(ids[n]))
    feats = {n: x.num_features for n, x in by_colmap.items()}
    rich = sum(v >= MIN_FEATURES for v in feats.values())
    if rich < 2:
        med = int(np.median(list(feats.values()))) if feats else 0
        raise EstimationError(
            f"too few features: {rich} of {len(feats)} images have {MIN_FEATURES} or more SIFT features "
            f"(median {med}); blank or textureless images cannot be reconstructed")
    return len(ids)


def _match(db_path, mode, n_img, options, log_base, progress):
    """Match the database's features, exhaustively or sequentially (`mode`), and verify the
    pairs' geometry. EstimationError on failure."""
    pycolmap = import_pycolmap()
    _, _, matcher, verification, pairing, _ = options
    try:
        with match_progress(log_base, mode, n_img, progress):
            if mode == "exhaustive":
                pycolmap.match_exhaustive(str(db_path), matching_options=matcher,
                                          verification_options=verification, device=pycolmap.Device.cpu)
            else:
                pycolmap.match_sequential(str(db_path), matching_options=matcher, pairing_options=pairing,
                                          verification_options=verification,
                                          device=pycolmap.Device.cpu)
    except Exception as e:  # pycolmap raises several types for C++ check failures
        raise EstimationError(f"feature matching failed: {_one_line(e)}") from None


def _check_verified(db_path):
    """EstimationError when no image pair passed geometric verification."""
    pycolmap = import_pycolmap()
    with contextlib.closing(pycolmap.Database.open(str(db_path))) as db:
        n_verified = int(db.num_verified_image_pairs())
        n_pairs = int(db.num_matched_image_pairs())
    if n_verified == 0:
        raise EstimationError(
            f"no image pair matched: 0 of {n_pairs} pairs passed geometric verification "
            "(do the images overlap? are they of a static scene?)")


def _map(db_path, image_path, scratch, mapper, n_img, progress):
    """COLMAP's incremental mapper (options `mapper`, intrinsics fixed), its models written
    to the folder `scratch` (removed afterwards); reports the registered images as "map"
    progress. Returns pycolmap's dict of models. EstimationError on failure."""
    pycolmap = import_pycolmap()
    scratch.mkdir(exist_ok=True)
    reg = {"n": 0}

    def on_pair():
        reg["n"] = 2
        if progress is not None:
            progress("map", min(2, n_img), n_img)

    def on_image():
        reg["n"] += 1
        if progress is not None:
            progress("map", min(reg["n"], n_img), n_img)

    if progress is not None:
        progress("map", 0, n_img)
    try:
        return pycolmap.incremental_mapping(str(db_path), image_path, str(scratch), options=mapper,
                                            initial_image_pair_callback=on_pair,
                                            next_image_callback=on_image)
    except Exception as e:  # pycolmap raises several types for C++ check failures
        raise EstimationError(f"incremental mapping failed: {_one_line(e)}") from None
    finally:
        shutil.rmtree(scratch, ignore_errors=True)


def _models_by_size(models, warnings):
    """The models, most registered frames (then 3D points) first; a warning when several."""
    recs = sorted(models.values(), key=lambda r: (r.num_reg_images(), r.num_points3D()), reverse=True)
    sizes = [int(r.num_reg_images()) for r in recs]
    if len(recs) > 1:
        warnings.append(f"mapping split the frames into {len(recs)} models of {', '.join(map(str, sizes))} "
                        "frames; using the largest (sparse/0)")
    return recs


def _check_camera_unchanged(rec, colmap_cam, want_params, camera):
    """EstimationError unless the model holds one camera bit-identical to the input."""
    cams = list(rec.cameras.values())
    got = [np.array(c.params, dtype=float) for c in cams]
    unchanged = (len(cams) == 1 and cams[0].model.name == colmap_cam.model.name
                 and int(cams[0].width) == camera.width and int(cams[0].height) == camera.height
                 and got[0].shape == want_params.shape and got[0].tobytes() == want_params.tobytes())
    if not unchanged:
        raise EstimationError("COLMAP changed the camera it was told to hold fixed "
                              f"({colmap_cam.params.tolist()} -> {[g.tolist() for g in got]})")


def _frames_of_model(items, rec):
    """One SfmFrame per input frame, with its pose where the model `rec` registered it, and
    why not where it did not."""
    frames = []
    for x in items:
        frames.append(SfmFrame(x.name, x.index, colmap_name=x.colmap_name, error=x.error,
                               num_features=x.num_features))
    by_name = {f.colmap_name: f for f in frames if f.colmap_name is not None}
    for im in rec.images.values():
        f = by_name.get(im.name)
        if f is None or not im.has_pose:
            continue
        pose = im.cam_from_world()
        R = np.array(pose.rotation.matrix(), dtype=float)
        t = np.array(pose.translation, dtype=float).reshape(3)
        f.registered = True
        f.R_cam_from_world = R
        f.t_cam_from_world = t
        f.camera_center = -R.T @ t
        f.num_points3D = int(im.num_points3D)
        f.error = None
    for f in frames:
        if f.registered or f.error is not None:
            continue
        if f.num_features < MIN_FEATURES:
            f.error = f"not registered: only {f.num_features} SIFT features"
        else:
            f.error = "not registered"
    return frames


def _check_registered(frames, min_registered, warnings):
    """The number of registered frames; EstimationError below `min_registered`, a warning
    naming the frames mapping left out."""
    n_reg = sum(f.registered for f in frames)
    if n_reg < min_registered:
        raise EstimationError(f"only {n_reg} of {len(frames)} frames registered (--min-registered {min_registered})")
    bad = [f.image for f in frames if not f.registered and f.error and f.error.startswith("not registered")]
    if bad:
        shown = ", ".join(bad[:5]) + (", ..." if len(bad) > 5 else "")
        warnings.append(f"{len(bad)} of {len(frames)} frames not registered: {shown}")
    return n_reg


def _write_models(recs, sparse):
    """Every model under ``sparse/<k>`` (sparse/0 the kept one), binary and text side by side."""
    for k, r in enumerate(recs):
        out = sparse / str(k)
        out.mkdir(parents=True, exist_ok=True)
        r.write_binary(str(out))
        r.write_text(str(out))


def _one_line(e) -> str:
    """First informative line of an exception (COLMAP check failures span several)."""
    lines = [ln.strip() for ln in str(e).splitlines() if ln.strip()]
    line = lines[0] if lines else type(e).__name__
    # "[file.cc:123] Check failed: x ..." -> keep the message, drop the source location
    return re.sub(r"^\S+\.(cc|h|cpp):\d+\]?\s*", "", line)


def bare_pycolmap(image_dir, camera, workdir, *, matching="auto", max_features=DEFAULT_MAX_FEATURES, seed=0,
                  num_threads=-1):
    """The reconstruction `reconstruct` makes, as the bare pycolmap calls: the baseline of
    the ``sfm_vs_pycolmap`` benchmark (validation/bench.py).

    Same camera in the database, same options (`options.pycolmap_options`), same seeds and log routing
    (``workdir/colmap.log``); none of the wrapper's own work: no decoding or size checks,
    no progress, no failure diagnosis, no pose extraction, no text model.

    Parameters
    ----------
    image_dir : str or Path
        A folder of images COLMAP reads (all of its images are used).
    camera : Camera
    workdir : str or Path
        Gets ``database.db``, ``sparse/<k>`` (binary, as pycolmap writes them), ``colmap.log``.
    matching, max_features, seed, num_threads
        As for `reconstruct`.

    Returns
    -------
    int
        Registered images of the largest model (0 when mapping found none).
    """
    pycolmap = import_pycolmap()

    workdir = Path(workdir)
    workdir.mkdir(parents=True, exist_ok=True)
    db_path = workdir / "database.db"
    n = sum(1 for p in Path(image_dir).iterdir() if p.suffix.lower() in COLMAP_READS)
    mode = choose_matching(matching, n)
    colmap_cam = camera_to_colmap(camera, 1, source="camera")
    colmap_cam.has_prior_focal_length = True
    with colmap_logging(workdir / "colmap.log"):
        if seed is not None and seed >= 0:
            pycolmap.set_random_seed(int(seed))
        cam_id = write_camera_db(db_path, colmap_cam)
        reader, extraction, matcher, verification, pairing, options = pycolmap_options(cam_id, max_features,
                                                                                         num_threads, seed)
        pycolmap.extract_features(str(db_path), str(image_dir), camera_mode=pycolmap.CameraMode.SINGLE,
                                  reader_options=reader, extraction_options=extraction, device=pycolmap.Device.cpu)
        if mode == "exhaustive":
            pycolmap.match_exhaustive(str(db_path), matching_options=matcher, verification_options=verification,
                                      device=pycolmap.Device.cpu)
        else:
            pycolmap.match_sequential(str(db_path), matching_options=matcher, pairing_options=pairing,
                                      verification_options=verification, device=pycolmap.Device.cpu)
        (workdir / "sparse").mkdir(exist_ok=True)
        models = pycolmap.incremental_mapping(str(db_path), str(image_dir), str(workdir / "sparse"), options=options)
    return max((int(r.num_reg_images()) for r in models.values()), default=0)
