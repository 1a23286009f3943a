"""pencilcal: orientation of a pencil of lines from its image angles, with the calibration
and validation a lab needs to trust it.

The public Python API; every function returns a typed result whose ``to_dict()`` (where
it has one) is the record pencilcal's files hold (docs/api.md has a runnable example of
each):

==================  ==============================================================
`read_camera`,      camera files of pencilcal (.json), OpenCV (.yaml/.xml), mrcal
`write_camera`,     (.cameramodel), COLMAP (cameras.txt/.bin, model folder); `Camera`
`Camera`            projects, undistorts, and holds the intrinsics
`fit_pencil`        the exact estimator: image angles of lines through one point ->
                    `PencilFit` (rotation, twin, tilt and normal with sigmas)
`orient_segments`   one frame's raw segments -> `Orientation` (the orientation.json
                    record)
`detect_lines`      one image -> `LineFrame` (segments or printed bars' midlines, with
                    their sigmas; the lines.json record)
`detect_shafts`     one image -> [`Shaft`]: instrument shafts, their axis images
`shafts_from_masks` one image and its instrument mask -> [`MaskShaft`]: each masked
                    instrument's axis refined on the image, with where they disagree
`fulcrum`           the lines of a pivot sequence -> `Fulcrum` (the fulcrum.json record)
`hand_eye`          a pivot's lines and the robot's tool poses -> `RobotCalibration`
                    (camera-to-robot transform, remote centre; fulcrum.json's robot)
`calibrate`         views of a board -> `CalibrationResult` (``.camera``, ``.checks``
                    with the verdict), as `pencilcal calibrate`
`board_pose`        one image of a board -> `PoseResult` (R_cam_from_target, t, cov)
==================  ==============================================================

Conventions: OpenCV camera frame (x right, y down, z forward), pixel (0, 0) the centre of
the top-left pixel, transforms named ``R_a_from_b``, radians in code (degrees in files).

Example
-------
>>> import numpy as np, pencilcal
>>> R = pencilcal.rotation_about_axis([1.0, 0.2, 0.0], np.radians(30))  # R_cam_from_target
>>> theta = np.radians(np.arange(8) * 20.0)                              # spoke angles
>>> vertex = np.array([0.1, -0.05])                                      # normalised image
>>> fit = pencilcal.fit_pencil(pencilcal.image_angles(R, vertex, theta), theta, vertex)
>>> round(float(np.degrees(fit.tilt)), 6) == round(float(np.degrees(
...     np.arccos(R[:, 2] @ fit.ray))), 6)
True
"""
from __future__ import annotations

import importlib

# Where each public name lives. They are imported on first use (PEP 562), so that
# `import pencilcal.toolkit.geometry` (which imports this package first) stays light and
# worker processes load only what they run.
_NAMES = {
    "read_camera": "pencilcal.toolkit.camera.formats", "write_camera": "pencilcal.toolkit.camera.formats",
    "Camera": "pencilcal.toolkit.camera.model",
    "fit_pencil": "pencilcal.toolkit.pencil.estimator", "PencilFit": "pencilcal.toolkit.pencil.estimator",
    "orient_segments": "pencilcal.toolkit.pencil.orient", "Orientation": "pencilcal.toolkit.pencil.orientation",
    "Shaft": "pencilcal.toolkit.detect.shaft.detector", "detect_shafts": "pencilcal.toolkit.detect.shaft.detector",
    "MaskShaft": "pencilcal.toolkit.detect.shaft.from_mask",
    "shafts_from_masks": "pencilcal.toolkit.detect.shaft.from_mask",
    "LineFrame": "pencilcal.toolkit.io.lines_file", "read_lines": "pencilcal.toolkit.io.lines_file",
    "Fulcrum": "pencilcal.toolkit.pencil.fulcrum",
    "RobotCalibration": "pencilcal.toolkit.pencil.hand_eye",
    "ToolPoses": "pencilcal.toolkit.io.tool_poses", "read_tool_poses": "pencilcal.toolkit.io.tool_poses",
    "CalibrationResult": "pencilcal.toolkit.board.calibrate",
    "Board": "pencilcal.toolkit.board.spec", "read_board": "pencilcal.toolkit.board.spec",
    "Pencil": "pencilcal.toolkit.pencil.spec", "read_pencil": "pencilcal.toolkit.pencil.spec",
    "image_angles": "pencilcal.toolkit.pencil.spec",
    "rotation_about_axis": "pencilcal.toolkit.geometry.frames",
    "PoseResult": "pencilcal.validation.pnp", "board_pose": "pencilcal.validation.pnp",
    "PencilcalError": "pencilcal.toolkit.errors", "InputError": "pencilcal.toolkit.errors",
    "EstimationError": "pencilcal.toolkit.errors",
}

__all__ = [
    "__version__", "read_camera", "write_camera", "Camera", "fit_pencil", "orient_segments", "detect_lines",
    "detect_shafts", "shafts_from_masks", "fulcrum", "hand_eye", "calibrate", "board_pose",
    # the results and inputs they take and give
    "PencilFit", "Orientation", "LineFrame", "Shaft", "MaskShaft", "Fulcrum", "RobotCalibration", "ToolPoses",
    "read_tool_poses", "CalibrationResult", "PoseResult",
    "Pencil", "read_pencil", "Board", "read_board", "read_lines", "image_angles", "rotation_about_axis",
    "PencilcalError", "InputError", "EstimationError",
]


def _version():
    """The installed distribution's version ("0+unknown" from a source tree without
    installing); looked up when first asked for: importing importlib.metadata costs a
    live command's start-up ~15 ms."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("pencilcal")
    except PackageNotFoundError:
        return "0+unknown"


def __getattr__(name):
    if name == "__version__":
        globals()[name] = _version()
        return globals()[name]
    if name in _NAMES:
        value = getattr(importlib.import_module(_NAMES[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'pencilcal' has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(__all__))


def calibrate(images, board, model="opencv", coefficients=None, *, symmetric_corners=False, **options):
    """Calibrate a camera from views of a board, as `pencilcal calibrate` does: a
    `CalibrationResult` (``.camera`` is the Camera) with the board's warp, sigmas from the
    corner errors seen, and ``.checks``: the two-halves cross-validation, the projection
    uncertainty map and the verdict (``.checks.verdict.status``, ``.headline``, ``.advice``);
    ``.to_dict()`` is the calib.json record.

    images: IMAGES (paths, folders, globs or a video) or a list of arrays; board: a Board or
    a board file; model: "opencv", "pinhole", "fisheye" or "auto" (chosen on held-out
    views); symmetric_corners: a ChArUco board's corners refined to their point of symmetry
    after CharucoDetector (a chessboard's always are; recorded in the camera's statistics so
    that its board poses detect them so: docs/calibration.md); options as
    `pencilcal.validation.calibration_run.calibrate_checked` (fix_aspect, min_corners,
    usable_px, ...)."""
    from pencilcal.toolkit.board.calibrate import detect_views
    from pencilcal.validation.calibration_run import calibrate_checked

    board, detections, size = detect_views(images, board, symmetric_corners)
    return calibrate_checked(detections, board, size, model=model, coefficients=coefficients, **options)


def detect_lines(image, camera=None, *, bars=False, detector="auto", name="image", **options):
    """The lines of one image as a `LineFrame`: edge segments, or with ``bars=True`` the
    midlines of printed bars (the spokes of a fan), each with its angle and offset sigma.

    image : (H, W) or (H, W, 3) array; camera : Camera (lines are straight in undistorted
    pixels, so give it for a distorting lens); detector : "auto" (as `pencilcal lines`: FLD
    for bars on frames of 720 lines or more, LSD otherwise), "lsd", "fld" or "edlines";
    options : ``min_length``, ``bar_width``, ``shaft`` (as `pencilcal lines`).
    """
    from pencilcal.toolkit.detect.lines import detect_frame_lines

    return detect_frame_lines(name, image, camera, detector=detector, bars=bars, **options)


def _line_frames(lines):
    """lines.json frames as records: from a path, or [`LineFrame`] or records."""
    from pencilcal.toolkit.io.lines_file import LineFrame, read_lines

    if isinstance(lines, (str, bytes)) or hasattr(lines, "__fspath__"):
        return read_lines(lines)
    return [f.to_dict() if isinstance(f, LineFrame) else f for f in lines]


def hand_eye(lines, camera, kinematics, shaft_diameter, *, tool_axis=(0.0, 0.0, 1.0)):
    """The camera-to-robot transform and the remote centre of motion of a pivot whose tool
    poses the robot reports, as `pencilcal fulcrum --kinematics` writes them: a
    `RobotCalibration` (``.hand_eye.R_cam_from_base``, ``.t_cam_from_base``, ``.cov``;
    ``.robot``: the centre in the base frame and its covariance; ``.agreement``: with the
    camera's own fulcrum); ``.to_dict()`` is fulcrum.json's ``robot`` record.

    lines : a lines.json path, or its frames ([`LineFrame`] or records), whose shafts carry
    their edges' covariance (`detect_shafts`, `pencilcal lines --shaft`); camera : Camera;
    kinematics : the kinematics CSV's path or `ToolPoses` (docs/formats.md); shaft_diameter
    : [mm]; tool_axis : the shaft's axis in the tool frame (the dVRK's z).
    """
    from pencilcal.toolkit.errors import EstimationError as _Estimation
    from pencilcal.toolkit.io.tool_poses import ToolPoses, read_tool_poses as _read
    from pencilcal.toolkit.pencil.fulcrum import fulcrum_point
    from pencilcal.toolkit.pencil.hand_eye import robot_from_frames

    frames = _line_frames(lines)
    poses = kinematics if isinstance(kinematics, ToolPoses) else _read(kinematics)
    try:
        near = fulcrum_point(camera, frames, shaft_diameter).fit.point
    except _Estimation:
        near = None
    return robot_from_frames(camera, frames, poses, shaft_diameter, tool_axis=tool_axis, near=near)


def fulcrum(lines, camera, angles=None, *, endpoint_sigma_px=None, shaft_diameter=None):
    """The fulcrum of a pivoting instrument from the lines of its frames, as a `Fulcrum`,
    with the sigmas `pencilcal fulcrum` writes.

    lines : the path of a lines.json, or its frames ([`LineFrame`] or records); camera :
    Camera; angles : (F,) pivot angles [rad] per frame, for the pivot plane too;
    endpoint_sigma_px : the end point noise [px] of segments without sigmas of their own, or
    None to estimate it from the residuals (the detector's own sigmas, a shaft's, are only
    ever inflated); shaft_diameter : for the 3-D fulcrum (``point``, in its unit). With 8
    frames or more each is left out once and where the frames disagree beyond chance the
    sigmas are the jackknife's. The result's ``noise`` and ``jackknife`` say what was found
    and its ``warnings`` what to tell the user (`validation.fulcrum_run`).
    """
    from pencilcal.validation.fulcrum_run import fulcrum_with_sigmas

    return fulcrum_with_sigmas(camera, _line_frames(lines), angles, endpoint_sigma_px=endpoint_sigma_px,
                               shaft_diameter=shaft_diameter)
