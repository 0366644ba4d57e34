"""A user's law on the batch path (``hil sweep``: every robot at once, the state and reference as
arrays of shape (N,); docs/own-controller.md, "Floats and arrays: one source", says what the
probe of :func:`for_batch` does). A law written for one robot on floats fails there or, worse,
returns one robot's torque for all: then :class:`PerRobot` runs it one robot at a time.

:func:`batch_update` is the batch path's call of the law, through the law guard
(:mod:`controller_service.laws.guard`): a robot whose torque is not finite is that robot's law
fault alone; a call on arrays that raises or returns the wrong type is a fault of every robot
of the batch (one call computed them all: no robot's result can be told apart), while
:class:`PerRobot` calls the law robot by robot, so there each robot's fault is its own. A
faulted robot gets zero torque from its fault on (its law is no longer called robot by robot;
on arrays its memory goes on with the others' but never acts again).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from controller_service.laws.base import ControlOutput, ReferenceSample, RobotState
from controller_service.laws.guard import (
    NON_FINITE,
    WRONG_TYPE,
    LawFault,
    LawFaultError,
    bad_torques,
    call_update,
    checked_update,
    fault,
)
from controller_service.registry import BUILTIN_LAWS, resolved_controller_table
from hil.errors import BadInputError
from hil.provenance import Toml

# Two robots that differ in every state field, so a law that mixes robots up is seen.
_PROBE_OFFSETS = (0.0, 0.1)


class PerRobot:
    """The batch path's face of a law that takes one robot on floats: ``update`` on arrays
    calls the law once per robot; the memory is a list of the robots' own memories."""

    def __init__(self, law: Any, reason: str, probe_fault: LawFault | None = None) -> None:
        self.law = law
        self.reason = reason
        self.probe_fault = probe_fault  # the law failed on one robot before the loop
        self.name = str(getattr(law, "name", type(law).__name__))

    def resolved_table(self) -> Toml:
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
        step = self.update_robots(t, dt, state, ref, memory, np.zeros(len(memory), dtype=bool))
        if step.faults:
            raise LawFaultError(next(iter(step.faults.values())))
        return ControlOutput(step.tau1, step.tau2, step.telemetry), step.memory

    def update_robots(
        self, t: Any, dt: float, state: Any, ref: Any, memory: list[Any], skip: np.ndarray
    ) -> BatchStep:
        """Each robot but those ``skip`` marks (faulted before) through the law guard, one
        call each: a robot whose call fails is faulted alone (zero torque, memory kept)."""
        n = len(memory)
        times = np.broadcast_to(np.asarray(t, dtype=float), (n,))
        states = [np.broadcast_to(np.asarray(f, dtype=float), (n,)) for f in state]
        refs = [np.broadcast_to(np.asarray(f, dtype=float), (n,)) for f in ref]
        tau1, tau2 = np.zeros(n), np.zeros(n)
        memory = list(memory)
        outs: dict[int, Any] = {}
        faults: dict[int, LawFault] = {}
        for i in np.flatnonzero(~skip).tolist():
            t_i = float(times[i])
            s_i = RobotState(*(float(f[i]) for f in states))
            r_i = ReferenceSample(*(float(f[i]) for f in refs))
            try:
                out, mem = call_update(self.law, t_i, dt, s_i, r_i, memory[i])
            except LawFaultError as exc:
                faults[i] = exc.fault.for_robot(i, t_i, s_i, r_i)
                continue
            bad = bad_torques(out.tau1, out.tau2)
            if bad is not None:
                kind = WRONG_TYPE if " of type " in bad else NON_FINITE
                faults[i] = fault(self.law, kind, t_i, s_i, r_i, bad).for_robot(i, t_i, s_i, r_i)
                continue
            tau1[i], tau2[i] = float(out.tau1), float(out.tau2)
            memory[i] = mem
            outs[i] = out
        keys = list(next(iter(outs.values())).telemetry) if outs else []
        telemetry = {
            k: np.array([float(outs[i].telemetry.get(k, np.nan)) if i in outs else np.nan
                         for i in range(n)])
            for k in keys
        }  # fmt: skip
        return BatchStep(tau1, tau2, telemetry, memory, faults)


@dataclass
class BatchStep:
    """One sample of the batch path: the torques (arrays (N,), zero for a robot that has
    faulted), the telemetry, the memory at t + dt and the robots that faulted at this sample."""

    tau1: np.ndarray
    tau2: np.ndarray
    telemetry: dict[str, Any]
    memory: Any
    faults: dict[int, LawFault] = field(default_factory=dict)


def batch_update(
    controller: Any, t: Any, dt: float, state: Any, ref: Any, memory: Any, faulted: np.ndarray
) -> BatchStep:
    """One sample of N robots through the law guard (module docstring); ``faulted``: (N,) the
    robots that faulted before (their torque stays zero, they are not faulted again)."""
    n = len(faulted)
    if isinstance(controller, PerRobot) and isinstance(memory, list):
        return controller.update_robots(t, dt, state, ref, memory, faulted)
    try:
        out, memory_next = call_update(controller, t, dt, state, ref, memory)
        tau1 = np.broadcast_to(np.asarray(out.tau1, dtype=float), (n,))
        tau2 = np.broadcast_to(np.asarray(out.tau2, dtype=float), (n,))
    except (LawFaultError, TypeError, ValueError) as exc:
        if isinstance(exc, LawFaultError):
            record = exc.fault
        else:  # torques that are no numbers, or not one per robot
            detail = f"torques of types {type(out.tau1).__name__}, {type(out.tau2).__name__}"
            record = fault(controller, WRONG_TYPE, t, state, ref, detail)
        faults = {i: record.for_robot(i, t, state, ref) for i in np.flatnonzero(~faulted).tolist()}
        return BatchStep(np.zeros(n), np.zeros(n), {}, memory, faults)
    bad = ~(np.isfinite(tau1) & np.isfinite(tau2))
    faults = {
        i: fault(controller, NON_FINITE, t, state, ref, bad_torques(tau1, tau2, i) or "?", robot=i)
        for i in np.flatnonzero(bad & ~faulted).tolist()
    }
    off = bad | faulted
    if off.any():
        tau1, tau2 = np.where(off, 0.0, tau1), np.where(off, 0.0, tau2)
    return BatchStep(tau1, tau2, dict(out.telemetry), memory_next, faults)


def _what(exc: BaseException) -> str:
    text = " ".join(str(exc).split())
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def array_problem(controller: Any, scenario: Any, reference: Any) -> str | None:
    """Why ``controller`` cannot run on arrays (None: it can). Raises LawFaultError when its
    update fails even on one robot (a fault of the law, at t = 0), BadInputError when its
    initial memory does."""
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
            out, _ = checked_update(controller, 0.0, ts, robot, ref, memory)
            singles.append((float(out.tau1), float(out.tau2)))
    except LawFaultError:
        raise  # the law itself failed: a fault of the law (hil.law.batch's callers say so)
    except Exception as exc:  # the user's initial_memory may raise anything
        raise BadInputError(
            f"[controller] law {law!r}: its initial memory on one robot failed: {_what(exc)}"
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
    try:
        problem = array_problem(controller, scenario, reference)
    except LawFaultError as exc:
        # Robot by robot, so that the loop finds each robot's own fault with its own input.
        return PerRobot(controller, f"it failed on one robot: {exc.fault.detail}", exc.fault)
    return controller if problem is None else PerRobot(controller, problem)


def batch_note(controller: Any, scenario: Any, reference: Any) -> str | None:
    """One line for the user when the batch path runs the law one robot at a time (none when
    the law failed even on one robot: the run reports that fault)."""
    ready = for_batch(controller, scenario, reference)
    if not isinstance(ready, PerRobot) or ready.probe_fault is not None:
        return None
    return (
        f"note: law {scenario.controller.get('law')!r} does not take numpy arrays "
        f"({ready.reason}); the batch path runs it one robot at a time (same results, slower). "
        "To run it on arrays, write it with runtime.mathns (docs/own-controller.md)."
    )
