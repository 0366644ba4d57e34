"""N closed loops whose disturbance is chosen by the loop: the batch path of the worst-case search
(docs/margin.md, "The worst disturbance": the ``MODES`` and the patterns).

The loop is the offline simulator's (:mod:`hil.sim.core`): at sample k the law gets the state,
its command lands ``land[k]`` plant steps later (newest wins, :class:`plant_emulator.sampled.
Hold`), the plant (1) is integrated by RK4 with the command held plus the disturbance of the
loop's pattern ``modes`` (N, 2, B: a mode per channel and block of the run's B equal blocks),
re-chosen at every landing; the torque limits are checked on the commands. The scenario's own
disturbance acts only when asked for (``own_seeds``), its sensor as in the simulator, one noise
seed for all loops. The law is called through its guard: a fault of any loop raises
``LawFaultError`` (:mod:`controller_service.laws.guard`), which ends the search.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from controller_service.laws.base import ReferenceSample, RobotState
from controller_service.laws.guard import LawFaultError, checked_update
from hil.errors import BadInputError
from hil.scenario import Scenario, build_loop
from plant_emulator.dynamics import NO_DISTURBANCE, Extremes, PlantState, rk4_array
from plant_emulator.landing import extra_delays, landing_offsets
from plant_emulator.sampled import Hold
from plant_emulator.sensors import measure

MODES = ("none", "aligned", "with_command", "outward")
LOST = -1  # a sample whose command never lands


@dataclass(frozen=True)
class Schedule:
    """When each sample's command lands, shared by the loops of a group. ``ts``: the sample
    period; ``land``: (G, K) plant steps from sample k to its landing for G landing draws over
    K samples (``LOST``: never lands); ``group``: (N,) the draw each loop uses; ``h``: the
    plant step (``ts`` / a whole number)."""

    ts: float
    h: float
    land: np.ndarray
    group: np.ndarray

    @property
    def samples(self) -> int:
        return int(self.land.shape[1])

    def max_age(self) -> float:
        """D of the schedule (s): the longest time a command stays in force after its sample
        (A2), counted from t = 0 before the first landing; landings after the run's end do
        not count."""
        m = round(self.ts / self.h)
        end = self.samples * m
        worst = 0
        for row in self.land:
            k = np.nonzero(row != LOST)[0]
            sample, land = k * m, k * m + row[k]
            order = np.lexsort((sample, land))
            land, sample = land[order], sample[order]
            inside = land < end
            land, sample = land[inside], sample[inside]
            before = np.maximum.accumulate(np.concatenate([[-1], sample]))[:-1]
            newer = sample > before  # newest wins: an older command landing later is dropped
            land, sample = land[newer], sample[newer]
            last = np.append(land[1:] != land[:-1], True)  # the newest of a shared landing step
            land, sample = land[last], sample[last]
            ages = np.append(land[:1], np.append(land[1:], end) - sample) if land.size else [end]
            worst = max(worst, int(np.max(ages)))
        return worst * self.h


def scenario_schedule(scenario: Scenario, n: int, seeds: np.ndarray | None = None) -> Schedule:
    """The scenario's own timing ([timing] ts, delay, jitter) as a schedule for ``n`` loops;
    ``seeds`` (N,) the jitter seed of each loop (default: the scenario's for all)."""
    t = scenario.timing
    if t.jitter_kind == "replay":
        raise BadInputError("the worst-case search takes [timing] delay and jitter, not replay")
    k = max(1, round(scenario.run.duration / t.ts))
    seeds = np.full(n, t.seed) if seeds is None else np.asarray(seeds, dtype=np.int64)
    rows: dict[int, int] = {}
    group = np.array([rows.setdefault(int(s), len(rows)) for s in seeds], dtype=np.intp)
    land = np.empty((len(rows), k), dtype=np.int64)
    for seed, row in rows.items():
        extra = extra_delays(t.jitter_kind, t.jitter, seed, k)
        land[row] = landing_offsets(extra, t.delay, scenario.plant_step)
    return Schedule(t.ts, scenario.plant_step, land, group)


def absolute_landings(land: np.ndarray, m: int) -> np.ndarray:
    """(G, K) landing steps on the plant grid; a ``LOST`` command lands with the earliest later
    landing of its row (or at the run's end), where the newer command overrides it at once
    (:meth:`plant_emulator.sampled.Hold.land` lands the older first): it never acts, and the
    hold's queue stays in landing order."""
    g, k = land.shape
    steps = np.arange(k, dtype=np.int64) * m + land
    lost = land == LOST
    out = np.where(lost, np.iinfo(np.int64).max, steps)
    # The earliest landing among the later samples of each row (a suffix minimum).
    later = np.minimum.accumulate(out[:, ::-1], axis=1)[:, ::-1]
    later = np.concatenate([later[:, 1:], np.full((g, 1), np.iinfo(np.int64).max)], axis=1)
    return np.where(lost, np.minimum(later, k * m), steps)


@dataclass
class LoopPeaks:
    """Per loop: the largest |v|, |omega| over plant steps, |tau1|, |tau2| over commands, and
    the largest position error over the second half of the run."""

    max_abs_v: np.ndarray
    max_abs_omega: np.ndarray
    max_abs_tau1: np.ndarray
    max_abs_tau2: np.ndarray
    max_late_error: np.ndarray


def _advance(
    state: PlantState,
    hold: Hold,
    h: float,
    span: tuple[int, int],
    coef: tuple[np.ndarray, ...],
    own: tuple[Any, Any],
    limits: Any,
    ext: Extremes,
) -> PlantState:
    """Integrate from plant step j to j_end, the disturbance re-chosen at every landing; ``own``
    = (the scenario's disturbance, its per-loop seeds) added on top (none when searching)."""
    j, j_end = span
    a1, a2, b1, b2 = coef
    dist, seeds = own
    for e in [*(hold.landings(j, j_end) if hold.pending else ()), j_end]:
        c1, c2 = hold.cmd1, hold.cmd2
        d1 = a1 * np.sign(c1) + b1 * np.sign(state.v)
        d2 = a2 * np.sign(c2) + b2 * np.sign(state.omega)
        state = rk4_array(
            state, c1 + d1, c2 + d2, j * h, h, e - j, dist, 0.0, seeds, limits, ext, j
        )
        if e < j_end:
            hold.land(e)
        j = e
    return state


def run_loops(
    scenario: Scenario,
    schedule: Schedule,
    modes: np.ndarray,
    initial: PlantState,
    memory: Any = None,
    loop: tuple[Any, Any, Any] | None = None,
    own_seeds: np.ndarray | None = None,
) -> LoopPeaks:
    """N loops of ``scenario``'s law and reference over ``schedule``, each disturbed by its
    pattern ``modes`` (N, 2, B) within the scenario's s1, s2, from ``initial`` (arrays (N,)).
    ``own_seeds``: (N,) disturbance seeds; then the scenario's own disturbance acts too (use
    with the mode ``none`` only, or the sum may exceed s1, s2)."""
    if scenario.plant.lag > 0.0:
        raise BadInputError("the worst-case search needs [plant] lag = 0 (docs: A4)")
    controller, reference, _context = loop or build_loop(scenario)
    n = len(schedule.group)
    ts, h = schedule.ts, schedule.h
    m = round(ts / h)
    k_all = schedule.samples
    together = schedule.land.shape[0] == 1
    steps = absolute_landings(schedule.land, m)
    land = steps[0].tolist() if together else steps
    own = (NO_DISTURBANCE, None) if own_seeds is None else (scenario.disturbance, own_seeds)
    # d = a sign(held torque) + b sign(velocity), a and b of shape (N, 2, B): aligned a = -s
    # (against the command in force), with_command a = s, outward b = s, none 0.
    scale = np.array([scenario.disturbance.s1, scenario.disturbance.s2], dtype=float)[None, :, None]
    a = scale * ((modes == 2).astype(float) - (modes == 1).astype(float))
    b = scale * (modes == 3).astype(float)
    hold = Hold(n, apart=not together)
    ext = Extremes.zeros(n)
    if memory is None:
        memory = controller.initial_memory(n, z1=scenario.initial.z1, z2=scenario.initial.z2)
    state = initial
    peaks = np.zeros((3, n))  # |tau1|, |tau2|, late position error
    ideal = scenario.sensor.is_ideal
    sensor_seeds = np.full(n, scenario.plant.noise_seed, dtype=np.int64)
    ones = np.ones(n)
    for k in range(k_all):
        t_k = k * ts
        ref = reference.sample(t_k)
        ref_arr = ReferenceSample(*(ones * float(value) for value in ref))
        rs = RobotState(state.x, state.y, state.theta, state.v, state.omega)
        meas = rs if ideal else measure(scenario.sensor, rs, k, sensor_seeds)
        # Any robot's fault ends the whole search: the law is broken (hil.analysis.margin says so).
        try:
            out, memory = checked_update(controller, t_k, ts, meas, ref_arr, memory)
        except LawFaultError as exc:
            if exc.fault.robot is not None:
                raise
            # The call on arrays failed as a whole: named with loop 0's input (the scenario's
            # own initial state, unmoved), one input that call had.
            raise LawFaultError(exc.fault.for_robot(0, t_k, meas, ref_arr)) from exc
        tau = [np.broadcast_to(np.asarray(t, dtype=float), (n,)) for t in (out.tau1, out.tau2)]
        np.maximum(peaks[:2], np.abs(tau), out=peaks[:2])
        j0 = k * m
        hold.send(k, land[k] if together else land[schedule.group, k], *tau)
        hold.land(j0)
        if 2 * k >= k_all:
            np.maximum(peaks[2], np.hypot(state.x - ref.xd, state.y - ref.yd), out=peaks[2])
        blk = k * modes.shape[2] // k_all
        coef = (a[:, 0, blk], a[:, 1, blk], b[:, 0, blk], b[:, 1, blk])
        state = _advance(state, hold, h, (j0, j0 + m), coef, own, scenario.limits, ext)
    v, omega = (np.asarray(x, dtype=float) for x in (ext.max_abs_v, ext.max_abs_omega))
    return LoopPeaks(v, omega, *peaks)


def initial_states(scenario: Scenario, n: int, spread: float, seed: int) -> PlantState:
    """``n`` initial states: the scenario's, the first exactly, the others moved by up to
    ``spread`` (m, rad, m/s, rad/s, uniformly) so that seeds differ."""
    ini = scenario.initial
    rng = np.random.default_rng(seed)
    base = np.array([ini.x, ini.y, ini.theta, ini.v, ini.omega], dtype=float)
    moved = base[:, None] + rng.uniform(-spread, spread, (5, n)) * (np.arange(n) > 0)
    return PlantState(*moved, np.zeros(n), np.zeros(n))
