"""Aligning a reconstruction to the board frame: robust rotation averaging and similarity.

A reconstruction (pycolmap) gives ``R_cam_from_world`` per frame in its own, arbitrary world
frame; board PnP gives ``R_cam_from_target`` for the same frames. Their relation
``R_cam_from_target = R_cam_from_world @ R_world_from_target`` holds for every frame with one
constant ``R_world_from_target``, so each frame votes for it with
``R_world_from_target_i = R_cam_from_world_i^T @ R_cam_from_target_i``. The vote is averaged
robustly: the geodesic L1 mean (Weiszfeld's algorithm on SO(3), Hartley et al., "L1 rotation
averaging using the Weiszfeld algorithm", CVPR 2011), which a few bad PnP poses cannot pull.

Camera centres then fix scale and translation: a similarity ``x_target = s R x_world + t``
(Umeyama's closed form, inside a RANSAC loop over minimal triples).

Example
-------
>>> import numpy as np
>>> from pencilcal.toolkit.geometry.frames import rotation_from_rotvec, rotation_angle
>>> rng = np.random.default_rng(0)
>>> R_wt = rotation_from_rotvec([0.3, -0.2, 1.0])
>>> R_cw = rotation_from_rotvec(rng.normal(size=(20, 3)))
>>> R_ct = R_cw @ R_wt
>>> R_ct[3] = rotation_from_rotvec([2.0, 0, 0])          # one wild PnP pose
>>> est, inl = align_rotations(R_cw, R_ct)
>>> bool(np.degrees(rotation_angle(est, R_wt)) < 1e-9), int(inl.sum())
(True, 19)
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pencilcal.toolkit.errors import EstimationError
from pencilcal.toolkit.geometry.frames import project_to_rotation, rotation_from_rotvec, rotvec_from_rotation

__all__ = ["l1_rotation_mean", "align_rotations", "Similarity", "umeyama", "align_similarity"]


def l1_rotation_mean(R, max_iter=100, tol=1e-12):
    """Geodesic L1 mean of rotations (Weiszfeld). R: (N, 3, 3) -> (3, 3).

    Starts at the chordal L2 mean and steps by the weighted mean of the log maps with
    weights 1 / angle, the fixed point of which minimises sum_i angle(R, R_i).
    """
    R = np.asarray(R, float)
    if R.ndim != 3 or R.shape[0] == 0:
        raise EstimationError("no rotations to average")
    M = project_to_rotation(R.mean(0))
    for _ in range(max_iter):
        v = rotvec_from_rotation(np.swapaxes(M, -1, -2)[None] @ R)
        ang = np.linalg.norm(v, axis=-1)
        w = 1.0 / np.maximum(ang, 1e-12)
        step = (w[:, None] * v).sum(0) / w.sum()
        M = M @ rotation_from_rotvec(step)
        if np.linalg.norm(step) < tol:
            break
    return M


def align_rotations(R_cam_from_world, R_cam_from_target, inlier_deg=2.0):
    """Robust R_world_from_target from per-frame pairs.

    R_cam_from_world, R_cam_from_target: (N, 3, 3) for the same frames. Returns
    (R_world_from_target (3, 3), inliers (N,) bool: frames whose vote is within
    `inlier_deg` of the L1 mean). The mean is recomputed on the inliers.
    """
    from pencilcal.toolkit.geometry.frames import rotation_angle

    Rcw = np.asarray(R_cam_from_world, float)
    Rct = np.asarray(R_cam_from_target, float)
    votes = np.swapaxes(Rcw, -1, -2) @ Rct
    M = l1_rotation_mean(votes)
    inl = np.degrees(rotation_angle(votes, M[None])) <= inlier_deg
    if inl.sum() >= 1:
        M = l1_rotation_mean(votes[inl])
        inl = np.degrees(rotation_angle(votes, M[None])) <= inlier_deg
    return M, inl


@dataclass(frozen=True)
class Similarity:
    """x_target = scale * R_target_from_world @ x_world + t_target_from_world."""

    scale: float
    R_target_from_world: np.ndarray
    t_target_from_world: np.ndarray

    def apply(self, x):
        """x: (..., 3) world points -> (..., 3) target points."""
        return self.scale * np.asarray(x, float) @ self.R_target_from_world.T + self.t_target_from_world


def umeyama(src, dst):
    """Least-squares similarity dst ~ s R src + t (Umeyama 1991). src, dst: (N, 3), N >= 3."""
    src = np.asarray(src, float)
    dst = np.asarray(dst, float)
    ms, md = src.mean(0), dst.mean(0)
    a, b = src - ms, dst - md
    var = (a * a).sum() / len(src)
    if var <= 0:
        raise EstimationError("the points coincide: no similarity")
    U, S, Vt = np.linalg.svd(b.T @ a / len(src))
    D = np.eye(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:
        D[2, 2] = -1
    R = U @ D @ Vt
    s = float(np.trace(np.diag(S) @ D) / var)
    return Similarity(s, R, md - s * R @ ms)


def align_similarity(centres_world, centres_target, inlier_ratio=0.05, trials=300, seed=0):
    """Robust similarity from camera centres in both frames.

    centres_world, centres_target: (N, 3). A triple's similarity is scored by the centres
    within `inlier_ratio` of the scene's spread (median distance of the target centres from
    their median); the best is refitted on its inliers. Returns (Similarity, inliers (N,)).
    """
    cw = np.asarray(centres_world, float)
    ct = np.asarray(centres_target, float)
    n = len(cw)
    if n < 3:
        raise EstimationError(f"a similarity needs at least three camera centres, got {n}")
    spread = np.median(np.linalg.norm(ct - np.median(ct, 0), axis=1))
    thr = max(inlier_ratio * spread, 1e-12)
    rng = np.random.default_rng(seed)
    best, best_n = None, -1
    for _ in range(trials):
        idx = rng.choice(n, 3, replace=False)
        try:
            S = umeyama(cw[idx], ct[idx])
        except (EstimationError, np.linalg.LinAlgError):
            continue
        inl = np.linalg.norm(S.apply(cw) - ct, axis=1) < thr
        if inl.sum() > best_n:
            best, best_n = inl, int(inl.sum())
    if best is None or best_n < 3:
        raise EstimationError("no similarity explains three or more camera centres")
    S = umeyama(cw[best], ct[best])
    inl = np.linalg.norm(S.apply(cw) - ct, axis=1) < thr
    return umeyama(cw[inl], ct[inl]) if inl.sum() >= 3 else S, inl
