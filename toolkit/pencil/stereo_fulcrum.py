"""The 3-D fulcrum from two calibrated views of one pivot (a stereo endoscope).

Each view's fulcrum ray comes from its own frames (`fulcrum.fulcrum_from_frames`); with the
rig (`camera.stereo.StereoRig`, the right camera's pose from the left's) the two rays meet at
the 3-D fulcrum (`stereo_fulcrum`: `cylinder.triangulate_rays`), in the left camera frame.
Where the left view has its diameter-based point, the two are fused as correlated estimates
(`gls_fusion`: the generalised least-squares mean, with the error they share across the line
of sight, `shared_across`, as their cross-covariance) and tested for agreement; the port's
play that both views see alike is carried as a shared term (`stereo_play`), and the
intrinsics' error as `triangulation_lens_cov`.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from pencilcal.toolkit.errors import EstimationError
from pencilcal.toolkit.geometry.frames import rotation_from_rotvec
from pencilcal.toolkit.geometry.quantiles import chi2_isf, chi2_sf
from pencilcal.toolkit.pencil.cylinder import (GATE_CONFIDENCE, Fusion, RayTriangulation, shared_difference_chi2,
                                               triangulate_rays)
from pencilcal.toolkit.pencil.fulcrum import Fulcrum
from pencilcal.toolkit.pencil.stereo_play import (cross_term, play_covariance, play_cross_cov, shared_offset_term,
                                                   shared_ray_cov)

__all__ = ["StereoFulcrum", "stereo_fulcrum", "triangulation_lens_cov", "triangulation_rig_cov",
           "gls_fusion", "shared_across", "CROSS_MARGIN"]

#: The largest correlation the fusion lets the two points' errors have along any pair of
#: directions (`gls_fusion`): their cross-covariance is scaled down to it where the model's
#: would make the pair's joint covariance singular or indefinite.
CROSS_MARGIN = 0.8


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
    and the triangulated point (`gls_fusion`; its chi2 the agreement test), else None;
    shared: the share of the error both points carry across the line of sight
    (`shared_across`) that the fusion took as their cross-covariance (1: whole; less where
    it would make the two correlated beyond `CROSS_MARGIN`); inflation: what the fused
    covariance was multiplied by because the two disagree (chi2 / dof; 1: they agree).
    lens_cov (3, 3): the intrinsics' term of the triangulated point's covariance (`triangulation_lens_cov`)
    from the views in lens_views ("left", "right": those whose camera carried an
    intrinsics covariance), None when neither did. common_cov (3, 3): the 3-D offset both
    views' rays share (`play_covariance`), in the triangulated and the combined point's
    covariance whole. rig_cov (3, 3): the rig calibration's term of the triangulated
    point's covariance (`triangulation_rig_cov`), in it and so in the combined point's
    weight and covariance; None when the rig has no
    covariance. paired: `stereo_play.play_cross_cov`'s record (``pairs``, ``sigma_px``) of
    the lines both views fitted in the same frames.
    """

    rig: object
    right: Fulcrum
    triangulated: RayTriangulation
    combined: Fusion | None = None
    shared: float = 1.0
    confidence: float = GATE_CONFIDENCE
    lens_cov: np.ndarray | None = None
    lens_views: tuple = ()
    common_cov: np.ndarray | None = None
    rig_cov: np.ndarray | None = None
    paired: dict | None = None
    inflation: float = 1.0

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
        ``shared_left_ray``, ``left_ray_share``: `shared`, ``inflation``) and ``combined``
        (``point``, ``point_cov``, ``point_sigma``)."""
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
                                "consistent": bool(c.consistent), "shared_left_ray": bool(self.shared > 0),
                                "left_ray_share": float(self.shared), "inflation": float(self.inflation)}
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


def shared_across(x, C1, C2):
    """(3, 3) the cross-covariance of two estimates of the point x (3,) (left camera frame)
    whose errors across its line of sight are one: the smaller of their covariances there.

    Across the line of sight C1 and C2 (3, 3) are turned into their common eigenvectors
    (those of C1 whitened by C2, ``C1 v = lam C2 v``); along each the shared error has the
    smaller variance (min(lam, 1) in C2's units): the estimate that is surer there holds
    that error and no more, the other holds it and its own besides. Along the line of
    sight they share nothing.

    >>> K = shared_across([0.0, 0, 100], np.diag([1.0, 4, 9]), np.diag([2.0, 3, 1]))
    >>> np.round(K, 6).tolist()
    [[1.0, 0.0, 0.0], [0.0, 3.0, 0.0], [0.0, 0.0, 0.0]]
    """
    u = np.asarray(x, float) / np.linalg.norm(x)
    B = np.linalg.svd(np.eye(3) - np.outer(u, u))[0][:, :2]    # (3, 2) across the line of sight
    A1, A2 = B.T @ np.asarray(C1, float) @ B, B.T @ np.asarray(C2, float) @ B
    L = np.linalg.cholesky(A2)
    W = np.linalg.inv(L)
    lam, V = np.linalg.eigh(W @ A1 @ W.T)
    M = L @ V
    K = B @ (M * np.minimum(lam, 1.0)) @ M.T @ B.T
    return 0.5 * (K + K.T)


def gls_fusion(x1, C1, x2, C2, C12, confidence=GATE_CONFIDENCE, margin=None):
    """(Fusion, share, inflation): the generalised least-squares mean of two correlated
    estimates of one point, and their consistency test.

    x1, x2: (n,) the estimates; C1, C2: (n, n) their covariances; C12: (n, n) ``E[e1 e2^T]``
    (`shared_across`). The joint covariance ``S = [[C1, C12], [C12^T, C2]]`` gives the
    point ``F A^T S^-1 [x1; x2]`` with ``F = (A^T S^-1 A)^-1`` (A = [1; 1]), its covariance F,
    never larger than C1 or C2 along any direction (each alone is one of the means it
    minimises over). C12 is scaled by share (up to 1) so that the whitened cross-covariance
    ``C1^-1/2 C12 C2^-T/2`` has singular values at most `margin` (`CROSS_MARGIN` when None):
    near 1, the mean would lean on the model's correlation and reach beyond both estimates.
    The test: ``d = x1 - x2``, ``cov_d = C1 + C2 - C12 - C12^T`` (the model's C12 whole: the
    margin guards the mean, and a scaled C12 would give d a variance it has not); the
    components whose share of their variance in C1 + C2 is under `cylinder.SHARED_FLOOR` (the
    two the same there) are left out, dof counts the others; chi2 = d^T cov_d^-1 d on them. Where chi2 exceeds its
    quantile at `confidence` the two disagree beyond their covariances and F is scaled by
    inflation = chi2 / dof (else 1): only then is it larger than an input's.

    >>> f, share, k = gls_fusion([0.0, 0, 100], np.eye(3), [0.0, 0, 102], np.eye(3), np.zeros((3, 3)))
    >>> f.point.tolist(), float(f.chi2), f.dof, share, k
    ([0.0, 0.0, 101.0], 2.0, 3, 1.0, 1.0)
    >>> f, _, _ = gls_fusion([0.0, 0, 100], np.eye(3), [0.0, 0, 102], 4 * np.eye(3), 0.5 * np.eye(3))
    >>> np.round(np.diag(f.cov), 4).tolist()                 # correlated: less than (1/1 + 1/4)^-1 = 0.8
    [0.9375, 0.9375, 0.9375]
    """
    margin = CROSS_MARGIN if margin is None else margin
    x1, x2 = np.asarray(x1, float), np.asarray(x2, float)
    C1, C2, C12 = (np.asarray(c, float) for c in (C1, C2, C12))
    n = x1.shape[-1]
    L1, L2 = np.linalg.cholesky(C1), np.linalg.cholesky(C2)
    s = float(np.linalg.svd(np.linalg.solve(L1, np.linalg.solve(L2, C12.T).T), compute_uv=False)[0])
    share = 1.0 if s <= margin else margin / s
    S = np.block([[C1, share * C12], [share * C12.T, C2]])
    A = np.vstack([np.eye(n), np.eye(n)])
    SiA = np.linalg.solve(S, A)
    F = np.linalg.inv(A.T @ SiA)
    F = 0.5 * (F + F.T)
    W = F @ SiA.T                                               # (n, 2n): the weights of x1, x2
    point = W @ np.concatenate([x1, x2])
    c2, dof = shared_difference_chi2(x1 - x2, C1 + C2 - C12 - C12.T, C1 + C2)
    c2, dof = float(c2), int(dof)
    threshold = chi2_isf(1.0 - confidence, dof) if dof else 0.0
    consistent = c2 <= threshold
    inflation = 1.0 if consistent or not dof else c2 / dof
    cov = F * inflation
    fused = Fusion(point=point, cov=cov, sigma=float(np.sqrt(np.trace(cov))), chi2=c2, dof=dof, threshold=threshold,
                   consistent=consistent, p_value=chi2_sf(c2, dof) if dof else 1.0)
    return fused, share, inflation


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
    unit, which must be the rig's), the two are compared and fused as correlated estimates
    (`gls_fusion`), each weighed by the whole covariance it reports (the diameter-based
    point's with its width and play terms, the triangulated point's with the rig's). Both
    hold the left view's midlines (the diameter-based axes lie in their planes; the
    triangulation holds their intersection, the left ray) and the port's play those lines
    read: across the line of sight their errors are one, and their cross-covariance is that
    error's, the smaller of their two covariances there (`shared_across`); along it the
    diameter's depth and the disparity's are each one's own. The fused covariance is then
    never larger than either point's along any direction, unless their agreement test
    fails at `confidence` (its chi2, on the components in which they differ); then it is
    scaled by chi2 / dof and says so (``StereoFulcrum.inflation``). pairs: [(i, j)] the
    left frame i taken with the right frame j (`camera.stereo.pair_frames`), None: the same
    index in both. With either view's intrinsics' term (`Fulcrum.ray_cov_lens`, the camera
    file's intrinsics covariance) the triangulated point's covariance gains it too
    (`triangulation_lens_cov`, ``StereoFulcrum.lens_cov``); the agreement and the fusion
    leave it out (the diameter-based point has no intrinsics term). Returns a
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
    # across the line of sight both points hold the left ray and the port's play it reads:
    # one error, which their mean does not average (`shared_across`); along it the diameter's
    # depth and the disparity's are each one's own
    C1, C2 = np.asarray(left.point.cov, float), np.asarray(tri.point_cov, float)
    fused, share, inflation = gls_fusion(left.point.fit.point, C1, tri.point, C2, shared_across(tri.point, C1, C2),
                                         confidence)
    return StereoFulcrum(rig, right, tri, fused, share, confidence, common_cov=common, rig_cov=rig_cov, paired=paired,
                         inflation=inflation, **lens)

