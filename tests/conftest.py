"""Shared fixtures: the real image sets in ../shared/data and reproducible random numbers."""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]
# The real image sets live beside the checkout; PENCILCAL_DATA overrides the location.
DATA = Path(os.environ.get("PENCILCAL_DATA", REPO.parent / "shared" / "data"))


def data_dir(name: str) -> Path:
    """Path of one real image set, or skip the test with the reason if it is absent."""
    p = DATA / name
    if not p.is_dir():
        pytest.skip(f"real image set {name!r} not found under {DATA} (set PENCILCAL_DATA)")
    return p


@pytest.fixture
def rng():
    return np.random.default_rng(12345)
