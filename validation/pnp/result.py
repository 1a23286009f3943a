"""The typed result of a board pose estimate (`PoseResult`) and the names of the methods.

`PoseResult.to_dict` is the pose part of a poses.json frame record: `poses_file.frame_record`
adds only the image name and the corner ids (and, with every method, their results), and
`poses_file.empty_frame_record` takes its keys from it. Conventions (pose, covariance) are
the package's: see `pencilcal.validation.pnp`.

Example
-------
>>> import numpy as np
>>> r = PoseResult(ok=True, method="sqpnp", R_cam_from_target=np.eye(3), t_cam_from_target=np.array([0, 0, 500.0]))
>>> r.distance, r.normal.tolist()
(500.0, [0.0, 0.0, 1.0])
>>> list(r.to_dict(residuals=False))[:4]
['ok', 'error', 'method', 'corners']
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from pencilcal.toolkit.geometry.frames import rotvec_from_rotation

__all__ = ["METHODS", "DEFAULT_METHOD", "PoseResult"]

#: Estimation methods, in the order `estimate_all` runs them.
METHODS = ("sqpnp", "ippe", "iterative", "epnp", "colmap")
DEFAULT_METHOD = "sqpnp"


@dataclass
class PoseResult:
    """One pose estimate of a target in a camera.

    Attributes
    ----------
    ok : bool
        False when no pose was found; then `error` says why and the pose fields are None.
    method : str
        One of `METHODS`.
    error : str or None
        Why there is no pose (one line).
    R_cam_from_target : (3, 3) ndarray or None
        Rotation, ``p_cam = R p_target + t``.
    t_cam_from_target : (3,) ndarray or None
        Translation [length unit of the object points].
    reproj_rms_px : float or None
        RMS of the per-corner reprojection error ``sqrt(mean |r_k|^2)`` [px].
    residuals_px : (K, 2) ndarray or None
        ``projected - observed`` raw pixels per corner, in the input order.
    cov : (6, 6) ndarray or None
        Covariance of (d_rot [rad], d_t [length]), rotation first; see the module doc.
    sigma_px : float or None
        Corner noise behind `cov` [px].
    sigma_from : {"given", "residuals"} or None
    corners : int
        Number of correspondences used.
    refined : bool
        Whether the LM refinement in raw pixels ran.
    lm_iterations : int
    refine_change_deg, refine_change : float or None
        How far the refinement moved the method's own pose: rotation [deg] and
        translation [length unit].
    flipped : bool
        True when the pose came from the planar twin of the method's own pose, i.e. the
        method returned the wrong one of a planar target's two near-solutions.
    alternative_rms_px, alternative_angle_deg : float or None
        The runner-up: IPPE's other solution, or (refined, planar targets) the planar
        twin; its RMS [px] and rotation angle from the chosen pose [deg]. An angle near 0
        means both converged to the same pose: no ambiguity left. A twin ruled out at its
        start (more than 10 times the pose's RMS) is reported there, unrefined.
    extra : dict
        Method-specific facts (``colmap_inliers``).
    time_s : float
        Wall time of the estimate [s].
    cov_total : (6, 6) ndarray or None
        The covariance with every modelled term, same convention as `cov`: correlated
        corner errors (when `correlated_corners_used`) and the intrinsics' uncertainty
        (when `intrinsics_used`); None when neither was given (`estimate_pose`).
    correlated_corners_used, intrinsics_used : bool
    intrinsics_sensitivity : (6, P) ndarray or None
        d(pose)/d(intrinsics) [rad or length per unit of each intrinsic, in
        `toolkit.camera.intrinsics.intrinsic_names` order] when `intrinsics_used`: a rig
        check needs it to tell what all frames of a camera share.
    """

    ok: bool
    method: str
    error: str | None = None
    R_cam_from_target: np.ndarray | None = None
    t_cam_from_target: np.ndarray | None = None
    reproj_rms_px: float | None = None
    residuals_px: np.ndarray | None = None
    cov: np.ndarray | None = None
    sigma_px: float | None = None
    sigma_from: str | None = None
    corners: int = 0
    refined: bool = False
    lm_iterations: int = 0
    refine_change_deg: float | None = None
    refine_change: float | None = None
    flipped: bool = False
    alternative_rms_px: float | None = None
    alternative_angle_deg: float | None = None
    extra: dict = field(default_factory=dict)
    time_s: float = 0.0
    cov_total: np.ndarray | None = None
    correlated_corners_used: bool = False
    intrinsics_used: bool = False
    intrinsics_sensitivity: np.ndarray | None = None

    @property
    def rvec(self):
        """(3,) rotation vector of R_cam_from_target [rad], as cv2.Rodrigues; None if not ok."""
        return None if self.R_cam_from_target is None else rotvec_from_rotation(self.R_cam_from_target)

    @property
    def tvec(self):
        """(3,) = t_cam_from_target (OpenCV's name); None if not ok."""
        return None if self.t_cam_from_target is None else self.t_cam_from_target.copy()

    @property
    def normal(self):
        """(3,) target z axis in the camera frame, R[:, 2] (points away from the camera)."""
        return None if self.R_cam_from_target is None else self.R_cam_from_target[:, 2].copy()

    @property
    def distance(self):
        """|t_cam_from_target|: distance of the target origin [length unit]."""
        return None if self.t_cam_from_target is None else float(np.linalg.norm(self.t_cam_from_target))

    @property
    def rotation_sigma_deg(self):
        """(3,) standard deviations of d_rot about the camera x, y, z axes [deg]."""
        return None if self.cov is None else np.degrees(np.sqrt(np.maximum(np.diag(self.cov)[:3], 0.0)))

    @property
    def translation_sigma(self):
        """(3,) standard deviations of t_cam_from_target along camera x, y, z [length unit]."""
        return None if self.cov is None else np.sqrt(np.maximum(np.diag(self.cov)[3:], 0.0))

    @property
    def normal_sigma_deg(self):
        """RMS angular error of `normal` [deg]: sqrt(trace(P C_rot P)), P = I - n n^T."""
        return self._normal_sigma_deg(self.cov)

    @property
    def rotation_sigma_total_deg(self):
        """(3,) as `rotation_sigma_deg`, from `cov_total`; None without it."""
        return None if self.cov_total is None else np.degrees(np.sqrt(np.maximum(np.diag(self.cov_total)[:3], 0.0)))

    @property
    def normal_sigma_total_deg(self):
        """As `normal_sigma_deg`, from `cov_total`; None without it."""
        return self._normal_sigma_deg(self.cov_total)

    def _normal_sigma_deg(self, cov):
        if cov is None:
            return None
        n = self.R_cam_from_target[:, 2]
        P = np.eye(3) - np.outer(n, n)
        return float(np.degrees(np.sqrt(max(np.trace(P @ cov[:3, :3] @ P), 0.0))))

    @classmethod
    def from_record(cls, rec):
        """The PoseResult of a poses.json frame record as `poses_file.read_board_poses` returns
        it (arrays as ndarrays): the pose, its covariances and their facts; the derived keys
        (rvec, normal, sigmas) are properties again."""
        names = {f for f in cls.__dataclass_fields__} - {"extra", "time_s"}
        kw = {k: rec[k] for k in names if k in rec and rec[k] is not None}
        kw.setdefault("method", rec.get("method") or DEFAULT_METHOD)
        return cls(**kw)

    def to_dict(self, residuals=True):
        """JSON-ready record of this estimate (numpy arrays are converted on writing): the
        pose keys of a poses.json frame, in the file's order, and each method's record
        under ``methods`` (there without the residuals).

        Keys: ok, error, method, corners, R_cam_from_target (3, 3), t_cam_from_target (3,)
        [length unit], rvec (3,) [rad], tvec (3,), normal (3,), distance [length unit],
        reproj_rms_px [px], cov (6, 6), sigma_px [px], sigma_from, rotation_sigma_deg (3,)
        [deg], translation_sigma (3,) [length unit], normal_sigma_deg [deg], cov_total (6, 6),
        rotation_sigma_total_deg (3,) [deg], normal_sigma_total_deg [deg],
        correlated_corners_used, intrinsics_used, intrinsics_sensitivity (6, P), flipped,
        alternative_rms_px [px], alternative_angle_deg [deg], refined, refine_change_deg
        [deg], refine_change [length unit], lm_iterations, the `extra` keys, and with
        `residuals` also residuals_px (K, 2) [px]. Pose keys are None when not ok.
        """
        d = {
            "ok": bool(self.ok), "error": self.error, "method": self.method, "corners": int(self.corners),
            "R_cam_from_target": self.R_cam_from_target, "t_cam_from_target": self.t_cam_from_target,
            "rvec": self.rvec, "tvec": self.tvec, "normal": self.normal, "distance": self.distance,
            "reproj_rms_px": self.reproj_rms_px, "cov": self.cov, "sigma_px": self.sigma_px,
            "sigma_from": self.sigma_from, "rotation_sigma_deg": self.rotation_sigma_deg,
            "translation_sigma": self.translation_sigma, "normal_sigma_deg": self.normal_sigma_deg,
            "cov_total": self.cov_total, "rotation_sigma_total_deg": self.rotation_sigma_total_deg,
            "normal_sigma_total_deg": self.normal_sigma_total_deg,
            "correlated_corners_used": bool(self.correlated_corners_used), "intrinsics_used": bool(self.intrinsics_used),
            "intrinsics_sensitivity": self.intrinsics_sensitivity,
            "flipped": bool(self.flipped), "alternative_rms_px": self.alternative_rms_px,
            "alternative_angle_deg": self.alternative_angle_deg,
            "refined": bool(self.refined), "refine_change_deg": self.refine_change_deg,
            "refine_change": self.refine_change, "lm_iterations": int(self.lm_iterations),
        }
        d.update(self.extra)
        if residuals:
            d["residuals_px"] = self.residuals_px
        return d

