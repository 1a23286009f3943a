"""Fixtures of the detector tests."""
from __future__ import annotations

import pytest

from tests.helpers import hd_camera


@pytest.fixture(scope="module")
def hd():
    return hd_camera()
