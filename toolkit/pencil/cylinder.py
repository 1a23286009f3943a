"""Instrument shafts as cylinders: the 3-D axis from one calibrated view, and the 3-D fulcrum.

A straight shaft of known radius r images as a band between two silhouette lines. Each line
back-projects to a plane through the camera centre C tangent to the cylinder; from the two
planes the axis follows exactly, with its distance from the camera (the band's width fixes
the depth). Over a sequence every axis of an instrument pivoting about its entry port passes
through that port, the fulcrum, which is then a weighted intersection of 3-D lines.

Conventions
-----------
- Camera frame OpenCV (x right, y down, z forward; frames.py), C at the origin. Lengths in
  the unit of the radius (mm throughout the docs); angles in radians unless named ``_deg``.
- Pixels are *undistorted* ("ideal") pixels of the pinhole ``K`` (the caller undistorts);
  normalised coordinates are ``x = K^-1 (u, v, 1)``. A homogeneous line ``l = (a, b, c)``
  is the set ``a x + b y + c = 0``; a pixel line ``l_px`` is ``K^T l_px`` in normalised
  coordinates, and its back-projected plane through C has normal ``K^T l_px``.
- Silhouette planes: unit normals n1, n2 oriented so the cylinder lies on their positive
  side, ``n_i . A = r`` for every axis point A (the band's inside is positive).
- Then (module tests check each against exact projections): the axis direction is
  ``d ~ n1 x n2``; the plane through C and the axis has normal ``n1 - n2`` (it bisects the
  two silhouette planes; its image is the axis image, *not* the 2-D angular bisector of the
  two image lines); ``sin(beta) = |n1 + n2| / 2`` with beta half the angle the shaft subtends
  at C; the axis lies at ``rho = r / sin(beta)`` and its point closest to C is
  ``rho (n1 + n2) / |n1 + n2|``.
- Axis direction sign: away from the camera, ``d_z > 0`` (``d_z = 0``: ``d_y > 0``, then
  ``d_x > 0``). Lines are unoriented: the functions accept either sign of a direction;
  only the chart coordinates below depend on it.
- Edge noise (as vertex.py): an edge segment ``[x1, y1, x2, y2]`` [px] has the direction
  ``(cos phi, sin phi)`` from its first end point to its second and the normal ``nu`` (the
  direction turned by +90 deg); its errors are an angle ``d_phi`` [rad] that pivots the line
  about the segment centre m and a shift ``d_c`` [px] along ``nu``, with a 2x2 covariance of
  ``(d_phi, d_c)`` per edge.

The axis chart (the 4-dof parametrisation of ``axis_cov``)
-----------------------------------------------------------
An axis is the line through ``axis_point`` A along the unit ``axis_direction`` d, with the
frame ``axis_frame(A, d) = (u, w)``: u the unit vector from C to the axis's point closest to
C (the "depth" direction), ``w = d x u``. A nearby line is given by four numbers
``p = (theta_u, theta_w, s_u, s_w)``: it crosses the plane through A orthogonal to d at
``A + s_u u + s_w w`` [length] and runs along ``d + theta_u u + theta_w w`` (theta [rad],
gnomonic: the tilt's tangents). `axis_chart` gives p of any line; ``axis_cov`` is the 4x4
covariance of p. To first order the axis distance changes by ``s_u``, and a point of the
line at distance t along d from A moves perpendicular to d by ``s + t theta``: its 2x2
covariance is ``J C J^T`` with ``J = [t I, I]``, which is what `fulcrum_3d` weights with.
The chart belongs to the direction with its sign: d -> -d turns (u, w) into (u, -w) and p
into (-theta_u, theta_w, s_u, -s_w), so flip a covariance with its direction.

Example
-------
>>> import numpy as np
>>> K = np.array([[900.0, 0, 960], [0, 900, 540], [0, 0, 1]])
>>> outline = project_cylinder(K, [10.0, -5.0, 100.0], [0.6, 0.0, 0.8], 4.0)
>>> outline.lines.shape
(2, 3)
>>> ax = cylinder_axis(outline.normals[0], outline.normals[1], 4.0)
>>> np.round(ax.direction, 12).tolist(), round(float(ax.distance), 9)
([0.6, 0.0, 0.8], 52.239831546)
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import NamedTuple

import numpy as np

from pencilcal.toolkit.errors import EstimationError, InputError
from pencilcal.toolkit.geometry.quantiles import chi2_isf, chi2_sf
from pencilcal.toolkit.geometry.frames import normalize
from pencilcal.toolkit.pencil.defaults import ENDPOINT_SIGMA_PX
from pencilcal.toolkit.pencil.vertex import propagate_cov, segment_angle_sigma, segment_lines

__all__ = [
    "GATE_CONFIDENCE", "SHARED_FLOOR", "AXIS_KEYS", "CylinderOutline", "CylinderAxis", "ShaftAxis",
    "Fulcrum3D", "RayTriangulation", "Fusion", "project_cylinder", "edge_lines",
    "silhouette_planes", "cylinder_axis", "axis_image_line", "axis_frame", "axis_chart",
    "axis_offsets", "offset_chi2", "shaft_axis", "shaft_axis_record", "fulcrum_3d", "scatter_scale",
    "ray_from_image_point", "triangulate_rays", "combine_estimates", "shared_difference_chi2", "common_part",
]

# Confidence of the chi2 gates (outlier axes in fulcrum_3d, the consistency test of
# combine_estimates); the thresholds are its chi2 quantiles, never literals.
GATE_CONFIDENCE = 0.99

# A component of two estimates' difference under this fraction of its independent variance is
# one their shared data make up (out of the test, `shared_difference_chi2`). Not smaller: two fits
# of one view's data differ a few per cent (an axis gated out of one, weights elsewhere).
SHARED_FLOOR = 0.05

# The least scale of scatter_scale: exact axes (chi2 ~ 1e-20) would gate on rounding.
SCATTER_FLOOR = 0.01

# Most refits of the inlier set in fulcrum_3d (it is stable after two or three).
_GATE_ROUNDS = 10

# Central-difference steps of the axis Jacobian: edge angle [rad] and edge offset [px].
_STEP_ANGLE = 1e-6
_STEP_OFFSET = 1e-4


def _arrays_to_lists(obj):
    """A record of plain Python values: arrays to (nested) lists, numpy scalars to floats."""
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, (tuple, list)):
        return [_arrays_to_lists(v) for v in obj]
    return obj


class _Record:
    """Base of the result dataclasses: `to_dict` is the record, each field under its name."""

    def to_dict(self) -> dict:
        """The record: every field as (nested) lists of floats (bools for masks)."""
        return {k: _arrays_to_lists(getattr(self, k)) for k in self.__dataclass_fields__}


def _dot(a, b):
    return np.sum(a * b, -1)


# ------------------------------------------------------------------------- the axis geometry


class CylinderOutline(NamedTuple):
    """The silhouette of a cylinder (`project_cylinder`).

    lines: (..., 2, 3) the two silhouette lines in pixels, ``a u + b v + c = 0`` with
        ``(a, b)`` unit, so ``l . (u, v, 1)`` is the signed distance [px], positive inside
        the band.
    normals: (..., 2, 3) the oriented unit normals n1, n2 of the tangent planes (camera
        frame), ordered so that ``n1 x n2`` points along the given axis direction.
    """

    lines: np.ndarray
    normals: np.ndarray


class CylinderAxis(NamedTuple):
    """A cylinder's axis (`cylinder_axis`): point (..., 3) closest to C [length],
    direction (..., 3) unit with d_z > 0, distance (...) rho = |point| [length]."""

    point: np.ndarray
    direction: np.ndarray
    distance: np.ndarray


def project_cylinder(K, axis_point, axis_direction, radius):
    """The exact silhouette lines of an infinite cylinder, from its two tangent planes.

    The planes through C tangent to the cylinder contain the axis direction d; with u the unit
    vector from C to the axis's closest point (distance rho) and ``w = d x u`` their normals
    are ``(r / rho) u -/+ sqrt(1 - r^2 / rho^2) w``.

    K: (3, 3) intrinsics [px]; axis_point: (..., 3) any point of the axis [length];
    axis_direction: (..., 3) (any length, either sign); radius: scalar or (...) [length].
    Returns a `CylinderOutline`. InputError when C lies inside the cylinder (rho <= r).

    >>> K = np.array([[900.0, 0, 960], [0, 900, 540], [0, 0, 1]])
    >>> o = project_cylinder(K, [0.0, 0, 100], [1.0, 0, 0], 4.0)      # horizontal shaft
    >>> np.round(o.lines, 6).tolist()                                   # band v = 540 -+ 36.03
    [[0.0, 1.0, -503.971165], [0.0, -1.0, 576.028835]]
    """
    d = normalize(axis_direction)
    p = np.asarray(axis_point, float)
    closest = p - _dot(p, d)[..., None] * d
    rho = np.linalg.norm(closest, axis=-1)
    r = np.asarray(radius, float)
    if np.any(~(rho > r)):
        raise InputError("project_cylinder: the camera centre lies inside the cylinder (axis distance <= radius)")
    u = closest / rho[..., None]
    w = np.cross(d, u)
    c = (r / rho)[..., None]
    s = np.sqrt(1.0 - c * c)
    normals = np.stack([c * u - s * w, c * u + s * w], -2)
    lines = normals @ np.linalg.inv(np.asarray(K, float))          # l_px = K^-T n
    lines = lines / np.linalg.norm(lines[..., :2], axis=-1, keepdims=True)
    return CylinderOutline(lines, normals)


def edge_lines(K, edges_px):
    """The two edge segments of a shaft as homogeneous lines in normalised coordinates.

    K: (3, 3) [px]; edges_px: (..., 2, 4) the edges ``[x1, y1, x2, y2]`` [undistorted px].
    Returns (lines_n, inside_n): (..., 2, 3) the lines ``K^T l_px``, scaled so ``(a, b)`` is
    unit, and (..., 2) the mean of the two segment centres in normalised coordinates (a point
    inside the band, for `silhouette_planes`).

    >>> K = np.array([[900.0, 0, 960], [0, 900, 540], [0, 0, 1]])
    >>> lines, inside = edge_lines(K, [[0, 504, 1920, 504], [0, 576, 1920, 576]])
    >>> np.round(lines, 6).tolist(), np.round(inside, 9).tolist()
    ([[0.0, 1.0, 0.04], [0.0, 1.0, -0.04]], [0.0, 0.0])
    """
    K = np.asarray(K, float)
    seg = segment_lines(edges_px)
    lines_px = np.concatenate([seg.normal, seg.offset[..., None]], -1)
    lines_n = lines_px @ K
    lines_n = lines_n / np.linalg.norm(lines_n[..., :2], axis=-1, keepdims=True)
    inside_px = np.mean(seg.centre, axis=-2)
    inside_n = (inside_px - K[:2, 2]) @ np.linalg.inv(K[:2, :2]).T
    return lines_n, inside_n


def silhouette_planes(lines_n, inside_n):
    """Unit normals of the two silhouette planes, oriented with the band's inside positive.

    lines_n: (..., 2, 3) the two edges as homogeneous lines ``a x + b y + c = 0`` in
    normalised coordinates (any scale, either sign); inside_n: (..., 2) a normalised image
    point inside the band (e.g. between the edges' centres, as `edge_lines` gives). The
    plane through C of line l has normal ``l``; it is flipped so that
    ``n . (x_inside, y_inside, 1) > 0``: every ray through the band's inside meets the
    cylinder, which lies on one side of each tangent plane, so the axis is on the positive
    side (``n_i . A = r``). Returns (..., 2, 3).

    >>> n = silhouette_planes([[0.0, 1, 0.04], [0, 1, -0.04]], [0.0, 0])
    >>> (np.round(n, 6) + 0.0).tolist()
    [[0.0, 0.999201, 0.039968], [0.0, -0.999201, 0.039968]]
    """
    n = normalize(lines_n)
    x = np.asarray(inside_n, float)
    xh = np.concatenate([x, np.ones(x.shape[:-1] + (1,))], -1)
    side = np.einsum("...ki,...i->...k", n, xh)
    if np.any(side == 0.0):
        raise InputError("silhouette_planes: the inside point lies on an edge line")
    return n * np.sign(side)[..., None]


def _canonical_sign(d):
    """+1/-1 (...) that makes d point away from the camera: d_z > 0, else d_y > 0, else d_x > 0."""
    tiny = 1e-12
    s = np.where(np.abs(d[..., 2]) > tiny, d[..., 2], np.where(np.abs(d[..., 1]) > tiny, d[..., 1], d[..., 0]))
    return np.where(s < 0, -1.0, 1.0)


def cylinder_axis(n1, n2, radius):
    """The axis of a cylinder of known radius from its two oriented silhouette planes.

    n1, n2: (..., 3) unit normals with the axis on their positive side (`silhouette_planes`);
    radius: scalar or (...) [length]. Returns a `CylinderAxis`: the point closest to C,
    ``rho (n1 + n2) / |n1 + n2|`` with ``rho = 2 r / |n1 + n2|``; the direction
    ``~ n1 x n2`` with d_z > 0; rho. EstimationError when the planes do not bound a cylinder
    in front of them (n1 = -n2: zero subtended angle; n1 = n2: the edges coincide).

    >>> ax = cylinder_axis([0.0, 0.999201, 0.039968], [0.0, -0.999201, 0.039968], 4.0)
    >>> np.round(ax.point, 3).tolist(), (np.round(ax.direction, 12) + 0.0).tolist()
    ([0.0, 0.0, 100.08], [1.0, 0.0, 0.0])
    """
    n1 = np.asarray(n1, float)
    n2 = np.asarray(n2, float)
    total = n1 + n2
    m = np.linalg.norm(total, axis=-1)
    cross = np.cross(n1, n2)
    if np.any(~(m > 1e-12)) or np.any(~(np.linalg.norm(cross, axis=-1) > 1e-12)) or np.any(m >= 2.0):
        raise EstimationError("cylinder_axis: the two silhouette planes do not bound a cylinder")
    rho = 2.0 * np.asarray(radius, float) / m
    point = rho[..., None] * total / m[..., None]
    d = normalize(cross)
    d = d * _canonical_sign(d)[..., None]
    return CylinderAxis(point, d, rho)


def axis_image_line(n1, n2):
    """The image of the axis: the line of the plane through C and the axis, normal n1 - n2.

    n1, n2: (..., 3) oriented silhouette normals. Returns (..., 3) a homogeneous line in
    normalised coordinates scaled so ``(a, b)`` is unit; positive on n1's side (towards
    edge 2). In pixels it is ``K^-T l`` (rescale for a unit normal).

    >>> np.round(axis_image_line([0.0, 0.999201, 0.039968], [0.0, -0.999201, 0.039968]), 6).tolist()
    [0.0, 1.0, 0.0]
    """
    m = np.asarray(n1, float) - np.asarray(n2, float)
    return m / np.linalg.norm(m[..., :2], axis=-1, keepdims=True)


def axis_frame(point, direction):
    """The chart frame (u, w) of an axis (module docstring): (..., 2, 3) unit rows.

    u: from the origin to the line's closest point; ``w = d x u`` with d the unit direction.
    For a line through the origin (a viewing ray) u is the unit axis least aligned with d,
    made orthogonal to it. point: (..., 3) any point of the line; direction: (..., 3).

    >>> axis_frame([0.0, 0, 100], [1.0, 0, 0]).tolist()
    [[0.0, 0.0, 1.0], [0.0, -1.0, 0.0]]
    """
    d = normalize(direction)
    p = np.asarray(point, float)
    perp = p - _dot(p, d)[..., None] * d
    size = np.linalg.norm(perp, axis=-1)
    helper = np.eye(3)[np.argmin(np.abs(d), axis=-1)]
    alt = helper - _dot(helper, d)[..., None] * d
    through_origin = ~(size > 1e-12 * (1.0 + np.linalg.norm(p, axis=-1)))
    u = normalize(np.where(through_origin[..., None], alt, perp))
    return np.stack([u, np.cross(d, u)], -2)


def axis_chart(point, direction, ref_point, ref_direction, ref_frame=None):
    """The 4 chart coordinates (theta_u, theta_w, s_u, s_w) of a line about a reference axis.

    point, direction: (..., 3) the line (either sign of direction); ref_point,
    ref_direction: (..., 3) the reference axis, whose chart (module docstring) is centred on
    ref_point; ref_frame: (..., 2, 3) its (u, w), default ``axis_frame(ref_point,
    ref_direction)``. Returns (..., 4): theta [rad] (tangents of the tilt), s [length] (the
    crossing of the plane through ref_point orthogonal to ref_direction). Exact, not only
    first order; undefined for a line orthogonal to the reference direction.

    >>> axis_chart([0.0, 1, 101], [1.0, 0, 0.01], [0.0, 0, 100], [1.0, 0, 0]).tolist()
    [0.01, 0.0, 1.0, -1.0]
    """
    d0 = normalize(ref_direction)
    p0 = np.asarray(ref_point, float)
    E = axis_frame(p0, d0) if ref_frame is None else np.asarray(ref_frame, float)
    d = normalize(direction)
    along = _dot(d, d0)
    d = d * np.where(along < 0, -1.0, 1.0)[..., None]
    along = np.abs(along)
    p = np.asarray(point, float)
    crossing = p + d * (_dot(d0, p0 - p) / along)[..., None]
    theta = np.einsum("...ki,...i->...k", E, d) / along[..., None]
    s = np.einsum("...ki,...i->...k", E, crossing - p0)
    return np.concatenate([theta, s], -1)


# --------------------------------------------------------------------- the axis from edges


@dataclass(frozen=True, eq=False)
class ShaftAxis(_Record):
    """The 3-D axis of a shaft seen in one view, with its first-order covariance (`shaft_axis`).

    Leading shape (...) as the edges'.
    axis_point: (..., 3) [length] the axis's point closest to C.
    axis_direction: (..., 3) unit, d_z > 0 (away from the camera).
    axis_distance: (...) [length] rho = |axis_point|.
    axis_cov: (..., 4, 4) covariance of the chart coordinates (theta_u [rad], theta_w [rad],
        s_u [length], s_w [length]) about this axis (module docstring).
    axis_frame: (..., 2, 3) the chart's (u, w): u = axis_point / rho, w = d x u.
    axis_direction_sigma_deg: (...) [deg] RMS angle error of the direction,
        sqrt(var theta_u + var theta_w).
    axis_distance_sigma: (...) [length] sd of rho, sqrt(var s_u).
    normals: (..., 2, 3) the oriented silhouette-plane normals n1, n2.
    image_line_px: (..., 3) the axis image in pixels, ``(a, b)`` unit.
    """

    axis_point: np.ndarray
    axis_direction: np.ndarray
    axis_distance: np.ndarray
    axis_cov: np.ndarray
    axis_frame: np.ndarray
    axis_direction_sigma_deg: np.ndarray
    axis_distance_sigma: np.ndarray
    normals: np.ndarray
    image_line_px: np.ndarray


def _edge_covariance(edges, angle_sigma, offset_sigma, edge_cov):
    """(..., 4, 4) block-diagonal covariance of (d_phi1, d_c1, d_phi2, d_c2) [rad, px]."""
    if edge_cov is not None:
        if angle_sigma is not None or offset_sigma is not None:
            raise InputError("shaft_axis: give edge_cov or angle_sigma/offset_sigma, not both")
        blocks = np.broadcast_to(np.asarray(edge_cov, float), edges.shape[:-1] + (2, 2))
    else:
        sa = segment_angle_sigma(edges, ENDPOINT_SIGMA_PX) if angle_sigma is None else angle_sigma
        so = ENDPOINT_SIGMA_PX / np.sqrt(2.0) if offset_sigma is None else offset_sigma
        sa, so = np.broadcast_arrays(np.asarray(sa, float), np.asarray(so, float), edges[..., 0])[:2]
        blocks = np.zeros(sa.shape + (2, 2))
        blocks[..., 0, 0] = sa * sa
        blocks[..., 1, 1] = so * so
    cov = np.zeros(blocks.shape[:-3] + (4, 4))
    cov[..., 0:2, 0:2] = blocks[..., 0, :, :]
    cov[..., 2:4, 2:4] = blocks[..., 1, :, :]
    return cov


def _axis_from_edges(K, centre, phi, inside_n, radius, d_phi=0.0, d_c=0.0):
    """(CylinderAxis, normals) of edges through ``centre`` (..., 2, 2) [px] at angles ``phi``
    (..., 2), turned by d_phi [rad] about the centre and shifted by d_c [px] along the normal."""
    a = phi + d_phi
    nu = np.stack([-np.sin(a), np.cos(a)], -1)
    lines_px = np.concatenate([nu, (-_dot(nu, centre) - d_c)[..., None]], -1)
    normals = silhouette_planes(lines_px @ K, inside_n)
    return cylinder_axis(normals[..., 0, :], normals[..., 1, :], radius), normals


def shaft_axis(K, edges_px, radius, *, angle_sigma=None, offset_sigma=None, edge_cov=None, inside_px=None):
    """The 3-D axis of a shaft of known radius from its two image edges, with its covariance.

    K: (3, 3) intrinsics of the undistorted pixels (``camera.K``).
    edges_px: (..., 2, 4) the two edges ``[x1, y1, x2, y2]`` [undistorted px], in either
        order; each segment's centre is the pivot of its angle error (module docstring).
    radius: scalar or (...) [length] the shaft radius (half its diameter).
    angle_sigma [rad], offset_sigma [px]: scalars or (..., 2), independent sds of each edge's
        angle and of its offset at its centre; or edge_cov: (..., 2, 2, 2) the 2x2 covariance
        of (angle [rad], offset [px]) per edge. Default: the end-point model of vertex.py with
        ENDPOINT_SIGMA_PX (angle sd sqrt(2) sigma / L, offset sd sigma / sqrt(2)). A line
        fitted by least squares through N edge points of sd sigma, spread over along-positions
        s_k about their centroid, has angle sd ``sigma / sqrt(sum s_k^2)`` and offset sd
        ``sigma / sqrt(N)`` at the centroid.
    inside_px: (..., 2) a pixel inside the band; default the mean of the two edge centres.

    The covariance is first order, ``J C J^T``, with J the central-difference Jacobian of
    the axis chart coordinates with respect to the four edge parameters. Returns a
    `ShaftAxis`.

    >>> K = np.array([[900.0, 0, 960], [0, 900, 540], [0, 0, 1]])
    >>> ax = shaft_axis(K, [[0, 504, 1920, 504], [0, 576, 1920, 576]], 4.0,
    ...                 angle_sigma=1e-4, offset_sigma=0.3)
    >>> np.round(ax.axis_point, 3).tolist(), round(float(ax.axis_distance_sigma), 3)
    ([0.0, 0.0, 100.08], 0.589)
    """
    K = np.asarray(K, float)
    edges = np.asarray(edges_px, float)
    if edges.shape[-2:] != (2, 4):
        raise InputError(f"shaft_axis: edges_px must be (..., 2, 4), got {edges.shape}")
    seg = segment_lines(edges)
    if np.any(~(seg.length > 0)):
        raise InputError("shaft_axis: an edge segment has zero length")
    phi = np.arctan2(seg.direction[..., 1], seg.direction[..., 0])
    inside = np.mean(seg.centre, axis=-2) if inside_px is None else np.asarray(inside_px, float)
    inside_n = (inside - K[:2, 2]) @ np.linalg.inv(K[:2, :2]).T
    cov_edges = _edge_covariance(edges, angle_sigma, offset_sigma, edge_cov)

    axis, normals = _axis_from_edges(K, seg.centre, phi, inside_n, radius)
    frame = axis_frame(axis.point, axis.direction)
    steps = np.array([_STEP_ANGLE, _STEP_OFFSET, _STEP_ANGLE, _STEP_OFFSET])
    columns = []
    for j, h in enumerate(steps):
        sides = []
        for sign in (1.0, -1.0):
            q = np.zeros(4)
            q[j] = sign * h
            moved, _ = _axis_from_edges(K, seg.centre, phi, inside_n, radius, q[[0, 2]], q[[1, 3]])
            sides.append(axis_chart(moved.point, moved.direction, axis.point, axis.direction, frame))
        columns.append((sides[0] - sides[1]) / (2.0 * h))
    cov = propagate_cov(cov_edges, np.stack(columns, -1))
    image_n = axis_image_line(normals[..., 0, :], normals[..., 1, :])
    image_px = image_n @ np.linalg.inv(K)
    image_px = image_px / np.linalg.norm(image_px[..., :2], axis=-1, keepdims=True)
    return ShaftAxis(
        axis_point=axis.point,
        axis_direction=axis.direction,
        axis_distance=axis.distance,
        axis_cov=cov,
        axis_frame=frame,
        axis_direction_sigma_deg=np.degrees(np.sqrt(cov[..., 0, 0] + cov[..., 1, 1])),
        axis_distance_sigma=np.sqrt(cov[..., 2, 2]),
        normals=normals,
        image_line_px=image_px,
    )


#: The keys `shaft_axis_record` adds to a shaft's record (docs/formats.md).
AXIS_KEYS = ("axis_point", "axis_direction", "axis_distance", "axis_cov", "axis_direction_sigma_deg",
             "axis_distance_sigma")


def shaft_axis_record(camera, edges_raw, edge_cov, diameter):
    """The 3-D axis keys of one detected shaft (`AXIS_KEYS`), in the camera frame.

    camera: the `Camera` the shaft was detected with; edges_raw: (2, 4) the shaft's two
    edges [raw px] (``Shaft.edges``, a lines.json shaft's ``edges``); edge_cov: (2, 2, 2)
    per edge the covariance of its (angle [rad], offset [undistorted px]) about the centre
    of its undistorted segment (``Shaft.edge_cov``: the edge fits' a-posteriori variances
    plus the detector's edge floor); diameter: the shaft's diameter, in the unit every
    length of the result takes. The edges are undistorted (the detector fitted them
    straight there) and `shaft_axis` gives the axis and its chart covariance.

    Returns a dict of plain floats and lists: axis_point (3,), axis_direction (3,),
    axis_distance, axis_cov (4, 4) (the chart of the module docstring: theta_u, theta_w
    [rad], s_u, s_w [length]), axis_direction_sigma_deg, axis_distance_sigma [length].
    InputError for a diameter that is not positive or edges the lens model cannot undistort;
    EstimationError when the edges bound no cylinder.
    """
    if not (np.isfinite(diameter) and diameter > 0):
        raise InputError(f"shaft diameter must be a positive number, got {diameter!r}")
    edges_raw = np.asarray(edges_raw, float).reshape(2, 4)
    ideal = np.asarray(camera.undistort_pixels(edges_raw.reshape(-1, 2)), float).reshape(2, 4)
    if not np.all(np.isfinite(ideal)):
        raise InputError("shaft edges beyond the reach of the lens model cannot be undistorted")
    ax = shaft_axis(np.asarray(camera.K, float), ideal, 0.5 * float(diameter),
                    edge_cov=np.asarray(edge_cov, float).reshape(2, 2, 2))
    return {k: _arrays_to_lists(getattr(ax, k)) for k in AXIS_KEYS}


# ------------------------------------------------------------------ weighted line intersection


def axis_offsets(x, points, directions, frames, covs):
    """Offsets of the point x (..., 3) from lines (..., N, .) in their charts.

    Returns r (..., N, 2) = (u, w) . (x - point) [length], S (..., N, 2, 2) the covariance of
    that offset from the line's 4x4 chart covariance (``J C J^T``, ``J = [t I, I]``) and
    t (..., N) the distance of x's foot along each line from its point [length].
    """
    dx = x[..., None, :] - points
    t = _dot(dx, directions)
    r = np.einsum("...nki,...ni->...nk", frames, dx)
    tt = t[..., None, None]
    cross = covs[..., :2, 2:]
    S = tt * tt * covs[..., :2, :2] + tt * (cross + np.swapaxes(cross, -1, -2)) + covs[..., 2:, 2:]
    return r, S, t


def _inv2(S):
    """Inverses of symmetric 2x2 matrices (..., 2, 2), in closed form (many small ones)."""
    a, b, c = S[..., 0, 0], 0.5 * (S[..., 0, 1] + S[..., 1, 0]), S[..., 1, 1]
    det = a * c - b * b
    return np.stack([np.stack([c, -b], -1), np.stack([-b, a], -1)], -2) / det[..., None, None]


def offset_chi2(r, S):
    """r^T S^-1 r over the last axis: (..., N, 2), (..., N, 2, 2) -> (..., N)."""
    a, b, c = S[..., 0, 0], 0.5 * (S[..., 0, 1] + S[..., 1, 0]), S[..., 1, 1]
    x, y = r[..., 0], r[..., 1]
    return (c * x * x - 2.0 * b * x * y + a * y * y) / (a * c - b * b)


def _plain_point(points, directions, use):
    """The point with the least sum of squared distances to the used lines (unweighted)."""
    P = np.eye(3) - directions[..., :, None] * directions[..., None, :]
    P = P * use[..., None, None]
    H = P.sum(-3)
    g = np.einsum("...nij,...nj->...i", P, points)
    try:
        return np.linalg.solve(H, g[..., None])[..., 0]
    except np.linalg.LinAlgError:
        raise EstimationError("the axes do not fix a point (fewer than two, or all parallel)") from None


def _information(x, points, directions, frames, covs, use):
    """Normal equations (H (..., 3, 3), g (..., 3)) of the weighted fit at the point x."""
    _, S, _ = axis_offsets(x, points, directions, frames, covs)
    W = np.where(use[..., None, None], _inv2(S), 0.0)
    M = np.einsum("...nki,...nkl,...nlj->...nij", frames, W, frames)
    return M.sum(-3), np.einsum("...nij,...nj->...i", M, points)


def _weighted_point(x, points, directions, frames, covs, use, max_iter, tol):
    """Iterated weighted least squares of the point-to-line offsets (weights at the point).

    Returns the point (..., 3), its covariance H^-1 (..., 3, 3) at the final point and the
    number of iterations. EstimationError when the used lines do not fix a point.
    """
    it = 0
    for it in range(1, max_iter + 1):
        H, g = _information(x, points, directions, frames, covs, use)
        try:
            new = np.linalg.solve(H, g[..., None])[..., 0]
        except np.linalg.LinAlgError:
            raise EstimationError("the axes do not fix a point (fewer than two, or all parallel)") from None
        step = np.linalg.norm(new - x, axis=-1)
        x = new
        if np.all(step <= tol * (1.0 + np.linalg.norm(x, axis=-1))):
            break
    H, _ = _information(x, points, directions, frames, covs, use)
    cov = np.linalg.inv(H)
    if not np.all(np.isfinite(cov)):
        raise EstimationError("the axes do not fix a point (fewer than two, or all parallel)")
    return x, cov, it


def _pair_candidates(points, directions, max_pairs, seed):
    """Midpoints (..., H, 3) of the closest points of pairs of lines, and (..., H) valid."""
    n = points.shape[-2]
    i, j = np.triu_indices(n, 1)
    if i.size > max_pairs:
        pick = np.random.default_rng(seed).choice(i.size, size=max_pairs, replace=False)
        i, j = i[pick], j[pick]
    p, q = points[..., i, :], points[..., j, :]
    a, b = directions[..., i, :], directions[..., j, :]
    w0 = p - q
    ab, da, eb = _dot(a, b), _dot(a, w0), _dot(b, w0)
    den = 1.0 - ab * ab
    valid = den > 1e-12
    den = np.where(valid, den, 1.0)
    s = (ab * eb - da) / den
    t = (eb - ab * da) / den
    return 0.5 * (p + s[..., None] * a + q + t[..., None] * b), valid


def _robust_start(points, directions, frames, covs, gate, max_pairs, seed):
    """MSAC over pair midpoints: the candidate with the least sum of min(chi2, gate)."""
    cand, valid = _pair_candidates(points, directions, max_pairs, seed)
    lines = [a[..., None, :, :] for a in (points, directions)] + [a[..., None, :, :, :] for a in (frames, covs)]
    r, S, _ = axis_offsets(cand, *lines)
    score = np.minimum(offset_chi2(r, S), gate).sum(-1)
    score = np.where(valid, score, np.inf)
    best = np.argmin(score, axis=-1)
    return np.take_along_axis(cand, best[..., None, None], axis=-2)[..., 0, :]


@dataclass(frozen=True, eq=False)
class Fulcrum3D(_Record):
    """The 3-D fulcrum of a pivoting instrument (`fulcrum_3d`). N axes; leading shape (...).

    point: (..., 3) [length] the weighted intersection of the used axes.
    point_cov: (..., 3, 3) [length^2] its covariance H^-1 from the normal equations at the
        point (the Cramer-Rao bound at first order when the axis covariances are right);
        large along the common direction when the axes are nearly parallel.
    point_sigma: (...) [length] sqrt(trace(point_cov)): the predicted RMS 3-D error.
    distances: (..., N) [length] distance of the point from each axis (outliers included).
    chi2: (..., N) the normalised squared offset r^T S^-1 r of the point from each axis
        (2 dof), S the covariance of that axis's perpendicular position at the point.
    along: (..., N) [length] position of the point's foot along each axis from its point.
    inliers: (..., N) bool, the axes used (all when not robust).
    gate: the chi2 threshold (2 dof at `confidence`); iterations: of the last weighted solve.
    """

    point: np.ndarray
    point_cov: np.ndarray
    point_sigma: np.ndarray
    distances: np.ndarray
    chi2: np.ndarray
    along: np.ndarray
    inliers: np.ndarray
    gate: float
    iterations: int

    @property
    def outliers(self):
        """Indices of the axes left out: a tuple of ints; for batched results a list of
        such tuples over the flattened leading dimensions."""
        bad = ~np.asarray(self.inliers)
        if bad.ndim == 1:
            return tuple(int(k) for k in np.flatnonzero(bad))
        return [tuple(int(k) for k in np.flatnonzero(b)) for b in bad.reshape(-1, bad.shape[-1])]

    def to_dict(self) -> dict:
        """The record: every field as (nested) lists of floats, plus ``outliers``."""
        out = super().to_dict()
        out["outliers"] = _arrays_to_lists(self.outliers)
        return out


def _check_lines(points, directions, covs, frames):
    """Validated float arrays (points, unit directions, covs (.., 4, 4), frames (.., 2, 3))."""
    points = np.asarray(points, float)
    directions = normalize(directions)
    covs = np.asarray(covs, float)
    if points.shape[-1] != 3 or directions.shape[-1] != 3 or covs.shape[-2:] != (4, 4):
        raise InputError("axes: points and directions must be (..., N, 3), covariances (..., N, 4, 4)")
    frames = axis_frame(points, directions) if frames is None else np.asarray(frames, float)
    shape = np.broadcast_shapes(points.shape[:-1], directions.shape[:-1], covs.shape[:-2], frames.shape[:-2])
    return (np.broadcast_to(points, shape + (3,)), np.broadcast_to(directions, shape + (3,)),
            np.broadcast_to(covs, shape + (4, 4)), np.broadcast_to(frames, shape + (2, 3)))


def scatter_scale(chi2, clip=True):
    """(..., 1) the axes' own scale of their covariances: median chi2 (..., N) over chi2(2)'s
    median (2 ln 2), a robust (MAD-like) variance factor; clipped (the default) at most 1
    (never widening a gate, `fulcrum_3d`) and at least `SCATTER_FLOOR`.

    >>> scatter_scale(np.array([0.0, 2 * np.log(2) / 4, 9.0])).round(6).tolist()
    [0.25]
    """
    s = np.median(np.asarray(chi2, float), axis=-1, keepdims=True) / (2.0 * np.log(2.0))
    return np.clip(s, SCATTER_FLOOR, 1.0) if clip else s


def fulcrum_3d(axis_points, axis_directions, axis_covs, robust=True, *, axis_frames=None,
               confidence=GATE_CONFIDENCE, max_pairs=200, seed=0, max_iter=50, tol=1e-10, scatter_gate=False):
    """The fulcrum: the point closest to N 3-D axes, each weighted by its covariance.

    Minimises ``sum_k r_k^T S_k^-1 r_k`` with r_k the point's perpendicular offset from axis
    k in its chart frame and S_k the 2x2 covariance of the axis's perpendicular position at
    the point's foot (position and direction uncertainty, the latter times the distance
    along the axis; module docstring), iterating because S_k depends on the point. The
    covariance is the inverse of the normal equations' matrix at the solution.

    axis_points: (..., N, 3) [length] a point of each axis (the reference of its chart: the
        closest point to C for `shaft_axis` results); axis_directions: (..., N, 3) (either
        sign); axis_covs: (..., N, 4, 4) chart covariances ([rad, rad, length, length]);
        axis_frames: (..., N, 2, 3) the charts' (u, w), default `axis_frame`.
    robust: start from the best pair of axes by MSAC and keep iterating a chi2 gate (2 dof,
        ``chi2.ppf(confidence, 2)``) on the axes until the inlier set is stable; else use all.
    max_pairs, seed: the pairs tried for the robust start (all when fewer).
    scatter_gate: the gate on chi2 over `scatter_scale` (axes scattering less than their
        covariances say: an edge floor), so that a few axes misread alike (near shafts' edges
        leaning onto the wrist) do not pass it; weights and covariance stay the stated ones.
    Returns a `Fulcrum3D`; EstimationError when fewer than two non-parallel axes remain.

    >>> d = normalize([[1.0, 0, 0], [0, 1, 0], [1, 1, 1]])
    >>> pts = np.array([0.0, 0, 100]) - 20 * d             # three axes through (0, 0, 100)
    >>> covs = np.diag([1e-6, 1e-6, 0.01, 0.01])            # 1 mrad, 0.1 mm
    >>> fit = fulcrum_3d(pts, d, np.broadcast_to(covs, (3, 4, 4)))
    >>> # (+ 0.0: a zero that comes out as -1e-15 rounds to -0.0)
    >>> (np.round(fit.point, 9) + 0.0).tolist(), fit.outliers
    ([0.0, 0.0, 100.0], ())
    """
    P, D, C, E = _check_lines(axis_points, axis_directions, axis_covs, axis_frames)
    if P.shape[-2] < 2:
        raise EstimationError("fulcrum_3d: at least two axes are needed")
    gate = chi2_isf(1.0 - confidence, 2)
    use = np.ones(P.shape[:-1], bool)
    if robust:
        x = _robust_start(P, D, E, C, gate, max_pairs, seed)
        c2 = offset_chi2(*axis_offsets(x, P, D, E, C)[:2])
        use = c2 < gate * (scatter_scale(c2) if scatter_gate else 1.0)
    else:
        x = _plain_point(P, D, use)
    rounds = _GATE_ROUNDS if robust else 1
    for k in range(rounds):
        if np.any(use.sum(-1) < 2):
            raise EstimationError("fulcrum_3d: fewer than two axes pass the chi2 gate")
        x, cov, it = _weighted_point(x, P, D, E, C, use, max_iter, tol)
        r, S, t = axis_offsets(x, P, D, E, C)
        c2 = offset_chi2(r, S)
        gated = c2 < gate * (scatter_scale(c2) if scatter_gate else 1.0)
        if np.array_equal(gated, use) or k == rounds - 1:
            break
        use = gated
    return Fulcrum3D(point=x, point_cov=cov, point_sigma=np.sqrt(np.trace(cov, axis1=-2, axis2=-1)),
                     distances=np.linalg.norm(r, axis=-1), chi2=c2, along=t, inliers=use,
                     gate=gate, iterations=it)


# ------------------------------------------------------------------- two views, and fusion


def ray_from_image_point(x_n, cov_n=None):
    """The unit viewing ray of a normalised image point, and its 3x3 covariance.

    x_n: (..., 2) normalised coordinates; cov_n: (..., 2, 2) their covariance (e.g. a
    vertex's pixel covariance through propagate_cov with inv(K[:2, :2])). Returns
    (ray (..., 3) with ray_z > 0, cov (..., 3, 3) singular along the ray, or None).

    >>> ray, cov = ray_from_image_point([0.0, 0.0], np.eye(2) * 1e-6)
    >>> ray.tolist(), np.round(cov, 9).tolist()
    ([0.0, 0.0, 1.0], [[1e-06, 0.0, 0.0], [0.0, 1e-06, 0.0], [0.0, 0.0, 0.0]])
    """
    x = np.asarray(x_n, float)
    v = np.concatenate([x, np.ones(x.shape[:-1] + (1,))], -1)
    size = np.linalg.norm(v, axis=-1)[..., None, None]
    ray = v / size[..., 0]
    if cov_n is None:
        return ray, None
    J = ((np.eye(3) - ray[..., :, None] * ray[..., None, :]) / size)[..., :, :2]
    return ray, propagate_cov(cov_n, J)


def _ray_cov3(ray, cov, what):
    """(..., 3, 3) covariance of a unit ray from its 2x2 (normalised point) or 3x3 form."""
    cov = np.asarray(cov, float)
    if cov.shape[-2:] == (3, 3):
        return cov
    if cov.shape[-2:] == (2, 2):
        if np.any(~(ray[..., 2] > 0)):
            raise InputError(f"triangulate_rays: {what} has a 2x2 covariance but does not point forward")
        return ray_from_image_point(ray[..., :2] / ray[..., 2:], cov)[1]
    raise InputError(f"triangulate_rays: {what}'s covariance must be (..., 2, 2) or (..., 3, 3), got {cov.shape}")


@dataclass(frozen=True, eq=False)
class RayTriangulation(_Record):
    """A point from two views' rays (`triangulate_rays`), in the left camera frame.

    point: (..., 3) [length]; point_cov: (..., 3, 3); point_sigma: (...) sqrt(trace).
    ranges: (..., 2) [length] distance of the point's foot along each ray from its camera.
    distances: (..., 2) [length] the point's distance from each ray.
    chi2: (...) sum of the rays' normalised squared offsets; it has 1 dof (4 - 3).
    ray_information: (..., 2, 3, 3) what each ray (left, right) tells of the point, at the
        point: ``E^T S^-1 E`` with E (2, 3) the ray's chart rows and S the covariance of the
        point's offset from it (the ray's angular covariance times the squared range);
        their sum is ``point_cov^-1``. ray_information_vector: (..., 2, 3) ``I_k c_k`` with
        c_k the ray's camera centre (left frame): with it a ray is one term of an
        information sum (`combine_estimates`'s ``shared``).
    """

    point: np.ndarray
    point_cov: np.ndarray
    point_sigma: np.ndarray
    ranges: np.ndarray
    distances: np.ndarray
    chi2: np.ndarray
    ray_information: np.ndarray
    ray_information_vector: np.ndarray


def triangulate_rays(ray_left, cov_left, ray_right, cov_right, R_right_from_left, t_right_from_left,
                     *, max_iter=50, tol=1e-10):
    """The point where two views' rays (e.g. their fulcrum rays) meet, with its covariance.

    ray_left: (..., 3) the ray in the left camera frame, ray_right: (..., 3) in the right one
    (any length); cov_left, cov_right: (..., 2, 2) covariance of the ray's normalised image
    point (x/z, y/z), or (..., 3, 3) covariance of the unit ray. ``p_right = R p_left + t``
    with R_right_from_left (..., 3, 3) and t_right_from_left (..., 3) [length].

    The weighted least-squares point: each ray's perpendicular offset is weighted by its
    angular covariance times the squared range (iterated); for equal isotropic angular
    noise at equal ranges it is the midpoint of the common perpendicular. Result in the left
    camera frame; a `RayTriangulation`. EstimationError for parallel rays.

    >>> R, t = np.eye(3), np.array([-50.0, 0, 0])             # right camera 50 mm to the right
    >>> X = np.array([10.0, 0, 100])
    >>> tri = triangulate_rays(X, np.eye(2) * 1e-6, R @ X + t, np.eye(2) * 1e-6, R, t)
    >>> np.round(tri.point, 9).tolist(), round(float(tri.point_sigma), 3)
    ([10.0, 0.0, 100.0], 0.303)
    """
    R = np.asarray(R_right_from_left, float)
    t = np.asarray(t_right_from_left, float)
    a = normalize(ray_left)
    b_right = normalize(ray_right)
    cov_a = _ray_cov3(a, cov_left, "ray_left")
    cov_b = np.swapaxes(R, -1, -2) @ _ray_cov3(b_right, cov_right, "ray_right") @ R
    b = np.einsum("...ji,...j->...i", R, b_right)
    centre_right = -np.einsum("...ji,...j->...i", R, t)
    points = np.stack(np.broadcast_arrays(np.zeros(3), centre_right), -2)
    dirs = np.stack(np.broadcast_arrays(a, b), -2)
    points = np.broadcast_to(points, np.broadcast_shapes(points.shape, dirs.shape))
    frames = axis_frame(points, dirs)
    cov3 = np.stack(np.broadcast_arrays(cov_a, cov_b), -3)
    covs = np.zeros(np.broadcast_shapes(frames.shape[:-2], cov3.shape[:-2]) + (4, 4))
    covs[..., :2, :2] = frames @ cov3 @ np.swapaxes(frames, -1, -2)
    x0, valid = _pair_candidates(points, dirs, 1, 0)
    if not np.all(valid):
        raise EstimationError("triangulate_rays: the rays are parallel")
    use = np.ones(points.shape[:-1], bool)
    x, cov, _ = _weighted_point(x0[..., 0, :], points, dirs, frames, covs, use, max_iter, tol)
    r, S, along = axis_offsets(x, points, dirs, frames, covs)
    info = np.swapaxes(frames, -1, -2) @ _inv2(S) @ frames
    return RayTriangulation(point=x, point_cov=cov, point_sigma=np.sqrt(np.trace(cov, axis1=-2, axis2=-1)),
                            ranges=along, distances=np.linalg.norm(r, axis=-1), chi2=offset_chi2(r, S).sum(-1),
                            ray_information=info, ray_information_vector=np.einsum("...ij,...j->...i", info, points))


@dataclass(frozen=True, eq=False)
class Fusion(_Record):
    """Two estimates of one point fused by information (`combine_estimates`).

    point: (..., n) [length]; cov: (..., n, n) = (C1^-1 + C2^-1)^-1; sigma: (...) sqrt(trace).
    chi2: (...) squared Mahalanobis distance of x1 - x2 under its covariance (C1 + C2 for
    independent estimates; n dof); dof: n; threshold: ``chi2.ppf(confidence, n)``;
    consistent: (...) bool, chi2 <= threshold; p_value: (...) chi2.sf(chi2, n).
    """

    point: np.ndarray
    cov: np.ndarray
    sigma: np.ndarray
    chi2: np.ndarray
    dof: int
    threshold: float
    consistent: np.ndarray
    p_value: np.ndarray


def combine_estimates(x1, C1, x2, C2, confidence=GATE_CONFIDENCE, shared=None, common=None, shared_own=None,
                      unweighted1=None):
    """Information-weighted fusion of two estimates, and their consistency test.

    x1, x2: (..., n) the estimates; C1, C2: (..., n, n) their covariances. shared: None when
    the estimates come from independent data, else ``(I_s, h_s)``, (..., n, n) and (..., n):
    the information matrix and vector of data that both contain (e.g. one view's fulcrum
    ray, `RayTriangulation.ray_information`, in a triangulation and in that view's
    diameter-based point), each estimate being, to first order, the information sum of
    its own data and these. Then the fusion counts them once,
    ``cov = (C1^-1 + C2^-1 - I_s)^-1``, ``point = cov (C1^-1 x1 + C2^-1 x2 - h_s)``, and the
    difference's covariance is ``cov_diff = C1 + C2 - C1 I_s C2 - C2 I_s C1`` (their shared
    part cancels in it). The test: ``(x1 - x2)^T cov_diff^-1 (x1 - x2)`` is chi2 with n dof
    when both are right (independent estimates: ``cov_diff = C1 + C2``). With shared data a
    component of the difference can vanish (both estimates hold nothing else there): the
    components whose variance in cov_diff is under `SHARED_FLOOR` of their variance in
    C1 + C2 (or below zero: two fits of the same data differ a little in what they hold)
    are left out of the test, and ``dof`` counts the others (the least over a batch).
    Consistent at `confidence` when chi2 is at most ``chi2.ppf(confidence, dof)``. Returns a
    `Fusion`; EstimationError when the shared information exceeds what both estimates hold
    together (the fused covariance is not positive definite).

    common: None, or (..., n, n) the covariance of one error that both estimates carry alike
    (an offset of the point itself, e.g. a pivoting instrument's play in its port: not
    data that both hold, which `shared` counts once, but an error no second estimate
    averages). The point is the one without it (the same weights W_k = cov C_k^-1), and its
    covariance gains the cross terms ``W1 S W2^T + W2 S W1^T`` (S counted whole where both
    weigh it, not averaged); S cancels in the difference, so the test is that of C1 - S
    and C2 - S. S is `common` scaled down where needed (by the largest factor up to 1 that
    leaves C1 - S and C2 - S positive definite, with a margin of 10 %), so that neither
    estimate is said to hold less than nothing of its own. EstimationError also where the
    fused covariance with the cross terms is not positive definite.

    shared_own: None (``shared``), or ``(I_s, h_s)`` as ``shared`` but of the shared data's
    own noise, the common error taken out (its information is then larger): the test's
    covariances C1 - S and C2 - S hold the shared data with that information, and the part
    of the difference they cancel is read with it (with ``shared``, whose information holds
    the common error, the shared data's component of the difference keeps a variance it
    does not have and counts as a dof it is not). Where the own information exceeds what
    C1 - S and C2 - S hold together, the test is read with ``shared``.

    unweighted1: None, or (..., n, n) the covariance of an error of x1 alone that C1 leaves
    out and the fusion does not weigh (e.g. the depth a diameter-based point takes from the
    band width, whose error the sequence shares): the point and the test are those without
    it, and the fused covariance gains ``W1 E W1^T`` (W1 = cov C1^-1, the weight x1 had), the
    part of that error the point took.

    >>> f = combine_estimates([0.0, 0, 100], np.eye(3), [0.0, 0, 102], np.eye(3))
    >>> f.point.tolist(), float(f.chi2), bool(f.consistent), f.dof
    ([0.0, 0.0, 101.0], 2.0, True, 3)
    >>> I_s = np.diag([0.5, 0.5, 0.0])                      # both hold the same x, y information
    >>> f = combine_estimates([0.0, 0, 100], np.eye(3), [0.0, 0, 102], np.eye(3), shared=(I_s, np.zeros(3)))
    >>> np.round(np.diag(f.cov), 6).tolist(), f.dof         # x, y counted once
    ([0.666667, 0.666667, 0.5], 3)
    >>> f = combine_estimates([0.0, 0, 100], np.eye(3), [0.0, 0, 102], np.eye(3), shared=(np.diag([1.0, 0, 0]),
    ...                       np.zeros(3)))                     # x: all either holds
    >>> float(f.chi2), f.dof
    (2.0, 2)
    """
    x1, x2 = np.asarray(x1, float), np.asarray(x2, float)
    C1, C2 = np.asarray(C1, float), np.asarray(C2, float)
    f, W1 = _fused(x1, C1, x2, C2, confidence, shared, common, shared_own)
    if unweighted1 is None:
        return f
    # the weights as without it: x1's error E moves the point by W1 E
    cov = f.cov + W1 @ np.asarray(unweighted1, float) @ np.swapaxes(W1, -1, -2)
    cov = 0.5 * (cov + np.swapaxes(cov, -1, -2))
    return replace(f, cov=cov, sigma=np.sqrt(np.trace(cov, axis1=-2, axis2=-1)))


def _fused(x1, C1, x2, C2, confidence, shared, common, shared_own):
    """`combine_estimates` without ``unweighted1``: (the `Fusion`, W1 (..., n, n) the weight
    x1 has in its point, ``cov C1^-1`` of the fusion without ``common``), in one pass of the
    shared-only fusion."""
    if common is not None:
        S = common_part(common, C1, C2)
        f, _ = _fused(x1, C1, x2, C2, confidence, shared, None, None)
        # the same weights, W_k = cov I_k; the error both carry adds W1 S W2^T + W2 S W1^T
        W1, W2 = f.cov @ np.linalg.inv(C1), f.cov @ np.linalg.inv(C2)
        cross = W1 @ S @ np.swapaxes(W2, -1, -2)
        cov = f.cov + cross + np.swapaxes(cross, -1, -2)
        if np.any(np.linalg.eigvalsh(cov)[..., 0] <= 0):
            raise EstimationError("combine_estimates: the common error exceeds what the estimates hold")
        try:
            test, _ = _fused(x1, C1 - S, x2, C2 - S, confidence, shared if shared_own is None else shared_own,
                             None, None)
        except EstimationError:
            # the own information exceeds what the noise parts hold together (their fusion,
            # not used here, is not positive definite): the test as with `shared`
            test, _ = _fused(x1, C1 - S, x2, C2 - S, confidence, shared, None, None)
        return Fusion(point=f.point, cov=cov, sigma=np.sqrt(np.trace(cov, axis1=-2, axis2=-1)), chi2=test.chi2,
                      dof=test.dof, threshold=test.threshold, consistent=test.consistent,
                      p_value=test.p_value), W1
    I1, I2 = np.linalg.inv(C1), np.linalg.inv(C2)
    if shared is None:
        I_s, h_s = np.zeros_like(I1), np.zeros_like(x1)
    else:
        I_s, h_s = np.asarray(shared[0], float), np.asarray(shared[1], float)
    cov = np.linalg.inv(I1 + I2 - I_s)
    point = np.einsum("...ij,...j->...i", cov, np.einsum("...ij,...j->...i", I1, x1)
                      + np.einsum("...ij,...j->...i", I2, x2) - h_s)
    diff = x1 - x2
    n = x1.shape[-1]
    if np.any(np.linalg.eigvalsh(cov)[..., 0] <= 0):
        raise EstimationError("combine_estimates: the shared information exceeds what the estimates hold")
    if shared is None:
        c2 = _dot(diff, np.linalg.solve(C1 + C2, diff[..., None])[..., 0])
        dof = np.full(c2.shape, n)
    else:
        cross = C1 @ I_s @ C2
        c2, dof = shared_difference_chi2(diff, C1 + C2 - cross - np.swapaxes(cross, -1, -2), C1 + C2)
    dof = int(np.min(dof)) if np.ndim(dof) else int(dof)
    threshold = chi2_isf(1.0 - confidence, dof)
    return Fusion(point=point, cov=cov, sigma=np.sqrt(np.trace(cov, axis1=-2, axis2=-1)), chi2=c2, dof=dof,
                  threshold=threshold, consistent=c2 <= threshold, p_value=chi2_sf(c2, dof)), cov @ I1


def shared_difference_chi2(diff, cov_diff, cov_independent):
    """(chi2 (...), dof (...)): the test of two estimates' difference diff (..., n), its
    covariance cov_diff (..., n, n) made smaller by shared data than cov_independent: whitened
    by it, cov_diff's eigenvalues are the share each component keeps (1: independent, 0: the
    same in both); those under `SHARED_FLOOR` are left out, dof counts the others.

    >>> [float(v) for v in shared_difference_chi2(np.array([1.0, 2.0]), np.diag([0.5, 1e-6]), np.eye(2))]
    [2.0, 1.0]"""
    W, D = np.linalg.inv(np.linalg.cholesky(cov_independent)), np.asarray(cov_diff, float)
    lam, V = np.linalg.eigh(W @ (0.5 * (D + np.swapaxes(D, -1, -2))) @ np.swapaxes(W, -1, -2))
    keep = lam > SHARED_FLOOR
    z = np.einsum("...ji,...j->...i", V, np.einsum("...ij,...j->...i", W, diff))
    return np.sum(np.where(keep, z * z / np.where(keep, lam, 1.0), 0.0), -1), keep.sum(-1)


def common_part(common, *covs, margin=0.9):
    """(..., n, n) the covariance `common` scaled by the largest factor up to 1 that leaves
    every one of `covs` (..., n, n) less it positive definite, with `margin` of what it
    could take: the largest generalised eigenvalue of (common, C) is at most `margin`
    after scaling (`combine_estimates`'s ``common``).

    >>> common_part(np.eye(2), np.eye(2) * 4.0).tolist()
    [[1.0, 0.0], [0.0, 1.0]]
    >>> np.round(common_part(np.eye(2), np.diag([4.0, 0.5])), 6).tolist()
    [[0.45, 0.0], [0.0, 0.45]]
    """
    S = np.asarray(common, float)
    S = 0.5 * (S + np.swapaxes(S, -1, -2))
    scale = np.ones(S.shape[:-2])
    for C in covs:
        try:
            W = np.linalg.inv(np.linalg.cholesky(np.asarray(C, float)))
        except np.linalg.LinAlgError:
            raise EstimationError("a covariance to fuse is not positive definite") from None
        top = np.linalg.eigvalsh(W @ S @ np.swapaxes(W, -1, -2))[..., -1]
        scale = np.minimum(scale, np.where(top > margin, margin / np.maximum(top, 1e-300), 1.0))
    return S * scale[..., None, None]
