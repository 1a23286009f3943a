"""The camera's 3-D motion over a sequence, measured on the background: every frame's pose
in the reference frame's camera, up to one scale for the whole sequence
(`pencilcal fulcrum --stabilize` with --shaft-diameter).

A homography (`background_motion`) takes out a camera that turns; an endoscope moved about
its port also translates (along its axis: the background's scale changes), and a 3-D axis
then lives in its own frame's camera. Here each frame's pose comes from the same matches to
the reference frame's features (undistorted px, off the instrument):

1. *relative poses*: per frame the essential matrix to the reference by RANSAC
   (`RANSAC_PX`) and its decomposition (cv2.recoverPose): a rotation and the direction of
   the translation;
2. *the map*: the frame whose inliers see the background under the largest median parallax
   (at least `MIN_PARALLAX_DEG`) is the anchor; the reference's features it matches are
   triangulated with a baseline of one (the map's unit) where their parallax is at least
   `MAP_PARALLAX_DEG`;
3. *poses*: every frame (the anchor too) by PnP on the map points it matches (RANSAC, then
   Levenberg-Marquardt in undistorted px), so that all translations share the map's unit;
   each frame posed adds its own matches to the map (triangulated with its pose, the same
   parallax), and the frames the map did not reach are tried again (`MAP_ROUNDS`);
4. *bundle adjustment*: the map and every posed frame refined together, each map point on
   its reference ray at an inverse depth, the reprojection errors of all frames (soft L1 at
   1 px; the matches within 1.5 `BUNDLE_INLIER_PX` of the start), the scale's gauge held
   by the anchor's |t|. Its covariance is ``s^2 S^-1`` with
   S the normal matrix's Schur complement on the poses over the inliers (within
   `BUNDLE_INLIER_PX`) and ``s^2`` their residual variance: the map's noise is in each
   pose's covariance (not the poses' correlations through it). Each frame's 6 x 6 block
   is carried to ``(rotation vector of a left turn of R_frame_from_ref,
   t_frame_from_ref)``. The anchor's pose is tried from the essential matrix and from each
   decomposition of its homography (the essential matrix of a few matches, or of a flat
   background, is easily wrong), and the map that poses most frames with the most matches
   within `BUNDLE_INLIER_PX` is kept.

Poses are named by their frames as in COLMAP (X_a = R_a_from_b X_b + t_a_from_b, a frame's
camera from the reference's as COLMAP's cam_from_world): the essential matrix, PnP, the map,
the bundle and every `FramePose` hold R_frame_from_ref, t_frame_from_ref;
`pencil.moving_fulcrum` carries a frame's axis into the reference camera by its inverse.

The map's unit is not a length: the 3-D fulcrum fits it (mm per map unit) with the point,
from the shafts' metric depths (`pencil.moving_fulcrum`). Where no frame has the parallax
(the camera only turned, or stood still) the poses are the homographies' rotations
(``R = polar(K^-1 H K)``) with no translation (``model`` "rotation"). Not modelled: the
reference frame's feature noise (its rays are held), and the poses' correlations through
the shared map.

>>> import numpy as np
>>> K = np.array([[800.0, 0, 480], [0, 800, 270], [0, 0, 1]])
>>> R, cov = rotation_from_homography(K @ np.eye(3) @ np.linalg.inv(K), np.zeros((8, 8)), K)
>>> np.allclose(R, np.eye(3)), cov.shape
(True, (3, 3))
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pencilcal.toolkit.geometry.frames import rotation_from_rotvec

__all__ = ["FramePose", "background_poses", "rotation_from_homography", "pose_left_cov", "MIN_PARALLAX_DEG",
           "MAP_PARALLAX_DEG", "MIN_MAP_POINTS"]

#: RANSAC's inlier threshold [undistorted px] of the essential matrix and of PnP.
RANSAC_PX = 1.5
#: The least median parallax [deg] of the anchor frame's inliers: below it no frame moved
#: enough for a map, and the poses are rotations.
MIN_PARALLAX_DEG = 0.5
#: The least parallax [deg] of a map point (a narrower one has a depth error over ~10x its
#: image noise in radians divided by the parallax).
MAP_PARALLAX_DEG = 0.3
#: The least map points (PnP inliers) a frame's pose needs.
MIN_MAP_POINTS = 12
#: Rounds of posing the frames the map reaches and growing the map from them.
MAP_ROUNDS = 6
#: The bundle adjustment's inliers: reprojection errors below this [undistorted px].
BUNDLE_INLIER_PX = 3.0
#: Weight [px per map unit] of the bundle adjustment's gauge: the anchor's |t| held.
_GAUGE = 1e4


@dataclass(frozen=True)
class FramePose:
    """A frame's camera from the reference's (`background_poses`): R_frame_from_ref (3, 3),
    t_frame_from_ref (3,) [map unit] (X_frame = R_frame_from_ref X_ref + t_frame_from_ref),
    cov (6, 6) of (rotation vector of a left turn of R_frame_from_ref [rad],
    t_frame_from_ref [map unit]); inliers of the PnP (or of the homography for
    "rotation"), rms_px their reprojection error."""

    R_frame_from_ref: np.ndarray
    t_frame_from_ref: np.ndarray
    cov: np.ndarray
    inliers: int
    rms_px: float

    def to_dict(self) -> dict:
        """fulcrum.json's record of the pose (``stabilize.frames[].pose``)."""
        return {"R_frame_from_ref": self.R_frame_from_ref.tolist(), "t_frame_from_ref": self.t_frame_from_ref.tolist(),
                "cov": self.cov.tolist(),
                "inliers": self.inliers, "rms_px": float(self.rms_px)}

    @classmethod
    def from_dict(cls, d):
        """The pose of a `to_dict` record."""
        return cls(np.asarray(d["R_frame_from_ref"], float), np.asarray(d["t_frame_from_ref"], float),
                   np.asarray(d["cov"], float), int(d["inliers"]), float(d["rms_px"]))


def _rodrigues(v):
    import cv2

    return cv2.Rodrigues(np.asarray(v, float).reshape(3, 1))[0]


def _small_log(D):
    """The rotation vector of a rotation D (3, 3) near the identity, to first order: half
    its antisymmetric part (cv2.Rodrigues returns 0 below 1e-5 rad, which central
    differences need)."""
    return 0.5 * np.array([D[2, 1] - D[1, 2], D[0, 2] - D[2, 0], D[1, 0] - D[0, 1]])


def rotation_from_homography(H, cov_H, K):
    """(R (3, 3), cov (3, 3) of its left-turn rotation vector [rad^2]) of the camera turn a
    homography H (3, 3; H[2, 2] = 1, frame to reference, undistorted px) with the covariance
    cov_H (8, 8) of its first eight entries stands for: the rotation nearest ``K^-1 H K``
    (the polar factor), its covariance by central differences."""
    K = np.asarray(K, float)
    Ki = np.linalg.inv(K)

    def rot(h):
        U, _, Vt = np.linalg.svd(Ki @ np.append(h, 1.0).reshape(3, 3) @ K)
        R = U @ Vt
        return R * np.sign(np.linalg.det(R))

    h0 = (np.asarray(H, float) / H[2, 2]).ravel()[:8]
    R0 = rot(h0)
    J = np.zeros((3, 8))
    for k in range(8):
        s = 1e-7 if k >= 6 else 1e-4
        e = np.zeros(8)
        e[k] = s
        J[:, k] = (_small_log(rot(h0 + e) @ R0.T) - _small_log(rot(h0 - e) @ R0.T)) / (2 * s)
    return R0, J @ np.asarray(cov_H, float) @ J.T


def pose_left_cov(rvec, cov):
    """(R_frame_from_ref, the 6 x 6 covariance of (a left turn's rotation vector,
    t_frame_from_ref)) of a PnP or bundle pose whose covariance cov (6, 6) is of (rvec,
    tvec) (cv2's: rvec the rotation vector of R_frame_from_ref): the rotation's block by
    central differences of the left turn ``log(R(rvec + e) R(rvec)^T)``."""
    r0 = np.ravel(rvec).astype(float)
    R0 = _rodrigues(r0)
    J = np.eye(6)
    for k in range(3):
        e = np.zeros(3)
        e[k] = 1e-6
        J[:3, k] = (_small_log(_rodrigues(r0 + e) @ R0.T) - _small_log(_rodrigues(r0 - e) @ R0.T)) / 2e-6
    out = J @ np.asarray(cov, float) @ J.T
    return R0, 0.5 * (out + out.T)


def _relative(src, dst, K):
    """(R_frame_from_ref, t_frame_from_ref, inlier mask, median parallax [deg]) of a frame
    (points src (M, 2)) to the reference (dst): X_frame = R_frame_from_ref X_ref +
    t_frame_from_ref, |t_frame_from_ref| = 1; None where there is no essential matrix."""
    import cv2

    if len(src) < 8:
        return None
    # SIFT gives one keypoint several orientations: the same match repeated. A five-point
    # sample drawn from repeats is degenerate, and OpenCV's solver then fails an assertion
    # (solvePoly's leading coefficient) rather than rejecting the sample: sample distinct
    # matches, and take a failure that is left as no pose for this frame.
    _, first = np.unique(np.round(np.c_[src, dst], 3), axis=0, return_index=True)
    first = np.sort(first)
    if len(first) < 8:
        return None
    try:
        E, m = cv2.findEssentialMat(dst[first], src[first], K, method=cv2.RANSAC, prob=0.999, threshold=RANSAC_PX)
    except cv2.error:
        return None
    if E is None or E.shape != (3, 3):
        return None
    mask = np.zeros((len(src), 1), np.uint8)
    mask[first] = m.reshape(-1, 1)
    n, R_frame_from_ref, t_frame_from_ref, mask = cv2.recoverPose(E, dst, src, K, mask=mask)
    keep = mask.ravel() > 0
    if n < MIN_MAP_POINTS:
        return None
    Ki = np.linalg.inv(K)
    a = np.c_[dst[keep], np.ones(keep.sum())] @ Ki.T
    b = (np.c_[src[keep], np.ones(keep.sum())] @ Ki.T) @ R_frame_from_ref   # the frame's rays in the reference's
    cosang = np.sum(a * b, -1) / (np.linalg.norm(a, axis=-1) * np.linalg.norm(b, axis=-1))
    return (R_frame_from_ref, t_frame_from_ref.ravel(), keep,
            float(np.degrees(np.median(np.arccos(np.clip(cosang, -1.0, 1.0))))))


def _triangulate(src, dst, K, R_frame_from_ref, t_frame_from_ref):
    """(X (M, 3) in the reference camera, good (M,)) of matches src (frame) to dst
    (reference) with the frame's pose (R_frame_from_ref, t_frame_from_ref): in front of
    both cameras, reprojected within RANSAC_PX in both, parallax at least MAP_PARALLAX_DEG."""
    import cv2

    P0 = K @ np.c_[np.eye(3), np.zeros(3)]
    P1 = K @ np.c_[R_frame_from_ref, t_frame_from_ref]
    Xh = cv2.triangulatePoints(P0, P1, dst.T.astype(float), src.T.astype(float))
    X = (Xh[:3] / Xh[3]).T
    Xf = X @ R_frame_from_ref.T + t_frame_from_ref
    good = (X[:, 2] > 0) & (Xf[:, 2] > 0)
    q0, q1 = X @ K.T, Xf @ K.T
    e0 = np.hypot(*(q0[:, :2] / q0[:, 2:] - dst).T)
    e1 = np.hypot(*(q1[:, :2] / q1[:, 2:] - src).T)
    c = -R_frame_from_ref.T @ t_frame_from_ref                 # the frame's centre in the reference
    a, b = X, X - c
    cosang = np.sum(a * b, -1) / (np.linalg.norm(a, axis=-1) * np.linalg.norm(b, axis=-1))
    par = np.degrees(np.arccos(np.clip(cosang, -1.0, 1.0)))
    return X, good & (e0 < RANSAC_PX) & (e1 < RANSAC_PX) & (par >= MAP_PARALLAX_DEG)


def _pnp(X, x, K):
    """(rvec, tvec, cov (6, 6), inliers, rms [px]) of the pose (R_frame_from_ref's rotation
    vector, t_frame_from_ref) that
    projects the map points X (N, 3) to the frame's x (N, 2) [undistorted px], or None."""
    import cv2

    if len(X) < MIN_MAP_POINTS:
        return None
    ok, rvec, tvec, inl = cv2.solvePnPRansac(X, x, K, None, iterationsCount=500, reprojectionError=2.0 * RANSAC_PX,
                                             confidence=0.999, flags=cv2.SOLVEPNP_EPNP)
    if not ok or inl is None or len(inl) < MIN_MAP_POINTS:
        return None
    i = inl.ravel()
    rvec, tvec = cv2.solvePnPRefineLM(X[i], x[i], K, None, rvec, tvec)
    p, J = cv2.projectPoints(X[i], rvec, tvec, K, None)
    r = (x[i] - p.reshape(-1, 2)).ravel()
    A = J[:, :6]
    s2 = float(r @ r) / max(r.size - 6, 1)
    try:
        cov = s2 * np.linalg.inv(A.T @ A)
    except np.linalg.LinAlgError:
        return None
    return rvec.ravel(), tvec.ravel(), cov, len(i), float(np.sqrt(np.mean(r * r)))


def background_poses(matches, K, ref, homographies=None):
    """Every frame's pose in the reference frame's camera (module docstring).

    matches: per frame (src (M, 2) its undistorted px, dst (M, 2) the reference's, ref_idx
    (M,) the reference features' indices) or None (a frame not measured); K: (3, 3); ref:
    the reference frame's index; homographies: per frame (H, cov_H) or None, for the
    rotations where no frame has the parallax (or no map poses the anchor). Returns (model
    "map" or "rotation", anchor index or None, [FramePose or None] per frame: the
    reference's the identity; None where the pose is not measured).
    """
    K = np.asarray(K, float)
    matches = [None if i == ref else m for i, m in enumerate(matches)]
    rel = [None if m is None else _relative(m[0], m[1], K) for m in matches]
    par = [-1.0 if r is None else r[3] for r in rel]
    anchor = int(np.argmax(par)) if par else None
    identity = FramePose(np.eye(3), np.zeros(3), np.zeros((6, 6)), 0, 0.0)
    if anchor is None or par[anchor] < MIN_PARALLAX_DEG:
        return "rotation", None, _rotations(matches, homographies, ref, K, identity)
    best = None
    for R_frame_from_ref, t_frame_from_ref in _anchor_candidates(rel[anchor], matches[anchor], K):
        got, world = _grow(matches, anchor, R_frame_from_ref, t_frame_from_ref, K)
        if anchor not in got:
            continue
        got, agree = _bundle(matches, got, world, K, anchor)
        key = (len(got), agree)
        if best is None or key > best[0]:
            best = (key, got)
    if best is None:  # no map poses the anchor: no frame measured in 3-D but by its turn
        return "rotation", None, _rotations(matches, homographies, ref, K, identity)
    got = best[1]
    out = []
    for i in range(len(matches)):
        if i not in got:
            out.append(identity if i == ref else None)
            continue
        R_frame_from_ref, C = pose_left_cov(got[i][0], got[i][2])
        out.append(FramePose(R_frame_from_ref, np.asarray(got[i][1], float), C, got[i][3], got[i][4]))
    return "map", anchor, out


def _rotations(matches, homographies, ref, K, identity):
    """[FramePose or None] of the "rotation" model: each measured frame's homography's turn
    (`rotation_from_homography`), no translation."""
    out = []
    for i, (m, h) in enumerate(zip(matches, homographies or [None] * len(matches))):
        if i == ref or m is None or h is None:
            out.append(identity if i == ref else None)
            continue
        R_ref_from_frame, c = rotation_from_homography(h[0], h[1], K)
        cov = np.zeros((6, 6))
        # a left turn d of R_ref_from_frame is the left turn -R^T d of its inverse
        cov[:3, :3] = R_ref_from_frame.T @ c @ R_ref_from_frame
        out.append(FramePose(R_ref_from_frame.T, np.zeros(3), cov, len(m[0]), float("nan")))
    return out


def _observations(matches, frames, world):
    """(frame slot (M,), point slot (M,), observed px (M, 2), per point its reference
    pixel (P, 2), the map's keys (P,)) of every match of the posed `frames` to a map point."""
    keys = sorted(world)
    slot = {k: j for j, k in enumerate(keys)}
    fi, pj, uv = [], [], []
    ref_px = np.zeros((len(keys), 2))
    for a, i in enumerate(frames):
        src, dst, idx = matches[i]
        for s, d, k in zip(np.asarray(src, float), np.asarray(dst, float), idx):
            j = slot.get(int(k))
            if j is not None:
                fi.append(a)
                pj.append(j)
                uv.append(s)
                ref_px[j] = d
    return np.array(fi, int), np.array(pj, int), np.array(uv, float).reshape(-1, 2), ref_px, keys


def _project(x, nf, fi, pj, rays, K):
    """(M, 2) the map points pj (on their reference rays `rays` at the inverse depths in x
    after the nf poses) projected into the frames fi [undistorted px]."""
    P = x[:6 * nf].reshape(nf, 6)
    X = rays[pj] / x[6 * nf + pj][:, None]
    q = (np.einsum("nij,nj->ni", rotation_from_rotvec(P[fi, :3]), X) + P[fi, 3:]) @ K.T
    return q[:, :2] / q[:, 2:3]


def _bundle(matches, got, world, K, anchor):
    """({frame: (rvec, tvec, cov (6, 6), inliers, rms)}, the observations within
    `BUNDLE_INLIER_PX` at the solution) of the map and every posed frame refined together
    (module docstring, step 4): each map point on its reference ray at an inverse depth, the
    reprojection errors in every posed frame of the matches within 1.5 `BUNDLE_INLIER_PX`
    of the start (soft L1 at 1 px), the scale held by the anchor's |t|; the poses'
    covariance is the Schur complement's inverse over the inliers, times their residual
    variance."""
    from scipy.optimize import least_squares
    from scipy.sparse import lil_matrix

    frames = sorted(got)
    fi, pj, uv, ref_px, keys = _observations(matches, frames, world)
    nf = len(frames)
    rays = np.c_[ref_px, np.ones(len(keys))] @ np.linalg.inv(K).T
    a = frames.index(anchor)
    x0 = np.r_[np.concatenate([np.r_[got[i][0], got[i][1]] for i in frames]),
               [1.0 / max(world[k][2], 1e-9) for k in keys]]
    near = np.hypot(*(_project(x0, nf, fi, pj, rays, K) - uv).T) < 1.5 * BUNDLE_INLIER_PX
    seen = np.unique(pj[near])                    # the points some start inlier sees, renumbered
    slot = -np.ones(len(keys), int)
    slot[seen] = np.arange(len(seen))
    fi, pj, uv = fi[near], slot[pj[near]], uv[near]
    rays, npt = rays[seen], len(seen)
    x0 = np.r_[x0[:6 * nf], x0[6 * nf:][seen]]
    norm0 = float(np.linalg.norm(got[anchor][1]))

    def residuals(x):
        return np.r_[(_project(x, nf, fi, pj, rays, K) - uv).ravel(),
                     _GAUGE * (np.linalg.norm(x[6 * a + 3:6 * a + 6]) - norm0)]

    A = lil_matrix((2 * len(fi) + 1, 6 * nf + npt), dtype=int)
    rows = np.arange(len(fi))
    for c in range(6):
        A[2 * rows, 6 * fi + c] = 1
        A[2 * rows + 1, 6 * fi + c] = 1
    A[2 * rows, 6 * nf + pj] = 1
    A[2 * rows + 1, 6 * nf + pj] = 1
    A[2 * len(fi), 6 * a + 3:6 * a + 6] = 1
    sol = least_squares(residuals, x0, jac_sparsity=A, method="trf", loss="soft_l1", f_scale=1.0, x_scale="jac",
                        max_nfev=50)
    r = sol.fun[:-1].reshape(-1, 2)
    inl = np.hypot(*r.T) < BUNDLE_INLIER_PX
    J = sol.jac.tocsc()[np.r_[np.repeat(inl, 2), True]]
    Jc, Jp = J[:, :6 * nf], J[:, 6 * nf:]          # the points' block of J^T J is diagonal
    Hx = (Jc.T @ Jp).toarray()
    Hp = np.asarray(Jp.multiply(Jp).sum(0)).ravel()
    S = (Jc.T @ Jc).toarray() - (Hx / np.maximum(Hp, 1e-300)) @ Hx.T
    dof = max(2 * int(inl.sum()) - 6 * nf - npt + 1, 1)
    s2 = float(np.sum(r[inl] ** 2)) / dof
    try:
        cov = s2 * np.linalg.inv(S)
    except np.linalg.LinAlgError:
        return got, 0
    P = sol.x[:6 * nf].reshape(nf, 6)
    out = {}
    for k, i in enumerate(frames):
        mine = inl & (fi == k)
        rms = float(np.sqrt(np.mean(r[mine] ** 2))) if mine.any() else float("nan")
        out[i] = (P[k, :3], P[k, 3:], cov[6 * k:6 * k + 6, 6 * k:6 * k + 6], int(mine.sum()), rms)
    return out, int(inl.sum())


def _anchor_candidates(rel, match, K):
    """[(R_frame_from_ref, t_frame_from_ref)] the anchor's relative poses to try (|t| = 1): the
    essential matrix's, and the decompositions of the homography of its inliers (a flat
    background leaves the essential matrix two-fold ambiguous; the map that poses the
    other frames best decides)."""
    import cv2

    R_frame_from_ref, t_frame_from_ref, keep, _ = rel
    out = [(R_frame_from_ref, t_frame_from_ref)]
    src, dst = (np.asarray(a, float)[keep] for a in match[:2])
    H, _ = cv2.findHomography(dst, src, cv2.RANSAC, RANSAC_PX)
    if H is None:
        return out
    n, Rs, ts, _ = cv2.decomposeHomographyMat(H, K)
    for Rc, tc in zip(Rs, ts):
        tc = tc.ravel()
        if np.linalg.norm(tc) > 1e-9:
            out.append((Rc, tc / np.linalg.norm(tc)))
    return out


def _grow(matches, anchor, R_frame_from_ref, t_frame_from_ref, K):
    """({frame index: PnP pose}, the map) of every frame the map reaches, from the anchor's
    relative pose: the map triangulated from it, the frames posed, the map grown from their
    matches, again (`MAP_ROUNDS`)."""
    src, dst, idx = (np.asarray(a) for a in matches[anchor])
    world = _add_points({}, src.astype(float), dst.astype(float), idx, K, R_frame_from_ref, t_frame_from_ref)
    got = {}
    for _ in range(MAP_ROUNDS):  # pose what the map reaches, grow the map from the new poses, again
        new = {}
        for i, m in enumerate(matches):
            if m is None or i in got:
                continue
            sel = [k for k, j in enumerate(m[2]) if int(j) in world]
            pose = None if len(sel) < MIN_MAP_POINTS else _pnp(
                np.array([world[int(m[2][k])] for k in sel]), np.asarray(m[0], float)[sel], K)
            if pose is not None:
                new[i] = pose
        if not new:
            break
        got.update(new)
        for i, pose in new.items():
            m = matches[i]
            world = _add_points(world, np.asarray(m[0], float), np.asarray(m[1], float), np.asarray(m[2]), K,
                                _rodrigues(pose[0]), pose[1])
    return got, world


def _add_points(world, src, dst, idx, K, R_frame_from_ref, t_frame_from_ref):
    """The map `world` ({reference feature index: (3,) point}) with the matches of a frame
    of pose (R_frame_from_ref, t_frame_from_ref) triangulated where they are not yet in it
    (`_triangulate`)."""
    X, good = _triangulate(src, dst, K, R_frame_from_ref, t_frame_from_ref)
    out = dict(world)
    for k, x, g in zip(idx, X, good):
        if g and int(k) not in out:
            out[int(k)] = x
    return out
