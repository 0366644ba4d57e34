"""An example user controller, loaded by import path in tests: ``tests.example_user_controller:
SaturatedPD``. It satisfies the Controller protocol of controller_service.laws.base."""

from __future__ import annotations

import math
from typing import Any

from controller_service.laws.base import ControlOutput, DesignContext, ReferenceSample, RobotState


class SaturatedPD:
    """Drives v, omega towards the reference's vd, wd with a saturated proportional torque."""

    name = "saturated_pd"

    def __init__(self, params: dict[str, Any], context: DesignContext) -> None:
        unknown = set(params) - {"gain"}
        if unknown:
            raise ValueError(f"unknown key(s) {sorted(unknown)}")
        self.gain = float(params.get("gain", 5.0))
        self.limits = context.limits

    def initial_memory(self, n: int | None = None, z1: float = 0.0, z2: float = 0.0) -> Any:
        return None

    def update(
        self, t: float, dt: float, state: RobotState, ref: ReferenceSample, memory: Any
    ) -> tuple[ControlOutput, Any]:
        def clip(value: float, bound: float) -> float:
            return max(-bound, min(bound, value)) if math.isfinite(value) else 0.0

        tau1 = clip(self.gain * (ref.vd - state.v), self.limits.varpi1)
        tau2 = clip(self.gain * (ref.wd - state.omega), self.limits.varpi2)
        return ControlOutput(tau1, tau2, {}), memory


class OldMemorySignature(SaturatedPD):
    """``initial_memory(n)`` without z1, z2: loading it must fail, naming initial_memory."""

    def initial_memory(self, n: int | None = None) -> Any:  # type: ignore[override]
        return None


class NotAController:
    """Has no update method: loading it must fail clearly."""

    def __init__(self, params: dict[str, Any], context: DesignContext) -> None:
        self.name = "broken"

    def initial_memory(self, n: int | None = None, z1: float = 0.0, z2: float = 0.0) -> Any:
        return None
