"""The camera's motion over a sequence, measured on the background, and the instrument's
lines carried into one reference frame (`pencilcal fulcrum --stabilize`).

Within a pivot epoch every frame's shaft axis passes through one fulcrum image only while
the camera holds still. Where it moves (a hand-held or drifting endoscope), each frame's
lines are taken into the reference frame's image first:

1. *features*: SIFT key points (a low contrast threshold, `CONTRAST`, after local contrast
   equalisation: tissue is smooth) of every frame inside the sequence's valid region, off the
   instrument (a band `BAND_WIDTHS` shaft widths either side of each shaft's midline, from
   the border to `TIP_WIDTHS` widths beyond its far end: the wrist and jaws);
2. *matches* to the reference frame's (Lowe's ratio test, `RATIO`), in undistorted pixels;
3. *homography* ``H_ref_from_frame`` by RANSAC (`RANSAC_PX`), then Gauss-Newton on its
   inliers' transfer errors, ``H[2, 2] = 1``: its 8 x 8 covariance is ``s^2 (J^T J)^-1``
   with ``s^2`` the inliers' residual variance, so what the background does beyond a
   homography (tissue that deforms, parallax) widens it; a frame whose own matches give
   none (too little background shared with the reference) is measured through the nearest
   frame that has one (`_through_neighbour`, `chain_homography`), and so is a frame whose
   own homography no chain through another frame confirms and a stronger one refutes
   (`CHAIN_PX`: a coincidence of a few matches);
4. *lines*: a line's two end points map by H (its homogeneous vector by ``H^-T``), and its
   (angle, offset) covariance about its centre is carried by the Jacobian of the mapped
   line's (angle, offset) about its new centre in the line's own two parameters and in
   the homography's eight: ``J_l C_l J_l^T + J_h C_h J_h^T`` (numeric central differences);
   each mapped shaft carries its frame's parallax scale, ``parallax_scale_px = f *
   non_rotation`` [px]: what the homography does not carry (below) grows with it, and the
   fulcrum fit takes that in (`pencil.parallax`).

The assumption: the background's image motion is a homography. That is exact for a camera
that turns about its centre (``H = K R K^-1``, any scene: the fulcrum's image moves with
it) and for a planar background; an endoscope moved about its port also translates, and a
homography fitted to the tissue then carries points off the tissue's depth (the fulcrum)
with a parallax error of the translation times the difference of inverse depths (the
term `pencil.parallax` adds to each line, one factor for the sequence fitted from the lines).
The homography's uncertainty is carried into each line, but its error is shared by all
lines of the frame and the reference's feature noise by all frames: neither correlation is
modelled.

>>> import numpy as np
>>> H = np.array([[1.0, 0.0, 5.0], [0.0, 1.0, -3.0], [0.0, 0.0, 1.0]])
>>> seg, cov = map_segment(np.array([0.0, 0.0, 100.0, 0.0]), np.diag([1e-4, 0.25]), H, np.zeros((8, 8)))
>>> np.round(seg, 6).tolist(), np.round(np.sqrt(np.diag(cov)), 4).tolist()
([5.0, -3.0, 105.0, -3.0], [0.01, 0.5])
"""
from __future__ import annotations

import copy
from dataclasses import dataclass

import numpy as np

from pencilcal.toolkit.camera.model import mean_focal
from pencilcal.toolkit.detect.background_pose import FramePose, background_poses
from pencilcal.toolkit.errors import EstimationError

__all__ = ["FrameMotion", "background_motion", "background_motion_3d", "instrument_exclusion", "map_segment", "stabilize_frames",
           "homography_cov", "chain_homography", "MIN_INLIERS", "MAX_NON_ROTATION", "CHAIN_PX"]

#: Lowe's ratio test of a feature's best match against its second best.
RATIO = 0.8
#: RANSAC's inlier threshold [undistorted px] of the homography's transfer error.
RANSAC_PX = 3.0
#: The least RANSAC inliers a frame's homography needs: fewer and its motion is unmeasured.
MIN_INLIERS = 15
#: Half-width of the band about each shaft's midline kept free of features [shaft widths].
BAND_WIDTHS = 1.5
#: How far beyond the midline's far end the band goes (the wrist and jaws) [shaft widths].
TIP_WIDTHS = 4.0
#: The most a homography may depart from a turn of the camera, as the ratio of the largest
#: to the smallest singular value of K^-1 H K less 1 (0 for any rotation; a translation of
#: a tenth of the scene's depth gives about 0.1-0.3): beyond it the matches that carried
#: RANSAC are a coincidence (the phantom's frame 3: 2.3, from 23 of 103 matches; it is measured
#: through frame 2, `_through_neighbour`).
MAX_NON_ROTATION = 0.5
#: Frames measured directly, nearest first, through which a frame whose own matches to the
#: reference give no motion is tried (`_through_neighbour`).
NEIGHBOURS = 2
#: The most a frame's own homography to the reference may depart from a chain through
#: another measured frame (``H_ref_from_j H_j_from_i``) that confirms it, as the median
#: transfer difference at the background the two frames share [undistorted px]: twice
#: RANSAC's inlier threshold, as each of the two paths holds its matches only to within it.
#: One that no chain confirms and a chain of more inliers refutes is refused. On the phantom the frames
#: measured directly agree with the nearest agreeing chain to 1-2 px; frame 3's coincidental
#: matches to frame 11 (28 inliers of 109 where frame 11's band runs on over the wrist, a
#: homography 0.35 from a turn) depart 10-18 px from every chain (`_chain_agreement`).
CHAIN_PX = 2.0 * RANSAC_PX
#: Chains tried per directly measured frame (`_chain_agreement`), nearest first: a genuine
#: homography is confirmed by its nearest neighbour's chain (1-2 px on the phantom), and a
#: bound keeps a long video from matching every frame with every other.
CHAIN_TRIES = 4
#: SIFT features per frame.
FEATURES = 4000
#: SIFT's contrast threshold (its default 0.04 finds ~200 features on a bowel phantom's
#: smooth tissue, 0.01 after CLAHE ~3600).
CONTRAST = 0.01


@dataclass(frozen=True)
class FrameMotion:
    """The background's motion of one frame to the reference: H (3, 3) maps its undistorted
    pixels to the reference's (H[2, 2] = 1), cov (8, 8) of H's first eight entries (row
    major), rms_px the inliers' transfer error [undistorted px], inliers of matches,
    shift_px the median displacement of the inliers [px], non_rotation its departure from
    a turn of the camera (`MAX_NON_ROTATION`); ok False (H None) with error
    saying why where it is not measured; pose: its 3-D pose in the reference's camera
    (`background_pose.FramePose`) where measured (`background_motion` with ``poses``); via:
    the index of the frame it was measured through where its own matches to the reference
    gave no motion (H the two steps' product; rms_px, inliers and matches the step's to that
    frame), else None."""

    image: str
    ok: bool
    H: np.ndarray | None = None
    cov: np.ndarray | None = None
    rms_px: float = float("nan")
    inliers: int = 0
    matches: int = 0
    shift_px: float = float("nan")
    non_rotation: float = float("nan")
    error: str | None = None
    pose: FramePose | None = None
    via: int | None = None

    @classmethod
    def from_dict(cls, d):
        """The motion of a `to_dict` record (fulcrum.json's ``stabilize.frames`` entries; its
        ``via``, a frame's name there, is not read back)."""
        if not d["ok"]:
            return cls(str(d["image"]), False, matches=int(d["matches"]), inliers=int(d["inliers"]), error=d["error"])
        pose = None if d.get("pose") is None else FramePose.from_dict(d["pose"])
        return cls(str(d["image"]), True, np.asarray(d["H_ref_from_frame"], float), np.asarray(d["H_cov"], float),
                   float(d["rms_px"]), int(d["inliers"]), int(d["matches"]), float(d["shift_px"]),
                   float(d["non_rotation"]), pose=pose)

    def to_dict(self) -> dict:
        """fulcrum.json's record of the frame's motion (docs/formats.md, ``stabilize``)."""
        out = {"image": self.image, "ok": self.ok, "matches": self.matches, "inliers": self.inliers}
        if self.ok:
            out.update({"H_ref_from_frame": self.H.tolist(), "H_cov": self.cov.tolist(),
                        "rms_px": float(self.rms_px), "shift_px": float(self.shift_px),
                        "non_rotation": float(self.non_rotation)})
            if self.via is not None:
                out["via"] = int(self.via)
            if self.pose is not None:
                out["pose"] = self.pose.to_dict()
        else:
            out["error"] = self.error
        return out


def instrument_exclusion(shape, shafts, valid=None):
    """(H, W) uint8 mask, 255 where features may be taken: inside `valid` ((H, W) bool or
    None: everywhere), off each shaft's band (module docstring; shafts: lines.json shaft
    records, midline in raw px from the near end to the far end, width_px)."""
    import cv2

    m = np.full(shape[:2], 255, np.uint8) if valid is None else np.where(valid, 255, 0).astype(np.uint8)
    reach = float(np.hypot(*shape[:2]))
    for s in shafts or ():
        x1, y1, x2, y2 = (float(v) for v in s["midline"])
        d = np.array([x2 - x1, y2 - y1])
        n = float(np.hypot(*d))
        if not np.isfinite(n) or n < 1e-9:
            continue
        d /= n
        w = max(float(s.get("width_px") or 10.0), 4.0)
        a = np.array([x1, y1]) - reach * d
        b = np.array([x2, y2]) + TIP_WIDTHS * w * d
        cv2.line(m, tuple(int(round(v)) for v in a), tuple(int(round(v)) for v in b), 0,
                 thickness=max(int(round(2 * BAND_WIDTHS * w)), 3))
        cv2.circle(m, (int(round(b[0])), int(round(b[1]))), int(round(2.0 * w)), 0, -1)
    return m


def _features(image, mask, sift):
    """(key points (N, 2) raw px, descriptors) of an image (grey or BGR) within mask."""
    import cv2

    g = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    if g.dtype != np.uint8:
        g = cv2.normalize(g, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)
    g = cv2.createCLAHE(3.0, (8, 8)).apply(g)
    kp, des = sift.detectAndCompute(g, mask)
    return np.array([k.pt for k in kp], float).reshape(-1, 2), des


def _transfer(h, src):
    """src (N, 2) mapped by the homography of h (8,), H[2, 2] = 1, and the Jacobian
    (N, 2, 8) of the mapped points in h."""
    x, y = src[:, 0], src[:, 1]
    w = h[6] * x + h[7] * y + 1.0
    u = (h[0] * x + h[1] * y + h[2]) / w
    v = (h[3] * x + h[4] * y + h[5]) / w
    J = np.zeros((len(src), 2, 8))
    one = np.ones_like(x)
    J[:, 0, 0:3] = np.stack([x, y, one], -1) / w[:, None]
    J[:, 1, 3:6] = np.stack([x, y, one], -1) / w[:, None]
    J[:, 0, 6:8] = -np.stack([x, y], -1) * (u / w)[:, None]
    J[:, 1, 6:8] = -np.stack([x, y], -1) * (v / w)[:, None]
    return np.stack([u, v], -1), J


def homography_cov(H, src, dst, iterations=3):
    """(H refined, cov (8, 8), rms [px]) of the homography mapping src (N, 2) to dst (N, 2),
    N >= 5: Gauss-Newton on the transfer errors from H (3, 3), its covariance s^2 (J^T J)^-1
    with s^2 = |r|^2 / (2N - 8), the columns scaled for the inverse (pixel coordinates
    make them differ by 10^6).

    >>> rng = np.random.default_rng(0)
    >>> src = rng.uniform(0, 500, (200, 2))
    >>> H0 = np.array([[1.01, 0.02, 4.0], [-0.01, 0.99, -2.0], [1e-5, -2e-5, 1.0]])
    >>> q = np.c_[src, np.ones(200)] @ H0.T
    >>> dst = q[:, :2] / q[:, 2:] + rng.normal(0, 0.5, (200, 2))
    >>> H, cov, rms = homography_cov(np.eye(3), src, dst, iterations=6)
    >>> grid = np.array([[0.0, 0.0], [500.0, 0.0], [0.0, 500.0], [500.0, 500.0]])
    >>> bool(np.abs(_apply(H, grid) - _apply(H0, grid)).max() < 0.3), round(rms, 1), cov.shape
    (True, 0.5, (8, 8))
    """
    h = (np.asarray(H, float) / H[2, 2]).ravel()[:8].copy()
    src, dst = np.asarray(src, float), np.asarray(dst, float)
    for it in range(iterations + 1):  # the last pass only evaluates: r, N at the final h
        p, J = _transfer(h, src)
        r = (dst - p).reshape(-1)
        A = J.reshape(-1, 8)
        scale = 1.0 / np.maximum(np.linalg.norm(A, axis=0), 1e-300)
        As = A * scale
        N = np.linalg.inv(As.T @ As)
        if it < iterations:
            h = h + scale * (N @ (As.T @ r))
    dof = max(r.size - 8, 1)
    s2 = float(r @ r) / dof
    cov = s2 * (scale[:, None] * N * scale[None, :])
    rms = float(np.sqrt(np.mean(np.sum((dst - p) ** 2, -1)) / 2.0))
    return np.append(h, 1.0).reshape(3, 3), cov, rms


def _match(ref, cur, camera):
    """(src, dst) (M, 2) undistorted px of the matches of the current frame's features
    `cur` to the reference's `ref` (each (points, descriptors)), Lowe's ratio test, and the
    reference features' indices (M,)."""
    import cv2

    if cur[1] is None or ref[1] is None or len(cur[0]) < 2 or len(ref[0]) < 2:
        return np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0, int)
    pairs = cv2.BFMatcher(cv2.NORM_L2).knnMatch(cur[1], ref[1], k=2)
    good = [(m.queryIdx, m.trainIdx) for m, *rest in (p for p in pairs if len(p) >= 1)
            if not rest or m.distance < RATIO * rest[0].distance]
    if not good:
        return np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0, int)
    qi, ti = np.array(good).T
    src = camera.undistort_pixels(cur[0][qi])
    dst = camera.undistort_pixels(ref[0][ti])
    ok = np.all(np.isfinite(src), -1) & np.all(np.isfinite(dst), -1)
    return src[ok], dst[ok], ti[ok]


def _frame_motion(name, ref, cur, camera, matches=None):
    """The `FrameMotion` of one frame's features `cur` to the reference's `ref`; the
    matches (src, dst, reference indices) are appended to `matches` where given."""
    import cv2

    src, dst, ti = _match(ref, cur, camera)
    if matches is not None:
        matches.append((src, dst, ti))
    if len(src) < MIN_INLIERS:
        return FrameMotion(name, False, matches=len(src), error=f"{len(src)} background matches (< {MIN_INLIERS})")
    H, inl = cv2.findHomography(src, dst, cv2.RANSAC, RANSAC_PX, maxIters=5000, confidence=0.999)
    k = 0 if inl is None else int(inl.sum())
    if H is None or k < MIN_INLIERS or not np.isfinite(H).all() or abs(H[2, 2]) < 1e-12:
        return FrameMotion(name, False, matches=len(src), inliers=k,
                           error=f"no homography of the background ({k} inliers of {len(src)} matches)")
    keep = inl.ravel().astype(bool)
    H, cov, rms = homography_cov(H, src[keep], dst[keep])
    shift = float(np.median(np.hypot(*(dst[keep] - src[keep]).T)))
    nr = _non_rotation(H, camera)
    if not nr <= MAX_NON_ROTATION:
        return FrameMotion(name, False, matches=len(src), inliers=k, non_rotation=nr, error=(
            f"the background's homography is no camera motion ({k} inliers of {len(src)} matches, departs "
            f"{nr:.2f} from a turn)"))
    return FrameMotion(name, True, H, cov, rms, k, len(src), shift, nr)


def _non_rotation(H, camera):
    """The departure of a homography H (3, 3) from a turn of the camera (`MAX_NON_ROTATION`)."""
    K = np.asarray(camera.K, float)
    sv = np.linalg.svd(np.linalg.solve(K, H @ K), compute_uv=False)
    return float(sv[0] / sv[2] - 1.0)


def _measure(images, shafts, camera, valid, reference):
    """(reference index, [FrameMotion], per frame its matches (src, dst, reference indices)
    or None) of `background_motion`."""
    import cv2

    sift = cv2.SIFT_create(nfeatures=FEATURES, contrastThreshold=CONTRAST)
    feats = [None if im is None else _features(im, instrument_exclusion(im.shape, sh, valid), sift)
             for im, sh in zip(images, shafts)]
    idx = [i for i, f in enumerate(feats) if f is not None]
    if not idx:
        raise EstimationError("no frame decodes: no camera motion to measure")
    ref = idx[len(idx) // 2] if reference is None else int(reference)
    out, matches = [], []
    for i, f in enumerate(feats):
        name = str(i)
        if f is None:
            out.append(FrameMotion(name, False, error="frame not decoded"))
            matches.append(None)
        elif i == ref:
            out.append(FrameMotion(name, True, np.eye(3), np.zeros((8, 8)), 0.0, len(f[0]), len(f[0]), 0.0, 0.0))
            matches.append(None)
        else:
            got = []
            out.append(_frame_motion(name, feats[ref], f, camera, got))
            matches.append(got[0] if out[-1].ok else None)
    direct = [m.ok for m in out]
    # a direct homography that no chain through another measured frame confirms is a
    # coincidence of a few matches: the frame is measured through its neighbour instead
    refused, steps = {}, {}
    for i, f in enumerate(feats):
        if f is not None and direct[i] and i != ref:
            least, refuting = _chain_agreement(i, ref, feats, out, direct, camera, steps)
            if refuting:
                m = out[i]
                refused[i] = FrameMotion(m.image, False, matches=m.matches, inliers=m.inliers, non_rotation=m.non_rotation,
                                         error=(f"the background's homography ({m.inliers} inliers of {m.matches} matches) "
                                                f"departs {least:.1f} px or more from {refuting} stronger chain(s) through "
                                                f"other frames (> {CHAIN_PX:g}) and none confirms it"))
    for i, m in refused.items():
        out[i], matches[i], direct[i] = m, None, False
    for i, f in enumerate(feats):
        if f is not None and not direct[i]:
            out[i] = _through_neighbour(i, ref, feats, out, direct, camera, steps)
    return ref, out, matches


def _nearest_steps(i, ref, feats, direct, camera, count, steps):
    """(j, the `FrameMotion` of frame i's features to frame j's, its matches (src, dst,
    indices)) for the `count` nearest frames j measured directly (never i, nor the reference
    `ref`: that step is the frame's own homography), nearest first, where the step is
    measured. steps: {(i, j): (step, matches)}, shared by one sequence's searches (the chain
    check and the route through a neighbour try the same pairs; matching and RANSAC are
    deterministic, so a step is the same whichever asks first)."""
    near = sorted((j for j in range(len(feats)) if direct[j] and j not in (i, ref)), key=lambda j: (abs(j - i), j))
    for j in near[:count]:
        if (i, j) not in steps:
            got = []
            steps[(i, j)] = (_frame_motion(str(i), feats[j], feats[i], camera, got), got[0])
        step, got = steps[(i, j)]
        if step.ok:
            yield j, step, got


def _chain_agreement(i, ref, feats, out, direct, camera, steps):
    """(the departure [undistorted px] of frame i's direct homography from the chains
    ``H_ref_from_j H_j_from_i`` through other frames j measured directly, the chains that
    refute it). The departure of a chain is the median transfer difference of the two at
    frame i's background matched to frame j (the step's RANSAC inliers): the region both
    paths are measured on. The `CHAIN_TRIES` nearest frames j are tried, nearest first
    (never the reference `ref`: its chain is the direct homography); the first chain within
    `CHAIN_PX` confirms it and ends the search: (its departure, 0). A chain beyond it refutes
    the direct homography only where both its links hold more inliers than the direct one (a
    weaker chain may be the coincidence): (the least departure of those, their count); (inf,
    0) where none does. steps: `_nearest_steps`' cache."""
    best, refuting = float("inf"), 0
    for j, step, (src, dst, _) in _nearest_steps(i, ref, feats, direct, camera, CHAIN_TRIES, steps):
        shared = src[np.hypot(*(_apply(step.H, src) - dst).T) <= RANSAC_PX]
        d = float(np.median(np.hypot(*(_apply(out[j].H @ step.H, shared) - _apply(out[i].H, shared)).T)))
        if d <= CHAIN_PX:
            return d, 0
        if min(out[j].inliers, step.inliers) > out[i].inliers:
            best, refuting = min(best, d), refuting + 1
    return best, refuting


def _through_neighbour(i, ref, feats, out, direct, camera, steps):
    """Frame i's `FrameMotion` through the nearest frame j measured directly (not the reference
    `ref`: its step is the frame's own homography) whose features
    it matches (`NEIGHBOURS` tried, nearest first): H_ref_from_i = H_ref_from_j H_j_from_i, its
    covariance the two homographies' carried by the product's Jacobian (independent: j's
    matches are to the reference, i's to j). A frame after the camera's largest move may
    share too little background with the reference (the phantom's frame 3: 23 RANSAC
    inliers of 103 matches, a coincidence) yet hundreds of matches with the frame beside
    it. Its matches are not the reference's, so it gets no 3-D pose. Returns out[i] where
    no neighbour measures it. steps: `_nearest_steps`' cache."""
    for j, step, got in _nearest_steps(i, ref, feats, direct, camera, NEIGHBOURS, steps):
        H, cov = chain_homography(out[j].H, out[j].cov, step.H, step.cov)
        nr = _non_rotation(H, camera)
        if nr <= MAX_NON_ROTATION:
            src = got[0]  # the background's displacement to the reference, as H carries it
            shift = float(np.median(np.hypot(*(_apply(H, src) - src).T)))
            return FrameMotion(str(i), True, H, cov, step.rms_px, step.inliers, step.matches, shift, nr, via=j)
    return out[i]


def chain_homography(H_a, cov_a, H_b, cov_b, step=1e-7):
    """(H_a H_b normalised to H[2, 2] = 1, its (8, 8) covariance) of two homographies with
    independent (8, 8) covariances of their first eight entries (H[2, 2] = 1), carried by the
    product's Jacobian in each (central differences, steps relative to each entry).

    >>> H, cov = chain_homography(np.eye(3), np.eye(8) * 1e-6, np.eye(3), np.zeros((8, 8)))
    >>> np.allclose(H, np.eye(3)), np.allclose(cov, np.eye(8) * 1e-6)
    (True, True)
    """
    ha = (np.asarray(H_a, float) / H_a[2, 2]).ravel()[:8]
    hb = (np.asarray(H_b, float) / H_b[2, 2]).ravel()[:8]

    def prod(x, y):
        P = np.append(x, 1.0).reshape(3, 3) @ np.append(y, 1.0).reshape(3, 3)
        return (P / P[2, 2]).ravel()[:8]

    def jac(f, x):
        J = np.empty((8, 8))
        for k in range(8):
            e = np.zeros(8)
            e[k] = step * max(1.0, abs(x[k]))
            J[:, k] = (f(x + e) - f(x - e)) / (2.0 * e[k])
        return J

    Ja, Jb = jac(lambda x: prod(x, hb), ha), jac(lambda y: prod(ha, y), hb)
    cov = Ja @ np.asarray(cov_a, float) @ Ja.T + Jb @ np.asarray(cov_b, float) @ Jb.T
    return np.append(prod(ha, hb), 1.0).reshape(3, 3), cov


def background_motion(images, shafts, camera, valid=None, reference=None):
    """The background's motion of every frame to the reference frame (module docstring).

    images: iterable of (H, W[, 3]) uint8 frames or None (not decoded), raw px, read once
    (only their features are kept); shafts: per frame its lines.json shaft records (their
    bands are kept free of features); camera: a `Camera` (features matched in undistorted
    px); valid: (H, W) bool valid region or None; reference: index of the reference frame,
    default the middle one of those decoded. Returns (reference index, [FrameMotion] per
    frame, named by index: the reference's the identity with zero covariance).
    """
    ref, out, _ = _measure(images, shafts, camera, valid, reference)
    return ref, out


def background_motion_3d(images, shafts, camera, valid=None, reference=None):
    """`background_motion` with every measured frame's 3-D pose in the reference frame's
    camera too (`background_pose.background_poses`, from the same matches; ``pose`` of each
    `FrameMotion`, None where it is not measured). Returns (reference index, [FrameMotion],
    the poses' model: "map" (translations in the map's unit) or "rotation", the anchor
    frame's index or None)."""
    import dataclasses

    ref, out, matches = _measure(images, shafts, camera, valid, reference)
    homs = [(m.H, m.cov) if m.ok else None for m in out]
    model, anchor, poses = background_poses(matches, camera.K, ref, homs)
    out = [dataclasses.replace(m, pose=p) if m.ok else m for m, p in zip(out, poses)]
    return ref, out, model, anchor


def _apply(H, p):
    """p (N, 2) mapped by H (3, 3)."""
    q = np.c_[p, np.ones(len(p))] @ H.T
    return q[:, :2] / q[:, 2:]


def _angle_offset(q, c0):
    """(angle of q[0] -> q[1], offset of the line through them about the point c0 along
    the direction turned by +90 deg)."""
    d = q[1] - q[0]
    a = np.arctan2(d[1], d[0])
    n = np.array([-np.sin(a), np.cos(a)])
    return np.array([a, n @ (q[0] - c0)])


def map_segment(seg, cov, H, cov_H, step=(1e-6, 1e-4, 1e-7)):
    """(mapped segment (4,), its (angle, offset) covariance (2, 2) about its new centre) of
    a segment [x1, y1, x2, y2] in undistorted px with the (angle [rad], offset [px])
    covariance `cov` (2, 2) about its centre, by H (3, 3, H[2, 2] = 1) with the covariance
    cov_H (8, 8) of its first eight entries (module docstring, step 4). step: the central
    differences' steps in the angle [rad], the offset [px] and H's entries (the projective
    ones scaled by 1e-3)."""
    seg = np.asarray(seg, float).reshape(2, 2)
    H = np.asarray(H, float) / H[2, 2]
    c = seg.mean(0)
    d = seg[1] - seg[0]
    L = float(np.hypot(*d))
    a0 = float(np.arctan2(d[1], d[0]))
    q0 = _apply(H, seg)
    c0 = q0.mean(0)

    def mapped(a, o, h):
        u, n = np.array([np.cos(a), np.sin(a)]), np.array([-np.sin(a), np.cos(a)])
        p = c + o * n + np.outer([-L / 2.0, L / 2.0], u)
        r = _angle_offset(_apply(np.append(h, 1.0).reshape(3, 3), p), c0)
        r[0] = a0 + np.angle(np.exp(1j * (r[0] - a0)))  # no wrap between the two sides
        return r

    h0 = H.ravel()[:8]
    Jl = np.zeros((2, 2))
    for k, s in enumerate(step[:2]):
        e = np.zeros(2)
        e[k] = s
        Jl[:, k] = (mapped(a0 + e[0], e[1], h0) - mapped(a0 - e[0], -e[1], h0)) / (2 * s)
    Jh = np.zeros((2, 8))
    for k in range(8):
        s = step[2] if k >= 6 else step[2] * 1e3
        e = np.zeros(8)
        e[k] = s
        Jh[:, k] = (mapped(a0, 0.0, h0 + e) - mapped(a0, 0.0, h0 - e)) / (2 * s)
    out = Jl @ np.asarray(cov, float) @ Jl.T + Jh @ np.asarray(cov_H, float) @ Jh.T
    return q0.ravel(), 0.5 * (out + out.T)


def _map_raw(camera, raw, cov, motion):
    """(raw segment (4,), cov (2, 2)) of a raw-px segment mapped into the reference (undistorted
    for the homography, distorted back); None where the lens model does not reach it."""
    ideal = camera.undistort_pixels(np.asarray(raw, float).reshape(2, 2)).ravel()
    if not np.isfinite(ideal).all():
        return None
    seg, c = map_segment(ideal, cov, motion.H, motion.cov)
    back = camera.distort_pixels(seg.reshape(2, 2)).ravel()
    return None if not np.isfinite(back).all() else (back, c)


def _map_shaft(camera, s, motion, keep_own=False):
    """A lines.json shaft record mapped into the reference frame, or None (lens); with
    `keep_own` its own edges and their covariance kept (``edges_frame``, ``edge_cov_frame``)."""
    s = copy.deepcopy(s)
    if keep_own:
        s["edges_frame"], s["edge_cov_frame"] = copy.deepcopy(s.get("edges")), copy.deepcopy(s.get("edge_cov"))
    cov = np.diag([np.radians(float(s.get("angle_sigma_deg") or 0.0)) ** 2, float(s.get("offset_sigma_px") or 0.0) ** 2])
    m = _map_raw(camera, s["midline"], cov, motion)
    if m is None:
        return None
    s["midline"] = m[0].tolist()
    # the parallax of a point off the background's depth, per unit of its relative inverse
    # depth (`pencil.parallax`): f |t| / d, |t| / d the homography's departure from a turn
    K = np.asarray(camera.K, float)
    nr = float(motion.non_rotation)
    s["parallax_scale_px"] = mean_focal(K) * nr if np.isfinite(nr) else 0.0
    if s.get("angle_sigma_deg") is not None:
        s["angle_sigma_deg"] = float(np.degrees(np.sqrt(m[1][0, 0])))
    if s.get("offset_sigma_px") is not None:
        s["offset_sigma_px"] = float(np.sqrt(m[1][1, 1]))
    if s.get("edges"):
        ecov = s.get("edge_cov") or [np.zeros((2, 2))] * len(s["edges"])
        mapped = [_map_raw(camera, e, c, motion) for e, c in zip(s["edges"], ecov)]
        if any(x is None for x in mapped):
            return None
        s["edges"] = [x[0].tolist() for x in mapped]
        if s.get("edge_cov") is not None:
            s["edge_cov"] = [x[1].tolist() for x in mapped]
    return s


def stabilize_frames(camera, frames, motions):
    """lines.json `frames` with every shaft (midline, edges and their sigmas) and segment
    mapped into the reference frame by its frame's `FrameMotion` (module docstring), each
    shaft with its frame's ``parallax_scale_px``: a frame whose motion is not measured keeps
    no line (its error says why). Where the motions
    carry 3-D poses (`background_motion_3d`), every frame keeps its camera's pose
    (``camera_pose``) and each shaft its own edges (``edges_frame``, ``edge_cov_frame``):
    `pencil.fulcrum.fulcrum_point` carries the 3-D axes with the poses. Returns new frames."""
    posed = any(m.pose is not None for m in motions)
    out = []
    for fr, mo in zip(frames, motions):
        fr = dict(fr)
        if not fr.get("ok", True):
            out.append(fr)
            continue
        if not mo.ok:
            fr.update({"shafts": [], "segments": np.zeros((0, 4)), "error": f"camera motion: {mo.error}"})
            out.append(fr)
            continue
        shafts = [m for m in (_map_shaft(camera, s, mo, posed) for s in fr.get("shafts") or []) if m is not None]
        if posed:  # None: not measured, its shafts give no 3-D axis
            fr["camera_pose"] = None if mo.pose is None else mo.pose.to_dict()
        seg = np.asarray(fr.get("segments", np.zeros((0, 4))), float).reshape(-1, 4)
        if len(seg):
            ideal = camera.undistort_pixels(seg.reshape(-1, 2))
            seg = camera.distort_pixels(_apply(mo.H / mo.H[2, 2], ideal)).reshape(-1, 4)
        fr.update({"shafts": shafts, "segments": seg})
        out.append(fr)
    return out
