"""Reading a run or simulation folder (CONTRACT.md, "Run and simulation folders").

A folder is: ``trace.csv`` (one row per control sample), ``summary.json``,
``scenario.resolved.toml`` and, for a real run, its recording (``*.mcap``). Anything else is
not a run: :func:`load_folder` raises :class:`hil.errors.BadInputError` (exit code 2) with
the reason.
"""

from __future__ import annotations

import csv
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
    """One run or simulation folder, loaded."""

    path: Path
    trace: dict[str, np.ndarray]
    summary: dict[str, Any]
    scenario: dict[str, Any]
    recordings: list[Path] = field(default_factory=list)

    @property
    def kind(self) -> str:
        """ "run" (has a recording or a timing object) or "simulation"."""
        return "run" if self.recordings or "timing" in self.summary else "simulation"

    @property
    def name(self) -> str:
        return self.path.name


def read_trace(path: Path) -> dict[str, np.ndarray]:
    """trace.csv as column name -> float array; every required column present and finite
    where it must be."""
    try:
        with open(path, newline="") as f:
            header = next(csv.reader(f))
    except (OSError, StopIteration, UnicodeDecodeError, csv.Error) as exc:
        raise BadInputError(f"{path}: cannot read a CSV header ({exc})") from exc
    header = [h.strip() for h in header]
    missing = [c for c in TRACE_COLUMNS if c not in header]
    if missing:
        raise BadInputError(f"{path}: trace.csv lacks columns {', '.join(missing)}")
    try:
        data = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2, dtype=float)
    except ValueError as exc:
        raise BadInputError(f"{path}: trace.csv has a non-numeric cell ({exc})") from exc
    if data.shape[0] < 2:
        raise BadInputError(f"{path}: trace.csv has fewer than two samples")
    if data.shape[1] != len(header):
        raise BadInputError(
            f"{path}: trace.csv rows have {data.shape[1]} cells, header {len(header)}"
        )
    trace = {name: data[:, i].copy() for i, name in enumerate(header)}
    if not np.all(np.isfinite(trace["t"])) or np.any(np.diff(trace["t"]) < 0):
        raise BadInputError(f"{path}: column t is not finite and non-decreasing")
    return trace


def load_folder(path: str | Path) -> Folder:
    """Load and check a run or simulation folder; BadInputError when it is not one."""
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
    trace = read_trace(p / "trace.csv")
    return Folder(
        path=p,
        trace=trace,
        summary=summary,
        scenario=scenario,
        recordings=sorted(p.glob("*.mcap")),
    )
