"""trace.csv: one row per control sample (docs/run-folder.md, "trace.csv"), read and written."""

from __future__ import annotations

import csv
import itertools
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path

import numpy as np

from hil.errors import BadInputError
from hil.trace import TRACE_COLUMNS


def write_trace_csv(path: Path, columns: list[str], trace: np.ndarray) -> None:
    """A simulation's trace: ``trace`` rows under the ``columns`` header."""
    np.savetxt(path, trace, delimiter=",", fmt="%.10g", header=",".join(columns), comments="")


#: Rows parsed per call of the C reader (np.loadtxt): ~4 MB of floats at 15 columns.
CHUNK_ROWS = 32_768


def _count_lines(path: Path) -> int:
    n, last = 0, b"\n"
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


def read_trace(path: Path, columns: Sequence[str] | None = None) -> dict[str, np.ndarray]:
    """trace.csv as column name -> float array (every column, or ``columns`` and ``t``), its
    required columns present and ``t`` finite and non-decreasing. Read in chunks of
    :data:`CHUNK_ROWS` lines by numpy's C parser straight into one preallocated (columns, rows)
    array: an hour's trace (millions of rows) costs its columns and one chunk, in linear time."""
    header = trace_header(path)
    names = header if columns is None else [c for c in header if c in {"t", *columns}]
    usecols = [header.index(c) for c in names]
    capacity = max(0, _count_lines(path) - 1)
    data = np.empty((len(names), capacity), dtype=float)
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
                if len(usecols) < len(header):
                    chunk = chunk[:, usecols]
                end = filled + chunk.shape[0]
                if end > capacity:  # cannot happen (one row per line), but never overrun
                    capacity = max(end, 2 * capacity)
                    data = np.concatenate(
                        [data, np.empty((len(names), capacity - data.shape[1]))], 1
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
    trace = {name: data[i] for i, name in enumerate(names)}
    t = trace["t"]
    if not np.all(np.isfinite(t)) or np.any(t[1:] < t[:-1]):
        raise BadInputError(f"{path}: column t is not finite and non-decreasing")
    return trace


#: Columns a lazily loaded folder (:func:`hil.folder.load_folder`, ``lazy``) reads only when
#: asked for, in a pass of their own: the commanded torques and the state's sequence number,
#: which the report, the margin and the replay never draw (an hour's trace: 86 MB not held).
RARELY_READ = ("tau1_cmd", "tau2_cmd", "state_seq")


class TraceColumns(Mapping[str, np.ndarray]):
    """trace.csv's columns read on first use, ``deferred`` ones in a pass of their own; keys
    and ``in`` answer from the header without reading."""

    def __init__(self, path: Path, deferred: Sequence[str] = RARELY_READ) -> None:
        self.path = path
        self.header = trace_header(path)
        self.deferred = frozenset(deferred)
        self._data: dict[str, np.ndarray] = {}

    def __getitem__(self, name: str) -> np.ndarray:
        if name not in self._data:
            if name not in self.header:
                raise KeyError(name)
            rare = name in self.deferred
            wanted = [
                c for c in self.header if (c in self.deferred) == rare and c not in self._data
            ]
            read = read_trace(self.path, wanted)
            self._data.update({c: read[c] for c in wanted if c != "t" or "t" not in self._data})
        return self._data[name]

    def __contains__(self, name: object) -> bool:
        return name in self.header

    def __iter__(self) -> Iterator[str]:
        return iter(self.header)

    def __len__(self) -> int:
        return len(self.header)
