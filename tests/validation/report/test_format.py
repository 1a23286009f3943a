"""validation.report.format: numbers for people, and values read out of odd files."""
from __future__ import annotations

from pencilcal.validation.report.format import finite, lookup, num, pct


def test_number_format():
    assert [num(v) for v in (None, float("nan"), 0, 0.12, 0.1204, 5.0, 145.24, 2.7e-8, 1234.5)] == \
        ["–", "–", "0", "0.120", "0.120", "5.00", "145", "2.7e-08", "1234"]
    assert [pct(v) for v in (None, "x", 0.6827, 1)] == ["–", "–", "68%", "100%"]


def test_missing_and_odd_values_become_defaults():
    d = {"a": {"b": [1, None, {"c": 3}]}, "n": None}
    assert lookup(d, "a", "b", 2, "c") == 3
    assert lookup(d, "a", "b", 1, default="gap") == "gap"  # None inside
    assert lookup(d, "a", "b", 5) is None and lookup(d, "n", "x", default=0) == 0
    assert lookup([1, 2], "a") is None  # a string key into a list
    assert [finite(v) for v in (True, None, "2.5", "x", float("inf"), 3)] == [None, None, 2.5, None, None, 3.0]
