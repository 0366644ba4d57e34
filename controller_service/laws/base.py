"""The controller interface every law implements (the paper's four and a user's own).

Modelled on ros2_control: a controller's ``update(t, dt, ...)`` knows nothing of transports.
Everything is explicit: the law's internal states (for the unified law eta, z1, z2) live in a
*memory* value that ``update`` takes and returns, so the same object serves the offline
simulator, the batch path (fields are numpy arrays of shape (N,)) and the real-time service
(fields are floats).

A user's controller is any class with this shape, named in the scenario as
``[controller] law = "package.module:Class"``; it is built as ``Class(params, context)`` where
``params`` is the ``[controller]`` table (a dict) and ``context`` a :class:`DesignContext`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, NamedTuple, Protocol, runtime_checkable

from protocol.robot import Limits, Number, RobotState

__all__ = [
    "ControlOutput",
    "Controller",
    "DesignContext",
    "Limits",
    "Number",
    "ReferenceSample",
    "RobotState",
]


class ReferenceSample(NamedTuple):
    """The virtual robot (3) at one instant, with the accelerations of Assumption 2."""

    xd: Number
    yd: Number
    thetad: Number
    vd: Number
    wd: Number
    dvd: Number = 0.0
    dwd: Number = 0.0


class ControlOutput(NamedTuple):
    """Commanded torques (tau1 on v, tau2 on omega, model (1)) and the law's telemetry.

    ``telemetry`` holds the paper's internal signals when the law has them (xe, ye, theta_e, xi,
    v_tilde, w_tilde, z1, z2, eta); it may be empty.
    """

    tau1: Number
    tau2: Number
    telemetry: Mapping[str, Number]


@dataclass(frozen=True)
class DesignContext:
    """What a controller may know when it is built: limits (2), disturbance bounds of
    Assumption 1 (s1, s2 = the paper's varsigma) and reference bounds of Assumption 2."""

    limits: Limits = Limits()  # noqa: RUF009 (Limits is frozen: one shared default is safe)
    s1: float = 0.0
    s2: float = 0.0
    mu1: float = 0.5
    mu2: float = 0.2
    k1: float = 1.0
    k2: float = 1.0


@runtime_checkable
class Controller(Protocol):
    """One control law. ``update`` is pure: same inputs, same outputs, memory passed explicitly.

    - ``initial_memory(n, z1=0.0, z2=0.0)``: the law's internal state at t = 0 for one robot
      (``n is None``, floats) or for ``n`` robots (numpy arrays of shape (n,)), starting the
      adaptive states of (8) at z1(0), z2(0) (the scenario's [initial] z1, z2); a law without
      adaptive states ignores them.
    - ``update(t, dt, state, ref, memory)``: the torque command at law time ``t`` from the
      sampled ``state`` and reference, and the memory advanced to ``t + dt`` by the law's
      stated rule (``dt`` is the nominal control period). Torques never exceed the limits.
    """

    name: str

    def initial_memory(self, n: int | None = None, z1: float = 0.0, z2: float = 0.0) -> Any: ...

    def update(
        self, t: float, dt: float, state: RobotState, ref: ReferenceSample, memory: Any
    ) -> tuple[ControlOutput, Any]: ...
