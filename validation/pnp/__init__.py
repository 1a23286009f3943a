"""Board pose from corner correspondences (PnP), refined in raw pixels, with covariance.

`estimate_pose` finds the pose of a target (a calibration board) from its known corner
positions and their raw (distorted) pixels with one of several initialisers, then refines
it by Levenberg-Marquardt on the reprojection error in raw pixels under the camera's full
lens model, and reports the reprojection residuals and the 6x6 pose covariance.

Methods
-------
``"iterative"``
    OpenCV's SOLVEPNP_ITERATIVE (homography or DLT start, then its own LM). Needs 4 points
    on a plane, 6 otherwise (OpenCV's DLT; its planarity test is used here too).
``"sqpnp"`` (default)
    OpenCV's SOLVEPNP_SQPNP (globally optimal algebraic solver). 4 points or more here
    (OpenCV accepts 3, which leave up to 4 poses).
``"ippe"``
    OpenCV's SOLVEPNP_IPPE, planar targets only; it returns the two poses that explain a
    planar target. Both are refined; the one with the lower RMS is kept and the other's
    RMS and angle are recorded (``alternative_rms_px``, ``alternative_angle_deg``).
``"epnp"``
    OpenCV's SOLVEPNP_EPNP. 4 points or more. On planar targets OpenCV's EPnP is
    unreliable (opencv/opencv#22351): on 5 of the 28 real RealSense ChArUco frames, and on
    ~13 % of random synthetic views, it returns a pose 80-145 deg off that refines to the
    wrong planar twin (RMS 17-38 px on the real frames); the twin check below corrects it
    (``flipped``).
``"colmap"``
    pycolmap.estimate_and_refine_absolute_pose: LO-RANSAC (P3P, EPnP local optimisation)
    and COLMAP's own Ceres refinement with a Cauchy loss, with the camera converted by
    `toolkit.camera.formats.camera_to_colmap` (principal point + 0.5 px) and the image points shifted
    by the same + 0.5 px into COLMAP's pixel convention. The camera must be a model COLMAP
    has (no skew, no thin-prism/tilt coefficients).

Every OpenCV method runs on *undistorted* points: the raw pixels are undistorted exactly
by `Camera.normalized_from_pixels` (opencv, fisheye or pinhole) and handed to OpenCV as
ideal pinhole pixels ``(fx x + cx, fy y + cy)`` with no distortion coefficients. So every
lens model is handled alike, including fisheye lenses that cv2.solvePnP cannot take.
All solutions a method returns are refined (``refine=True``) and the best kept. For a
planar target the refinement also starts from the *planar twin* of that pose (its mirror
image about the line of sight, the other near-solution every planar pose has) and keeps
whichever fits better, so a method that returned the wrong twin is corrected (``flipped``)
and the twin's RMS is recorded (``alternative_rms_px``): EPnP returns the wrong twin on
about one planar view in eight. A twin whose start already reprojects more than 10 times
worse (RMS) than the pose is ruled out there, unrefined, and that start's RMS is recorded
(refining it could only lower it; no twin that refined to the better pose ever started
more than 1.9 times worse in 12 600 trials, see `estimate_pose`). This skips the twin's
refinement on most views, where perspective resolves the twin clearly.

Refinement and covariance
-------------------------
The refinement minimises ``sum_k |project(R X_k + t) - u_k|^2`` over the pose with
``project`` = `Camera.project` (raw pixels, full distortion), by Levenberg-Marquardt on
the parameters ``(delta, dt)``::

    R <- expm(skew(delta)) @ R        (left perturbation, in the camera frame; geometry/frames.py)
    t <- t + dt                       (t = t_cam_from_target, target length unit)

with the analytic Jacobian (lens Jacobian from `Camera.jacobian_pixels_from_normalized`).

``cov`` (6x6) is the covariance of the error of the estimate in these same coordinates,
rotation first: the true pose is ``R_true = expm(skew(d_rot)) @ R_hat`` and
``t_true = t_hat + d_t`` with ``(d_rot, d_t) ~ N(0, cov)``; d_rot is a rotation vector
in radians about the *camera* axes, d_t is in the length unit of the object points. It
is ``sigma^2 (J^T J)^-1`` at the optimum, with ``sigma`` the corner noise (px): given
(``corner_sigma_px``), or estimated from the residuals as
``sqrt(sum r^2 / (2 K - 6))`` (K corners). The translation block is *not* an SE(3)
(``exp(xi) T``) perturbation: rotation and translation are perturbed independently.
(COLMAP reports its covariance on the quaternion tangent, whose rotation block is a
quarter of ours at sigma = 1 px; see `colmap_covariance_to_pencilcal`.) The covariance
is local: it does not cover the planar twin, whose distance in RMS (`alternative_rms_px`
against `reproj_rms_px`) says how clearly the twin is ruled out.

It assumes independent corner errors. On real frames they need not be (blur, compression and
interlaced fields can correlate neighbouring corners), and what they share mostly moves the
pose, which no per-frame residual can show: on the da Vinci stereo pair the relative
rotation of the two cameras scatters by about as much as the covariances say, but only 31 %
of the frames fall inside their 68 % region (docs/experiments.md). Read PnP sigmas on real
frames as about 1.5 times too small.

Degenerate input never gives a pose: fewer points than the method needs, NaN/inf,
collinear object points, image points on one line (a plane seen edge-on), a pose with
points behind the camera, a numerically singular normal matrix, or a pose whose
reprojection RMS exceeds `max_rms_px` (a wrong local minimum) give ``ok=False`` and an
``error`` that says why.

Modules
-------
``result``      `PoseResult`, the typed result (its `to_dict` is a poses.json frame's pose)
``estimate``    the initialisers, `estimate_pose`, `estimate_all`, `best_method`
``refine``      reprojection in raw pixels and its Jacobian, the LM refinement
``covariance``  the pose covariance, and COLMAP's converted to this convention
``poses_file``  the board poses.json of `pencilcal pnp`: `frame_record`, writer and reader

Example
-------
>>> import numpy as np
>>> from pencilcal.toolkit.camera.model import Camera
>>> from pencilcal.toolkit.geometry.frames import rotation_about_axis
>>> cam = Camera("opencv", 1280, 720, [[900.0, 0, 639.5], [0, 900.0, 359.5], [0, 0, 1]],
...              [-0.2, 0.05, 0.0, 0.0])
>>> j, i = np.mgrid[1:5, 1:7]
>>> X = np.stack([i.ravel() * 30.0, j.ravel() * 30.0, np.zeros(24)], -1)   # mm
>>> R = rotation_about_axis([1.0, 0.2, 0.0], np.radians(30))
>>> t = np.array([-100.0, -70.0, 500.0])
>>> u = cam.project(X @ R.T + t)
>>> res = estimate_pose(X, u, cam, method="sqpnp", corner_sigma_px=0.2)
>>> res.ok, bool(np.allclose(res.R_cam_from_target, R, atol=1e-9)), res.cov.shape
(True, True, (6, 6))
>>> bool(res.reproj_rms_px < 1e-6)
True
"""
from __future__ import annotations

from .covariance import colmap_covariance_to_pencilcal, pose_covariance
from .estimate import DEFAULT_MAX_RMS_PX, MIN_POINTS, best_method, board_points, board_pose, estimate_all, \
    estimate_pose
from .poses_file import (
    COV_CONVENTION,
    POSE_KEYS,
    empty_frame_record,
    frame_record,
    read_board_poses,
    write_board_poses,
)
from .refine import refine_pose
from .result import DEFAULT_METHOD, METHODS, PoseResult

#: The names these had when pnp was one module (`pencilcal pnp` still imports them so).
read_poses = read_board_poses
write_poses = write_board_poses

__all__ = [
    "METHODS",
    "DEFAULT_METHOD",
    "DEFAULT_MAX_RMS_PX",
    "MIN_POINTS",
    "PoseResult",
    "estimate_pose",
    "board_pose",
    "estimate_all",
    "best_method",
    "refine_pose",
    "pose_covariance",
    "colmap_covariance_to_pencilcal",
    "frame_record",
    "empty_frame_record",
    "write_board_poses",
    "read_board_poses",
    "write_poses",
    "read_poses",
    "POSE_KEYS",
    "COV_CONVENTION",
]
