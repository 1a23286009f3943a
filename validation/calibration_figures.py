"""The calibration report's figures: the maps over the image, the per-view residuals, coverage.

Every map is drawn over the image in pixels (u to the right, v down, as the image), with a
colour bar that names its quantity and unit, the region the views cover outlined in white
and, on the uncertainty map, the usable region's edge (the verdict's threshold) in red.
matplotlib is imported when a figure is made.

Example
-------
>>> m = {"step_px": 20.0, "grid": [4, 3], "covered": [[1, 1, 1, 0], [1, 1, 1, 0], [1, 1, 1, 0]],
...      "sigma_px": [[0.1, 0.2, 0.3, 2.0], [0.1, 0.1, 0.2, 1.5], [0.2, None, 0.3, 3.0]]}
>>> fig_uncertainty(m, (80, 60), 1.0).alt
'map of the projection uncertainty over the image'
"""
from __future__ import annotations

import numpy as np

from .report.document import Plot
from .report.figures import legend_below, new_figure, png_bytes

__all__ = ["fig_uncertainty", "fig_difference", "fig_views", "fig_coverage", "grid_array"]


def grid_array(rows):
    """(ny, nx) float array of a record's map (None -> NaN)."""
    return np.array([[np.nan if v is None else float(v) for v in row] for row in rows], float)


def _map_axes(fig, size):
    ax = fig.add_subplot()
    ax.set_xlim(-0.5, size[0] - 0.5)
    ax.set_ylim(size[1] - 0.5, -0.5)
    ax.set_xlabel("u [px]")
    ax.set_ylabel("v [px]")
    ax.set_aspect("equal")
    return ax


def _draw_map(ax, values, step, size, vmax, cmap):
    import matplotlib

    ny, nx = values.shape
    extent = (-0.5, nx * step - 0.5, ny * step - 0.5, -0.5)
    cm = matplotlib.colormaps[cmap].with_extremes(bad="0.85")   # pixels whose ray the lens cannot find
    return ax.imshow(np.clip(values, 0, vmax), extent=extent, cmap=cm, vmin=0.0, vmax=vmax,
                     interpolation="nearest")


def _outline(ax, mask, step, color, style, label):
    """The edge of a boolean cell mask, as a contour through the cells' centres."""
    m = np.asarray(mask, float)
    if not m.any() or m.all():
        return
    ny, nx = m.shape
    u = (np.arange(nx) + 0.5) * step - 0.5
    v = (np.arange(ny) + 0.5) * step - 0.5
    padded = np.pad(m, 1)
    uu = np.r_[u[0] - step, u, u[-1] + step]
    vv = np.r_[v[0] - step, v, v[-1] + step]
    cs = ax.contour(uu, vv, padded, levels=[0.5], colors=color, linestyles=style, linewidths=1.6)
    cs.set_label(label)


def _size(m, size):
    return size if size is not None else (m["grid"][0] * m["step_px"], m["grid"][1] * m["step_px"])


def fig_uncertainty(umap, size, usable_px):
    """The projection uncertainty map (`calibration_checks.uncertainty_map`'s record)."""
    size = _size(umap, size)
    s = grid_array(umap["sigma_px"])
    covered = np.asarray(umap["covered"], bool)
    inside = s[covered & np.isfinite(s)]
    top = float(inside.max()) if inside.size else float(np.nanmax(s))
    vmax = max(2.0 * top, 1.2 * usable_px) if top < usable_px else 2.0 * top
    fig = new_figure(figsize=(7.2, 7.2 * size[1] / size[0] + 0.9))
    ax = _map_axes(fig, size)
    im = _draw_map(ax, s, umap["step_px"], size, vmax, "viridis")
    step = umap["step_px"]
    _outline(ax, covered, step, "white", "dashed", "covered by the views")
    _outline(ax, covered & np.isfinite(s) & (s <= usable_px), step, "red", "solid", f"usable (<= {usable_px:g} px)")
    fig.colorbar(im, ax=ax, extend="max", shrink=0.85,
                 label="projection uncertainty, worst direction, 1 sigma [px]")
    ax.set_title("Projection uncertainty over the image")
    return Plot(png_bytes(fig),
                f"How well the calibration knows where a ray lands: the worst direction's standard deviation [px] "
                f"of the pixel of the ray each pixel sees, from the intrinsics' covariance (the corner errors seen), "
                f"up to the common rotation the board poses absorb. White dashed: the region the views cover; red: "
                f"the usable region (<= {usable_px:g} px and covered); grey: no ray (the lens model does not invert "
                f"there). Colours stop at {vmax:.3g} px.",
                "map of the projection uncertainty over the image")


def fig_difference(cv_map, size):
    """The odd-even projection difference map (`calibration_checks.calibration_halves`' map)."""
    size = _size(cv_map, size)
    d = grid_array(cv_map["difference_px"])
    p = grid_array(cv_map["predicted_px"])
    covered = np.asarray(cv_map["covered"], bool)
    inside = np.r_[d[covered & np.isfinite(d)], p[covered & np.isfinite(p)]]
    vmax = 2.0 * float(inside.max()) if inside.size else float(np.nanmax(d))
    step = cv_map["step_px"]
    # one above the other: each as wide as the page allows at 900 px
    fig = new_figure(figsize=(7.2, 2.0 * 6.0 * size[1] / size[0] + 1.6))
    axes = fig.subplots(2, 1)
    for ax, values, title in ((axes[0], d, "odd - even views: |difference|"),
                              (axes[1], p, "predicted RMS difference (both halves' sigmas)")):
        ax.set_xlim(-0.5, size[0] - 0.5)
        ax.set_ylim(size[1] - 0.5, -0.5)
        ax.set_aspect("equal")
        ax.set_xlabel("u [px]")
        ax.set_ylabel("v [px]")
        im = _draw_map(ax, values, step, size, vmax, "magma")
        _outline(ax, covered, step, "white", "dashed", "covered")
        ax.set_title(title, fontsize=10)
    fig.colorbar(im, ax=list(axes), extend="max", shrink=0.85, label="projection difference [px]")
    return Plot(png_bytes(fig),
                "Cross-validation: the odd and the even views calibrated apart. Top, how far apart the two put each "
                "pixel's ray [px], after the rotation that best aligns them over the covered region (white dashed); "
                f"bottom, the RMS difference the two calibrations' sigmas predict [px]. Colours stop at {vmax:.3g} px.",
                "map of the projection difference between the two halves")


def fig_views(views):
    """Per-view RMS residual bars; rejected views in red, views without a board as crosses."""
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


def fig_coverage(grid):
    """Corner counts per cell of the coverage grid (`calibration_report.coverage_grid`)."""
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
