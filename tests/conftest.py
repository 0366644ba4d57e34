"""Shared fixtures. ``spawn`` starts processes that are stopped by PID even when a test fails."""

from __future__ import annotations

import signal

import pytest

from tests import vcan_lane
from tests.procs import Spawner
from tests.vcan_lane import LANE_TEST


def pytest_configure(config):
    """Children start with SIGINT as at a terminal, however the suite was launched.

    A shell starts a background job (``.ci/run &`` from a script) with SIGINT ignored, and an
    ignored signal is inherited across exec: every process a test starts would then ignore
    the Ctrl-C the Ctrl-C tests send it. A handled signal is reset to its default on exec."""
    if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)


@pytest.fixture
def spawn():
    spawner = Spawner()
    try:
        yield spawner
    finally:
        spawner.stop_all()


def _vcan_skip_reason() -> str | None:
    """Why ``vcan`` tests cannot run in this process, or None when vcan0 is usable here."""
    from tools.vcan_guest.native import native_vcan_status

    usable, reason = native_vcan_status()
    if usable:
        return None
    return (
        f"{reason}: vcan tests run in the QEMU guest lane instead "
        "(tests/test_vcan_lane.py; python -m tools.vcan_guest run -- python -m pytest -m vcan)"
    )


def pytest_collection_modifyitems(config, items):
    # The vcan lane runs beside the session (tests/vcan_lane.py): its test, which waits for it,
    # goes last so that it waits least.
    lane = [item for item in items if item.name == LANE_TEST]
    items[:] = [item for item in items if item.name != LANE_TEST] + lane
    vcan_items = [item for item in items if item.get_closest_marker("vcan")]
    if not vcan_items:
        return
    reason = _vcan_skip_reason()
    if reason is None:
        return
    for item in vcan_items:
        item.add_marker(pytest.mark.skip(reason=reason))


def pytest_collection_finish(session):
    vcan_lane.start_beside(session.items, collect_only=session.config.option.collectonly)


def pytest_sessionfinish(session, exitstatus):
    vcan_lane.stop_beside()
    vcan_lane.remove_beside_log(keep=exitstatus != 0)
