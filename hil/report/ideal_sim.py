"""The ideal trajectory by the offline simulator (hil.sim): the folder's own scenario with
Ts/10 as control period, no delay and no jitter, so the law acts almost continuously."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from hil.scenario import parse_scenario
from hil.sim import simulate

FINE_FACTOR = 10


def ideal_scenario(resolved: Mapping[str, Any], base_dir: Path) -> Any:
    """The resolved scenario at Ts/FINE_FACTOR with delay and jitter removed; the plant step
    is kept at most the fine period (RK4 with one step per fine period at the default)."""
    data = {k: (dict(v) if isinstance(v, Mapping) else v) for k, v in resolved.items()}
    sc = parse_scenario(data, base_dir)
    fine = sc.timing.ts / FINE_FACTOR
    timing = dataclasses.replace(
        sc.timing, ts=fine, delay=0.0, jitter=0.0, jitter_kind="uniform", replay=""
    )
    plant = sc.plant
    if plant.step is not None and plant.step > fine:
        plant = dataclasses.replace(plant, step=fine)
    return dataclasses.replace(sc, timing=timing, plant=plant)


def simulate_ideal(resolved: Mapping[str, Any], folder: Path) -> dict[str, np.ndarray] | None:
    base = folder
    source = (resolved.get("provenance") or {}).get("scenario_file")
    if isinstance(source, str) and Path(source).parent.is_dir():
        base = Path(source).resolve().parent  # a csv reference is relative to the scenario
    sc = ideal_scenario(resolved, base)
    result = simulate(sc)
    return {name: result.column(name) for name in ("t", "x", "y", "theta")}
