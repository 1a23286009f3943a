"""mrcal's splined stereographic lens model: a stereographic core and a B-spline correction.

The model is mrcal's ``LENSMODEL_SPLINED_STEREOGRAPHIC_order=3_Nx=.._Ny=.._fov_x_deg=..``,
written the same in pencilcal as the `Camera` model ``"splined_stereographic_order=3_Nx=.._
Ny=.._fov_x_deg=.."`` (`splined_name`). A camera-frame point ``p`` projects as:

1. the normalised stereographic projection ``u = 2 p_xy / (|p| + p_z)``, i.e. ``u = 2
   tan(theta / 2)`` along ``p_xy``, theta the angle off the optical axis (defined for every
   direction but straight back, beyond 90 degrees too);
2. a correction ``du(u)``: two cubic B-spline surfaces (x and y) over a regular grid of
   ``Nx`` x ``Ny`` control points in u;
3. ``pixel = (fx (u_x + du_x) + cx, fy (u_y + du_y) + cy)``: the `Camera`'s K applied to
   ``u + du`` (``Camera.distort_normalized`` returns ``u + du``).

The grid: ``Nx`` knots span ``u_x`` from ``-2 tan(fov_x / 4)`` to ``+2 tan(fov_x / 4)``
(fov_x = ``fov_x_deg``, the field of view the spline covers across x), so knot ``ix`` sits at
``(ix - (Nx - 1) / 2) / k`` with ``k = (Nx - 1) / (4 tan(fov_x / 4))`` knots per unit of u;
the same spacing holds along y, ``Ny`` knots centred on the axis. A point's correction uses
the 4 x 4 control points around it (uniform cubic B-spline, the point in the patch between
the middle two); beyond the outer knots the nearest patch is extended, so the projection
stays continuous. The parameters after fx, fy, cx, cy are the control points in mrcal's
order: row by row (y), along each row (x), the pair (du_x, du_y) at each:
``intrinsics[4 + 2 (iy Nx + ix) + {0, 1}]``.

The correction's affine part (a scale and shift of u) duplicates fx, fy, cx, cy, and a
rotation of u about the axis duplicates the board poses: a calibration pins them by a
small penalty on the control points (`REGULARIZATION`, as mrcal does), so the core takes
the affine part and the spline only what the core cannot describe.

Example
-------
>>> import numpy as np
>>> name = splined_name(8, 6, 90)
>>> cfg = splined_config(name)
>>> (cfg.Nx, cfg.Ny, cfg.fov_x_deg, cfg.parameters)
(8, 6, 90, 96)
>>> ctrl = np.zeros(cfg.parameters)
>>> u, _ = stereographic(np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0]]))
>>> u.round(6).tolist()          # the axis and 90 degrees off it (2 tan 45 deg = 2)
[[0.0, 0.0], [2.0, 0.0]]
>>> correction(cfg, ctrl, u)[0].tolist()
[[0.0, 0.0], [0.0, 0.0]]
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass

import numpy as np

from pencilcal.toolkit.errors import InputError

__all__ = ["PREFIX", "MRCAL_PREFIX", "SplineConfig", "splined_name", "splined_config", "is_splined", "stereographic",
           "stereographic_jacobian", "rays_from_stereographic", "normalized_from_stereographic", "correction",
           "knot_positions", "control_names", "REGULARIZATION", "fit_correction", "config_covering"]

#: pencilcal's name of the model family, and mrcal's.
PREFIX = "splined_stereographic"
MRCAL_PREFIX = "LENSMODEL_SPLINED_STEREOGRAPHIC"
#: The penalty on each control point in a calibration: the residual ``REGULARIZATION *
#: f * du`` [px] per control point and axis (f the geometric mean focal length), so a
#: correction of 1 px at a knot costs (0.1 px)^2, against corner residuals of 0.1-1 px
#: each: enough to pin the directions no corner sees (the affine part, knots outside the
#: views), far too little to bend the fit where corners are.
REGULARIZATION = 0.1
_NAME = re.compile(r"^(?:splined_stereographic|LENSMODEL_SPLINED_STEREOGRAPHIC)_order=(\d+)_Nx=(\d+)_Ny=(\d+)"
                   r"_fov_x_deg=(\d+)$")
# grids outside these are not lenses: at least one full cubic patch, at most mrcal's
# densest recommended grid several times over
_MIN_KNOTS, _MAX_KNOTS = 4, 200


@dataclass(frozen=True)
class SplineConfig:
    """The model's fixed configuration: spline order (3), the knots along x and y, the
    field of view [deg] the knots span across x."""

    order: int
    Nx: int
    Ny: int
    fov_x_deg: int

    @property
    def parameters(self):
        """Control-point parameters: 2 Nx Ny (the intrinsics are fx, fy, cx, cy and these)."""
        return 2 * self.Nx * self.Ny

    @property
    def knots_per_u(self):
        """Knot intervals per unit of stereographic u (both axes)."""
        return (self.Nx - 1) / (4.0 * math.tan(math.radians(self.fov_x_deg) / 4.0))

    @property
    def name(self):
        return splined_name(self.Nx, self.Ny, self.fov_x_deg, self.order)


def splined_name(Nx, Ny, fov_x_deg, order=3, mrcal=False):
    """The model name of a grid: ``splined_stereographic_order=3_Nx=.._Ny=.._fov_x_deg=..``
    (mrcal's ``LENSMODEL_SPLINED_STEREOGRAPHIC_...`` with ``mrcal=True``)."""
    prefix = MRCAL_PREFIX if mrcal else PREFIX
    return f"{prefix}_order={int(order)}_Nx={int(Nx)}_Ny={int(Ny)}_fov_x_deg={int(fov_x_deg)}"


def is_splined(model):
    """True when `model` names the splined family (configured or not)."""
    return isinstance(model, str) and (model.startswith(PREFIX) or model.startswith(MRCAL_PREFIX))


def splined_config(model):
    """The `SplineConfig` of a splined model name (pencilcal's or mrcal's); InputError
    naming what is wrong with one that does not parse or is out of range."""
    m = _NAME.match(model) if isinstance(model, str) else None
    if m is None:
        raise InputError(f"splined model {model!r} must read {PREFIX}_order=3_Nx=<int>_Ny=<int>_fov_x_deg=<int>")
    order, Nx, Ny, fov = (int(v) for v in m.groups())
    if order != 3:
        raise InputError(f"splined model {model!r}: only cubic splines (order=3) are supported, got order={order}")
    for name, n in (("Nx", Nx), ("Ny", Ny)):
        if not _MIN_KNOTS <= n <= _MAX_KNOTS:
            raise InputError(f"splined model {model!r}: {name} must be {_MIN_KNOTS}..{_MAX_KNOTS}, got {n}")
    if not 0 < fov < 360:
        raise InputError(f"splined model {model!r}: fov_x_deg must be 1..359, got {fov}")
    return SplineConfig(order, Nx, Ny, fov)


def stereographic(p):
    """Normalised stereographic coordinates u (..., 2) of camera-frame points p (..., 3), and
    du/dp (..., 2, 3). NaN for the direction straight back (|p| + p_z = 0)."""
    p = np.asarray(p, float)
    n = np.linalg.norm(p, axis=-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        d = n + p[..., 2]
        d = np.where(d > 1e-300 * np.maximum(n, 1e-300), d, np.nan)
        u = 2.0 * p[..., :2] / d[..., None]
        # u = 2 p_xy / d with d = |p| + z: du/dp = 2/d [I | 0] - 2 p_xy/d^2 (p/|p| + e_z)^T
        dd = p / n[..., None]
        dd[..., 2] += 1.0
        J = -(u / d[..., None])[..., :, None] * dd[..., None, :]
        J[..., 0, 0] += 2.0 / d
        J[..., 1, 1] += 2.0 / d
    return u, J


def stereographic_jacobian(xy):
    """du/dxy (..., 2, 2) of u at normalised points xy (..., 2) (the point (x, y, 1))."""
    xy = np.asarray(xy, float)
    p = np.concatenate([xy, np.ones_like(xy[..., :1])], -1)
    return stereographic(p)[1][..., :, :2]


def rays_from_stereographic(u):
    """Unit rays (..., 3) of stereographic coordinates u (..., 2): ``(u, 1 - |u|^2/4) / (1 +
    |u|^2/4)``; beyond 90 degrees where |u| > 2."""
    u = np.asarray(u, float)
    t2 = 0.25 * np.sum(u * u, -1)
    return np.concatenate([u, (1.0 - t2)[..., None]], -1) / (1.0 + t2)[..., None]


def normalized_from_stereographic(u):
    """Normalised coordinates (..., 2) of u: ``u / (1 - |u|^2/4)``; NaN from 90 degrees off
    the axis on (|u| >= 2), where no point on z = 1 exists."""
    u = np.asarray(u, float)
    den = 1.0 - 0.25 * np.sum(u * u, -1)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where((den > 0)[..., None], u / np.where(den > 0, den, 1.0)[..., None], np.nan)


def knot_positions(cfg):
    """(Ny, Nx, 2) the u of every control point."""
    k = cfg.knots_per_u
    x = (np.arange(cfg.Nx) - 0.5 * (cfg.Nx - 1)) / k
    y = (np.arange(cfg.Ny) - 0.5 * (cfg.Ny - 1)) / k
    return np.stack(np.meshgrid(x, y), -1)


def control_names(cfg):
    """Names of the 2 Nx Ny control-point parameters, in mrcal's order: ``du_x[iy,ix]``,
    ``du_y[iy,ix]``, ..."""
    return [f"du_{a}[{iy},{ix}]" for iy in range(cfg.Ny) for ix in range(cfg.Nx) for a in "xy"]


def _basis(t):
    """Uniform cubic B-spline weights (..., 4) of the 4 control points around a point at t in
    [0, 1) between the middle two, and their derivatives."""
    t2, t3 = t * t, t * t * t
    w = np.stack([(1 - t) ** 3, 3 * t3 - 6 * t2 + 4, -3 * t3 + 3 * t2 + 3 * t + 1, t3], -1) / 6.0
    dw = np.stack([-3 * (1 - t) ** 2, 9 * t2 - 12 * t, -9 * t2 + 6 * t + 3, 3 * t2], -1) / 6.0
    return w, dw


def _patch(cfg, u):
    """Each point's patch: first control index along x and y (...,) and the weights (..., 4)
    along each with their derivatives in u."""
    k = cfg.knots_per_u
    out = []
    for axis, n in ((0, cfg.Nx), (1, cfg.Ny)):
        s = u[..., axis] * k + 0.5 * (n - 1)
        s = np.where(np.isfinite(s), s, 0.0)
        # the patch between knots i and i + 1 uses i - 1 .. i + 2; clamped at the edges, so
        # outside the grid the edge patch is extended
        i = np.clip(np.floor(s).astype(int), 1, n - 3)
        w, dw = _basis(s - i)
        out.append((i - 1, w, dw * k))
    return out


def correction(cfg, ctrl, u, jac=False):
    """The spline's correction du (..., 2) at u (..., 2), with `jac`: also d du / du (..., 2,
    2), and the control points each point uses, as flat parameter indices (..., 16, 2) into
    `ctrl` and their weights (..., 16) (d du_a / d ctrl[idx[..., a]] = weight).

    ctrl : (2 Nx Ny,) the control points in mrcal's order.
    """
    u = np.asarray(u, float)
    C = np.asarray(ctrl, float).reshape(cfg.Ny, cfg.Nx, 2)
    (ix, wx, dwx), (iy, wy, dwy) = _patch(cfg, u)
    offs = np.arange(4)
    gx = ix[..., None] + offs                                  # (..., 4) columns
    gy = iy[..., None] + offs                                  # (..., 4) rows
    P = C[gy[..., :, None], gx[..., None, :]]                  # (..., 4 rows, 4 cols, 2)
    du = np.einsum("...r,...c,...rcd->...d", wy, wx, P)
    bad = ~np.all(np.isfinite(u), -1)
    du = np.where(bad[..., None], np.nan, du)
    if not jac:
        return du, None, None, None
    J = np.empty(u.shape[:-1] + (2, 2))
    J[..., :, 0] = np.einsum("...r,...c,...rcd->...d", wy, dwx, P)
    J[..., :, 1] = np.einsum("...r,...c,...rcd->...d", dwy, wx, P)
    flat = 2 * (gy[..., :, None] * cfg.Nx + gx[..., None, :]).reshape(u.shape[:-1] + (16,))
    idx = np.stack([flat, flat + 1], -1)
    weights = (wy[..., :, None] * wx[..., None, :]).reshape(u.shape[:-1] + (16,))
    return du, J, idx, weights


def config_covering(camera, Nx=None, spacing_px=None, margin=1.05):
    """The `SplineConfig` whose knots cover `camera`'s whole image: fov_x_deg from the
    stereographic extent of the image's border under `camera` (any lens model) with a
    margin, Ny to match the image's extent along y.

    Nx : knots across x; or ``spacing_px``: the knot spacing in pixels at the centre
    (Nx from it). Default: one knot interval per 1/6 of the image width (Nx = 9 with the
    margin's extra knots), a patch of about 15 corners on a calibration board that fills a
    third of the image.
    """
    w, h = camera.size
    border = np.concatenate([np.c_[np.linspace(-0.5, w - 0.5, 65), np.full(65, -0.5)],
                             np.c_[np.linspace(-0.5, w - 0.5, 65), np.full(65, h - 0.5)],
                             np.c_[np.full(65, -0.5), np.linspace(-0.5, h - 0.5, 65)],
                             np.c_[np.full(65, w - 0.5), np.linspace(-0.5, h - 0.5, 65)]])
    u, _ = stereographic(camera.rays_from_pixels(border))
    u = u[np.all(np.isfinite(u), -1)]
    if u.size == 0:
        raise InputError("the camera's image border does not unproject: no spline grid can be placed")
    ux = margin * float(np.abs(u[:, 0]).max())
    uy = margin * float(np.abs(u[:, 1]).max())
    fov = int(math.ceil(math.degrees(4.0 * math.atan(ux / 2.0))))
    fov = min(max(fov, 1), 359)
    if Nx is None:
        f = camera.f_mean
        spacing = (w / 6.0) if spacing_px is None else float(spacing_px)
        width_u = 4.0 * math.tan(math.radians(fov) / 4.0)
        Nx = max(_MIN_KNOTS, int(math.ceil(width_u * f / spacing)) + 1)
    k = (Nx - 1) / (4.0 * math.tan(math.radians(fov) / 4.0))
    Ny = max(_MIN_KNOTS, int(math.ceil(2.0 * uy * k)) + 1)
    return splined_config(splined_name(Nx, Ny, fov))


def fit_correction(cfg, camera, samples=60):
    """Control points (2 Nx Ny,) that make the splined model with `camera`'s fx, fy, cx, cy
    project as `camera` (any lens model) over its image: linear least squares on a
    `samples` x `samples` grid of pixels, with the calibration's regularization. A start
    for a splined calibration from a lean one.
    """
    w, h = camera.size
    px = np.stack(np.meshgrid(np.linspace(0, w - 1, samples), np.linspace(0, h - 1, samples)), -1).reshape(-1, 2)
    u, _ = stereographic(camera.rays_from_pixels(px))
    ok = np.all(np.isfinite(u), -1)
    px, u = px[ok], u[ok]
    target = np.c_[(px[:, 0] - camera.cx) / camera.fx, (px[:, 1] - camera.cy) / camera.fy] - u
    _, _, idx, wts = correction(cfg, np.zeros(cfg.parameters), u, jac=True)
    P = cfg.parameters
    A = np.zeros((2 * len(u), P))
    rows = np.arange(len(u))
    for a in range(2):
        np.add.at(A, (2 * rows[:, None] + a, idx[..., a]), wts)
    f = camera.f_mean
    # the data's rows in pixels, the penalty's as in a calibration
    A *= f
    b = target.reshape(-1) * f
    reg = REGULARIZATION * f
    lhs = A.T @ A + reg * reg * np.eye(P)
    return np.linalg.solve(lhs, A.T @ b)
