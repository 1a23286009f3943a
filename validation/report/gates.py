"""Are the sigmas honest? One gate per method and quantity, before the verdict's prose.

Every sigma pencilcal writes is a promise: the truth lies within one sigma of the estimate
in a known fraction of frames (68.3% for a 1-D error such as the tilt, 1 - 1/e = 63.2%
for the RMS angle of a 2-D error such as the normal; validation/metrics.py). A gate
compares the fraction found with that expected, against the binomial band for the number
of frames (the central 95% of what honest sigmas would give), and says PASS or FAIL;
with fewer than `MIN_FRAMES` frames it cannot tell ("too few frames"). The book chapter's
models, kept beside the exact estimator for comparison (`facts.comparison_keys`), are
listed with status "comparison": shown, never judged. Methods whose gates agree exactly
(the PnP methods, often) share one row of the table.

Gates come from the summary `pencilcal validate` writes (tilt and normal coverage per
method) and from its truth-free checks (``checks``: any record with ``fraction``,
``expected`` and ``count``, such as a stereo rig's relative rotation).

The normalised squared errors (NEES) behind them are drawn by `fig_nees`: for honest
sigmas their distribution is chi2 with 1 degree of freedom for the tilt and 2 for the
normal (whose sigma is an RMS of two axes, so NEES = 2 (error / sigma)^2).

Example
-------
>>> g = gate("orient:exact", "tilt", 0.55, 0.6827, 40)
>>> g.status, round(g.band[0], 3), round(g.band[1], 3)
('PASS', 0.525, 0.825)
>>> gate("pnp:sqpnp", "normal", 0.04, 0.632, 50).status
'FAIL'
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from .document import Cell, Table
from .facts import comparison_keys, method_errors, method_keys, method_label, same_as_reference
from .figures import MAX_WIDTH_IN, legend_below, new_figure, plot_of
from .format import finite, lookup, pct

__all__ = ["Gate", "gate", "gates", "gates_table", "failed_gates_sentence", "fig_nees", "MIN_FRAMES", "BAND"]

# below this many frames a coverage says nothing either way (the 95% band spans most of [0, 1])
MIN_FRAMES = 8
# the central probability of the binomial band a gate accepts
BAND = 0.95


@dataclass(frozen=True)
class Gate:
    """One honesty test: `found` of `count` frames within one sigma against `expected`;
    `band` the binomial band of fractions honest sigmas give (central `BAND`); status
    PASS, FAIL, "too few frames", or "comparison" (a comparison model's: not judged)."""

    method: str
    quantity: str
    found: float
    expected: float
    count: int
    band: tuple
    status: str


def gate(method, quantity, found, expected, count):
    """The `Gate` of one coverage (fractions in [0, 1], count frames)."""
    from scipy.stats import binom

    lo, hi = binom.ppf([(1 - BAND) / 2, (1 + BAND) / 2], max(int(count), 1), expected) / max(int(count), 1)
    if count < MIN_FRAMES:
        status = "too few frames"
    else:
        status = "PASS" if lo <= found <= hi else "FAIL"
    return Gate(method, quantity, float(found), float(expected), int(count), (float(lo), float(hi)), status)


def _check_gates(data):
    """Gates from the truth-free checks (``checks`` of validation.json)."""
    out = []
    for name, rec in (data.get("checks") or {}).items():
        if not isinstance(rec, dict):
            continue
        cands = [("", rec)] + [(k, v) for k, v in rec.items() if isinstance(v, dict)]
        for sub, r in cands:
            f, e, n = finite(r.get("fraction")), finite(r.get("expected")), r.get("count")
            if f is not None and e is not None and isinstance(n, int) and n > 0:
                out.append(gate(name, sub or "coverage", f, e, n))
    return out


def gates(data):
    """Every gate of a validation dict: per method tilt and normal coverage (status
    "comparison" for the comparison models), then checks."""
    out = []
    compare = set(comparison_keys(data))
    for key in method_keys(data):
        if same_as_reference(data, key):
            continue  # the reference itself: no error to judge its sigmas by
        s = lookup(data, "summary", key, default={}) or {}
        for quantity in ("tilt", "normal"):
            c = s.get(f"{quantity}_coverage") or {}
            f, e, n = finite(c.get("fraction")), finite(c.get("expected")), c.get("count") or 0
            if f is not None and e is not None and n:
                g = gate(method_label(key), quantity, f, e, n)
                out.append(replace(g, status="comparison") if key in compare else g)
    return out + _check_gates(data)


def _merged(gs):
    """[(methods, gate)]: gates equal in all but the method, of one family (orient:, pnp:),
    in one row."""
    rows = []
    for g in gs:
        fam = g.method.split(":", 1)[0]
        for names, h in rows:
            if (h.method.split(":", 1)[0] == fam and ":" in g.method and h.quantity == g.quantity
                    and h.status == g.status and h.count == g.count and abs(h.found - g.found) < 1e-12
                    and abs(h.expected - g.expected) < 1e-12):
                names.append(g.method)
                break
        else:
            rows.append(([g.method], g))
    return rows


def gates_table(gs):
    """The gates as a table: one row per gate (gates equal but for the method share one),
    the comparison models grey."""
    rows = []
    for names, g in _merged(gs):
        fam = names[0].split(":", 1)[0]
        name = names[0] if len(names) == 1 else f"{fam}: " + ", ".join(n.split(":", 1)[1] for n in names)
        if g.status == "comparison":
            rows.append([Cell(name, "muted"), Cell(g.quantity, "muted"), Cell(pct(g.found), "muted"),
                         Cell(pct(g.expected), "muted"), Cell(str(g.count), "muted"),
                         Cell(f"{pct(g.band[0])} - {pct(g.band[1])}", "muted"),
                         Cell("comparison, not judged", "muted")])
            continue
        cls = {"PASS": "good", "FAIL": "bad"}.get(g.status, "muted")
        rows.append([name, g.quantity, pct(g.found), pct(g.expected), str(g.count),
                     f"{pct(g.band[0])} - {pct(g.band[1])}", Cell(g.status, cls)])
    return Table(["method", "quantity", "within 1 sigma", "expected", "frames", f"{pct(BAND)} band", "gate"], rows,
                 numeric_from=2, text_cols=(6,),
                 caption="Are the sigmas honest? The fraction of frames whose error is within the reported sigma, "
                         "against the fraction honest sigmas give and the binomial band for this many frames. The "
                         "book chapter's models (grey) are kept for comparison and not judged.")


def failed_gates_sentence(gs):
    """A sentence naming every failed gate (empty when none failed)."""
    bad = [g for g in gs if g.status == "FAIL"]
    if not bad:
        return ""
    parts = [f"{g.method} {g.quantity} ({pct(g.found)} within 1 sigma, {pct(g.band[0])}-{pct(g.band[1])} expected)"
             for g in bad]
    small = [g for g in bad if g.found < g.band[0]]
    why = " Sigmas too small promise more than the data hold." if small else ""
    return f"Gates failed: {'; '.join(parts)}.{why}"


def _nees(data, key):
    """(tilt NEES (n,), normal NEES (m,)) of a method's frames."""
    tilt, normal = [], []
    for _, _, e in method_errors(data, key):
        t, st = finite(e.get("tilt_deg")), finite(e.get("tilt_sigma_deg"))
        if t is not None and st:
            tilt.append((t / st) ** 2)
        n = finite(e.get("normal_closer_deg") if key.startswith("orient") else e.get("normal_deg"))
        sn = finite(e.get("normal_sigma_deg"))
        if n is not None and sn:
            normal.append(2.0 * (n / sn) ** 2)
    return np.array(tilt), np.array(normal)


def fig_nees(data):
    """The normalised squared errors' distribution per method against chi2 (1 dof for
    the tilt, 2 for the normal): a Plot, or None without errors and sigmas."""
    from scipy.stats import chi2

    keys = [k for k in method_keys(data) if not same_as_reference(data, k)]
    series = [(k, *_nees(data, k)) for k in keys]
    series = _same_drawn_once([s for s in series if s[1].size or s[2].size])
    if not series:
        return None
    fig = new_figure(figsize=(MAX_WIDTH_IN, 4.2))
    axes = fig.subplots(1, 2)
    for ax, j, dof, what in ((axes[0], 1, 1, "tilt"), (axes[1], 2, 2, "normal")):
        top = 1.0
        for i, s in enumerate(series):
            v = np.sort(s[j])
            if v.size:
                ax.step(v, np.arange(1, v.size + 1) / v.size, where="post", label=s[0], color=f"C{i}")
                top = max(top, float(v[-1]))
        x = np.logspace(-3, np.log10(max(top, chi2.ppf(0.999, dof))), 200)
        ax.plot(x, chi2.cdf(x, dof), "k--", label="chi2 (honest sigmas): 1 dof tilt, 2 dof normal")
        ax.set_xscale("log")
        ax.set_xlabel(f"NEES of the {what}")
        ax.set_ylabel("fraction of frames")
        ax.set_ylim(0, 1.02)
    handles, labels = axes[1].get_legend_handles_labels()
    for h, lab in zip(*axes[0].get_legend_handles_labels()):
        if lab not in labels:
            handles.append(h)
            labels.append(lab)
    legend_below(fig, handles, labels, ncol=2)
    return plot_of(fig, "Normalised squared errors (error / sigma)^2 of every method, against the chi2 "
                "distribution honest sigmas give: a curve to the right of the dashed one means sigmas too small. "
                "Methods whose errors and sigmas agree are drawn once, named together.",
                "empirical CDFs of the normalised squared errors")


def _same_drawn_once(series):
    """[(label, tilt NEES, normal NEES)]: methods with the same NEES (to 1e-4) in one
    series, labelled "first (= others)"."""
    out = []
    for k, t, n in series:
        for item in out:
            _, t0, n0, names = item
            if t0.shape == t.shape and n0.shape == n.shape and np.allclose(t0, t, rtol=1e-4) \
                    and np.allclose(n0, n, rtol=1e-4):
                names.append(method_label(k))
                break
        else:
            out.append((k, t, n, [method_label(k)]))
    return [(names[0] + (f" (= {', '.join(names[1:])})" if len(names) > 1 else ""), t, n)
            for _, t, n, names in out]
