"""Replay latencies read from a file or a real run, for ``[timing] jitter_kind = "replay"``.

The draw of each sample's extra delay and its landing step (:func:`extra_delays`,
:func:`landing_offsets`) is :mod:`plant_emulator.landing`'s, shared with the plant in lockstep;
``hil`` reads the replay's latencies here once and hands them to both.

From a real run (a run folder or a ``.mcap`` recording) the latencies are the run's measured
sample-to-apply latencies, ``Measurement.latency_us()`` (applied path: apply - sample; shadow
path: receive - sample), read from the folder's saved measurement
(:mod:`hil.analysis.measure.folder`)
or, for a recording alone, measured from its attached hop logs, so a folder and its recording
replay the same latencies. ``PATH::zenoh`` or ``PATH::can`` keeps one path (default: every
path, each in landing order, Zenoh first).
"""

from __future__ import annotations

import csv
import json
from collections.abc import Callable
from pathlib import Path

import numpy as np

from hil.errors import BadInputError

REPLAY_MAX = 1e6  # s, the largest latency a replay file may hold (as [timing] delay)


#: The reader of a real run's latencies (seconds), :func:`hil.analysis.replay.latencies_from_run`.
RunLatencies = Callable[[str | Path], np.ndarray]


def jitter_samples_from(path: str | Path, run_latencies: RunLatencies | None = None) -> np.ndarray:
    """Latencies in seconds from a JSON list (or an object with a ``latencies`` list), a CSV
    with a ``latency`` column, one number per line, or a real run (``run_latencies``: its
    reader; without it a run is refused, named)."""
    if is_run_source(path):
        if run_latencies is None:
            raise BadInputError(
                f"[timing] replay: {path} is a run: its latencies are measured by the analysis "
                "(hil.analysis.replay), which this caller does not run"
            )
        return run_latencies(path)
    p = Path(path)
    try:
        text = p.read_text()
    except OSError as exc:
        raise BadInputError(f"[timing] replay: cannot read {p}: {exc.strerror or exc}") from exc
    except UnicodeDecodeError as exc:
        raise BadInputError(f"[timing] replay: {p} is not a text file ({exc.reason})") from exc
    values: list[float]
    try:
        if p.suffix == ".json":
            data = json.loads(text)
            if isinstance(data, dict):
                data = data.get("latencies")
            if not isinstance(data, list):
                raise ValueError("expected a list of seconds or {'latencies': [...]}")
            values = [float(v) for v in data]
        else:
            rows = [r for r in csv.reader(text.splitlines()) if r and r[0].strip()]
            col = 0
            if rows and rows[0][0].strip().lower().startswith(("latency", "t", "#")):
                header = [c.strip().lower() for c in rows.pop(0)]
                col = header.index("latency") if "latency" in header else 0
            values = [float(r[col]) for r in rows]
    except (ValueError, TypeError, IndexError, json.JSONDecodeError, csv.Error) as exc:
        raise BadInputError(f"[timing] replay: {p} is not a latency list: {exc}") from exc
    arr = np.asarray(values, dtype=float)
    if arr.size == 0 or not np.all(np.isfinite(arr)) or np.any(arr < 0):
        raise BadInputError(f"[timing] replay: {p} needs at least one finite latency >= 0 seconds")
    if np.any(arr > REPLAY_MAX):
        raise BadInputError(
            f"[timing] replay: {p} holds a latency above {REPLAY_MAX:g} s ({arr.max():g})"
        )
    return arr


def split_path(spec: str | Path) -> tuple[Path, str | None]:
    head, sep, which = str(spec).rpartition("::")
    return (Path(head), which or None) if sep else (Path(which), None)


def is_run_source(spec: str | Path) -> bool:
    p, _ = split_path(spec)
    return p.is_dir() or p.suffix == ".mcap"


def write_latency_file(seconds: np.ndarray, out: Path, source: str | Path) -> Path:
    """Latencies read from a run (``source`` names it) as a JSON latency list the simulator's
    replay hook reads."""
    out.write_text(json.dumps({"latencies": seconds.tolist(), "source": str(source)}))
    return out
