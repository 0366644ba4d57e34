"""trace.csv: one row per control sample (docs/run-folder.md, "trace.csv"), read and written."""

from __future__ import annotations

import csv
import itertools
from pathlib import Path

import numpy as np

from hil.errors import BadInputError
from hil.trace import TRACE_COLUMNS


def write_trace_csv(path: Path, columns: list[str], trace: np.ndarray) -> None:
    """A simulation's trace: ``trace`` rows under the ``columns`` header."""
    with path.open("w") as f:
        f.write(",".join(columns) + "\n")
        if len(trace):
            np.savetxt(f, trace, delimiter=",", fmt="%.10g")


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
