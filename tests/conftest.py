"""Shared fixtures (plain helpers live in tests/helpers.py)."""

from __future__ import annotations

import pytest

from .helpers import run


@pytest.fixture(scope="session")
def circle_set1_traces():
    """Circle, no load, default sensing, 7 s: DRC, DARC, DIARC (used by several tests)."""
    return {name: run(name)[0] for name in ("drc", "darc", "diarc")}
