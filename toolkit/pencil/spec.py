"""Pencils: the pencil file, and exact projection of a pencil into the image.

A *pencil* is a fan of coplanar spokes through one point, the vertex. Spoke k points along
``(cos theta_k, sin theta_k, 0)`` in the target frame (frames.py); the vertex sits at
``(vertex[0], vertex[1], 0)`` and the spokes run from ``radius[0]`` to ``radius[1]`` from it.

What is printed along a spoke is its *shape*: a thin line or a bar whose centre line is the
spoke (``line``, a printed fan), a wedge whose two edges are rays through the vertex and
whose centre line is the spoke (``wedge``, a Siemens star), or the boundary between two
sectors of different shade (``edge``, a dartboard, a checkered star). Where the spokes are
edges (`Pencil.edge_angles`), the image measures the edges themselves: each is an exact ray
through the vertex, whatever the perspective, where a wedge's image bisector is not the
image of its centre line. ``circles`` are the radii of circles about the vertex printed
with it (a dartboard's rings, a star's outline): their images give the plane a second time.

The forward model works in *normalised* image coordinates (z = 1 plane, no distortion):
a spoke with camera-frame direction d through the vertex P0 = depth * (x_d, y_d, 1) images
as the line through x_d with oriented direction

    w = d_xy - x_d * d_z          (up to a positive factor; derivative of x(P0 + s d) at s=0)

and image angle ``atan2(w_y, w_x)``. It depends on the vertex only through its image x_d:
depth drops out. This is the exact model every estimator and test in pencilcal is
measured against.

Example
-------
>>> import numpy as np
>>> R = np.eye(3)                        # frontal target, vertex on the optical axis
>>> np.degrees(image_angles(R, [0.0, 0.0], np.radians([0, 30, 90]))).round(9).tolist()
[0.0, 30.0, 90.0]
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pencilcal.toolkit.errors import InputError
from pencilcal.toolkit.io.files import atomic_write, is_number, load_structured

__all__ = [
    "MAX_SPOKES",
    "SHAPES",
    "POLARITIES",
    "Pencil",
    "pencil_from_dict",
    "may_be_star",
    "as_star",
    "read_pencil",
    "write_pencil",
    "spoke_directions",
    "image_directions",
    "image_angles",
    "spoke_points_cam",
    "project_spokes",
]


#: What is printed along each spoke (the pencil file's ``shape``): a thin line or a bar whose
#: centre line is the spoke, a wedge whose centre line it is (its edges rays through the
#: vertex: a Siemens star), or the boundary between two sectors of different shade.
SHAPES = ("line", "wedge", "edge")
#: ``polarity``: dark wedges on a light ground or light ones on a dark ground; for edges,
#: whether the sector that starts at the first spoke (turning towards larger angles) is dark
#: or light.
POLARITIES = ("dark", "light")


@dataclass(frozen=True, eq=False)
class Pencil:
    """A fan of spokes in the target plane.

    angles: (N,) spoke directions theta_k [rad] in the target frame, in the file's order.
    vertex: (2,) vertex in the target frame (length unit), or None if unknown.
    radius: (2,) inner and outer end of every spoke, measured from the vertex, or None.
    width: printed width of each spoke (a dark bar, length unit), or None. The spoke is
        the bar's centre line; `pencilcal lines` finds it from the bar's two edges.
    shape: "line" (thin lines or bars), "wedge" or "edge" (`SHAPES`).
    wedge: angular width [rad] of each wedge (shape "wedge"), or None.
    polarity: "dark", "light" (`POLARITIES`) or None (edges: not said).
    circles: (C,) radii of printed circles centred on the vertex (length unit), or None.
    """

    angles: np.ndarray
    vertex: np.ndarray | None = None
    radius: np.ndarray | None = None
    width: float | None = None
    shape: str = "line"
    wedge: float | None = None
    polarity: str | None = None
    circles: np.ndarray | None = None

    @property
    def count(self) -> int:
        return int(self.angles.shape[0])

    @property
    def full_circle(self) -> bool:
        """True when the spokes go all around the vertex: no gap between neighbours (in
        angle order) reaches 180 deg, so every image line through the vertex has spokes on
        both sides of it."""
        a = np.sort(np.remainder(self.angles, 2 * np.pi))
        return bool(np.max(np.diff(np.r_[a, a[0] + 2 * np.pi])) < np.pi)

    def edge_angles(self):
        """The lines the image measures, as a pencil of their own: (angles (E,) [rad],
        spoke (E,) the spoke each belongs to, kind (E,) or None).

        For ``line`` the spokes themselves (E = N). For ``wedge`` the two edges of every
        wedge, at theta_k -+ wedge / 2 (E = 2N). For ``edge`` the spokes. ``kind`` says which
        side of an edge is brighter, seen from the vertex: +1 when the image gets brighter
        turning towards larger angles, -1 when darker; None where the pencil file does not
        say (lines, or edges without a polarity).

        >>> p = pencil_from_dict({"start_deg": 0, "step_deg": 90, "count": 4, "shape": "wedge"})
        >>> a, k, kind = p.edge_angles()
        >>> np.degrees(a).round(6).tolist()[:4], k.tolist()[::4], kind.tolist()[::4]
        ([-22.5, 67.5, 157.5, 247.5], [0, 0], [-1, 1])
        """
        n = self.count
        if self.shape == "wedge":
            h = 0.5 * self.wedge
            sign = 1 if self.polarity != "light" else -1
            angles = np.concatenate([self.angles - h, self.angles + h])
            kind = np.concatenate([np.full(n, -sign), np.full(n, sign)])
            return angles, np.tile(np.arange(n), 2), kind
        if self.shape == "edge" and self.polarity is not None:
            # alternating sectors: rank the spokes by angle from the first one
            rank = np.empty(n, int)
            rank[np.argsort(np.remainder(self.angles - self.angles[0], 2 * np.pi), kind="stable")] = np.arange(n)
            sign = 1 if self.polarity == "dark" else -1
            return self.angles.copy(), np.arange(n), np.where(rank % 2 == 0, -sign, sign)
        return self.angles.copy(), np.arange(n), None

    def to_dict(self) -> dict:
        # degrees are what people type; 12 decimals hide the radian round trip's last bit
        d = {"angles_deg": [float(a) for a in np.round(np.degrees(self.angles), 12)]}
        if self.vertex is not None:
            d["vertex"] = [float(v) for v in self.vertex]
        if self.radius is not None:
            d["radius"] = [float(r) for r in self.radius]
        if self.width is not None:
            d["width"] = float(self.width)
        if self.shape != "line":
            d["shape"] = self.shape
        if self.wedge is not None:
            d["wedge_deg"] = float(np.round(np.degrees(self.wedge), 12))
        if self.polarity is not None:
            d["polarity"] = self.polarity
        if self.circles is not None:
            d["circles"] = [float(c) for c in self.circles]
        return d


def may_be_star(pencil):
    """True for a pencil file that may describe a Siemens star without saying so: lines all
    round the vertex (`Pencil.full_circle`), no bar width, at least 8 of them. Such a file's
    spokes may be a star's wedges' centre lines (`as_star`), which the wedges' edges measure.

    >>> may_be_star(pencil_from_dict({"start_deg": 0, "step_deg": 5.625, "count": 64}))
    True
    """
    return pencil.shape == "line" and pencil.width is None and pencil.count >= 8 and pencil.full_circle


def as_star(pencil, polarity="dark"):
    """The Siemens star a pencil of lines (`may_be_star`) describes when its spokes are the
    centre lines of its wedges (dark ones on a light ground for `polarity` "dark", light on
    dark for "light"), each wedge half the smallest gap wide: the same spokes, vertex, radius
    and circles, shape "wedge". A printed star's wedges are rarely exactly that wide (the
    ink spreads); the orientation, fitted to their edges, tolerates it (docs/method.md).

    >>> s = as_star(pencil_from_dict({"start_deg": 0, "step_deg": 5.625, "count": 64, "radius": [12, 70]}))
    >>> s.shape, round(float(np.degrees(s.wedge)), 4), s.polarity, s.radius.tolist()
    ('wedge', 2.8125, 'dark', [12.0, 70.0])
    """
    if polarity not in POLARITIES:
        raise InputError(f"polarity must be one of {', '.join(POLARITIES)}, got {polarity!r}")
    a = np.sort(np.remainder(pencil.angles, 2 * np.pi))
    gap = float(np.min(np.diff(np.r_[a, a[0] + 2 * np.pi])))
    return Pencil(pencil.angles, pencil.vertex, pencil.radius, None, "wedge", 0.5 * gap, polarity, pencil.circles)


#: Most spokes a pencil file may give. A printed fan has a few dozen; past a few hundred the
#: spokes are under a degree apart, no image tells them apart, and the spoke assignment's
#: work (hypotheses pair triples of lines with triples of spokes) grows with their number.
MAX_SPOKES = 360


def _floats(value, n, key, source):
    """`value` as n finite numbers (n,); InputError naming `source` and `key` otherwise.

    Only numbers are numbers: the string "12" or true is refused, not converted.
    """
    items = value if isinstance(value, (list, tuple)) else [value]
    bad = next((v for v in items if not is_number(v)), None)
    if bad is not None or len(items) != n:
        what = f"got {bad!r}" if bad is not None else f"got {len(items)} value(s)"
        raise InputError(f"{source}: '{key}' must be {'a number' if n == 1 else f'a list of {n} numbers'}, {what}")
    arr = np.asarray(items, dtype=float).reshape(-1)
    if not np.all(np.isfinite(arr)):
        raise InputError(f"{source}: '{key}' must be {n} finite numbers (no NaN or inf), got {value!r}")
    return arr


def pencil_from_dict(d, source="pencil"):
    """Build a Pencil from a parsed pencil file (docs/formats.md), validating every field.

    Accepts ``angles_deg: [...]`` or ``start_deg, step_deg, count``; optional ``vertex``,
    ``radius``, ``width``, ``shape`` (`SHAPES`), ``wedge_deg`` (wedges: their angular
    width, default half the smallest gap between spokes: a regular Siemens star's wedges and
    gaps are equal), ``polarity`` (`POLARITIES`; wedges default to dark) and ``circles``
    (radii of circles about the vertex). `source` names the file in error messages. At most
    `MAX_SPOKES` spokes, no two in the same direction; every number a finite number (a
    string such as "12" is refused, not converted).

    >>> pencil_from_dict({"start_deg": 0, "step_deg": 20, "count": 8}).count
    8
    >>> pencil_from_dict({"start_deg": 0, "step_deg": 0.3, "count": 1000}, "p.yaml")
    Traceback (most recent call last):
    ...
    pencilcal.toolkit.errors.InputError: p.yaml: 'count' is 1000 spokes, over the limit of 360
    """
    if not isinstance(d, dict):
        raise InputError(f"{source}: expected a mapping with 'angles_deg' or 'start_deg/step_deg/count'")
    known = {"angles_deg", "start_deg", "step_deg", "count", "vertex", "radius", "width", "name", "units", "shape",
             "wedge_deg", "polarity", "circles"}
    unknown = sorted(set(d) - known)
    if unknown:
        raise InputError(f"{source}: unknown key(s) {unknown}; expected {sorted(known)}")
    if "angles_deg" in d:
        if any(k in d for k in ("start_deg", "step_deg", "count")):
            raise InputError(f"{source}: give either 'angles_deg' or 'start_deg/step_deg/count', not both")
        raw = d["angles_deg"]
        if not isinstance(raw, (list, tuple)):
            raise InputError(f"{source}: 'angles_deg' must be a list of numbers")
        if len(raw) > MAX_SPOKES:
            raise InputError(f"{source}: 'angles_deg' gives {len(raw)} spokes, over the limit of {MAX_SPOKES}")
        angles = _floats(raw, len(raw), "angles_deg", source)
    elif all(k in d for k in ("start_deg", "step_deg", "count")):
        count = d["count"]
        if isinstance(count, bool) or not isinstance(count, int) or count < 1:
            raise InputError(f"{source}: 'count' must be a positive integer, got {count!r}")
        if count > MAX_SPOKES:
            raise InputError(f"{source}: 'count' is {count} spokes, over the limit of {MAX_SPOKES}")
        start = _floats([d["start_deg"]], 1, "start_deg", source)[0]
        step = _floats([d["step_deg"]], 1, "step_deg", source)[0]
        angles = start + step * np.arange(count)
    else:
        raise InputError(f"{source}: needs 'angles_deg' or all of 'start_deg', 'step_deg', 'count'")
    if angles.size < 3:
        raise InputError(f"{source}: a pencil needs at least three spokes, got {angles.size}")
    # two spokes in the same direction cannot be told apart in the image
    order = np.argsort(np.remainder(angles, 360.0), kind="stable")
    a = np.remainder(angles, 360.0)[order]
    gaps = np.diff(np.concatenate([a, a[:1] + 360.0]))
    if np.min(gaps) < 1e-6:
        k = int(np.argmin(gaps))
        i, j = sorted((int(order[k]), int(order[(k + 1) % a.size])))
        raise InputError(f"{source}: spokes {i} and {j} share the same direction "
                         f"({angles[i]:g} and {angles[j]:g} deg)")
    for key in ("name", "units"):
        if d.get(key) is not None and not isinstance(d[key], str):
            raise InputError(f"{source}: '{key}' must be a string, got {d[key]!r}")
    vertex = _floats(d["vertex"], 2, "vertex", source) if d.get("vertex") is not None else None
    radius = None
    if d.get("radius") is not None:
        radius = _floats(d["radius"], 2, "radius", source)
        if not (0.0 <= radius[0] < radius[1]):
            raise InputError(f"{source}: 'radius' must be [inner, outer] with 0 <= inner < outer, got {d['radius']!r}")
    width = None
    if d.get("width") is not None:
        width = _floats([d["width"]], 1, "width", source)[0]
        if width <= 0:
            raise InputError(f"{source}: 'width' must be positive, got {d['width']!r}")
    shape, wedge, polarity = _shape_fields(d, source, np.min(gaps), width, angles.size)
    circles = None
    if d.get("circles") is not None:
        raw = d["circles"]
        if not isinstance(raw, (list, tuple)) or not raw:
            raise InputError(f"{source}: 'circles' must be a list of radii")
        circles = _floats(raw, len(raw), "circles", source)
        if np.any(circles <= 0):
            raise InputError(f"{source}: 'circles' must be positive radii, got {raw!r}")
    return Pencil(np.radians(angles), vertex, radius, width, shape, wedge, polarity, circles)


def _shape_fields(d, source, min_gap_deg, width, count):
    """(shape, wedge [rad] or None, polarity or None) of a pencil file's mapping `d`, checked:
    a wedge narrower than the smallest gap between spokes, no width but for lines, an even
    count of alternating edges."""
    shape = d.get("shape", "line")
    if shape not in SHAPES:
        raise InputError(f"{source}: 'shape' must be one of {', '.join(SHAPES)}, got {shape!r}")
    polarity = d.get("polarity")
    if polarity is not None and polarity not in POLARITIES:
        raise InputError(f"{source}: 'polarity' must be one of {', '.join(POLARITIES)}, got {polarity!r}")
    if polarity is not None and shape == "line":
        raise InputError(f"{source}: 'polarity' is for wedges and edges (shape wedge or edge)")
    if width is not None and shape != "line":
        raise InputError(f"{source}: 'width' is the width of bars (shape line), not of {shape}s")
    if d.get("wedge_deg") is not None and shape != "wedge":
        raise InputError(f"{source}: 'wedge_deg' needs 'shape: wedge'")
    wedge = None
    if shape == "wedge":
        wedge_deg = 0.5 * min_gap_deg
        if d.get("wedge_deg") is not None:
            wedge_deg = _floats([d["wedge_deg"]], 1, "wedge_deg", source)[0]
            if not 0 < wedge_deg < min_gap_deg:
                raise InputError(f"{source}: 'wedge_deg' must be between 0 and the smallest gap between spokes "
                                 f"({min_gap_deg:g} deg), got {d['wedge_deg']!r}")
        wedge = float(np.radians(wedge_deg))
        polarity = polarity or "dark"
    if shape == "edge" and polarity is not None and count % 2:
        raise InputError(f"{source}: edges between alternating sectors come in an even number, got {count}")
    return shape, wedge, polarity


def read_pencil(path):
    """Read a pencil file (.yaml/.yml/.json). Raises InputError naming the file on any problem."""
    return pencil_from_dict(load_structured(path, "pencil file"), source=str(path))


def write_pencil(path, pencil, force=False):
    """Write a pencil file; YAML or JSON by extension."""
    import json
    import yaml

    p = Path(path)
    if p.suffix.lower() == ".json":
        text = json.dumps(pencil.to_dict(), indent=1) + "\n"
    else:
        text = yaml.safe_dump(pencil.to_dict(), default_flow_style=None, sort_keys=False)
    atomic_write(p, text, force)


def spoke_directions(R_cam_from_target, angles):
    """Camera-frame unit directions of the spokes.

    R_cam_from_target: (..., 3, 3); angles: (..., N) [rad]. Returns (..., N, 3).
    """
    R = np.asarray(R_cam_from_target, float)
    a = np.asarray(angles, float)
    c = np.stack([np.cos(a), np.sin(a)], -1)  # (..., N, 2)
    return np.einsum("...ij,...nj->...ni", R[..., :, :2], c)


def image_directions(R_cam_from_target, vertex, angles):
    """Oriented image directions w = d_xy - x_d d_z of the spokes (normalised coordinates).

    R_cam_from_target: (..., 3, 3); vertex: (..., 2) normalised image of the vertex;
    angles: (..., N) [rad]. Returns (..., N, 2), not normalised (a positive multiple of
    the true direction as long as the vertex is in front of the camera).
    """
    d = spoke_directions(R_cam_from_target, angles)
    x = np.asarray(vertex, float)[..., None, :]
    return d[..., :2] - x * d[..., 2:3]


def image_angles(R_cam_from_target, vertex, angles):
    """Exact image angles of the spokes, atan2(w_y, w_x), in normalised coordinates.

    Shapes as `image_directions`; returns (..., N) [rad], oriented (period 2*pi).
    """
    w = image_directions(R_cam_from_target, vertex, angles)
    return np.arctan2(w[..., 1], w[..., 0])


def spoke_points_cam(R_cam_from_target, t_cam_from_target, pencil, radii=None):
    """Camera-frame 3D points along every spoke.

    radii: (M,) distances from the vertex (default: the pencil's radius, or [0.1, 1] units
    if it has none). Returns (N, M, 3). The vertex defaults to the target origin.
    """
    if radii is None:
        radii = pencil.radius if pencil.radius is not None else np.array([0.1, 1.0])
    radii = np.asarray(radii, float)
    v = np.zeros(3) if pencil.vertex is None else np.array([pencil.vertex[0], pencil.vertex[1], 0.0])
    c = np.stack([np.cos(pencil.angles), np.sin(pencil.angles), np.zeros_like(pencil.angles)], -1)
    pts_target = v + c[:, None, :] * radii[None, :, None]
    return pts_target @ np.asarray(R_cam_from_target, float).T + np.asarray(t_cam_from_target, float)


def project_spokes(camera, R_cam_from_target, t_cam_from_target, pencil, radii=None):
    """Raw (distorted) pixel segments of the spokes, [x1, y1, x2, y2] from inner to outer end.

    camera: a pencilcal Camera. Returns (N, 4). Only the two end points are projected: with
    lens distortion the true image of a spoke is curved, but its end points are exact.
    """
    if radii is None:
        radii = pencil.radius if pencil.radius is not None else np.array([0.1, 1.0])
    pts = spoke_points_cam(R_cam_from_target, t_cam_from_target, pencil, np.asarray(radii, float)[[0, -1]])
    px = camera.project(pts)  # (N, 2, 2)
    return px.reshape(-1, 4)
