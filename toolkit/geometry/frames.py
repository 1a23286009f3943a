"""Rotations and frames: the one home for frame conventions in pencilcal.

Conventions
-----------
- Camera frame: OpenCV (x right, y down, z forward).
- Transforms are named ``a_from_b``: ``p_a = R_a_from_b @ p_b + t_a_from_b`` (pycolmap).
- Target frame: the printed sheet, x right, y down the sheet, z = x cross y into the sheet,
  away from a camera that sees the printed face (OpenCV's ChArUco board frame).
- The pencil *normal* is ``R_cam_from_target[..., :, 2]``; it points away from the camera.
- Rotation vectors are axis * angle (radians), as ``cv2.Rodrigues``.
- Small rotation errors are *left* perturbations in the camera frame:
  ``R = expm(skew(delta)) @ R_hat``; covariances of rotations are of ``delta`` (3x3, rad^2).

Every function broadcasts over leading dimensions.

Example
-------
>>> import numpy as np
>>> R = rotation_about_axis([0, 0, 1], np.pi / 2)
>>> np.round(R @ [1.0, 0, 0], 12).tolist()
[0.0, 1.0, 0.0]
>>> float(np.degrees(rotation_angle(R, np.eye(3))))
90.0
"""
from __future__ import annotations

import numpy as np

__all__ = [
    "skew",
    "rotation_from_rotvec",
    "rotvec_from_rotation",
    "rotation_about_axis",
    "rotation_from_quaternion",
    "rotation_angle",
    "angle_between",
    "project_to_rotation",
    "rotation_to_z",
    "twin_rotation",
    "twin_normal",
    "normal_from_rotation",
    "normalize",
]


def normalize(v, axis=-1):
    """Unit vectors along `axis`. v: (..., 3)."""
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v, axis=axis, keepdims=True)


def skew(v):
    """Cross-product matrix: skew(v) @ w == cross(v, w). v: (..., 3) -> (..., 3, 3)."""
    v = np.asarray(v, dtype=float)
    z = np.zeros(v.shape[:-1])
    x, y, w = v[..., 0], v[..., 1], v[..., 2]
    return np.stack(
        [np.stack([z, -w, y], -1), np.stack([w, z, -x], -1), np.stack([-y, x, z], -1)], -2
    )


def rotation_from_rotvec(rotvec):
    """Rodrigues' formula. rotvec: (..., 3) axis * angle [rad] -> (..., 3, 3)."""
    r = np.asarray(rotvec, dtype=float)
    theta = np.linalg.norm(r, axis=-1)[..., None, None]
    K = skew(r)
    K2 = K @ K
    small = theta < 1e-8
    safe = np.where(small, 1.0, theta)
    # Taylor terms below 1e-8 rad keep the result exact to double precision
    a = np.where(small, 1.0 - theta**2 / 6.0, np.sin(safe) / safe)
    b = np.where(small, 0.5 - theta**2 / 24.0, (1.0 - np.cos(safe)) / safe**2)
    return np.eye(3) + a * K + b * K2


def rotvec_from_rotation(R):
    """Inverse of `rotation_from_rotvec`, stable near 0 and pi. R: (..., 3, 3) -> (..., 3)."""
    R = np.asarray(R, dtype=float)
    tr = np.trace(R, axis1=-2, axis2=-1)
    cos = np.clip((tr - 1.0) / 2.0, -1.0, 1.0)
    theta = np.arccos(cos)
    vee = np.stack([R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]], -1)
    sin = np.sin(theta)
    small = theta < 1e-6
    near_pi = np.pi - theta < 1e-3
    scale = np.where(small, 0.5 + theta**2 / 12.0, theta / (2.0 * np.where(small | near_pi, 1.0, sin)))
    out = vee * scale[..., None]
    if np.any(near_pi):
        # Near pi the antisymmetric part vanishes: take the axis from the symmetric part.
        B = (R + np.swapaxes(R, -1, -2)) / 2.0 - cos[..., None, None] * np.eye(3)
        B = B / np.maximum(1.0 - cos, 1e-300)[..., None, None]
        idx = np.argmax(np.diagonal(B, axis1=-2, axis2=-1), axis=-1)
        axis = np.take_along_axis(B, idx[..., None, None].repeat(3, -1), axis=-2)[..., 0, :]
        axis = normalize(axis)
        sgn = np.sign(np.sum(axis * vee, -1))
        axis = axis * np.where(sgn == 0, 1.0, sgn)[..., None]
        out = np.where(near_pi[..., None], axis * theta[..., None], out)
    return out


def rotation_about_axis(axis, angle):
    """Rotation by `angle` [rad] about `axis` (normalised here). (..., 3), (...) -> (..., 3, 3)."""
    axis = normalize(axis)
    return rotation_from_rotvec(axis * np.asarray(angle, dtype=float)[..., None])


def rotation_from_quaternion(q):
    """The rotation of a unit quaternion in the order (w, x, y, z) (Hamilton, as ROS and
    Eigen: ``v' = q v q*``). q: (..., 4) (either sign, normalised here) -> (..., 3, 3).

    >>> np.round(rotation_from_quaternion([np.cos(np.pi / 4), 0, 0, np.sin(np.pi / 4)]) @ [1.0, 0, 0], 12).tolist()
    [0.0, 1.0, 0.0]
    """
    q = np.asarray(q, float)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1)], -2)


def rotation_angle(R_a, R_b):
    """Geodesic angle [rad] between rotations, |log(R_a^T R_b)|. (..., 3, 3) -> (...)."""
    M = np.swapaxes(np.asarray(R_a, float), -1, -2) @ np.asarray(R_b, float)
    # the antisymmetric part keeps precision for tiny angles where acos(trace) does not
    vee = np.stack([M[..., 2, 1] - M[..., 1, 2], M[..., 0, 2] - M[..., 2, 0], M[..., 1, 0] - M[..., 0, 1]], -1)
    s = np.linalg.norm(vee, axis=-1) / 2.0
    c = (np.trace(M, axis1=-2, axis2=-1) - 1.0) / 2.0
    return np.arctan2(s, c)


def angle_between(a, b):
    """Angle [rad] between vectors (not necessarily unit). (..., 3) -> (...)."""
    a = np.asarray(a, float)
    b = np.asarray(b, float)
    return np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.sum(a * b, axis=-1))


def project_to_rotation(M):
    """Nearest rotation (Frobenius) to a 3x3 matrix. (..., 3, 3) -> (..., 3, 3)."""
    U, _, Vt = np.linalg.svd(np.asarray(M, float))
    d = np.sign(np.linalg.det(U @ Vt))
    D = np.ones(U.shape[:-1])
    D[..., -1] = d
    return (U * D[..., None, :]) @ Vt


def rotation_to_z(v):
    """Minimal rotation Q with Q @ unit(v) = (0, 0, 1): the 'virtual camera' looking along v.

    v: (..., 3) with v_z > -|v| (not pointing straight backwards). Returns (..., 3, 3).
    Rotates about the axis v x z, so the image axes turn as little as possible.
    """
    v = normalize(v)
    z = np.array([0.0, 0.0, 1.0])
    axis = np.cross(v, z)
    s = np.linalg.norm(axis, axis=-1)
    c = v[..., 2]
    ang = np.arctan2(s, c)
    safe_axis = np.where(s[..., None] > 1e-15, axis / np.maximum(s, 1e-300)[..., None], [1.0, 0.0, 0.0])
    return rotation_from_rotvec(safe_axis * ang[..., None])


def normal_from_rotation(R_cam_from_target):
    """The target's z axis in the camera frame (the pencil normal). (..., 3, 3) -> (..., 3)."""
    return np.asarray(R_cam_from_target, float)[..., :, 2]


def twin_rotation(R_cam_from_target, ray):
    """The twin R' = Rot(ray, pi) @ R @ Rot(z, pi) that images every spoke identically.

    Rotating the whole pencil by 180 deg about the vertex's viewing ray leaves every image
    line unchanged; composing with Rot(z, pi) in the target frame turns the in-plane offset
    by 180 deg so that even oriented spoke directions are reproduced (docs/conventions.md, "The twin").

    R_cam_from_target: (..., 3, 3); ray: (..., 3) viewing ray of the vertex (any length).
    """
    d = normalize(ray)
    rot_ray = 2.0 * d[..., :, None] * d[..., None, :] - np.eye(3)  # Rot(d, pi)
    rot_z = np.diag([-1.0, -1.0, 1.0])
    return rot_ray @ np.asarray(R_cam_from_target, float) @ rot_z


def twin_normal(normal, ray):
    """Normal of the twin solution, n' = 2 (n . d) d - n with d the unit ray. (..., 3)."""
    d = normalize(ray)
    n = np.asarray(normal, float)
    return 2.0 * np.sum(n * d, -1, keepdims=True) * d - n
