"""A small user law for ``hil margin`` and the worst-disturbance search, loaded by import path
(``tests.margin_user_law:SaturatedTracker``). It runs on floats and on numpy arrays (the batch
path), as every law the bench simulates in batches must."""

from __future__ import annotations

from typing import Any

import numpy as np

from controller_service.laws.base import ControlOutput, DesignContext, ReferenceSample, RobotState


class SaturatedTracker:
    """A kinematic tracker (Kanayama-like velocity commands) with a saturated proportional
    torque loop: tau = clip(k (v_c - v)), no adaptive states."""

    name = "saturated_tracker"

    def __init__(self, params: dict[str, Any], context: DesignContext) -> None:
        unknown = set(params) - {"gain", "kx", "ky", "kth"}
        if unknown:
            raise ValueError(f"unknown key(s) {sorted(unknown)}")
        self.gain = float(params.get("gain", 20.0))
        self.kx = float(params.get("kx", 1.0))
        self.ky = float(params.get("ky", 2.0))
        self.kth = float(params.get("kth", 2.0))
        self.limits = context.limits

    def initial_memory(self, n: int | None = None, z1: float = 0.0, z2: float = 0.0) -> Any:
        return None

    def update(
        self, t: Any, dt: Any, state: RobotState, ref: ReferenceSample, memory: Any
    ) -> tuple[ControlOutput, Any]:
        c, s = np.cos(state.theta), np.sin(state.theta)
        dx, dy = ref.xd - state.x, ref.yd - state.y
        xe, ye = c * dx + s * dy, c * dy - s * dx
        the = ref.thetad - state.theta
        v_c = ref.vd * np.cos(the) + self.kx * xe
        w_c = ref.wd + ref.vd * (self.ky * ye + self.kth * np.sin(the))
        lim = self.limits
        tau1 = np.clip(self.gain * (v_c - state.v), -lim.varpi1, lim.varpi1)
        tau2 = np.clip(self.gain * (w_c - state.omega), -lim.varpi2, lim.varpi2)
        if np.ndim(tau1) == 0:
            tau1, tau2 = float(tau1), float(tau2)
        return ControlOutput(tau1, tau2, {}), memory


class ConstantPush:
    """tau1 = push, tau2 = push / 10 whatever the state: tests of the disturbance modes."""

    name = "constant_push"

    def __init__(self, params: dict[str, Any], context: DesignContext) -> None:
        self.push = float(params.get("push", 1.0))

    def initial_memory(self, n: int | None = None, z1: float = 0.0, z2: float = 0.0) -> Any:
        return None

    def update(
        self, t: Any, dt: Any, state: RobotState, ref: ReferenceSample, memory: Any
    ) -> tuple[ControlOutput, Any]:
        return ControlOutput(self.push, self.push / 10.0, {}), memory
