"""calib.json, the report of `pencilcal calibrate --report`: its writer and its one reader.

The report is a JSON object (docs/formats.md): the camera (``camera``, with its statistics),
per-view errors and rejections, counts, and what later estimates need to carry the
calibration's uncertainty: ``cov_intrinsics`` (``{"names", "cov"}``,
`toolkit.camera.intrinsics.IntrinsicsCovariance`), ``corner_noise`` (the correlated
corner-error model, `toolkit.board.corner_noise.CornerNoise`) and ``cross_validation``
(two halves of the views, `validation.calibration_checks.calibration_halves`), and the
verdict and the maps of `pencilcal calibrate` (docs/calibration.md).

`read_calibration_file` returns a typed `CalibrationFile`; `uncertainty_of` gives a
camera's intrinsics covariance and corner-noise model from a report or, without one, from
the camera file's own statistics. `board_model` gives a board's corners as the camera's
calibration measured them (its warp), for the board poses later estimated with that camera.

Example
-------
>>> import os, tempfile
>>> import numpy as np
>>> from pencilcal.toolkit.camera.model import Camera
>>> from pencilcal.toolkit.camera.formats import camera_to_dict
>>> cam = Camera("pinhole", 640, 480, [[500.0, 0, 319.5], [0, 500.0, 239.5], [0, 0, 1]])
>>> p = os.path.join(tempfile.mkdtemp(), "calib.json")
>>> write_calibration_file(p, {"command": "calibrate", "camera": camera_to_dict(cam),
...     "cov_intrinsics": {"names": ["fx", "fy", "cx", "cy"], "cov": np.eye(4).tolist()}})
>>> r = read_calibration_file(p)
>>> r.camera == cam, r.cov_intrinsics.std.tolist(), r.corner_noise
(True, [1.0, 1.0, 1.0, 1.0], None)
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pencilcal.toolkit.board.corner_noise import CornerNoise
from pencilcal.toolkit.camera.intrinsics import META_KEY, IntrinsicsCovariance, camera_intrinsics_covariance
from pencilcal.toolkit.errors import InputError
from pencilcal.toolkit.io.files import load_structured, write_json

__all__ = ["CalibrationFile", "write_calibration_file", "read_calibration_file", "uncertainty_of",
           "camera_with_report", "uncertainty_record", "board_model", "symmetric_corners_of", "CORNER_NOISE_KEY",
           "SYMMETRIC_KEY"]

#: The camera meta and report key of the corner-noise model.
CORNER_NOISE_KEY = "corner_noise"
#: The key, in the camera meta's ``calibration`` record, of whether the calibration's
#: ChArUco corners were refined to their point of symmetry (`detect.detect_board`).
SYMMETRIC_KEY = "symmetric_corners"


@dataclass(frozen=True, eq=False)
class CalibrationFile:
    """What a calib.json says about the camera's uncertainty.

    camera : Camera; cov_intrinsics : IntrinsicsCovariance or None; corner_noise :
    CornerNoise or None; cross_validation : dict or None (as written); source : the path.
    """

    camera: object
    cov_intrinsics: IntrinsicsCovariance | None
    corner_noise: CornerNoise | None
    cross_validation: dict | None
    source: str


def write_calibration_file(path, report, force=False):
    """Write the report dict (numpy inside is fine) atomically (`files.write_json`)."""
    write_json(path, report, force=force)


def read_calibration_file(path):
    """Read a calib.json into a `CalibrationFile`; InputError (one line, naming the file)
    when it is not one (no ``camera``) or a key is malformed. A report of an older
    pencilcal, without ``cov_intrinsics``, gives None there (its camera's statistics may
    still carry one)."""
    from pencilcal.toolkit.camera.formats import camera_from_dict

    data = load_structured(path, "calibration report")
    if not isinstance(data, dict) or not isinstance(data.get("camera"), dict):
        raise InputError(f"{path}: not a calibration report (no 'camera'; write one with `pencilcal calibrate "
                         "--report`)")
    camera = camera_from_dict(data["camera"], source=str(path))
    cov = data.get(META_KEY)
    cov = IntrinsicsCovariance.from_dict(cov, str(path)) if cov is not None else \
        camera_intrinsics_covariance(camera, str(path))
    if cov is not None:
        cov.for_camera(camera)
    noise = data.get(CORNER_NOISE_KEY, (camera.meta or {}).get(CORNER_NOISE_KEY))
    noise = None if noise is None else CornerNoise.from_dict(noise, str(path))
    cv = data.get("cross_validation")
    return CalibrationFile(camera, cov, noise, cv if isinstance(cv, dict) else None, str(path))


def uncertainty_of(camera, report=None, camera_source="camera"):
    """(IntrinsicsCovariance or None, CornerNoise or None) for `camera`: from the
    CalibrationFile `report` when given (InputError if it calibrated another camera),
    else from the camera file's statistics (``cov_intrinsics``, ``corner_noise``)."""
    if report is not None:
        if report.camera != camera:
            raise InputError(f"{report.source}: the calibration report is of another camera (its intrinsics differ "
                             f"from {camera_source}'s)")
        return report.cov_intrinsics, report.corner_noise
    cov = camera_intrinsics_covariance(camera, camera_source)
    noise = (camera.meta or {}).get(CORNER_NOISE_KEY)
    return cov, (None if noise is None else CornerNoise.from_dict(noise, camera_source))


def camera_with_report(camera, report, camera_source="camera"):
    """`camera` with the report's intrinsics covariance and corner-noise model in its
    statistics (``meta``), so every estimate made with it carries them (InputError if the
    report calibrated another camera)."""
    from pencilcal.toolkit.camera.model import Camera

    cov, noise = uncertainty_of(camera, report, camera_source)
    meta = dict(camera.meta or {})
    if cov is not None:
        meta[META_KEY] = cov.to_dict()
    if noise is not None:
        meta[CORNER_NOISE_KEY] = noise.to_dict()
    calib = (report.camera.meta or {}).get("calibration")
    if isinstance(calib, dict) and SYMMETRIC_KEY in calib:
        # how its corners were found, for a camera file that could not hold it (COLMAP, mrcal)
        meta["calibration"] = {**(meta.get("calibration") or {}), SYMMETRIC_KEY: calib[SYMMETRIC_KEY]}
    return Camera(camera.model, camera.width, camera.height, camera.K, camera.dist, meta=meta)


def uncertainty_record(camera, source):
    """The run-level record of what a camera's estimates carry: ``intrinsics_covariance``
    (`source` or None) and ``corner_noise`` (the model's record or None)."""
    cov, noise = uncertainty_of(camera, camera_source=source)
    return {"intrinsics_covariance": None if cov is None else str(source),
            "corner_noise": None if noise is None else noise.to_dict()}


def symmetric_corners_of(camera):
    """Whether the camera's calibration refined ChArUco corners to their point of symmetry
    (its statistics' ``calibration.symmetric_corners``, `pencilcal calibrate
    --symmetric-corners`): the board's later detections with this camera (`pencilcal pnp`,
    `validate`) refine them the same way, the corner-noise model having been measured on
    those corners. False for a camera without the record (CharucoDetector's corners, the
    default). Chessboard corners are refined so whatever it says.

    >>> from pencilcal.toolkit.camera.model import Camera
    >>> K = [[500.0, 0, 320], [0, 500.0, 240], [0, 0, 1]]
    >>> meta = {"calibration": {"symmetric_corners": True}}
    >>> symmetric_corners_of(Camera("pinhole", 640, 480, K, meta=meta)), symmetric_corners_of(Camera("pinhole", 640, 480, K))
    (True, False)
    """
    calib = (camera.meta or {}).get("calibration")
    return bool(calib.get(SYMMETRIC_KEY, False)) if isinstance(calib, dict) else False


def board_model(board, camera):
    """The board's corners as the camera's calibration measured them.

    When the camera's statistics (``meta``, written by `pencilcal calibrate`) record a
    calibration of this same board (``calibration.board``) with its warp (``board_warp``),
    each corner is lifted off the board's plane by the warp (`bundle.warp_basis`: zero on
    the corner grid's border, ``warp_x`` / ``warp_y`` [board unit] at its middle, and
    ``warp_twist`` at its corners where the calibration estimated the board's twist); the
    poses of that board are then those of the board the calibration saw. The printed
    board's corner offsets (``board_corners``) are a variance, not per-corner values: in one
    view they are white errors its residuals already hold (`print_errors`), nothing to add.

    board : Board; camera : Camera. Returns (points (M, 3) [board unit], basis (M, W): d
    point z / d warp, warp covariance (W, W) [board unit^2] or None; W = 2, or 3 with the
    twist): the nominal
    `Board.object_points` with basis and covariance None for another board, no warp, or a
    camera without the record.

    >>> from pencilcal.toolkit.board.spec import board_from_dict
    >>> from pencilcal.toolkit.camera.model import Camera
    >>> b = board_from_dict({"type": "chessboard", "squares": [3, 2], "square": 10.0})
    >>> meta = {"calibration": {"board": b.to_dict()}, "board_warp": {"value": [0.2, 0.0], "cov": [[0.01, 0], [0, 0.01]]}}
    >>> cam = Camera("pinhole", 640, 480, [[500.0, 0, 320], [0, 500.0, 240], [0, 0, 1]], meta=meta)
    >>> X, basis, cov = board_model(b, cam)
    >>> X[:, 2].round(3).tolist()
    [0.0, 0.2, 0.0, 0.0, 0.2, 0.0]
    >>> board_model(b, Camera("pinhole", 640, 480, cam.K))[1] is None
    True
    """
    # bundle takes ~0.2 s to import and only this function of the module needs it
    from pencilcal.toolkit.board.bundle import warp_basis

    X = np.asarray(board.object_points(), float)
    meta = camera.meta or {}
    calib, warp = meta.get("calibration"), meta.get("board_warp")
    if not isinstance(calib, dict) or not isinstance(warp, dict) or not _same_board(calib.get("board"), board):
        return X, None, None
    try:
        value = np.asarray(warp["value"], float).reshape(-1)
        if value.size not in (2, 3):
            raise ValueError(f"{value.size} values (2: the parabolas, 3: and the twist)")
        cov = np.asarray(warp["cov"], float).reshape(value.size, value.size) if warp.get("cov") is not None else None
    except (KeyError, TypeError, ValueError) as e:
        raise InputError(f"the camera's board_warp record is malformed: {e}") from None
    basis = warp_basis(X, X, twist=value.size == 3)
    out = X.copy()
    out[:, 2] += basis @ value
    return out, basis, cov


def _same_board(rec, board):
    """Whether a calibration's board record (``Board.to_dict``, maybe read back from JSON)
    describes `board`."""
    if not isinstance(rec, dict):
        return False
    want = board.to_dict()
    norm = lambda v: [float(x) for x in v] if isinstance(v, (list, tuple)) else v  # noqa: E731
    return set(rec) == set(want) and all(norm(rec[k]) == norm(want[k]) for k in want)
