"""What a reviewer may trust a report's figure to be, checked on the matplotlib figure
itself as it is saved (`linted_figures` patches `Figure.savefig` while a report is made):

- legible at 900 px: at most `MAX_WIDTH_IN` wide at the report's 100 dpi, no text smaller
  than `MIN_POINTS`;
- every plot axis labelled, with its unit in brackets ("[deg]", "[px]", "[mm]") unless it
  counts or compares (`UNITLESS`); a colour bar too;
- every legend outside every plot's area (never over data) and inside the figure (whole);
- no degenerate plot: the data of a plot span more than one value on each axis, and no
  curve lies wholly on the edge of its axes (where it cannot be seen).

Image panels (a frame drawn with its overlays: no ticks) have no axes to label.
"""
from __future__ import annotations

import contextlib
import re

import numpy as np

MAX_WIDTH_IN = 9.0
MIN_POINTS = 8.0
UNITLESS = re.compile(r"fraction|frame|shaft|view|corners|NEES|/ .*sigma|ratio|spokes|count|chi2|probability|flagged", re.I)


def _is_image_panel(ax):
    return not ax.get_xticks().size and not ax.get_yticks().size or (
        not ax.xaxis.get_visible() and not ax.yaxis.get_visible()) or not ax.axison


def _label_problem(what, label):
    if not label.strip():
        return f"{what} has no label"
    if "[" not in label and not UNITLESS.search(label):
        return f"{what} label {label!r} has no unit"
    return None


def _data_lines(ax):
    """Line2D artists drawn in data coordinates with at least two finite points."""
    out = []
    for ln in ax.get_lines():
        if ln.get_transform() != ax.transData or not ln.get_visible():
            continue  # axhline / axvline: blended transforms
        x, y = (np.asarray(v, float) for v in ln.get_data())
        ok = np.isfinite(x) & np.isfinite(y)
        if ok.sum():
            out.append((ln, x[ok], y[ok]))
    return out


def _seen(ax, x, y):
    """Whether a polyline passes through the inside of its axes (not only along the edges
    or outside them): sampled along its segments in axes coordinates."""
    uv = ax.transAxes.inverted().transform(ax.transData.transform(np.column_stack([x, y])))
    t = np.linspace(0.0, 1.0, 25)[:, None, None]
    pts = (uv[:-1][None] * (1 - t) + uv[1:][None] * t).reshape(-1, 2)
    pts = pts[np.all(np.isfinite(pts), axis=1)]
    return bool(np.any(np.all((pts > 0.003) & (pts < 0.997), axis=1)))


def _spans(ax):
    """(x values, y values) of the data a plot shows: lines, scatter offsets, bars."""
    xs, ys = [], []
    for _, x, y in _data_lines(ax):
        xs.append(x)
        ys.append(y)
    for c in ax.collections:
        off = np.asarray(c.get_offsets(), float).reshape(-1, 2)
        if off.size and c.get_offset_transform() == ax.transData:
            xs.append(off[:, 0])
            ys.append(off[:, 1])
    from matplotlib.patches import Rectangle

    bars = [p for p in ax.patches if isinstance(p, Rectangle) and p.get_data_transform() == ax.transData]
    if bars:
        xs.append(np.array([p.get_x() + p.get_width() / 2 for p in bars]))
        ys.append(np.array([p.get_y() + p.get_height() for p in bars] + [p.get_y() for p in bars]))
    x = np.concatenate(xs) if xs else np.zeros(0)
    y = np.concatenate(ys) if ys else np.zeros(0)
    return x[np.isfinite(x)], y[np.isfinite(y)]


def figure_problems(fig, name="figure"):
    """The ways `fig` breaks the rules above (list of str; empty: none)."""
    problems = []
    w, _ = fig.get_size_inches()
    if w > MAX_WIDTH_IN + 1e-9:
        problems.append(f"{name}: {w:.1f} in wide, more than {MAX_WIDTH_IN} (legible at 900 px)")
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    canvas = fig.canvas if isinstance(fig.canvas, FigureCanvasAgg) else FigureCanvasAgg(fig)
    canvas.draw()
    renderer = canvas.get_renderer()
    small = {t.get_text() for t in fig.findobj(lambda a: hasattr(a, "get_fontsize") and hasattr(a, "get_text"))
             if t.get_visible() and t.get_text().strip() and t.get_fontsize() < MIN_POINTS - 1e-9}
    if small:
        problems.append(f"{name}: text under {MIN_POINTS} pt: {sorted(small)[:4]}")
    plots = [ax for ax in fig.axes if ax.get_visible() and not _is_image_panel(ax)]
    for ax in plots:
        title = ax.get_title() or ax.get_ylabel() or "an axes"
        if hasattr(ax, "_colorbar"):
            label = ax.get_ylabel() or ax.get_xlabel()
            p = _label_problem(f"{name}: colour bar of {title!r}", label)
            problems += [p] if p else []
            continue
        for what, label, ticks in (("x axis", ax.get_xlabel(), ax.get_xticklabels()),
                                   ("y axis", ax.get_ylabel(), ax.get_yticklabels())):
            if not any(t.get_visible() and t.get_text() for t in ticks):
                continue  # a shared axis, labelled on its neighbour
            p = _label_problem(f"{name}: {what} of {title!r}", label)
            problems += [p] if p else []
        x, y = _spans(ax)
        if x.size and (np.ptp(x) == 0 or np.ptp(y) == 0):
            problems.append(f"{name}: {title!r} shows a single value on its {'x' if np.ptp(x) == 0 else 'y'} axis")
        for ln, lx, ly in _data_lines(ax):
            if lx.size >= 2 and not _seen(ax, lx, ly):
                problems.append(f"{name}: {title!r}: the curve {ln.get_label()!r} lies on the edge of its axes")
    boxes = [ax.get_window_extent(renderer) for ax in fig.axes if ax.get_visible() and not hasattr(ax, "_colorbar")]
    legends = [ax.get_legend() for ax in fig.axes if ax.get_legend() is not None] + list(fig.legends)
    fb = fig.bbox
    for lg in legends:
        lb = lg.get_window_extent(renderer)
        if lb.x0 < fb.x0 - 1 or lb.x1 > fb.x1 + 1 or lb.y0 < fb.y0 - 1 or lb.y1 > fb.y1 + 1:
            problems.append(f"{name}: a legend is cut by the figure's edge")
        for ab in boxes:
            ix = min(lb.x1, ab.x1) - max(lb.x0, ab.x0)
            iy = min(lb.y1, ab.y1) - max(lb.y0, ab.y0)
            if ix > 1 and iy > 1:
                problems.append(f"{name}: a legend ({', '.join(t.get_text() for t in lg.get_texts())[:60]}) "
                                f"lies over a plot")
                break
    return problems


@contextlib.contextmanager
def linted_figures():
    """Within it, every matplotlib figure saved is checked first (`figure_problems`); yields
    the list the problems are gathered in."""
    from matplotlib.figure import Figure

    found = []
    save = Figure.savefig

    def checked(self, fname, *args, **kwargs):
        if kwargs.get("format", "png") == "png" and not getattr(self, "_pdf_page", False):
            label = self.get_suptitle() or next((a.get_title() for a in self.axes if a.get_title()), "") or "figure"
            found.extend(figure_problems(self, label[:50]))
        return save(self, fname, *args, **kwargs)

    Figure.savefig = checked
    try:
        yield found
    finally:
        Figure.savefig = save
