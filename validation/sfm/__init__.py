"""Structure from motion with the intrinsics held fixed (pycolmap), for validation.

`reconstruct` runs COLMAP's incremental pipeline through pycolmap on a sequence of frames
seen by one calibrated camera and returns every frame's pose ``R_cam_from_world``,
``t_cam_from_world`` (p_cam = R p_world + t) in the reconstruction's own world frame
(arbitrary rotation, translation and scale; validation/align.py maps it onto the board
frame). The calibrated intrinsics are never refined: a reconstruction that may change the
camera could absorb a calibration error into the lens and hide it.

Pipeline
--------
1. Frames: a folder, glob or video (toolkit/io/images.py), or a list of frames, paths or
   arrays. Every frame is decoded once to check its size against the camera (InputError
   on a mismatch) and to skip undecodable ones (reported per frame). Files COLMAP reads
   itself (png, jpg, bmp, tif) are read in place; video frames and other formats are
   written as PNG under ``workdir/images``. COLMAP names images by their path relative
   to one image folder, so files from several folders, duplicate names, or (for
   sequential matching, which pairs images in *byte* order of their names) names whose
   byte order is not the frame order are linked into ``workdir/images`` under names
   prefixed with the frame index. Each frame's result keeps the input name.
2. One camera in the database, ``toolkit.camera.formats.camera_to_colmap(camera)`` (model mapping and
   the +0.5 px principal-point shift to COLMAP's pixel convention), written before
   extraction and shared by every image (``CameraMode.SINGLE`` with
   ``ImageReaderOptions.existing_camera_id``): the parameters reach COLMAP as doubles,
   never through COLMAP's text parsing of ``camera_params``.
3. SIFT on the CPU (``pycolmap.extract_features``), at most `max_features` per image.
4. Matching: ``exhaustive`` (every pair) or ``sequential`` (each frame with its next
   `SEQUENTIAL_OVERLAP` frames, loop detection off: ordered video frames). ``auto`` is
   exhaustive up to `EXHAUSTIVE_MAX_IMAGES` images, sequential beyond.
5. ``pycolmap.incremental_mapping`` with ``ba_refine_focal_length``,
   ``ba_refine_principal_point`` and ``ba_refine_extra_params`` false (COLMAP also uses
   the first and last for ``abs_pose_refine_*`` when registering an image: colmap
   src/colmap/controllers/incremental_pipeline.cc, IncrementalPipelineOptions::Mapper),
   and the camera listed in ``constant_cameras``. After mapping the camera's parameters
   are checked to be bit-identical to the input (EstimationError otherwise).
6. Several models: the largest (most registered frames) is kept as ``sparse/0`` and the
   others follow in decreasing size (``sparse/1``, ...), with a warning.

Output (``workdir``, COLMAP's project layout)
---------------------------------------------
``database.db``          features, matches and two-view geometries (COLMAP GUI: File >
                         Import model needs it to show matches)
``sparse/0/``            the model, binary (``cameras.bin`` ``images.bin``
                         ``points3D.bin`` ``rigs.bin`` ``frames.bin``, what COLMAP and its
                         GUI read first) *and* text (``*.txt``, for people)
``sparse/1/`` ...        smaller models, when mapping split the sequence
``images/``              decoded frames or links (only when needed; removed unless
                         ``keep_frames``)
``colmap.log``           pycolmap's own log of this run (nothing reaches the terminal
                         unless ``verbose``)

`bare_pycolmap` makes the same reconstruction with the bare pycolmap calls (same options and
seeds), the baseline of the ``sfm_vs_pycolmap`` benchmark.

`write_sfm_poses` writes ``poses.json`` (per frame ``image``, ``registered``,
``R_cam_from_world``, ``t_cam_from_world``, ``camera_center``; plus the summary) and
`read_sfm_poses` reads it back (`poses_file`). It is not the board poses.json of
`pencilcal pnp` (`pencilcal.validation.pnp.read_board_poses`): there the board's pose in
each camera, here the cameras' poses in the reconstruction's own arbitrary world frame.

Logging: pycolmap logs through glog, by default on stderr *and* into files under /tmp.
For the duration of `reconstruct` its log goes to ``workdir/colmap.log`` only (and to
stderr as well with ``verbose``); afterwards glog's file logging stays off and its other
settings are restored.

Progress: the ``progress(stage, done, total)`` callback hears extraction (images) and
matching (image pairs) from COLMAP's own progress lines in that log, read by a thread
while pycolmap works; never from ``database.db``, which COLMAP holds in WAL mode with a
memory-mapped index that a second SQLite library in the process must not touch.

Modules
-------
``pipeline``     `reconstruct` in named steps, and `bare_pycolmap`
``prepare``      step 1: the frames, checked, and what COLMAP reads
``options``      matching modes, feature limits, the pycolmap options shared with the baseline
``progress``     progress of extraction and matching, followed in COLMAP's log
``glog``         `import_pycolmap` (every pycolmap import goes through it) and `colmap_logging`
``result``       `SfmFrame`, `SfmResult`, the typed results
``poses_file``   the sfm poses.json: `write_sfm_poses`, `read_sfm_poses`

Example
-------
A 12-frame orbit around the printed sheet at 640x360 (about 10 s on two cores):

>>> import tempfile                                                     # doctest: +SKIP
>>> from pencilcal.toolkit.synth.scenarios import make_scenario                  # doctest: +SKIP
>>> sc = make_scenario("orbit", frames=12, seed=1, size=(640, 360))     # doctest: +SKIP
>>> frames = [sc.render(i) for i in range(len(sc))]                     # doctest: +SKIP
>>> res = reconstruct(frames, sc.camera, tempfile.mkdtemp(), max_features=2048)  # doctest: +SKIP
>>> res.n_registered, res.camera_unchanged                              # doctest: +SKIP
(12, True)
>>> names, R_cam_from_world = res.rotations()                           # doctest: +SKIP
>>> R_cam_from_world.shape                                              # doctest: +SKIP
(12, 3, 3)
"""
from __future__ import annotations

from .glog import colmap_logging, import_pycolmap
from .options import (
    DEFAULT_MAX_FEATURES,
    DEFAULT_MIN_REGISTERED,
    EXHAUSTIVE_MAX_IMAGES,
    MATCHING_MODES,
    MIN_FEATURES,
    SEQUENTIAL_OVERLAP,
    choose_matching,
)
from .poses_file import CONVENTION, read_sfm_poses, write_sfm_poses
from .pipeline import bare_pycolmap, reconstruct
from .result import STAGES, SfmFrame, SfmResult

#: The names these had when sfm was one module (`pencilcal sfm` still imports them so).
read_poses = read_sfm_poses
write_poses = write_sfm_poses

__all__ = [
    "MATCHING_MODES",
    "DEFAULT_MAX_FEATURES",
    "DEFAULT_MIN_REGISTERED",
    "EXHAUSTIVE_MAX_IMAGES",
    "SEQUENTIAL_OVERLAP",
    "MIN_FEATURES",
    "STAGES",
    "CONVENTION",
    "SfmFrame",
    "SfmResult",
    "reconstruct",
    "bare_pycolmap",
    "choose_matching",
    "write_sfm_poses",
    "read_sfm_poses",
    "write_poses",
    "read_poses",
    "colmap_logging",
    "import_pycolmap",
]
