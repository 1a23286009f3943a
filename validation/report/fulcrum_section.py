"""The report's fulcrum section: the fulcrum of a pivot sequence (validation.json's
``fulcrum``, `validation.fulcrum_validation`), against its truth where known.

A table of the 2-D vertex and the 3-D point with their sigmas, errors and the board-frame
point; the fulcrum drawn on a few sample frames with their shaft midlines and a top view
(x-z plane of the camera frame) of the 3-D point among the frames' 3-D axes, with its
ellipses (`fulcrum_figures`); the per-frame axis residuals (2-D, against their sigmas),
drawn and tabled.

Example
-------
>>> fulcrum_section({"frames": []}) is None
True
"""
from __future__ import annotations

import numpy as np

from .document import Details, Para, Section, Table
from .figures import legend_below, new_figure, plot_of
from .format import finite, lookup, num, vec
from .fulcrum_figures import fig_top_view, fulcrum_frames
from .headline import no_shaft_frames

__all__ = ["fulcrum_section"]


def _fig_residuals(rows):
    """Each shaft's 2-D residual against its sigma (a bar per shaft)."""
    if not rows:
        return None
    fig = new_figure(figsize=(6.4, 3.4))
    ax = fig.add_subplot(1, 1, 1)
    x = np.arange(len(rows))
    res = np.array([finite(r.get("residual_px")) or 0.0 for r in rows])
    sig = np.array([finite(r.get("sigma_px")) or 0.0 for r in rows])
    used = np.array([bool(r.get("used")) for r in rows])
    ax.bar(x[used], res[used], color="C0", label="residual (used)")
    if np.any(~used):
        ax.bar(x[~used], res[~used], color="C3", label="residual (outlier)")
    ax.plot(x, sig, "k_", ms=10, label="midline sigma there")
    ax.set_xlabel("shaft (frame order)")
    ax.set_ylabel("residual [px]")
    legend_below(fig, *ax.get_legend_handles_labels())
    return plot_of(fig, "Each frame's axis residual: the distance of the fulcrum's (undistorted) image from "
                "the frame's shaft midline, with the midline's sigma at that point.", "axis residuals per frame")


def fulcrum_section(data, number=8, samples=3, source=None):
    """The fulcrum section (`Section`), or None when the file has no ``fulcrum`` record.
    samples: how many frames to draw the fulcrum on; source: the validation file's path
    (relative image paths are looked for beside it)."""
    rec = data.get("fulcrum")
    if not isinstance(rec, dict):
        return None
    sec = Section("fulcrum", f"{number}. Fulcrum of the pivoting instrument")
    if not rec.get("ok"):
        sec.blocks.append(Para(f"No fulcrum: {rec.get('error')}.", "note"))
        return sec
    t = rec.get("truth") or {}
    cov = rec.get("vertex_cov_px2")
    vs = None if cov is None else float(np.sqrt(np.trace(np.asarray(cov, float))))
    rows = [["2-D vertex", vec(rec.get("vertex_px"), " px"), num(vs, " px"), num(t.get("vertex_error_px"), " px"),
             f"{rec.get('lines_used')} lines of {rec.get('frames_used')} frames, {len(rec.get('outliers') or [])} "
             "outliers"]]
    if rec.get("point") is not None:
        rows.append(["3-D point (camera frame)", vec(rec["point"], " mm"), num(rec.get("point_sigma"), " mm"),
                     num(t.get("point_error_norm"), " mm"),
                     f"{rec.get('point_axes_used')} axes, chi2/dof {num(rec.get('point_chi2_dof'))}"
                     + (f", truth chi2 {num(t.get('point_chi2'))} (3 dof, p {num(t.get('point_p_value'))})"
                        if "point_chi2" in t else "")])
    board = rec.get("board_frame")
    if isinstance(board, dict):
        bs = float(np.sqrt(np.trace(np.asarray(board["point_cov"], float))))
        rows.append(["3-D point (board frame)", vec(board.get("point"), " mm"), num(bs, " mm"),
                     num(board.get("error"), " mm"),
                     f"median over {board.get('frames')} PnP poses (spread {num(board.get('spread'))})"])
    sec.blocks.append(Table(["estimate", "value", "sigma (rms)", "error vs truth", "from"], rows, None,
                            f"The fulcrum as `pencilcal fulcrum` finds it from the shafts detected in every frame; "
                            f"lengths in mm, the unit of the board file and of the shaft's diameter "
                            f"({num(rec.get('shaft_diameter'), ' mm')}).",
                            numeric_from=2, text_cols=(4,)))
    missing = no_shaft_frames(data, rec)
    if missing:
        sec.blocks.append(Para(f"No shaft was found in {len(missing)} of {len(data['frames'])} frames: "
                               f"{', '.join(missing[:12])}{' ...' if len(missing) > 12 else ''}; the fulcrum is "
                               f"found from the others.", "note"))
    sec.blocks += fulcrum_frames(data, rec, samples, source)
    for p in (fig_top_view(rec), _fig_residuals(rec.get("axis_residuals") or [])):
        if p is not None:
            sec.blocks.append(p)
    axes3 = {(a["image"], a["shaft"]): a for a in rec.get("point_axes") or []}
    table = [[r["image"], str(r["shaft"]), num(r["residual_px"]), num(r["sigma_px"]),
              num(lookup(axes3, (r["image"], r["shaft"]), "distance")),
              num(lookup(axes3, (r["image"], r["shaft"]), "chi2")), "yes" if r["used"] else "no"]
             for r in rec.get("axis_residuals") or []]
    sec.blocks.append(Details(f"Axis residuals ({len(table)} shafts)", [Table(
        ["image", "shaft", "2-D residual [px]", "sigma [px]", "3-D distance", "3-D chi2", "used"], table, None,
        "2-D: the fulcrum image's distance from the midline; 3-D: the point's distance from the frame's 3-D axis "
        "and its chi2 (2 dof).", numeric_from=2, text_cols=(6,))]))
    return sec
