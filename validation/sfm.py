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
2. One camera in the database, ``camera_io.camera_to_colmap(camera)`` (model mapping and
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

`write_poses` writes ``poses.json`` (per frame ``image``, ``registered``,
``R_cam_from_world``, ``t_cam_from_world``, ``camera_center``; plus the summary) and
`read_poses` reads it back.

Logging: pycolmap logs through glog, by default on stderr *and* into files under /tmp.
For the duration of `reconstruct` its log goes to ``workdir/colmap.log`` only (and to
stderr as well with ``verbose``); afterwards glog's file logging stays off and its other
settings are restored.

Progress: the ``progress(stage, done, total)`` callback hears extraction (images) and
matching (image pairs) from COLMAP's own progress lines in that log, read by a thread
while pycolmap works; never from ``database.db``, which COLMAP holds in WAL mode with a
memory-mapped index that a second SQLite library in the process must not touch.

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

import contextlib
import os
import re
import shutil
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pencilcal.toolkit.camera.model import Camera
from pencilcal.toolkit.camera.formats import camera_to_colmap, camera_to_dict
from pencilcal.toolkit.errors import EstimationError, InputError
from pencilcal.toolkit.io.files import load_frames, write_json
from pencilcal.toolkit.io.images import IMAGE_EXTENSIONS, Frame, ImageSource, check_image_size, open_images

__all__ = [
    "MATCHING_MODES",
    "DEFAULT_MAX_FEATURES",
    "DEFAULT_MIN_REGISTERED",
    "EXHAUSTIVE_MAX_IMAGES",
    "SEQUENTIAL_OVERLAP",
    "MIN_FEATURES",
    "STAGES",
    "SfmFrame",
    "SfmResult",
    "reconstruct",
    "bare_pycolmap",
    "choose_matching",
    "write_poses",
    "read_poses",
    "colmap_logging",
]

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
#: Stages reported to the progress callback, in order, and timed in `SfmResult.timings`.
STAGES = ("prepare", "extract", "match", "map", "write")

# Formats every COLMAP build reads itself; anything else is decoded here and written as PNG.
_COLMAP_READS = {".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff"}
_POLL_S = 0.25
_POSE_KEYS = ("image", "registered", "R_cam_from_world", "t_cam_from_world", "camera_center")
CONVENTION = ("p_cam = R_cam_from_world p_world + t_cam_from_world (OpenCV camera frame: x right, y down, "
              "z forward); camera_center = -R^T t in the world frame; the world frame and its scale are "
              "the reconstruction's own (arbitrary; validation/align.py maps it onto the board frame); "
              "camera intrinsics held fixed at the input camera")


# --------------------------------------------------------------------------- results
@dataclass
class SfmFrame:
    """One input frame's result.

    Attributes
    ----------
    image : str
        The input frame's name (file name, or frame_000123 for a video frame).
    index : int
        Position in the input sequence.
    registered : bool
        True when the kept model holds a pose for this frame.
    R_cam_from_world : (3, 3) ndarray or None
        Rotation world -> camera (OpenCV camera frame).
    t_cam_from_world : (3,) ndarray or None
        Translation, in the reconstruction's arbitrary length unit.
    camera_center : (3,) ndarray or None
        Camera centre in the world frame, ``-R^T t``.
    colmap_name : str or None
        The image's name in the COLMAP database and model (None when never given to COLMAP).
    num_features : int
        SIFT features extracted (0 when not extracted).
    num_points3D : int
        Features of this frame that are observations of a 3D point of the kept model.
    error : str or None
        Why the frame has no pose (undecodable, too few features, not registered).
    """

    image: str
    index: int
    registered: bool = False
    R_cam_from_world: np.ndarray | None = None
    t_cam_from_world: np.ndarray | None = None
    camera_center: np.ndarray | None = None
    colmap_name: str | None = None
    num_features: int = 0
    num_points3D: int = 0
    error: str | None = None

    def to_dict(self):
        return {
            "image": self.image,
            "index": self.index,
            "registered": bool(self.registered),
            "error": self.error,
            "R_cam_from_world": None if self.R_cam_from_world is None else self.R_cam_from_world.tolist(),
            "t_cam_from_world": None if self.t_cam_from_world is None else self.t_cam_from_world.tolist(),
            "camera_center": None if self.camera_center is None else self.camera_center.tolist(),
            "colmap_name": self.colmap_name,
            "num_features": int(self.num_features),
            "num_points3D": int(self.num_points3D),
        }


@dataclass
class SfmResult:
    """What `reconstruct` found.

    Attributes
    ----------
    frames : list of SfmFrame
        One per input frame, in input order.
    camera : Camera
        The camera the reconstruction used (the input; unchanged).
    n_registered, n_points3D : int
        Registered frames and 3D points of the kept model.
    mean_reprojection_error_px : float
        COLMAP's mean reprojection error over the kept model's observations [px].
    matching : str
        "exhaustive" or "sequential" (what "auto" chose).
    max_features : int
    n_models : int
        Models mapping produced; the largest is kept (``sparse/0``).
    model_sizes : list of int
        Registered frames per model, largest first.
    workdir, model_path, database_path : Path
        ``workdir``, ``workdir/sparse/0`` and ``workdir/database.db``.
    image_path : str or None
        The folder COLMAP read the images from (None once a staged folder is removed).
    timings : dict
        Seconds per stage (`STAGES`) and ``total``.
    camera_unchanged : bool
        The model's camera parameters are bit-identical to the input (always true for a
        returned result: anything else raises).
    pycolmap_version : str
    warnings : list of str
        One-line warnings (several models, frames not registered or undecodable).
    reconstruction : pycolmap.Reconstruction or None
        The kept model in memory (not written to poses.json).
    """

    frames: list
    camera: Camera
    n_registered: int
    n_points3D: int
    mean_reprojection_error_px: float
    matching: str
    max_features: int
    n_models: int
    model_sizes: list
    workdir: Path
    model_path: Path
    database_path: Path
    image_path: str | None
    timings: dict
    camera_unchanged: bool
    pycolmap_version: str
    warnings: list = field(default_factory=list)
    reconstruction: object = None

    @property
    def n_frames(self):
        return len(self.frames)

    @property
    def registered(self):
        """(N,) bool: which frames have a pose."""
        return np.array([f.registered for f in self.frames], bool)

    def frame(self, image):
        """The SfmFrame of the input frame named `image` (KeyError if none)."""
        for f in self.frames:
            if f.image == image:
                return f
        raise KeyError(image)

    def rotations(self):
        """(names, R_cam_from_world (K, 3, 3)) over the registered frames, in input order."""
        reg = [f for f in self.frames if f.registered]
        R = np.array([f.R_cam_from_world for f in reg]).reshape(-1, 3, 3)
        return [f.image for f in reg], R

    def summary(self, relative_to=None):
        """The summary keys of poses.json (paths relative to `relative_to` when given)."""
        def rel(p):
            if p is None:
                return None
            if relative_to is None:
                return str(p)
            try:
                return os.path.relpath(p, relative_to)
            except ValueError:  # another drive (Windows)
                return str(p)

        image_path = self.image_path
        if image_path is not None and relative_to is not None and Path(image_path).is_relative_to(self.workdir):
            image_path = rel(image_path)
        return {
            "frames_count": self.n_frames,
            "registered_count": self.n_registered,
            "points3D_count": self.n_points3D,
            "mean_reprojection_error_px": self.mean_reprojection_error_px,
            "matching": self.matching,
            "max_features": self.max_features,
            "models_count": self.n_models,
            "model_sizes": list(self.model_sizes),
            "model": rel(self.model_path),
            "database": rel(self.database_path),
            "image_path": image_path,
            "camera": camera_to_dict(self.camera),
            "camera_unchanged": bool(self.camera_unchanged),
            "timings_s": dict(self.timings),
            "pycolmap_version": self.pycolmap_version,
            "warnings": list(self.warnings),
        }


# --------------------------------------------------------------------------- helpers
def _one_line(e) -> str:
    """First informative line of an exception (COLMAP check failures span several)."""
    lines = [ln.strip() for ln in str(e).splitlines() if ln.strip()]
    line = lines[0] if lines else type(e).__name__
    # "[file.cc:123] Check failed: x ..." -> keep the message, drop the source location
    return re.sub(r"^\S+\.(cc|h|cpp):\d+\]?\s*", "", line)


def choose_matching(matching, n_images):
    """The matching mode for `n_images`: ``auto`` -> exhaustive up to
    `EXHAUSTIVE_MAX_IMAGES` images, else sequential. InputError for an unknown mode."""
    if matching not in MATCHING_MODES:
        raise InputError(f"unknown matching mode {matching!r}; expected one of {', '.join(MATCHING_MODES)}")
    if matching == "auto":
        return "exhaustive" if n_images <= EXHAUSTIVE_MAX_IMAGES else "sequential"
    return matching


def _sequential_pair_count(n, overlap, of=None):
    """Pairs COLMAP's sequential matcher visits without quadratic overlap or loops, for the
    first `n` images of `of` (default `n`) images."""
    of = n if of is None else of
    return sum(min(overlap, of - 1 - i) for i in range(n))


def _glog_base(log_path):
    """glog names its file ``<base>YYYYmmdd-HHMMSS.pid``; `colmap_logging` renames it."""
    return Path(log_path).with_name(Path(log_path).name + ".")


@contextlib.contextmanager
def colmap_logging(log_path=None, verbose=False):
    """Route pycolmap's glog output for the duration of the block.

    Without `verbose` nothing reaches stderr (glog's stderr threshold is raised to FATAL,
    which aborts anyway); with a `log_path` every message is written there (glog names
    its file ``<base>YYYYmmdd-HHMMSS.pid``; it is renamed to `log_path` at the end).
    glog's own log files under /tmp stay off afterwards; the other settings come back.
    """
    import pycolmap

    L = pycolmap.logging
    saved = {k: getattr(L, k) for k in ("minloglevel", "logtostderr", "alsologtostderr", "stderrthreshold")}
    levels = (L.Level.INFO, L.Level.WARNING, L.Level.ERROR, L.Level.FATAL)
    base = None
    try:
        # INFO's file receives every severity; the others would duplicate it
        for lv in levels:
            L.set_log_destination(lv, "")
        if log_path is not None:
            base = str(_glog_base(log_path))
            L.set_log_destination(L.Level.INFO, base)
        L.logtostderr = False
        L.alsologtostderr = bool(verbose)
        L.stderrthreshold = 0 if verbose else 3
        L.minloglevel = 0 if (verbose or log_path is not None) else 2
        yield
    finally:
        # an empty destination closes (and so flushes) glog's file
        for lv in levels:
            L.set_log_destination(lv, "")
        for k, v in saved.items():
            setattr(L, k, v)
        if base is not None:
            made = sorted(Path(base).parent.glob(Path(base).name + "*"))
            if made:
                with contextlib.suppress(OSError):
                    os.replace(made[-1], log_path)


# COLMAP's own progress lines (glog, INFO): an image written to the database; the start of
# a sequential matcher's image; the start of an exhaustive matcher's block of pairs.
_EXTRACTED = re.compile(rb"Processed file \[(\d+)/(\d+)\]")
_SEQUENTIAL = re.compile(rb"Processing image \[(\d+)/(\d+)\]")
_BLOCK = re.compile(rb"Processing block \[(\d+)/(\d+), (\d+)/(\d+)\]")


class _LogProgress:
    """Follows a stage of COLMAP in its glog file while pycolmap works (it releases the
    GIL), for a progress bar on extraction and matching. Any error just stops reporting.

    `done_of(match)` turns the newest progress line of `pattern` into units done. The log,
    not the database: COLMAP keeps ``database.db`` in WAL mode with a memory-mapped index,
    and a second SQLite library in the process (Python's sqlite3) shares its POSIX locks,
    so opening and closing the file beside it can truncate that index under COLMAP: a bus
    error (https://www.sqlite.org/howtocorrupt.html, 2.2). glog writes each line through
    at once because `pencilcal.toolkit` sets GLOG_logbuflevel=-1 before pycolmap loads;
    where pycolmap was loaded first the lines arrive in 4 KiB blocks, the bar in steps.
    """

    def __init__(self, log_base, pattern, done_of, stage, total, progress):
        self.log_base, self.pattern, self.done_of = Path(log_base), pattern, done_of
        self.stage, self.total, self.progress = stage, total, progress
        self._stop = threading.Event()
        self._thread = None
        self._file, self._offset, self._tail = None, 0, b""

    def __enter__(self):
        if self.progress is not None:
            self.progress(self.stage, 0, self.total)
            self._thread = threading.Thread(target=self._run, daemon=True)
            self._thread.start()
        return self

    def _newest(self):
        """The units done by the newest progress line written since the last call, or None."""
        made = sorted(self.log_base.parent.glob(self.log_base.name + "*"))
        if not made:
            return None
        if made[-1] != self._file:  # glog opened its file (or a new one): read it whole
            self._file, self._offset, self._tail = made[-1], 0, b""
        with open(self._file, "rb") as f:
            f.seek(self._offset)
            chunk = f.read()
        self._offset += len(chunk)
        lines = (self._tail + chunk).split(b"\n")
        self._tail = lines.pop()  # a line still being written
        found = [m for m in map(self.pattern.search, lines) if m]
        return self.done_of(found[-1]) if found else None

    def _run(self):
        last = 0  # __enter__ reported 0
        while not self._stop.wait(_POLL_S):
            try:
                n = self._newest()
            except Exception:  # an unreadable log: stop reporting, never the work
                return
            if n is None:
                continue
            n = max(0, min(int(n), self.total))
            if n > last:
                last = n
                try:
                    self.progress(self.stage, n, self.total)
                except Exception:  # a broken progress display must not stop the work
                    return

    def __exit__(self, *exc):
        if self._thread is not None:
            self._stop.set()
            self._thread.join()
            if exc[0] is None:
                self.progress(self.stage, self.total, self.total)
        return False


def _extract_progress(log_base, n_images, progress):
    """Progress of feature extraction in images written to the database."""
    return _LogProgress(log_base, _EXTRACTED, lambda m: int(m[1]), "extract", n_images, progress)


def _match_progress(log_base, mode, n_images, progress):
    """Progress of matching in image pairs matched and verified.

    Sequential: COLMAP starts image k once the pairs of images 1..k-1 are done (exact).
    Exhaustive: it works through nb x nb blocks of about equally many pairs each (COLMAP
    spreads the pairs so), so the pairs done are estimated from the blocks done.
    """
    if mode == "exhaustive":
        total = n_images * (n_images - 1) // 2

        def done_of(m):
            a, nb, b = int(m[1]), int(m[2]), int(m[3])
            return total * ((a - 1) * nb + (b - 1)) // max(nb * nb, 1)

        return _LogProgress(log_base, _BLOCK, done_of, "match", total, progress)
    total = _sequential_pair_count(n_images, SEQUENTIAL_OVERLAP)
    return _LogProgress(log_base, _SEQUENTIAL,
                        lambda m: _sequential_pair_count(int(m[1]) - 1, SEQUENTIAL_OVERLAP, n_images),
                        "match", total, progress)


# --------------------------------------------------------------------------- frames
@dataclass
class _Item:
    name: str                 # the input frame's name
    index: int
    source: str | None        # a file COLMAP can read in place, else None
    error: str | None = None  # undecodable
    colmap_name: str | None = None
    num_features: int = 0


def _frames_of(images):
    """Iterate (Frame) over any accepted input; also say whether it is a video."""
    if isinstance(images, ImageSource):
        return iter(images), images.count, images.kind == "video", images.description
    if isinstance(images, (str, os.PathLike)):
        src = open_images(images)
        return iter(src), src.count, src.kind == "video", src.description
    items = list(images)

    def gen():
        for i, it in enumerate(items):
            if isinstance(it, Frame):
                yield Frame(it.name, i, it.image, it.error, it.path)
            elif isinstance(it, np.ndarray):
                yield Frame(f"{i:06d}", i, it, None, None)
            elif isinstance(it, (str, os.PathLike)):
                p = Path(it)
                if not p.is_file():
                    raise InputError(f"{p}: no such image file")
                fr = next(iter(ImageSource(p)))
                yield Frame(fr.name, i, fr.image, fr.error, fr.path)
            else:
                raise InputError(f"frame {i}: expected an image array, a Frame or a path, got {type(it).__name__}")

    return gen(), len(items), False, f"{len(items)} frames"


def _png_name(name):
    """A decoded frame's file name: its name with .png for its image extension, if any."""
    p = Path(name)
    return (p.stem if p.suffix.lower() in IMAGE_EXTENSIONS else name) + ".png"


def _prepare(images, camera, workdir, matching, min_registered, progress):
    """Check every frame and decide what COLMAP reads.

    Returns (items, image_path, names, mode, staged): staged is true when image_path is
    the folder made here (``workdir/images``), never the input's own folder.
    """
    import cv2

    it, count, is_video, desc = _frames_of(images)
    stage_dir = Path(workdir) / "images"
    staged = []

    def stage():
        # never write into a folder that was there before (it may hold the input images)
        if not staged:
            stage_dir.parent.mkdir(parents=True, exist_ok=True)
            try:
                stage_dir.mkdir()
            except FileExistsError:
                raise InputError(f"{stage_dir}: exists; give reconstruct an empty work folder") from None
            staged.append(stage_dir)
        return stage_dir

    items, decoded = [], {}
    for fr in it:
        if progress is not None:
            progress("prepare", fr.index + 1, max(count, fr.index + 1))
        if fr.image is None:
            items.append(_Item(fr.name, len(items), None, fr.error or "cannot decode the image"))
            continue
        check_image_size(fr, camera)
        direct = (not is_video and fr.path is not None and Path(fr.path).suffix.lower() in _COLMAP_READS
                  and Path(fr.path).is_file())
        item = _Item(fr.name, len(items), str(Path(fr.path).resolve()) if direct else None)
        if not direct:
            # written now as PNG (fast compression: a scratch copy), so no frame stays in memory
            img = fr.image
            if img.dtype not in (np.uint8, np.uint16):
                raise InputError(f"{fr.name}: image type {img.dtype} is neither 8 nor 16 bit")
            tmp = stage() / f".frame{item.index:09d}.png"
            if not cv2.imwrite(str(tmp), img, [cv2.IMWRITE_PNG_COMPRESSION, 1]):
                raise InputError(f"{tmp}: cannot write a decoded frame")
            decoded[item.index] = tmp
        items.append(item)
    good = [x for x in items if x.error is None]
    need = max(2, min_registered)
    if len(good) < need:
        got = f"{len(good)} decodable image{'s' if len(good) != 1 else ''}" + \
            (f" of {len(items)}" if len(items) != len(good) else "")
        raise InputError(f"{desc}: structure from motion needs at least {need} images "
                         f"(--min-registered {min_registered}); got {got}")
    mode = choose_matching(matching, len(good))

    # the input names when they are unique, sort in frame order (sequential matching pairs
    # images in byte order of their names) and, for files read in place, share one folder
    plain = [Path(x.source).name if x.source else _png_name(x.name) for x in good]
    unique = len(set(plain)) == len(plain)
    ordered = mode != "sequential" or plain == sorted(plain)
    folders = {str(Path(x.source).parent) for x in good if x.source}
    if not decoded and unique and ordered and len(folders) == 1:
        for x, n in zip(good, plain):
            x.colmap_name = n
        return items, folders.pop(), [x.colmap_name for x in good], mode, False
    width = max(6, len(str(len(items))))
    folder = stage()
    for x, n in zip(good, plain):
        x.colmap_name = n if unique and ordered else f"{x.index:0{width}d}_{n}"
        dst = folder / x.colmap_name
        if x.source is not None:
            try:
                os.symlink(x.source, dst)
            except OSError:  # no symlinks on this filesystem: copy
                shutil.copyfile(x.source, dst)
        else:
            os.replace(decoded[x.index], dst)
    return items, str(folder), [x.colmap_name for x in good], mode, True


# --------------------------------------------------------------------------- pycolmap options
def _options(camera_id, max_features, num_threads, seed):
    """pycolmap options shared by `reconstruct` and `bare_pycolmap` (so the benchmark
    compares the same work): (reader, extraction, matcher, verification, pairing, mapper)."""
    import pycolmap

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


def _write_camera_db(db_path, colmap_cam):
    import pycolmap

    with contextlib.closing(pycolmap.Database.open(str(db_path))) as db:
        return db.write_camera(colmap_cam, use_camera_id=True)


# --------------------------------------------------------------------------- reconstruct
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
        The calibrated camera; any model COLMAP holds exactly (`camera_io.camera_to_colmap`:
        pinhole, opencv with 4/5/8 coefficients, fisheye). Image size must match.
    workdir : str or Path
        Folder for COLMAP's project (module docstring); created if missing. It must not
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
    import pycolmap

    if not isinstance(camera, Camera):
        raise TypeError(f"expected a Camera, got {type(camera).__name__}")
    if matching not in MATCHING_MODES:
        raise InputError(f"unknown matching mode {matching!r}; expected one of {', '.join(MATCHING_MODES)}")
    if isinstance(max_features, bool) or not isinstance(max_features, (int, np.integer)) or max_features < 1:
        raise InputError(f"max_features must be a positive integer, got {max_features!r}")
    if isinstance(min_registered, bool) or not isinstance(min_registered, (int, np.integer)) or min_registered < 2:
        raise InputError(f"min_registered must be an integer >= 2, got {min_registered!r}")
    colmap_cam = camera_to_colmap(camera, 1, source="camera")
    colmap_cam.has_prior_focal_length = True
    want_params = np.array(colmap_cam.params, dtype=float)

    workdir = Path(workdir)
    if workdir.exists() and not workdir.is_dir():
        raise InputError(f"{workdir}: exists and is not a folder")
    for used in ("database.db", "sparse"):
        if (workdir / used).exists():
            raise InputError(f"{workdir}: already holds {used} (a previous reconstruction)")
    workdir.mkdir(parents=True, exist_ok=True)
    db_path = workdir / "database.db"
    sparse = workdir / "sparse"
    timings = {}
    warnings = []
    t_start = time.perf_counter()

    # ---- 1. frames
    t0 = time.perf_counter()
    items, image_path, names, mode, staged = _prepare(images, camera, workdir, matching, min_registered, progress)
    by_colmap = {x.colmap_name: x for x in items if x.colmap_name is not None}
    timings["prepare"] = time.perf_counter() - t0

    log_base = _glog_base(workdir / "colmap.log")
    with colmap_logging(workdir / "colmap.log", verbose):
        if seed is not None and seed >= 0:
            pycolmap.set_random_seed(int(seed))
        # ---- 2. the camera, then 3. SIFT
        t0 = time.perf_counter()
        try:
            cam_id = _write_camera_db(db_path, colmap_cam)
            reader, extraction, matcher, verification, pairing, options = _options(cam_id, max_features,
                                                                                     num_threads, seed)
            with _extract_progress(log_base, len(names), progress):
                pycolmap.extract_features(str(db_path), image_path, image_names=names,
                                          camera_mode=pycolmap.CameraMode.SINGLE, reader_options=reader,
                                          extraction_options=extraction, device=pycolmap.Device.cpu)
        except Exception as e:  # pycolmap raises several types for C++ check failures
            raise EstimationError(f"feature extraction failed: {_one_line(e)}") from None
        timings["extract"] = time.perf_counter() - t0

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

        # ---- 4. matching
        t0 = time.perf_counter()
        n_img = len(ids)
        try:
            with _match_progress(log_base, mode, n_img, progress):
                if mode == "exhaustive":
                    pycolmap.match_exhaustive(str(db_path), matching_options=matcher,
                                              verification_options=verification, device=pycolmap.Device.cpu)
                else:
                    pycolmap.match_sequential(str(db_path), matching_options=matcher, pairing_options=pairing,
                                              verification_options=verification,
                                              device=pycolmap.Device.cpu)
        except Exception as e:  # pycolmap raises several types for C++ check failures
            raise EstimationError(f"feature matching failed: {_one_line(e)}") from None
        timings["match"] = time.perf_counter() - t0
        with contextlib.closing(pycolmap.Database.open(str(db_path))) as db:
            n_verified = int(db.num_verified_image_pairs())
            n_pairs = int(db.num_matched_image_pairs())
        if n_verified == 0:
            raise EstimationError(
                f"no image pair matched: 0 of {n_pairs} pairs passed geometric verification "
                "(do the images overlap? are they of a static scene?)")

        # ---- 5. incremental mapping, intrinsics fixed
        t0 = time.perf_counter()
        scratch = workdir / ".mapper"
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
            models = pycolmap.incremental_mapping(str(db_path), image_path, str(scratch), options=options,
                                                  initial_image_pair_callback=on_pair,
                                                  next_image_callback=on_image)
        except Exception as e:  # pycolmap raises several types for C++ check failures
            raise EstimationError(f"incremental mapping failed: {_one_line(e)}") from None
        finally:
            shutil.rmtree(scratch, ignore_errors=True)
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
    recs = sorted(models.values(), key=lambda r: (r.num_reg_images(), r.num_points3D()), reverse=True)
    sizes = [int(r.num_reg_images()) for r in recs]
    rec = recs[0]
    if len(recs) > 1:
        warnings.append(f"mapping split the frames into {len(recs)} models of {', '.join(map(str, sizes))} "
                        "frames; using the largest (sparse/0)")
    cams = list(rec.cameras.values())
    got = [np.array(c.params, dtype=float) for c in cams]
    unchanged = (len(cams) == 1 and cams[0].model.name == colmap_cam.model.name
                 and int(cams[0].width) == camera.width and int(cams[0].height) == camera.height
                 and got[0].shape == want_params.shape and got[0].tobytes() == want_params.tobytes())
    if not unchanged:
        raise EstimationError("COLMAP changed the camera it was told to hold fixed "
                              f"({colmap_cam.params.tolist()} -> {[g.tolist() for g in got]})")

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
    n_reg = sum(f.registered for f in frames)
    if n_reg < min_registered:
        raise EstimationError(f"only {n_reg} of {len(frames)} frames registered (--min-registered {min_registered})")
    bad = [f.image for f in frames if not f.registered and f.error and f.error.startswith("not registered")]
    if bad:
        shown = ", ".join(bad[:5]) + (", ..." if len(bad) > 5 else "")
        warnings.append(f"{len(bad)} of {len(frames)} frames not registered: {shown}")

    # ---- write the models: sparse/0 the kept one; binary and text side by side
    for k, r in enumerate(recs):
        out = sparse / str(k)
        out.mkdir(parents=True, exist_ok=True)
        r.write_binary(str(out))
        r.write_text(str(out))
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
        max_features=int(max_features), n_models=len(recs), model_sizes=sizes, workdir=workdir,
        model_path=sparse / "0", database_path=db_path, image_path=image_path, timings=timings,
        camera_unchanged=True, pycolmap_version=str(pycolmap.__version__), warnings=warnings,
        reconstruction=rec)


def bare_pycolmap(image_dir, camera, workdir, *, matching="auto", max_features=DEFAULT_MAX_FEATURES, seed=0,
                  num_threads=-1):
    """The reconstruction `reconstruct` makes, as the bare pycolmap calls: the baseline of
    the ``sfm_vs_pycolmap`` benchmark (validation/bench.py).

    Same camera in the database, same options (`_options`), same seeds and log routing
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
    import pycolmap

    workdir = Path(workdir)
    workdir.mkdir(parents=True, exist_ok=True)
    db_path = workdir / "database.db"
    n = sum(1 for p in Path(image_dir).iterdir() if p.suffix.lower() in _COLMAP_READS)
    mode = choose_matching(matching, n)
    colmap_cam = camera_to_colmap(camera, 1, source="camera")
    colmap_cam.has_prior_focal_length = True
    with colmap_logging(workdir / "colmap.log"):
        if seed is not None and seed >= 0:
            pycolmap.set_random_seed(int(seed))
        cam_id = _write_camera_db(db_path, colmap_cam)
        reader, extraction, matcher, verification, pairing, options = _options(cam_id, max_features, num_threads,
                                                                                 seed)
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


# --------------------------------------------------------------------------- poses.json
def write_poses(path, result, force=False, **meta):
    """Write ``poses.json`` for a reconstruction, atomically.

    ``{**meta, **result.summary(...), "convention": ..., "frames": [...]}``; paths are
    relative to the file's folder. Each frame: ``image``, ``index``, ``registered``,
    ``error``, ``R_cam_from_world`` (3x3), ``t_cam_from_world``, ``camera_center``
    (world frame, reconstruction units; null when not registered), ``colmap_name``,
    ``num_features``, ``num_points3D``.
    """
    folder = Path(path).parent
    out = dict(meta)
    out.update(result.summary(relative_to=folder if str(folder) else "."))
    out["convention"] = CONVENTION
    out["frames"] = [f.to_dict() for f in result.frames]
    write_json(path, out, force=force)


def read_poses(path):
    """Read a ``poses.json`` written by `write_poses` (pencilcal sfm).

    Returns the file's object with ``frames`` a list of `SfmFrame` (arrays as ndarrays).
    InputError with a one-line reason for anything malformed.

    Example
    -------
    >>> d = read_poses("sfm/poses.json")                     # doctest: +SKIP
    >>> [f.image for f in d["frames"] if f.registered][:2]   # doctest: +SKIP
    ['000.png', '001.png']
    """
    data, frames = load_frames(path, "sfm poses file", _POSE_KEYS)
    out = []
    for i, (f, where) in enumerate(frames):
        if not isinstance(f["registered"], bool):
            raise InputError(f"{where}: 'registered' must be true or false")
        arrays = {}
        for k, shape in (("R_cam_from_world", (3, 3)), ("t_cam_from_world", (3,)), ("camera_center", (3,))):
            v = f.get(k)
            if v is None:
                if f["registered"]:
                    raise InputError(f"{where}: a registered frame needs '{k}'")
                arrays[k] = None
                continue
            try:
                a = np.array(v, dtype=float)
            except (TypeError, ValueError):
                raise InputError(f"{where}: '{k}' must be numbers") from None
            if a.shape != shape or not np.all(np.isfinite(a)):
                raise InputError(f"{where}: '{k}' must be {'x'.join(map(str, shape))} finite numbers")
            arrays[k] = a
        out.append(SfmFrame(str(f["image"]), int(f.get("index", i)), f["registered"], colmap_name=f.get("colmap_name"),
                            num_features=int(f.get("num_features") or 0),
                            num_points3D=int(f.get("num_points3D") or 0), error=f.get("error"), **arrays))
    res = dict(data)
    res["frames"] = out
    return res
