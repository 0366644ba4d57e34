"""A user's law on the batch path (``hil sweep``: every robot at once, the state and reference as
arrays of shape (N,); docs/own-controller.md, "Floats and arrays: one source", says what the
probe of :func:`for_batch` does). A law written for one robot on floats fails there or, worse,
returns one robot's torque for all: then :class:`PerRobot` runs it one robot at a time.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from controller_service.laws.base import ControlOutput, ReferenceSample, RobotState
from controller_service.registry import BUILTIN_LAWS, resolved_controller_table
from hil.errors import BadInputError

# Two robots that differ in every state field, so a law that mixes robots up is seen.
_PROBE_OFFSETS = (0.0, 0.1)


class PerRobot:
    """The batch path's face of a law that takes one robot on floats: ``update`` on arrays
    calls the law once per robot; the memory is a list of the robots' own memories."""

    def __init__(self, law: Any, reason: str) -> None:
        self.law = law
        self.reason = reason
        self.name = str(getattr(law, "name", type(law).__name__))

    def resolved_table(self) -> dict[str, Any]:
        return resolved_controller_table(self.law)

    def initial_memory(self, n: int | None = None, z1: Any = 0.0, z2: Any = 0.0) -> Any:
        if n is None:
            return self.law.initial_memory(None, z1=z1, z2=z2)
        z1s, z2s = np.broadcast_to(z1, (n,)), np.broadcast_to(z2, (n,))
        return [self.law.initial_memory(None, z1=float(z1s[i]), z2=float(z2s[i])) for i in range(n)]

    def update(
        self, t: Any, dt: float, state: RobotState, ref: ReferenceSample, memory: Any
    ) -> tuple[ControlOutput, Any]:
        if not isinstance(memory, list):  # one robot on floats: the law itself
            return self.law.update(t, dt, state, ref, memory)
        n = len(memory)
        times = np.broadcast_to(np.asarray(t, dtype=float), (n,))
        states = [np.broadcast_to(np.asarray(f, dtype=float), (n,)) for f in state]
        refs = [np.broadcast_to(np.asarray(f, dtype=float), (n,)) for f in ref]
        robots = [
            self.law.update(
                float(times[i]),
                dt,
                RobotState(*(float(f[i]) for f in states)),
                ReferenceSample(*(float(f[i]) for f in refs)),
                memory[i],
            )
            for i in range(n)
        ]
        outs = [out for out, _ in robots]
        keys = list(outs[0].telemetry)
        telemetry = {k: np.array([float(o.telemetry.get(k, np.nan)) for o in outs]) for k in keys}
        tau1 = np.array([float(o.tau1) for o in outs])
        tau2 = np.array([float(o.tau2) for o in outs])
        return ControlOutput(tau1, tau2, telemetry), [mem for _, mem in robots]


def _what(exc: BaseException) -> str:
    text = " ".join(str(exc).split())
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def array_problem(controller: Any, scenario: Any, reference: Any) -> str | None:
    """Why ``controller`` cannot run on arrays (None: it can). Raises BadInputError when it
    fails even on one robot: then no path can run it."""
    law = str(scenario.controller.get("law", "unified"))
    ini, ts = scenario.initial, float(scenario.timing.ts)
    robots = [
        RobotState(ini.x + d, ini.y - d, ini.theta + d, ini.v + d, ini.omega - d)
        for d in _PROBE_OFFSETS
    ]
    ref = ReferenceSample(*(float(v) for v in reference.sample(0.0)))
    singles = []
    try:
        for robot in robots:
            memory = controller.initial_memory(None, z1=ini.z1, z2=ini.z2)
            out, _ = controller.update(0.0, ts, robot, ref, memory)
            singles.append((float(out.tau1), float(out.tau2)))
    except Exception as exc:  # the user's code may raise anything
        raise BadInputError(
            f"[controller] law {law!r}: its first update on one robot failed: {_what(exc)}"
        ) from exc
    n = len(robots)
    try:
        memory = controller.initial_memory(n, z1=ini.z1, z2=ini.z2)
        state = RobotState(*(np.array(f, dtype=float) for f in zip(*robots, strict=True)))
        refs = ReferenceSample(*(np.full(n, v) for v in ref))
        out, _ = controller.update(0.0, ts, state, refs, memory)
        tau = [np.broadcast_to(np.asarray(t, dtype=float), (n,)) for t in (out.tau1, out.tau2)]
    except Exception as exc:  # the user's code may raise anything on arrays
        return _what(exc)
    got = np.stack(tau, axis=1)
    if not np.allclose(got, np.array(singles), rtol=1e-9, atol=1e-12, equal_nan=True):
        return "on arrays it returned other torques than robot by robot"
    return None


def for_batch(controller: Any, scenario: Any, reference: Any) -> Any:
    """The law ready for the batch path: a built-in law as it is (they are written for arrays,
    tests/test_law_unified.py), a user's law as it is when the probe agrees, else wrapped in
    :class:`PerRobot`."""
    builtin = scenario.controller.get("law", "unified") in BUILTIN_LAWS
    if builtin or isinstance(controller, PerRobot):
        return controller
    problem = array_problem(controller, scenario, reference)
    return controller if problem is None else PerRobot(controller, problem)


def batch_note(controller: Any, scenario: Any, reference: Any) -> str | None:
    """One line for the user when the batch path runs the law one robot at a time."""
    ready = for_batch(controller, scenario, reference)
    if not isinstance(ready, PerRobot):
        return None
    return (
        f"note: law {scenario.controller.get('law')!r} does not take numpy arrays "
        f"({ready.reason}); the batch path runs it one robot at a time (same results, slower). "
        "To run it on arrays, write it with runtime.mathns (docs/own-controller.md)."
    )
