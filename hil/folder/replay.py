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
from pathlib import Path

import numpy as np

from hil.analysis.measure.folder import measure_folder, measure_recording, measured
from hil.errors import BadInputError
from hil.folder import load_folder
from hil.folder.layout import SUMMARY

REPLAY_MAX = 1e6  # s, the largest latency a replay file may hold (as [timing] delay)


def jitter_samples_from(path: str | Path) -> np.ndarray:
    """Latencies in seconds from a JSON list (or an object with a ``latencies`` list), a CSV
    with a ``latency`` column, one number per line, or a real run (:func:`latencies_from_run`)."""
    if is_run_source(path):
        return latencies_from_run(path)
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


def latencies_from_run(spec: str | Path) -> np.ndarray:
    """Measured sample-to-apply latencies (seconds) of a run folder (its saved measurement, else
    its hop logs measured) or recording."""
    p, which = split_path(spec)
    try:
        if p.is_dir():
            m = measured(load_folder(p, lazy=True)) if (p / SUMMARY).is_file() else None
            m = m if m is not None else measure_folder(p)
            where = "hop logs (controller.hoplog, plant.hoplog)"
        elif p.suffix == ".mcap" and p.is_file():
            m, where = measure_recording(p), "attached hop logs"
        else:
            raise BadInputError(f"{p} is neither a run folder nor a .mcap recording")
        if m is None:
            raise BadInputError(f"{p} has no {where}: not a run of hil run")
        per_path = m.latency_us()  # µs per path
    except BadInputError as exc:  # named once as the key it comes from
        text = str(exc).removeprefix("[timing] replay: ")
        raise BadInputError(f"[timing] replay: {text}") from exc
    except Exception as exc:  # a damaged folder or recording: whatever its reader raised
        raise BadInputError(
            f"[timing] replay: cannot read latencies from {p}: {type(exc).__name__}: {exc}"
        ) from exc
    if which is not None:
        if which not in per_path:
            raise BadInputError(
                f"[timing] replay: {p} has no latencies of path {which!r} "
                f"(has: {', '.join(sorted(per_path)) or 'none'})"
            )
        per_path = {which: per_path[which]}
    values = [v for v in per_path.values() if v.size]
    if not values:
        raise BadInputError(f"[timing] replay: no latency samples found in {p}")
    seconds = np.concatenate(values) * 1e-6  # µs to s
    seconds = seconds[np.isfinite(seconds) & (seconds >= 0)]
    if seconds.size == 0:
        raise BadInputError(f"[timing] replay: {p} holds no finite latency >= 0")
    return seconds


def write_latency_file(seconds: np.ndarray, out: Path, source: str | Path) -> Path:
    """Latencies read from a run (``source`` names it) as a JSON latency list the simulator's
    replay hook reads."""
    out.write_text(json.dumps({"latencies": seconds.tolist(), "source": str(source)}))
    return out
