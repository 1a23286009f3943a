"""Facts the report's parts share, drawn from a validation dict: which methods there are,
their per-frame errors, which one the verdict speaks for, and how the reference, the
pencil and the calibration are named on the page.

Methods are named by their key in validation.json: ``orient:<model>``, ``pnp:<method>``,
``sfm``, or any other key of the summary.

Example
-------
>>> data = {"models": ["exact"], "methods": ["sqpnp"], "reference": "truth",
...         "summary": {"pnp:sqpnp": {"frames": 1}, "orient:exact": {"frames": 1}},
...         "frames": [{"errors": {"orient:exact": {"normal_deg": 0.2}, "pnp:sqpnp": {"normal_deg": 0.0}}}]}
>>> method_keys(data), primary_method(data), same_as_reference(data, "pnp:sqpnp")
(['orient:exact', 'pnp:sqpnp'], 'orient:exact', True)
>>> reference_phrase(data)
'ground-truth poses (truth.json)'
"""
from __future__ import annotations

from collections import Counter
from pathlib import Path

import numpy as np

from .format import finite, lookup, num

__all__ = [
    "SAME_AS_REFERENCE_DEG",
    "method_label",
    "method_keys",
    "method_errors",
    "same_as_reference",
    "reference_counts",
    "primary_method",
    "comparison_keys",
    "reference_phrase",
    "pencil_phrase",
    "calibration_same_images",
]

#: [deg] a method whose errors stay below this in every frame *is* the reference (PnP
#: against the best PnP): it is listed, but neither plotted nor judged
SAME_AS_REFERENCE_DEG = 1e-6


def method_label(key):
    """How a method is named on the page: its key in validation.json."""
    return str(key)


def method_keys(data):
    """Every method of the file, in reading order: orient models, PnP methods, sfm, others."""
    summ = data.get("summary") or {}
    order = [f"orient:{m}" for m in (data.get("models") or [])] + [f"pnp:{m}" for m in (data.get("methods") or [])]
    if "sfm" in summ or isinstance(data.get("sfm"), dict):
        order.append("sfm")
    for k in summ:
        if k not in order:
            order.append(k)
    # orient first, then pnp, then the rest, each group in the file's order
    rank = lambda k: 0 if k.startswith("orient:") else 1 if k.startswith("pnp:") else 2  # noqa: E731
    return sorted(dict.fromkeys(order), key=lambda k: (rank(k), order.index(k)))


def method_errors(data, key):
    """[(frame index, frame, error record)] of one method, for the frames that have one."""
    out = []
    for i, fr in enumerate(data["frames"]):
        e = lookup(fr, "errors", key)
        if isinstance(e, dict):
            out.append((i, fr, e))
    return out


def same_as_reference(data, key):
    """True when the method's errors vanish in every frame (it is the reference itself)."""
    vals = [finite(e.get("normal_deg")) for _, _, e in method_errors(data, key)]
    vals = [v for v in vals if v is not None]
    rot = [finite(e.get("rotation_deg")) for _, _, e in method_errors(data, key)]
    rot = [v for v in rot if v is not None]
    return bool(vals) and max(vals + rot) < SAME_AS_REFERENCE_DEG


def reference_counts(data):
    """How often each PnP method was the per-frame reference (reference pnp): a Counter."""
    return Counter(f.get("pnp_best") for f in data["frames"]
                   if f.get("reference") == "pnp" and f.get("pnp_best") and f.get("R_ref") is not None)


def primary_method(data):
    """The orient key the verdict speaks for (exact, else general, else aligned, else any
    orient key with frames), or None when no orient model produced an estimate."""
    for key in ("orient:exact", "orient:general", "orient:aligned"):
        if (lookup(data, "summary", key, "frames") or 0) > 0:
            return key
    for key in method_keys(data):
        if key.startswith("orient:") and (lookup(data, "summary", key, "frames") or 0) > 0:
            return key
    return None


def comparison_keys(data):
    """The orient keys kept for comparison: every orient model but the primary one (the
    book chapter's general and aligned models beside the exact estimator). The report
    shows them labelled, grey, and never judges them."""
    prim = primary_method(data)
    return [k for k in method_keys(data) if k.startswith("orient:") and k != prim]


def reference_phrase(data):
    """What the errors are measured against, in words."""
    ref = data.get("reference")
    if ref == "truth":
        return "ground-truth poses (truth.json)"
    if ref == "pnp":
        return "board pose from PnP (best method per frame)"
    return f"reference ({ref or 'unknown'})"


def _distinct_directions(angles):
    """How many line directions (angles in degrees, modulo 180) a list of spoke angles has."""
    try:
        return int(np.unique(np.round(np.mod(np.asarray(angles, float), 180.0), 6) % 180.0).size)
    except (TypeError, ValueError):
        return 0


def pencil_phrase(data):
    """The pencil in words: a printed fan (spokes, radii) or the board's grid lines."""
    p = data.get("pencil") or {}
    if not isinstance(p, dict):
        return "pencil: unknown"
    n = len(p.get("angles_deg") or [])
    if p.get("grid") is not None:
        where = "the best detected inner corner of each frame" if p.get("grid") == "auto" else f"corner {p['grid']}"
        d = _distinct_directions(p.get("angles_deg"))
        return f"the board's grid lines through {where} ({n} spokes in {d} line directions; no spoke radii)"
    radius = p.get("radius")
    return (f"a printed fan of {n} spokes" + (f", radius {num(radius[0])}-{num(radius[1])}"
                                              if isinstance(radius, list) and len(radius) == 2 else ", no radii"))


def calibration_same_images(data):
    """True when the camera was calibrated on the very images it is validated on."""
    cal = data.get("calibration")
    if not isinstance(cal, dict) or not cal.get("images") or not data.get("images"):
        return False
    try:
        return Path(str(cal["images"])).resolve() == Path(str(data["images"])).resolve()
    except OSError:
        return str(cal["images"]) == str(data["images"])
