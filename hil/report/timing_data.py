"""Timing data of a run, wherever the folder keeps it.

Sources, in order: the ``timing`` object of summary.json (percentile summaries, always present
in a run), per-sample columns of trace.csv (``*_latency_us``, ``lateness_us``, ``jitter_us``),
and the recording (``*.mcap``, read through :mod:`hil.recording` by :mod:`hil.report.mcap_timing`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from hil.report.folder import Folder

US = 1e-6


@dataclass
class TimingData:
    latency: dict[str, np.ndarray] = field(default_factory=dict)  # path -> samples in µs
    lateness: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)  # (t s, µs)
    source: list[str] = field(default_factory=list)


def _max_us(figure: object) -> float | None:
    if isinstance(figure, dict):
        value = figure.get("max_us", figure.get("max"))
        if isinstance(value, int | float) and not isinstance(value, bool):
            return float(value)
    return None


def worst_gap_and_delay(folder: Folder, ts: float) -> tuple[float | None, float | None]:
    """The longest gap between applied samples and the worst sample-to-apply latency, in
    seconds, from the run's timing summary (and per-sample data when present)."""
    timing = folder.summary.get("timing") or {}
    gaps: list[float] = []
    wake_gaps: list[float] = []
    delays: list[float] = []
    for name, figure in timing.items() if isinstance(timing, dict) else ():
        m = _max_us(figure)
        if m is None:
            continue
        key = name.lower()
        if "gap" in key or key in ("period", "sample_period", "applied_period"):
            gaps.append(m * US)
        elif "lateness" in key or "wake" in key:
            # A wake-up late by L after an on-time one stretches the gap to Ts + L.
            wake_gaps.append(ts + m * US)
        elif "apply" in key or "latency" in key or "delay" in key:
            delays.append(m * US)
    data = collect(folder)
    for values in data.latency.values():
        if values.size:
            delays.append(float(values.max()) * US)
    # A measured gap between applied samples beats the estimate from wake-up lateness.
    gaps = gaps or wake_gaps
    gap = max(gaps) if gaps else None
    delay = max(delays) if delays else None
    return gap, delay


def collect(folder: Folder) -> TimingData:
    out = TimingData()
    tr = folder.trace
    for name, col in tr.items():
        if name.endswith("_latency_us"):
            finite = col[np.isfinite(col)]
            if finite.size:
                out.latency[name.removesuffix("_latency_us")] = finite
                out.source.append("trace.csv")
        elif name in ("lateness_us", "jitter_us"):
            mask = np.isfinite(col)
            if mask.any():
                out.lateness[name.removesuffix("_us")] = (tr["t"][mask], col[mask])
                out.source.append("trace.csv")
    from hil.report.hop_logs import from_hop_logs

    hop = from_hop_logs(folder.path)
    for k, v in hop.latency.items():
        out.latency.setdefault(k, v)
    for k, v in hop.lateness.items():
        out.lateness.setdefault(k, v)
    out.source.extend(hop.source)
    if folder.recordings and not (out.latency or out.lateness):
        from hil.report.mcap_timing import from_recordings

        rec = from_recordings(folder.recordings)
        for k, v in rec.latency.items():
            out.latency.setdefault(k, v)
        for k, v in rec.lateness.items():
            out.lateness.setdefault(k, v)
        out.source.extend(rec.source)
    out.source = sorted(set(out.source))
    return out


def epoch_ns(folder: Folder) -> int | None:
    """The run's time origin (monotonic ns) from its hop logs, when it has them."""
    from hil.report.hop_logs import _load

    for name in ("plant_log.msgpack", "controller_log.msgpack"):
        log = _load(folder.path / name)
        if log and isinstance(log.get("epoch_ns"), int):
            return int(log["epoch_ns"])
    return None
