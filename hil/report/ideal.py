"""The ideal trajectory of a folder: the simulator at a fine period (Ts/10, no delay, no
jitter) standing in for continuous time, from the trace's first state and time; a trace
longer than :data:`hil.report.ideal_sim.WINDOW_S` gets the windowed ideal, each window
restarted from the robot's state and the law's memory at its start (hil.report.ideal_sim).
A user's law whose module cannot be found here (the run measured everything the report shows;
only this fresh simulation needs the law): :class:`IdealUnavailableError`, and the report says why.
"""

from __future__ import annotations

import importlib.util

import numpy as np

from hil.folder import RunFolder as Folder
from hil.report.ideal_sim import simulate_ideal
from hil.report.telemetry import folder_telemetry


def memory_source(folder: Folder):
    """The law's memory at trace rows, from the trace's own columns (a simulation's trace
    carries the law's telemetry) or the run's recorded telemetry at the rows' sample times
    (at or before them); NaN where unknown."""

    def at(fields: tuple[str, ...], rows: np.ndarray) -> dict[str, np.ndarray]:
        tr = folder.trace
        if all(f in tr for f in fields):
            return {f: np.asarray(tr[f], dtype=float)[rows] for f in fields}
        if "sample_ns" not in tr or not folder.recordings:
            return {}

        tel = folder_telemetry(folder)
        if not all(f in tel for f in fields):
            return {}
        when = np.asarray(tr["sample_ns"], dtype=float)[rows].astype(np.int64)
        out = {}
        for f in fields:
            tn, values = tel[f]
            i = np.searchsorted(tn, when, side="right") - 1
            out[f] = np.where(i >= 0, values[np.maximum(i, 0)], np.nan)
        return out

    return at


class IdealUnavailableError(Exception):
    """The ideal trajectory cannot be simulated here (the reason is the message)."""


def law_findable(law: str) -> bool:
    """A built-in law, or a user's law whose module is found (without importing it)."""
    module = law.partition(":")[0] if ":" in law else ""
    if not module:
        return True
    try:
        return importlib.util.find_spec(module) is not None
    except (ImportError, ValueError):
        return False


def ideal_from_simulator(folder: Folder) -> dict[str, np.ndarray] | None:
    law = str((folder.scenario.get("controller") or {}).get("law", "unified"))
    if not law_findable(law):
        raise IdealUnavailableError(
            f"not computed: the ideal simulation needs the law {law!r}, whose module is not "
            "importable here (every other figure is the run's own and needs no law)"
        )
    return simulate_ideal(folder.scenario, folder.path, folder.trace, memory_source(folder))
