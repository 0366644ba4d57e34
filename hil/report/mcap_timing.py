"""Latency and lateness samples out of a run's recording (``*.mcap``, :mod:`hil.recording`).

Each recorded message carries the recorder's receive time (``log_time_ns``) and the sender's
stamp (``publish_time_ns``); messages whose payload holds explicit stamps (``sample_ns`` /
``apply_ns`` and ``lateness_ns``) give the sample-to-apply latency and the wake-up lateness.
Samples are grouped per path: the topic's leading component after the robot id (Zenoh key
expressions) or ``can`` for CAN frames.
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

import numpy as np

from hil.report.timing_data import TimingData

SAMPLE_KEYS = ("sample_ns", "t_sample_ns", "sample_time_ns")
APPLY_KEYS = ("apply_ns", "t_apply_ns", "applied_ns")
LATENESS_KEYS = ("lateness_ns", "wake_lateness_ns")


def _first(d: dict, keys: Iterable[str]) -> int | None:
    for k in keys:
        v = d.get(k)
        if isinstance(v, int | float) and not isinstance(v, bool):
            return int(v)
    return None


def path_of(topic: str) -> str:
    return "can" if "can" in topic.lower().split("/") else "zenoh"


def from_recordings(paths: Iterable[Path]) -> TimingData:
    from hil.recording import read_messages

    lat: dict[str, list[float]] = {}
    late_t: dict[str, list[float]] = {}
    late_v: dict[str, list[float]] = {}
    t0: int | None = None
    out = TimingData()
    for path in paths:
        try:
            messages = list(read_messages(path))
        except Exception as exc:  # a truncated recording still gives the rest of the report
            out.source.append(f"{Path(path).name}: unreadable ({exc})")
            continue
        for m in messages:
            if t0 is None:
                t0 = m.log_time_ns
            data = m.data if isinstance(m.data, dict) else {}
            p = path_of(m.topic)
            s, a = _first(data, SAMPLE_KEYS), _first(data, APPLY_KEYS)
            if s is not None and a is not None:
                lat.setdefault(p, []).append((a - s) / 1000.0)
            late = _first(data, LATENESS_KEYS)
            if late is not None:
                name = f"{p} lateness"
                late_t.setdefault(name, []).append((m.log_time_ns - t0) / 1e9)
                late_v.setdefault(name, []).append(late / 1000.0)
        out.source.append(Path(path).name)
    out.latency = {k: np.asarray(v) for k, v in lat.items()}
    out.lateness = {k: (np.asarray(late_t[k]), np.asarray(late_v[k])) for k in late_v}
    return out


def sliding_from_recordings(paths: Iterable[Path]) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """v~ and w~ of (10) from the controller's telemetry messages: name -> (time_ns, values).
    Telemetry may be decimated; the band is then computed over the recorded samples."""
    from hil.recording import read_messages

    t: list[int] = []
    vt: list[float] = []
    wt: list[float] = []
    for path in paths:
        try:
            for m in read_messages(path):
                d = m.data if isinstance(m.data, dict) else {}
                if not m.topic.endswith("telemetry") or "v_tilde" not in d:
                    continue
                v, w = d.get("v_tilde"), d.get("w_tilde")
                if isinstance(v, int | float) and isinstance(w, int | float):
                    t.append(int(d.get("time_ns", m.log_time_ns)))
                    vt.append(float(v))
                    wt.append(float(w))
        except Exception:  # a truncated recording: keep what was read
            continue
    if not t:
        return {}
    order = np.argsort(np.asarray(t), kind="stable")
    tn = np.asarray(t, dtype=np.int64)[order]
    return {
        "v_tilde": (tn, np.asarray(vt)[order]),
        "w_tilde": (tn, np.asarray(wt)[order]),
    }
