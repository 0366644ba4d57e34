"""The run or simulation folder: its one owner (layout, reading, writing; docs/run-folder.md).

Every file name is in :mod:`hil.folder.layout`, every JSON file follows :mod:`hil.folder.jsonio`.
A folder without trace.csv, summary.json and scenario.resolved.toml is not a run:
:func:`load_folder` raises :class:`hil.errors.BadInputError` (exit code 2) with the reason.
"""

from __future__ import annotations

import datetime as dt
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, cast

import numpy as np

from hil.errors import BadInputError
from hil.folder import layout
from hil.folder.jsonio import read_json_object, write_json
from hil.folder.records import Summary
from hil.folder.scenario_view import folder_scenario
from hil.folder.trace_csv import TraceColumns, read_trace
from hil.provenance import Toml
from hil.scenario import Scenario


@dataclass
class RunFolder:
    """One run or simulation folder, loaded (:func:`load_folder`)."""

    path: Path
    #: trace.csv's columns, a lazy folder's read on first use, so that a long run's trace and
    #: its series never sit in memory together (:class:`hil.folder.trace_csv.TraceColumns`).
    trace: Mapping[str, np.ndarray]
    summary: Summary
    scenario: Toml  # scenario.resolved.toml's tables
    recordings: list[Path] = field(default_factory=list)
    #: What more than one part of the report reads (the recorded telemetry), read once.
    cache: dict[str, Any] = field(default_factory=dict, repr=False)
    #: ``scenario`` parsed (:func:`typed_scenario`): handed down by a process that holds it
    #: already (``hil run``), else parsed on first use, once.
    typed: Scenario | None = field(default=None, repr=False)

    def typed_scenario(self) -> Scenario:
        """The folder's resolved scenario as a :class:`hil.scenario.Scenario`, parsed once."""
        if self.typed is None:
            self.typed = folder_scenario(self.scenario)
        return self.typed

    @property
    def kind(self) -> str:
        """ "run" (has a recording or a timing object) or "simulation"."""
        return "run" if self.recordings or "timing" in self.summary else "simulation"

    @property
    def name(self) -> str:
        return self.path.name


def has_hop_logs(path: Path) -> bool:
    return (path / layout.PLANT_LOG).is_file() or (path / layout.CONTROLLER_LOG).is_file()


def read_scenario(path: Path) -> Toml:
    """The folder's resolved scenario; BadInputError when it is missing or not TOML."""
    f = path / layout.SCENARIO_RESOLVED
    try:
        return tomllib.loads(f.read_text())
    except (OSError, ValueError) as exc:
        raise BadInputError(f"{f}: not TOML ({exc})") from exc


def write_summary(path: Path, summary: Summary) -> Path:
    return write_json(path / layout.SUMMARY, summary)


def write_series(path: Path, arrays: dict[str, np.ndarray]) -> Path:
    """The measurement's series, written whole (a temporary file renamed)."""
    tmp = path / (layout.SERIES + ".writing.npz")
    np.savez(tmp, **arrays)
    return tmp.replace(path / layout.SERIES)


def read_series(path: Path) -> dict[str, np.ndarray] | None:
    """The measurement's saved per-sample series (None: not measured yet, or a sim)."""
    f = path / layout.SERIES
    if not f.is_file():
        return None
    try:
        with np.load(f, allow_pickle=False) as z:
            return {k: z[k] for k in z.files}
    except (OSError, ValueError) as exc:
        raise BadInputError(f"{f}: not the measurement's series ({exc})") from exc


def new_run_dir(root: str | Path = "runs", prefix: str = "run") -> Path:
    """A fresh folder name under ``root``: ``PREFIX-YYYYmmdd-HHMMSS`` (local time), suffixed
    ``-1``, ``-2``... when taken."""
    stamp = dt.datetime.now().strftime("%Y%m%d-%H%M%S")
    for i in range(1000):
        p = Path(root) / (f"{prefix}-{stamp}" + (f"-{i}" if i else ""))
        if not p.exists():
            return p
    raise BadInputError(f"cannot find a free folder name under {root}")


def load_folder(path: str | Path, lazy: bool = False) -> RunFolder:
    """Load and check a run or simulation folder; BadInputError when it is not one. ``lazy``:
    check only the trace's header now, read its rows on first use (a bad row raises there)."""
    p = Path(path)
    if not p.is_dir():
        raise BadInputError(f"{p}: not a folder")
    for required in layout.REQUIRED:
        if not (p / required).is_file():
            raise BadInputError(f"{p}: not a run or simulation folder (no {required})")
    summary = cast(Summary, read_json_object(p / layout.SUMMARY))
    scenario = read_scenario(p)
    trace = TraceColumns(p / layout.TRACE) if lazy else read_trace(p / layout.TRACE)
    return RunFolder(p, trace, summary, scenario, recordings=sorted(p.glob("*.mcap")))
