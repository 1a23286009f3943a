"""The 3-D fulcrum from two calibrated views of one pivot (a stereo endoscope).

Each view's fulcrum ray comes from its own frames (`fulcrum.fulcrum_from_frames`); with the
rig (`camera.stereo.StereoRig`, the right camera's pose from the left's) the two rays meet at
the 3-D fulcrum (`stereo_fulcrum`: `cylinder.triangulate_rays`), in the left camera frame.
Where the left view has its diameter-based point, the two are fused and tested for agreement
(`cylinder.combine_estimates`); the port's play that both views see alike is carried as a
shared term (`stereo_play`), and the intrinsics' error as `triangulation_lens_cov`.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from pencilcal.toolkit.errors import EstimationError
from pencilcal.toolkit.geometry.frames import rotation_from_rotvec
from pencilcal.toolkit.geometry.quantiles import chi2_sf
from pencilcal.toolkit.pencil.cylinder import (GATE_CONFIDENCE, Fusion, RayTriangulation, combine_estimates,
                                               triangulate_rays)
from pencilcal.toolkit.pencil.fulcrum import Fulcrum
from pencilcal.toolkit.pencil.stereo_play import (cross_term, play_covariance, play_cross_cov, shared_offset_term,
                                                   shared_ray_cov)

__all__ = ["StereoFulcrum", "stereo_fulcrum", "triangulation_lens_cov", "triangulation_rig_cov"]


_RIGHT_KEYS = ("vertex_px", "vertex_cov_px2", "ray", "ray_cov", "ray_sigma_deg", "lines_used", "outliers",
               "frames_used", "rms", "lines_from", "ray_cov_total", "ray_sigma_total_deg", "vertex_cov_total_px2",
               "intrinsics_used", "play")


@dataclass(frozen=True, eq=False)
class StereoFulcrum:
    """The 3-D fulcrum from two views (`stereo_fulcrum`), in the left camera frame, lengths in
    the unit of the rig's translation.

    rig: the `camera.stereo.StereoRig`; right: the right view's `Fulcrum` (its ray in the
    right camera frame); triangulated: the `cylinder.RayTriangulation` of the two fulcrum
    rays; combined: with the left view's diameter-based point, the `cylinder.Fusion` of it
    and the triangulated point (its chi2 the agreement test, 3 dof), else None; shared:
    whether the fusion counted the left ray once (False: the shared information exceeded
    the diameter point's, the two were fused as independent). lens_cov (3, 3): the
    intrinsics' term of the triangulated point's covariance (`triangulation_lens_cov`)
    from the views in lens_views ("left", "right": those whose camera carried an
    intrinsics covariance), None when neither did. common_cov (3, 3): the 3-D offset both
    views' rays share (`play_covariance`), in the triangulated and the combined point's
    covariances whole. rig_cov (3, 3): the rig calibration's term of the triangulated
    point's covariance (`triangulation_rig_cov`), in it and in the combined point's as
    much as the fusion took from the triangulated point; None when the rig has no
    covariance. paired: `stereo_play.play_cross_cov`'s record (``pairs``, ``sigma_px``) of
    the lines both views fitted in the same frames.
    """

    rig: object
    right: Fulcrum
    triangulated: RayTriangulation
    combined: Fusion | None = None
    shared: bool = True
    confidence: float = GATE_CONFIDENCE
    lens_cov: np.ndarray | None = None
    lens_views: tuple = ()
    common_cov: np.ndarray | None = None
    rig_cov: np.ndarray | None = None
    paired: dict | None = None

    def to_dict(self) -> dict:
        """fulcrum.json's ``stereo`` record: the rig (``file``, ``R_right_from_left``,
        ``t_right_from_left``, ``baseline``), ``right`` (the right view's fulcrum keys),
        ``triangulated`` (``point``, ``point_cov``, ``point_sigma``, ``ranges``,
        ``ray_distances``, ``chi2``, ``dof``, ``p_value``; ``point_cov_shared``; ``paired_lines``,
        ``shared_offset_px`` and ``own_offset_px`` (`stereo_play.play_cross_cov`); with the rig's
        covariance ``point_cov_rig``; with the intrinsics' covariance
        of either camera also ``point_cov_total``, ``point_sigma_total``, ``intrinsics_used``
        and ``intrinsics_views``) and with the diameter ``agreement``
        (``chi2``, ``dof``, ``p_value``, ``threshold``, ``confidence``, ``consistent``,
        ``shared_left_ray``) and ``combined`` (``point``, ``point_cov``, ``point_sigma``)."""
        rec = self.right.to_dict()
        t = self.triangulated
        out = {**self.rig.to_dict(), "right": {k: rec[k] for k in _RIGHT_KEYS if k in rec}}
        out["triangulated"] = {"point": np.asarray(t.point, float).tolist(),
                               "point_cov": np.asarray(t.point_cov, float).tolist(),
                               "point_sigma": float(t.point_sigma), "ranges": np.asarray(t.ranges, float).tolist(),
                               "ray_distances": np.asarray(t.distances, float).tolist(), "chi2": float(t.chi2),
                               "dof": 1, "p_value": chi2_sf(float(t.chi2), 1)}
        if self.common_cov is not None:
            out["triangulated"]["point_cov_shared"] = np.asarray(self.common_cov, float).tolist()
        if self.paired is not None:
            out["triangulated"]["paired_lines"] = int(self.paired["pairs"])
            out["triangulated"]["shared_offset_px"] = self.paired["sigma_px"]
            out["triangulated"]["own_offset_px"] = self.paired.get("own_sd_px")
        if self.rig_cov is not None:
            out["triangulated"]["point_cov_rig"] = np.asarray(self.rig_cov, float).tolist()
        if self.lens_cov is not None:
            total = np.asarray(t.point_cov, float) + np.asarray(self.lens_cov, float)
            out["triangulated"].update({"point_cov_total": total.tolist(),
                                        "point_sigma_total": float(np.sqrt(max(np.trace(total), 0.0))),
                                        "intrinsics_used": True, "intrinsics_views": list(self.lens_views)})
        c = self.combined
        if c is not None:
            out["agreement"] = {"chi2": float(c.chi2), "dof": int(c.dof), "p_value": float(c.p_value),
                                "threshold": float(c.threshold), "confidence": float(self.confidence),
                                "consistent": bool(c.consistent), "shared_left_ray": bool(self.shared)}
            out["combined"] = {"point": np.asarray(c.point, float).tolist(),
                               "point_cov": np.asarray(c.cov, float).tolist(), "point_sigma": float(c.sigma)}
        return out


def triangulation_lens_cov(tri, lens_left, lens_right):
    """(3, 3) the intrinsics' term of a triangulated point's covariance (left camera frame).

    tri: the `cylinder.RayTriangulation` of two rays; lens_left, lens_right: (3, 3) the
    intrinsics' term of each unit ray's covariance (`Fulcrum.ray_cov_lens`; the right one
    in the left camera frame, ``R^T C R``), or None where that camera has none. The point
    is the weighted least-squares meeting of the rays, ``x = H^-1 sum_k I_k c_k`` with I_k
    the ray's information (`RayTriangulation.ray_information`) and H their sum; turning
    ray k by d moves its offset from x by its range rho_k times d, and x by
    ``H^-1 I_k rho_k d``. The rays' lens errors (independent cameras) then add
    ``H^-1 (sum_k rho_k^2 I_k C_k I_k) H^-1``; with a ray's noise covariance in place of
    C_k the same sum is H^-1, the noise-only covariance.
    """
    # the rays' own information: point_cov may hold an offset both rays share (`stereo_fulcrum`)
    H_inv = np.linalg.inv(np.sum(np.asarray(tri.ray_information, float), axis=0))
    M = np.zeros((3, 3))
    for k, C in enumerate((lens_left, lens_right)):
        if C is not None:
            I_k = np.asarray(tri.ray_information, float)[k]
            M += float(tri.ranges[k]) ** 2 * I_k @ np.asarray(C, float) @ I_k
    out = H_inv @ M @ H_inv
    return 0.5 * (out + out.T)


def triangulation_rig_cov(ray_left, cov_left, ray_right, cov_right, rig, step=1e-6):
    """(3, 3) [length^2] the rig calibration's term of a triangulated point's covariance
    (left camera frame), or None where the rig has no covariance.

    ray_left, cov_left, ray_right, cov_right: as `cylinder.triangulate_rays` takes them (the
    right ray in the right camera frame); rig: the `camera.stereo.StereoRig`, its ``cov``
    (6, 6) that of the rotation vector w [rad] (``R = exp(w) R_right_from_left``) and the
    translation [length]. A rig error moves the right ray in the left frame: it shifts the
    point's depth (the disparity) and its across-sight position by ``J cov J^T``, J (3, 6)
    the point's derivative by (w, t), here by central differences of `triangulate_rays`
    (steps of `step` rad and `step` times the baseline). The left view's diameter-based
    point holds none of it: in a fusion it is the triangulated point's own error.
    """
    if getattr(rig, "cov", None) is None:
        return None
    R, t = np.asarray(rig.R_right_from_left, float), np.asarray(rig.t_right_from_left, float)
    J = np.zeros((3, 6))
    for k in range(6):
        h = step if k < 3 else step * max(rig.baseline, 1e-12)
        moved = []
        for sign in (1.0, -1.0):
            e = np.zeros(3)
            e[k % 3] = sign * h
            Rk, tk = (rotation_from_rotvec(e) @ R, t) if k < 3 else (R, t + e)
            moved.append(np.asarray(triangulate_rays(ray_left, cov_left, ray_right, cov_right, Rk, tk).point, float))
        J[:, k] = (moved[0] - moved[1]) / (2.0 * h)
    out = J @ np.asarray(rig.cov, float) @ J.T
    return 0.5 * (out + out.T)


def stereo_fulcrum(left, right, rig, confidence=GATE_CONFIDENCE, pairs=None):
    """The 3-D fulcrum from the fulcrum rays of two calibrated views of one pivot.

    left, right: the `Fulcrum` of each view (`fulcrum_from_frames` on its own frames; the
    right's ray in the right camera frame), each with its ray covariance
    (`Fulcrum.ray_covariance`); rig: the `camera.stereo.StereoRig` (``p_right =
    R_right_from_left p_left + t_right_from_left``). The point is the weighted least-squares
    meeting of the two rays (`cylinder.triangulate_rays`: each ray's angular covariance
    times its range, iterated), in the left camera frame and the rig's length unit, with
    its covariance and the chi2 (1 dof) of the rays' miss. Where both views' lines are
    shaft midlines of the same frames the point's covariance gains the rays' cross terms
    read from those pairs (`play_cross_cov`, `cross_term`: the offset a frame's shaft has in
    both views, along the line of sight and across it). Otherwise the rays meet with their own
    parts (what their lines' sigmas give) and the point's covariance gains what the 3-D
    offset both rays share adds across the line of sight (`play_covariance`: the scatter
    beyond the lines' sigmas, which the instrument's play in its port gives both views
    alike; `shared_offset_term`: the two rays do not halve it), and, where the rig carries
    its calibration's covariance, what that error moves the point by
    (`triangulation_rig_cov`: mostly its depth, through the disparity).

    When `left` has its diameter-based point (`FulcrumPoint`, lengths in the diameter's
    unit, which must be the rig's), the two are compared and fused
    (`cylinder.combine_estimates`): both hold the left view's midlines (the diameter-based
    axes lie in their planes; the triangulation holds their intersection, the left ray),
    so the left ray's information (`RayTriangulation.ray_information`) is passed as
    shared: the agreement chi2 (2 dof where the component that only the left ray holds
    drops out, else 3) then tests the depth from the shaft's width against the depth from
    the baseline and the right view, and the fusion counts the left ray once; the shared
    offset is passed as ``common`` (an error both carry: the port's play moves the
    diameter-based point as it moves the rays), so the fused covariance does not average
    it. The test takes that offset out of both covariances, so the left ray it counts once
    there is the one of its lines' own sigmas (``shared_own``). confidence: of the
    agreement test. pairs: [(i, j)] the left frame i taken with the right frame j
    (`camera.stereo.pair_frames`), None: the same index in both. With either view's
    intrinsics' term
    (`Fulcrum.ray_cov_lens`, the camera file's intrinsics covariance) the triangulated
    point's covariance gains it too (`triangulation_lens_cov`, ``StereoFulcrum.lens_cov``);
    the agreement and the fusion's weights leave it out (the diameter-based point has no
    intrinsics term, nor its width term); they take the rig's term, which is the
    triangulated point's alone. The diameter-based point is weighed by the covariance it
    reports but the width term: its fit's with the port's play its image lines read beyond
    its axes' (`FulcrumPoint.play_cov`, across the line of sight). The width term
    (`FulcrumPoint.width_cov`: the band width's error the sequence shares, which sets the
    depth the diameter gives) joins the combined point's covariance after the fusion, as
    much of it as the point took from the diameter (``unweighted1``: ``W1 width_cov W1^T``);
    the point stays the one the weights give. Returns a
    `StereoFulcrum`; EstimationError when a ray has no covariance, the rays are parallel or
    meet behind a camera.
    """
    Cl, Cr = left.ray_covariance(), right.ray_covariance()
    if Cl is None or Cr is None:
        raise EstimationError("the stereo fulcrum needs each view's ray covariance")
    R, t = rig.R_right_from_left, rig.t_right_from_left
    tri = triangulate_rays(left.ray, Cl, right.ray, Cr, R, t)
    common = play_covariance(tri, shared_ray_cov(left), R.T @ shared_ray_cov(right) @ R)
    # the frames both views fitted give the rays' cross-covariance line by line; without
    # them, the excess each view's lines read is taken as shared, across the line of sight
    X, paired = play_cross_cov(left, right, R, pairs)
    cov = tri.point_cov + (shared_offset_term(tri, common) if X is None else cross_term(tri, X))
    # the rig's calibration error is the triangulated point's own (the diameter-based point
    # holds none of it): in its covariance, the fusion's weights and the agreement test
    rig_cov = triangulation_rig_cov(left.ray, Cl, right.ray, Cr, rig)
    if rig_cov is not None:
        cov = cov + rig_cov
    tri = dataclasses.replace(tri, point_cov=cov, point_sigma=np.sqrt(np.trace(cov)))
    if np.any(~(np.asarray(tri.ranges) > 0)):
        raise EstimationError("the two views' fulcrum rays meet behind a camera (ranges {:.3g}, {:.3g}): check the "
                              "stereo file's R and T (right from left)".format(*np.asarray(tri.ranges, float)))
    lens = {"lens_cov": None, "lens_views": tuple(v for v, f in (("left", left), ("right", right))
                                                  if f.ray_cov_lens is not None)}
    if lens["lens_views"]:
        lens["lens_cov"] = triangulation_lens_cov(tri, left.ray_cov_lens, None if right.ray_cov_lens is None
                                                  else R.T @ np.asarray(right.ray_cov_lens, float) @ R)
    if left.point is None:
        return StereoFulcrum(rig, right, tri, confidence=confidence, common_cov=common, rig_cov=rig_cov, paired=paired,
                             **lens)
    fit = left.point.fit
    # the diameter-based point's covariance as it reports it but the width term (unweighted
    # below): the fit's with the play its image lines read beyond the axes' (`play_cov`);
    # the fit's alone made it up to 3 times surer across the line of sight than it says
    C1 = np.asarray(fit.point_cov, float)
    if left.point.play_cov is not None:
        C1 = C1 + np.asarray(left.point.play_cov, float)
    shared = True
    # the test takes the common offset out of both covariances: the left ray it cancels is
    # then the one of its lines' own sigmas, more informative than the ray with the offset
    own = triangulate_rays(left.ray, Cl - shared_ray_cov(left), right.ray, Cr - shared_ray_cov(right), R, t)
    try:
        fused = combine_estimates(fit.point, C1, tri.point, tri.point_cov, confidence,
                                  shared=(tri.ray_information[0], tri.ray_information_vector[0]), common=common,
                                  shared_own=(own.ray_information[0], own.ray_information_vector[0]),
                                  unweighted1=left.point.width_cov)
    except EstimationError:
        shared = False
        fused = combine_estimates(fit.point, C1, tri.point, tri.point_cov, confidence, common=common,
                                  unweighted1=left.point.width_cov)
    return StereoFulcrum(rig, right, tri, fused, shared, confidence, common_cov=common, rig_cov=rig_cov, paired=paired,
                         **lens)

