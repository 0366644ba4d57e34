"""Shared fixtures. ``spawn`` starts processes that are stopped by PID even when a test fails."""

from __future__ import annotations

import pytest

from tests.procs import Spawner


@pytest.fixture
def spawn():
    spawner = Spawner()
    try:
        yield spawner
    finally:
        spawner.stop_all()
