"""The ideal trajectory by the offline simulator (hil.sim): the folder's own scenario at Ts/10,
no delay, no jitter (the law acts almost continuously), from the trace's first state and time (a
run's first sample may come late: the reference and the law's clock then start there).

A trace longer than :data:`WINDOW_S` gets a *windowed* ideal: each window starts from the
robot's state at its first sample, at that sample's time, with the law's memory there where the
folder has it (else the initial memory), and runs to the next window's start. The windows run at
once on the batch path (one robot per window: an hour's run costs one window's steps on a few
hundred robots, not 36 M single steps), compiled or numpy (:func:`_windowed`). The ideal is
returned at the trace's sample times (linear interpolation between fine samples), so the
deviation measures how far sampling and delay took the robot from the continuous loop within
each window.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
import os
import pickle
import subprocess
import sys
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from hil.folder.scenario_view import folder_scenario
from hil.scenario import Scenario, build_loop
from hil.sim import compiled, simulate, simulate_batch
from hil.sim.core import RobotVariation, _initial_memory

FINE_FACTOR = 10
START_STATE = ("x", "y", "theta", "v", "omega")
#: Length of the windows of a long trace's ideal (s); a trace no longer gets one simulation.
WINDOW_S = 10.0
#: From this many windows on, the batch path simulates them all at once (its per-step overhead
#: pays off only across many; below, the single path, the same arithmetic to rounding).
BATCH_MIN_WINDOWS = 8
#: ... and from this many per process on, it spreads them over the CPUs (one process each).
PARALLEL_MIN_WINDOWS = 32
#: Law memory at trace rows: field names, row indices -> field -> values (NaN: unknown).
MemorySource = Callable[[tuple[str, ...], np.ndarray], dict[str, np.ndarray]]


def ideal_scenario(resolved: Scenario, start: Mapping[str, float] | None = None) -> Scenario:
    """The resolved scenario at Ts/FINE_FACTOR without delay and jitter, its plant step at most
    the fine period; ``start``: the initial state (:data:`START_STATE`) and ``duration``."""
    sc = resolved
    if start is not None:
        initial = dataclasses.replace(sc.initial, **{k: start[k] for k in START_STATE})
        run = dataclasses.replace(sc.run, duration=start["duration"])
        sc = dataclasses.replace(sc, initial=initial, run=run)
    fine = sc.timing.ts / FINE_FACTOR
    timing = dataclasses.replace(
        sc.timing, ts=fine, delay=0.0, jitter=0.0, jitter_kind="uniform", replay=""
    )
    plant = sc.plant
    if plant.step is not None and plant.step > fine:
        plant = dataclasses.replace(plant, step=fine)
    return dataclasses.replace(sc, timing=timing, plant=plant)


def trace_start(trace: Mapping[str, np.ndarray]) -> dict[str, float]:
    """The trace's first time and state, and how long it runs."""
    t0, duration = float(trace["t"][0]), float(trace["t"][-1] - trace["t"][0])
    return {**{k: float(trace[k][0]) for k in START_STATE}, "t0": t0, "duration": duration}


def window_starts(t: np.ndarray, window: float = WINDOW_S) -> np.ndarray:
    """The rows where the windows of a trace start: the first sample at or after
    t[0] + i window, for every window that holds a sample."""
    span = float(t[-1] - t[0])
    count = max(1, math.ceil(span / window - 1e-9))
    rows = np.searchsorted(t, t[0] + window * np.arange(count), side="left")
    return np.unique(rows[rows < t.size])


def base_dir_of(resolved: Mapping[str, Any], folder: Path) -> Path:
    """The folder the ideal's scenario is read in: the run's scenario file's, else the run
    folder (a csv reference and a user's law module are looked up there)."""
    source = (resolved.get("provenance") or {}).get("scenario_file")
    if isinstance(source, str) and Path(source).parent.is_dir():
        return Path(source).resolve().parent  # a csv reference is relative to the scenario
    return folder


def simulate_ideal(
    resolved: Mapping[str, Any],
    folder: Path,
    trace: Mapping[str, np.ndarray] | None = None,
    memory_source: MemorySource | None = None,
    window: float = WINDOW_S,
    parsed: Scenario | None = None,
) -> dict[str, np.ndarray] | None:
    """The ideal trajectory (t, x, y, theta): at the fine period's times for a trace of at most
    ``window`` seconds, else windowed, at the trace's times, with ``window_start_t``;
    ``parsed``: ``resolved`` already parsed (:func:`hil.folder.scenario_view.folder_scenario`)."""
    base = base_dir_of(resolved, folder)
    sc = parsed if parsed is not None else folder_scenario(resolved)
    sc = dataclasses.replace(sc, base_dir=base)
    if trace is not None and float(trace["t"][-1] - trace["t"][0]) > window * (1.0 + 1e-9):
        return _windowed(sc, trace, memory_source, window)
    start = trace_start(trace) if trace is not None else None
    sc = ideal_scenario(sc, start)
    result = simulate(sc, t0=start["t0"] if start is not None else 0.0)
    return {name: result.column(name) for name in ("t", "x", "y", "theta")}


def _window_memories(
    controller: Any, sc: Any, starts: np.ndarray, memory_source: MemorySource | None
) -> tuple[Any, np.ndarray]:
    """The law's memory at each window's start (arrays, one per window) and which windows
    got the recorded memory (the first window and unknown ones keep the initial memory)."""
    n = starts.size
    mem = _initial_memory(controller, n, sc)
    fields = getattr(mem, "_fields", None)
    known = np.zeros(n, dtype=bool)
    got = memory_source(tuple(fields), starts) if memory_source is not None and fields else {}
    if not fields or not all(f in got for f in fields):
        return mem, known
    known = np.all([np.isfinite(got[f]) for f in fields], axis=0)
    known[0] = False  # the first window starts as the single ideal does
    values = [np.where(known, got[f], np.asarray(getattr(mem, f), dtype=float)) for f in fields]
    return type(mem)(*values), known


def _windowed(
    resolved: Scenario,
    trace: Mapping[str, np.ndarray],
    memory_source: MemorySource | None,
    window: float,
) -> dict[str, np.ndarray]:
    t = np.asarray(trace["t"], dtype=float)
    starts = window_starts(t, window)
    start0 = trace_start(trace)
    sc0 = ideal_scenario(resolved, start0)
    t_stop = np.append(t[starts[1:]], t[-1])
    # fine samples 0 .. steps of every window reach its last row (the next window's start)
    steps = max(1, math.ceil(float(np.max(t_stop - t[starts])) / sc0.timing.ts - 1e-9) + 1)
    loop = build_loop(sc0)
    memory, known = _window_memories(loop[0], sc0, starts, memory_source)
    states = {s: np.asarray(trace[s], dtype=float)[starts] for s in START_STATE}
    whole = _Windows(resolved, start0, t, starts, memory, known, states, steps)
    if starts.size < BATCH_MIN_WINDOWS:
        out = _one_by_one(whole, loop)
    elif compiled.chosen(loop[0], sc0, starts.size * steps):
        # one parallel kernel over the windows, on every CPU, in a process of its own: the
        # compiler's and the interpolation's memory leave with it, not beside the report's
        out = _spread([whole], loop, here=False)
    else:
        # Only memory of per-window arrays (a NamedTuple, as the bundled laws keep) splits.
        groups = _groups(starts.size) if hasattr(memory, "_fields") else 1
        out = _spread(whole.split(groups), loop)
    return {"t": t.copy(), **out, "window_start_t": t[starts]}


def _groups(windows: int) -> int:
    """Processes for the batch route: one per CPU this process may use, each with at least
    :data:`PARALLEL_MIN_WINDOWS` windows (fewer are not worth a process's start-up)."""
    return max(1, min(len(os.sched_getaffinity(0)), windows // PARALLEL_MIN_WINDOWS))


@dataclass(frozen=True)
class _Windows:
    """Consecutive windows of a trace, all a process needs to simulate them (picklable): their
    rows' times, each window's first row in them, law memory and starting state."""

    resolved: Scenario  # the folder's, its base_dir the ideal's (base_dir_of)
    start0: dict[str, float]  # the whole trace's first state: the scenario the ideal runs
    t: np.ndarray
    starts: np.ndarray
    memory: Any  # the law's memory, per window (arrays)
    known: np.ndarray
    states: dict[str, np.ndarray]
    steps: int

    def split(self, groups: int) -> list[_Windows]:
        """``groups`` runs of consecutive windows, as even as they divide."""
        cuts = np.linspace(0, self.starts.size, groups + 1).round().astype(int)
        rows = np.append(self.starts, self.t.size)
        parts = []
        for a, b in itertools.pairwise(cuts):
            lo, hi = int(rows[a]), int(rows[b])
            part = dataclasses.replace(
                self,
                t=self.t[lo:hi],
                starts=self.starts[a:b] - lo,
                memory=type(self.memory)(*(np.asarray(f)[a:b] for f in self.memory)),
                known=self.known[a:b],
                states={k: v[a:b] for k, v in self.states.items()},
            )
            parts.append(part)
        return parts

    def variations(self) -> list[RobotVariation]:
        rows = zip(*(self.states[s] for s in START_STATE), strict=True)
        return [RobotVariation(**dict(zip(START_STATE, map(float, r), strict=True))) for r in rows]

    def scenario(self, steps: int) -> Any:
        """The ideal's scenario, run for ``steps`` fine periods."""
        sc = ideal_scenario(self.resolved, self.start0)
        run = dataclasses.replace(sc.run, duration=steps * sc.timing.ts)
        return dataclasses.replace(sc, run=run)

    def rows(self) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """Each window's end row, and the ideal's columns to fill, one row per trace row."""
        ends = np.append(self.starts[1:], self.t.size)
        return ends, {name: np.empty(self.t.size) for name in ("x", "y", "theta")}


def _spread(parts: list[_Windows], loop: Any, here: bool = True) -> dict[str, np.ndarray]:
    """Each part on the batch path, the first here (unless not ``here``), each other one at the
    same time in a process of its own (``python -m hil.analysis.report.ideal_sim``, pickled on stdin
    and stdout: no multiprocessing, which would import the caller's main module again); the rows
    joined in order. A part whose process fails (a law it cannot import) runs here after."""
    away = parts[1:] if here else parts
    procs: list[subprocess.Popen[bytes]] = []
    try:
        for part in away:
            argv = [sys.executable, "-m", "hil.analysis.report.ideal_sim"]
            proc = subprocess.Popen(argv, stdin=subprocess.PIPE, stdout=subprocess.PIPE)
            procs.append(proc)
            assert proc.stdin is not None
            with proc.stdin:
                pickle.dump(part, proc.stdin, protocol=pickle.HIGHEST_PROTOCOL)
        done = [_batch(parts[0], loop)] if here else []
        for part, proc in zip(away, procs, strict=True):
            assert proc.stdout is not None
            raw = proc.stdout.read()  # a failed process: the same work, here
            done.append(pickle.loads(raw) if proc.wait() == 0 else _batch(part, loop))
    finally:
        for proc in procs:  # Ctrl-C: the other processes stop with this one
            if proc.poll() is None:
                proc.kill()
                proc.wait()
    return {name: np.concatenate([d[name] for d in done]) for name in ("x", "y", "theta")}


def _batch(w: _Windows, loop: Any = None) -> dict[str, np.ndarray]:
    """All windows of ``w`` at once on the batch path (one robot per window)."""
    sc = w.scenario(w.steps)
    ends, out = w.rows()
    hook = _Interpolator(w, ends, sc.timing.ts, out)
    loop = loop if loop is not None else build_loop(sc)
    simulate_batch(sc, w.variations(), loop=loop, t0=w.t[w.starts], memory=w.memory, on_sample=hook)
    return out


def _one_by_one(w: _Windows, loop: Any) -> dict[str, np.ndarray]:
    """The windows one after the other on the single path."""
    sc = w.scenario(w.steps + 1)
    ends, out = w.rows()
    for i, var in enumerate(w.variations()):
        mem_i = type(w.memory)(*(float(np.asarray(f)[i]) for f in w.memory)) if w.known[i] else None
        res = simulate(sc, var, t0=float(w.t[w.starts[i]]), memory=mem_i, loop=loop)
        rows = slice(w.starts[i], ends[i])
        for name in out:
            out[name][rows] = np.interp(w.t[rows], res.column("t"), res.column(name))
    return out


class _Interpolator:
    """The batch path's ``on_sample`` hook: each trace row is the linear interpolation of its
    window's state between the fine samples k and k + 1 around its time; rows are visited in
    the order of k, so a step touches only the rows whose k is j (they take the state) or
    j - 1 (they move towards it)."""

    def __init__(self, w: _Windows, ends: np.ndarray, fine: float, out: dict[str, np.ndarray]):
        # int32 rows and robots: an hour's trace has a few million rows, and these tables
        # live through the whole simulation beside the trace
        win = np.repeat(np.arange(w.starts.size, dtype=np.int32), ends - w.starts)
        u = (w.t - w.t[w.starts][win]) / fine
        k = np.clip(np.floor(u).astype(np.int32), 0, w.steps - 1)
        self.order = np.argsort(k, kind="stable").astype(np.int32)
        self.bounds = np.searchsorted(k[self.order], np.arange(w.steps + 2), side="left")
        self.robot = win[self.order]
        del win
        self.weight = np.clip(u - k, 0.0, 1.0)[self.order]
        self.out = out

    def __call__(self, j: int, state: Any) -> None:
        lo, hi = self.bounds[j], self.bounds[j + 1]
        if hi > lo:
            rows, robots = self.order[lo:hi], self.robot[lo:hi]
            for name, col in self.out.items():
                col[rows] = getattr(state, name)[robots]
        if j > 0:
            lo, hi = self.bounds[j - 1], self.bounds[j]
            if hi > lo:
                rows, robots, w = self.order[lo:hi], self.robot[lo:hi], self.weight[lo:hi]
                for name, col in self.out.items():
                    left = col[rows]
                    col[rows] = left + w * (getattr(state, name)[robots] - left)


if __name__ == "__main__":  # a worker of _spread: the part pickled on stdin, its rows on stdout
    rows = _batch(pickle.load(sys.stdin.buffer))
    pickle.dump(rows, sys.stdout.buffer, protocol=pickle.HIGHEST_PROTOCOL)
