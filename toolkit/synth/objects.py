"""What stands around and over the printed sheet: a table scene and an instrument shaft.

- `Backdrop`: a textured table (the plane z = 0 of the target frame, around the sheet) with
  boxes standing on it and a wall beyond, for structure from motion; lit from `TO_LIGHT`
  (`face_shade`).
- `Instrument`: a cylindrical instrument shaft with a rounded tip, pivoting about a
  fulcrum; its exact silhouette (`Instrument.outline`, `Instrument.silhouette_planes`) and
  metallic shading (`Instrument.shade`).

render.py draws both. Conventions: target frame = board frame (x right, y down the sheet, z
into the sheet), OpenCV camera frame, transforms ``a_from_b``; lengths in mm.

Example
-------
>>> ins = Instrument.in_plane([182.0, 62.5], height=4.5, angle_deg=0.0)
>>> m = ins.silhouette_planes(np.eye(3), np.array([-182.0, -62.5, 300.0]))
>>> m.shape, bool(np.allclose(np.linalg.norm(m, axis=1), 1.0))
((2, 3), True)
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pencilcal.toolkit.errors import InputError
from pencilcal.toolkit.synth.polygons import convex_hull
from pencilcal.toolkit.synth.texture import texture_pyramid

__all__ = ["Backdrop", "Instrument", "TO_LIGHT", "face_shade"]


@dataclass(frozen=True, eq=False)
class Backdrop:
    """A textured table (the plane z = 0 of the target frame), boxes on it, a wall beyond.

    Parameters
    ----------
    table : (4,) float
        Table extent (x0, y0, x1, y1) in the target frame [mm]; the sheet lies on it.
    boxes : tuple of (5,) float
        Boxes standing on the table, each (x0, y0, x1, y1, height) [mm]; a box occupies
        ``z`` from ``-height`` to 0 (towards a camera that sees the printed face).
    seed : int
        Seed of the procedural texture (the same seed, the same scene).
    texel : float
        Texture resolution [mm per texel].

    Notes
    -----
    All geometry is consistent 3D in the target frame, so the scene suits structure from
    motion: the texture is fixed to the surfaces, and the boxes give depth off the plane.

    Example
    -------
    >>> from pencilcal.toolkit.synth.sheet import layout_sheet
    >>> bd = Backdrop.around(layout_sheet(), seed=3)
    >>> len(bd.boxes) > 0, bd.table[2] - bd.table[0]
    (True, 1000.0)
    """

    table: tuple = (-400.0, -300.0, 600.0, 500.0)
    boxes: tuple = ()
    seed: int = 0
    texel: float = 0.5

    @classmethod
    def around(cls, sheet, seed=0, size=(1000.0, 800.0), boxes=6, clearance=60.0):
        """A table of `size` [mm] centred on the sheet's paper, with `boxes` random boxes
        at least `clearance` [mm] from the paper (so they never hide it from the views
        scenarios.py makes). `sheet`: a `Sheet`; `seed`: int; `size`: (2,) [mm]."""
        rng = np.random.default_rng([int(seed), 104729])
        px0, py0 = sheet.paper_origin
        pw, ph = sheet.paper_size
        cx, cy = px0 + pw / 2.0, py0 + ph / 2.0
        table = (cx - size[0] / 2.0, cy - size[1] / 2.0, cx + size[0] / 2.0, cy + size[1] / 2.0)
        placed = []
        for _ in range(400):
            if len(placed) >= boxes:
                break
            w, d = rng.uniform(40.0, 110.0, 2)
            h = rng.uniform(20.0, 55.0)
            x = rng.uniform(table[0] + 20, table[2] - 20 - w)
            y = rng.uniform(table[1] + 20, table[3] - 20 - d)
            cand = (x, y, x + w, y + d, h)
            c = clearance + h * 0.3
            if x + w > px0 - c and x < px0 + pw + c and y + d > py0 - c and y < py0 + ph + c:
                continue
            if any(x < b[2] + 15 and x + w > b[0] - 15 and y < b[3] + 15 and y + d > b[1] - 15 for b in placed):
                continue
            placed.append(tuple(round(float(v), 3) for v in cand))
        return cls(tuple(float(v) for v in table), tuple(placed), int(seed))

    @property
    def texture(self):
        """The table's texture: `texture.texture_pyramid` of `seed`, one texel per `texel` mm."""
        x0, y0, x1, y1 = self.table
        shape = (int(np.ceil((y1 - y0) / self.texel)), int(np.ceil((x1 - x0) / self.texel)))
        return texture_pyramid(self.seed, shape)

    def to_dict(self):
        """The backdrop for truth files: table (4,), boxes (K, 5) [mm], seed, texel [mm]."""
        return {"table": list(self.table), "boxes": [list(b) for b in self.boxes], "seed": self.seed,
                "texel": self.texel}


#: Unit direction towards the light of the table scene (target frame; -z points up from the table).
TO_LIGHT = np.array([0.35, -0.45, -1.0]) / np.linalg.norm([0.35, -0.45, -1.0])
TO_LIGHT.setflags(write=False)


def face_shade(normal_t):
    """Lambert shade (float, ambient 0.45, 1 facing the light) of a surface with unit outward
    normal `normal_t` (3,) in the target frame, lit from `TO_LIGHT`."""
    return 0.45 + 0.55 * max(0.0, float(np.dot(normal_t, TO_LIGHT)))


@dataclass(frozen=True, eq=False)
class Instrument:
    """A cylindrical instrument shaft (a capsule: a cylinder with a rounded tip).

    Parameters
    ----------
    fulcrum : (3,) float
        A point of the shaft's axis, the pivot point [target frame, mm].
    direction : (3,) float
        Axis direction from the fulcrum towards the tip (normalised here) [target frame].
    radius : float
        Shaft radius [mm].
    tip : float
        Distance from the fulcrum to the centre of the rounded tip [mm].
    back : float
        Length of shaft behind the fulcrum (towards the handle) [mm].
    albedo : float
        Diffuse reflectance; a specular stripe is added on top.

    Example
    -------
    >>> ins = Instrument.in_plane([182.0, 62.5], height=4.5, angle_deg=90.0)
    >>> ins.fulcrum.tolist(), np.round(ins.direction, 12).tolist()
    ([182.0, 62.5, -4.5], [0.0, 1.0, 0.0])
    """

    fulcrum: np.ndarray
    direction: np.ndarray
    radius: float = 2.5
    tip: float = 60.0
    back: float = 300.0
    albedo: float = 0.35

    def __post_init__(self):
        f = np.asarray(self.fulcrum, float).reshape(3)
        d = np.asarray(self.direction, float).reshape(3)
        if not np.all(np.isfinite(f)) or not np.all(np.isfinite(d)) or np.linalg.norm(d) == 0:
            raise InputError("instrument fulcrum and direction must be finite, direction non-zero")
        if not (self.radius > 0 and self.tip > -self.back):
            raise InputError("instrument radius must be positive and tip > -back")
        object.__setattr__(self, "fulcrum", f)
        object.__setattr__(self, "direction", d / np.linalg.norm(d))

    @classmethod
    def in_plane(cls, fulcrum_xy, height, angle_deg, **kw):
        """A shaft pivoting in the plane z = -height (parallel to the sheet, towards the
        camera), at angle `angle_deg` from the target x axis (towards +y), through the
        fulcrum (fulcrum_xy, -height)."""
        a = np.radians(float(angle_deg))
        return cls(np.array([fulcrum_xy[0], fulcrum_xy[1], -float(height)]),
                   np.array([np.cos(a), np.sin(a), 0.0]), **kw)

    def axis_cam(self, R, t):
        """(fulcrum (3,) [mm], unit direction (3,)) of the axis in the camera frame, for the
        pose R (3, 3), t (3,) [mm] of the target."""
        return np.asarray(R, float) @ self.fulcrum + t, np.asarray(R, float) @ self.direction

    def silhouette_planes(self, R, t):
        """(2, 3) unit normals m of the two planes through the camera centre tangent to the
        (infinite) shaft, oriented so that m . X >= 0 on the shaft. In normalised image
        coordinates the silhouette edges are the lines m . (x, y, 1) = 0. R (3, 3), t (3,)
        [mm]: pose of the target."""
        F, a = self.axis_cam(R, t)
        Fp = F - np.dot(F, a) * a
        D = np.linalg.norm(Fp)
        if D <= self.radius:
            raise InputError("the camera is inside the instrument shaft")
        e1 = Fp / D
        e2 = np.cross(a, e1)
        c = self.radius / D
        s = np.sqrt(1.0 - c * c)
        return np.array([c * e1 + s * e2, c * e1 - s * e2])

    def outline(self, R, t):
        """Camera-frame polygon (N, 3) on z = 1 whose projection is the shaft's outline,
        or None if it is behind the camera. Convex hull of the images of the two end
        spheres' silhouette circles, with the exact tangent points added, so the hull's
        long edges are exactly the silhouette lines. R (3, 3), t (3,) [mm]: pose of the
        target; raises InputError if the camera is inside the instrument."""
        F, a = self.axis_cam(R, t)
        r = self.radius
        ends = [F + self.tip * a, F - self.back * a]
        near = 2.0 * r + 1.0
        za, zb = ends[0][2], ends[1][2]
        if za < near and zb < near:
            return None
        if za < near or zb < near:  # keep the part of the axis in front of the camera
            s = (near - za) / (zb - za)
            cut = ends[0] + s * (ends[1] - ends[0])
            ends = [cut, ends[1]] if za < near else [ends[0], cut]
        m = self.silhouette_planes(R, t)
        pts = []
        phi = np.linspace(0.0, 2 * np.pi, 256, endpoint=False)
        for E in ends:
            D2 = float(E @ E)
            if D2 <= r * r:
                raise InputError("the camera is inside the instrument")
            c0 = E * (1.0 - r * r / D2)
            rho = r * np.sqrt(D2 - r * r) / np.sqrt(D2)
            u = np.cross(E, [1.0, 0.0, 0.0] if abs(E[0]) < 0.9 * np.sqrt(D2) else [0.0, 1.0, 0.0])
            u /= np.linalg.norm(u)
            v = np.cross(E / np.sqrt(D2), u)
            circ = c0 + rho * (np.cos(phi)[:, None] * u + np.sin(phi)[:, None] * v)
            pts.append(circ)
            pts.append(E - r * m)  # the exact tangent points of the silhouette planes
        P = np.concatenate(pts)
        if np.any(P[:, 2] <= 0):
            return None
        hull = convex_hull(P[:, :2] / P[:, 2:3])
        return np.concatenate([hull, np.ones((len(hull), 1))], 1)

    def shade(self, R, t, rays):
        """Luminance (linear, 0..~1.2) of the shaft seen along camera-frame rays (..., 3).

        Metallic grey: a little diffuse light and a sharp specular stripe from a light
        beside the camera (an endoscope's). Rays that miss get the grazing shade."""
        F, a = self.axis_cam(R, t)
        r = self.radius
        d = rays
        da = d @ a
        w = d - da[..., None] * a
        Fp = F - np.dot(F, a) * a
        ww = np.sum(w * w, -1)
        wf = w @ Fp
        with np.errstate(invalid="ignore", divide="ignore"):
            disc = wf * wf - ww * (np.dot(Fp, Fp) - r * r)
            s = (wf - np.sqrt(np.maximum(disc, 0.0))) / ww
            s_close = wf / ww
        s = np.where(disc > 0, s, s_close)
        P = s[..., None] * d
        h = (P - F) @ a
        h_c = np.clip(h, -self.back, self.tip)
        # beyond the tip: the rounded end (sphere)
        tipc = F + self.tip * a
        dt = d @ tipc
        with np.errstate(invalid="ignore"):
            disc_t = dt * dt - (np.dot(tipc, tipc) - r * r)
            s_t = dt - np.sqrt(np.maximum(disc_t, 0.0))
        on_tip = h > self.tip
        P = np.where(on_tip[..., None], np.where((disc_t > 0)[..., None], s_t[..., None] * d,
                                                 dt[..., None] * d), P)
        centre = F + h_c[..., None] * a
        n = P - np.where(on_tip[..., None], tipc, centre)
        nn = np.linalg.norm(n, axis=-1, keepdims=True)
        with np.errstate(invalid="ignore", divide="ignore"):
            n = n / nn
        v = -d
        light = -d + np.array([-0.25, -0.35, 0.0])
        light /= np.linalg.norm(light, axis=-1, keepdims=True)
        ndl = np.clip(np.sum(n * light, -1), 0.0, 1.0)
        refl = 2.0 * ndl[..., None] * n - light
        spec = np.clip(np.sum(refl * v, -1), 0.0, 1.0) ** 60
        ndv = np.clip(np.sum(n * v, -1), 0.0, 1.0)
        lum = self.albedo * (0.12 + 0.55 * ndl) + 0.9 * spec + 0.05 * ndv
        return np.nan_to_num(lum, nan=self.albedo * 0.12)

    def to_dict(self):
        """The shaft for truth files: fulcrum (3,), direction (3,), radius, tip, back [mm]."""
        return {"fulcrum": self.fulcrum.tolist(), "direction": self.direction.tolist(), "radius": self.radius,
                "tip": self.tip, "back": self.back}
