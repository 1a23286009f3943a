"""A calibration checked without truth: two halves of its views, and its projection uncertainty.

`calibration_halves` splits the views a calibration kept in two (the odd and the even ones,
then `RANDOM_HALVES` random halves) and solves each half alone: the same corners, lens
model and board warp as the full calibration, started from its solution, each half's
covariance from the same corner-noise model (`toolkit.board.bundle.covariance`). Where
the calibration keeps the printed board's own corner offsets (`toolkit.board.
print_errors`) or a correlated corner error fixed in the image (`toolkit.board.
image_field`), both halves saw them: each half's covariance gains its share and the two
halves' errors their covariance, so the difference holds only what differs between their
views' gains; that part goes through the projection at the full calibration, where the
gains are linearised, and each half's own errors through its own. Two calibrations of one
camera must agree within their covariances:

- on the parameters: the chi-square of the intrinsics' difference over the sum of the two
  covariances, with its degrees of freedom and p-value (mrcal's cross-validation idea);
- on the image: the rays one half sees are projected by the other, over the region the
  views cover, after the rotation that best aligns the two (`toolkit.camera.
  projection_uncertainty.projection_difference`: a common rotation is what every later pose
  absorbs); the RMS of that difference against the RMS the two covariances predict (their
  ratio is 1 for honest sigmas). The camera-frame figures, without the rotation, are given
  beside it.

`uncertainty_map` is the full calibration's projection uncertainty on a grid over the image
(the worst direction's sigma [px], up to the same rotation), with the covered cells.

Example
-------
>>> import numpy as np
>>> from pencilcal.toolkit.board.spec import board_from_dict
>>> from pencilcal.toolkit.board.calibrate import calibrate, synthetic_detections
>>> from pencilcal.toolkit.camera.model import Camera
>>> board = board_from_dict({"type": "chessboard", "squares": [9, 6], "square": 25.0})
>>> cam = Camera("opencv", 640, 480, [[530.0, 0, 320.0], [0, 530.0, 240.0], [0, 0, 1]], [-0.2, 0.05, 0, 0, 0])
>>> dets = synthetic_detections(cam, board, views=16, noise_px=0.2, seed=5)
>>> res = calibrate(dets, board, (640, 480), warp=True, corner_noise=True)
>>> cv = calibration_halves(res, dets, board, repeats=2)
>>> cv["odd_even"]["views"], cv["odd_even"]["dof"], cv["random"]["repeats"]
([8, 8], 9, 2)
>>> m = uncertainty_map(res, dets, board)
>>> bool(0 < m["median_covered_px"] < 0.5), m["grid"]
(True, [48, 36])
"""
from __future__ import annotations

import math

import numpy as np

from pencilcal.toolkit.board import image_field
from pencilcal.toolkit.board.bundle import camera_parts, covariance, penalty_normal, refine, warp_basis
from pencilcal.toolkit.board.corner_noise import WHITE
from pencilcal.toolkit.board.coverage import covered_grid
from pencilcal.toolkit.board.print_errors import covariance_term, intrinsic_gain, view_gains
from pencilcal.toolkit.camera.model import Camera
from pencilcal.toolkit.camera.projection_uncertainty import linearity, projection_difference, \
    projection_sensitivity, projection_uncertainty
from pencilcal.toolkit.errors import EstimationError
from pencilcal.toolkit.geometry.quantiles import chi2_isf, chi2_sf

__all__ = ["RANDOM_HALVES", "RATIO_DRAWS", "used_views", "calibration_halves", "uncertainty_map", "halves_agreement",
           "ratio_chance", "difference_modes", "view_focal_scales"]

#: Random halves solved besides the odd and even views.
RANDOM_HALVES = 16
#: Draws of the two halves' errors behind a projection ratio's chance probability.
RATIO_DRAWS = 2000
# a half needs at least this many views
_MIN_HALF_VIEWS = 3


def used_views(result, detections, board):
    """The views and corners a `CalibrationResult` fitted, in its solution's order: (view
    indices, board points (K_i, 3), corners (K_i, 2) [px], warp bases (K_i, 2))."""
    obj_all = board.object_points()
    idx = [i for i, u in enumerate(result.used) if u]
    objs, imgs = [], []
    for i in idx:
        d, m = detections[i], np.asarray(result.corner_used[i], bool)
        objs.append(obj_all[np.asarray(d.ids, int)][m])
        imgs.append(np.asarray(d.corners, float).reshape(-1, 2)[m])
    return idx, objs, imgs, [warp_basis(obj_all, o) for o in objs]


def _camera(layout, theta, size):
    K, dist = camera_parts(theta, layout)
    return Camera(layout.model, size[0], size[1], K, dist)


def _noise_of(result):
    if result.covariance is None or result.covariance.model == "white":
        return None
    return result.corner_noise if result.corner_noise is not None else WHITE


def _solve_half(result, views, subset):
    _, objs, imgs, bases = views
    sol = result.solution
    o, p, b = [objs[j] for j in subset], [imgs[j] for j in subset], [bases[j] for j in subset]
    w = None if result.weights is None else [result.weights[j] for j in subset]
    half = refine(result.layout, sol.theta, sol.poses[subset], o, p, b if result.layout.warp else None, warp=sol.warp,
                  weights=w)
    pr, fd = result.print_errors, result.image_field
    cov = covariance(result.layout, half, o, p, b if result.layout.warp else None, _noise_of(result), w,
                     shared=pr if pr is not None and pr.kept else None, field=fd if fd is not None and fd.kept else None)
    return half, cov


def _region_summary(diff, pred2):
    """RMS and max of the differences (N, 2), the RMS their predicted 2 x 2 covariances
    (N, 2, 2) give, and the ratio."""
    ok = np.all(np.isfinite(diff), -1) & np.all(np.isfinite(pred2), (-1, -2))
    d2 = np.sum(diff[ok] ** 2, -1)
    p2 = np.maximum(np.trace(pred2[ok], axis1=-2, axis2=-1), 0.0)
    rms, pred = math.sqrt(float(np.mean(d2))), math.sqrt(float(np.mean(p2)))
    return {"rms_px": rms, "max_px": float(np.sqrt(d2.max())), "predicted_rms_px": pred,
            "ratio": rms / pred if pred > 0 else None}


def _sensitivities(camera_a, camera_b, pixels, region, shared=None):
    """`projection_sensitivity` at `pixels` of both calibrations and, with `shared`, of the
    camera the shared errors are linearised at (else zeros): (Aa, Ab, As), each (N, 2, P)."""
    Aa = projection_sensitivity(camera_a, pixels, region)
    Ab = projection_sensitivity(camera_b, pixels, region)
    return Aa, Ab, projection_sensitivity(shared[1], pixels, region) if shared is not None else np.zeros_like(Aa)


def _pred(camera_a, cov_a, camera_b, cov_b, pixels, region, shared=None, sens=None):
    """(N, 2, 2) the covariance of the difference of two calibrations' projections at
    `pixels`, each one's own errors linearised at its own intrinsics; shared : (D (P, P), the
    camera it is linearised at) for the errors both saw (the printed board's corners, the
    image-fixed field): D is their part of the difference of the intrinsics, taken through
    the projection at that one camera, None: none. sens : `_sensitivities` at these pixels
    (None: computed)."""
    Aa, Ab, As = sens if sens is not None else _sensitivities(camera_a, camera_b, pixels, region, shared)
    out = Aa @ cov_a @ np.swapaxes(Aa, -1, -2) + Ab @ cov_b @ np.swapaxes(Ab, -1, -2)
    if shared is not None:
        out = out + As @ shared[0] @ np.swapaxes(As, -1, -2)
    return out


def _root(C):
    """L with L L^T = C for a symmetric positive semi-definite C (negative round-off cut)."""
    w, V = np.linalg.eigh(0.5 * (C + C.T))
    return V * np.sqrt(np.clip(w, 0.0, None))


def _difference_factor(camera_a, cov_a, camera_b, cov_b, region, shared=None, ok=None, sens=None):
    """(G (2M, 3P), the region's pixels used (M_all,) bool): the halves' pixel differences
    over `region` under their covariances are ``G z`` with z standard normal, each half's own
    errors through its own linearised projection, the shared ones (`_pred`'s `shared`)
    through theirs, up to the aligning rotation; G None where no pixel projects. ok : a mask
    of the pixels to keep besides (None: all); sens : `_sensitivities` over the region."""
    Aa, Ab, As = sens if sens is not None else _sensitivities(camera_a, camera_b, region, region, shared)
    good = np.all(np.isfinite(Aa), (-1, -2)) & np.all(np.isfinite(Ab), (-1, -2)) & np.all(np.isfinite(As), (-1, -2))
    if ok is not None:
        good &= ok
    if not np.any(good):
        return None, good
    P = cov_a.shape[0]
    parts = [Aa[good] @ _root(cov_a), -(Ab[good] @ _root(cov_b))]
    if shared is not None:
        parts.append(As[good] @ _root(shared[0]))
    return np.concatenate([g.reshape(-1, P) for g in parts], -1), good


def ratio_chance(camera_a, cov_a, camera_b, cov_b, region, observed, draws=RATIO_DRAWS, seed=0, shared=None,
                 sens=None):
    """The probability that two calibrations whose errors are as their covariances say
    differ over `region` (M, 2) by a projection ratio of `observed` or more: the share of
    `draws` pairs of errors drawn from them (through each one's linearised projection, up
    to the aligning rotation) whose RMS difference is at least `observed` x the predicted
    RMS. A one-split figure's p-value: when the difference lies along one direction (a
    focal length, say) the ratio scatters like |z|, and 1.9 happens once in 20 splits.
    shared : as `_pred` (the errors both calibrations saw), None: independent; sens : the
    projections' sensitivities over the region, as `_pred` takes them (None: computed)."""
    G, ok = _difference_factor(camera_a, cov_a, camera_b, cov_b, region, shared, sens=sens)
    if G is None or observed is None:
        return None
    M = int(ok.sum())
    rng = np.random.default_rng(seed)
    pred2 = float(np.sum(G * G)) / M
    if pred2 <= 0:
        return None
    # the RMS difference squared of a draw is z^T (G^T G / M) z: only G's singular values matter
    lam = np.linalg.eigvalsh(G.T @ G) / M
    lam = lam[lam > 1e-12 * lam.max()]
    z2 = rng.standard_normal((int(draws), lam.size)) ** 2
    ratios = np.sqrt(z2 @ lam / pred2)
    return float(np.mean(ratios >= observed))


def difference_modes(camera_a, cov_a, camera_b, cov_b, region, shared=None, modes=3, sens=None):
    """The halves' projection difference over `region` (M, 2) split along the directions of
    its predicted covariance (as `ratio_chance` draws it): per mode, largest first, its share
    of the predicted mean square and the observed difference's z along it. The projection
    ratio squared is ``sum share_k z_k^2`` (up to the part outside the modes' span, which the
    covariance says cannot occur): one mode holding most of the prediction makes the ratio
    scatter like |z| of one normal. Returns ``{"share": [...], "z": [...], "outside_px2"}``
    or None where no projection is found. sens : as `ratio_chance`."""
    diff = projection_difference(camera_a, camera_b, region, region)
    G, ok = _difference_factor(camera_a, cov_a, camera_b, cov_b, region, shared, np.all(np.isfinite(diff), -1), sens)
    if G is None:
        return None
    U, s, _ = np.linalg.svd(G, full_matrices=False)
    keep = s > 1e-9 * s.max()
    U, s = U[:, keep], s[keep]
    d = diff[ok].reshape(-1)
    proj = U.T @ d
    M = int(ok.sum())
    lam = s * s / M
    rest = d - U @ proj
    k = min(int(modes), s.size)
    return {"share": [float(x) for x in lam[:k] / lam.sum()], "z": [float(x) for x in (proj / s)[:k]],
            "outside_px2": float(rest @ rest / M)}


def halves_agreement(camera_a, cov_a, camera_b, cov_b, grid, shared=None, modes=False):
    """Do two calibrations of one camera agree within their covariances (P, P) of their own
    errors? grid : the `CoveredGrid` of the views; shared : (D (P, P), camera) the part of
    their difference due to the errors both saw (the printed board's corner offsets,
    `toolkit.board.print_errors`, the image-fixed field) and the camera that part is
    linearised at (`_pred`), None: none. Returns the chi-square record and the projection
    differences over the covered region (up to rotation, and in the camera frame), plus the
    maps of both over the whole grid; with `modes` the difference along its predicted
    modes (`difference_modes`, ``projection_modes``)."""
    names = camera_a.dist.size + 4
    d = np.r_[camera_a.fx - camera_b.fx, camera_a.fy - camera_b.fy, camera_a.cx - camera_b.cx,
              camera_a.cy - camera_b.cy, camera_a.dist - camera_b.dist]
    C = cov_a + cov_b if shared is None else cov_a + cov_b + shared[0]
    free = np.diag(C) > 0
    w, V = np.linalg.eigh(C[np.ix_(free, free)])
    keep = w > 1e-12 * w.max()
    df = V.T @ d[free]
    chi2, dof = float(np.sum(df[keep] ** 2 / w[keep])), int(keep.sum())
    z = [float(d[i] / math.sqrt(C[i, i])) if C[i, i] > 0 else None for i in range(names)]
    region = grid.pixels()
    rec = {"chi2": chi2, "dof": dof, "p_value": float(chi2_sf(chi2, dof)) if dof else None,
           "chi2_per_dof": chi2 / dof if dof else None, "z_values": z}
    # each calibration's own error linearised at its own estimate: the difference's
    # covariance is the sum of the two projection covariances (not C_a + C_b through one
    # Jacobian, which a lens model with nearly degenerate coefficients turns into
    # nonsense); the shared errors' part through the projection at the camera its gains
    # were linearised at, for the same reason
    # the sensitivities once, over every cell (the covered ones are the region's)
    centres = grid.centres().reshape(-1, 2)
    every = _sensitivities(camera_a, camera_b, centres, region, shared)
    inside = grid.mask.reshape(-1)
    sens = tuple(A[inside] for A in every)
    covered = _region_summary(projection_difference(camera_a, camera_b, region, region),
                              _pred(camera_a, cov_a, camera_b, cov_b, region, region, shared, sens))
    frame = _region_summary(projection_difference(camera_a, camera_b, region),
                            _pred(camera_a, cov_a, camera_b, cov_b, region, None, shared))
    rec.update(projection_rms_px=covered["rms_px"], projection_max_px=covered["max_px"],
               projection_predicted_rms_px=covered["predicted_rms_px"], projection_ratio=covered["ratio"],
               projection_ratio_p=ratio_chance(camera_a, cov_a, camera_b, cov_b, region, covered["ratio"],
                                               shared=shared, sens=sens),
               projection_modes=difference_modes(camera_a, cov_a, camera_b, cov_b, region, shared, sens=sens)
               if modes else None,
               camera_frame=frame)
    full = projection_difference(camera_a, camera_b, centres, region)
    pred = np.sqrt(np.maximum(np.trace(_pred(camera_a, cov_a, camera_b, cov_b, centres, region, shared, every),
                                       axis1=-2, axis2=-1), 0.0))
    rec["_maps"] = (np.linalg.norm(full, axis=-1).reshape(grid.shape), pred.reshape(grid.shape))
    return rec


def _shared_gains(result, views, detections):
    """Each used view's gains at the calibration's solution of the errors all views share:
    (`print_errors.gains` or None when the printed board's corner offsets are not in its
    model, `image_field.gains` or None without an image-fixed field)."""
    from pencilcal.toolkit.board.bundle import view_jacobians

    pr, fd = result.print_errors, result.image_field
    prints, field = pr is not None and pr.kept, fd is not None and fd.kept
    if not (prints or field) or result.solution is None:
        return None, None
    idx, objs, imgs, bases = views
    jac = view_jacobians(result.layout, result.solution, objs, imgs, bases if result.layout.warp else None)
    pg = fg = None
    if prints:
        ids = [np.asarray(detections[i].ids, int).ravel()[np.asarray(result.corner_used[i], bool)] for i in idx]
        n = int(max(int(i.max()) for i in ids if i.size) + 1)
        pg = view_gains(jac, ids, n, result.weights)
    if field:
        fg = image_field.view_gains(jac, imgs, result.camera.size, fd.length_px, result.weights)
    return pg, fg


def _shared(result, gains, first, second):
    """(the shared errors' part of each half's covariance (P, P) x 2, their cross
    covariance (P, P)): the printed corners' and the image-fixed field's, linearised at
    the full calibration; None without them."""
    if gains is None or all(g is None for g in gains):
        return None
    T = result.layout.transform(result.solution.theta)
    P = T.shape[0]
    prior = penalty_normal(result.layout, result.solution.theta)
    out = np.zeros((3, P, P))
    for g, term in zip(gains, (lambda a, b: covariance_term(a, b, result.print_errors),
                               lambda a, b: image_field.covariance_term(a, b, result.image_field,
                                                                        result.camera.size))):
        if g is None:
            continue
        Ga, Gb = intrinsic_gain(g, first, T, prior)[:P], intrinsic_gain(g, second, T, prior)[:P]
        out += [term(Ga, Ga), term(Gb, Gb), term(Ga, Gb)]
    return out[0], out[1], out[2]


def _split(result, views, grid, first, size, gains=None, modes=False):
    idx = views[0]
    second = [j for j in range(len(idx)) if j not in set(first)]
    if min(len(first), len(second)) < _MIN_HALF_VIEWS:
        raise EstimationError(f"two halves need at least {2 * _MIN_HALF_VIEWS} views, got {len(idx)}")
    (sa, ca), (sb, cb) = _solve_half(result, views, list(first)), _solve_half(result, views, second)
    if not (np.all(np.isfinite(ca.intrinsics)) and np.all(np.isfinite(cb.intrinsics))):
        raise EstimationError("a half's intrinsics are not determined (no covariance)")
    shared = _shared(result, gains, list(first), second)
    if shared is not None:
        # the shared errors' gains are linearised at the full calibration: their part of
        # the difference, (G_a - G_b) e, goes through the projection there. Taken through
        # each half's own projection instead, a lens model whose coefficients the views do
        # not determine (OpenCV's rational terms, each half thousands apart) turned it into
        # a predicted difference 11 x the real one (opencv 14, da Vinci left views)
        shared = (shared[0] + shared[1] - shared[2] - shared[2].T, result.camera)
    rec = halves_agreement(_camera(result.layout, sa.theta, size), ca.intrinsics,
                           _camera(result.layout, sb.theta, size), cb.intrinsics, grid, shared, modes)
    rec["z"] = dict(zip(result.layout.names, rec.pop("z_values")))
    rec["views"] = [len(first), len(second)]
    return rec


def _map_list(a):
    return [[None if not np.isfinite(v) else round(float(v), 4) for v in row] for row in a]


def calibration_halves(result, detections, board, repeats=RANDOM_HALVES, seed=0):
    """The two-halves check of a `CalibrationResult` (the module's docstring).

    detections, board : what `calibrate` was given. repeats : random halves besides the odd
    and even views.

    Returns ``{"odd_even": rec, "random": summary, "pooled": summary, "map": {...}}``: ``rec`` as
    `halves_agreement` (``z``: each intrinsic's difference in its combined sigma; ``views``);
    the random halves' mean chi-square per dof, the ratio of their pooled projection RMS to
    the predicted one, and the fraction inside the 68.3 % region with its binomial band;
    ``pooled`` the same two figures over every split, odd-even included (one split's
    figures scatter: a difference along one direction gives a ratio distributed as |z|);
    the map holds the odd-even difference and its predicted RMS per grid cell [px] and the
    covered cells. EstimationError when a half cannot be solved (fewer than 6 views).
    """
    from pencilcal.validation.checks import REGION, binomial_band

    views = used_views(result, detections, board)
    size = result.camera.size
    grid = covered_grid(views[2], size)
    n = len(views[0])
    gains = _shared_gains(result, views, detections)
    odd_even = _split(result, views, grid, list(range(0, n, 2)), size, gains, modes=True)
    maps = odd_even.pop("_maps")
    out = {"method": "halves solved apart with the calibration's corners, lens model, board warp and corner-noise "
                     "model, the printed board's corner offsets and the corners' image-fixed error shared by "
                     "both; projection differences over the covered region, up to the rotation that aligns them",
           "odd_even": odd_even}
    recs = []
    if repeats:
        rng = np.random.default_rng(seed)
        for _ in range(int(repeats)):
            r = _split(result, views, grid, sorted(rng.choice(n, n // 2, replace=False).tolist()), size, gains)
            r.pop("_maps")
            recs.append(r)
        inside = float(np.mean([r["chi2"] < chi2_isf(1.0 - REGION, r["dof"]) for r in recs]))
        lo, hi = binomial_band(len(recs))
        out["random"] = {
            "repeats": len(recs), "chi2_per_dof_mean": float(np.mean([r["chi2_per_dof"] for r in recs])),
            "projection_ratio": math.sqrt(sum(r["projection_rms_px"] ** 2 for r in recs)
                                          / sum(r["projection_predicted_rms_px"] ** 2 for r in recs)),
            "inside": inside, "expected": REGION, "band": [lo, hi], "consistent": bool(lo <= inside <= hi),
            "chi2_per_dof": [r["chi2_per_dof"] for r in recs]}
    every = [odd_even] + recs
    out["pooled"] = {"splits": len(every),
                     "chi2_per_dof": float(np.mean([r["chi2_per_dof"] for r in every])),
                     "projection_ratio": math.sqrt(sum(r["projection_rms_px"] ** 2 for r in every)
                                                   / sum(r["projection_predicted_rms_px"] ** 2 for r in every)),
                     "projection_rms_px": math.sqrt(float(np.mean([r["projection_rms_px"] ** 2 for r in every]))),
                     "projection_predicted_rms_px": math.sqrt(float(np.mean([r["projection_predicted_rms_px"] ** 2
                                                                             for r in every])))}
    out["map"] = {"step_px": grid.step_px, "grid": [grid.shape[1], grid.shape[0]],
                  "difference_px": _map_list(maps[0]), "predicted_px": _map_list(maps[1]),
                  "covered": grid.mask.astype(int).tolist()}
    return out


def view_focal_scales(result, detections, board, largest=3):
    """Does each view see the camera's focal scale, within its noise? Each used view's pose
    and one focal scale (fx and fy by one factor, the rest held at the calibration) fitted
    to its corners, linearised at the solution, as the final fit weighs them; its variance
    the sandwich under the calibration's corner-noise model (the view's level, its shape and
    correlated part). A focus or zoom that changed between the views, or a board that
    bends differently in each, scatters these scales beyond their sigmas and shows in the
    halves' focal difference without any corner noise to carry it.

    Returns ``{"views", "chi2_per_dof", "p_value" (of the weighted scatter about the
    weighted mean, V - 1 dof), "tau" (the scatter's part beyond the noise, a relative
    scale: DerSimonian-Laird), "sigma_median" (a view's relative sigma), "largest": [[view
    index, z], ...]}``, or None for a model without a noise model or fewer than 3 views.
    """
    from pencilcal.toolkit.board.bundle import board_scale, view_jacobians
    from pencilcal.toolkit.board.corner_noise import CornerView, kernel, variance_factor, white_variance

    noise = _noise_of(result)
    if noise is None or result.solution is None:
        return None
    idx, objs, imgs, bases = used_views(result, detections, board)
    if len(idx) < 3:
        return None
    lay, sol = result.layout, result.solution
    T = lay.transform(sol.theta)
    e = np.zeros(T.shape[0])
    e[:2] = sol.theta[:2]
    # the focal scale in the free parameters (fx follows fy where the aspect is held)
    ef = np.linalg.lstsq(T, e, rcond=None)[0]
    weights = result.weights if result.weights is not None else [None] * len(objs)
    est, var = [], []
    for (r, Jg, Jp, _), pose, img, w in zip(view_jacobians(lay, sol, objs, imgs, bases if lay.warp else None),
                                            sol.poses, imgs, weights):
        img = np.asarray(img, float)
        d = variance_factor(noise, img, board_scale(pose, Jp), sol.theta[2:4])
        sw = np.ones(img.shape[0]) if w is None else np.sqrt(np.asarray(w, float))
        g = np.repeat(np.sqrt(d) * sw, 2)
        X = np.hstack([Jp, (Jg[:, :ef.size] @ ef)[:, None]]) * np.repeat(sw, 2)[:, None]
        rw = r.reshape(-1) * np.repeat(sw, 2)
        H = np.linalg.inv(X.T @ X)
        k = kernel(img, noise.length_px) if noise.ratio > 0 else None
        level = white_variance(CornerView(img, -(rw / g).reshape(-1, 2), (Jp * np.repeat(sw, 2)[:, None]) / g[:, None]),
                               noise, k)
        GX = X * g[:, None]
        meat = GX.T @ GX
        if k is not None:
            X3 = GX.reshape(img.shape[0], 2, -1)
            meat = meat + noise.ratio * np.einsum("kbp,kbq->pq", X3, np.einsum("kl,lbq->kbq", k, X3))
        est.append(float((H @ (X.T @ rw))[-1]))
        var.append(float(level * (H @ meat @ H)[-1, -1]))
    s, v = np.array(est), np.array(var)
    w = 1.0 / v
    m = float(np.sum(w * s) / w.sum())
    Q, dof = float(np.sum(w * (s - m) ** 2)), s.size - 1
    tau2 = max(0.0, (Q - dof) / (w.sum() - np.sum(w * w) / w.sum()))
    z = (s - m) / np.sqrt(v)
    top = np.argsort(-np.abs(z))[:int(largest)]
    return {"views": int(s.size), "chi2_per_dof": Q / dof, "p_value": float(chi2_sf(Q, dof)), "tau": math.sqrt(tau2),
            "sigma_median": float(np.median(np.sqrt(v))),
            "largest": [[int(idx[i]), round(float(z[i]), 2)] for i in top]}


def uncertainty_map(result, detections, board):
    """The projection uncertainty of a `CalibrationResult` on a grid over the image.

    Returns ``{"step_px", "grid": [nx, ny], "sigma_px": ny x nx (the worst direction's
    standard deviation, up to the rotation fitted over the covered region), "covered": ny
    x nx 0/1, "covered_fraction", "median_covered_px", "max_covered_px", "median_image_px",
    "max_image_px"}``.
    """
    views = used_views(result, detections, board)
    grid = covered_grid(views[2], result.camera.size)
    if result.cov_intrinsics is None:
        raise EstimationError("the calibration has no covariance (its intrinsics are not determined)")
    centres = grid.centres().reshape(-1, 2)
    sigma, _ = projection_uncertainty(result.camera, result.cov_intrinsics.cov, centres, grid.pixels())
    sigma = sigma.reshape(grid.shape)
    inside = sigma[grid.mask & np.isfinite(sigma)]
    allv = sigma[np.isfinite(sigma)]
    region = grid.pixels()
    dep = linearity(result.camera, result.cov_intrinsics.cov, region)["departure_share"] if len(region) else None
    return {"step_px": grid.step_px, "grid": [grid.shape[1], grid.shape[0]], "sigma_px": _map_list(sigma),
            "covered": grid.mask.astype(int).tolist(), "covered_fraction": grid.fraction,
            "median_covered_px": float(np.median(inside)) if inside.size else None,
            "max_covered_px": float(inside.max()) if inside.size else None,
            "median_image_px": float(np.median(allv)) if allv.size else None,
            "max_image_px": float(allv.max()) if allv.size else None,
            "linear_departure": None if dep is None else (float(dep) if math.isfinite(dep) else "inf")}
