"""When sampled commands land at the plant: constant delay plus seeded jitter (or a replay).

Sample k is taken at t_k = k Ts; its command lands at t_k + delay + extra_k, rounded to the plant
step h. extra_k is drawn once per run from ``numpy.random.default_rng(seed)``:
``uniform``: U[0, jitter]; ``normal``: |N(0, jitter)| (a half-normal of scale ``jitter``);
``replay``: the latencies of a file, cycled in order (``jitter`` is ignored, ``delay`` adds).
The draw depends only on (kind, jitter, seed, number of samples), so single and batch runs of
the same seed see the same landing times.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np

from hil.errors import BadInputError

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


def extra_delays(
    kind: str, jitter: float, seed: int, n: int, replay: np.ndarray | None = None
) -> np.ndarray:
    """The extra delay of each of ``n`` samples (seconds)."""
    if kind == "replay":
        if replay is None or replay.size == 0:
            raise BadInputError("[timing] replay: no latencies")
        return np.resize(replay, n).astype(float)
    if jitter <= 0.0:
        return np.zeros(n)
    rng = np.random.default_rng(seed)
    if kind == "uniform":
        return rng.uniform(0.0, jitter, n)
    if kind == "normal":
        return np.abs(rng.normal(0.0, jitter, n))
    raise BadInputError(f"[timing] jitter_kind {kind!r} unknown")


def landing_offsets(delays: np.ndarray, delay: float, h: float) -> np.ndarray:
    """Plant steps from a sample to its command's landing: round((delay + extra) / h)."""
    steps = np.rint((delay + delays) / h)
    return steps.astype(np.int64)
