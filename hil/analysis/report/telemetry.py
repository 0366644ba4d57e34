"""The controller's telemetry out of a run's recording (``*.mcap``): v~ and w~ of (10) for the
quasi-sliding bands when trace.csv lacks them (a run's trace holds the plant's samples, not the
law's internals), and the law's memory (z1, z2, eta) from which a long run's windowed ideal
restarts (:mod:`hil.analysis.report.ideal_sim`). Never a timing figure: those are
hil.analysis.measure's.

Only the telemetry topics are read (:func:`hil.folder.recording.read_topic_payloads`), decoded a
batch at a time into numpy columns: an hour's recording costs seconds and a few arrays of its
length.
"""

from __future__ import annotations

import json
from array import array
from collections.abc import Iterable
from contextlib import suppress
from pathlib import Path
from typing import Any

import numpy as np
import orjson

from hil.folder.recording import list_topics, read_topic_payloads

#: The telemetry read, in groups whose values a message carries together: the sliding
#: variables, and the unified law's memory.
SLIDING = ("v_tilde", "w_tilde")
MEMORY = ("eta", "z1", "z2")
_BATCH = 4096


def _decode(payloads: list[bytes]) -> list[Any]:
    """The payloads decoded, one value each (None: not JSON): by orjson (an hour's telemetry is
    millions of messages), else the standard library (NaN, integers beyond 64 bits)."""
    try:
        return orjson.loads(b"[" + b",".join(payloads) + b"]")
    except ValueError:  # decode one by one, keeping the others in place
        return [_one(p) for p in payloads]


def _one(payload: bytes) -> Any:
    with suppress(ValueError):
        return orjson.loads(payload)
    with suppress(ValueError):
        return json.loads(payload)
    return None


#: JSON's numbers, by exact type: decoded JSON holds no subclasses, and bool is not one of them.
_PLAIN = frozenset((int, float))


def recorded_telemetry(
    paths: Iterable[Path], groups: tuple[tuple[str, ...], ...] = (SLIDING, MEMORY)
) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Telemetry values of the controller: name -> (time_ns, values), sorted by time. A
    message gives the values of a group when it carries every name of the group as a number
    (the time is its ``time_ns``, else its log time). Telemetry may be decimated; a truncated
    recording gives what was read."""
    times = [array("q") for _ in groups]
    vals = [[array("d") for _ in g] for g in groups]

    def take(batch: list[tuple[int, bytes]]) -> None:
        decoded = _decode([p for _, p in batch])
        dicts = [d if type(d) is dict else {} for d in decoded]
        when = [d.get("time_ns", t) for d, (t, _) in zip(dicts, batch, strict=True)]
        whole = set(map(type, when)) <= {int}  # times: integers only, for array('q')
        for g, names in enumerate(groups):
            cols = [[d.get(k) for d in dicts] for k in names]
            if whole and all(set(map(type, col)) <= _PLAIN for col in cols):
                times[g].extend(when)  # every message carries the group: whole columns
                for out, col in zip(vals[g], cols, strict=True):
                    out.extend(col)
                continue
            for i, tw in enumerate(when):  # some do not: message by message
                row = [col[i] for col in cols]
                if type(tw) in _PLAIN and all(type(v) in _PLAIN for v in row):
                    times[g].append(int(tw))
                    for out, v in zip(vals[g], row, strict=True):
                        out.append(v)

    for path in paths:
        batch: list[tuple[int, bytes]] = []
        with suppress(Exception):  # a truncated or damaged recording: keep what was read
            topics = [name for name in list_topics(path) if name.endswith("telemetry")]
            for _topic, log_time, payload in read_topic_payloads(path, topics):
                batch.append((log_time, payload))
                if len(batch) >= _BATCH:
                    take(batch)
                    batch = []
        take(batch)
    out = {}
    for g, names in enumerate(groups):
        if not times[g]:
            continue
        tn = np.frombuffer(times[g], dtype=np.int64)
        columns = [np.frombuffer(col, dtype=np.float64) for col in vals[g]]
        if tn.size > 1 and not np.all(tn[1:] >= tn[:-1]):
            # Recordings are written in time order, so this is rare; sorted copies otherwise
            # (an hour's sorted telemetry would double the report's largest arrays).
            order = np.argsort(tn, kind="stable")
            tn, columns = tn[order], [c[order] for c in columns]
        out.update({k: (tn, col) for k, col in zip(names, columns, strict=True)})
    return out


def folder_telemetry(folder: Any) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """:func:`recorded_telemetry` of a loaded folder's recordings, read once per folder (the
    bands and the windowed ideal both use it)."""
    if "telemetry" not in folder.cache:
        folder.cache["telemetry"] = recorded_telemetry(folder.recordings)
    return folder.cache["telemetry"]


def forget_memory(folder: Any) -> None:
    """Drop the law's memory from a folder's cached telemetry: the windowed ideal, its only
    reader, is done, and an hour's three columns and times (~115 MB) would stay otherwise."""
    for name in MEMORY:
        folder.cache.get("telemetry", {}).pop(name, None)


def sliding_from_recordings(paths: Iterable[Path]) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """:func:`recorded_telemetry`'s v~ and w~ of (10) alone."""
    return recorded_telemetry(paths, (SLIDING,))
