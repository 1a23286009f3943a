"""One frame's orientation of a pencil (`Orientation`) and the file that holds them,
``orientation.json``: its one reader and its one writer.

An `Orientation` is what `orient.orient_segments` returns for a frame; its `to_dict()` is
that frame's record in ``orientation.json`` (docs/formats.md), key for key:

- ``ok`` is false only when no estimate exists (``error`` says why); a tilt below the
  detection threshold is ``ok`` with ``detectable`` false;
- ``normal`` is ``R_cam_from_target[:, 2]`` (camera frame, pointing away from the camera);
  ``normal_twin`` and ``R_cam_from_target_twin`` are the other solution that reproduces
  the same image; ``ambiguous`` is false when the twin was resolved (``resolved_by``);
- ``vertex_px`` (raw pixels) is None where the lens model does not reach the vertex; the
  vertex is then given by ``ray`` alone.

Angles in the record are degrees; vectors and matrices are numpy arrays here and lists in
the file.

Example
-------
>>> o = Orientation(image="000.png", ok=False, error="fewer than three usable segments: 2 of 2")
>>> d = o.to_dict()
>>> d["ok"], d["tilt_deg"], list(d)[:3]
(False, None, ['image', 'ok', 'error'])
>>> Orientation.from_dict(d) == o
True
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from pencilcal.toolkit.errors import InputError
from pencilcal.toolkit.io.files import load_frames, write_json

__all__ = ["Orientation", "read_orientations", "write_orientations"]

# The record's keys, in the order the file gives them. The first group is every record's;
# a frame with no estimate has them all null (but image, ok, error, model).
_CORE = ("image", "ok", "error", "vertex_px", "vertex_cov_px2", "lines_used", "rms_residual_deg", "tilt_deg",
         "tilt_sigma_deg", "detectable", "normal", "normal_sigma_deg", "normal_twin", "R_cam_from_target",
         "R_cam_from_target_twin", "ambiguous", "model")
# an estimate's further keys, always written for it (null when unknown)
_ESTIMATE = ("resolved_by", "ray")
# written only when known
_OPTIONAL = ("tilt_threshold_deg", "labels_ambiguous", "normal_ambiguous", "normal_alternatives", "spokes",
             "spokes_used",
             "lines", "vertex_cam", "t_cam_from_target", "tilt_sigma_total_deg", "normal_sigma_total_deg",
             "vertex_cov_total_px2", "intrinsics_used", "tilt_sigma_shutter_deg", "normal_sigma_shutter_deg", "chi2", "circle_normal", "circle_normal_sigma_deg",
             "circle_tilt_deg", "circles_used", "circle_angle_deg", "circle_chi2", "circle_consistent", "bend_chi2",
             "bend_taken", "misfit_scale")
_ARRAYS = {"vertex_px": (2,), "vertex_cov_px2": (2, 2), "normal": (3,), "normal_twin": (3,),
           "R_cam_from_target": (3, 3), "R_cam_from_target_twin": (3, 3), "ray": (3,), "vertex_cam": (3,),
           "t_cam_from_target": (3,), "vertex_cov_total_px2": (2, 2), "circle_normal": (3,)}


@dataclass(frozen=True, eq=False)
class Orientation:
    """The orientation of a pencil in one frame (a record of orientation.json).

    Angles in degrees; vertex_px (2,) and vertex_cov_px2 (2, 2) in raw pixels; normal,
    normal_twin, ray (3,) unit vectors in the camera frame; R_cam_from_target(_twin)
    (3, 3); spokes (M,) the spoke of every input segment (-1: not used); spokes_used: the
    spokes with a line in the fit (a wedge's two edges are one spoke); lines (only with
    ``keep_lines``): the used lines in normalised coordinates, for experiments;
    vertex_cam, t_cam_from_target (3,) in the pencil file's length unit, when the spoke
    radii fix the depth; tilt_sigma_total_deg, normal_sigma_total_deg [deg] and
    vertex_cov_total_px2 (2, 2) [px^2]: the sigmas with the intrinsics' uncertainty too
    (`lens_uncertainty`), only when the intrinsics' covariance was known (intrinsics_used);
    tilt_sigma_shutter_deg, normal_sigma_shutter_deg [deg]: the part of the sigmas (added in
    quadrature) for a rolling shutter of unknown readout, on tracked video (`shutter`);
    chi2: the fit's sum of squared weighted angle residuals (lines_used - 3 degrees of
    freedom; `sequence_noise` pools it); circle_*: the plane's normal from the images of
    circles about the vertex (`circle`), its sigma [deg] and tilt [deg], how many circles,
    its angle [deg] from ``normal`` and their difference's chi2 (2 dof), and whether that is
    within the 99 % quantile (circle_consistent); bend_chi2, bend_taken, misfit_scale
    (printed radial targets): the chi2 (3 dof) of the sheet's bend the lines show, whether
    its term is in the covariance, and the factor (at least 1) by which the misfit it leaves
    widens the lines' error variances (`bend`).
    """

    image: str | None = None
    ok: bool = False
    error: str | None = None
    vertex_px: np.ndarray | None = None
    vertex_cov_px2: np.ndarray | None = None
    lines_used: int | None = None
    rms_residual_deg: float | None = None
    tilt_deg: float | None = None
    tilt_sigma_deg: float | None = None
    detectable: bool | None = None
    normal: np.ndarray | None = None
    normal_sigma_deg: float | None = None
    normal_twin: np.ndarray | None = None
    R_cam_from_target: np.ndarray | None = None
    R_cam_from_target_twin: np.ndarray | None = None
    ambiguous: bool | None = None
    model: str = "exact"
    resolved_by: str | None = None
    ray: np.ndarray | None = None
    tilt_threshold_deg: float | None = None
    labels_ambiguous: bool | None = None
    normal_ambiguous: bool | None = None
    normal_alternatives: list | None = None
    spokes: np.ndarray | None = None
    spokes_used: int | None = None
    lines: dict | None = None
    vertex_cam: np.ndarray | None = None
    t_cam_from_target: np.ndarray | None = None
    tilt_sigma_total_deg: float | None = None
    normal_sigma_total_deg: float | None = None
    vertex_cov_total_px2: np.ndarray | None = None
    intrinsics_used: bool | None = None
    tilt_sigma_shutter_deg: float | None = None
    normal_sigma_shutter_deg: float | None = None
    chi2: float | None = None
    circle_normal: np.ndarray | None = None
    circle_normal_sigma_deg: float | None = None
    circle_tilt_deg: float | None = None
    circles_used: int | None = None
    circle_angle_deg: float | None = None
    circle_chi2: float | None = None
    circle_consistent: bool | None = None
    bend_chi2: float | None = None
    bend_taken: bool | None = None
    misfit_scale: float | None = None

    def replace(self, **changes) -> "Orientation":
        """A copy with `changes` (dataclasses.replace)."""
        return dataclasses.replace(self, **changes)

    def swapped(self) -> "Orientation":
        """The same estimate with the twin chosen instead."""
        return self.replace(R_cam_from_target=self.R_cam_from_target_twin,
                            R_cam_from_target_twin=self.R_cam_from_target,
                            normal=self.normal_twin, normal_twin=self.normal)

    def to_dict(self) -> dict:
        """The orientation.json record (numpy arrays kept; the writer makes them lists)."""
        keys = _CORE + (_ESTIMATE if self.ok else ())
        out = {k: getattr(self, k) for k in keys}
        for k in _OPTIONAL:
            v = getattr(self, k)
            if v is not None and not (k == "normal_alternatives" and len(v) == 0):
                out[k] = v
        return out

    @classmethod
    def from_dict(cls, d: dict, where: str = "orientation record") -> "Orientation":
        """An Orientation from a record (as read from orientation.json); InputError naming
        `where` and the key for a record that is not one."""
        if not isinstance(d, dict):
            raise InputError(f"{where}: must be an object")
        known = {f.name for f in dataclasses.fields(cls)}
        kw = {}
        for k, v in d.items():
            if k not in known:
                continue  # a later version's key: kept by nobody, harmful to nobody
            if v is not None and k in _ARRAYS:
                try:
                    v = np.asarray(v, float)
                except (TypeError, ValueError):
                    raise InputError(f"{where}: '{k}' must be numbers") from None
                if v.shape != _ARRAYS[k]:
                    raise InputError(f"{where}: '{k}' must have shape {_ARRAYS[k]}, got {v.shape}")
            elif v is not None and k == "spokes":
                v = np.asarray(v, int)
            kw[k] = v
        if not isinstance(kw.get("ok", False), bool):
            raise InputError(f"{where}: 'ok' must be true or false")
        return cls(**kw)

    def __eq__(self, other):
        if not isinstance(other, Orientation):
            return NotImplemented
        for f in dataclasses.fields(self):
            a, b = getattr(self, f.name), getattr(other, f.name)
            if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
                if a is None or b is None or not np.array_equal(np.asarray(a), np.asarray(b)):
                    return False
            elif a != b:
                return False
        return True


def write_orientations(path, orientations, force=False, **header):
    """Write orientation.json: ``header`` keys first (model, camera, pencil, lines,
    images, ...), then ``frames``, one record per Orientation, atomically."""
    write_json(path, {**header, "frames": [o.to_dict() for o in orientations]}, force=force)


def read_orientations(path):
    """The frames of an orientation.json as Orientations; (header dict, [Orientation])."""
    data, frames = load_frames(path, "orientation file", required=("ok",))
    header = {k: v for k, v in data.items() if k != "frames"}
    return header, [Orientation.from_dict(f, where) for f, where in frames]
