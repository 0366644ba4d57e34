"""A hop log (:mod:`protocol.hoplog`) of a run folder read into numpy columns: the one reader
of the services' hop logs by column, for the analysis (:mod:`hil.analysis.measure.logs` joins
the two logs of a run) and for the bench's repair (:mod:`hil.bench.repair`).

Read chunk by chunk straight into compact numpy columns (only the columns asked for; small
integers in small types), so an hour's run at 1 kHz fits in a few hundred MB and is read in
linear time; a log truncated by a kill is read to its last whole record.
"""

from __future__ import annotations

from array import array
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from protocol.hoplog import HOST_TABLES, HopLogError, header_tables, iter_records

_F8, _F4, _I8, _I4, _I2, _I1 = np.float64, np.float32, np.int64, np.int32, np.int16, np.int8
# The columns read, with their types (every stamp int64: nanoseconds, exact). Sequence numbers
# (NARROW) are int32 in memory when a chunk's values fit, int64 otherwise (numpy promotes on
# concatenation). A CAN frame's torque is float32: that is what the frame carries.
COLUMNS: dict[str, dict[str, Any]] = {
    "ticks": {
        "k": _I8, "deadline_ns": _I8, "wake_ns": _I8, "skipped": _I4, "state_seq": _I8,
        "state_sample_ns": _I8, "state_send_ns": _I8, "state_recv_ns": _I8,
        "compute_start_ns": _I8, "compute_end_ns": _I8, "zenoh_send_ns": _I8,
        "can_send_ns": _I8, "cmd_seq": _I8, "tau1": _F8, "tau2": _F8, "flags": _I4,
    },
    "state_rx": {"seq": _I8, "sample_ns": _I8, "send_ns": _I8, "recv_ns": _I8},
    "can_tx": {"node": _I2, "send_ns": _I8, "cmd_seq": _I8, "value": _F4, "bus_end_ns": _I8},
    "samples": {
        "seq": _I8, "sample_ns": _I8, "wake_ns": _I8, "send_ns": _I8, "x": _F8, "y": _F8,
        "theta": _F8, "v": _F8, "omega": _F8, "tau1": _F8, "tau2": _F8, "cmd1": _F8,
        "cmd2": _F8, "flags": _I1,
    },
    # tau1, tau2 as sent (a Zenoh command's float64; a CAN frame's float32 is exact in it):
    # the torques a device asked are judged against the limits of (2) at their own precision.
    "cmd_rx": {"path": _I1, "seq": _I8, "recv_ns": _I8, "node": _I2, "verdict": _I1,
               "tau1": _F8, "tau2": _F8, "send_ns": _I8, "state_sample_ns": _I8,
               "state_seq": _I8},
    "enc_tx": {"node": _I2, "sample_ns": _I8, "send_ns": _I8},
    "apply": {"path": _I1, "seq": _I8, "node": _I2, "recv_ns": _I8, "apply_ns": _I8,
              "outcome": _I1},
    "zero": {"timeout_ns": _I8, "applied_ns": _I8},
    "socket_drops": {"since_ns": _I8, "seen_ns": _I8, "dropped": _I8},
    "drive_events": {"node": _I2, "time_ns": _I8, "event": _I1, "detail": _I8},
    "host": {c: _I8 for c in HOST_TABLES["host"]},
}  # fmt: skip
NARROW = {"k", "skipped", "state_seq", "cmd_seq", "seq"}
# Each column grows in one typed buffer (array.array: amortized in place, C conversion of the
# msgpack values) and becomes a numpy array without a copy. Per-chunk numpy arrays concatenated
# at the end left ~400 MB of freed small blocks in the heap after an hour's log.
_TYPECODE = {_F8: "d", _F4: "f", _I8: "q", _I4: "i", _I2: "h", _I1: "b"}


def column(buf: array | None, name: str, dtype: Any) -> np.ndarray:
    """The column as numpy (a view of ``buf``, empty without it); sequence numbers int32 when
    they fit."""
    if buf is None:
        return np.zeros(0, np.int32 if name in NARROW else dtype)
    a = np.frombuffer(buf, dtype=np.int64 if name in NARROW else dtype)
    if name in NARROW and (a.size == 0 or (int(a.min()) >= -(2**31) and int(a.max()) < 2**31)):
        return a.astype(np.int32)
    return a


#: A service's own JSON in its hop log (header meta, counters, footer): written by
#: controller_service and plant_emulator under protocol's log version, read key by key
#: (docs/architecture.md, "Free-form records").
ServiceFacts = dict[str, Any]


@dataclass
class LogHead:
    """A hop log's non-row parts: meta (header, merged with later meta records), the newest
    counters, the footer, and whether the service exited cleanly."""

    meta: ServiceFacts = field(default_factory=dict)
    counters: ServiceFacts = field(default_factory=dict)
    final: ServiceFacts | None = None
    complete: bool = False
    truncated: bool = False
    restarts: int = 0

    @property
    def info(self) -> ServiceFacts:
        return self.final if self.final is not None else self.counters


def read_columns(
    path: str | Path, tables: dict[str, tuple[str, ...]]
) -> tuple[LogHead, dict[str, dict[str, np.ndarray]]]:
    """One hop log, chunk by chunk, into numpy columns: ``tables`` maps each table to read to
    the columns wanted (every one of them is in the result, empty when the log lacks it)."""
    head = LogHead()
    parts: dict[str, dict[str, array]] = {}
    index: dict[str, dict[str, int]] = {}
    fields: dict[str, list[str]] | None = None
    end = 0
    size = Path(path).stat().st_size
    for rec, offset in iter_records(path):
        end = offset
        kind = rec.get("r")
        if kind == "header":
            got = header_tables(rec, path)
            if fields is not None:  # a restarted service continued the log
                if got != fields:
                    raise HopLogError(f"{path}: a restart changed the tables")
                head.restarts += 1
                head.complete = False
                head.meta.update({k: v for k, v in (rec.get("meta") or {}).items() if v})
                continue
            fields = got
            head.meta = dict(rec.get("meta") or {})
            for name in tables:
                cols = fields.get(name, [])
                index[name] = {c: cols.index(c) for c in tables[name] if c in cols}
                parts[name] = {
                    c: array("q" if c in NARROW else _TYPECODE[COLUMNS[name][c]])
                    for c in index[name]
                }
        elif fields is None:
            continue
        elif kind == "rows" and rec.get("table") in parts:
            name = rec["table"]
            width = len(fields[name])
            try:  # strict: every row as long as the first (one C loop, no Python-level check)
                columns = list(zip(*rec["rows"], strict=True))
            except ValueError:
                columns = []
            if rec["rows"] and len(columns) != width:
                raise HopLogError(f"{path}: a row of table {name} has not {width} fields")
            for c, i in index[name].items():
                try:
                    parts[name][c].extend(columns[i])
                except (TypeError, OverflowError) as exc:
                    raise HopLogError(f"{path}: table {name} column {c}: {exc}") from None
        elif kind == "meta":
            head.meta.update(rec.get("meta") or {})
        elif kind == "counters":
            head.counters = dict(rec.get("counters") or {})
        elif kind == "footer":
            head.final = dict(rec.get("final") or {})
            head.complete = True
    if fields is None:
        raise HopLogError(f"{path}: no hop-log header")
    head.truncated = end < size
    return head, {
        name: {c: column(parts.get(name, {}).pop(c, None), c, COLUMNS[name][c]) for c in wanted}
        for name, wanted in tables.items()
    }
