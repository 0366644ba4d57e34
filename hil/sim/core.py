"""The offline simulator: one closed loop on floats, or N loops at once on numpy arrays.

At each sample k (t_k = k Ts) the law gets the measured state (noise and quantization of
[plant]), the reference sample and the law time t_k; its command lands at
t_k + delay + extra_k rounded to the plant step h (see :mod:`hil.sim.timing`); when delays
reorder commands the newest by sequence number wins and older ones are dropped (counted).
Between landings the command is held (zero-order hold) and model (1) is integrated by RK4 at
step h = Ts / ceil(Ts / [plant] step). Before the first command lands the torque is zero.

Both paths run the same law object and the same RK4 arithmetic
(:mod:`plant_emulator.dynamics`): :func:`simulate` on Python floats, :func:`simulate_batch` on
arrays of N robots that share Ts, h, the law and the reference but may differ in initial state,
delay, jitter seed, disturbance seed and sensor seed (:class:`RobotVariation`).
"""

from __future__ import annotations

import heapq
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from controller_service.from_settings import initial_memory
from controller_service.laws.base import ReferenceSample, RobotState
from controller_service.references import sample_array
from hil.scenario import SCHEMA_VERSION, Scenario, build_loop, resolved_dict
from hil.sim.timing import extra_delays, jitter_samples_from, landing_offsets
from hil.trace import COMMAND_COLUMNS, TRACE_COLUMNS
from plant_emulator.dynamics import (
    Extremes,
    PlantState,
    advance_array_tracked,
    advance_float_tracked,
    track_initial,
)
from plant_emulator.sensors import measure, wrap_angle

BASE_COLUMNS = (
    *TRACE_COLUMNS,
    *COMMAND_COLUMNS,
    "position_error",
    "heading_error",
)
Progress = Callable[[int, int], None]


@dataclass(frozen=True)
class RobotVariation:
    """How one robot of a batch differs from the scenario (None = the scenario's value)."""

    x: float | None = None
    y: float | None = None
    theta: float | None = None
    v: float | None = None
    omega: float | None = None
    delay: float | None = None
    jitter: float | None = None
    jitter_seed: int | None = None
    disturbance_seed: int | None = None
    sensor_seed: int | None = None


@dataclass
class SimResult:
    """One simulated loop: the trace (one row per control sample) and its summary."""

    scenario: Scenario
    resolved: dict[str, Any]
    columns: list[str]
    trace: np.ndarray
    summary: dict[str, Any]
    interrupted: bool = False

    def column(self, name: str) -> np.ndarray:
        return self.trace[:, self.columns.index(name)]


@dataclass
class BatchResult:
    """N simulated loops: a summary per robot and the traces of the recorded robots."""

    scenario: Scenario
    resolved: dict[str, Any]
    variations: list[RobotVariation]
    summaries: list[dict[str, Any]]
    columns: list[str]
    traces: dict[int, np.ndarray] = field(default_factory=dict)
    interrupted: bool = False

    def result(self, i: int) -> SimResult:
        """Robot ``i`` as a :class:`SimResult` (its trace must have been recorded)."""
        return SimResult(
            self.scenario,
            self.resolved,
            self.columns,
            self.traces[i],
            self.summaries[i],
            self.interrupted,
        )


def _initial_memory(controller: Any, n: int | None, scenario: Scenario) -> Any:
    # The controller service's own rule (lockstep must equal the simulation bit for bit).
    return initial_memory(controller, n, scenario.initial.z1, scenario.initial.z2)


def _replay(scenario: Scenario) -> np.ndarray | None:
    t = scenario.timing
    if t.jitter_kind != "replay":
        return None
    path = scenario.base_dir / t.replay
    return jitter_samples_from(path)


def _summary(
    scenario: Scenario,
    ext_vals: dict[str, float],
    violations: dict[str, int],
    last: tuple[float, float, float, float, float, float],
    rms: float,
    samples: int,
    steps: int,
    dropped: int,
    interrupted: bool,
    law: str,
) -> dict[str, Any]:
    x, y, th, xd, yd, thd = last
    limits = scenario.limits
    return {
        "schema_version": SCHEMA_VERSION,
        "final_position_error": math.hypot(x - xd, y - yd),
        "final_heading_error": wrap_angle(th - thd),
        "rms_position_error": rms,
        **ext_vals,
        "violations": violations,
        "limits_held": not any(violations.values()),
        "limits": {
            "phi1": limits.phi1,
            "phi2": limits.phi2,
            "varpi1": limits.varpi1,
            "varpi2": limits.varpi2,
        },
        "law": law,
        "ts": scenario.timing.ts,
        "plant_step": scenario.plant_step,
        "duration": samples * scenario.timing.ts,
        "samples": samples,
        "plant_steps": steps,
        "commands_dropped": dropped,
        "interrupted": interrupted,
    }


def simulate(
    scenario: Scenario,
    variation: RobotVariation | None = None,
    progress: Progress | None = None,
    loop: tuple[Any, Any, Any] | None = None,
    t0: float = 0.0,
    memory: Any = None,
) -> SimResult:
    """One closed loop on plain floats (the single-run path).

    ``progress(k, K)`` is called now and then; Ctrl-C stops the loop and returns what was
    computed with ``interrupted = True``. ``loop`` = (controller, reference, context) reuses
    built objects. ``t0``: the time of the first sample (default 0): the law's clock, the
    reference and the disturbance run from there, as in a run whose first sample came at t0
    (the initial state is then the state at t0, the law's memory its initial memory unless
    ``memory`` gives the law's memory at t0).
    """
    var = variation or RobotVariation()
    controller, reference, context = loop or build_loop(scenario)
    ts = scenario.timing.ts
    m = scenario.substeps
    h = scenario.plant_step
    n_samples = max(1, round(scenario.run.duration / ts))
    ini = scenario.initial
    state = PlantState(
        float(ini.x if var.x is None else var.x),
        float(ini.y if var.y is None else var.y),
        float(ini.theta if var.theta is None else var.theta),
        float(ini.v if var.v is None else var.v),
        float(ini.omega if var.omega is None else var.omega),
        0.0,
        0.0,
    )
    timing = scenario.timing
    delay = timing.delay if var.delay is None else var.delay
    jitter = timing.jitter if var.jitter is None else var.jitter
    jseed = timing.seed if var.jitter_seed is None else var.jitter_seed
    dseed = scenario.disturbance.seed if var.disturbance_seed is None else var.disturbance_seed
    sseed = scenario.plant.noise_seed if var.sensor_seed is None else var.sensor_seed
    offsets = landing_offsets(
        extra_delays(timing.jitter_kind, jitter, jseed, n_samples, _replay(scenario)), delay, h
    ).tolist()
    sensor = scenario.sensor
    ideal_sensor = sensor.is_ideal
    dist = scenario.disturbance
    lag = scenario.plant.lag
    limits = scenario.limits
    ext = Extremes.zeros()
    track_initial(ext, state, limits)
    if memory is None:
        memory = _initial_memory(controller, None, scenario)
    pending: list[tuple[int, int, float, float]] = []
    applied_seq = -1
    cmd1 = cmd2 = 0.0
    dropped = 0
    rows: list[tuple[float, ...]] = []
    tel_keys: list[str] | None = None
    rms_from = math.floor(0.9 * n_samples)
    sq_sum = 0.0
    sq_n = 0
    interrupted = False
    every = max(1, n_samples // 200)
    last = (state.x, state.y, state.theta, 0.0, 0.0, 0.0)
    try:
        for k in range(n_samples):
            t_k = t0 + k * ts
            rs = RobotState(state.x, state.y, state.theta, state.v, state.omega)
            meas = rs if ideal_sensor else measure(sensor, rs, k, sseed)
            ref = reference.sample(t_k)
            out, memory = controller.update(t_k, ts, meas, ref, memory)
            if tel_keys is None:
                tel_keys = list(out.telemetry)
            j0 = k * m
            heapq.heappush(pending, (j0 + offsets[k], k, float(out.tau1), float(out.tau2)))
            j = j0
            j_end_period = j0 + m
            first = True
            while True:
                while pending and pending[0][0] <= j:
                    _, seq, c1, c2 = heapq.heappop(pending)
                    if seq > applied_seq:
                        applied_seq, cmd1, cmd2 = seq, c1, c2
                    else:
                        dropped += 1
                if first:
                    first = False
                    a1 = cmd1 if lag <= 0.0 else state.tau1
                    a2 = cmd2 if lag <= 0.0 else state.tau2
                    e_pos = math.hypot(state.x - ref.xd, state.y - ref.yd)
                    rows.append(
                        (
                            t_k,
                            state.x,
                            state.y,
                            state.theta,
                            state.v,
                            state.omega,
                            ref.xd,
                            ref.yd,
                            ref.thetad,
                            a1,
                            a2,
                            float(out.tau1),
                            float(out.tau2),
                            e_pos,
                            wrap_angle(state.theta - ref.thetad),
                            *(float(out.telemetry[key]) for key in tel_keys),
                        )
                    )
                    last = (state.x, state.y, state.theta, ref.xd, ref.yd, ref.thetad)
                    if k >= rms_from:
                        sq_sum += e_pos * e_pos
                        sq_n += 1
                nxt = pending[0][0] if pending else j_end_period
                j_next = min(nxt, j_end_period)
                if j_next > j:
                    state = advance_float_tracked(
                        state,
                        cmd1,
                        cmd2,
                        t0 + j * h,
                        h,
                        j_next - j,
                        dist,
                        lag,
                        dseed,
                        limits,
                        ext,
                        j if t0 == 0.0 else None,  # off the step grid: times from t0
                    )
                    j = j_next
                if j >= j_end_period:
                    break
            if progress is not None and k % every == 0:
                progress(k, n_samples)
    except KeyboardInterrupt:
        interrupted = True
    if progress is not None and not interrupted:
        progress(len(rows), n_samples)
    columns = [*BASE_COLUMNS, *(tel_keys or [])]
    trace = np.array(rows, dtype=float).reshape(len(rows), len(columns))
    ext_vals = {
        "max_abs_v": ext.max_abs_v,
        "max_abs_omega": ext.max_abs_omega,
        "max_abs_tau1": ext.max_abs_tau1,
        "max_abs_tau2": ext.max_abs_tau2,
    }
    violations = {
        "v": ext.violations_v,
        "omega": ext.violations_omega,
        "tau1": ext.violations_tau1,
        "tau2": ext.violations_tau2,
    }
    rms = math.sqrt(sq_sum / sq_n) if sq_n else float("nan")
    summary = _summary(
        scenario,
        ext_vals,
        violations,
        last,
        rms,
        len(rows),
        ext.steps,
        dropped,
        interrupted,
        getattr(controller, "name", type(controller).__name__),
    )
    summary["seeds"] = {"timing": jseed, "disturbance": dseed, "sensor": sseed}
    resolved = resolved_dict(scenario, controller, context)
    return SimResult(scenario, resolved, columns, trace, summary, interrupted)


def _per_robot(values: Sequence[Any], default: Any, dtype: Any) -> np.ndarray:
    return np.array([default if v is None else v for v in values], dtype=dtype)


def _batch_summaries(
    scenario: Scenario,
    ext: Extremes,
    last: tuple[Any, ...],
    rms: np.ndarray,
    samples: int,
    dropped: np.ndarray,
    interrupted: bool,
    law: str,
    seeds: tuple[np.ndarray, np.ndarray, np.ndarray],
) -> list[dict[str, Any]]:
    """:func:`_summary` for every robot of a batch, with the same keys in the same order.

    Why: for short runs of many robots, building 10,000 summaries one ``_summary`` call at a
    time (numpy scalar reads, scenario properties, per-robot ``wrap_angle``) cost more than a
    hundred control periods; here the per-robot columns are computed on arrays and read back as
    Python lists once, and what all robots share is computed once.
    """
    n = len(rms)
    x, y, th, xd, yd, thd = (np.broadcast_to(np.asarray(q, dtype=float), (n,)) for q in last)
    pos_err = [math.hypot(a, b) for a, b in zip((x - xd).tolist(), (y - yd).tolist(), strict=True)]
    head_err = np.asarray(wrap_angle(np.asarray(th - thd)), dtype=float).tolist()
    cols = [
        np.asarray(q).tolist()
        for q in (
            ext.max_abs_v,
            ext.max_abs_omega,
            ext.max_abs_tau1,
            ext.max_abs_tau2,
            ext.violations_v,
            ext.violations_omega,
            ext.violations_tau1,
            ext.violations_tau2,
        )
    ]
    limits = scenario.limits
    limit_table = {
        "phi1": limits.phi1,
        "phi2": limits.phi2,
        "varpi1": limits.varpi1,
        "varpi2": limits.varpi2,
    }
    ts = scenario.timing.ts
    plant_step = scenario.plant_step
    duration = samples * ts
    steps = ext.steps
    rows = zip(
        pos_err,
        head_err,
        rms.tolist(),
        *cols,
        dropped.tolist(),
        *(q.tolist() for q in seeds),
        strict=True,
    )
    out = []
    for pe, he, rm, mv, mw, mt1, mt2, nv, nw, nt1, nt2, dr, js, ds, ss in rows:
        out.append(
            {
                "schema_version": SCHEMA_VERSION,
                "final_position_error": pe,
                "final_heading_error": he,
                "rms_position_error": rm,
                "max_abs_v": mv,
                "max_abs_omega": mw,
                "max_abs_tau1": mt1,
                "max_abs_tau2": mt2,
                "violations": {"v": nv, "omega": nw, "tau1": nt1, "tau2": nt2},
                "limits_held": not (nv or nw or nt1 or nt2),
                "limits": dict(limit_table),
                "law": law,
                "ts": ts,
                "plant_step": plant_step,
                "duration": duration,
                "samples": samples,
                "plant_steps": steps,
                "commands_dropped": dr,
                "interrupted": interrupted,
                "seeds": {"timing": js, "disturbance": ds, "sensor": ss},
            }
        )
    return out


def simulate_batch(
    scenario: Scenario,
    variations: Sequence[RobotVariation] | int,
    record: Sequence[int] = (),
    progress: Progress | None = None,
    loop: tuple[Any, Any, Any] | None = None,
    t0: float | Sequence[float] | np.ndarray = 0.0,
    memory: Any = None,
    on_sample: Callable[[int, PlantState], None] | None = None,
) -> BatchResult:
    """N closed loops at once on numpy arrays (the batch path), one per variation.

    ``variations`` may be an int N (N identical robots). ``record`` lists the robots whose full
    trace is kept (every robot gets a summary).

    ``t0``: the time of each robot's first sample (one value or one per robot; default 0), as
    in :func:`simulate`: each robot's law clock, reference and disturbance run from its own
    t0 (the reference is then sampled on arrays, :func:`controller_service.references.
    sample_array`). ``memory``: the law's memory at the first sample, arrays of shape (N,) per
    field (default: its initial memory). ``on_sample(k, state)`` is called with the robots'
    state (arrays) at each sample time t0 + k Ts, k = 0 .. K (K: after the last period).
    With the defaults the results are those of the batch path without these arguments.
    """
    if isinstance(variations, int):
        variations = [RobotVariation()] * variations
    variations = list(variations)
    n = len(variations)
    if n == 0:
        raise ValueError("simulate_batch needs at least one robot")
    controller, reference, context = loop or build_loop(scenario)
    ts = scenario.timing.ts
    m = scenario.substeps
    h = scenario.plant_step
    n_samples = max(1, round(scenario.run.duration / ts))
    ini = scenario.initial
    timing = scenario.timing
    starts = None  # per-robot first-sample times, when any is not 0
    if np.ndim(t0) or float(t0) != 0.0:
        starts = np.array(np.broadcast_to(np.asarray(t0, dtype=float), (n,)))
    # N copies of one variation (``variations`` given as an int) need no per-robot reads.
    first = variations[0]
    shared = all(v is first for v in variations)

    def per_robot(name: str, default: Any, dtype: Any) -> np.ndarray:
        if shared:
            value = getattr(first, name)
            return np.full(n, default if value is None else value, dtype=dtype)
        return _per_robot([getattr(v, name) for v in variations], default, dtype)

    state = PlantState(
        per_robot("x", ini.x, float),
        per_robot("y", ini.y, float),
        per_robot("theta", ini.theta, float),
        per_robot("v", ini.v, float),
        per_robot("omega", ini.omega, float),
        np.zeros(n),
        np.zeros(n),
    )
    delays = per_robot("delay", timing.delay, float)
    jitters = per_robot("jitter", timing.jitter, float)
    jseeds = per_robot("jitter_seed", timing.seed, np.int64)
    dseeds = per_robot("disturbance_seed", scenario.disturbance.seed, np.int64)
    sseeds = per_robot("sensor_seed", scenario.plant.noise_seed, np.int64)
    replay = _replay(scenario)
    # Offsets per distinct (delay, jitter, seed), drawn exactly as the single path draws them
    # (same seed, same n); robot i uses row group[i] of ``offsets``.
    keys: dict[tuple[float, float, int], int] = {}
    group = np.array(
        [
            keys.setdefault(key, len(keys))
            for key in zip(delays.tolist(), jitters.tolist(), jseeds.tolist(), strict=True)
        ],
        dtype=np.intp,
    )
    offsets = np.empty((len(keys), n_samples), dtype=np.int64)
    for (delay, jitter, seed), row in keys.items():
        extra = extra_delays(timing.jitter_kind, jitter, seed, n_samples, replay)
        offsets[row] = landing_offsets(extra, delay, h)
    all_zero = not offsets.any()
    depth = int(offsets.max()) // m + 2  # periods a command can stay pending
    sensor = scenario.sensor
    ideal_sensor = sensor.is_ideal
    dist = scenario.disturbance
    dseed_arg = dseeds if dist.kind == "random" else None
    lag = scenario.plant.lag
    limits = scenario.limits
    ext = Extremes.zeros(n)
    track_initial(ext, state, limits)
    if memory is None:
        memory = _initial_memory(controller, n, scenario)
    cmd1 = np.zeros(n)
    cmd2 = np.zeros(n)
    applied_seq = np.full(n, -1, dtype=np.int64)
    dropped = np.zeros(n, dtype=np.int64)
    ring_c1 = np.zeros((depth, n))
    ring_c2 = np.zeros((depth, n))
    ring_land = np.full((depth, n), -1, dtype=np.int64)
    record = [int(i) for i in record]
    rec_rows: dict[int, list[np.ndarray]] = {i: [] for i in record}
    tel_keys: list[str] | None = None
    rms_from = math.floor(0.9 * n_samples)
    sq_sum = np.zeros(n)
    sq_n = 0
    last = None
    interrupted = False
    done = 0
    every = max(1, n_samples // 200)
    ones = np.ones(n)
    try:
        for k in range(n_samples):
            if on_sample is not None:
                on_sample(k, state)
            rs = RobotState(state.x, state.y, state.theta, state.v, state.omega)
            meas = rs if ideal_sensor else measure(sensor, rs, k, sseeds)
            if starts is None:
                t_k = k * ts
                ref = reference.sample(t_k)
                ref_arr = ReferenceSample(*(ones * float(value) for value in ref))
            else:
                t_k = starts + k * ts
                ref = ref_arr = sample_array(reference, t_k)
            out, memory = controller.update(t_k, ts, meas, ref_arr, memory)
            tau1 = np.broadcast_to(np.asarray(out.tau1, dtype=float), (n,))
            tau2 = np.broadcast_to(np.asarray(out.tau2, dtype=float), (n,))
            if tel_keys is None:
                tel_keys = list(out.telemetry)
            j0 = k * m
            if all_zero:
                cmd1, cmd2 = tau1, tau2
                applied_seq[:] = k
                events: list[int] = []
            else:
                slot = k % depth
                ring_c1[slot] = tau1
                ring_c2[slot] = tau2
                ring_land[slot] = j0 + offsets[group, k]
                in_period = (ring_land >= j0) & (ring_land < j0 + m)
                events = sorted(set(ring_land[in_period].tolist())) if in_period.any() else []
                # Slots oldest first, so at a shared landing step the newest command wins.
                order = [(k - back) % depth for back in range(depth - 1, -1, -1)]
                seqs = [k - back for back in range(depth - 1, -1, -1)]
            j = j0
            j_end_period = j0 + m
            ei = 0
            first = True
            while True:
                while ei < len(events) and events[ei] <= j:
                    e = events[ei]
                    ei += 1
                    for slot_i, seq in zip(order, seqs, strict=True):
                        if seq < 0:
                            continue
                        lands = ring_land[slot_i] == e
                        if not lands.any():
                            continue
                        newer = lands & (seq > applied_seq)
                        dropped += lands & ~newer
                        cmd1 = np.where(newer, ring_c1[slot_i], cmd1)
                        cmd2 = np.where(newer, ring_c2[slot_i], cmd2)
                        applied_seq = np.where(newer, seq, applied_seq)
                if first:
                    first = False
                    if k >= rms_from or record:
                        e_pos = np.hypot(state.x - ref.xd, state.y - ref.yd)
                    if k >= rms_from:
                        sq_sum += e_pos * e_pos
                        sq_n += 1
                    last = (state.x, state.y, state.theta, ref.xd, ref.yd, ref.thetad)
                    if record:
                        a1 = cmd1 if lag <= 0.0 else state.tau1
                        a2 = cmd2 if lag <= 0.0 else state.tau2
                        head = wrap_angle(state.theta - ref.thetad)
                        tel = [np.broadcast_to(out.telemetry[key], (n,)) for key in tel_keys]
                        for i in record:
                            rec_rows[i].append(
                                np.array(
                                    [
                                        t_k if starts is None else t_k[i],
                                        state.x[i],
                                        state.y[i],
                                        state.theta[i],
                                        state.v[i],
                                        state.omega[i],
                                        ref.xd if starts is None else ref.xd[i],
                                        ref.yd if starts is None else ref.yd[i],
                                        ref.thetad if starts is None else ref.thetad[i],
                                        a1[i],
                                        a2[i],
                                        tau1[i],
                                        tau2[i],
                                        e_pos[i],
                                        head[i],
                                        *(float(col[i]) for col in tel),
                                    ]
                                )
                            )
                nxt = events[ei] if ei < len(events) else j_end_period
                j_next = min(nxt, j_end_period)
                if j_next > j:
                    state = advance_array_tracked(
                        state,
                        cmd1,
                        cmd2,
                        j * h if starts is None else starts + j * h,
                        h,
                        j_next - j,
                        dist,
                        lag,
                        dseed_arg,
                        limits,
                        ext,
                        j if starts is None else None,  # off the step grid: times from t0
                    )
                    j = j_next
                if j >= j_end_period:
                    break
            done = k + 1
            if progress is not None and k % every == 0:
                progress(k, n_samples)
    except KeyboardInterrupt:
        interrupted = True
    if on_sample is not None and not interrupted:
        on_sample(n_samples, state)
    if progress is not None and not interrupted:
        progress(done, n_samples)
    columns = [*BASE_COLUMNS, *(tel_keys or [])]
    law = getattr(controller, "name", type(controller).__name__)
    if last is None:
        last = (state.x, state.y, state.theta, 0.0, 0.0, 0.0)
    rms = np.sqrt(sq_sum / sq_n) if sq_n else np.full(n, np.nan)
    summaries = _batch_summaries(
        scenario, ext, last, rms, done, dropped, interrupted, law, (jseeds, dseeds, sseeds)
    )
    traces = {
        i: np.array(rows, dtype=float).reshape(len(rows), len(columns))
        for i, rows in rec_rows.items()
    }
    resolved = resolved_dict(scenario, controller, context)
    return BatchResult(scenario, resolved, variations, summaries, columns, traces, interrupted)


def wall_clock() -> float:
    return time.perf_counter()
