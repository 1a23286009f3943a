"""What COLMAP is told: the matching modes and feature limits, and the pycolmap option
objects that `reconstruct` and `bare_pycolmap` share (so the benchmark compares the same
work). The intrinsics are held fixed: no bundle adjustment or pose registration refines
the focal length, principal point or distortion, and the camera is listed as constant.

Example
-------
>>> choose_matching("auto", 12), choose_matching("auto", 41)
('exhaustive', 'sequential')
>>> reader, extraction, matcher, verification, pairing, mapper = pycolmap_options(1, 2048, -1, 0)
>>> extraction.sift.max_num_features, pairing.overlap, mapper.ba_refine_focal_length
(2048, 10, False)
"""
from __future__ import annotations

import contextlib

from pencilcal.toolkit.errors import InputError

from .glog import import_pycolmap

__all__ = ["MATCHING_MODES", "DEFAULT_MAX_FEATURES", "DEFAULT_MIN_REGISTERED", "EXHAUSTIVE_MAX_IMAGES",
           "SEQUENTIAL_OVERLAP", "MIN_FEATURES", "COLMAP_READS", "choose_matching", "pycolmap_options",
           "write_camera_db"]

MATCHING_MODES = ("auto", "sequential", "exhaustive")
#: COLMAP's default cap on SIFT features per image.
DEFAULT_MAX_FEATURES = 8192
#: Fewer registered frames than this is a failure (a pair alone always registers).
DEFAULT_MIN_REGISTERED = 3
#: ``auto`` matching: exhaustive (n^2/2 pairs, order-free) up to this many images.
EXHAUSTIVE_MAX_IMAGES = 40
#: ``sequential`` matching: each frame is matched with this many following frames.
SEQUENTIAL_OVERLAP = 10
#: A frame with fewer SIFT features cannot seed a reconstruction (COLMAP's initial pair
#: needs 100 inlier matches, init_min_num_inliers) and hardly registers (30 inliers).
MIN_FEATURES = 100
#: Image formats every COLMAP build reads itself; anything else is decoded here and written as PNG.
COLMAP_READS = frozenset({".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff"})


def choose_matching(matching, n_images):
    """The matching mode for `n_images`: ``auto`` -> exhaustive up to
    `EXHAUSTIVE_MAX_IMAGES` images, else sequential. InputError for an unknown mode."""
    if matching not in MATCHING_MODES:
        raise InputError(f"unknown matching mode {matching!r}; expected one of {', '.join(MATCHING_MODES)}")
    if matching == "auto":
        return "exhaustive" if n_images <= EXHAUSTIVE_MAX_IMAGES else "sequential"
    return matching


def pycolmap_options(camera_id, max_features, num_threads, seed):
    """pycolmap options shared by `reconstruct` and `bare_pycolmap` (so the benchmark
    compares the same work): (reader, extraction, matcher, verification, pairing, mapper).

    camera_id: the database's one camera; max_features: SIFT features per image;
    num_threads: -1 for all cores; seed: RANSAC and mapper seed (None or < 0: random).
    """
    pycolmap = import_pycolmap()

    reader = pycolmap.ImageReaderOptions()
    reader.existing_camera_id = int(camera_id)
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.sift.max_num_features = int(max_features)
    extraction.num_threads = int(num_threads)
    extraction.use_gpu = False
    matcher = pycolmap.FeatureMatchingOptions()
    matcher.num_threads = int(num_threads)
    matcher.use_gpu = False
    verification = pycolmap.TwoViewGeometryOptions()
    pairing = pycolmap.SequentialPairingOptions()
    # linear overlap: each frame with its next SEQUENTIAL_OVERLAP frames (COLMAP's quadratic
    # overlap pairs frame i with i + 2^k only, reaching far beyond what a video overlaps)
    pairing.overlap = SEQUENTIAL_OVERLAP
    pairing.quadratic_overlap = False
    pairing.loop_detection = False
    pairing.num_threads = int(num_threads)
    mapper = pycolmap.IncrementalPipelineOptions()
    mapper.ba_refine_focal_length = False
    mapper.ba_refine_principal_point = False
    mapper.ba_refine_extra_params = False
    # COLMAP overwrites these from the two ba_refine_* above when registering an image
    # (IncrementalPipelineOptions::Mapper); set them too so the intent holds in any version
    mapper.mapper.abs_pose_refine_focal_length = False
    mapper.mapper.abs_pose_refine_extra_params = False
    mapper.constant_cameras = {int(camera_id)}
    mapper.num_threads = int(num_threads)
    if seed is not None and seed >= 0:
        verification.ransac.random_seed = int(seed)
        mapper.random_seed = int(seed)
    return reader, extraction, matcher, verification, pairing, mapper


def write_camera_db(db_path, colmap_cam):
    """Write `colmap_cam` (pycolmap.Camera) into the database at `db_path` (created if
    missing) under its own id; returns that id."""
    pycolmap = import_pycolmap()

    with contextlib.closing(pycolmap.Database.open(str(db_path))) as db:
        return db.write_camera(colmap_cam, use_camera_id=True)
