"""The offline simulator: one closed loop on floats, or N loops at once on numpy arrays.

At each sample k (t_k = k Ts) the law gets the measured state (noise and quantization of
[plant]), the reference sample and the law time t_k; its command lands at
t_k + delay + extra_k rounded to the plant step h (see :mod:`hil.folder.replay`); when delays
reorder commands the newest by sequence number wins and older ones are dropped (counted).
Between landings the command is held (zero-order hold) and model (1) is integrated by RK4 at
step h = Ts / ceil(Ts / [plant] step). Before the first command lands the torque is zero.

Both paths run the same law object and the same sampled-data step (hold, landing, RK4:
:mod:`plant_emulator.sampled`) as the plant emulator's lockstep: :func:`simulate` on Python
floats, :func:`simulate_batch` on arrays of N robots that share Ts, h, the law and the
reference but may differ in initial state, delay, jitter seed, disturbance seed and sensor
seed (:class:`RobotVariation`).

The law is called through its guard (:mod:`controller_service.laws.guard`): when it raises,
returns the wrong type or a non-finite torque, :func:`simulate` stops at that sample (the
trace ends with the sample before it; the plant is not advanced past it) and the summary
holds the fault (``law_fault``); on the batch path that robot alone is faulted
(:func:`hil.law.batch.batch_update`: zero torque from then on, ``law_fault`` in its summary)
and the batch stops early when every robot has faulted. Either way ``limits_held`` is false.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from controller_service.from_settings import initial_memory
from controller_service.laws.base import ReferenceSample, RobotState
from controller_service.laws.guard import LawFault, LawFaultError, checked_update
from controller_service.references import sample_array
from hil.folder.records import Summary
from hil.folder.replay import jitter_samples_from
from hil.folder.scenario_view import as_resolved, view_of
from hil.law.batch import batch_update, for_batch
from hil.provenance import Toml
from hil.scenario import SCHEMA_VERSION, Scenario, build_loop, resolved_dict
from hil.sim import compiled
from hil.sim.certificate import scenario_certificate
from hil.trace import COMMAND_COLUMNS, TRACE_COLUMNS
from plant_emulator.dynamics import Extremes, PlantState, track_initial
from plant_emulator.landing import extra_delays, landing_offsets
from plant_emulator.sampled import Hold, Plant, advance_period
from plant_emulator.sensors import measure
from protocol.angles import wrap_angle

BASE_COLUMNS = (*TRACE_COLUMNS, *COMMAND_COLUMNS, "position_error", "heading_error")
Progress = Callable[[int, int], None]
_POSE = ("x", "y", "theta", "v", "omega")  # the RobotVariation fields of the initial state


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
    resolved: Toml  # scenario.resolved.toml's tables
    columns: list[str]
    trace: np.ndarray
    summary: Summary
    interrupted: bool = False

    def column(self, name: str) -> np.ndarray:
        return self.trace[:, self.columns.index(name)]


@dataclass
class BatchResult:
    """N simulated loops: a summary per robot and the traces of the recorded robots."""

    scenario: Scenario
    resolved: Toml  # scenario.resolved.toml's tables
    variations: list[RobotVariation]
    summaries: list[Summary]
    columns: list[str]
    traces: dict[int, np.ndarray] = field(default_factory=dict)
    interrupted: bool = False


def _initial_memory(controller: Any, n: int | None, scenario: Scenario) -> Any:
    # The controller service's own rule (lockstep must equal the simulation bit for bit).
    return initial_memory(controller, n, scenario.initial.z1, scenario.initial.z2)


def _or(value: Any, default: Any) -> Any:
    """A RobotVariation's ``value``, or the scenario's ``default`` where it is None."""
    return default if value is None else value


def _replay(scenario: Scenario) -> np.ndarray | None:
    t = scenario.timing
    return jitter_samples_from(scenario.base_dir / t.replay) if t.jitter_kind == "replay" else None


def _summaries(
    scenario: Scenario, run: _Loops, samples: int, per_robot: tuple[Any, ...]
) -> list[Summary]:
    """Each robot's summary.json from ``run.ext`` (peaks and violation counts of (2)) and
    ``per_robot`` (final position and heading errors, RMS position error, commands dropped,
    timing, disturbance and sensor seeds): floats for one robot, arrays for a batch. Built by
    columns, each read back as a Python list once, and what all robots share computed once:
    10,000 summaries built robot by robot cost more than a hundred control periods."""
    ext = run.ext
    peaks = (ext.max_abs_v, ext.max_abs_omega, ext.max_abs_tau1, ext.max_abs_tau2)
    peaks += (ext.violations_v, ext.violations_omega, ext.violations_tau1, ext.violations_tau2)
    peaks += (ext.nonfinite_steps, ext.nonfinite_first_t)
    columns = np.broadcast_arrays(*per_robot[:3], *peaks, *per_robot[3:])
    limit_table = asdict(scenario.limits)
    law = getattr(run.controller, "name", type(run.controller).__name__)
    ts, plant_step = scenario.timing.ts, scenario.plant_step
    robots = zip(*(np.atleast_1d(q).tolist() for q in columns), strict=True)
    faults = {i: f.to_dict() for i, f in run.faults.items()}
    return [
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
            "nonfinite_steps": int(nf),
            "nonfinite_first_t_s": None if not nf or math.isnan(nft) else nft,
            **({"law_fault": faults[i]} if i in faults else {}),
            "limits_held": not (nv or nw or nt1 or nt2 or nf or i in faults),
            "limits": dict(limit_table),
            "law": law,
            "ts": ts,
            "plant_step": plant_step,
            "duration": samples * ts,
            "samples": samples,
            "plant_steps": ext.steps,
            "commands_dropped": dr,
            "interrupted": run.interrupted,
            "seeds": {"timing": js, "disturbance": ds, "sensor": ss},
        }
        for i, (pe, he, rm, mv, mw, mt1, mt2, nv, nw, nt1, nt2, nf, nft, dr, js, ds, ss) in (
            enumerate(robots)
        )
    ]


@dataclass
class _Loops:
    """One loop on floats or N on arrays: the set-up and, once run, what the summaries need."""

    controller: Any
    reference: Any
    context: Any
    plant: Plant
    state: PlantState
    land: Any  # landing offsets: a list (one draw for all robots) or (groups, samples) rows
    hold: Hold
    seeds: tuple[Any, Any, Any]  # timing, disturbance, sensor: ints, or arrays for a batch
    memory: Any
    n_samples: int
    ext: Extremes
    rows: list[tuple[float, ...]] = field(default_factory=list)  # the single path's trace
    tel_keys: list[str] | None = None
    last: tuple[Any, ...] | None = None
    rms: Any = None
    interrupted: bool = False
    group: np.ndarray | None = None  # robot i lands by row group[i] of ``land``
    starts: np.ndarray | None = None  # per-robot first-sample times, when any is not 0
    record: list[int] = field(default_factory=list)
    rec_rows: dict[int, list[np.ndarray]] = field(default_factory=dict)
    done: int = 0
    faults: dict[int, LawFault] = field(default_factory=dict)  # robot -> its law's fault


def _plant(scenario: Scenario, seed: Any) -> Plant:
    p = scenario.plant
    return Plant(scenario.plant_step, scenario.disturbance, p.lag, seed, scenario.limits, p.drag)


def _single_loop(run: _Loops, scenario: Scenario, t0: float, progress: Progress | None) -> None:
    """The sampled-data loop on floats: sample, law, send, land at t_k, record, advance."""
    controller, reference, hold = run.controller, run.reference, run.hold
    plant, ext = run.plant, run.ext
    state, memory, offsets, rows = run.state, run.memory, run.land, run.rows
    ts, m, n_samples = scenario.timing.ts, scenario.substeps, run.n_samples
    sensor, sseed = scenario.sensor, run.seeds[2]
    ideal_sensor = sensor.is_ideal
    lag = plant.lag
    grid_t0 = None if t0 == 0.0 else t0  # off the step grid: times from t0
    rms_from = math.floor(0.9 * n_samples)
    sq_sum = 0.0
    every = max(1, n_samples // 200)
    tel_keys, last = run.tel_keys, run.last
    try:
        for k in range(n_samples):
            t_k = t0 + k * ts
            rs = RobotState(state.x, state.y, state.theta, state.v, state.omega)
            meas = rs if ideal_sensor else measure(sensor, rs, k, sseed)
            ref = reference.sample(t_k)
            try:
                out, memory = checked_update(controller, t_k, ts, meas, ref, memory)
            except LawFaultError as exc:  # the law failed: the loop ends before this sample
                run.faults[0] = exc.fault
                break
            if tel_keys is None:
                tel_keys = run.tel_keys = list(out.telemetry)
            tau1, tau2 = float(out.tau1), float(out.tau2)
            j0 = k * m
            hold.send(k, j0 + offsets[k], tau1, tau2)
            hold.land(j0)
            e_pos = math.hypot(state.x - ref.xd, state.y - ref.yd)
            applied = (hold.cmd1, hold.cmd2) if lag <= 0.0 else (state.tau1, state.tau2)
            row = (t_k, *state[:5], ref.xd, ref.yd, ref.thetad, *applied, tau1, tau2, e_pos)
            head = wrap_angle(state.theta - ref.thetad)
            rows.append((*row, head, *map(float, map(out.telemetry.__getitem__, tel_keys))))
            last = (state.x, state.y, state.theta, ref.xd, ref.yd, ref.thetad)
            if k >= rms_from:
                sq_sum += e_pos * e_pos
            state = advance_period(state, hold, plant, j0, j0 + m, ext, grid_t0)
            if progress is not None and k % every == 0:
                progress(k, n_samples)
    except KeyboardInterrupt:
        run.interrupted = True
    sq_n = len(rows) - rms_from
    run.rms = math.sqrt(sq_sum / sq_n) if sq_n > 0 else float("nan")
    run.state, run.memory, run.last = state, memory, last


def simulate(
    scenario: Scenario,
    variation: RobotVariation | None = None,
    progress: Progress | None = None,
    loop: tuple[Any, Any, Any] | None = None,
    t0: float = 0.0,
    memory: Any = None,
    replay: np.ndarray | None = None,
) -> SimResult:
    """One closed loop on plain floats (the single-run path). ``progress(k, K)`` is called now
    and then; Ctrl-C stops the loop and returns what was computed with ``interrupted = True``.
    ``loop`` = (controller, reference, context) reuses built objects. ``t0``: the time of the
    first sample (default 0): the law's clock, the reference and the disturbance run from there,
    as in a run whose first sample came at t0 (the initial state is then the state at t0, the
    law's memory its initial memory unless ``memory`` gives the law's memory at t0).
    ``replay``: ``[timing] replay``'s latencies, read by the caller (a real run's are measured
    by the analysis, :func:`hil.analysis.replay.scenario_latencies`); None: read here from the
    scenario's latency file.
    """
    var = variation or RobotVariation()
    controller, reference, context = loop or build_loop(scenario)
    n_samples = max(1, round(scenario.run.duration / scenario.timing.ts))
    ini, timing = scenario.initial, scenario.timing
    state = PlantState(*(float(_or(getattr(var, q), getattr(ini, q))) for q in _POSE))
    delay, jitter = _or(var.delay, timing.delay), _or(var.jitter, timing.jitter)
    jseed = _or(var.jitter_seed, timing.seed)
    dseed = _or(var.disturbance_seed, scenario.disturbance.seed)
    sseed = _or(var.sensor_seed, scenario.plant.noise_seed)
    replay = replay if replay is not None else _replay(scenario)
    extra = extra_delays(timing.jitter_kind, jitter, jseed, n_samples, replay)
    run = _Loops(
        controller,
        reference,
        context,
        _plant(scenario, dseed),
        state,
        landing_offsets(extra, delay, scenario.plant_step).tolist(),
        Hold(),
        (jseed, dseed, sseed),
        _initial_memory(controller, None, scenario) if memory is None else memory,
        n_samples,
        Extremes.zeros(),
        last=(state.x, state.y, state.theta, 0.0, 0.0, 0.0),
    )
    track_initial(run.ext, state, scenario.limits)
    _single_loop(run, scenario, t0, progress)
    if progress is not None and not run.interrupted:
        progress(len(run.rows), run.n_samples)
    rows, columns = run.rows, [*BASE_COLUMNS, *(run.tel_keys or [])]
    trace = np.array(rows, dtype=float).reshape(len(rows), len(columns))
    x, y, th, xd, yd, thd = run.last
    errors = (math.hypot(x - xd, y - yd), wrap_angle(th - thd), run.rms)
    per_robot = (*errors, run.hold.dropped, *run.seeds)
    summary = _summaries(scenario, run, len(rows), per_robot)[0]
    resolved = resolved_dict(scenario, controller, context)
    # The bound at the scenario's timing, once, here: the report reads it, as it reads a run's.
    summary["certificate"] = scenario_certificate(view_of(as_resolved(scenario, resolved)))
    return SimResult(scenario, resolved, columns, trace, summary, run.interrupted)


def _batch_setup(
    scenario: Scenario,
    variations: list[RobotVariation],
    record: Sequence[int],
    loop: tuple[Any, Any, Any] | None,
    t0: float | Sequence[float] | np.ndarray,
    memory: Any,
) -> _Loops:
    """The loops' objects, initial states, landing offsets and seeds for N robots."""
    n = len(variations)
    controller, reference, context = loop or build_loop(scenario)
    if memory is None:  # a law that takes only floats runs one robot at a time (hil.law.batch)
        controller = for_batch(controller, scenario, reference)
    n_samples = max(1, round(scenario.run.duration / scenario.timing.ts))
    ini, timing = scenario.initial, scenario.timing
    starts = None
    if np.ndim(t0) or float(t0) != 0.0:
        starts = np.array(np.broadcast_to(np.asarray(t0, dtype=float), (n,)))
    # N copies of one variation (``variations`` given as an int) need no per-robot reads.
    first = variations[0]
    shared = all(v is first for v in variations)

    def per_robot(name: str, default: Any, dtype: Any) -> np.ndarray:
        if shared:
            return np.full(n, _or(getattr(first, name), default), dtype=dtype)
        return np.array([_or(getattr(v, name), default) for v in variations], dtype=dtype)

    pose = (per_robot(q, getattr(ini, q), float) for q in _POSE)
    state = PlantState(*pose, np.zeros(n), np.zeros(n))
    delays = per_robot("delay", timing.delay, float)
    jitters = per_robot("jitter", timing.jitter, float)
    jseeds = per_robot("jitter_seed", timing.seed, np.int64)
    dseeds = per_robot("disturbance_seed", scenario.disturbance.seed, np.int64)
    sseeds = per_robot("sensor_seed", scenario.plant.noise_seed, np.int64)
    # Landing offsets per distinct (delay, jitter, seed), drawn exactly as the single path draws
    # them (same seed, same n); robot i lands by row group[i].
    keys: dict[tuple[float, float, int], int] = {}
    draws = zip(delays.tolist(), jitters.tolist(), jseeds.tolist(), strict=True)
    group = np.array([keys.setdefault(key, len(keys)) for key in draws], dtype=np.intp)
    offsets = np.empty((len(keys), n_samples), dtype=np.int64)
    replay = _replay(scenario)
    for (delay, jitter, seed), row in keys.items():
        extra = extra_delays(timing.jitter_kind, jitter, seed, n_samples, replay)
        offsets[row] = landing_offsets(extra, delay, scenario.plant_step)
    together = len(offsets) == 1  # one draw: every robot lands each command at the same step
    ext = Extremes.zeros(n)
    track_initial(ext, state, scenario.limits)
    record = [int(i) for i in record]
    return _Loops(
        controller,
        reference,
        context,
        _plant(scenario, dseeds if scenario.disturbance.kind == "random" else None),
        state,
        offsets[0].tolist() if together else offsets,
        Hold(n, apart=not together),
        (jseeds, dseeds, sseeds),
        _initial_memory(controller, n, scenario) if memory is None else memory,
        n_samples,
        ext,
        group=group,
        starts=starts,
        record=record,
        rec_rows={i: [] for i in record},
    )


def _batch_loop(
    run: _Loops,
    scenario: Scenario,
    progress: Progress | None,
    on_sample: Callable[[int, PlantState], None] | None,
) -> None:
    """The sampled-data loop on arrays: sample, law, send, land at t_k, record, advance."""
    controller, reference, hold = run.controller, run.reference, run.hold
    plant, ext = run.plant, run.ext
    state, memory, starts, land, group = run.state, run.memory, run.starts, run.land, run.group
    ts, m, n_samples = scenario.timing.ts, scenario.substeps, run.n_samples
    sensor, sseeds = scenario.sensor, run.seeds[2]
    ideal_sensor = sensor.is_ideal
    n = len(group)
    together = isinstance(land, list)
    rms_from = math.floor(0.9 * n_samples)
    sq_sum, sq_n = np.zeros(n), 0
    every = max(1, n_samples // 200)
    ones = np.ones(n)
    faulted = np.zeros(n, dtype=bool)
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
            out = batch_update(controller, t_k, ts, meas, ref_arr, memory, faulted)
            memory, tau1, tau2 = out.memory, out.tau1, out.tau2
            if out.faults:
                run.faults.update(out.faults)
                faulted[list(out.faults)] = True
            if run.tel_keys is None:
                run.tel_keys = list(out.telemetry)
            j0 = k * m
            hold.send(k, j0 + (land[k] if together else land[group, k]), tau1, tau2)
            hold.land(j0)
            if k >= rms_from or run.record:
                e_pos = np.hypot(state.x - ref.xd, state.y - ref.yd)
            if k >= rms_from:
                sq_sum += e_pos * e_pos
                sq_n += 1
            run.last = (state.x, state.y, state.theta, ref.xd, ref.yd, ref.thetad)
            if run.record:  # the single path's row of each recorded robot, robot by robot
                # (scalar reads: a few robots are recorded out of a batch of any size)
                applied = (hold.cmd1, hold.cmd2) if plant.lag <= 0.0 else (state.tau1, state.tau2)
                tel_keys = run.tel_keys or []
                head = wrap_angle(state.theta - ref.thetad)
                tel = [np.broadcast_to(out.telemetry.get(key, np.nan), (n,)) for key in tel_keys]
                timed = (t_k, ref.xd, ref.yd, ref.thetad)  # floats when the robots share t_k
                robot = (*state[:5], *applied, tau1, tau2, e_pos, head, *tel)
                for i in run.record:
                    t, xd, yd, thd = timed if starts is None else (q[i] for q in timed)
                    x, y, th, v, w, *rest = (q[i] for q in robot)
                    row = np.array([t, x, y, th, v, w, xd, yd, thd, *rest], dtype=float)
                    run.rec_rows[i].append(row)
            state = advance_period(state, hold, plant, j0, j0 + m, ext, starts)
            run.done = k + 1
            if progress is not None and k % every == 0:
                progress(k, n_samples)
            if out.faults and faulted.all():  # every robot's law has failed: nothing to run
                break
    except KeyboardInterrupt:
        run.interrupted = True
    if on_sample is not None and not run.interrupted:
        on_sample(run.done, state)  # n_samples, unless every robot's law failed before
    run.rms = np.sqrt(sq_sum / sq_n) if sq_n else np.full(n, np.nan)
    run.state, run.memory = state, memory


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
    """N closed loops at once on numpy arrays (the batch path), one per variation (an int N: N
    identical robots); every robot gets a summary, the robots ``record`` lists their full trace.
    ``t0``: each robot's first-sample time (one value or one per robot; default 0), as in
    :func:`simulate`. ``memory``: the law's memory at the first sample, arrays of shape (N,) per
    field (default: its initial memory). ``on_sample(k, state)`` is called with the robots'
    state (arrays) at each sample time t0 + k Ts, k = 0 .. K (K: after the last period).
    """
    if isinstance(variations, int):
        variations = [RobotVariation()] * variations
    variations = list(variations)
    if not variations:
        raise ValueError("simulate_batch needs at least one robot")
    run = _batch_setup(scenario, variations, record, loop, t0, memory)
    # the same loops in one numba kernel, unless traces are recorded
    if not run.record and compiled.chosen(run.controller, scenario, len(run.group) * run.n_samples):
        compiled.run(run, scenario, progress, on_sample)
    else:
        _batch_loop(run, scenario, progress, on_sample)
    if progress is not None and not run.interrupted:
        progress(run.done, run.n_samples)
    state, columns = run.state, [*BASE_COLUMNS, *(run.tel_keys or [])]
    last = run.last or (state.x, state.y, state.theta, 0.0, 0.0, 0.0)
    n = len(run.group)
    x, y, th, xd, yd, thd = (np.broadcast_to(np.asarray(q, dtype=float), (n,)) for q in last)
    pos_err = [math.hypot(a, b) for a, b in zip((x - xd).tolist(), (y - yd).tolist(), strict=True)]
    dropped = np.asarray(run.hold.dropped, dtype=np.int64)
    per_robot = (pos_err, wrap_angle(th - thd), run.rms, dropped, *run.seeds)
    summaries = _summaries(scenario, run, run.done, per_robot)
    traces = {
        i: np.array(rows, dtype=float).reshape(len(rows), len(columns))
        for i, rows in run.rec_rows.items()
    }
    resolved = resolved_dict(scenario, run.controller, run.context)
    return BatchResult(scenario, resolved, variations, summaries, columns, traces, run.interrupted)
