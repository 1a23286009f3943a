"""The pencil as a 1-D projective map: homography, cross-ratio, prediction from three lines.

Every line through the image of the vertex back-projects to a plane through the camera
centre, so the map from 3D spoke directions to image line directions is *linear* on
direction vectors:

    (cos a_k, sin a_k)  ~  H @ (cos theta_k, sin theta_k)          H: 2x2, up to scale

In normalised image coordinates with the vertex imaged at x_d = (x, y) (pencil.py),
``H = [[1, 0, -x], [0, 1, -y]] @ R_cam_from_target[:, :2]`` exactly, with a positive factor,
so H also carries the orientation of the spokes. In pixels of an undistorted camera the
map is ``K[:2, :2] @ H`` (any fx, fy, skew): still a 1-D homography. Hence

- H has 3 degrees of freedom: three lines with known 3D angles fix it and predict every
  other line exactly, with no intrinsics (`predict_line_angles`);
- the cross-ratio of four lines is a projective invariant (`cross_ratio`): it is the same
  for the four 3D spokes, their image in normalised coordinates and their image in raw
  (undistorted) pixels.

The line through two image points and the point where two lines meet, in homogeneous
coordinates, have their one home here too (`line_through`, `line_meet`).

Angles are radians; image angles are ``atan2(dv, du)`` (angles.py). Line angles have
period pi and every function here accepts them that way; directions (period 2*pi) are
reproduced when the inputs are oriented (the sign of H is fixed by them).

Example
-------
>>> import numpy as np
>>> from pencilcal.toolkit.pencil.spec import image_angles
>>> from pencilcal.toolkit.geometry.frames import rotation_about_axis
>>> R = rotation_about_axis([1.0, 0.2, 0.0], np.radians(50))
>>> th = np.radians([0, 25, 60, 100, 150])
>>> a = image_angles(R, [0.3, -0.1], th)
>>> pred = predict_line_angles(a[:3], th[:3], th[3:])
>>> bool(np.allclose(pred, a[3:], atol=1e-12))
True
>>> bool(np.isclose(cross_ratio(*a[:4]), cross_ratio(*th[:4]), rtol=1e-13))
True
"""
from __future__ import annotations

import numpy as np

from pencilcal.toolkit.geometry.angles import wrap_angle
from pencilcal.toolkit.errors import EstimationError, InputError

__all__ = [
    "pencil_homography",
    "apply_pencil_homography",
    "cross_ratio",
    "predict_line_angles",
    "homography_from_pose",
    "line_through",
    "line_meet",
]

# A (..., N, 4) DLT system whose third singular value falls below this fraction of the
# first has a null space of dimension >= 2: fewer than three distinct line/spoke pairs.
_RANK_TOL = 1e-10
# An H whose singular values differ by more than this ratio maps every spoke to (nearly)
# one image line: the pencil plane contains the viewing ray, or the data are inconsistent.
_SINGULAR_TOL = 1e-12


def _as_pairs(line_angles, spoke_angles, weights, what="lines"):
    try:
        a = np.asarray(line_angles, dtype=float)
        th = np.asarray(spoke_angles, dtype=float)
    except (TypeError, ValueError):
        raise InputError(f"{what}: line and spoke angles must be numbers") from None
    try:
        a, th = np.broadcast_arrays(a, th)
    except ValueError:
        raise InputError(
            f"{what}: line angles {a.shape} and spoke angles {th.shape} do not broadcast"
        ) from None
    if a.ndim == 0:
        raise InputError(f"{what}: expected arrays of angles (..., N), got scalars")
    if not (np.all(np.isfinite(a)) and np.all(np.isfinite(th))):
        raise InputError(f"{what}: line or spoke angles contain NaN or infinity")
    if weights is None:
        w = np.ones(a.shape)
    else:
        try:
            w = np.broadcast_to(np.asarray(weights, dtype=float), a.shape)
        except ValueError:
            raise InputError(f"{what}: weights {np.shape(weights)} do not broadcast to {a.shape}") from None
        if not np.all(np.isfinite(w)) or np.any(w < 0):
            raise InputError(f"{what}: weights must be finite and >= 0")
    return a, th, w


def pencil_homography(line_angles, spoke_angles, weights=None):
    """1-D homography H with (cos a, sin a) ~ H (cos theta, sin theta), by DLT.

    line_angles: (..., N) image angles a_k [rad] (lines, period pi, or oriented directions);
    spoke_angles: (..., N) 3D angles theta_k [rad] of the same lines in their plane;
    weights: optional (..., N), e.g. 1 / sigma_k^2 (each DLT row is scaled by sqrt(w)).
    Returns H: (..., 2, 2), unit Frobenius norm. The sign of H is chosen so that the
    predicted directions agree with the given ones (weighted sum of cosines >= 0): with
    oriented inputs H is oriented too, and for noise-free data equals
    ``homography_from_pose(R, vertex)`` up to a positive factor.

    Each line gives one equation  cos(a) (h21 c + h22 s) - sin(a) (h11 c + h12 s) = 0
    (c, s = cos theta, sin theta); N >= 3 lines; N = 3 is the exact minimal solution.

    Raises InputError for NaN/inf or mismatched shapes, EstimationError for fewer than
    three lines, fewer than three distinct (line, spoke) pairs, or data that only fit a
    singular H (all spokes on one image line: the pencil plane contains the viewing ray).

    >>> import numpy as np
    >>> H = pencil_homography(np.radians([0, 45, 90]), np.radians([0, 45, 90]))
    >>> np.round(H * np.sqrt(2), 12).tolist()
    [[1.0, 0.0], [0.0, 1.0]]
    """
    a, th, w = _as_pairs(line_angles, spoke_angles, weights, "pencil_homography")
    n = a.shape[-1]
    if n < 3:
        raise EstimationError(f"pencil_homography: a 1-D homography needs at least three lines, got {n}")
    ca, sa, ct, st = np.cos(a), np.sin(a), np.cos(th), np.sin(th)
    A = np.stack([-sa * ct, -sa * st, ca * ct, ca * st], -1) * np.sqrt(w)[..., None]  # (..., N, 4)
    _, s, Vt = np.linalg.svd(A, full_matrices=True)
    s0 = s[..., 0]
    bad = ~(s[..., 2] > _RANK_TOL * s0)
    if np.any(bad):
        where = "" if bad.ndim == 0 else f" (in {int(np.sum(bad))} of {bad.size} problems)"
        raise EstimationError(
            "pencil_homography: fewer than three distinct lines with distinct spoke angles"
            " (two lines or two spokes coincide, every line is the same image line because the"
            f" pencil plane contains the viewing ray, or weights are zero){where}"
        )
    H = Vt[..., -1, :].reshape(a.shape[:-1] + (2, 2))
    sv = np.linalg.svd(H, compute_uv=False)
    sing = ~(sv[..., 1] > _SINGULAR_TOL * sv[..., 0])
    if np.any(sing):
        raise EstimationError(
            "pencil_homography: the lines only fit a singular map (every spoke on one image line):"
            " the pencil plane contains the viewing ray, or the data are inconsistent"
        )
    p = np.einsum("...ij,...nj->...ni", H, np.stack([ct, st], -1))  # (..., N, 2)
    p = p / np.linalg.norm(p, axis=-1, keepdims=True)
    agree = np.sum(w * (p[..., 0] * ca + p[..., 1] * sa), -1)
    sign = np.where(agree < 0, -1.0, 1.0)
    H = H * sign[..., None, None]
    return H / np.linalg.norm(H, axis=(-2, -1), keepdims=True)


def apply_pencil_homography(H, spoke_angles):
    """Image angles atan2 of H @ (cos theta, sin theta).

    H: (..., 2, 2); spoke_angles: (..., N) [rad]. Returns (..., N) [rad] in (-pi, pi],
    oriented directions if H is oriented (pencil_homography with oriented inputs).

    >>> import numpy as np
    >>> round(float(np.degrees(apply_pencil_homography(np.diag([1.0, 0.5]), np.radians(45.0)))), 9)
    26.565051177
    """
    H = np.asarray(H, dtype=float)
    th = np.asarray(spoke_angles, dtype=float)
    c = np.stack([np.cos(th), np.sin(th)], -1)
    p = np.einsum("...ij,...nj->...ni", H, c) if th.ndim else H @ c
    return np.arctan2(p[..., 1], p[..., 0])


def homography_from_pose(R_cam_from_target, vertex):
    """The exact H of a pose: [[1, 0, -x], [0, 1, -y]] @ R[:, :2] (normalised coordinates).

    R_cam_from_target: (..., 3, 3); vertex: (..., 2) normalised image of the vertex.
    Returns (..., 2, 2), not normalised; oriented (a positive multiple of pencil.py's
    image directions).
    """
    R = np.asarray(R_cam_from_target, dtype=float)
    x = np.asarray(vertex, dtype=float)
    return R[..., :2, :2] - x[..., :, None] * R[..., 2:3, :2]


def line_through(p, q):
    """The homogeneous line (..., 3) ``a x + b y + c = 0`` through the points p, q (..., 2)
    (unnormalised: ``(a, b)`` has the length of q - p), their join ``(p, 1) x (q, 1)``.

    >>> line_through([0.0, 1.0], [2.0, 1.0]).tolist()                 # y = 1
    [0.0, 2.0, -2.0]
    """
    p, q = np.asarray(p, float), np.asarray(q, float)
    return np.cross(np.concatenate([p, np.ones(p.shape[:-1] + (1,))], -1),
                    np.concatenate([q, np.ones(q.shape[:-1] + (1,))], -1))


def line_meet(l1, l2):
    """The homogeneous point (..., 3) where the homogeneous lines l1, l2 (..., 3) meet, their
    cross product: its third coordinate 0 where they are parallel (a point at infinity),
    the point (x, y) = its first two over it otherwise.

    >>> line_meet([1.0, 0.0, -2.0], [0.0, 1.0, -3.0]).tolist()        # x = 2 and y = 3
    [2.0, 3.0, 1.0]
    """
    return np.cross(np.asarray(l1, float), np.asarray(l2, float))


def cross_ratio(a1, a2, a3, a4):
    """Cross-ratio (l1, l2; l3, l4) of four concurrent lines from their angles.

        CR = sin(a1 - a3) sin(a2 - a4) / (sin(a1 - a4) sin(a2 - a3))

    the angle form of (A, B; C, D) = (AC * BD) / (AD * BC) for the points where the lines
    cut any transversal. Each angle appears once in the numerator and once in the
    denominator, so CR is unchanged when any line is turned by pi (line or direction angles
    both work), and it is invariant under any 1-D homography of the pencil: the same for the
    3D spokes (theta_k), their perspective image, and raw pixels of an undistorted camera
    with any fx, fy and skew. a1..a4: broadcastable arrays [rad]. Returns their broadcast
    shape; huge, +-inf or NaN where lines 1 and 4 or 2 and 3 coincide.

    >>> import numpy as np
    >>> round(float(cross_ratio(*np.radians([0, 30, 60, 90]))), 12)
    1.5
    """
    a1, a2, a3, a4 = (np.asarray(v, dtype=float) for v in (a1, a2, a3, a4))
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.sin(a1 - a3) * np.sin(a2 - a4) / (np.sin(a1 - a4) * np.sin(a2 - a3))


def predict_line_angles(three_line_angles, three_spoke_angles, spoke_angles):
    """Predict the image angle of every spoke from three lines with known 3D angles.

    No intrinsics, vertex or pose are needed: three (line, spoke) pairs fix the 1-D
    homography (3 DOF) exactly. three_line_angles, three_spoke_angles: (..., 3) [rad]
    (more than three are accepted and fitted by DLT); spoke_angles: (..., M) [rad].
    Returns (..., M) [rad]; oriented when the three inputs are oriented directions, else
    meaningful modulo pi. Raises EstimationError when two of the three lines (or spokes)
    coincide, InputError on NaN.

    >>> import numpy as np
    >>> th = np.radians([0, 60, 120])
    >>> np.round(np.degrees(predict_line_angles(th, th, np.radians([30, 90]))), 9).tolist()
    [30.0, 90.0]
    """
    H = pencil_homography(three_line_angles, three_spoke_angles)
    th = np.asarray(spoke_angles, dtype=float)
    if not np.all(np.isfinite(th)):
        raise InputError("predict_line_angles: spoke angles contain NaN or infinity")
    return wrap_angle(apply_pencil_homography(H, th))
