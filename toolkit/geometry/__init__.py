"""Geometry shared by everything: angle wrapping (`angles`), rotations and frames (`frames`),
and the pencil as a 1-D projective map (`projective`).

Conventions (their one home is each module's docstring and docs/conventions.md): OpenCV
camera frame, transforms named ``R_a_from_b``, radians in code.
"""

from __future__ import annotations

from pencilcal.toolkit.geometry.angles import wrap_angle, wrap_line, circular_mean
from pencilcal.toolkit.geometry.frames import (rotation_from_rotvec, rotvec_from_rotation,
                                               rotation_about_axis, rotation_angle, angle_between,
                                               twin_rotation, normalize)
from pencilcal.toolkit.geometry.projective import pencil_homography, cross_ratio, predict_line_angles

__all__ = ["wrap_angle", "wrap_line", "circular_mean", "rotation_from_rotvec", "rotvec_from_rotation",
           "rotation_about_axis", "rotation_angle", "angle_between", "twin_rotation", "normalize",
           "pencil_homography", "cross_ratio", "predict_line_angles"]
