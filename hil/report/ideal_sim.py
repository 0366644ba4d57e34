"""The ideal trajectory by the offline simulator (hil.sim): the folder's own scenario with
Ts/10 as control period, no delay and no jitter, so the law acts almost continuously, started
from the trace's first state and time (a run's first sample may come late: the reference and
the law's clock then start there, as they did in the run)."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from hil.scenario import parse_scenario
from hil.sim import simulate

FINE_FACTOR = 10
START_STATE = ("x", "y", "theta", "v", "omega")


def ideal_scenario(
    resolved: Mapping[str, Any], base_dir: Path, start: Mapping[str, float] | None = None
) -> Any:
    """The resolved scenario at Ts/FINE_FACTOR with delay and jitter removed; the plant step
    is kept at most the fine period (RK4 with one step per fine period at the default).
    ``start``: the initial state (x, y, theta, v, omega) and ``duration`` to simulate."""
    data = {k: (dict(v) if isinstance(v, Mapping) else v) for k, v in resolved.items()}
    if start is not None:
        data["initial"] = {**data.get("initial", {}), **{k: start[k] for k in START_STATE}}
        data["run"] = {**data.get("run", {}), "duration": start["duration"]}
    sc = parse_scenario(data, base_dir)
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
    out = {k: float(trace[k][0]) for k in START_STATE}
    out["t0"] = float(trace["t"][0])
    out["duration"] = float(trace["t"][-1] - trace["t"][0])
    return out


def simulate_ideal(
    resolved: Mapping[str, Any], folder: Path, trace: Mapping[str, np.ndarray] | None = None
) -> dict[str, np.ndarray] | None:
    base = folder
    source = (resolved.get("provenance") or {}).get("scenario_file")
    if isinstance(source, str) and Path(source).parent.is_dir():
        base = Path(source).resolve().parent  # a csv reference is relative to the scenario
    start = trace_start(trace) if trace is not None else None
    sc = ideal_scenario(resolved, base, start)
    result = simulate(sc, t0=start["t0"] if start is not None else 0.0)
    return {name: result.column(name) for name in ("t", "x", "y", "theta")}
