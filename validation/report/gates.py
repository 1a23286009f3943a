"""Are the sigmas honest? One gate per method and quantity, before the verdict's prose.

Every sigma pencilcal writes is a promise: the truth lies within one sigma of the estimate
in a known fraction of frames (68.3% for a 1-D error such as the tilt, 1 - 1/e = 63.2%
for the RMS angle of a 2-D error such as the normal; validation/metrics.py). A gate
compares the fraction found with that expected, against the binomial band for the number
of frames (the central 95% of what honest sigmas would give), and says PASS or FAIL;
with fewer than `MIN_FRAMES` frames it cannot tell ("too few frames").

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

from dataclasses import dataclass

import numpy as np

from .document import Cell, Plot, Table
from .facts import method_errors, method_keys, method_label, same_as_reference
from .figures import new_figure, png_bytes
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
    PASS, FAIL or "too few frames"."""

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
    """Every gate of a validation dict: per method tilt and normal coverage, then checks."""
    out = []
    for key in method_keys(data):
        if same_as_reference(data, key):
            continue  # the reference itself: no error to judge its sigmas by
        s = lookup(data, "summary", key, default={}) or {}
        for quantity in ("tilt", "normal"):
            c = s.get(f"{quantity}_coverage") or {}
            f, e, n = finite(c.get("fraction")), finite(c.get("expected")), c.get("count") or 0
            if f is not None and e is not None and n:
                out.append(gate(method_label(key), quantity, f, e, n))
    return out + _check_gates(data)


def gates_table(gs):
    """The gates as the report's first table."""
    rows = []
    for g in gs:
        cls = {"PASS": "good", "FAIL": "bad"}.get(g.status, "muted")
        rows.append([g.method, g.quantity, pct(g.found), pct(g.expected), str(g.count),
                     f"{pct(g.band[0])} - {pct(g.band[1])}", Cell(g.status, cls)])
    return Table(["method", "quantity", "within 1 sigma", "expected", "frames", f"{pct(BAND)} band", "gate"], rows,
                 numeric_from=2, text_cols=(6,),
                 caption="Are the sigmas honest? The fraction of frames whose error is within the reported sigma, "
                         "against the fraction honest sigmas give and the binomial band for this many frames.")


def failed_gates_sentence(gs):
    """A sentence naming every failed gate (empty when none failed)."""
    bad = [g for g in gs if g.status == "FAIL"]
    if not bad:
        return ""
    parts = [f"{g.method} {g.quantity} ({pct(g.found)} within 1 sigma, {pct(g.band[0])}-{pct(g.band[1])} expected)"
             for g in bad]
    small = [g for g in bad if g.found < g.band[0]]
    why = " Sigmas too small promise more than the data hold." if small else ""
    if all(g.method in ("orient:general", "orient:aligned") for g in bad):
        why += " (Only the chapter's models, kept for comparison, fail: the exact estimator's sigmas hold.)"
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
    series = [s for s in series if s[1].size or s[2].size]
    if not series:
        return None
    fig = new_figure(figsize=(9.0, 3.6))
    axes = fig.subplots(1, 2)
    for ax, j, dof, what in ((axes[0], 1, 1, "tilt"), (axes[1], 2, 2, "normal")):
        top = 1.0
        for i, s in enumerate(series):
            v = np.sort(s[j])
            if v.size:
                ax.step(v, np.arange(1, v.size + 1) / v.size, where="post", label=method_label(s[0]), color=f"C{i}")
                top = max(top, float(v[-1]))
        x = np.logspace(-3, np.log10(max(top, chi2.ppf(0.999, dof))), 200)
        ax.plot(x, chi2.cdf(x, dof), "k--", label=f"chi2, {dof} dof (honest sigmas)")
        ax.set_xscale("log")
        ax.set_xlabel(f"NEES of the {what}")
        ax.set_ylabel("fraction of frames")
        ax.set_ylim(0, 1.02)
    axes[1].legend(fontsize=7, loc="lower right")
    return Plot(png_bytes(fig), "Normalised squared errors (error / sigma)^2 of every method, against the chi2 "
                "distribution honest sigmas give: a curve to the right of the dashed one means sigmas too small.",
                "empirical CDFs of the normalised squared errors")
