"""A user's law that stalls its controller once, by a known amount, loaded by import path in
tests: ``tests.stall_law:SpinOnceUnified``. It is the unified law; the first update at or after
law time ``spin_at_s`` busy-waits ``spin_ms`` (default 30 ms) before it returns, longer than many
periods: the controller's own stall, on a CPU it holds (tests/test_stall_rows.py)."""

from __future__ import annotations

import time
from typing import Any

from controller_service.laws.base import ControlOutput, DesignContext, ReferenceSample, RobotState
from controller_service.registry import build_controller


class SpinOnceUnified:
    """The unified law (the rest of the [controller] table is its parameters) + one busy wait."""

    name = "spin_once_unified"

    def __init__(self, params: dict[str, Any], context: DesignContext) -> None:
        params = dict(params)
        self.spin_ns = int(float(params.pop("spin_ms", 30.0)) * 1e6)
        self.at_s = float(params.pop("spin_at_s", 1.0))
        self.done = False
        self.inner = build_controller({"law": "unified", **params}, context)

    def initial_memory(self, n: int | None = None, z1: float = 0.0, z2: float = 0.0) -> Any:
        return self.inner.initial_memory(n, z1=z1, z2=z2)

    def update(
        self, t: float, dt: float, state: RobotState, ref: ReferenceSample, memory: Any
    ) -> tuple[ControlOutput, Any]:
        out = self.inner.update(t, dt, state, ref, memory)
        if not self.done and t >= self.at_s:
            self.done = True
            # Spin, not sleep: the controller keeps its CPU, runnable and running, so its
            # lateness is its own (no run-queue wait), as a law too slow for its period.
            end = time.perf_counter_ns() + self.spin_ns
            while time.perf_counter_ns() < end:
                pass
        return out
