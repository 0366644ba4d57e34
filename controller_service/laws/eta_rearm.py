"""The unified law with eta re-armed when the reference comes to rest (beyond the paper).

The paper's eta decays as exp(-integral of (vd^2 + wd^2)): after 70 s of its circle eta is about
1e-9, so xi = eta f is gone and a robot whose reference stops no longer removes a lateral error
(the time-varying term is what makes the nonholonomic robot stabilizable). This wrapper resets
eta to 1 at a sample where

- the reference is at rest (|vd| + |wd| <= ``REST_TOL``),
- eta has decayed below ``below`` (default 0.5), and
- at least ``dwell`` seconds of law time have passed since the last reset (or since t = 0),

then runs the paper's law (:class:`controller_service.laws.unified.UnifiedController`)
unchanged on the re-armed memory. While the reference rests eta' = 0, so one reset per stop; the
dwell bounds the resets to one per ``dwell`` even for a reference that stops and starts. eta
stays in [0, 1], which is all the constraint proofs use (docs/laws.md, "eta re-arm").

Memory: the paper's (eta, z1, z2) and ``since``, the law time since the last reset (starts at
``dwell``: a reference at rest from t = 0 with eta(0) = 1 never triggers). Telemetry: the
paper's keys and ``eta_rearmed`` (1 at the sample where eta was reset).
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import numpy as np

from controller_service.laws.base import ControlOutput, ReferenceSample, RobotState
from controller_service.laws.unified import UnifiedController, UnifiedMemory

REST_TOL = 1e-9  # |vd| + |wd| at or below this is a reference at rest
DWELL_DEFAULT = 5.0  # s between resets at least
BELOW_DEFAULT = 0.5  # reset only an eta that has decayed below this


class RearmMemory(NamedTuple):
    """The paper's eta, z1, z2 and the law time since eta was last reset."""

    eta: Any
    z1: Any
    z2: Any
    since: Any


class EtaRearmController:
    """:class:`UnifiedController` whose eta is reset to 1 when the reference comes to rest
    (module doc). Same name, parameters and design checks as the wrapped law."""

    def __init__(
        self, inner: UnifiedController, dwell: float = DWELL_DEFAULT, below: float = BELOW_DEFAULT
    ) -> None:
        dwell, below = float(dwell), float(below)
        if not (math.isfinite(dwell) and dwell > 0.0):
            raise ValueError(f"[controller] eta_rearm_dwell must be > 0 s, got {dwell!r}")
        if not (0.0 < below <= 1.0):
            raise ValueError(f"[controller] eta_rearm_below must be in (0, 1], got {below!r}")
        self.inner = inner
        self.dwell = dwell
        self.below = below
        self.name = inner.name
        self.params = inner.params
        self.context = inner.context

    def initial_memory(self, n: int | None = None, z1: float = 0.0, z2: float = 0.0) -> Any:
        eta, z1_0, z2_0 = self.inner.initial_memory(n, z1=z1, z2=z2)
        since = self.dwell if n is None else np.full(n, self.dwell)
        return RearmMemory(eta, z1_0, z2_0, since)

    def update(
        self, t: Any, dt: Any, state: RobotState, ref: ReferenceSample, memory: RearmMemory
    ) -> tuple[ControlOutput, RearmMemory]:
        """Reset eta if the rule of the module doc fires, then the paper's law."""
        eta, z1, z2, since = memory
        if isinstance(eta, np.ndarray) or isinstance(ref.vd, np.ndarray):
            rest = np.abs(ref.vd) + np.abs(ref.wd) <= REST_TOL
            fire = rest & (eta < self.below) & (since >= self.dwell)
            eta = np.where(fire, 1.0, eta)
            since = np.where(fire, 0.0, since)
            fired: Any = fire.astype(float)
        else:
            fire = abs(ref.vd) + abs(ref.wd) <= REST_TOL and eta < self.below
            fire = fire and since >= self.dwell
            if fire:
                eta, since = 1.0, 0.0
            fired = 1.0 if fire else 0.0
        out, nxt = self.inner.update(t, dt, state, ref, UnifiedMemory(eta, z1, z2))
        out.telemetry["eta_rearmed"] = fired
        return out, RearmMemory(nxt.eta, nxt.z1, nxt.z2, since + dt)

    def signals(self, t: Any, state: RobotState, ref: ReferenceSample, memory: Any) -> Any:
        return self.inner.signals(t, state, ref, UnifiedMemory(*memory[:3]))

    def resolved_table(self) -> dict[str, Any]:
        """The wrapped law's table and the re-arm keys."""
        return {
            **self.inner.resolved_table(),
            "eta_rearm": True,
            "eta_rearm_dwell": self.dwell,
            "eta_rearm_below": self.below,
        }
