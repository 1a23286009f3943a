"""Reading optional values out of a validation dict, and numbers written for people.

A validation.json may lack any optional part, hold None where a value is missing, or an
odd type where a file was edited by hand: `lookup` and `finite` turn all of those into a
default, and `num` / `pct` into a dash, so that the report shows a gap instead of failing.

Example
-------
>>> lookup({"a": {"b": [1, 2]}}, "a", "b", -1), lookup({"a": None}, "a", "b", default="none")
(2, 'none')
>>> finite("0.5"), finite(float("nan")), finite(True)
(0.5, None, None)
>>> num(0.12345, " deg"), num(2.7e-8), num(None), pct(0.683)
('0.123 deg', '2.7e-08', '–', '68%')
>>> vec([1.0, 2.5, None], " px"), vec(None)
('(1.00, 2.50, –) px', '–')
"""
from __future__ import annotations

import math

import numpy as np

__all__ = ["lookup", "finite", "finite_or_nan", "num", "pct", "vec"]


def lookup(d, *keys, default=None):
    """d[k1][k2]... or `default` when any level is missing, None or not a mapping (an int
    key also indexes a list)."""
    for k in keys:
        if isinstance(d, dict):
            d = d.get(k)
        elif isinstance(d, list) and isinstance(k, int) and -len(d) <= k < len(d):
            d = d[k]
        else:
            return default
        if d is None:
            return default
    return d


def finite(x):
    """A finite float, or None (for None, booleans, text that is no number, NaN and inf)."""
    if isinstance(x, bool) or x is None:
        return None
    try:
        v = float(x)
    except (TypeError, ValueError):
        return None
    return v if math.isfinite(v) else None


def finite_or_nan(x):
    """`finite(x)`, with NaN in place of None (for arrays to plot)."""
    v = finite(x)
    return np.nan if v is None else v


def num(x, unit=""):
    """Angles and errors for people: 3 significant digits, tiny values in e-notation, a
    dash for a missing value; `unit` is appended as given (" deg", " px")."""
    v = finite(x)
    if v is None:
        return "–"
    if v == 0:
        s = "0"
    elif abs(v) < 1e-3:
        s = f"{v:.1e}"
    elif abs(v) >= 1000:
        s = f"{v:.0f}"
    else:
        s = f"{v:#.3g}".rstrip(".")
    return s + unit


def pct(x):
    """A fraction (0.683) as a whole percentage ("68%"), a dash when missing."""
    v = finite(x)
    return "–" if v is None else f"{100 * v:.0f}%"


def vec(v, unit=""):
    """A vector for people, "(x, y, z)" with each number as `num` writes it and `unit`
    after it; a dash when it is no vector."""
    try:
        return "(" + ", ".join(num(x) for x in v) + ")" + unit
    except TypeError:
        return "–"
