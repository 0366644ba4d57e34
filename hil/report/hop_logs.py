"""Per-sample timing out of a run's hop logs (controller_log.msgpack, plant_log.msgpack).

The run's summary.json keeps only percentiles; the histograms, CDFs and time series of a report
need the samples. The stamps and their meaning are those of :mod:`hil.run.results` (one
monotonic clock, nanoseconds): a plant command row has ``path`` (0 Zenoh, 1 CAN),
``state_sample_ns``, ``recv_ns``, ``apply_ns``, ``applied``; a controller row has ``k``,
``deadline_ns``, ``wake_ns``, ``can_send_ns``, ``state_sample_ns``. The sample-to-apply latency
of a path is apply (or, for the shadow path, receive) minus the sample time, as in the summary.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import msgpack
import numpy as np

from hil.report.timing_data import TimingData

US_PER_NS = 1e-3


def _load(path: Path) -> dict[str, Any] | None:
    try:
        data = msgpack.unpackb(path.read_bytes(), raw=False, strict_map_key=False)
    except (OSError, ValueError, msgpack.UnpackException):
        return None
    return data if isinstance(data, dict) else None


def _rows(log: dict[str, Any] | None, rows_key: str, fields_key: str) -> list[dict[str, Any]]:
    if not log or rows_key not in log or fields_key not in log:
        return []
    names = log[fields_key]
    return [dict(zip(names, r, strict=False)) for r in log[rows_key]]


def from_hop_logs(folder: Path) -> TimingData:
    out = TimingData()
    clog = _load(folder / "controller_log.msgpack")
    plog = _load(folder / "plant_log.msgpack")
    if clog is None and plog is None:
        return out
    epoch = int((plog or clog or {}).get("epoch_ns", 0) or 0)
    crow = _rows(clog, "rows", "fields")
    cmds = _rows(plog, "commands", "cmd_fields")
    zen = [c for c in cmds if c.get("path") == 0 and c.get("state_sample_ns", 0) > 0]
    if zen:
        out.latency["zenoh"] = (
            np.array(
                [
                    (c["apply_ns"] if c["applied"] else c["recv_ns"]) - c["state_sample_ns"]
                    for c in zen
                ],
                dtype=float,
            )
            * US_PER_NS
        )
    # CAN frames are plain CANSimple (no sequence number): arrivals are matched in order to the
    # controller's CAN sends, after the arming frames, exactly as hil.run.results does.
    can_sends = [r for r in crow if r.get("can_send_ns", 0) > 0]
    arm = int(((clog or {}).get("can") or {}).get("arm_sends", 0))
    can_lat = []
    for c in (c for c in cmds if c.get("path") == 1):
        i = c["seq"] - arm
        if 0 <= i < len(can_sends) and can_sends[i]["state_sample_ns"] > 0:
            end = c["apply_ns"] if c["applied"] else c["recv_ns"]
            can_lat.append(end - can_sends[i]["state_sample_ns"])
    if can_lat:
        out.latency["can"] = np.asarray(can_lat, dtype=float) * US_PER_NS
    ticks = (
        [r for r in crow if r.get("k", -1) >= 0]
        if (clog or {}).get("trigger") == "periodic"
        else []
    )
    if ticks:
        wake = np.array([r["wake_ns"] for r in ticks], dtype=np.int64)
        deadline = np.array([r["deadline_ns"] for r in ticks], dtype=np.int64)
        t = (deadline - epoch) / 1e9
        out.lateness["wake-up lateness"] = (t, (wake - deadline) * US_PER_NS)
        period = int(clog.get("period_ns", 0) or 0)
        if period > 0 and wake.size > 1:
            out.lateness["period jitter"] = (t[1:], np.abs(np.diff(wake) - period) * US_PER_NS)
    out.source.append("hop logs")
    return out
