"""Geometry shared by everything: angle wrapping (`angles`), rotations and frames (`frames`),
and the pencil as a 1-D projective map (`projective`).

Conventions (their one home is each module's docstring and docs/conventions.md): OpenCV
camera frame, transforms named ``R_a_from_b``, radians in code.
"""

from __future__ import annotations

from pencilcal.toolkit.lazy import lazy_exports

# each name imported from its module when first used: importing one module of this package
# does not import the others
__getattr__, __dir__ = lazy_exports(__name__, {
    "angles": ["wrap_angle", "wrap_line", "circular_mean"],
    "frames": ["rotation_from_rotvec", "rotvec_from_rotation", "rotation_about_axis", "rotation_angle",
               "angle_between", "twin_rotation", "normalize"],
    "projective": ["pencil_homography", "cross_ratio", "predict_line_angles"],
})


__all__ = ["wrap_angle", "wrap_line", "circular_mean", "rotation_from_rotvec", "rotvec_from_rotation",
           "rotation_about_axis", "rotation_angle", "angle_between", "twin_rotation", "normalize",
           "pencil_homography", "cross_ratio", "predict_line_angles"]
