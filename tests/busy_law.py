"""A user's law that is slower by a known amount, loaded by import path in tests:
``tests.busy_law:BusyUnified``. It is the unified law, then a busy wait of ``busy_us``
(default 200 µs) on every ``busy_every``-th sample (default 1: every one; the sample's slot k =
t / dt), so the controller's ``compute`` figure must rise by exactly that there and nowhere else
(the known answer of tests/test_calibration.py)."""

from __future__ import annotations

import time
from typing import Any

from controller_service.laws.base import ControlOutput, DesignContext, ReferenceSample, RobotState
from controller_service.registry import build_controller


class BusyUnified:
    """The unified law (the rest of the [controller] table is its parameters) + a busy wait."""

    name = "busy_unified"

    def __init__(self, params: dict[str, Any], context: DesignContext) -> None:
        params = dict(params)
        self.busy_ns = int(float(params.pop("busy_us", 200.0)) * 1000)
        self.every = int(params.pop("busy_every", 1))
        self.inner = build_controller({"law": "unified", **params}, context)

    def initial_memory(self, n: int | None = None, z1: float = 0.0, z2: float = 0.0) -> Any:
        return self.inner.initial_memory(n, z1=z1, z2=z2)

    def update(
        self, t: float, dt: float, state: RobotState, ref: ReferenceSample, memory: Any
    ) -> tuple[ControlOutput, Any]:
        out = self.inner.update(t, dt, state, ref, memory)
        if round(t / dt) % self.every:
            return out
        # Spin, not sleep: a sleep would hand the CPU away and wake late by a scheduler's
        # whim; the wait starts after the law, so it adds busy_ns to whatever the law took.
        end = time.perf_counter_ns() + self.busy_ns
        while time.perf_counter_ns() < end:
            pass
        return out
