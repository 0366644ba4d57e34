"""The ideal trajectory of a folder (:mod:`hil.analysis.report.ideal_sim`: Ts/10, no delay, no
jitter, standing in for continuous time; windowed for a long trace). A user's law is not run again
unless asked (``hil report DIR --ideal``): the report shows what the run measured and never
imports the user's module on its own (it may have changed since the run, or be gone; and at
Ts/10 in Python the ideal costs ten times the run's steps). Asked, it is looked up as for a
simulation (the installed packages, the run's scenario folder, the working directory); not
found there, or failing there, :class:`IdealUnavailableError`, and the report says why.
"""

from __future__ import annotations

import importlib.machinery
import importlib.util
from collections.abc import Iterable
from contextlib import suppress

import numpy as np

from controller_service.registry import law_path_for
from hil.analysis.report.ideal_sim import base_dir_of, simulate_ideal
from hil.analysis.report.telemetry import folder_telemetry, forget_memory
from hil.folder import RunFolder as Folder


def memory_source(folder: Folder):
    """The law's memory at trace rows, from the trace's own columns (a simulation's trace
    carries the law's telemetry) or the run's recorded telemetry at the rows' sample times
    (at or before them); NaN where unknown."""

    def at(fields: tuple[str, ...], rows: np.ndarray) -> dict[str, np.ndarray]:
        tr = folder.trace
        if all(f in tr for f in fields):
            return {f: np.asarray(tr[f], dtype=float)[rows] for f in fields}
        tel = folder_telemetry(folder) if "sample_ns" in tr and folder.recordings else {}
        if not all(f in tel for f in fields):
            return {}
        when = np.asarray(tr["sample_ns"], dtype=float)[rows].astype(np.int64)
        out = {}
        for f in fields:
            tn, values = tel[f]
            i = np.searchsorted(tn, when, side="right") - 1
            out[f] = np.where(i >= 0, values[np.maximum(i, 0)], np.nan)
        forget_memory(folder)  # read once, at the windows' starts: not kept beside the ideal
        return out

    return at


class IdealUnavailableError(Exception):
    """The ideal trajectory cannot be simulated here (the reason is the message)."""


def law_findable(law: str, folders: Iterable[str] = ()) -> bool:
    """A built-in law, or a user's law whose module is found (without importing it) in the
    installed packages or, as :func:`controller_service.registry.build_controller` looks for
    it, in ``folders``."""
    module = law.partition(":")[0] if ":" in law else ""
    if not module:
        return True
    with suppress(ImportError, ValueError):
        if importlib.util.find_spec(module) is not None:
            return True
    top = module.split(".")[0]  # a package in one of the folders: its submodule is checked
    return importlib.machinery.PathFinder.find_spec(top, [str(f) for f in folders]) is not None


def ideal_from_simulator(folder: Folder, user_law: bool = False) -> dict[str, np.ndarray] | None:
    """The folder's ideal trajectory; with a user's law only when ``user_law`` (asked for)."""
    law = str((folder.scenario.get("controller") or {}).get("law", "unified"))
    own = ":" in law  # module:Class, the user's (the built-in laws are plain names)
    if own and not user_law:
        raise IdealUnavailableError(
            f"not computed: the law {law!r} is your own, and the report does not run it again "
            "unless asked (hil report DIR --ideal; at Ts/10 it costs ten times the run's "
            "steps); every other figure is the run's own and needs no law"
        )
    folders = law_path_for(base_dir_of(folder.scenario, folder.path))
    if not law_findable(law, folders):
        raise IdealUnavailableError(
            f"not computed: the ideal simulation needs the law {law!r}, whose module is not "
            f"found here (looked in the installed packages, {', '.join(folders)}; every other "
            "figure is the run's own and needs no law)"
        )
    try:
        return simulate_ideal(
            folder.scenario,
            folder.path,
            folder.trace,
            memory_source(folder),
            parsed=folder.typed_scenario(),
        )
    except Exception as exc:  # the user's module, maybe edited since the run, may raise anything
        if not own:
            raise  # a built-in law's failure is the bench's bug: shown, not explained away
        raise IdealUnavailableError(
            f"not computed: the law {law!r} failed in the ideal simulation here "
            f"({type(exc).__name__}: {exc}; every other figure is the run's own and needs no law)"
        ) from exc
