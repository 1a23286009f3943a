"""The PNG figures of the experiments' results (matplotlib, Agg).

Example
-------
>>> figure_paths("distribution", "figs/ts")
['figs/ts_distribution-angles.png', 'figs/ts_distribution-spacing.png']
"""
from __future__ import annotations

import math
from types import MappingProxyType

import numpy as np

__all__ = ["figure_paths", "write_figures"]


# the figures of each experiment (file name suffixes)
_FIGURES = MappingProxyType({
    "single-angle": ("single-angle",),
    "distribution": ("distribution-angles", "distribution-spacing"),
    "threshold": ("threshold",),
})


def figure_paths(experiment, prefix):
    """PNG paths an experiment writes: ``<prefix>_<name>.png``."""
    return [f"{prefix}_{n}.png" for n in _FIGURES[experiment]]


def _save(fig, path, force):
    """Write `fig` as a PNG at `path`, atomically."""
    from pencilcal.toolkit.io.files import atomic_path

    with atomic_path(path, force) as tmp:
        fig.savefig(tmp, format="png", dpi=110)


def _title(fig, r):
    """The figure's title: experiment, sequence, reference, frames and line sigma."""
    fig.suptitle(f"{r['experiment']}: {r.get('sequence') or ''} (reference: {r.get('reference')}, "
                 f"{r['frames_used']} frames, line sigma {r['sigma_line_deg']:.3g} deg)", fontsize=9)


def write_figures(result, prefix, force=False):
    """Write the PNG figures of an experiment's result (`figure_paths`); returns their paths."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    from matplotlib.figure import Figure

    name = result["experiment"]
    paths = figure_paths(name, prefix)
    if name == "single-angle":
        fig = Figure(figsize=(13, 5), layout="constrained")
        _fig_single(fig, result)
        _save(fig, paths[0], force)
    elif name == "distribution":
        fig = Figure(figsize=(13, 5), layout="constrained")
        _fig_angles(fig, result)
        _save(fig, paths[0], force)
        fig = Figure(figsize=(13, 5), layout="constrained")
        _fig_spacing(fig, result)
        _save(fig, paths[1], force)
    else:
        fig = Figure(figsize=(13, 5), layout="constrained")
        _fig_threshold(fig, result)
        _save(fig, paths[0], force)
    return paths


def _no_data(ax, text):
    """Say in the axes why they are empty."""
    ax.text(0.5, 0.5, text, ha="center", va="center", transform=ax.transAxes, fontsize=8, wrap=True)


# colour and marker of each single-angle case
_CASE_STYLE = MappingProxyType({"on_line": ("tab:blue", "o"), "known": ("tab:green", "s"),
                                 "unknown": ("tab:purple", "^")})


def _fig_single(fig, r):
    """single-angle: the estimates by status, and their errors against the theory."""
    ax1, ax2 = fig.subplots(1, 2)
    _title(fig, r)
    lim = 0.0
    for case, (col, mk) in _CASE_STYLE.items():
        s = r.get(case)
        if not s or s.get("status") != "ok":
            continue
        recs = s["pairs"]
        lim = max(lim, max(p["reference_tilt_deg"] for p in recs))
        uni = [p for p in recs if p["status"] == "unique"]
        if uni:
            ax1.plot([p["reference_tilt_deg"] for p in uni], [p["gamma_deg"][0] for p in uni], mk, color=col, ms=3,
                     alpha=0.6, label=f"{case}: unique ({len(uni)})")
            ax2.semilogy([p["reference_tilt_deg"] for p in uni], [max(abs(p["error_deg"][0]), 1e-6) for p in uni], mk,
                         color=col, ms=3, alpha=0.5, label=f"{case}: |error| ({len(uni)})")
        two = [p for p in recs if p["status"] == "two_roots"]
        if two:
            for p in two:
                ax1.plot([p["reference_tilt_deg"]] * 2, p["gamma_deg"], "-", color=col, lw=0.5, alpha=0.4)
            ax1.plot([p["reference_tilt_deg"] for p in two for _ in p["gamma_deg"]],
                     [g for p in two for g in p["gamma_deg"]], mk, mfc="none", color=col, ms=4,
                     label=f"{case}: two roots, both shown ({len(two)})")
        lb = [p for p in recs if p["status"] == "lower_bound"]
        if lb:
            ax1.plot([p["reference_tilt_deg"] for p in lb], [p["gamma_deg"][0] for p in lb], "^", color=col, mfc="none",
                     ms=3, alpha=0.4, label=f"{case}: lower bound only ({len(lb)})")
        inc = [p for p in recs if p["status"] in ("inconsistent", "no information")]
        if inc:
            y0 = {"on_line": -1.5, "known": -3.0, "unknown": -4.5}[case]
            ax1.plot([p["reference_tilt_deg"] for p in inc], [y0] * len(inc), "x", color=col, ms=5,
                     label=f"{case}: inconsistent, no tilt ({len(inc)})")
        if uni and s.get("unique", {}).get("bins"):
            bins = [b for b in s["unique"]["bins"] if b.get("error_rms_deg")]
            ax2.semilogy([0.5 * (b["tilt_lo_deg"] + b["tilt_hi_deg"]) for b in bins], [b["error_rms_deg"] for b in bins],
                         mk + "-", color=col, ms=7, lw=1.5, mec="k", label=f"{case}: RMS error per 10 deg")
    hi = max(lim, 10.0) + 2
    ax1.plot([0, hi], [0, hi], "k-", lw=0.7, label="estimate = reference")
    ax1.set_xlim(-1, hi)
    ax1.set_ylim(-5, 92)
    ax1.set_xlabel("reference tilt (rotation) [deg]")
    ax1.set_ylabel("single-angle tilt [deg]")
    ax1.set_title("estimates by status (x below 0: no tilt fits)")
    ax1.legend(fontsize=6, loc="upper left")
    curves = r.get("theory", {}).get("curves", [])
    if len(curves) > 4:  # the extremes and two between
        curves = [curves[i] for i in sorted({0, len(curves) // 3, 2 * len(curves) // 3, len(curves) - 1})]
    for c, ls in zip(curves, ("-", "--", "-.", ":")):
        ax2.semilogy(c["tilt_deg"], c["sd_deg"], ls, color="k", lw=1.1,
                     label=f"theory sd, on_line, theta {c['theta_deg']:.0f} deg "
                           f"(sigma_alpha {r['theory']['sigma_alpha_deg']:.3g})")
    ax2.set_xlabel("reference tilt (rotation) [deg]")
    ax2.set_ylabel("|tilt error| [deg]")
    ax2.set_title("single-angle error vs rotation (unique results only)")
    ax2.set_xlim(-1, hi)
    ax2.legend(fontsize=6, loc="upper right")


def _fig_angles(fig, r):
    """distribution (a): angular variation, residuals, the largest change against tilt."""
    ax1, ax2, ax3 = fig.subplots(1, 3)
    _title(fig, r)
    a = r.get("angles", {})
    if a.get("status") != "ok":
        for ax in (ax1, ax2, ax3):
            _no_data(ax, a.get("reason", "no data"))
        return
    lines = a["lines"]
    spokes = sorted({ln["spoke"] for ln in lines})
    cmap = __import__("matplotlib").colormaps["tab20"]
    for j, k in enumerate(spokes):
        ls = sorted([ln for ln in lines if ln["spoke"] == k], key=lambda ln: ln["reference_tilt_deg"])
        col = cmap(j % 20)
        t = [ln["reference_tilt_deg"] for ln in ls]
        # one axis for the whole sequence (a sweep): curves; else each frame its own: ticks
        style = dict(ls="-", lw=0.8) if a.get("sequence_axis_deg") is not None else dict(ls="none", marker="_", ms=6)
        ax1.plot(t, [ln["variation_predicted_deg"] for ln in ls], color=col, **style)
        ax1.plot(t, [ln["variation_measured_deg"] for ln in ls], "o", color=col, ms=2.5, mfc="none",
                 label=f"spoke {k}" if len(spokes) <= 16 else None)
        ax2.plot(t, [ln["z"] for ln in ls], "o", color=col, ms=2.5)
    ax1.set_xlabel("reference tilt (rotation) [deg]")
    ax1.set_ylabel("angle in T from the axis minus 3D angle [deg]")
    ax1.set_title("angular variation: measured (o), exact projection ("
                  + ("lines)" if a.get("sequence_axis_deg") is not None else "ticks)"))
    ax1.legend(fontsize=6, ncol=2)
    ax2.axhspan(-1, 1, color="0.85", zorder=0)
    ax2.axhline(0, color="k", lw=0.6)
    ax2.set_xlabel("reference tilt (rotation) [deg]")
    ax2.set_ylabel("(measured - predicted) / line sigma")
    ax2.set_title(f"residuals: RMS {a['residual_rms_deg']:.3g} deg, z RMS {a['z_rms']:.2f}")
    mv = sorted(a["max_variation"], key=lambda m: m["reference_tilt_deg"])
    t = [m["reference_tilt_deg"] for m in mv]
    ax3.plot(t, [m["max_angular_change_deg"] for m in mv], "k-", lw=1, label="largest possible change (any spoke)")
    ax3.plot(t, [m["max_variation_predicted_deg"] for m in mv], "-", color="tab:orange", lw=1,
             label="predicted, these spokes")
    ax3.plot(t, [m["max_variation_measured_deg"] for m in mv], "o", color="tab:blue", ms=3, mfc="none", label="measured")
    ax3.axhline(r["sigma_line_deg"], color="tab:red", ls="--", lw=1, label="line sigma")
    ax3.set_yscale("log")
    ax3.set_xlabel("reference tilt (rotation) [deg]")
    ax3.set_ylabel("largest |variation| over the spokes [deg]")
    ax3.set_title("angular change vs tilt")
    ax3.legend(fontsize=6)


def _fig_spacing(fig, r):
    """distribution (b): normal and tilt errors by spoke spacing, with the bounds."""
    ax1, ax2 = fig.subplots(1, 2)
    _title(fig, r)
    s = r.get("spacing", {})
    if s.get("status") != "ok":
        for ax in (ax1, ax2):
            _no_data(ax, s.get("reason", "no data"))
        return
    cols = ["tab:blue", "tab:orange", "tab:green", "tab:red", "tab:purple", "tab:brown"]
    for j, row in enumerate(s["strides"]):
        if row.get("status") != "ok":
            continue
        m = row["stride"]
        col = cols[j % len(cols)]
        fits = sorted([f for f in s["fits"] if f.get("stride") == m and f.get("ok")],
                      key=lambda f: f["reference_tilt_deg"])
        t = [f["reference_tilt_deg"] for f in fits]
        lab = f"every {m}: {row['spacing_deg']:.0f} deg apart, ~{row['lines_median']:.0f} lines"
        ax1.semilogy(t, [max(f["normal_error_closer_deg"], 1e-5) for f in fits], "o", color=col, ms=2.5, mfc="none",
                     label=lab)
        ax2.semilogy(t, [max(abs(f["tilt_error_deg"]), 1e-5) for f in fits], "o", color=col, ms=2.5, mfc="none", label=lab)
        # the bound, averaged over the subsets of this stride in each frame
        by = {}
        for f in fits:
            if f["crlb_normal_deg"]:
                by.setdefault(f["frame"], []).append((f["reference_tilt_deg"], f["crlb_normal_deg"], f["crlb_tilt_deg"]))
        pts = sorted((v[0][0], math.sqrt(np.mean([b[1] ** 2 for b in v])), math.sqrt(np.mean([b[2] ** 2 for b in v])))
                     for v in by.values())
        if pts:
            ax1.semilogy([p[0] for p in pts], [p[1] for p in pts], "-", color=col, lw=1)
            ax2.semilogy([p[0] for p in pts], [p[2] for p in pts], "-", color=col, lw=1)
    ax1.set_xlabel("reference tilt (rotation) [deg]")
    ax1.set_ylabel("normal error, closer twin [deg]")
    ax1.set_title("orientation error by spoke spacing (o), Cramer-Rao bound (lines)")
    ax2.set_xlabel("reference tilt (rotation) [deg]")
    ax2.set_ylabel("|tilt error| [deg]")
    ax2.set_title("tilt error by spoke spacing (o), bound (lines)")
    ax1.legend(fontsize=7)


def _fig_threshold(fig, r):
    """threshold: detection against tilt, and the tilt error against rotation."""
    ax1, ax2 = fig.subplots(1, 2)
    _title(fig, r)
    per = r["frames"]
    x = np.array([p["reference_tilt_deg"] for p in per])
    det = np.array([p["detectable"] for p in per], float)
    th = r["theory"]
    ax1.plot(x, det + np.random.default_rng(0).uniform(-0.02, 0.02, x.size), "o", ms=3, mfc="none", color="tab:blue",
             label="detectable (1) or not (0), per frame")
    ax1.plot(x, [p["predicted_detect_probability"] for p in per], "-", color="tab:orange", lw=1,
             label="predicted P(detectable), LR test at 1%")
    d = r["detection"]
    if d.get("status") == "ok":
        ax1.axvspan(*d["interval_deg"], color="tab:blue", alpha=0.15, label="measured 50% crossing, interval")
        ax1.axvline(d["tilt50_deg"], color="tab:blue", lw=1.2, label=f"measured 50%: {d['tilt50_deg']:.2f} deg")
    ax1.axvline(th["two_sqrt_sigma_deg"], color="tab:red", ls="--", lw=1,
                label=f"2 sqrt(sigma) = {th['two_sqrt_sigma_deg']:.2f} deg")
    ax1.axvline(th["detection_threshold_deg"], color="k", ls=":", lw=1,
                label=f"detection_threshold = {th['detection_threshold_deg']:.2f} deg")
    near = 4.0 * th["two_sqrt_sigma_deg"]
    hi = max(near, d["interval_deg"][1] * 1.3) if d.get("status") == "ok" else near
    ax1.set_xlim(0, hi if x.min() < near else 1.05 * x.max())
    ax1.set_ylim(-0.1, 1.1)
    ax1.set_xlabel("reference tilt [deg]")
    ax1.set_ylabel("detectable")
    ax1.set_title("detection" + ("" if d.get("status") == "ok" else f" ({d.get('reason')})"), fontsize=8)
    ax1.legend(fontsize=6, loc="center right")
    est = [p["tilt_deg"] for p in per]
    err = [abs(p["tilt_error_deg"]) if p["tilt_error_deg"] is not None else np.nan for p in per]
    ax2.loglog(np.maximum(x, 0.05), np.maximum(err, 1e-4), "o", ms=3, mfc="none", color="tab:blue", label="|tilt error|")
    ax2.loglog(np.maximum(x, 0.05), np.maximum(np.asarray(est, float), 1e-4), ".", ms=3, color="tab:green",
               label="estimated tilt")
    crb = [p["crlb_tilt_deg"] if p["crlb_tilt_deg"] else np.nan for p in per]
    ax2.loglog(np.maximum(x, 0.05), crb, "d", color="tab:orange", ms=2.5, label="Cramer-Rao sd of the tilt")
    g = np.logspace(-1.3, math.log10(max(x.max(), 1.0)), 50)
    ax2.loglog(g, 0.5 * g, "k--", lw=0.8, label="0.5 x tilt (noise-level above it)")
    fr = r.get("frontal", {})
    geo = fr.get("geometry")
    if geo:
        ax2.axhline(geo["median_deg"], color="tab:red", ls=":", lw=1,
                    label=f"frontal noise floor (median), scaled: {geo['median_deg']:.2f} deg")
    ax2.axvline(th["two_sqrt_sigma_deg"], color="tab:red", ls="--", lw=1)
    ax2.set_xlabel("reference tilt [deg] (0 drawn at 0.05)")
    ax2.set_ylabel("[deg]")
    ax2.set_title("tilt error vs rotation")
    ax2.legend(fontsize=6)
