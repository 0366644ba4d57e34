"""Replay latencies read from a file or a real run, for ``[timing] jitter_kind = "replay"``.

The draw of each sample's extra delay and its landing step (:func:`extra_delays`,
:func:`landing_offsets`) is :mod:`plant_emulator.landing`'s, shared with the plant in lockstep;
``hil`` reads the replay's latencies here once and hands them to both.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np

from hil.errors import BadInputError
from plant_emulator.landing import extra_delays, landing_offsets

__all__ = ["REPLAY_MAX", "extra_delays", "jitter_samples_from", "landing_offsets"]

REPLAY_MAX = 1e6  # s, the largest latency a replay file may hold (as [timing] delay)


def jitter_samples_from(path: str | Path) -> np.ndarray:
    """Latencies in seconds from a file: a JSON list (or an object with a ``latencies`` list),
    a CSV with a ``latency`` column or one number per line; or, from a real run, its folder or
    ``.mcap`` recording, optionally ``PATH::zenoh`` or ``PATH::can`` for one path's latencies
    (:func:`hil.sweep.replay.latencies_from_run`)."""
    from hil.sweep.replay import is_run_source, latencies_from_run

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
            if rows and rows[0][0].strip().lower().startswith(("latency", "t", "#")):
                header = [c.strip().lower() for c in rows[0]]
                col = header.index("latency") if "latency" in header else 0
                rows = rows[1:]
            else:
                col = 0
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
