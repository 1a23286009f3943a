"""The shape every experiment's result shares: a header, sections with a status, tilt bins
and RMS summaries (JSON-ready values: degrees, None for what is not finite).

Example
-------
>>> out = {"a": {"status": "ok"}, "b": insufficient_section("no frame below 1 deg")}
>>> finish(out, ["a", "b"])["status"], out["insufficient"]
('partial', [{'section': 'b', 'reason': 'no frame below 1 deg'}])
>>> [(b["tilt_lo_deg"], b["count"], b["x_rms_deg"]) for b in tilt_bins([1.0, 2.0, 15.0], {"x_rms_deg": [3.0, 4.0, 1.0]})]
[(0.0, 2, 3.5355339059327378), (10.0, 1, 1.0)]
"""
from __future__ import annotations

import math

import numpy as np

from .frames import sigma_line

__all__ = ["INSUFFICIENT", "GROSS_Z", "deg_or_none", "insufficient_section", "finish", "header", "tilt_bins", "rms"]

#: The status of a section (or a whole result) the data could not fill.
INSUFFICIENT = "insufficient data"
#: A result this many sd off the reference is a gross error (a wrong root, a mislabelled line).
GROSS_Z = 5.0
# tilt bins of the summaries [deg]
_BIN_DEG = 10.0


def deg_or_none(x):
    """x [rad] in degrees, or None for None, NaN or inf (JSON has neither)."""
    return None if x is None or not np.isfinite(x) else float(np.degrees(x))


def insufficient_section(reason, **extra):
    """A result section the data could not fill: its status, the reason, and what it does bound."""
    return {"status": INSUFFICIENT, "reason": reason, **extra}


def finish(out, sections):
    """Top-level status from the sections: "ok", "partial" or "insufficient data" (then
    with the reasons joined in ``reason``; what the data bound is still in the sections)."""
    bad = [(k, out[k]["reason"]) for k in sections if out[k].get("status") == INSUFFICIENT]
    out["insufficient"] = [{"section": k, "reason": r} for k, r in bad]
    if not bad:
        out["status"] = "ok"
    elif len(bad) < len(sections):
        out["status"] = "partial"
    else:
        out["status"] = INSUFFICIENT
        out["reason"] = "; ".join(f"{k}: {r}" for k, r in bad)
    return out


def header(v, name, frames, skipped):
    """The keys every experiment's result starts with (the input, the frames used and skipped,
    the median line sigma)."""
    sig = sigma_line(frames)
    return {
        "experiment": name,
        "reference": v.get("reference"),
        "sequence": v.get("sequence"),
        "pencil": v.get("pencil"),
        "frames_used": len(frames),
        "frames_skipped": skipped,
        "sigma_line_deg": math.degrees(sig),
        "sigma_line_note": "median of orient.exact.lines.sigma (normalised image coordinates)",
    }


def tilt_bins(tilts_deg, values, weights=None):
    """Per tilt bin (10 deg of `tilts_deg`): count, RMS (and for names with ``_rms_`` the
    median |.|) of each named array in `values`, a list of dicts (empty bins left out)."""
    t = np.asarray(tilts_deg, float)
    out = []
    for lo in np.arange(0.0, 90.0, _BIN_DEG):
        m = (t >= lo) & (t < lo + _BIN_DEG)
        if not m.any():
            continue
        row = {"tilt_lo_deg": float(lo), "tilt_hi_deg": float(lo + _BIN_DEG), "count": int(m.sum())}
        for k, arr in values.items():
            a = np.asarray(arr, float)[m]
            a = a[np.isfinite(a)]
            row[k] = float(np.sqrt(np.mean(a * a))) if a.size else None
            if "_rms_" in k:  # and the median, which a single near-zero-tilt value cannot dominate
                row[k.replace("_rms_", "_median_abs_")] = float(np.median(np.abs(a))) if a.size else None
        out.append(row)
    return out


def rms(x):
    """RMS of the finite values of `x` (None entries skipped), or None when there is none."""
    a = np.asarray([v for v in x if v is not None], float)
    a = a[np.isfinite(a)]
    return float(np.sqrt(np.mean(a * a))) if a.size else None
