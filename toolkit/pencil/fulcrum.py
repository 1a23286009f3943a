"""The fulcrum of a pivoting instrument, and its pivot plane, over a sequence.

An instrument pivoting about its entry port (the fulcrum) images, in every frame, as a line
through the fulcrum's image. Over the sequence those lines form a pencil:

1. its vertex is the fulcrum's image: the robust weighted intersection of all the lines
   (vertex.intersect_lines), rejecting lines that miss it (other edges, bad detections);
   lines stabilised from a moving camera (``parallax_scale_px``) take the parallax their
   frame's homography leaves, one factor fitted for the sequence (`parallax`);
2. with the pivot angle of every frame known (``angles``), the lines are a pencil with
   labelled spokes, and the exact estimator gives the orientation of the pivot plane (the
   plane the shaft sweeps) with its twin, exactly as for a printed fan.

Per frame the instrument line is the shaft midline when the lines file has shafts
(``pencilcal lines --shaft``) in any frame, else the frame's segments, of which the fulcrum
fit keeps those through the fulcrum; for the pivot plane each frame contributes its longest such
line, oriented from the fulcrum towards the visible shaft.

3. with the shafts' diameter known (``shaft_diameter``), every shaft's two silhouette edges
   give its 3-D axis (`cylinder.shaft_axis_record`: the band's width fixes the depth), and
   the fulcrum is the robust weighted least-squares point closest to all of them
   (`cylinder.fulcrum_3d`), a 3-D point in the camera frame with its covariance, the axes
   that pass far from it named (`fulcrum_point`).

4. with a second, calibrated view of the same instrument (a stereo endoscope: the right
   camera's pose from the left's, `camera.stereo.StereoRig`), the right view's own fulcrum
   ray and the left's meet at the 3-D fulcrum (`stereo_fulcrum.stereo_fulcrum`: `cylinder.triangulate_rays`),
   with no diameter needed; with the diameter too, the two 3-D estimates are compared
   (chi2, 3 dof) and fused (`cylinder.combine_estimates`), the left ray they share counted
   once.

The pivot frame ("target" of the orientation): the shaft at pivot angle theta points along
(cos theta, sin theta, 0); its normal is R_cam_from_target[:, 2].
"""
from __future__ import annotations

import csv
import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

import numpy as np

from pencilcal.toolkit.errors import EstimationError, InputError
from pencilcal.toolkit.pencil.estimator import check_vertex, fit_pencil
from pencilcal.toolkit.geometry.frames import normalize
from pencilcal.toolkit.pencil.band_width import band_width_sd, point_width_cov
from pencilcal.toolkit.pencil.defaults import ENDPOINT_SIGMA_PX
from pencilcal.toolkit.camera.intrinsics import propagate
from pencilcal.toolkit.pencil.lens_uncertainty import (orientation_totals, ray_sigma_total_deg,
                                                       resolve_intrinsics_cov, vertex_cov_total_px2)
from pencilcal.toolkit.pencil.orient import orientation_record, raw_vertex
from pencilcal.toolkit.pencil.orientation import Orientation
from pencilcal.toolkit.pencil.cylinder import (Fulcrum3D, axis_frame, axis_offsets, fulcrum_3d,
                                               project_cylinder, shaft_axis, shaft_axis_record)
from pencilcal.toolkit.pencil.sequence_noise import MAX_RUNS, inflation
from pencilcal.toolkit.pencil.scatter_gate import over_all_axes, scatter_inliers
from pencilcal.toolkit.pencil.parallax import vertex_with_parallax

__all__ = ["Fulcrum", "FulcrumPoint", "SequenceLines", "fulcrum_from_frames", "fulcrum_point",
           "frame_axes", "leave_one_out_points", "pose_arrays", "point_lens_cov", "sequence_lines",
           "read_angles"]

# a run's own variance factor above this (a sigma scale of 1.1) fits the axes again with the
# scaled covariances: the gate of that run was set for a smaller noise
_RERUN_FACTOR = 1.1**2


def read_angles(path, images):
    """Pivot angles [rad] for the frames `images` from a CSV file.

    Accepted: a header with ``image`` and ``angle_deg`` columns (matched by image name), or
    a header with ``angle_deg`` only / no header with one number per row (in frame order,
    one row per frame). Returns (F,) radians; InputError naming the file otherwise.
    """
    p = Path(path)
    try:
        rows = [r for r in csv.reader(p.read_text(encoding="utf-8").splitlines()) if r and any(c.strip() for c in r)]
    except (OSError, UnicodeDecodeError) as e:
        raise InputError(f"{p}: cannot read angles file: {e}") from None
    if not rows:
        raise InputError(f"{p}: no angles")
    head = [c.strip().lower() for c in rows[0]]
    by_name = ii = None
    try:
        if "angle_deg" in head:
            ia = head.index("angle_deg")
            ii = head.index("image") if "image" in head else None
            body = rows[1:]
            vals = [float(r[ia]) for r in body]
            if ii is not None:
                names = [r[ii].strip() for r in body]
        else:
            vals = [float(r[0]) for r in rows]
    except (ValueError, IndexError):
        raise InputError(f"{p}: angles must be numbers (columns image,angle_deg or one angle per row)") from None
    if not np.all(np.isfinite(vals)):
        raise InputError(f"{p}: angles must be finite")
    if ii is not None:
        by_name = {}
        for k, (name, v) in enumerate(zip(names, vals)):
            if name in by_name:
                raise InputError(f"{p}: image {name!r} is listed twice (row {k + 2}); one angle per image")
            by_name[name] = v
    if by_name is not None:
        missing = [im for im in images if im not in by_name]
        if missing:
            raise InputError(f"{p}: no angle for image {missing[0]!r} ({len(missing)} missing)")
        return np.radians([by_name[im] for im in images])
    if len(vals) != len(images):
        raise InputError(f"{p}: {len(vals)} angles for {len(images)} frames")
    return np.radians(vals)


@dataclass(frozen=True, eq=False)
class Fulcrum:
    """The fulcrum of a pivoting instrument over a sequence (the record of fulcrum.json).

    vertex_px (2,) and vertex_cov_px2 (2, 2): the fulcrum's image in raw pixels (None where
    the lens model does not reach it); ray (3,): its unit viewing ray (camera frame) and
    ray_sigma_deg; lines_used, frames_used; outliers: [{"image", "segment"}] of the lines
    that miss it; rms: the weighted RMS of the lines' residuals; lines_from: "shafts" or
    "segments" (which lines of the frames were used); warnings: what the caller should
    tell the user. With pivot angles, `pivot` is the pivot plane's `Orientation` (its keys
    join the record) from `pivot_frames` frames. With the shafts' diameter, `point` is the 3-D
    fulcrum (`FulcrumPoint`, its keys join the record). With the intrinsics' covariance known
    (`intrinsics_used`), ray_sigma_total_deg and vertex_cov_total_px2 hold its term too
    (`lens_uncertainty`), as the pivot's total keys do. ray_cov (3, 3): the unit ray's
    covariance when the fit was made (`ray_covariance` gives it with the current
    ray_sigma_deg); ray_cov_lens (3, 3): the intrinsics' term of it (with intrinsics_used;
    a rescaled noise leaves it as it is), ``ray_cov_total`` in the record their sum.
    noise, jackknife: the fulcrum.json records of the noise its sigmas hold and of the
    leave-one-out check, where they were decided (`validation.fulcrum_run`); None otherwise.
    parallax: where the lines carry parallax scales (stabilised shafts), the record of the
    parallax term their covariances took (`vertex_with_parallax`); None otherwise.
    play: where the lines are a still camera's shaft midlines, the record of the port's
    play their offsets took (`_vertex_fit`: ``sigma_px``, 0 where the lines scatter no more
    than their sigmas say); None otherwise.
    ray_cov_offset (3, 3): the part of ray_cov that the parallax or the play term gave (an
    offset of every line at the vertex, the scene's rather than each line's own:
    `stereo_fulcrum.stereo_fulcrum` takes it as shared by two views); None where the lines
    took none. vertex_lines: where the lines are shaft midlines, the inlier lines as a
    second view of the same frames needs them to count what the two share line by line
    (`stereo_play.play_cross_cov`): (frames (N,) int, each line's frame index in the frames
    given; gains (N, 3) [1/px], how far the unit ray turns per px the line moves along its
    normal at the vertex; normals (N, 2), those unit normals in undistorted px; residuals
    (N,) [px], the vertex's signed distance from the line along its normal; sigmas (N,)
    [px], the sd the fit gave the line there); None otherwise.
    """

    vertex_px: np.ndarray | None
    vertex_cov_px2: np.ndarray | None
    ray: np.ndarray
    ray_sigma_deg: float
    lines_used: int
    outliers: list
    frames_used: int
    rms: float
    lines_from: str = "segments"
    warnings: tuple = ()
    pivot: Orientation | None = None
    pivot_frames: int | None = None
    ray_sigma_total_deg: float | None = None
    vertex_cov_total_px2: np.ndarray | None = None
    intrinsics_used: bool | None = None
    point: "FulcrumPoint | None" = None
    ray_cov: np.ndarray | None = None
    ray_cov_lens: np.ndarray | None = None
    noise: dict | None = None
    jackknife: dict | None = None
    parallax: dict | None = None
    ray_cov_offset: np.ndarray | None = None
    play: dict | None = None
    vertex_lines: tuple | None = None

    def ray_covariance(self):
        """(3, 3) covariance of the unit `ray` (camera frame), singular along it, with the
        noise `ray_sigma_deg` holds (``trace = radians(ray_sigma_deg)^2``: a rescaled
        fulcrum's ray_sigma_deg rescales it); None when not known."""
        if self.ray_cov is None:
            return None
        C = np.asarray(self.ray_cov, float)
        tr = float(np.trace(C))
        return C * (np.radians(self.ray_sigma_deg) ** 2 / tr) if tr > 0 else C

    def ray_covariance_total(self):
        """(3, 3) the unit ray's covariance with the intrinsics' term (`ray_covariance` plus
        ray_cov_lens); None without the intrinsics' covariance."""
        C = self.ray_covariance()
        return None if C is None or self.ray_cov_lens is None else C + np.asarray(self.ray_cov_lens, float)

    def to_dict(self) -> dict:
        """The fulcrum.json record: ``noise`` and ``jackknife`` where they were decided, the
        fulcrum's keys, then with a pivot plane the keys of orientation.json (but the image
        and those the fulcrum has) and pivot_frames."""
        out = {} if self.noise is None else {"noise": self.noise, "jackknife": self.jackknife}
        out.update({"ok": True, "error": None, "vertex_px": self.vertex_px, "vertex_cov_px2": self.vertex_cov_px2,
                    "ray": self.ray, "ray_sigma_deg": self.ray_sigma_deg, "lines_used": self.lines_used,
                    "outliers": self.outliers, "frames_used": self.frames_used, "rms": self.rms})
        if self.ray_cov is not None:
            out["ray_cov"] = self.ray_covariance()
            if self.ray_cov_lens is not None:
                out["ray_cov_total"] = self.ray_covariance_total()
        for k in ("ray_sigma_total_deg", "vertex_cov_total_px2", "intrinsics_used"):
            if getattr(self, k) is not None:
                out[k] = getattr(self, k)
        if self.pivot is not None:
            rec = self.pivot.to_dict()
            rec.pop("image", None)
            out.update({k: v for k, v in rec.items() if k not in out})
            out["pivot_frames"] = self.pivot_frames
        if self.point is not None:
            out.update(self.point.to_dict())
        out["lines_from"] = self.lines_from
        if self.parallax is not None:
            out["parallax"] = self.parallax
        if self.play is not None:
            out["play"] = self.play
        return out


@dataclass(frozen=True, eq=False)
class FulcrumPoint:
    """The 3-D fulcrum from the shafts' 3-D axes (`fulcrum_point`), camera frame, lengths in
    the unit of the diameter.

    fit: the `cylinder.Fulcrum3D` over the N axes; owners: N (image, shaft index) of the
    axes; diameter: the shafts' diameter; skipped: shafts without a 3-D axis (no edge
    covariance in the lines file, or edges that bound no cylinder). axis_points,
    axis_directions: (N, 3) each axis's point closest to the camera centre and its unit
    direction (camera frame), or None. camera_motion: where the frames carry their
    camera's pose (a moving camera: `moving_fulcrum`), {frames_moved, scale (the length
    of the poses' map unit; None where the camera only turned), scale_sigma,
    variance_factor (what the point's covariance was multiplied by: its axes' chi2 per
    degree of freedom, at least 1)}; every 3-D
    quantity is then in the reference frame's camera, and the axes' points are carried.
    variance_factor: what point_cov was multiplied by, the still camera's and the moving
    camera's alike: the used axes' chi2 per degree of freedom (2N - 3, or 2N - 4 with the
    map unit) where above 1, else 1; where the still camera's axes took the port's play
    (`_point_with_play`), the factor on the axes' covariances that went with it. play: that
    play's variance [length^2] per direction (0: none taken). width_cov (3, 3): the term of
    the bands' width error shared by the sequence (`point_width_cov`), added to the fit's
    covariance in ``point_cov`` (None: none); width_sd: that relative width sd. play_cov
    (3, 3): the term of the port's play the image lines read beyond the axes' own
    (`_play_term`), added to ``point_cov`` as well (None: none).
    """

    fit: Fulcrum3D
    owners: list
    diameter: float
    skipped: int = 0
    axis_points: np.ndarray | None = None
    axis_directions: np.ndarray | None = None
    lens_cov: np.ndarray | None = None
    camera_motion: dict | None = None
    variance_factor: float = 1.0
    play: float = 0.0
    width_cov: np.ndarray | None = None
    width_sd: float = 0.0
    play_cov: np.ndarray | None = None

    @property
    def cov(self) -> np.ndarray:
        """(3, 3) the point's covariance: the fit's (noise, play) plus the shared width term and
        the lines' play term."""
        C = np.asarray(self.fit.point_cov, float)
        for term in (self.width_cov, self.play_cov):
            if term is not None:
                C = C + np.asarray(term, float)
        return C

    def to_dict(self) -> dict:
        """point, point_cov, point_sigma, point_axes_used, point_outliers ({image, shaft,
        distance, chi2} of each axis left out), point_axes ({image, shaft, distance, chi2,
        used, and axis_point, axis_direction where known} of every axis), point_chi2_dof,
        point_variance_factor, point_play_sigma, point_width_sd, point_cov_width and
        shaft_diameter; point_cov is the fit's plus the width term (`cov`); with `lens_cov` (the
        intrinsics' term) also point_cov_total = point_cov + lens_cov and point_sigma_total
        (docs/formats.md)."""
        f = self.fit
        used = np.asarray(f.inliers)
        axes = [{"image": im, "shaft": j, "distance": float(f.distances[k]), "chi2": float(f.chi2[k]),
                 "used": bool(used[k])} for k, (im, j) in enumerate(self.owners)]
        if self.axis_points is not None and self.axis_directions is not None:
            for a, p, d in zip(axes, self.axis_points, self.axis_directions):
                a.update(axis_point=np.asarray(p, float).tolist(), axis_direction=np.asarray(d, float).tolist())
        dof = max(2 * int(used.sum()) - 3, 1)
        cov = self.cov
        out = {"point": np.asarray(f.point, float).tolist(), "point_cov": cov.tolist(),
               "point_sigma": float(np.sqrt(max(np.trace(cov), 0.0))), "point_axes_used": int(used.sum()),
               "point_outliers": [{k: a[k] for k in ("image", "shaft", "distance", "chi2")} for a in axes
                                  if not a["used"]],
               "point_chi2_dof": float(np.sum(np.asarray(f.chi2)[used]) / dof),
               "point_variance_factor": float(self.variance_factor),
               "point_play_sigma": float(np.sqrt(self.play)), "point_width_sd": float(self.width_sd),
               "point_cov_width": None if self.width_cov is None else np.asarray(self.width_cov, float).tolist(),
               "point_cov_play": None if self.play_cov is None else np.asarray(self.play_cov, float).tolist(),
               "point_axes": axes, "shaft_diameter": self.diameter}
        if self.camera_motion is not None:
            out["point_camera_motion"] = dict(self.camera_motion)
        if self.lens_cov is not None:
            # the jackknife may have replaced the fit's covariance: the intrinsics' term adds to whichever
            total = cov + np.asarray(self.lens_cov, float)
            out.update(point_cov_total=total.tolist(), point_sigma_total=float(np.sqrt(max(np.trace(total), 0.0))))
        return out


def fulcrum_point(camera, frames, diameter, robust=True, intrinsics_cov=None, width_sd_px=None, lines_play=None, scatter_gate=True):
    """The 3-D fulcrum: the point closest to every shaft's 3-D axis over a sequence.

    camera: Camera; frames: lines.json frame dicts whose shafts carry ``edges`` [raw px]
    and ``edge_cov`` (`pencilcal lines --shaft`); diameter: the shafts' diameter (every
    length of the result in its unit). Each shaft's axis and its 4x4 chart covariance come
    from its edges and their covariance (`cylinder.shaft_axis_record`); the point is their
    robust weighted least-squares intersection (`cylinder.fulcrum_3d`: an MSAC start from
    pairs of axes, then a chi2 gate at 99 % on each axis's offset), its covariance the
    inverse of the normal equations times the used axes' chi2 per degree of freedom where
    that is above 1 (the a-posteriori variance factor: on real frames the short shafts'
    edge covariances are small, `sequence_noise.inflation`). intrinsics_cov: (P, P) the
    covariance of the camera's intrinsics (`camera.intrinsics`), or None: then also the
    point's ``lens_cov`` (`point_lens_cov`). width_sd_px: the sd [px] of the bands' width
    error shared by the sequence, whose term (`point_width_cov`) joins the point's
    covariance: None for each band's own from what the detector measured on it
    (`band_width.band_width_sd`: its edge model, polarity and width), a number for every
    band (0: none). lines_play: the port's play the sequence's image lines read at their
    vertex (`lines_play_rad`: its sd as an angle [rad] seen from the camera), or None: where
    that angle times the point's distance exceeds the play the axes read, the rest joins
    the point's covariance (`_play_term`, ``play_cov``); the point is the same.
    scatter_gate: True (default) gates the axes at their own scatter first where they all
    scatter well inside their covariances (`scatter_gate.scatter_inliers`; docs/method.md).
    Returns a `FulcrumPoint`; EstimationError when fewer than two crossing axes remain.

    A moving camera (`pencilcal fulcrum --stabilize`): frames whose ``camera_pose`` gives
    their camera from the reference frame's (R_frame_from_ref, t_frame_from_ref in the
    poses' map unit, cov (6, 6): `detect.background_pose.FramePose.to_dict`) take each
    shaft's axis from its own edges (``edges_frame``, ``edge_cov_frame``), carry it into
    the reference camera and fit the point with the map unit's length
    (`moving_fulcrum.fulcrum_moving`); no ``lens_cov`` then (the poses hold the lens too).
    A frame whose ``camera_pose`` is None (its pose not measured) gives no axis.
    """
    axes = frame_axes(camera, frames, diameter)
    if width_sd_px is None:
        width_sd_px = [band_width_sd(frames[i]["shafts"][j]) for i, (_, j) in zip(axes[6], axes[3])]
    return _point_of_axes(camera, axes, diameter, robust, intrinsics_cov, width_sd_px, lines_play, scatter_gate)


def lines_play_rad(play, K, x_n):
    """The port's play the image lines read (`_vertex_fit`'s record ``play``: ``sigma_px``, the
    sd of every line's offset at the vertex beyond its own [undistorted px]; or None) as an
    angle [rad] seen from the camera: ``sigma_px`` times the unit ray's move per pixel at the
    vertex x_n (2,) (normalised image coordinates; K (3, 3) the intrinsics [px]), the root
    mean square of its two directions. None where the lines read none.

    >>> K = np.array([[520.0, 0, 319.5], [0, 520, 239.5], [0, 0, 1]])
    >>> round(lines_play_rad({"sigma_px": 2.6}, K, [0.0, 0.0]), 6)
    0.005
    """
    if not play or not play.get("sigma_px"):
        return None
    v = np.r_[np.asarray(x_n, float), 1.0]
    P = (np.eye(3) - np.outer(v, v) / (v @ v))[:, :2] / np.linalg.norm(v)
    M = P @ np.linalg.inv(np.asarray(K, float))[:2, :2]
    return float(play["sigma_px"]) * float(np.sqrt(0.5 * np.trace(M @ M.T)))


def leave_one_out_points(camera, frames, diameter, robust=True):
    """[(k, point (3,) or None)]: for each frame k with shafts, the 3-D fulcrum of the others
    (`fulcrum_point` of ``frames[:k] + frames[k + 1:]``; None where that has no point), as a
    jackknife over frames takes them (`validation.checks.point_jackknife`). Each shaft's
    axis comes from its own edges alone, so the axes are found once for all the frames and
    every point is the one `fulcrum_point` gives (the same numbers), at a fraction of the
    cost."""
    axes = frame_axes(camera, frames, diameter)
    out = []
    for k, f in enumerate(frames):
        if not f.get("shafts"):
            continue
        keep = [a for a, i in enumerate(axes[6]) if i != k]
        rest = tuple([v[a] for a in keep] for v in axes[:7]) + (axes[7],)
        try:
            out.append((k, _point_of_axes(camera, rest, diameter, robust).fit.point))
        except EstimationError:
            out.append((k, None))
    return out


def _point_of_axes(camera, axes, diameter, robust=True, intrinsics_cov=None, width_sd_px=0.0, lines_play=None, scatter_gate=True):
    """`fulcrum_point` of the axes `frame_axes` gave (axes: its tuple); width_sd_px: one or
    (N,) per axis; lines_play: as `fulcrum_point`'s."""
    points, dirs, covs, owners, measured, poses, _, skipped = axes
    if len(points) < 2:
        raise EstimationError(f"the 3-D fulcrum needs the 3-D axes of two shafts at least, got {len(points)}"
                              + (f" ({skipped} shaft(s) without edge_cov or a valid axis)" if skipped else ""))
    if any(p is not None for p in poses):
        return _moving_point(points, dirs, covs, poses, owners, diameter, skipped, robust)
    # every point undistorted on its own: one call for all the edges gives each shaft's numbers
    ideal = np.asarray(camera.undistort_pixels(np.array([np.asarray(e, float).reshape(2, 4) for e, _ in measured])
                                               .reshape(-1, 2)), float).reshape(-1, 2, 4)
    edge_cov = np.array([np.asarray(c, float).reshape(2, 2, 2) for _, c in measured])
    fit, factor, play, play_cov = _point_with_noise(
        np.array(points), np.array(dirs), np.array(covs), robust,
        (np.asarray(camera.K, float), (ideal, edge_cov), 0.5 * float(diameter)), lines_play, scatter_gate)
    lens = None
    if intrinsics_cov is not None:
        used = [measured[k] for k in np.flatnonzero(np.asarray(fit.inliers))]
        lens = point_lens_cov(camera, intrinsics_cov, used, diameter)
    width_cov, width_sd = None, 0.0
    sd = np.broadcast_to(np.asarray(width_sd_px, float), (len(points),))
    if np.any(sd > 0):
        used = np.asarray(fit.inliers, bool)
        width_cov, width_sd = point_width_cov(camera.K, ideal[used], edge_cov[used], 0.5 * float(diameter), sd[used])
    return FulcrumPoint(fit=fit, owners=owners, diameter=float(diameter), skipped=skipped,
                        axis_points=np.array(points), axis_directions=normalize(np.array(dirs)), lens_cov=lens,
                        variance_factor=factor, play=play, width_cov=width_cov, width_sd=width_sd, play_cov=play_cov)


def _point_with_noise(points, dirs, covs, robust, edges=None, lines_play=None, scatter_gate=True):
    """(Fulcrum3D, variance factor, play, play term or None) of `fulcrum_point`'s still camera
    (points, dirs (N, 3), covs (N, 4, 4) as `cylinder.fulcrum_3d` takes them): the axes' own
    scatter taken in, as the image lines' fulcrum takes its lines' (`sequence_noise`), only
    ever inflating.

    With the axes' edges (edges: (K (3, 3), (edges (N, 2, 4) [undistorted px], edge_cov (N,
    2, 2, 2)), radius)) the scatter is first read as the stereo axes' is
    (`_point_with_play`: a factor on the axes' covariances and the port's play, each axis
    weighed at the line through the point); that fit is kept where the play it reads is one
    a port can have (`_PLAY_OF_DIAMETER`). Otherwise, and without the edges, a factor alone:
    the used axes' chi2 over 2N - 3; while a run's own factor
    is above 1.1^2 the axes are fitted again with their covariances times the factor so far
    (at most `sequence_noise.MAX_RUNS` runs), because the 99 % gate of a run whose
    covariances are too small leaves out the larger residuals and would bias the factor
    low. The last run's covariance times its own factor; the factor returned is the total
    (with the play: the factor on the axes' covariances). play: the play's variance
    [length^2] per direction, 0 without it. lines_play: the play the image lines read [rad]
    (`fulcrum_point`), or None; the play term (3, 3) is `_play_term`'s, None with the factor
    alone. scatter_gate: the axes gated at their own scatter first (`fulcrum_point`)."""
    keep = scatter_inliers(points, dirs, covs) if robust and scatter_gate else np.ones(len(points), bool)
    if not np.all(keep):  # the rest fitted as before, the axes left out marked outliers
        K, (e, c), radius = edges if edges is not None else (None, (None, None), None)
        sub = None if edges is None else (K, (e[keep], c[keep]), radius)
        fit, factor, play, term = _point_with_noise(points[keep], dirs[keep], covs[keep], robust, sub, lines_play)
        return over_all_axes(fit, keep, points, dirs, covs), factor, play, term
    if edges is not None:
        played = _point_with_play(points, dirs, covs, robust, *edges, lines_play=lines_play)
        if played is not None:
            return played

    def own_factor(fit):
        used = np.asarray(fit.inliers, bool)
        return inflation(np.sum(np.asarray(fit.chi2)[used]), 2 * int(used.sum()) - 3)

    fit, own, total = _runs_at_noise(lambda f: fulcrum_3d(points, dirs, covs * f, robust=robust), own_factor)
    fit = dataclasses.replace(fit, point_cov=fit.point_cov * own, point_sigma=fit.point_sigma * np.sqrt(own))
    return fit, total * own, 0.0, None


#: The largest play (sd per direction, as a fraction of the shaft's diameter) read as the
#: port's: an instrument's shaft fits its port within a fraction of its width (a millimetre
#: or so for an 8 mm shaft). A scatter that needs more is not one pivot with play (a fulcrum
#: or camera that moved, misread shafts), and an isotropic play would hide it: the factor
#: alone then, whose jackknife (`validation.checks.point_jackknife`) judges it.
_PLAY_OF_DIAMETER = 1.0 / 8.0


def _point_with_play(points, dirs, covs, robust, K, edges, radius, lines_play=None):
    """(Fulcrum3D, factor, play, play term) of the still camera's axes with a factor k on their
    covariances and an isotropic play s2 on their positions, as the stereo axes' (`stereo_axes.
    axes_with_noise`: k and s2 by maximum likelihood on the gate's offsets), each axis
    weighed by its covariance evaluated at the line through the point nearest to it
    (`_covariances_at_point`; twice, the noise terms refitted each time). None where the
    play's sd exceeds `_PLAY_OF_DIAMETER` of the diameter (2 radius), or where too few axes
    meet with the play in.

    An axis's covariance evaluated at its own estimate follows its own error: its depth's
    sd grows as the square of its depth, so an axis read too near weighs more and the
    point leans towards the camera; and a factor alone, one scale on every axis, leaves
    the precise axes' share of the port's play too small. (The fused two-eye point weighs
    its axes at their own estimates; for one eye that leant further on fresh pivots:
    docs/method.md, "One eye's axes weighed at their own estimates again".)

    lines_play [rad]: the play the image lines read at their vertex (`lines_play_rad`), or
    None. The axes' offsets at the point seldom show the play: each axis's offset there is
    extrapolated from its edges over the shaft, its stated sd as large as the play or larger,
    so their chi2 reads none (on rendered pivots with 0.35 mm of play, none on 22 of 32
    views), while across the line of sight the point, a weighted mean of the axes' offsets,
    moves with it. The lines' offsets at the vertex show it: where the angle they read times
    the point's distance exceeds the axes' play, the rest is the play term (`_play_term`;
    None otherwise), the point the same (docs/uncertainty.md, "The port's play in the 3-D
    point")."""
    from pencilcal.toolkit.pencil.stereo_axes import axes_with_noise

    E = axis_frame(points, dirs)
    try:
        fit, used, play, k = axes_with_noise(points, dirs, covs, E, robust)
        for _ in range(2):
            at = _covariances_at_point(K, edges, radius, points, dirs, covs, E, np.asarray(fit.point, float))
            fit, used, play, k = axes_with_noise(points, dirs, at, E, robust)
    except EstimationError:  # too few axes meet with the play in: the factor's own gate decides
        return None
    if np.sqrt(play) > _PLAY_OF_DIAMETER * 2.0 * radius:
        return None
    term = None
    if lines_play is not None:
        seen = (float(lines_play) * float(np.linalg.norm(fit.point))) ** 2
        if seen > play:
            term = _play_term(fit, points, dirs, used, E, seen - play)
    return fit, float(k), float(play), term


def _play_term(fit, points, dirs, covs, frames, s2):
    """(3, 3) what an offset of every used axis, independent between frames, of variance s2
    [length^2] per direction across it (the port's play) adds to the covariance of the point
    the axes give with the covariances covs (N, 4, 4) they were weighed with: the point is
    ``H^-1 sum E_i^T W_i E_i a_i`` (W_i the inverse of the axis's offset covariance at the
    point, E_i (2, 3) its chart frame, H the sum of ``E_i^T W_i E_i``), so the offsets add
    ``s2 H^-1 (sum E_i^T W_i W_i E_i) H^-1``. points, dirs (N, 3), frames (N, 2, 3) as
    `cylinder.fulcrum_3d` takes them."""
    use = np.asarray(fit.inliers, bool)
    _, S, _ = axis_offsets(np.asarray(fit.point, float), points[use], dirs[use], frames[use], covs[use])
    G = np.swapaxes(frames[use], -1, -2) @ np.linalg.inv(S)                   # (n, 3, 2): E^T W
    H_inv = np.linalg.inv(np.sum(G @ frames[use], 0))
    T = s2 * H_inv @ np.sum(G @ np.swapaxes(G, -1, -2), 0) @ H_inv
    return 0.5 * (T + T.T)


def _rowdot(a, b):
    """(...) the dot products of a, b (..., k) along their last axis, rounded as ``a[i] @ b[i]``
    rounds them one at a time (a sum of products can round otherwise): the batched axes give
    the numbers the axes one by one gave."""
    return (a[..., None, :] @ b[..., :, None])[..., 0, 0]


def _covariances_at_point(K, edges, radius, points, dirs, covs, frames, x):
    """(N, 4, 4) each axis's chart covariance evaluated at the line through the point x (3,)
    nearest to it in its own covariance's metric (``p = C M^T (M C M^T)^-1 r`` in its chart,
    r the offset of x from the axis, ``M = [t I, I]``, t along the axis to x): what its
    edges' noise gives a shaft lying there (`_axis_covs_at`); covs where it cannot be had.

    edges: (edges (N, 2, 4) [undistorted px], edge_cov (N, 2, 2, 2)) of the axes; points,
    dirs (N, 3), covs (N, 4, 4), frames (N, 2, 3) as `cylinder.fulcrum_3d` takes them.
    All the axes at once; an axis whose line cannot be had (a singular M C M^T, no cylinder
    clear of the camera, edges that bound none) keeps its covariance, found one by one
    only where the whole set fails, so that one such axis leaves the others' unchanged."""
    e, c = edges
    out = np.array(covs, float, copy=True)
    v = x - points                                                  # (N, 3)
    t = _rowdot(dirs, v)
    M = np.zeros((len(t), 2, 4))
    M[:, 0, 0] = M[:, 1, 1] = t
    M[:, 0, 2] = M[:, 1, 3] = 1.0
    Mt = np.swapaxes(M, -1, -2)
    r = (frames @ v[..., None])[..., 0]
    A = M @ covs @ Mt                                               # (N, 2, 2)
    ok = np.abs(np.linalg.det(A)) > 0.0
    p = np.zeros((len(t), 4))
    if np.any(ok):
        p[ok] = (covs[ok] @ Mt[ok] @ np.linalg.solve(A[ok], r[ok][..., None]))[..., 0]
    u, w = frames[:, 0], frames[:, 1]
    at = points + p[:, 2:3] * u + p[:, 3:4] * w
    d = normalize(dirs + p[:, 0:1] * u + p[:, 1:2] * w)
    at = at - _rowdot(at, d)[:, None] * d
    idx = np.flatnonzero(ok)
    try:
        C, good = _axis_covs_at(K, e[idx], c[idx], radius, points[idx], dirs[idx], frames[idx], at[idx], d[idx])
    except (EstimationError, InputError):  # one axis's line bounds no cylinder: each on its own
        C, good = np.zeros((len(idx), 4, 4)), np.zeros(len(idx), bool)
        for j, i in enumerate(idx):
            try:
                one = _axis_covs_at(K, e[i:i + 1], c[i:i + 1], radius, points[i:i + 1], dirs[i:i + 1],
                                    frames[i:i + 1], at[i:i + 1], d[i:i + 1])
            except (EstimationError, InputError):
                continue
            C[j], good[j] = one[0][0], one[1][0]
    out[idx[good]] = C[good]
    return out


def _axis_covs_at(K, edges, edge_cov, radius, point, direction, frame, at_point, at_direction):
    """((N, 4, 4), (N,) bool) the chart covariances (about point, direction (N, 3), frame
    (N, 2, 3): each axis's own) of the axes shafts on the lines (at_point, at_direction (N,
    3)) would give from edges over the same stretch as `edges` (N, 2, 4) [undistorted px]
    with their covariance edge_cov (N, 2, 2, 2): each edge moved onto that cylinder's
    silhouette line nearest it (`cylinder.shaft_axis`), and whether each is finite.
    InputError or EstimationError where any line bounds no cylinder clear of the camera."""
    n = len(edges)
    lines = project_cylinder(K, at_point, at_direction, radius).lines       # (N, 2, 3)
    e = np.asarray(edges, float).reshape(n, 2, 4)
    centre = 0.5 * (e[..., :2] + e[..., 2:])
    dist = np.abs(lines[..., :2] @ np.swapaxes(centre, -1, -2) + lines[..., 2:3])   # (N, line, edge)
    swap = dist[:, 0, 0] + dist[:, 1, 1] > dist[:, 1, 0] + dist[:, 0, 1]   # (N,) edge k on line 1 - k
    onto = lines[np.arange(n)[:, None], np.where(swap[:, None], [1, 0], [0, 1])]    # (N, 2 edges, 3)
    ends = e.reshape(n, 2, 2, 2)                                             # (N, edge, end, xy)
    off = _rowdot(onto[:, :, None, :2], ends) + onto[:, :, None, 2]
    moved = (ends - off[..., None] * onto[:, :, None, :2]).reshape(n, 2, 4)
    ax = shaft_axis(K, moved, radius, edge_cov=np.asarray(edge_cov, float).reshape(n, 2, 2, 2))
    # the chart about the line's own point into the axis's: its reference point moved along
    # the line to the axis's (s + tau theta), then both (u, w) pairs turned into the axis's
    tau = _rowdot(np.asarray(point, float) - ax.axis_point, ax.axis_direction)
    T = np.zeros((n, 4, 4))
    G = np.asarray(frame, float) @ np.swapaxes(np.asarray(ax.axis_frame, float), -1, -2)
    along = _rowdot(ax.axis_direction, direction)
    T[:, :2, :2] = np.where(along == 0.0, 1.0, np.sign(along))[:, None, None] * G
    T[:, 2:, 2:] = G
    T[:, 2:, :2] = tau[:, None, None] * G
    C = T @ np.asarray(ax.axis_cov, float) @ np.swapaxes(T, -1, -2)
    return C, np.all(np.isfinite(C), axis=(-2, -1))


def _runs_at_noise(fit_at, own_factor):
    """The one rule of the 3-D point's runs (`_point_with_noise`, `_moving_point`): fit_at(f)
    fits with the covariances times f, own_factor(fit) its variance factor; while a run's
    own factor is above `_RERUN_FACTOR` the fit runs again at the factor so far (at most
    `sequence_noise.MAX_RUNS` runs). Returns (the last fit, its own factor, the factor it
    ran at)."""
    total = 1.0
    for i in range(MAX_RUNS):
        fit = fit_at(total)
        own = own_factor(fit)
        if own <= _RERUN_FACTOR or i == MAX_RUNS - 1:
            break
        total *= own
    return fit, own, total


def frame_axes(camera, frames, diameter):
    """(points, directions, covs, owners [(image, shaft index)], measured [(edges,
    edge_cov)], poses [``camera_pose`` or None], frame indices, skipped) of every shaft's
    3-D axis in lines.json `frames` (`fulcrum_point`: in its own frame's camera where the
    frame carries its ``camera_pose``); lists, one entry an axis."""
    found = []  # (frame index, shaft index, frame, its keys) of every shaft with edges and their covariance
    skipped = 0
    for i, fr in enumerate(frames):
        if not fr.get("ok", True):
            continue
        keys = ("edges", "edge_cov") if "camera_pose" not in fr else ("edges_frame", "edge_cov_frame")
        for j, sh in enumerate(fr.get("shafts") or []):
            if ("camera_pose" in fr and fr["camera_pose"] is None) or sh.get(keys[0]) is None or sh.get(keys[1]) is None:
                skipped += 1
                continue
            found.append((i, j, fr, (sh[keys[0]], sh[keys[1]])))
    points, dirs, covs, owners, measured, poses, index = [], [], [], [], [], [], []
    for (i, j, fr, m), ax in zip(found, _shaft_axes(camera, [m for *_, m in found], diameter)):
        if ax is None:
            skipped += 1
            continue
        points.append(ax["axis_point"])
        dirs.append(ax["axis_direction"])
        covs.append(ax["axis_cov"])
        owners.append((fr.get("image"), j))
        measured.append(m)
        poses.append(fr.get("camera_pose"))
        index.append(i)
    return points, dirs, covs, owners, measured, poses, index, skipped


def _shaft_axes(camera, measured, diameter):
    """[`cylinder.shaft_axis_record` or None where it has no axis] of each shaft of measured
    [(edges (2, 4) [raw px], edge_cov (2, 2, 2))]: every shaft at once (each edge point is
    undistorted on its own and each axis found from its own edges, so the numbers are each
    shaft's own), one by one only where a shaft of the set gives no axis."""
    if measured and np.isfinite(diameter) and diameter > 0:
        raw = np.array([np.asarray(e, float).reshape(2, 4) for e, _ in measured])
        ideal = np.asarray(camera.undistort_pixels(raw.reshape(-1, 2)), float).reshape(-1, 2, 4)
        if np.all(np.isfinite(ideal)):
            try:
                ax = shaft_axis(np.asarray(camera.K, float), ideal, 0.5 * float(diameter),
                                edge_cov=np.array([np.asarray(c, float).reshape(2, 2, 2) for _, c in measured]))
            except (EstimationError, InputError):
                ax = None
            if ax is not None:
                return [{k: getattr(ax, k)[n].tolist() for k in ("axis_point", "axis_direction", "axis_cov")}
                        for n in range(len(measured))]
    out = []
    for e, c in measured:
        try:
            out.append(shaft_axis_record(camera, e, c, diameter))
        except (EstimationError, InputError):
            out.append(None)
    return out


def pose_arrays(poses):
    """(R (N, 3, 3), t (N, 3), cov (N, 6, 6)) of ``camera_pose`` records (None: the
    reference's camera)."""
    still = {"R_frame_from_ref": np.eye(3), "t_frame_from_ref": np.zeros(3), "cov": np.zeros((6, 6))}
    poses = [still if p is None else p for p in poses]
    return (np.array([p["R_frame_from_ref"] for p in poses], float),
            np.array([p["t_frame_from_ref"] for p in poses], float), np.array([p["cov"] for p in poses], float))


def _moving_point(points, dirs, covs, poses, owners, diameter, skipped, robust):
    """`fulcrum_point` of axes whose frames carry their camera's pose in the reference's
    (``camera_pose``; a frame without one is the reference's camera): `moving_fulcrum`."""
    from pencilcal.toolkit.pencil.moving_fulcrum import fulcrum_moving

    R, t, S = pose_arrays(poses)
    # as the still camera's (`_point_with_noise`): fitted again with the axes' and the poses'
    # covariances times the factor so far while a run's own factor is above 1.1^2
    mv, own, total = _runs_at_noise(
        lambda f: fulcrum_moving(np.array(points), np.array(dirs), np.array(covs) * f, R, t, S * f, robust=robust),
        lambda run: run.variance_factor)
    mv = dataclasses.replace(mv, variance_factor=own * total)
    moved = int(np.sum(np.any(t != 0, axis=-1) | np.any(R != np.eye(3), axis=(-2, -1))))
    motion = {"frames_moved": moved, "scale": mv.scale, "scale_sigma": mv.scale_sigma,
              "variance_factor": mv.variance_factor}
    return FulcrumPoint(fit=mv.fit, owners=owners, diameter=float(diameter), skipped=skipped,
                        axis_points=mv.points, axis_directions=mv.directions, camera_motion=motion,
                        variance_factor=mv.variance_factor)


def point_lens_cov(camera, intrinsics_cov, shafts, diameter):
    """(3, 3) the intrinsics' term of the 3-D fulcrum's covariance (camera frame, unit of
    the diameter), or None where it cannot be had.

    shafts: [(edges (2, 4) [raw px], edge_cov (2, 2, 2))] of the axes the point was fitted
    to. Every intrinsic parameter with a variance is stepped by 1e-3 of its sigma either
    way (`lens_uncertainty.perturbed_cameras`), each shaft's axis found again through the
    stepped lens and the point fitted again to those axes with the same weights' model
    (`cylinder.fulcrum_3d`, no outlier search: the same axes); the central differences G
    (3, P) give ``G C G^T``. One lens for every frame: its error moves all the axes
    together, which is why this term is no smaller for more frames, unlike the noise's.
    """
    from pencilcal.toolkit.camera.intrinsics import propagate
    from pencilcal.toolkit.pencil.lens_uncertainty import intrinsics_steps, perturbed_cameras

    C = np.asarray(intrinsics_cov, float)
    steps = intrinsics_steps(C)
    if not steps or len(shafts) < 2:
        return None

    def point(cam):
        axes = [shaft_axis_record(cam, e, c, diameter) for e, c in shafts]
        return fulcrum_3d(np.array([a["axis_point"] for a in axes]), np.array([a["axis_direction"] for a in axes]),
                          np.array([a["axis_cov"] for a in axes]), robust=False).point

    G = np.zeros((3, C.shape[0]))
    try:
        for j, h, plus, minus in perturbed_cameras(camera, steps):
            G[:, j] = (np.asarray(point(plus), float) - np.asarray(point(minus), float)) / (2.0 * h)
    except (EstimationError, InputError):
        return None
    return propagate(G, C)


def _frame_lines(fr, endpoint_sigma_px, shafts_only):
    """Raw lines (K, 4), their angle sigma (K,) [rad] (NaN: from the end points) and
    parallax scale (K,) [px] (a stabilised shaft's ``parallax_scale_px``, else 0) for one
    frame: its shaft midlines when `shafts_only`, else its segments."""
    if shafts_only:
        shafts = fr.get("shafts") or []
        seg = np.array([np.asarray(s["midline"], float) for s in shafts]).reshape(-1, 4)
        sig = np.array([np.radians(float(s["angle_sigma_deg"])) if s.get("angle_sigma_deg") is not None else np.nan
                        for s in shafts])
        par = np.array([float(s.get("parallax_scale_px") or 0.0) for s in shafts])
        return seg, sig, par
    seg = np.asarray(fr.get("segments", np.zeros((0, 4))), float).reshape(-1, 4)
    sig = fr.get("angle_sigma_deg")
    sig = np.full(len(seg), np.nan) if sig is None else np.radians(np.asarray(sig, float))
    return seg, sig, np.zeros(len(seg))


def _sequence_lines(frames, endpoint_sigma_px):
    """Every usable line of the sequence: (segments (N, 4), sigmas (N,), parallax scales (N,),
    owner [(frame, index)], lines_from, warnings).

    When any frame has shaft midlines only midlines are used: a frame without a shaft
    has only its edge segments (hundreds, mostly not the instrument's), which would
    outvote the other frames' midlines.
    """
    ok_frames = [(i, fr) for i, fr in enumerate(frames) if fr.get("ok", True)]
    shafts_only = any(fr.get("shafts") for _, fr in ok_frames)
    warnings = []
    segs, sigs, pars, owner, bad = [], [], [], [], 0
    for i, fr in ok_frames:
        s, g, q = _frame_lines(fr, endpoint_sigma_px, shafts_only)
        finite = np.all(np.isfinite(s), -1)
        bad += int((~finite).sum())
        keep = finite & (np.hypot(s[:, 2] - s[:, 0], s[:, 3] - s[:, 1]) > 1.0)
        for j in np.flatnonzero(keep):
            segs.append(s[j])
            sigs.append(g[j])
            pars.append(q[j])
            owner.append((i, int(j)))
    if shafts_only:
        without = sum(1 for _, fr in ok_frames if not fr.get("shafts"))
        if without:
            warnings.append(f"{without} frame(s) without a shaft midline contribute no line (their edge segments "
                            "are not used when other frames have shafts)")
    if bad:
        warnings.append(f"{bad} {'shaft midline' if shafts_only else 'segment'}(s) with non-finite coordinates dropped")
    return np.array(segs).reshape(-1, 4), np.asarray(sigs, float), np.asarray(pars, float), owner, \
        ("shafts" if shafts_only else "segments"), warnings


class SequenceLines(NamedTuple):
    """The instrument lines of a sequence as the fulcrum fits them (`sequence_lines`), N lines.

    raw: (N, 4) raw px; ideal: (N, 4) undistorted px (NaN where the lens model does not
    reach); good: (N,) bool, undistorted; length: (N,) [ideal px]; angle_sigma (N,) [rad]
    (the line's own, else from the end point noise) and offset_sigma (N,) [px] at the
    line's centre; owner: [(frame index, line index in the frame)]; lines_from: "shafts"
    or "segments"; warnings: what the caller should tell the user; parallax: (N,) [px] each
    line's parallax scale (a stabilised shaft's ``parallax_scale_px``, 0 where its frame's
    motion is a turn or it was not stabilised; `fulcrum_from_frames`).
    """

    raw: np.ndarray
    ideal: np.ndarray
    good: np.ndarray
    length: np.ndarray
    angle_sigma: np.ndarray
    offset_sigma: np.ndarray
    owner: list
    lines_from: str
    warnings: list
    parallax: np.ndarray | None = None


def sequence_lines(camera, frames, endpoint_sigma_px=ENDPOINT_SIGMA_PX):
    """The instrument lines of lines.json `frames` in undistorted pixels with their noise
    model (`SequenceLines`): per frame its shaft midlines when any frame of the sequence
    has them, else its segments; a line without its own angle sigma has the end point
    noise's, ``sqrt(2) endpoint_sigma_px / L``, and every line the offset sigma
    ``endpoint_sigma_px / sqrt(2)`` (`vertex.segment_angle_sigma`)."""
    seg, sig, par, owner, lines_from, warnings = _sequence_lines(frames, endpoint_sigma_px)
    ideal = camera.undistort_pixels(seg.reshape(-1, 2)).reshape(-1, 4)
    good = np.all(np.isfinite(ideal), -1)
    L = np.hypot(ideal[:, 2] - ideal[:, 0], ideal[:, 3] - ideal[:, 1])
    st = np.where(np.isfinite(sig), sig, np.sqrt(2.0) * endpoint_sigma_px / np.maximum(np.nan_to_num(L), 1e-9))
    sc = np.full(len(seg), endpoint_sigma_px / np.sqrt(2.0))
    return SequenceLines(seg, ideal, good, L, st, sc, owner, lines_from, warnings, par)


def without_frame(lines, frames, k):
    """`sequence_lines` of `frames` with frame k left out, from those of all frames
    (`lines`) without undistorting them again (each point is undistorted on its own, so the
    numbers are the same); None where leaving it out changes which lines are used (the only
    frame with shaft midlines). Its ``warnings`` are those of all frames."""
    if lines.lines_from == "shafts" and not any(fr.get("shafts") for i, fr in enumerate(frames)
                                                if i != k and fr.get("ok", True)):
        return None
    keep = np.array([o[0] != k for o in lines.owner], bool)
    owner = [(f - (f > k), j) for f, j in lines.owner if f != k]
    return SequenceLines(lines.raw[keep], lines.ideal[keep], lines.good[keep], lines.length[keep],
                         lines.angle_sigma[keep], lines.offset_sigma[keep], owner, lines.lines_from, lines.warnings,
                         None if lines.parallax is None else lines.parallax[keep])


def _offset_cov(vf, segments, extra):
    """(2, 2) [px^2] the part of the vertex's covariance (`vertex.VertexFit.cov`) that the lines'
    added offset variance extra (N,) [px^2] gives (the parallax term; None where none):
    ``cov (sum n n^T extra / sigma^4) cov`` over the inliers (n the normal, sigma the sd)."""
    inl = np.asarray(vf.inliers, bool) & (np.asarray(extra) > 0)
    if not np.any(inl):
        return None
    d = segments[inl, 2:] - segments[inl, :2]
    n = np.stack([-d[:, 1], d[:, 0]], -1) / np.linalg.norm(d, axis=-1, keepdims=True)
    w = np.asarray(extra)[inl] / np.asarray(vf.sigmas, float)[inl] ** 4
    M = np.einsum("k,ki,kj->ij", w, n, n)
    return vf.cov @ M @ vf.cov


def _vertex_fit(segments, angle_sigma, offset_sigma, parallax, lines_from):
    """(VertexFit, parallax record or None, offset sigmas used (N,) [px], play record or None):
    the fulcrum's image from its N lines (segments (N, 4) undistorted px, angle_sigma (N,)
    [rad], offset_sigma (N,) [px], parallax (N,) [px] or None as `vertex_with_parallax`
    takes them).

    Lines stabilised from a moving camera take their parallax term. A still camera's shaft
    midlines take the port's play instead: every frame's shaft passes the fulcrum off by
    the play, whose image is an offset of the line at the vertex of about the same size in
    every frame (one fulcrum depth), whatever the line's own precision. So each line's
    offset variance takes one sd for the sequence, ``tau^2`` [px^2] (the parallax term with
    a scale of 1 px on every line: tau brings the inliers' chi2 to its degrees of freedom,
    the gate run again with it until it holds). A factor on the lines' own sigmas instead
    (`sequence_noise.fulcrum_noise`) leaves the long, precise lines' share of the play far
    too small, and the gate set for their sigmas leaves out the frames the play moved
    most: the factor read on what passes is too small (docs/uncertainty.md). play: {sigma_px
    (tau), chi2_without, dof, p_value (the fit without it)}; None for segments."""
    par = None if parallax is None else np.asarray(parallax, float)
    if lines_from != "shafts" or (par is not None and np.any(par > 0)):
        vf, rec, used = vertex_with_parallax(segments, angle_sigma, offset_sigma, par)
        return vf, rec, used, None
    vf, rec, used = vertex_with_parallax(segments, angle_sigma, offset_sigma, np.ones(len(segments)),
                                        median_start=True)
    play = {"sigma_px": rec["kappa"], "chi2_without": rec["chi2_without"], "dof": rec["dof"],
            "p_value": rec["p_value"], "start": rec["start"]}
    return vf, None, used, play


def fulcrum_from_frames(camera, frames, angles=None, endpoint_sigma_px=ENDPOINT_SIGMA_PX, intrinsics_cov="camera",
                        shaft_diameter=None, lines=None, raw_px=True):
    """The fulcrum (and with `angles` the pivot plane) from the lines of a sequence.

    camera: Camera; frames: lines.json frame dicts (io.lines_file.read_lines); angles: (F,)
    pivot angles [rad] per frame or None; endpoint_sigma_px: end point noise [px] of
    segments without their own angle sigma. Per frame the lines are the shaft midlines
    when any frame of the sequence has them, else the segments. intrinsics_cov: as
    `orient.orient_segments` ("camera": the camera file's, if it carries one).
    shaft_diameter: the shafts' diameter; then also the 3-D fulcrum (`fulcrum_point`).
    lines: the frames' `sequence_lines` (with this endpoint_sigma_px) when the caller has
    them (a jackknife: `without_frame`), else None. raw_px: False leaves the raw pixel
    (vertex_px, vertex_cov_px2) None, not mapped through the lens: fits of which only the
    ray and the pivot plane are used (a jackknife's).

    Returns a `Fulcrum` (its ``to_dict()`` is the fulcrum.json record). Raises
    EstimationError when there is no fulcrum.
    """
    if lines is None:
        lines = sequence_lines(camera, frames, endpoint_sigma_px)
    seg, ideal, good, L, st, sc, owner, lines_from, warnings, par = lines
    if len(seg) < 2:
        raise EstimationError(f"fewer than two instrument lines in the sequence ({len(seg)})")
    if good.sum() < 2:
        raise EstimationError("fewer than two lines could be undistorted")
    idx = np.flatnonzero(good)
    vf, parallax, sc_used, play = _vertex_fit(ideal[idx], st[idx], sc[idx], None if par is None else par[idx],
                                              lines_from)
    extra = sc_used ** 2 - sc[idx] ** 2
    sc = sc.copy()
    sc[idx] = sc_used
    inl = np.zeros(len(seg), bool)
    inl[idx[vf.inliers]] = True
    K = np.asarray(camera.K, float)
    Kinv = np.linalg.inv(K)
    A = Kinv[:2, :2]
    x = A @ vf.vertex + Kinv[:2, 2]
    check_vertex(x)
    cov_x = A @ vf.cov @ A.T
    # the ray from the ideal vertex itself: the lens model need not reach it (raw_vertex)
    ray = normalize(np.r_[x, 1.0])
    # ray uncertainty: the unit ray moves by (I - r r^T)[:, :2] / |(x, 1)| per unit of x
    v = np.r_[x, 1.0]
    P = (np.eye(3) - np.outer(v, v) / (v @ v))[:, :2] / np.linalg.norm(v)
    ray_cov = P @ cov_x @ P.T
    ray_sigma = np.sqrt(max(np.trace(ray_cov), 0.0))
    off = _offset_cov(vf, ideal[idx], extra)
    vertex_lines = None
    if lines_from == "shafts":
        k_in = np.flatnonzero(vf.inliers)
        a = ideal[idx[k_in], :2]
        dv = ideal[idx[k_in], 2:] - a
        n = np.stack([-dv[:, 1], dv[:, 0]], -1) / np.linalg.norm(dv, axis=-1, keepdims=True)
        sd = np.asarray(vf.sigmas, float)[k_in]
        # the vertex moves by cov n / sigma^2 per px the line moves along n (least squares)
        g = (n @ vf.cov) / sd[:, None] ** 2
        vertex_lines = (np.array([owner[idx[k]][0] for k in k_in], int), g @ (P @ A).T, n,
                        np.sum(n * (vf.vertex - a), -1), sd)
    v_raw, cov_raw = raw_vertex(camera, x, vf.vertex, vf.cov) if raw_px else (None, None)
    out = Fulcrum(
        vertex_px=v_raw, vertex_cov_px2=cov_raw, ray=ray, ray_sigma_deg=float(np.degrees(ray_sigma)),
        lines_used=int(vf.lines_used),
        outliers=[{"image": frames[owner[k][0]].get("image"), "segment": owner[k][1]} for k in np.flatnonzero(~inl)],
        frames_used=int(len({owner[k][0] for k in np.flatnonzero(inl)})), rms=vf.rms, lines_from=lines_from,
        warnings=tuple(warnings), ray_cov=ray_cov, parallax=parallax, play=play, vertex_lines=vertex_lines,
        ray_cov_offset=None if off is None else P @ (A @ off @ A.T) @ P.T)
    C = resolve_intrinsics_cov(camera, intrinsics_cov)
    if C is not None:
        k_in = idx[vf.inliers]
        ray_total, X = ray_sigma_total_deg(camera, C, x, cov_x, seg[k_in], st[k_in], sc[k_in])
        out = dataclasses.replace(out, ray_sigma_total_deg=ray_total, intrinsics_used=True, vertex_cov_total_px2=(
            None if cov_raw is None else vertex_cov_total_px2(camera, C, x, X, cov_raw)),
            ray_cov_lens=P @ propagate(X, C) @ P.T)
    if shaft_diameter is not None:
        pt = fulcrum_point(camera, frames, shaft_diameter, intrinsics_cov=C, lines_play=lines_play_rad(play, K, x))
        more = [f"{pt.skipped} shaft(s) without edge_cov or a valid 3-D axis left out of the 3-D fulcrum"] \
            if pt.skipped else []
        out = dataclasses.replace(out, point=pt, warnings=out.warnings + tuple(more))
    if angles is None:
        return out
    # one oriented line per frame: its longest inlier, pointing from the fulcrum outwards
    angles = np.asarray(angles, float)
    best = {}
    for k in np.flatnonzero(inl):
        f = owner[k][0]
        if f not in best or L[k] > L[best[f]]:
            best[f] = k
    if len(best) < 3:
        raise EstimationError(f"the pivot plane needs lines in three frames, got {len(best)}")
    ks = np.array([best[f] for f in sorted(best)])
    fr_idx = np.array(sorted(best))
    p1 = ideal[ks, :2] @ A.T + Kinv[:2, 2]
    p2 = ideal[ks, 2:] @ A.T + Kinv[:2, 2]
    far = np.where((np.linalg.norm(p2 - x, axis=1) >= np.linalg.norm(p1 - x, axis=1))[:, None], p2, p1)
    near = np.where((np.linalg.norm(p2 - x, axis=1) >= np.linalg.norm(p1 - x, axis=1))[:, None], p1, p2)
    d = far - near
    a = np.arctan2(d[:, 1], d[:, 0])
    # angle sd in normalised coordinates (a linear map A scales angles by det A / |A t|^2)
    t = (ideal[ks, 2:] - ideal[ks, :2]) / L[ks, None]
    s_n = st[ks] * abs(np.linalg.det(A)) / np.sum((t @ A.T) ** 2, -1)
    fit = fit_pencil(a, angles[fr_idx], x, sigma=s_n, vertex_cov=cov_x)
    pivot = orientation_record(camera, fit, x, vf.vertex, vf.cov, model="exact",
                               sigma_mean=float(np.sqrt(np.mean(s_n**2))))
    if C is not None:
        pivot = pivot.replace(**orientation_totals(
            camera, C, fit.R_cam_from_target, x, fit.cov, pivot.tilt_sigma_deg, pivot.vertex_cov_px2, seg[ks], a,
            angles[fr_idx], s_n, seg[k_in], st[k_in], sc[k_in]))
    return dataclasses.replace(out, pivot=pivot, pivot_frames=int(len(ks)))
