"""The sampled-data step: hold the command, land delayed commands, integrate to the next event.

The closed loop of Li et al. 2024 is sampled: the law computes tau_k = (tau1, tau2) from the
state measured at t_k = k Ts, and the plant, model (1)

    x' = v cos theta,  y' = v sin theta,  theta' = omega,  v' = tau1 + d1,  omega' = tau2 + d2,

runs in continuous time between samples under a zero-order hold: the torque it sees is the
newest command that has landed, held constant until the next one lands (with the actuator lag
of :mod:`plant_emulator.dynamics` between command and applied torque). Command k lands at
plant step ``land`` (t_k + delay + jitter rounded to the plant step h, :mod:`hil.sim.landing`);
before the first landing the held torque is zero; when delays reorder commands the newest by
sequence number wins and an older one that lands later is dropped (counted).

The plant's clock is the integer step index j (t = j h, or t0 + j h for a run whose first
sample is at t0), so landings happen exactly on the step grid and every user of this module
integrates the same steps: the offline simulator (:func:`hil.sim.simulate`, one robot on
floats; :func:`hil.sim.simulate_batch`, N robots on arrays) and the plant emulator (lockstep on
the same grid; real time, where events come at arbitrary times, through :func:`integrate_span`).
Lockstep therefore equals the simulator by construction. Pure: explicit state and time, no I/O.

A period k is ``hold.send(k, land, tau1, tau2)``, ``hold.land(j0)`` (the command acting from
t_k on, what a trace row at t_k reports) and ``advance_period(state, hold, plant, j0, j0 + m)``.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np

from plant_emulator.disturbances import Disturbance
from plant_emulator.dynamics import NO_DRAG, Drag, Extremes, PlantState, rk4_array, rk4_float
from protocol.robot import Limits


@dataclass(frozen=True)
class Plant:
    """Model (1) as integrated between events: plant step ``h``, disturbance (d1, d2) with its
    seed (an int, None for the disturbance's own, or one per robot), actuator lag, the limits
    (2) whose violations the extremes count, and the friction and top speed (off: none)."""

    h: float
    disturbance: Disturbance
    lag: float
    seed: Any
    limits: Limits
    drag: Drag = NO_DRAG


class Command(NamedTuple):
    """A command in flight: sequence number, landing plant step (one int for every robot, or
    one per robot), the torques to hold, and a note for the caller (e.g. its log fields)."""

    seq: int
    land: Any
    tau1: Any
    tau2: Any
    note: Any
    steps: tuple[int, ...]  # the distinct landing steps, ascending


_new = tuple.__new__


class _Together:
    """Every robot lands a command at the same step: plain Python conditions (one robot, or a
    batch whose robots share the delay draw; the torques may still be arrays)."""

    any = staticmethod(bool)

    @staticmethod
    def take(newer: bool, c: Command, hold: Hold) -> None:
        if newer:
            hold.cmd1, hold.cmd2, hold.applied_seq = c.tau1, c.tau2, c.seq

    @staticmethod
    def steps(land: int) -> tuple[int, ...]:
        return (land,)


class _Apart:
    """Robots land a command at their own steps: masks over robots."""

    any = staticmethod(np.ndarray.any)

    @staticmethod
    def take(newer: np.ndarray, c: Command, hold: Hold) -> None:
        hold.cmd1 = np.where(newer, c.tau1, hold.cmd1)
        hold.cmd2 = np.where(newer, c.tau2, hold.cmd2)
        hold.applied_seq = np.where(newer, c.seq, hold.applied_seq)

    @staticmethod
    def steps(land: np.ndarray) -> tuple[int, ...]:
        return tuple(np.unique(land).tolist())


class Hold:
    """The zero-order hold of the command and the commands still in flight.

    ``n``: robots (None: one robot on floats). ``apart``: robots land a command at their own
    steps (``land`` an int array of shape (n,)), else all at the same step (``land`` an int).
    ``log``: when a list, every landing is appended as (command, taken), taken a bool (or a
    mask over robots); a command not taken was overtaken by a newer one and is dropped.
    """

    def __init__(self, n: int | None = None, apart: bool = False, log: list | None = None):
        self.cmd1: Any = 0.0 if n is None else np.zeros(n)
        self.cmd2: Any = 0.0 if n is None else np.zeros(n)
        self.applied_seq: Any = np.full(n, -1, dtype=np.int64) if apart else -1
        self.dropped: Any = np.zeros(n, dtype=np.int64) if apart else 0
        self.pending: deque[Command] = deque()
        self.log = log
        self._ns: Any = _Apart if apart else _Together

    def send(self, seq: int, land: Any, tau1: Any, tau2: Any, note: Any = None) -> None:
        """Command ``seq`` leaves now and lands at plant step ``land`` (>= the current step)."""
        # tuple.__new__ skips the NamedTuple's Python-level __new__: once a period on the
        # single-run path, where it was a measurable part of the step's overhead.
        steps = self._ns.steps(land)
        self.pending.append(_new(Command, (seq, land, tau1, tau2, note, steps)))

    def land(self, j: int) -> None:
        """Land every command due at plant step ``j``, oldest first, so that at a shared step
        the newest wins; a command older than the held one is dropped instead."""
        ns = self._ns
        for c in self.pending:
            lands = c.land == j
            if not ns.any(lands):
                continue
            newer = lands & (c.seq > self.applied_seq)
            self.dropped += lands ^ newer  # landed but not newer
            ns.take(newer, c, self)
            if self.log is not None:
                self.log.append((c, newer))
        pending = self.pending
        while pending and pending[0].steps[-1] <= j:
            pending.popleft()

    def landings(self, j: int, j_end: int) -> list[int]:
        """The plant steps strictly between ``j`` and ``j_end`` where a command lands."""
        return sorted({e for c in self.pending for e in c.steps if j < e < j_end})


def advance_period(
    state: PlantState,
    hold: Hold,
    plant: Plant,
    j: int,
    j_end: int,
    ext: Extremes,
    t0: Any = None,
) -> PlantState:
    """Integrate from plant step ``j`` to ``j_end`` (the next sample), landing the commands due
    on the way: the held command is piecewise constant between landings (zero-order hold), so
    RK4 never steps across a change of torque. A landing at ``j_end`` is the next period's.

    ``t0``: None when the plant's clock is the step grid (step i starts at (j + i) h), else the
    time of step 0 (a float, or one per robot): step i then starts at t0 + j h + i h.
    """
    # The RK4 call is written out here rather than in a helper: the single-run path takes this
    # step once a control period, where one more call layer was a measurable overhead.
    h, dist, lag, seed, limits = plant.h, plant.disturbance, plant.lag, plant.seed, plant.limits
    drag = plant.drag
    rk4 = rk4_array if state.x.__class__ is np.ndarray else rk4_float
    grid = t0 is None
    for e in hold.landings(j, j_end) if hold.pending else ():
        start = j * h if grid else t0 + j * h
        c1, c2 = hold.cmd1, hold.cmd2
        state = rk4(
            state, c1, c2, start, h, e - j, dist, lag, seed, limits, ext, j if grid else None, drag
        )
        hold.land(e)
        j = e
    start = j * h if grid else t0 + j * h
    c1, c2 = hold.cmd1, hold.cmd2
    return rk4(
        state, c1, c2, start, h, j_end - j, dist, lag, seed, limits, ext, j if grid else None, drag
    )


def integrate_span(
    state: PlantState,
    cmd1: float,
    cmd2: float,
    plant: Plant,
    t0: float,
    t1: float,
    ext: Extremes,
) -> PlantState:
    """Integrate from time ``t0`` to ``t1`` with the command (cmd1, cmd2) held, in equal RK4
    steps of at most h (the real-time plant, whose events come at arbitrary times)."""
    span = t1 - t0
    if span <= 0.0:
        return state
    n = max(1, math.ceil(span / plant.h - 1e-9))
    return rk4_float(
        state,
        cmd1,
        cmd2,
        t0,
        span / n,
        n,
        plant.disturbance,
        plant.lag,
        plant.seed,
        plant.limits,
        ext,
        None,
        plant.drag,
    )
