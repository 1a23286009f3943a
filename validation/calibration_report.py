"""The calibration report as a page: what `pencilcal calibrate --report calib.html` writes.

Users of Kalibr and mrcal expect to *see* a calibration: how well each view fits, where
in the image the corners fell (lens distortion is only known where corners were), the
parameters with their sigmas, and a plain sentence on what to add. The page is built from
the same record `--report calib.json` holds (cli/calibrate.py), with the corner coverage
(`coverage_grid`) added, and drawn with the validation report's blocks and HTML renderer:

1. summary: model, views used, RMS, and the advice (`coverage_advice`);
2. per-view residuals: a bar per view (RMS), rejected views marked with their reasons;
3. coverage: a heatmap of the used corners over the image;
4. the intrinsics with their standard deviations;
5. the two-halves cross-validation, when the record has one;
6. every rejected view and corner with its reason.

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

from pencilcal.toolkit.io.files import atomic_write

from .report.document import Bullets, Cell, Para, Plot, Report, Section, Table
from .report.figures import legend_below, new_figure, png_bytes
from .report.format import num
from .report.html import render_html

__all__ = ["coverage_grid", "coverage_advice", "build_calibration_report", "write_calibration_report",
           "COVERAGE_CELLS"]

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
    head = f"Corners fell in {filled} of {counts.size} cells of the image ({100.0 * filled / counts.size:.0f}%)."
    if not thin:
        return head + " Every part of the image is covered; no region needs more views."
    if len(thin) == 8 and "centre" not in thin:
        return (head + " Only the middle of the image holds corners: add views with the board near every border "
                "and corner (tilted): the lens distortion there is extrapolated from the middle, not measured.")
    where = ", ".join(thin)
    return (head + f" Thin or empty: {where}. Add views with the board in those parts of the image (near the "
            "border, tilted): the lens distortion there is extrapolated from the middle, not measured.")


def _summary(rep, advice):
    c = rep.get("counts", {})
    lines = [f"{rep.get('model')} model with {rep.get('coefficients')} coefficients; "
             f"{c.get('views_used')} of {c.get('images')} views used, {c.get('corners_used')} corners; "
             f"RMS reprojection error {num(rep.get('rms_px'), ' px')}.",
             f"{c.get('views_rejected', 0)} outlier view(s) and {c.get('corners_rejected', 0)} outlier corner(s) "
             f"rejected, {c.get('views_skipped', 0)} view(s) skipped, {c.get('unreadable', 0)} unreadable."]
    return Section("summary", "1. Summary", [Para(advice, "lead"), Bullets(lines)])


def _fig_views(views):
    fig = new_figure(figsize=(8.0, 3.0))
    ax = fig.add_subplot()
    xs = np.arange(len(views))
    rms = np.array([v.get("rms_px") if v.get("rms_px") is not None else np.nan for v in views], float)
    used = np.array([bool(v.get("used")) for v in views])
    ax.bar(xs[used], rms[used], color="C0", label="used")
    bad = ~used & np.isfinite(rms)
    if bad.any():
        ax.bar(xs[bad], rms[bad], color="C3", label="rejected")
    none = ~np.isfinite(rms)
    if none.any():
        ax.plot(xs[none], np.zeros(none.sum()), "x", color="0.5", label="no corners / skipped")
    ax.set_xlabel("view")
    ax.set_ylabel("RMS residual [px]")
    legend_below(fig, *ax.get_legend_handles_labels())  # below the bars, never over them
    return Plot(png_bytes(fig), "Per-view RMS of the corner residuals; red: views rejected as outliers, grey "
                "crosses: views without a usable board.", "bar chart of per-view residuals")


def _fig_coverage(grid):
    counts = np.asarray(grid["counts"], float)
    w, h = grid["image_size"]
    fig = new_figure(figsize=(6.4, 6.4 * h / w + 0.6))
    ax = fig.add_subplot()
    shown = np.where(counts > 0, counts, np.nan)
    im = ax.imshow(shown, extent=(-0.5, w - 0.5, h - 0.5, -0.5), cmap="viridis", interpolation="nearest")
    ny, nx = counts.shape
    for j in range(ny):
        for i in range(nx):
            if counts[j, i] == 0:
                ax.text((i + 0.5) * w / nx - 0.5, (j + 0.5) * h / ny - 0.5, "0", ha="center", va="center",
                        color="C3", fontsize=8)
    ax.set_xlim(-0.5, w - 0.5)
    ax.set_ylim(h - 0.5, -0.5)
    ax.set_xlabel("u [px]")
    ax.set_ylabel("v [px]")
    fig.colorbar(im, ax=ax, label="corners used", shrink=0.8)
    return Plot(png_bytes(fig), "Where the corners used in the fit fell in the image (cells without any: red 0).",
                "heatmap of corner coverage")


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
        rows.append([name, num(v), num(s), Cell(num(abs(s / v) * 100 if v else None, " %"), "muted")])
    return Table(["parameter", "value", "sigma", "sigma / value"], rows,
                 caption="One standard deviation from the fit's covariance, scaled by its residuals.")


def _cross_validation(cv):
    """Blocks for the two-halves cross-validation (`validation.checks.calibration_halves`):
    per split a sentence (chi-square, p, the projection difference against its predicted
    size) and the difference of each intrinsic in sigmas."""
    if cv.get("error"):
        return [Para(f"The two halves could not be calibrated apart: {cv['error']}.")]
    blocks = []
    for name, r in cv.items():
        if not isinstance(r, dict) or "chi2" not in r:
            continue
        views = r.get("views") or ["?", "?"]
        agree = r.get("p_value") is not None and r["p_value"] >= 0.01
        blocks.append(Para(
            f"{name.replace('_', ' and ')} views calibrated apart ({views[0]} and {views[1]} views): the two sets "
            f"of intrinsics differ by chi-square {num(r['chi2'])} on {r['dof']} degrees of freedom (p = "
            f"{num(r['p_value'])}): {'they agree within their sigmas' if agree else 'they disagree beyond their sigmas'}"
            f". Their projections differ by {num(r.get('projection_rms_px'))} px RMS over the image (at most "
            f"{num(r.get('projection_max_px'))} px), against {num(r.get('projection_predicted_rms_px'))} px "
            "that the sigmas predict."))
        z = r.get("z") or {}
        if z:
            blocks.append(Table(["intrinsic", "difference / sigma"], [[k, num(v)] for k, v in z.items()],
                                caption="Each intrinsic's difference between the halves, in its combined sigma."))
    return blocks or [Para("No two-halves result in this record.")]


def _rejections(rep):
    rows = [[r.get("image", ""), r.get("stage", ""), str(r.get("corner", "")), r.get("reason", "")]
            for r in rep.get("rejected", [])]
    return Table(["image", "stage", "corner", "reason"], rows, numeric_from=99) if rows else \
        Para("Nothing was rejected.")


def build_calibration_report(rep, title=None):
    """The page of a calibration record (the --report JSON, with ``coverage``): a Report."""
    grid = rep.get("coverage")
    advice = coverage_advice(grid) if grid else "No corner coverage in this record."
    sections = [_summary(rep, advice),
                Section("views", "2. Per-view residuals", [_fig_views(rep.get("views", []))])]
    if grid:
        sections.append(Section("coverage", "3. Coverage of the image", [_fig_coverage(grid), Para(advice)]))
    sections.append(Section("intrinsics", "4. Intrinsics and their sigmas", [_intrinsics_table(rep)]))
    cv = rep.get("cross_validation")
    if cv:
        sections.append(Section("cross-validation", "5. Two halves of the views", _cross_validation(cv)))
    sections.append(Section("rejected", f"{len(sections) + 1}. Rejected views and corners", [_rejections(rep)]))
    size = rep.get("image_size") or ["?", "?"]
    return Report(title or f"Calibration: {rep.get('images')}",
                  f"{size[0]}x{size[1]} px, board {rep.get('board_file')}", sections)


def write_calibration_report(path, rep, force=False):
    """Write the page (self-contained HTML) atomically; returns the Report."""
    report = build_calibration_report(rep)
    atomic_write(path, render_html(report), force)
    return report
