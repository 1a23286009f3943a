"""The calibration report as a page: what `pencilcal calibrate --report calib.html` writes.

The answer comes first. The page is built from the record `--report calib.json` holds
(`CalibrationResult.to_dict` with the command's inputs) and drawn with the validation
report's blocks and HTML renderer:

1. the verdict: usable / usable within this region / not usable, the headline figure and
   why (`validation.calibration_verdict`), with the figures it read;
2. the projection uncertainty over the image (mrcal-show-projection-uncertainty's map:
   the worst direction's 1-sigma [px]), the covered and the usable region outlined;
3. the cross-validation: the odd and even views calibrated apart, their projection
   difference over the image beside the one their sigmas predict, and the figures of
   every split;
4. what to add (views at the corners, tilted views, other distances);
5. the lens model and, with --model auto, how it was chosen;
6. per-view residuals, 7. corner coverage, 8. the intrinsics with their sigmas, the board's
   warp and the corner-noise model, 9. every rejected view and corner with its reason.

Example
-------
>>> import numpy as np
>>> g = coverage_grid([np.array([[10.0, 10.0], [600.0, 400.0]])], (640, 480), cells=(4, 3))
>>> g["counts"]
[[1, 0, 0, 0], [0, 0, 0, 0], [0, 0, 0, 1]]
>>> coverage_advice(g).startswith("Corners fell in 2 of 12 cells")
True
"""
from __future__ import annotations

import numpy as np

from pencilcal.toolkit.camera.splined import is_splined, splined_config
from pencilcal.toolkit.errors import InputError
from pencilcal.toolkit.io.files import atomic_write

from .calibration_figures import fig_coverage, fig_difference, fig_uncertainty, fig_views
from .report.document import Bullets, Cell, Details, Para, Report, Section, Table
from .report.format import num
from .report.html import render_html

__all__ = ["coverage_grid", "coverage_advice", "coverage_sentence", "build_calibration_report",
           "write_calibration_report", "COVERAGE_CELLS"]

# cells of the coverage grid across and down the image: ~100 px cells at 1280x720, fine
# enough to show a missing corner of the image, coarse enough that a good set fills them
COVERAGE_CELLS = (16, 9)

_REGIONS = {(0, 0): "top-left corner", (1, 0): "top edge", (2, 0): "top-right corner",
            (0, 1): "left edge", (1, 1): "centre", (2, 1): "right edge",
            (0, 2): "bottom-left corner", (1, 2): "bottom edge", (2, 2): "bottom-right corner"}


def coverage_grid(corners, image_size, cells=COVERAGE_CELLS):
    """How many corners fell in each cell of a grid over the image.

    corners: sequence of (K_i, 2) raw-pixel corners (the views' corners that entered the
    fit); image_size: (width, height) [px]; cells: (nx, ny). Returns a JSON-ready dict
    ``{"cells": [nx, ny], "image_size": [w, h], "counts": ny lists of nx ints}``.
    """
    nx, ny = cells
    w, h = image_size
    counts = np.zeros((ny, nx), int)
    for c in corners:
        c = np.asarray(c, float).reshape(-1, 2)
        if c.size == 0:
            continue
        i = np.clip(((c[:, 0] + 0.5) / w * nx).astype(int), 0, nx - 1)
        j = np.clip(((c[:, 1] + 0.5) / h * ny).astype(int), 0, ny - 1)
        np.add.at(counts, (j, i), 1)
    return {"cells": [nx, ny], "image_size": [int(w), int(h)], "counts": counts.tolist()}


def coverage_sentence(grid):
    """How many cells of the coverage grid hold a corner, in words."""
    counts = np.asarray(grid["counts"], int)
    filled = int((counts > 0).sum())
    return f"Corners fell in {filled} of {counts.size} cells of the image ({100.0 * filled / counts.size:.0f}%)."


def coverage_advice(grid):
    """A plain sentence on which part of the image needs more views.

    The image is split in nine regions (corners, edges, centre); a region is thin where
    fewer than a quarter of its cells hold any corner, or where its corners are under a
    tenth of the busiest region's. Distortion is extrapolated, not measured, there.
    """
    counts = np.asarray(grid["counts"], int)
    ny, nx = counts.shape
    filled = int((counts > 0).sum())
    thin, density = [], {}
    for (ri, rj), name in _REGIONS.items():
        sub = counts[rj * ny // 3:(rj + 1) * ny // 3, ri * nx // 3:(ri + 1) * nx // 3]
        density[name] = (float((sub > 0).mean()) if sub.size else 0.0, float(sub.sum()))
    busiest = max(d[1] for d in density.values()) or 1.0
    for name, (frac, total) in density.items():
        if frac < 0.25 or total < 0.1 * busiest:
            thin.append(name)
    head = coverage_sentence(grid)
    if not thin:
        return head + " Every part of the image is covered; no region needs more views."
    if len(thin) == 8 and "centre" not in thin:
        return (head + " Only the middle of the image holds corners: add views with the board near every border "
                "and corner (tilted): the lens distortion there is extrapolated from the middle, not measured.")
    where = ", ".join(thin)
    return (head + f" Thin or empty: {where}. Add views with the board in those parts of the image (near the "
            "border, tilted): the lens distortion there is extrapolated from the middle, not measured.")


def _intrinsics_table(rep):
    cam = rep.get("camera", {})
    K = np.asarray(cam.get("K", np.eye(3)), float)
    values = {"fx": K[0, 0], "fy": K[1, 1], "cx": K[0, 2], "cy": K[1, 2]}
    names = [n for n in (rep.get("std_intrinsics") or {})]
    dist = list(cam.get("dist") or [])
    rows = []
    for k, name in enumerate(names):
        v = values.get(name, dist[k - 4] if 4 <= k < 4 + len(dist) else None)
        s = rep["std_intrinsics"][name]
        rows.append([name, "" if v is None else f"{v:.6g}", f"{s:.3g}",
                     Cell(num(abs(s / v) * 100 if v else None, " %"), "muted")])
    return Table(["parameter", "value", "sigma", "sigma / value"], rows,
                 caption="One standard deviation from the fit's covariance under the corner errors seen (each view's "
                         "own level and the correlated part).")


def _rejections(rep):
    rows = [[r.get("image", ""), r.get("stage", ""), str(r.get("corner", "")), r.get("reason", "")]
            for r in rep.get("rejected", [])]
    return Table(["image", "stage", "corner", "reason"], rows, numeric_from=99) if rows else \
        Para("Nothing was rejected.")


def _verdict(rep):
    """Section 1: the verdict first, then its reasons, warnings and the figures it read."""
    v = rep.get("verdict")
    if not v:
        return Section("verdict", "1. Verdict", [Para("No verdict in this record (a calib.json of an older "
                                                      "pencilcal).", "note")])
    blocks = [Para(v["headline"], "lead")]
    if len(v.get("reasons") or []) > 1:           # the headline says the first
        blocks.append(Bullets([f"Also: {r}." for r in v["reasons"][1:]]))
    blocks += [Para(f"Note: {w}.", "note") for w in v.get("warnings", [])]
    c, f = rep.get("counts", {}), v.get("figures", {})
    lines = [f"{_model_name(rep)}; {c.get('views_used')} of "
             f"{c.get('images', c.get('views'))} views used, {c.get('corners_used')} corners; RMS reprojection error "
             f"{num(rep.get('rms_px'), ' px')}.",
             f"Projection uncertainty over the covered region: median {num(f.get('median_covered_px'), ' px')}, worst "
             f"{num(f.get('max_covered_px'), ' px')}; usable (<= {num(v.get('region', {}).get('threshold_px'))} px and "
             f"covered) over {num(100 * (f.get('usable_share') or 0.0))}% of the image."]
    if f.get("halves_chi2_per_dof") is not None:
        lines.append(f"Two halves of the views, pooled over every split: chi-square per dof "
                     f"{num(f['halves_chi2_per_dof'])} and projection difference {num(f['halves_projection_ratio'])} x "
                     "the predicted (1 for honest sigmas).")
    blocks.append(Bullets(lines))
    return Section("verdict", "1. Verdict", blocks)


def _uncertainty(rep):
    um = rep.get("projection_uncertainty") or {}
    if "sigma_px" not in um:
        return [Para(f"No projection uncertainty: {um.get('error', 'not in this record')}.", "note")]
    thr = (rep.get("verdict") or {}).get("region", {}).get("threshold_px", 1.0)
    return [fig_uncertainty(um, rep.get("image_size"), thr)]


def _halves_table(cv):
    rows = []

    def row(name, r, ratio_key="projection_ratio"):
        rows.append([name, num(r.get("chi2_per_dof")), num(r.get("p_value")), num(r.get("projection_rms_px")),
                     num(r.get("projection_predicted_rms_px")), num(r.get(ratio_key)), num(r.get("projection_ratio_p"))])

    oe = cv["odd_even"]
    row(f"odd / even ({oe['views'][0]} + {oe['views'][1]} views)", oe)
    rd = cv.get("random")
    if rd:
        rows.append([f"{rd['repeats']} random halves (mean)", num(rd["chi2_per_dof_mean"]), "", "", "",
                     num(rd["projection_ratio"]), ""])
    po = cv.get("pooled")
    if po:
        row(f"all {po['splits']} splits (pooled)", po)
    return Table(["split", "chi2 / dof", "p", "difference RMS [px]", "predicted RMS [px]", "ratio", "ratio's p"], rows,
                 caption="Each split's two halves calibrated apart: the chi-square of their intrinsics' difference "
                         "per degree of freedom (1 expected), and their projection difference over the covered "
                         "region, up to the rotation that aligns them, against the RMS their sigmas predict; the "
                         "ratio's p: how often halves whose errors are as their sigmas say differ by that ratio "
                         "or more (one split's ratio scatters: 1.9 happens once in 20 when one direction "
                         "dominates).")


def _cross_validation(cv, size):
    """Blocks for the two-halves cross-validation (`validation.calibration_checks`)."""
    if cv.get("error"):
        return [Para(f"The two halves could not be calibrated apart: {cv['error']}.", "note")]
    if "odd_even" not in cv:
        return [Para("No two-halves result in this record.")]
    blocks = []
    if cv.get("map"):
        blocks.append(fig_difference(cv["map"], size))
    blocks.append(_halves_table(cv))
    oe = cv["odd_even"]
    z = oe.get("z") or {}
    if z:
        blocks.append(Details("Each intrinsic's odd-even difference in its combined sigma",
                              [Table(["intrinsic", "difference / sigma"], [[k, num(v)] for k, v in z.items()])]))
    md = oe.get("projection_modes")
    if md and md.get("share"):
        blocks.append(Para(f"Along the direction that holds {100 * md['share'][0]:.0f} % of the predicted difference "
                           f"the odd and even views differ by {num(md['z'][0])} sigma, along the next two by "
                           f"{', '.join(num(x) for x in md['z'][1:]) or '-'}: where one direction holds most of the "
                           "prediction the ratio is about that one |z|, and over 1.3 in one split of five with "
                           "sigmas that are right.", "caption"))
    vs = cv.get("view_focal_scale")
    if vs:
        blocks.append(Para(f"Each view's own focal scale (its pose and one scale fitted, the rest held) scatters "
                           f"{num(vs['chi2_per_dof'])} x as its corner noise says (chi-square per dof over "
                           f"{vs['views']} views, p {num(vs['p_value'])}; 1 expected): a focus or zoom that changed "
                           "between views would show here.", "caption"))
    fr = oe.get("camera_frame")
    if fr:
        blocks.append(Para(f"Without taking out the rotation, the odd and even views' projections differ by "
                           f"{num(fr['rms_px'])} px RMS against {num(fr['predicted_rms_px'])} px predicted "
                           f"(ratio {num(fr['ratio'])}): the part of an intrinsics error that every board pose "
                           "absorbs as a turn of the camera.", "caption"))
    return blocks


def _model_name(rep):
    """The lens model in words: "opencv model with 5 coefficients", or a splined model's
    grid and control points."""
    model = str(rep.get("model"))
    if is_splined(model):
        try:
            cfg = splined_config(model)
        except InputError:
            return f"{model} model"
        return (f"splined stereographic model ({cfg.Nx} x {cfg.Ny} knots over {cfg.fov_x_deg} deg, "
                f"{cfg.parameters} control-point values)")
    return f"{model} model with {rep.get('coefficients')} coefficients"


def _model(rep):
    blocks = [Para(_model_name(rep)
                   + (f", board warp {_warp_text(rep['board_warp'])}" if rep.get("board_warp") else "")
                   + _corners_text(rep.get("board_corners")) + ".")]
    mc = rep.get("model_choice")
    if mc:
        blocks.append(Para(mc["reason"]))
        rows = [[f"{c['model']} {c['coefficients']}", str(c["parameters"]), num(c.get("fit_rms_px")),
                 num(c.get("heldout_rms_px")), num(c.get("excess_px2")), num(c.get("excess_se_px2")), c["status"]]
                for c in mc["candidates"]]
        blocks.append(Table(["model", "parameters", "fit RMS [px]", "held-out RMS [px/axis]", "excess [px^2]",
                             "its SE [px^2]", "status"], rows, text_cols=(6,),
                            caption=f"{mc['folds']}-fold cross-validation over the views: each left-out view's pose "
                                    "alone refitted through the intrinsics fitted to the others. Rule: "
                                    f"{mc['rule']}."))
    for t in rep.get("models_tried") or []:
        blocks.append(Para(f"{t['model']} {t['coefficients']} was tried first and set aside: its two halves "
                           f"{t['halves']} (chi2/dof {num(t.get('chi2_per_dof'))}, projection ratio "
                           f"{num(t.get('projection_ratio'))}).", "note"))
    return blocks


def _warp_text(w):
    return ", ".join(f"{n} {num(v)} +- {num(s)}" for n, v, s in zip(w["names"], w["value"], w["std"])) + \
        " (board units, at the board's middle)"


def _corners_text(bc):
    """The printed board's corner offsets in words (empty when not measured)."""
    if not bc:
        return ""
    if not bc.get("kept"):
        return ", the printed corners' own offsets not significant"
    return (f", the printed corners off their nominal places by {num(bc['sigma'][0])} (x) and "
            f"{num(bc['sigma'][1])} (y) board units RMS, the same in every view (in the sigmas)")


def _noise(rep):
    cn = rep.get("corner_noise")
    if not cn:
        return []
    shape = ""
    if cn.get("scale_power") or cn.get("edge"):
        shape = (f" The white level varies within a view as (local px per board unit / the view's median)^"
                 f"-{num(cn['scale_power'])} +- {num(cn['scale_power_std'])} and as exp({num(cn['edge'])} +- "
                 f"{num(cn['edge_std'])} rho^2) towards the image's edge (rho: the distance from the principal "
                 f"point over {num(cn['radius_px'])} px; log-likelihood gain {num(cn['shape_gain'])})"
                 + ("; each corner weighs in the fit by the inverse of this factor."
                    if rep.get("fit_weights") == "corner_noise" else "."))
    return [Para(f"Corner errors: white per view plus a smooth part {num(cn['ratio'])} x its variance, correlated "
                 f"over {num(cn['length_px'])} px (fitted to {cn['corners']} corners of {cn['views']} views; "
                 f"log-likelihood gain {num(cn['log_likelihood_gain'])}).{shape} The sigmas hold "
                 f"{'all of it' if shape else 'both'} ({rep.get('covariance_model')}).")]


def build_calibration_report(rep, title=None):
    """The page of a calibration record (the --report JSON): a Report, the verdict first."""
    size = rep.get("image_size")
    grid = rep.get("coverage")
    advice = (rep.get("verdict") or {}).get("advice") or [coverage_advice(grid) if grid else "No advice."]
    cv = rep.get("cross_validation") or {}
    sections = [_verdict(rep),
                Section("uncertainty", "2. Projection uncertainty", _uncertainty(rep)),
                Section("cross-validation", "3. Cross-validation: two halves of the views",
                        _cross_validation(cv, size) if cv else [Para("No two-halves result in this record.")]),
                Section("advice", "4. What to add", [Bullets(advice)]),
                Section("model", "5. Lens model", _model(rep)),
                Section("views", "6. Per-view residuals", [fig_views(rep.get("views", []))])]
    if grid:
        sections.append(Section("coverage", "7. Coverage of the image",
                                [fig_coverage(grid), Para(coverage_sentence(grid))]))
    sections.append(Section("intrinsics", f"{len(sections) + 1}. Intrinsics and their sigmas",
                            [_intrinsics_table(rep)] + _noise(rep)))
    sections.append(Section("rejected", f"{len(sections) + 1}. Rejected views and corners", [_rejections(rep)]))
    size = size or ["?", "?"]
    return Report(title or f"Calibration: {rep.get('images')}",
                  f"{size[0]}x{size[1]} px, board {rep.get('board_file')}", sections)


def write_calibration_report(path, rep, force=False):
    """Write the page (self-contained HTML) atomically; returns the Report."""
    report = build_calibration_report(rep)
    atomic_write(path, render_html(report), force)
    return report
