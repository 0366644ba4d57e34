"""Reading a run or simulation folder (docs/run-folder.md).

A folder is: ``trace.csv`` (one row per control sample), ``summary.json``,
``scenario.resolved.toml`` and, for a real run, its recording (``*.mcap``). Anything else is
not a run: :func:`load_folder` raises :class:`hil.errors.BadInputError` (exit code 2) with
the reason.
"""

from __future__ import annotations

import csv
import itertools
import json
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from hil.errors import BadInputError
from hil.trace import TRACE_COLUMNS


@dataclass
class Folder:
    """One run or simulation folder, loaded. ``trace`` is read on first use when the folder
    was loaded lazily (:func:`load_folder`): a run's report measures the hop logs first, so
    the trace's columns and the measurement's never sit in memory together at its peak."""

    path: Path
    trace_data: dict[str, np.ndarray] | None
    summary: dict[str, Any]
    scenario: dict[str, Any]
    recordings: list[Path] = field(default_factory=list)
    #: What more than one part of the report reads (the recorded telemetry), read once.
    cache: dict[str, Any] = field(default_factory=dict, repr=False)

    @property
    def trace(self) -> dict[str, np.ndarray]:
        """trace.csv's columns (:func:`read_trace`; BadInputError when it is not a trace)."""
        if self.trace_data is None:
            self.trace_data = read_trace(self.path / "trace.csv")
        return self.trace_data

    @property
    def kind(self) -> str:
        """ "run" (has a recording or a timing object) or "simulation"."""
        return "run" if self.recordings or "timing" in self.summary else "simulation"

    @property
    def name(self) -> str:
        return self.path.name


#: Rows parsed per call of the C reader (np.loadtxt): ~4 MB of floats at 15 columns.
CHUNK_ROWS = 32_768


def _count_lines(path: Path) -> int:
    n = 0
    last = b"\n"
    with open(path, "rb") as f:
        while block := f.read(1 << 24):
            n += block.count(b"\n")
            last = block[-1:]
    return n + (last != b"\n")


def trace_header(path: Path) -> list[str]:
    """trace.csv's column names; BadInputError without a header or a required column."""
    try:
        with open(path, newline="") as f:
            header = next(csv.reader(f))
    except (OSError, StopIteration, UnicodeDecodeError, csv.Error) as exc:
        raise BadInputError(f"{path}: cannot read a CSV header ({exc})") from exc
    header = [h.strip() for h in header]
    missing = [c for c in TRACE_COLUMNS if c not in header]
    if missing:
        raise BadInputError(f"{path}: trace.csv lacks columns {', '.join(missing)}")
    return header


def read_trace(path: Path) -> dict[str, np.ndarray]:
    """trace.csv as column name -> float array; every required column present and finite
    where it must be.

    Read in chunks of :data:`CHUNK_ROWS` lines by numpy's C parser straight into one
    preallocated (columns, rows) array, so an hour's trace (millions of rows) costs its
    columns and one chunk of memory, in linear time; each column is a contiguous row of it.
    """
    header = trace_header(path)
    capacity = max(0, _count_lines(path) - 1)
    data = np.empty((len(header), capacity), dtype=float)
    filled = 0
    try:
        with open(path, newline="") as f:
            next(f)
            while lines := list(itertools.islice(f, CHUNK_ROWS)):
                chunk = np.loadtxt(lines, delimiter=",", ndmin=2, dtype=float)
                if chunk.size == 0:
                    continue
                if chunk.shape[1] != len(header):
                    raise BadInputError(
                        f"{path}: trace.csv rows have {chunk.shape[1]} cells, header {len(header)}"
                    )
                end = filled + chunk.shape[0]
                if end > capacity:  # cannot happen (one row per line), but never overrun
                    capacity = max(end, 2 * capacity)
                    data = np.concatenate(
                        [data, np.empty((len(header), capacity - data.shape[1]))], 1
                    )
                data[:, filled:end] = chunk.T
                filled = end
    except ValueError as exc:
        raise BadInputError(f"{path}: trace.csv has a non-numeric cell ({exc})") from exc
    except UnicodeDecodeError as exc:
        raise BadInputError(f"{path}: trace.csv is not text ({exc})") from exc
    if filled < 2:
        raise BadInputError(f"{path}: trace.csv has fewer than two samples")
    if filled < data.shape[1]:
        data = data[:, :filled].copy()  # blank lines were counted: rarely taken
    trace = {name: data[i] for i, name in enumerate(header)}
    t = trace["t"]
    if not np.all(np.isfinite(t)) or np.any(t[1:] < t[:-1]):
        raise BadInputError(f"{path}: column t is not finite and non-decreasing")
    return trace


def load_folder(path: str | Path, lazy: bool = False) -> Folder:
    """Load and check a run or simulation folder; BadInputError when it is not one.

    ``lazy``: check only the trace's header now and read its rows on first use (a bad row
    then raises BadInputError there)."""
    p = Path(path)
    if not p.is_dir():
        raise BadInputError(f"{p}: not a folder")
    for required in ("trace.csv", "summary.json", "scenario.resolved.toml"):
        if not (p / required).is_file():
            raise BadInputError(f"{p}: not a run or simulation folder (no {required})")
    try:
        summary = json.loads((p / "summary.json").read_text())
    except (OSError, ValueError) as exc:
        raise BadInputError(f"{p / 'summary.json'}: not JSON ({exc})") from exc
    if not isinstance(summary, dict):
        raise BadInputError(f"{p / 'summary.json'}: not a JSON object")
    try:
        scenario = tomllib.loads((p / "scenario.resolved.toml").read_text())
    except (OSError, ValueError) as exc:
        raise BadInputError(f"{p / 'scenario.resolved.toml'}: not TOML ({exc})") from exc
    if lazy:
        trace_header(p / "trace.csv")
    return Folder(
        path=p,
        trace_data=None if lazy else read_trace(p / "trace.csv"),
        summary=summary,
        scenario=scenario,
        recordings=sorted(p.glob("*.mcap")),
    )
