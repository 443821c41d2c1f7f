"""Fixtures of the core tests."""

from __future__ import annotations

import pytest


@pytest.fixture(params=["plain", "compiled"])
def runs(request):
    """The sequential rules' runs a link hands its effects: None (core's plain functions) or the
    compiled ones (engine/compiled/link_runs.py; skipped without numba)."""
    if request.param == "plain":
        return None
    return pytest.importorskip("haptic_teleop.engine.compiled.link_runs").RUNS
