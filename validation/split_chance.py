"""How often honest sigmas give a calibration's odd/even split: its own views simulated.

A split's projection ratio is one draw, and `calibration_checks.ratio_chance` gives its
chance under the halves' linearised covariances. This runner asks the same of the whole
pipeline: each run draws new corners for the calibration's own views (the same corners of the
same views, at the pixels its intrinsics, poses and warp put them) with errors from its own
noise model (each view's white level and its shape within the view, the correlated part, the
printed board's corner offsets and the image-fixed field where kept), calibrates them as
`pencilcal calibrate` does (the same lens model, warp and corner-noise model; no view
rejected, so the odd/even split holds the same views) and checks the halves. Per run: the
odd/even chi-square per dof, projection ratio and its `projection_ratio_p`, the pooled
figures, and the nine intrinsics' errors against the simulated truth in their sigmas.

`summary` gives the share of runs whose odd/even ratio reaches the real one (the split's
chance with the noise model's own estimation error in it), the mean squared ratio (1 for
honest sigmas), the p-values' shares under 0.1 and 0.5, and the truth's mean z^2:

    python -m pencilcal.validation.split_chance davinci/left --board board.yaml --seeds 100:180

Example
-------
>>> from pencilcal.toolkit.board.calibrate import calibrate, synthetic_detections
>>> from pencilcal.validation.field_coverage import BOARD, LENS
>>> dets = synthetic_detections(LENS, BOARD, views=12, noise_px=0.2, seed=5)
>>> r = run(calibrate(dets, BOARD, LENS.size, warp=True, corner_noise=True), dets, BOARD, 1, repeats=0)
>>> r["views"], len(r["z_truth"])
(12, 9)
"""
from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import numpy as np

from pencilcal.toolkit.board.bundle import board_scale, view_jacobians
from pencilcal.toolkit.board.calibrate import calibrate
from pencilcal.toolkit.board.corner_noise import kernel, variance_factor
from pencilcal.toolkit.board.detect import BoardDetection
from pencilcal.validation.calibration_checks import calibration_halves, used_views
from pencilcal.validation.field_coverage import smooth_field
from pencilcal.validation.metrics import seed_list

__all__ = ["simulated_views", "run", "summary", "main"]


def _correlated(rng, px, ratio, length_px):
    """(K, 2) draws of unit-level errors whose correlated part is ``ratio`` x the white one over
    ``length_px`` [px] at the points px (K, 2)."""
    w, V = np.linalg.eigh(kernel(px, length_px))
    return math.sqrt(ratio) * ((V * np.sqrt(np.clip(w, 0.0, None))) @ rng.standard_normal((px.shape[0], 2)))


def simulated_views(result, detections, board, seed):
    """New detections (list, None where the calibration used no view) of a `CalibrationResult`'s
    own views and corners: its projection of each corner plus errors drawn from its noise
    model (module docstring); and the truth, its full intrinsic vector (P,)."""
    rng = np.random.default_rng([int(seed), 25, 7])
    sol, noise, layout = result.solution, result.corner_noise, result.layout
    idx, objs, imgs, bases = used_views(result, detections, board)
    obj_all = board.object_points()
    pr, fd = result.print_errors, result.image_field
    var = np.asarray(pr.variance, float) if pr is not None and pr.kept else np.zeros(2)
    offsets = np.zeros_like(obj_all, dtype=float)
    offsets[:, :2] = rng.standard_normal((obj_all.shape[0], 2)) * np.sqrt(var)
    field = fd is not None and fd.kept
    share = float(fd.share) if field else 0.0
    shared_field = smooth_field(rng, math.sqrt(fd.variance_px2), fd.length_px) if field else None
    levels = np.asarray(result.covariance.sigma_w, float)
    ids_used = [np.asarray(detections[i].ids, int).ravel()[np.asarray(result.corner_used[i], bool)] for i in idx]
    b = bases if layout.warp else None
    # residuals against zeros are the projections, negated: the printed corners where
    # they sit, the nominal ones for the board's local scale (the shape's)
    printed = view_jacobians(layout, sol, [obj_all[ids] + offsets[ids] for ids in ids_used],
                             [np.zeros((ids.size, 2)) for ids in ids_used], b)
    nominal = view_jacobians(layout, sol, objs, imgs, b)
    out = [None] * len(detections)
    for j, i in enumerate(idx):
        d, ids, px, Jp = detections[i], ids_used[j], -printed[j][0], nominal[j][2]
        e = rng.standard_normal(px.shape)
        if noise is not None:
            f = variance_factor(noise, px, board_scale(sol.poses[j], Jp), sol.theta[2:4])
            if noise.ratio > 0:
                e = e + _correlated(rng, px, noise.ratio * (1.0 - share), noise.length_px)
            e = e * np.sqrt(f)[:, None]
        e = e * levels[j]
        if shared_field is not None:
            e = e + shared_field(px)
        out[i] = BoardDetection(ids.copy(), px + e, d.image_size, d.marker_ids, d.marker_corners, d.symmetric)
    return out, sol.theta.copy()


def run(result, detections, board, seed, repeats=4):
    """One run (module docstring): a dict of the seed, the views used, the odd/even figures
    (``chi2_per_dof``, ``ratio``, ``ratio_p``), the pooled ones over odd/even and ``repeats``
    random halves, and the nine intrinsics' errors in their sigmas (``z_truth``)."""
    sim, truth = simulated_views(result, detections, board, seed)
    size = result.camera.size
    res = calibrate(sim, board, size, model=result.model, coefficients=result.coefficients, warp=result.layout.warp,
                    twist=result.layout.twist, corner_noise=result.corner_noise is not None, outlier_view_sigma=None)
    h = calibration_halves(res, sim, board, repeats=repeats, seed=int(seed))
    oe = h["odd_even"]
    n = min(9, truth.size)
    z = (res.solution.theta[:n] - truth[:n]) / np.sqrt(np.diag(res.covariance.intrinsics)[:n])
    return {"seed": int(seed), "views": int(sum(res.used)), "chi2_per_dof": oe["chi2_per_dof"],
            "ratio": oe["projection_ratio"], "ratio_p": oe["projection_ratio_p"],
            "pooled_chi2_per_dof": h["pooled"]["chi2_per_dof"], "pooled_ratio": h["pooled"]["projection_ratio"],
            "z_truth": [float(v) for v in z]}


def summary(rows, observed):
    """The runs against the real split's ratio ``observed``: ``runs``, ``at_least`` (the share
    of odd/even ratios >= observed), ``over_1_3``, ``mean_ratio2``, ``p_under`` (shares of
    ``ratio_p`` under 0.1 and 0.5), ``chi2_per_dof``, ``pooled_ratio`` (means), ``truth_z2``
    (the intrinsics' mean z^2) and ``within_1`` (their share within one sigma)."""
    r = np.array([x["ratio"] for x in rows], float)
    p = np.array([x["ratio_p"] for x in rows], float)
    z = np.abs(np.array([x["z_truth"] for x in rows], float))
    return {"runs": len(rows), "observed": float(observed), "at_least": float(np.mean(r >= observed)),
            "over_1_3": float(np.mean(r > 1.3)), "mean_ratio2": float(np.mean(r ** 2)),
            "p_under": [float(np.mean(p < 0.1)), float(np.mean(p < 0.5))],
            "chi2_per_dof": float(np.mean([x["chi2_per_dof"] for x in rows])),
            "pooled_ratio": float(np.mean([x["pooled_ratio"] for x in rows])),
            "truth_z2": float(np.mean(z ** 2)), "within_1": float(np.mean(z < 1.0))}


def main(argv=None):
    """Calibrate the images as `pencilcal calibrate` does, then run the seeds (module docstring)."""
    import argparse

    from pencilcal.toolkit.board.calibrate import detect_views
    from pencilcal.validation.calibration_checks import calibration_halves as halves

    ap = argparse.ArgumentParser(prog="python -m pencilcal.validation.split_chance",
                                 description=__doc__.split("\n")[0])
    ap.add_argument("images", nargs="+", help="the calibration's views (files, folders or globs)")
    ap.add_argument("--board", required=True, help="board file (.yaml/.json)")
    ap.add_argument("--seeds", type=seed_list, default="100:110", help="A:B (seeds A to B-1) or a,b,c")
    ap.add_argument("--halves", type=int, default=4, help="random halves per run besides odd/even")
    ap.add_argument("--out", default=None, help="a JSON lines file the runs are appended to")
    a = ap.parse_args(argv)
    board, dets, size = detect_views(a.images, a.board)
    res = calibrate(dets, board, size, warp=True, corner_noise=True)
    observed = halves(res, dets, board, repeats=0)["odd_even"]["projection_ratio"]
    print(json.dumps({"views": int(sum(res.used)), "odd_even_ratio": observed}), flush=True)
    rows = []
    for seed in a.seeds:
        rows.append(run(res, dets, board, seed, a.halves))
        print(json.dumps({k: rows[-1][k] for k in ("seed", "chi2_per_dof", "ratio", "ratio_p")}), flush=True)
        if a.out:
            with Path(a.out).open("a") as f:
                f.write(json.dumps(rows[-1]) + "\n")
    print(json.dumps(summary(rows, observed)))


if __name__ == "__main__":
    sys.exit(main())
