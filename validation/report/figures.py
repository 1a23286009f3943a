"""The report's plots of every method's errors: error against the reference tilt with the
per-frame Cramer-Rao bound (`fig_error_vs_tilt`), and the calibration of the reported
sigmas (`fig_sigma_calibration`); and the figure helpers the other plots share
(`new_figure`, `png_bytes`, `legend_below`, `nice_floor`). Angles in degrees.

Every figure is drawn to be read at 900 px: at most `MAX_WIDTH_IN` wide at `DPI`, no text
under `MIN_FONT` points, its legend below its plots (never over their data), its axes
labelled with their units. A plot whose data have one value on an axis is not drawn that
way: every frame at one reference tilt is plotted against the frame instead.

matplotlib is imported when a figure is made, never on import (Agg backend, no window).

Example
-------
>>> nice_floor(37.0), nice_floor(0.3), nice(0.037)
(20.0, 1.0, 0.05)
>>> tilt_axis({"frames": [{"reference_tilt_deg": 12.0}, {"reference_tilt_deg": 20.0}, {}]})
({0: 12.0, 1: 20.0, 2: None}, 'reference tilt [deg]')
>>> tilt_axis({"frames": [{"reference_tilt_deg": 33.7}, {"reference_tilt_deg": 33.7}]})
({0: 0.0, 1: 1.0}, 'frame (every frame at a reference tilt of 33.7 deg)')
"""
from __future__ import annotations

import io
import math

import numpy as np

from .document import Plot
from .facts import method_errors, method_keys, method_label, primary_method, reference_phrase, same_as_reference
from .format import finite, finite_or_nan, lookup, num

__all__ = ["DPI", "MAX_WIDTH_IN", "MIN_FONT", "new_figure", "png_bytes", "plot_of", "axes_text", "legend_below", "nice", "nice_floor",
           "tilt_axis", "fig_error_vs_tilt", "fig_sigma_calibration"]

#: [dots per inch] of every PNG in the report
DPI = 100
#: [in] the widest figure: 900 px at `DPI`, shown at its size in a 900 px window
MAX_WIDTH_IN = 9.0
#: [pt] the smallest text in a figure (legends, tick labels)
MIN_FONT = 8.0
#: [deg] reference tilts spread less than this are one tilt (a fixed camera)
ONE_TILT_DEG = 1e-3

_ORIENT_STYLE = {"exact": ("C0", "o"), "general": ("C1", "s"), "aligned": ("C2", "^")}
_OTHER_MARKERS = ["D", "v", "<", ">", "P", "h", "*"]


def new_figure(**kw):
    """A matplotlib Figure (constrained layout, Agg backend, no pyplot state); kw: Figure's."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    from matplotlib.figure import Figure

    return Figure(layout="constrained", **kw)


def legend_below(fig, handles, labels, ncol=3):
    """One legend for the whole figure, below its plots (constrained layout makes room)."""
    if handles:
        fig.legend(handles, labels, loc="outside lower center", ncol=ncol, fontsize=MIN_FONT, framealpha=0.9)


def _gather(*axes):
    """(handles, labels) of the artists of `axes` that have a label, each label once."""
    out = {}
    for ax in axes:
        for h, lab in zip(*ax.get_legend_handles_labels()):
            out.setdefault(lab, h)
    return list(out.values()), list(out.keys())


def axes_text(fig):
    """What the figure's plots show, read off its axes after drawing: "x: LABEL; y: LABEL"
    per plot ("(none)" where a shown axis has no label; an axis whose tick labels are
    hidden, shared with its neighbour, left out), "image" for a panel without ticks (a
    frame drawn on), joined by " | "."""
    parts = []
    for ax in fig.axes:
        if not ax.get_visible() or hasattr(ax, "_colorbar"):
            continue
        if not ax.axison or (not len(ax.get_xticks()) and not len(ax.get_yticks())):
            parts.append("image")
            continue
        shown = []
        for name, label, ticks in (("x", ax.get_xlabel(), ax.get_xticklabels()),
                                   ("y", ax.get_ylabel(), ax.get_yticklabels())):
            if any(t.get_visible() and t.get_text() for t in ticks):
                shown.append(f"{name}: {label or '(none)'}")
        parts.append("; ".join(shown))
    return " | ".join(dict.fromkeys(p for p in parts if p))


def plot_of(fig, caption, alt, dpi=DPI):
    """The figure as a `Plot`: its PNG, the caption, the alt text and what its axes show."""
    png = png_bytes(fig, dpi)
    return Plot(png, caption, alt, axes_text(fig))


def png_bytes(fig, dpi=DPI):
    """The figure as PNG bytes, without the software tag (the same figure gives the same bytes)."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi, metadata={"Software": None}, pil_kwargs={"compress_level": 4})
    return buf.getvalue()


def nice_floor(v):
    """The largest of 1, 2, 5 x 10^k at or below v, and at least 1."""
    if not (v > 1):
        return 1.0
    k = math.floor(math.log10(v))
    return float(max(m * 10**k for m in (1, 2, 5) if m * 10**k <= v * (1 + 1e-12)))


def nice(v):
    """The smallest of 1, 2, 5 x 10^k at or above v (v > 0)."""
    k = math.floor(math.log10(v))
    for m in (1, 2, 5, 10):
        if m * 10**k >= v * (1 - 1e-12):
            return m * 10**k
    return 10 ** (k + 1)


def tilt_axis(data):
    """(x per frame index, axis label): the reference tilt [deg] (None where a frame has
    none); the frame index when no frame has a reference tilt, or when every frame has the
    same one (a fixed camera: one tilt would plot every frame on one vertical line)."""
    xs = {i: finite(f.get("reference_tilt_deg")) for i, f in enumerate(data["frames"])}
    known = [v for v in xs.values() if v is not None]
    if known and max(known) - min(known) >= ONE_TILT_DEG:
        return xs, "reference tilt [deg]"
    label = f"frame (every frame at a reference tilt of {num(known[0])} deg)" if known else "frame"
    return {i: float(i) for i in xs}, label


def _style(key, i):
    """(colour, marker, filled) of the i-th plotted method: orient models filled."""
    if key.startswith("orient:"):
        return _ORIENT_STYLE.get(key.split(":", 1)[1], (f"C{i % 10}", "o")) + (True,)
    if key == "sfm":
        return ("C8", "X", True)
    return (f"C{3 + i % 5}", _OTHER_MARKERS[i % len(_OTHER_MARKERS)], False)


def _plotted_keys(data):
    """(methods to plot, methods equal to the reference and so left out)."""
    keys, hidden = [], []
    for k in method_keys(data):
        if not method_errors(data, k):
            continue
        (hidden if same_as_reference(data, k) else keys).append(k)
    return keys, hidden


def _error_signature(data, key):
    """(M, 4) float: frame index, normal, normal (closer twin) and tilt error [deg] per frame
    with an error record; NaN where a value is missing."""
    rows = []
    for i, _, e in method_errors(data, key):
        rows.append([i] + [np.nan if finite(e.get(c)) is None else finite(e.get(c))
                           for c in ("normal_deg", "normal_closer_deg", "tilt_deg")])
    return np.array(rows, float).reshape(-1, 4)


def _duplicates(data, keys):
    """{key: earlier key} for methods whose per-frame errors repeat an earlier method's (to 1e-4)."""
    sig = {k: _error_signature(data, k) for k in keys}
    out = {}
    for j, k in enumerate(keys):
        for prev in keys[:j]:
            if prev in out:
                continue
            a, b = sig[prev], sig[k]
            if a.shape == b.shape and a.size and np.allclose(a, b, rtol=1e-4, atol=1e-9, equal_nan=True):
                out[k] = prev
                break
    return out


# ----------------------------------------------------------------------------------------
# error against tilt


def _draw_bounds(data, xs, ax1, ax2):
    """Shade the per-frame Cramer-Rao bounds; returns (normal bound values [deg] drawn,
    [(x, tilt bound [deg])])."""
    b = sorted((xs[i], finite(lookup(f, "crlb", "normal_deg")), finite(lookup(f, "crlb", "tilt_deg")))
               for i, f in enumerate(data["frames"]) if xs.get(i) is not None)
    bn = [(x, v) for x, v, _ in b if v is not None and v > 0]
    bt = [(x, v) for x, _, v in b if v is not None and v > 0]
    positive = []
    if bn:
        x, v = np.array(bn).T
        ax1.fill_between(x, 1e-12, v, color="0.6", alpha=0.25, lw=0, label="below the Cramer-Rao bound")
        ax1.plot(x, v, "-", color="0.3", lw=1.0, label="bound (per frame)")
        ax1.plot(x, 2 * v, "--", color="0.3", lw=1.0, label="2 x bound")
        positive += list(v)
    if bt:
        x, v = np.array(bt).T
        ax2.fill_between(x, -2 * v, 2 * v, color="0.6", alpha=0.15, lw=0, label="+-2 x bound")
        ax2.fill_between(x, -v, v, color="0.6", alpha=0.3, lw=0, label="+-1 x bound")
    ax2.axhline(0, color="0.2", lw=0.6)
    return positive, bt


def _draw_method(ax1, ax2, k, i, name, rows, chosen_label):
    """One method's normal errors (top) and tilt errors (bottom). rows: [(x, error record)].
    Returns (positive normal values drawn, |tilt errors| [deg], whether the 'as reported'
    legend entry is now taken)."""
    color, marker, filled = _style(k, i)
    x = np.array([r[0] for r in rows])
    closer = np.array([finite_or_nan(r[1].get("normal_closer_deg")) for r in rows])
    chosen = np.array([finite_or_nan(r[1].get("normal_deg")) for r in rows])
    tilt = np.array([finite_or_nan(r[1].get("tilt_deg")) for r in rows])
    ts = np.array([finite_or_nan(r[1].get("tilt_sigma_deg")) for r in rows])
    ns = np.array([finite_or_nan(r[1].get("normal_sigma_deg")) for r in rows])
    kw = dict(color=color, marker=marker, ls="none", ms=6 if filled else 5,
              mfc=color if filled else "none", mew=1.2, alpha=0.9)
    ax1.plot(x, np.where(closer > 0, closer, np.nan), label=name, **kw)
    positive = [v for v in closer if v > 0]
    diff = np.abs(chosen - closer) > 1e-9
    if diff.any():
        ax1.plot(x[diff], chosen[diff], ls="none", marker="x", color=color, ms=6, mew=1.0,
                 label=None if chosen_label else "as reported (other twin)")
        chosen_label = True
        positive += list(chosen[diff][chosen[diff] > 0])
    if k.startswith("orient:") and np.isfinite(ns).any():
        ax1.plot(x, ns, ls="none", marker="_", color=color, ms=12, mew=2,
                 label=f"{method_label(k)}: reported sigma")
    if k.startswith("orient:") and np.isfinite(ts).any():
        ax2.errorbar(x, tilt, yerr=np.where(np.isfinite(ts), ts, 0), fmt=marker, color=color, ms=5,
                     mfc=color if filled else "none", capsize=3, lw=1, label=f"{name} +- reported sigma")
    else:
        ax2.plot(x, tilt, label=name, **kw)
    return positive, [abs(v) for v in tilt if np.isfinite(v)], chosen_label


def _error_vs_tilt_caption(data, xs, symlog, dup, hidden, xlabel=""):
    """The caption, with what the plot leaves out or draws once. symlog: the tilt axis's
    linear half-width [deg] or None; xlabel: the x axis's label (`tilt_axis`)."""
    missing = sum(1 for i, f in enumerate(data["frames"]) if f.get("errors") and xs.get(i) is None)
    cap = ("Top: the angle between each method's normal and the reference normal (closer twin; a cross marks the "
           "solution the method reported where it is the other twin), with the Cramer-Rao bound of each frame's lines "
           "at the reference pose (shaded below 1x, dashed 2x) and the orient sigma as a tick (a point above its "
           "tick lies outside 1 sigma). Bottom: the signed tilt error with the orient sigmas as error bars, in the "
           "+-1x and +-2x bound bands.")
    if symlog:
        cap += f" The tilt axis is linear within +-{num(symlog)} deg and logarithmic beyond."
    if dup:
        cap += " Drawn once, as their errors agree to 1e-4: " + "; ".join(
            f"{method_label(k)} = {method_label(p)}" for k, p in dup.items()) + "."
    if hidden:
        cap += (f" Not drawn: {', '.join(method_label(h) for h in hidden)}, equal to the reference in every frame "
                f"(< 1e-6 deg).")
    if missing:
        cap += f" {missing} frames with errors but no reference tilt are left out."
    if xlabel.startswith("frame (every frame"):
        cap += (" Every frame has the same reference tilt (a fixed camera): the errors are drawn against the frame, "
                "not piled on one tilt.")
    return cap


def fig_error_vs_tilt(data):
    """Normal error and tilt error of every method against the reference tilt, with the
    per-frame Cramer-Rao bound and the reported sigmas. Returns Plot or None."""
    keys, hidden = _plotted_keys(data)
    if not keys:
        return None
    dup = _duplicates(data, keys)
    keys = [k for k in keys if k not in dup]
    alias = {k: [d for d, p in dup.items() if p == k] for k in keys}
    name = {k: method_label(k) + (f" (= {', '.join(method_label(a) for a in alias[k])})" if alias[k] else "")
            for k in keys}
    prim = primary_method(data)
    xs, xlabel = tilt_axis(data)
    fig = new_figure(figsize=(MAX_WIDTH_IN, 8.4))
    ax1, ax2 = fig.subplots(2, 1, sharex=True)
    positive, bt = _draw_bounds(data, xs, ax1, ax2)
    chosen_label = False
    tilt_abs, tilt_prim = [], []
    for i, k in enumerate(keys):
        rows = [(xs.get(j), e) for j, _, e in method_errors(data, k) if xs.get(j) is not None]
        if not rows:
            continue
        pos, tilt, chosen_label = _draw_method(ax1, ax2, k, i, name[k], rows, chosen_label)
        positive += pos
        tilt_abs += tilt
        if k == prim:
            tilt_prim += tilt
    ax1.set_yscale("log")
    pos = [p for p in positive if np.isfinite(p) and p > 0]
    if pos:
        ax1.set_ylim(min(pos) / 2, max(pos) * 2)
    ax1.set_ylabel("normal error [deg] (closer twin)")
    ax1.set_title("Normal error against the " + reference_phrase(data), fontsize=10)
    ax1.grid(True, which="both", alpha=0.25)
    symlog = None
    if tilt_abs:
        # a linear band that holds the bound and most errors, logarithmic beyond (outliers)
        inner = max([2.5 * v for _, v in bt] + [float(np.percentile(tilt_prim or tilt_abs, 95)) * 1.2] + [1e-6])
        if max(tilt_abs) > 8 * inner:
            symlog = nice(inner)
            ax2.set_yscale("symlog", linthresh=symlog, linscale=2.0)
    ax2.set_ylabel("tilt error [deg] (estimate - reference)")
    ax2.set_xlabel(xlabel)
    ax2.grid(True, alpha=0.25)
    ax2.margins(y=0.08)  # the outermost markers whole, not cut by the frame
    legend_below(fig, *_gather(ax1, ax2), ncol=2)
    return plot_of(fig, _error_vs_tilt_caption(data, xs, symlog, dup, hidden, xlabel), "Error versus reference tilt")


# ----------------------------------------------------------------------------------------
# calibration of the sigmas


def _half_normal_cdf(z):
    """P(|N(0, 1)| <= z) for each z: (N,) from any shape."""
    return np.array([math.erf(v / math.sqrt(2)) for v in np.ravel(z)])


def _sigma_series(data):
    """[(label, |error| (M,) [deg], sigma (M,) [deg], "tilt" | "normal", colour, marker)] of
    every plotted method that reports sigmas, and the combined sigma against PnP."""
    keys, _ = _plotted_keys(data)
    series = []
    for i, k in enumerate(keys):
        color = _style(k, i)[0]
        rows = [e for _, _, e in method_errors(data, k)]
        if k.startswith("orient:"):
            t = [(abs(finite(e.get("tilt_deg"))), finite(e.get("tilt_sigma_deg"))) for e in rows
                 if finite(e.get("tilt_deg")) is not None and finite(e.get("tilt_sigma_deg"))]
            if t:
                series.append((f"{method_label(k)} tilt", *np.array(t).T, "tilt", color, "o"))
            nrm = [(finite(e.get("normal_closer_deg")), finite(e.get("normal_sigma_deg"))) for e in rows
                   if finite(e.get("normal_closer_deg")) is not None and finite(e.get("normal_sigma_deg"))]
        else:
            nrm = [(finite(e.get("normal_deg")), finite(e.get("normal_sigma_deg"))) for e in rows
                   if finite(e.get("normal_deg")) is not None and finite(e.get("normal_sigma_deg"))]
        if nrm:
            series.append((f"{method_label(k)} normal", *np.array(nrm).T, "normal", color, "s"))
    if data.get("reference") == "pnp":
        prim = primary_method(data)
        if prim:
            pairs = []
            for _, fr, e in method_errors(data, prim):
                s_ref = finite(lookup(fr, "pnp", fr.get("pnp_best") or "", "normal_sigma_deg"))
                if s_ref and finite(e.get("normal_sigma_deg")) and finite(e.get("normal_closer_deg")) is not None:
                    pairs.append((finite(e["normal_closer_deg"]), math.hypot(finite(e["normal_sigma_deg"]), s_ref)))
            if pairs:
                series.append((f"{method_label(prim)} normal vs combined sigma (with PnP)", *np.array(pairs).T,
                               "normal", "k", "D"))
    return series


def _merge_repeated(series):
    """(series drawn once each, with the names they stand for in their labels; the list of
    "drawn = repeated" phrases): a series that repeats another's errors and sigmas is named,
    not redrawn."""
    kept, same = [], []
    for sr in series:
        for j, other in enumerate(kept):
            if other[3] == sr[3] and other[1].shape == sr[1].shape \
                    and np.allclose(other[1], sr[1], rtol=1e-4, atol=1e-9) \
                    and np.allclose(other[2], sr[2], rtol=1e-4, atol=1e-9):
                same[j].append(sr[0].rsplit(" ", 1)[0])
                break
        else:
            kept.append(sr)
            same.append([])
    series = [(lab + (f" (= {', '.join(o)})" if len(o) == 1 else f" (= {len(o)} others)" if o else ""),) + sr[1:]
              for (lab, *_), sr, o in zip(kept, kept, same)]
    merged = [f"{sr[0].split(' (=')[0]} = {', '.join(o)}" for sr, o in zip(series, same) if o]
    return series, merged


def _draw_sigma_series(ax1, ax2, series, zmax):
    """Error against sigma (left) and the distribution of error / sigma (right, up to
    zmax). Returns the labels of the series all of whose errors lie beyond zmax sigma (not
    drawn on the right: their curve would lie on its x axis)."""
    allv, beyond = [], []
    for label, e, s, kind, color, marker in series:
        ok = (e > 0) & (s > 0)
        ax1.plot(s[ok], e[ok], ls="none", marker=marker, ms=4, color=color, mfc="none" if kind == "normal" else color,
                 alpha=0.8, label=f"{label} (n={int(ok.sum())})")
        allv += list(e[ok]) + list(s[ok])
        z = np.sort(e / s)
        if z.size and z[0] >= zmax:
            beyond.append(label)
            continue
        ax2.step(np.r_[0, z], np.r_[0, np.arange(1, z.size + 1) / z.size], where="post", color=color,
                 ls="-" if kind == "tilt" else "--")
    if allv:
        lo, hi = min(allv) / 2, max(allv) * 2
        g = np.array([lo, hi])
        ax1.plot(g, g, "k-", lw=0.8, label="error = sigma")
        ax1.plot(g, 1.96 * g, "k:", lw=0.8, label="95% (tilt: 1.96 sigma; normal: 1.73)")
        ax1.plot(g, 1.731 * g, "k:", lw=0.8)
        ax1.set_xlim(lo, hi)
        ax1.set_ylim(lo, hi)
    return beyond


def fig_sigma_calibration(data):
    """Reported sigma against actual error, and the distribution of error/sigma against
    what correct sigmas give. Returns Plot or None."""
    series = _sigma_series(data)
    if not series:
        return None
    # keep the plot readable: a method that repeats another's errors and sigmas is named, not redrawn
    series, merged = _merge_repeated(series)
    fig = new_figure(figsize=(MAX_WIDTH_IN, 5.6))
    ax1, ax2 = fig.subplots(1, 2)
    zmax = 4.0
    beyond = _draw_sigma_series(ax1, ax2, series, zmax)
    ax1.set_xscale("log")
    ax1.set_yscale("log")
    ax1.set_xlabel("reported sigma [deg]")
    ax1.set_ylabel("|error| [deg]")
    ax1.set_title("Reported sigma against actual error", fontsize=10)
    ax1.grid(True, which="both", alpha=0.25)
    z = np.linspace(0, zmax, 200)
    ax2.plot(z, _half_normal_cdf(z), color="0.5", lw=2.5, alpha=0.5, label="expected, tilt (1-D Gaussian)")
    ax2.plot(z, 1 - np.exp(-z**2), color="0.5", lw=2.5, alpha=0.5, ls="--",
             label="expected, normal (2-D, RMS sigma)")
    ax2.axvline(1.0, color="0.4", lw=0.6)
    ax2.set_xlim(0, zmax)
    ax2.set_ylim(0, 1.02)
    ax2.set_xlabel("|error| / reported sigma")
    ax2.set_ylabel("fraction of frames")
    ax2.set_title("Calibration of the uncertainties", fontsize=10)
    ax2.grid(True, alpha=0.25)
    legend_below(fig, *_gather(ax1, ax2), ncol=2)
    cap = ("Left: each point is one frame (filled: tilt; open: normal); with correct sigmas the tilt points scatter "
           "about the solid line with 95% below the dotted one. Right: the fraction of frames with |error| / sigma "
           "below each value (solid: tilt; dashed: normal; coloured as on the left), against the curves correct "
           "sigmas give (grey: 68.3% at 1 for the tilt, 63.2% for the normal's RMS angle). A curve to the right of "
           "its expectation means sigmas that are too small.")
    if beyond:
        cap += (f" Not on the right: {', '.join(beyond)}, every error beyond {zmax:g} sigma (its sigmas far too "
                f"small).")
    if data.get("reference") == "pnp":
        cap += (" With PnP as the reference the errors include the reference's own; the black curve uses the combined "
                "sigma of both.")
    if merged:
        cap += " Drawn once, as their errors and sigmas agree to 1e-4: " + "; ".join(merged) + "."
    return plot_of(fig, cap, "Calibration of the reported sigmas")
