"""Truth-free checks of the sigmas: a rigid stereo rig, the jackknife.

None of these needs ground truth; each compares a scatter that the data show with the
scatter the reported covariances predict.

`rig_check`
    Two cameras fixed to each other (a stereo endoscope) see the same board: the relative
    rotation ``R_right R_left^T`` must be the same in every frame. Its deviations from the
    weighted mean are compared with their predicted covariance, as the fraction of frames
    inside the 68.3 % region of chi2(3), with the binomial band in which that fraction
    falls 95 % of the time for this many frames. The prediction is that of the deviation
    from the mean (not of one frame's relative rotation): each camera's intrinsics error is
    shared by all its frames, and the part of it that is the same in every frame moves
    only the mean (`rig_check`'s joint covariance). Run with every covariance kind given
    ("noise": the corner-noise `cov`; "total": `cov_total`).
`calibration_halves` (in `validation.calibration_checks`)
    The views split in two (odd and even, and random halves): each half calibrates the
    camera, and the two must agree within their covariances.
`jackknife`, `fulcrum_jackknife`
    Leave-one-out estimates and their covariance ``(n - 1)/n sum (y_i - mean)(y_i - mean)^T``,
    and for the fulcrum the jackknife sigma of its ray (leaving out one frame at a time)
    against the one it reports.

Every check returns a JSON-ready dict (its ``to_dict`` where it is a dataclass); `pencilcal
validate` writes them under ``checks`` in validation.json (docs/formats.md).

Example
-------
>>> import numpy as np
>>> jackknife(np.array([[1.0], [2.0], [3.0]]))["cov"].round(3).tolist()
[[1.333]]
>>> lo, hi = binomial_band(48)
>>> round(lo, 3), round(hi, 3)
(0.542, 0.812)
"""
from __future__ import annotations

import math

import numpy as np

from pencilcal.toolkit.camera.intrinsics import jacobian_pixels_wrt_intrinsics, propagate
from pencilcal.toolkit.errors import EstimationError
from pencilcal.toolkit.geometry.quantiles import chi2_isf
from pencilcal.toolkit.geometry.frames import rotation_from_rotvec, rotvec_from_rotation

__all__ = ["REGION", "binomial_band", "rig_check", "jackknife", "fulcrum_jackknife", "jackknife_inflation",
           "point_jackknife", "POINT_JACKKNIFE_AXES", "board_poses", "pair_by_name", "stereo_inputs"]

#: The fewest frames whose axes a 3-D fulcrum must use for its jackknife to be judged
#: (`point_jackknife`): four axes leave 5 degrees of freedom over the point's 3.
POINT_JACKKNIFE_AXES = 4

#: The probability of the region whose coverage the checks count (one sigma in 1-D).
REGION = 0.683
# the binomial band's probability
_BAND = 0.95
# iterations of the weighted mean rotation
_MEAN_ITERATIONS = 10
# image grid (columns, rows) on which two calibrations' projections are compared
_GRID = (9, 7)


def binomial_band(n, p=REGION, level=_BAND):
    """(low, high): the fractions of n Bernoulli(p) trials that fall inside with probability
    `level` (central binomial quantiles / n: the smallest k whose cumulative probability
    reaches the tail, as scipy.stats.binom.ppf; summed in logs, without importing scipy.stats)."""
    n = int(n)
    a = (1.0 - level) / 2.0
    logs = [math.lgamma(n + 1) - math.lgamma(k + 1) - math.lgamma(n - k + 1) + k * math.log(p)
            + (n - k) * math.log1p(-p) for k in range(n + 1)]
    cdf = np.cumsum(np.exp(logs))

    def ppf(q):
        return int(np.searchsorted(cdf, q * (1.0 - 1e-12), side="left"))

    return ppf(a) / n, ppf(1.0 - a) / n


def _coverage(z2, dof):
    """The coverage record of squared Mahalanobis distances z2 (N,) with `dof`."""
    from scipy import stats

    z2 = np.asarray(z2, float)
    thr = float(stats.chi2.ppf(REGION, dof))
    lo, hi = binomial_band(z2.size)
    inside = float(np.mean(z2 < thr))
    return {"pairs": int(z2.size), "inside": inside, "expected": REGION, "band": [lo, hi],
            "consistent": bool(lo <= inside <= hi), "median_chi2": float(np.median(z2)),
            "expected_median_chi2": float(stats.chi2.ppf(0.5, dof)), "dof": int(dof)}


def _weighted_mean_rotation(R, W):
    """The rotation M minimising sum dev_i^T W_i dev_i, dev_i = log(R_i M^T) (N, 3, 3), W (N, 3, 3)."""
    M = R[0]
    for _ in range(_MEAN_ITERATIONS):
        dev = np.array([rotvec_from_rotation(Ri @ M.T) for Ri in R])
        M = rotation_from_rotvec(np.linalg.solve(W.sum(0), np.einsum("nij,nj->i", W, dev))) @ M
    return M, np.array([rotvec_from_rotation(Ri @ M.T) for Ri in R])


def _joint_covariance(A, G, C):
    """(3N, 3N): independent blocks A (N, 3, 3) plus, per camera, the shared intrinsics'
    term G_c (N, 3, P_c) C_c G_c^T over all frames (G, C: lists, one per camera)."""
    N = A.shape[0]
    S = np.zeros((3 * N, 3 * N))
    for i in range(N):
        S[3 * i:3 * i + 3, 3 * i:3 * i + 3] = A[i]
    for Gc, Cc in zip(G, C):
        if Gc is not None and Cc is not None:
            Gf = Gc.reshape(3 * N, -1)
            S += propagate(Gf, Cc)
    return S


def rig_check(left, right, intrinsics_cov=(None, None)):
    """Is R_right R_left^T one rotation, within the predicted scatter?

    Parameters
    ----------
    left, right : sequences of PoseResult
        The board's pose in each camera, frame by frame (the same frames, ok in both).
    intrinsics_cov : (C_left, C_right)
        Each camera's intrinsics covariance (P, P), or None, where the poses' ``cov_total``
        holds its term: with each result's `PoseResult.intrinsics_sensitivity` G the term
        G C G^T is taken out of the frame's own block and put back as what all frames of
        the camera share; without them every frame's total counts as independent (which
        overstates the deviations' covariance).

    Returns
    -------
    dict
        ``pairs``, ``vergence_deg`` (angle of the mean relative rotation), and per kind
        ("noise": cov, "total": cov_total where every result has one) the median scatter
        and predicted sigma [deg] and the coverage (`inside` fraction of the 68.3 % region of
        chi2(3), its binomial band, `consistent`, median chi2 against 2.37).
    """
    pairs = [(a, b) for a, b in zip(left, right) if a is not None and b is not None and a.ok and b.ok]
    if len(pairs) < 3:
        raise EstimationError(f"the rig check needs poses in both cameras in three frames, got {len(pairs)}")
    Rrel = np.array([b.R_cam_from_target @ a.R_cam_from_target.T for a, b in pairs])
    out = {"pairs": len(pairs)}
    kinds = {"noise": "cov"}
    if all(a.cov_total is not None and b.cov_total is not None for a, b in pairs):
        kinds["total"] = "cov_total"
    for kind, attr in kinds.items():
        out[kind] = _rig_kind(pairs, Rrel, attr, intrinsics_cov if kind == "total" else (None, None))
    out["vergence_deg"] = out["noise"].pop("vergence_deg")
    for kind in kinds:
        out[kind].pop("vergence_deg", None)
    return out


def _rig_kind(pairs, Rrel, attr, intrinsics_cov):
    """One kind of `rig_check`: the relative rotation's deviations from the weighted mean
    against their covariance, with the intrinsics' shared part where it is known."""
    Cl, Cr = intrinsics_cov
    A, Gl, Gr = [], [], []
    shared = Cl is not None or Cr is not None
    for (a, b), Rx in zip(pairs, Rrel):
        ca, cb = getattr(a, attr)[:3, :3], getattr(b, attr)[:3, :3]
        ga, gb = a.intrinsics_sensitivity, b.intrinsics_sensitivity
        if shared and Cl is not None and ga is not None:
            ca = ca - propagate(ga[:3], Cl)
        if shared and Cr is not None and gb is not None:
            cb = cb - propagate(gb[:3], Cr)
        A.append(cb + Rx @ ca @ Rx.T)  # left perturbations: d_rel = d_r - R_rel d_l
        Gl.append(None if ga is None else -Rx @ ga[:3])
        Gr.append(None if gb is None else gb[:3])
    A = np.array(A)
    G = [np.array(Gl) if Cl is not None and all(g is not None for g in Gl) else None,
         np.array(Gr) if Cr is not None and all(g is not None for g in Gr) else None]
    S = _joint_covariance(A, G, [Cl, Cr])
    N = len(pairs)
    blocks = np.array([S[3 * i:3 * i + 3, 3 * i:3 * i + 3] for i in range(N)])
    W = np.linalg.inv(blocks)
    M, dev = _weighted_mean_rotation(Rrel, W)
    # the deviation from the weighted mean is (I - P) e, P = 1 (sum W)^-1 [W_1 ... W_N]
    Pm = np.tile(np.hstack([np.linalg.solve(W.sum(0), W[i]) for i in range(N)]), (N, 1))
    Q = np.eye(3 * N) - Pm
    Sd = Q @ S @ Q.T
    Cd = np.array([Sd[3 * i:3 * i + 3, 3 * i:3 * i + 3] for i in range(N)])
    z2 = np.einsum("ni,nij,nj->n", dev, np.linalg.inv(Cd), dev)
    rec = {"vergence_deg": float(np.degrees(np.linalg.norm(rotvec_from_rotation(M)))),
           "scatter_median_deg": float(np.median(np.degrees(np.linalg.norm(dev, axis=1)))),
           "predicted_median_deg": float(np.median(np.degrees(np.sqrt(np.trace(Cd, axis1=1, axis2=2))))),
           "shared_intrinsics": bool(G[0] is not None or G[1] is not None)}
    rec.update(_coverage(z2, 3))
    return rec


def jackknife(estimates):
    """Leave-one-out statistics of estimates (n, M): ``mean`` (M,), the jackknife ``cov``
    (M, M) = (n - 1)/n sum (y_i - mean)(y_i - mean)^T and ``n``."""
    y = np.asarray(estimates, float)
    n = y.shape[0]
    if n < 2:
        raise EstimationError("the jackknife needs at least two leave-one-out estimates")
    m = y.mean(0)
    d = y - m
    return {"n": int(n), "mean": m, "cov": (n - 1) / n * d.T @ d}


def fulcrum_jackknife(camera, frames, angles=None, full=None, **options):
    """The fulcrum's ray sigma against its jackknife over frames.

    camera; frames: lines.json frame dicts; angles: pivot angles (F,) [rad] or None;
    options: `toolkit.pencil.fulcrum.fulcrum_from_frames`'s. Every frame with a line is
    left out once. Returns ``frames`` (leave-one-out fits), ``ray_sigma_deg`` (reported by
    the full fit, noise only), ``ray_sigma_jackknife_deg`` (RMS angle of the jackknife
    covariance of the unit ray) and their ``ratio``; with angles also the pivot normal's
    ``normal_sigma_deg`` and ``normal_sigma_jackknife_deg``. full: the fit of all frames
    when the caller has it (not fitted again).
    """
    from pencilcal.toolkit.pencil.fulcrum import fulcrum_from_frames, sequence_lines, without_frame

    if full is None:
        full = fulcrum_from_frames(camera, frames, angles, **options)
    rays, normals = [], []
    # the lines undistorted once, each fit taking all but one frame's (the same numbers)
    sig = {"endpoint_sigma_px": options["endpoint_sigma_px"]} if "endpoint_sigma_px" in options else {}
    lines = sequence_lines(camera, frames, **sig)
    # a frame without a line leaves the fit as it is: it is not a leave-one-out estimate
    with_lines = [k for k, f in enumerate(frames) if len(f.get("segments", ())) or f.get("shafts")]
    for k in with_lines:
        keep = [i for i in range(len(frames)) if i != k]
        try:
            f = fulcrum_from_frames(camera, [frames[i] for i in keep],
                                    None if angles is None else np.asarray(angles)[keep],
                                    lines=without_frame(lines, frames, k), raw_px=False, **options)
        except EstimationError:
            continue
        rays.append(f.ray)
        if f.pivot is not None and full.pivot is not None:
            n = np.asarray(f.pivot.normal, float)
            normals.append(n if n @ full.pivot.normal >= 0 else -n)
    jr = jackknife(rays)
    out = {"frames": jr["n"], "ray_sigma_deg": full.ray_sigma_deg,
           "ray_sigma_jackknife_deg": float(np.degrees(np.sqrt(max(np.trace(jr["cov"]), 0.0))))}
    out["ratio"] = out["ray_sigma_jackknife_deg"] / full.ray_sigma_deg if full.ray_sigma_deg > 0 else None
    if full.pivot is not None and len(normals) >= 2:
        jn = jackknife(normals)
        out["normal_sigma_deg"] = full.pivot.normal_sigma_deg
        out["normal_sigma_jackknife_deg"] = float(np.degrees(np.sqrt(max(np.trace(jn["cov"]), 0.0))))
    return out


def board_poses(images, camera, board, methods=("sqpnp",)):
    """The board's pose in every frame of IMAGES: image name -> PoseResult of the best of
    `methods` (`pnp.best_method`), None where the board is not found (fewer than 4 corners)
    or no method gives a pose. The camera's statistics give the totals (`pnp.estimate_pose`)
    and how the corners are found (`calibration_file.symmetric_corners_of`)."""
    from pencilcal.toolkit.board.calibration_file import symmetric_corners_of
    from pencilcal.toolkit.board.detect import detect_board
    from pencilcal.toolkit.io.images import open_images

    from .pnp import best_method, board_points, estimate_all

    out = {}
    for frame in open_images(images):
        if frame.image is None:
            out[frame.name] = None
            continue
        det = detect_board(frame.image, board, symmetric_corners_of(camera))
        if det.count < 4:
            out[frame.name] = None
            continue
        X, warp = board_points(board, camera, det.ids)
        res = estimate_all(X, det.corners, camera, methods=methods, board_warp=warp)
        best = best_method(res)
        out[frame.name] = res[best] if best else None
    return out


def pair_by_name(names, left, right):
    """(left, right) lists of PoseResult (or None) for the frames both cameras have: `names`
    (N,) and `left` (N,) are one camera's frames, `right` a dict name -> PoseResult of the
    other's. Paired by image name; when no name is shared (the two cameras name their frames
    differently), by order."""
    shared = [i for i, n in enumerate(names) if n in right]
    if shared:
        return [left[i] for i in shared], [right[names[i]] for i in shared]
    other = list(right.values())
    k = min(len(left), len(other))
    return list(left[:k]), other[:k]


def _with_report(camera, camera_path, calibration):
    """(camera, report or None, note or None): the camera with a calib.json's uncertainty
    in its statistics when the report is of this camera; else unchanged, with a note."""
    from pencilcal.toolkit.board.calibration_file import camera_with_report, read_calibration_file

    if not calibration:
        return camera, None, None
    report = read_calibration_file(calibration)
    if report.camera != camera:
        return camera, report, f"{calibration}: the calibration report is of another camera; its uncertainty is not used"
    return camera_with_report(camera, report, str(camera_path)), report, None


def stereo_inputs(camera, camera_path, calibration, board, methods, right=None, right_camera=None,
                  right_calibration=None):
    """What `validate_path` needs for the checks: (camera, rig keywords of
    `validate.validate_sequence`, checks from the calibration reports).

    camera: the (left) Camera read from camera_path; calibration, right_calibration:
    calib.json paths or None (a report of this very camera lends its intrinsics' covariance
    and corner-noise model to the camera, and its ``cross_validation`` to the checks);
    right, right_camera: IMAGES and camera file of a second camera rigidly fixed to the
    first (`board_poses` on them). InputError when right is given without right_camera.
    """
    from pencilcal.toolkit.board.calibration_file import uncertainty_of
    from pencilcal.toolkit.camera.formats import read_camera
    from pencilcal.toolkit.errors import InputError

    camera, report, note = _with_report(camera, camera_path, calibration)
    checks = {}
    if report is not None and report.cross_validation is not None:
        checks["two_halves"] = report.cross_validation
    if note:
        checks["notes"] = [note]
    if right is None:
        return camera, {}, checks
    if right_camera is None:
        raise InputError("the rig check needs the second camera's file (--right-camera) with its images (--right)")
    cam_r, report_r, note_r = _with_report(read_camera(right_camera), right_camera, right_calibration)
    if report_r is not None and report_r.cross_validation is not None:
        checks["two_halves_right"] = report_r.cross_validation
    if note_r:
        checks.setdefault("notes", []).append(note_r)
    covs = tuple(None if c is None else c.cov for c in (uncertainty_of(camera)[0], uncertainty_of(cam_r)[0]))
    rig = {"right_poses": board_poses(right, cam_r, board, methods), "rig_intrinsics": covs}
    return camera, rig, checks


def jackknife_inflation(fulcrum, jk, level=0.99):
    """(Fulcrum, record): the fulcrum's sigmas raised to its jackknife's where the frames
    scatter it significantly more than its sigmas say.

    fulcrum: a `toolkit.pencil.fulcrum.Fulcrum` (its sigmas as reported, e.g. with the
    sequence's noise factor); jk: `fulcrum_jackknife`'s record for the same frames. The
    jackknife variance of the ray over n leave-one-out fits, against the reported one, is
    significant when their ratio exceeds chi2(n - 1) / (n - 1) at `level`: the lines of
    different frames then disagree in a way no per-line noise explains (a fulcrum that
    moved, a shaft misdetected in a group of frames), and the jackknife's is the honest
    figure. The record: ``frames``, ``ray_sigma_jackknife_deg``, ``ratio`` (jackknife /
    reported sigma), ``inflated``; with a pivot plane also ``normal_ratio``.
    """
    from pencilcal.toolkit.pencil.sequence_noise import rescale_fulcrum

    n = int(jk["frames"])
    rec = {"frames": n, "ray_sigma_jackknife_deg": jk["ray_sigma_jackknife_deg"], "inflated": False}
    if n < 3 or not fulcrum.ray_sigma_deg > 0:
        rec["ratio"] = None
        return fulcrum, rec
    limit = chi2_isf(1.0 - level, n - 1) / (n - 1)
    ratio = jk["ray_sigma_jackknife_deg"] / fulcrum.ray_sigma_deg
    rec["ratio"] = ratio
    pivot_factor = None
    if fulcrum.pivot is not None and jk.get("normal_sigma_jackknife_deg") and fulcrum.pivot.normal_sigma_deg > 0:
        r = jk["normal_sigma_jackknife_deg"] / fulcrum.pivot.normal_sigma_deg
        rec["normal_ratio"] = r
        pivot_factor = r**2 if r**2 > limit else 1.0
    if ratio**2 <= limit and not (pivot_factor and pivot_factor > 1.0):
        return fulcrum, rec
    rec["inflated"] = True
    return rescale_fulcrum(fulcrum, max(ratio**2, 1.0) if ratio**2 > limit else 1.0, pivot_factor), rec


def point_jackknife(camera, frames, diameter, point, level=0.99, min_axes=None):
    """(FulcrumPoint, record): the 3-D fulcrum's covariance against its jackknife over frames,
    raised to it where the frames scatter the point significantly more than it says.

    camera; frames: lines.json frame dicts with shafts (their ``edges``, ``edge_cov``);
    diameter: the shafts' diameter; point: the `toolkit.pencil.fulcrum.FulcrumPoint` of all
    frames. Each frame with a shaft is left out once (`fulcrum.leave_one_out_points`); the
    jackknife covariance of the point is compared with the fit's covariance and the lines'
    play term (``play_cov``: an offset of each frame's own, which leaving frames out shows) by
    their traces, and taken in place of both when the ratio exceeds chi2(3 (n - 1)) / (3 (n - 1))
    at `level` (the width term, which every frame shares, stays). The
    record: ``frames``, ``point_sigma_jackknife`` [unit of the diameter], ``ratio``
    (jackknife / reported RMS), ``inflated``.

    A point that uses the axes of fewer than `min_axes` frames (`POINT_JACKKNIFE_AXES`) is
    not judged: leaving out an axis it does not use leaves it where it is, and leaving out
    one it uses leaves too few to fix it, so the leave-one-out points measure the gate, not
    the noise. The record then has ``ratio`` None, ``inflated`` false and ``reason``.
    """
    import dataclasses

    from pencilcal.toolkit.pencil.fulcrum import leave_one_out_points

    min_axes = POINT_JACKKNIFE_AXES if min_axes is None else int(min_axes)
    used = {im for (im, _), u in zip(point.owners, np.asarray(point.fit.inliers)) if u}
    if len(used) < min_axes:
        return point, {"frames": 0, "point_sigma_jackknife": None, "ratio": None, "inflated": False,
                       "reason": f"the point uses the axes of {len(used)} frame(s), fewer than {min_axes}: "
                                 "its jackknife would measure the gate, not the noise"}
    pts = [x for _, x in leave_one_out_points(camera, frames, diameter) if x is not None]
    if len(pts) < 3:
        return point, {"frames": len(pts), "point_sigma_jackknife": None, "ratio": None, "inflated": False}
    jk = jackknife(np.asarray(pts, float))
    n = jk["n"]
    sigma_jk = float(np.sqrt(max(np.trace(jk["cov"]), 0.0)))
    said = np.asarray(point.fit.point_cov, float)
    if point.play_cov is not None:
        said = said + np.asarray(point.play_cov, float)
    said = float(np.sqrt(max(np.trace(said), 0.0)))
    ratio = sigma_jk / said if said > 0 else None
    rec = {"frames": n, "point_sigma_jackknife": sigma_jk, "ratio": ratio, "inflated": False}
    dof = 3 * (n - 1)
    if ratio is None or ratio**2 <= chi2_isf(1.0 - level, dof) / dof:
        return point, rec
    rec["inflated"] = True
    fit = dataclasses.replace(point.fit, point_cov=jk["cov"], point_sigma=np.asarray(sigma_jk))
    return dataclasses.replace(point, fit=fit, play_cov=None), rec
