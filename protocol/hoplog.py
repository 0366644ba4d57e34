"""Hop logs: the services' time stamps, streamed to disk in chunks, readable after a crash.

Both services log every event that a timing figure is made of (docs/realtime.md, "Timing
figures"): the controller its ticks, State arrivals and CAN sends; the plant its samples and
command arrivals. The figures are computed afterwards from these logs alone, by one module
(:mod:`hil.measure`), so the log is the single source of every timing number of a run.

File format (``*.hoplog``): a stream of msgpack maps, appended and flushed as the run goes:

- ``{"r": "header", "format": "hil-hoplog", "version": 1, "role": ..., "tables": {name:
  [field, ...]}, "meta": {...}}`` once, first;
- ``{"r": "rows", "table": name, "rows": [[...], ...]}``: a chunk of rows of one table, in
  the order they happened;
- ``{"r": "meta", "meta": {...}}``: meta learnt later (the run's epoch), merged into the
  header's;
- ``{"r": "counters", "time_ns": ..., "counters": {...}}``: a snapshot of the service's
  counters (the newest one wins);
- ``{"r": "footer", "final": {...}}`` once, last, when the service exits cleanly.

A service restarted after a crash (its log has no footer) continues the same file: a second
header follows (``restart`` counts them) and the rows go on in time order; a reader merges the
parts (:func:`crashed_log`, :func:`read_hoplog`).

A background thread writes a chunk at least every ``flush_interval`` seconds (default 0.1 s),
so a killed service loses at most that much; a reader stops at a truncated last record and
reports ``complete = False``. The loop thread only builds a row (a NamedTuple: about a
microsecond with keyword arguments) and appends it to a list (no I/O, no packing).
"""

from __future__ import annotations

import contextlib
import os
import threading
import time
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from enum import IntEnum
from pathlib import Path
from typing import Any, NamedTuple

import msgpack

FORMAT = "hil-hoplog"
VERSION = 1
SUFFIX = ".hoplog"
# Beside the hop logs in the run folder: the controller service writes this file when the law
# fails (one controller_service.laws.guard.LawFault record as JSON, traceback included) and
# then exits with LAW_FAULT_EXIT; hil reads the file into summary.json's ``law_fault``.
LAW_FAULT_FILE = "law_fault.json"
LAW_FAULT_EXIT = 5
# The names of the files the services write into the run folder (hil.folder.layout re-exports
# them): each service's hop log, and the controller's clock probe (runtime.clocksync).
CONTROLLER_HOPLOG = "controller" + SUFFIX
PLANT_HOPLOG = "plant" + SUFFIX
CLOCK_FILE = "clock-controller.csv"

# The tables each service writes (docs/realtime.md defines every stamp; one host, one
# CLOCK_MONOTONIC, nanoseconds): one NamedTuple per table, whose fields name the columns (the
# header's ``tables`` are their ``_fields``). A row packs as a msgpack array and an IntEnum as
# its int, so the file format is that of positional tuples, and logs written before the row
# types read the same.
#
# Sentinels: a column that has no value for a row holds one of these.
NO_SEQ = -1  # no sequence number: a tick that sent nothing, a lifecycle zero's cmd_seq, a CAN
# arrival's state_seq
NO_NODE = -1  # no CAN node: a Zenoh command
NO_STAMP = 0  # no time stamp: unknown, or the event never happened (a failed send)

# Flags of a tick row beyond protocol.messages' command flags:
TICK_NO_SEND = 1 << 8  # the tick found no fresh state and sent nothing (the last command stands)
TICK_DROPPED = 1 << 9  # the command was computed but not published: a [faults] drop
TICK_DUPLICATED = 1 << 10  # published twice: a [faults] duplicate
TICK_REORDERED = 1 << 11  # published after the next command: a [faults] reorder
SAMPLE_DROPPED = 1  # a plant sample whose State was not published: a [faults] drop
SAMPLE_DUPLICATED = 2  # a State published twice: a [faults] duplicate
SAMPLE_FEEDBACK_LOST = 4  # a State lost on the feedback path: a [faults] feedback_loss


class CmdPath(IntEnum):
    """The path a command took to the plant (cmd_rx.path, apply.path)."""

    ZENOH = 0  # a TorqueCommand message
    CAN = 1  # Set_Input_Torque frames through the drives


class ApplyOutcome(IntEnum):
    """What became of a command on the applied path (apply.outcome)."""

    LANDED = 0  # in force from apply_ns
    OVERTAKEN = 1  # a newer command was already in force: dropped
    BURST = 2  # landed, late by a [faults] delay burst
    REFUSED = 3  # refused by the drive (non-finite, short, disarmed): the torque in force
    # stays, it is no landing


class RxVerdict(IntEnum):
    """What the receiver made of an arrival (state_rx.verdict, cmd_rx.verdict)."""

    ACCEPTED = 0  # fresh: newer than every number seen
    DUPLICATE = 1  # seen before
    OLDER = 2  # older than one already seen
    LOST_BY_FAULT = 3  # a CAN frame the drive's receiver lost ([faults] frame loss)


# Tables of the controller.
class TickRow(NamedTuple):
    """One wake-up (periodic) or one fresh state (on_state, lockstep): k is the slot the tick
    was due for and deadline_ns that slot's deadline (never re-based). A tick that sent nothing
    (``TICK_NO_SEND``) has state_seq and cmd_seq NO_SEQ and no stamps."""

    k: int
    deadline_ns: int
    wake_ns: int
    skipped: int
    state_seq: int
    state_sample_ns: int
    state_send_ns: int
    state_recv_ns: int
    compute_start_ns: int
    compute_end_ns: int
    zenoh_send_ns: int
    can_send_ns: int
    cmd_seq: int
    tau1: float
    tau2: float
    flags: int


class StateRxRow(NamedTuple):
    """Every State of this robot that decoded, fresh or not (verdict: ACCEPTED, DUPLICATE,
    OLDER)."""

    seq: int
    sample_ns: int
    send_ns: int
    recv_ns: int
    verdict: RxVerdict


class CanTxRow(NamedTuple):
    """Every Set_Input_Torque frame sent, per node in bus order. cmd_seq NO_SEQ: a lifecycle
    zero; send_ns NO_STAMP: the send failed (bus-off, injected or real), the frame never
    reached the bus; value: the frame's Input_Torque (float32, N·m), which the matching of
    arrivals checks; bus_end_ns: the bus's own name for the frame when it has one (zenoh_can:
    the modelled end of transmission, which the receiver sees too), else NO_STAMP."""

    node: int
    send_ns: int
    cmd_seq: int
    value: float
    bus_end_ns: int


# Tables of the plant.
class SampleRow(NamedTuple):
    """One sensor sample: sample_ns is the slot's deadline (the sample time on the epoch's
    grid), wake_ns when the plant woke for it, send_ns when State left; the robot's state,
    the torque acting and the command held."""

    seq: int
    sample_ns: int
    wake_ns: int
    send_ns: int
    x: float
    y: float
    theta: float
    v: float
    omega: float
    tau1: float
    tau2: float
    cmd1: float
    cmd2: float
    flags: int


class CmdRxRow(NamedTuple):
    """Every command arrival on either path. For CAN, seq is the frame's index among the node's
    Set_Input_Torque frames (matched to the controller's can_tx in per-node order), tau1 is the
    frame's Input_Torque (N·m, the motor's), send_ns the bus's name for the frame when it has
    one (zenoh_can: can_tx.bus_end_ns) else NO_STAMP, and state_seq/state_sample_ns are
    unknown (NO_SEQ/NO_STAMP). A Zenoh arrival is logged before the tracker sees it
    (ACCEPTED); a CAN one may be LOST_BY_FAULT."""

    path: CmdPath
    seq: int
    state_seq: int
    state_sample_ns: int
    compute_start_ns: int
    send_ns: int
    recv_ns: int
    tau1: float
    tau2: float
    node: int
    verdict: RxVerdict


class EncTxRow(NamedTuple):
    """Every Get_Encoder_Estimates frame the virtual drives put on the bus (cyclic, or the
    answer to a request): its node, ``sample_ns`` when its content was taken (the drives'
    feedback brought up to that time: the frame's entry into the path toward the device) and
    ``send_ns`` when it was handed to the bus (later by a ``[faults] feedback_*`` hold)."""

    node: int
    sample_ns: int
    send_ns: int


class ApplyRow(NamedTuple):
    """Every landing on the applied path, in time order (node NO_NODE on Zenoh)."""

    path: CmdPath
    seq: int
    node: int
    recv_ns: int
    apply_ns: int
    tau1: float
    tau2: float
    outcome: ApplyOutcome


class ZeroRow(NamedTuple):
    """The command timeout: when it fired and when the zero torque was in force on the wall
    clock."""

    timeout_ns: int
    applied_ns: int


class DriveEvent(IntEnum):
    """What a virtual drive did (drive_events.event)."""

    ARMED = 0  # closed loop entered
    DISARMED = 1  # left closed loop; detail: the ODrive error bits latched
    CLEAR_ERRORS = 2
    STATE_REQUEST = 3  # detail: the axis state asked
    INPUT_WHILE_DISARMED = 4  # the first input refused after a disarm: the device kept on


class DriveEventRow(NamedTuple):
    """What a virtual drive did, when (the drives' CLOCK_MONOTONIC, ns)."""

    node: int
    time_ns: int
    event: DriveEvent
    detail: int


class SocketDropRow(NamedTuple):
    """Frames the plant's own receiving socket (the virtual drives' CAN bus) dropped because
    its queue was full: the kernel's count of the socket's drops (what ``SO_RXQ_OVFL``
    reports, protocol.can.rx_queue) rose by ``dropped`` between two reads, ``since_ns`` stamped
    just before the first and ``seen_ns`` just after the second: the frames were dropped in
    between. A loss of the bench's, not the wire's."""

    since_ns: int
    seen_ns: int
    dropped: int


class HostRow(NamedTuple):
    """What the bench's host did (written by ``hil run``, every 0.1 s): CPU time in clock ticks
    since boot, all CPUs together (/proc/stat: total, idle + iowait, steal: time the hypervisor
    gave to another guest), runnable tasks (/proc/loadavg), and the CPU time (utime + stime) of
    the plant, the controller and ``hil run`` itself (the recorder) from /proc/PID/stat, and the
    ns the plant's and the controller's main threads waited runnable for a CPU
    (/proc/PID/schedstat: a stopped or blocked process waits on no run queue). ``time_ns`` is
    stamped before the counters are read, ``read_ns`` after (absent from logs written before
    it): on a loaded host the sampler can be preempted between the two, and a stretch's figures
    must come from counters read before it began and after it ended."""

    time_ns: int
    cpu_total: int
    cpu_idle: int
    cpu_steal: int
    runnable: int
    plant_cpu: int
    controller_cpu: int
    recorder_cpu: int
    plant_wait_ns: int
    controller_wait_ns: int
    read_ns: int


CONTROLLER_TABLES: dict[str, tuple[str, ...]] = {
    "ticks": TickRow._fields,
    "state_rx": StateRxRow._fields,
    "can_tx": CanTxRow._fields,
}
PLANT_TABLES: dict[str, tuple[str, ...]] = {
    "samples": SampleRow._fields,
    "cmd_rx": CmdRxRow._fields,
    "enc_tx": EncTxRow._fields,  # absent from logs written before it: read as empty
    "apply": ApplyRow._fields,
    "zero": ZeroRow._fields,
    "socket_drops": SocketDropRow._fields,
    "drive_events": DriveEventRow._fields,
}
HOST_TABLES: dict[str, tuple[str, ...]] = {"host": HostRow._fields}


class HopLogWriter:
    """Append rows to named tables; a writer thread streams them to ``path`` in chunks."""

    def __init__(
        self,
        path: str | Path,
        role: str,
        tables: Mapping[str, Sequence[str]],
        meta: Mapping[str, Any] | None = None,
        flush_interval: float = 0.1,
        append: bool = False,
    ) -> None:
        self.path = Path(path)
        self.role = role
        self.fields = {name: list(cols) for name, cols in tables.items()}
        self._pending: dict[str, list[Any]] = {name: [] for name in self.fields}
        self._counters: dict[str, Any] | None = None
        self._interval = float(flush_interval)
        self._lock = threading.Lock()  # serialises file writes (thread and close)
        self._stop = threading.Event()
        self._closed = False
        self.rows_written = 0
        self.bytes_written = 0
        self.path.parent.mkdir(parents=True, exist_ok=True)
        mode = os.O_APPEND if append else os.O_TRUNC
        self._fd = os.open(self.path, os.O_WRONLY | os.O_CREAT | mode, 0o644)
        self._write(
            {
                "r": "header",
                "format": FORMAT,
                "version": VERSION,
                "role": role,
                "tables": self.fields,
                "meta": dict(meta or {}),
                "restart": bool(append),
            }
        )
        self._thread = threading.Thread(target=self._run, name=f"hoplog-{role}", daemon=True)
        self._thread.start()

    # --- the loop thread's side: cheap ---------------------------------------------------
    def append(self, table: str, row: Sequence[Any]) -> None:
        self._pending[table].append(row)

    def update_meta(self, meta: Mapping[str, Any]) -> None:
        """Meta learnt after the header (the epoch): written at once, merged when read."""
        self._write({"r": "meta", "meta": dict(meta)})

    def counters(self, counters: Mapping[str, Any]) -> None:
        """The newest counter snapshot; written with the next chunk."""
        self._counters = dict(counters)

    # --- the writer's side -----------------------------------------------------------------
    def _write(self, record: Mapping[str, Any]) -> None:
        data = msgpack.packb(record, use_bin_type=True)
        with self._lock:
            if self._fd < 0:
                return
            view = memoryview(data)
            while view:
                n = os.write(self._fd, view)
                view = view[n:]
            self.bytes_written += len(data)

    def flush(self) -> None:
        """Write every pending row (and the newest counters) now."""
        for name in self.fields:
            # Swapping the list is atomic under the GIL: the loop keeps appending to the new one.
            rows, self._pending[name] = self._pending[name], []
            if rows:
                self._write({"r": "rows", "table": name, "rows": rows})
                self.rows_written += len(rows)
        counters, self._counters = self._counters, None
        if counters is not None:
            self._write({"r": "counters", "time_ns": time.monotonic_ns(), "counters": counters})

    def _run(self) -> None:
        while not self._stop.wait(self._interval):
            with contextlib.suppress(OSError):
                self.flush()

    def close(self, final: Mapping[str, Any] | None = None) -> None:
        """Flush, write the footer (a clean exit) and close. Safe to call twice."""
        if self._closed:
            return
        self._closed = True
        self._stop.set()
        self._thread.join(timeout=2.0)
        self.flush()
        self._write({"r": "footer", "final": dict(final or {})})
        with self._lock:
            os.close(self._fd)
            self._fd = -1


@dataclass
class HopLog:
    """A hop log read back: rows per table (lists of tuples), meta, counters, final."""

    path: Path
    role: str = ""
    meta: dict[str, Any] = field(default_factory=dict)
    fields: dict[str, list[str]] = field(default_factory=dict)
    rows: dict[str, list[list[Any]]] = field(default_factory=dict)
    counters: dict[str, Any] = field(default_factory=dict)
    final: dict[str, Any] | None = None
    complete: bool = False  # the footer was read: the service exited cleanly
    truncated: bool = False  # the file ends inside a record (a killed writer)
    restarts: int = 0  # processes that continued this log after a crash

    def table(self, name: str) -> list[dict[str, Any]]:
        """Rows of ``name`` as dicts (field name -> value)."""
        names = self.fields.get(name, [])
        return [dict(zip(names, r, strict=False)) for r in self.rows.get(name, [])]

    def columns(self, name: str) -> dict[str, list[Any]]:
        """Rows of ``name`` as columns (field name -> list of values)."""
        names = self.fields.get(name, [])
        rows = self.rows.get(name, [])
        return {n: [r[i] for r in rows] for i, n in enumerate(names)}

    @property
    def info(self) -> dict[str, Any]:
        """The footer's final values, else the newest counters (a crashed service)."""
        return self.final if self.final is not None else self.counters


class HopLogError(ValueError):
    """Not a hop log (wrong magic, version, or no header)."""


def iter_records(path: str | Path) -> Iterator[tuple[dict[str, Any], int]]:
    """Every complete record of a hop log with the file offset where it ends, in order; stops
    quietly at a truncated tail."""
    unpacker = msgpack.Unpacker(raw=False, strict_map_key=False, max_buffer_size=1 << 30)
    with open(path, "rb") as f:
        while True:
            chunk = f.read(1 << 20)
            if not chunk:
                return
            unpacker.feed(chunk)
            for rec in unpacker:
                if isinstance(rec, dict):
                    yield rec, unpacker.tell()


def header_tables(rec: dict, path: str | Path) -> dict[str, list[str]]:
    """The column names per table of a header record, after checking its format and version."""
    if rec.get("format") != FORMAT or rec.get("version") != VERSION:
        raise HopLogError(f"{path}: not a {FORMAT} v{VERSION} file")
    return {k: list(v) for k, v in (rec.get("tables") or {}).items()}


def read_hoplog(path: str | Path) -> HopLog:
    """Read a hop log whole (the newest counters, the footer if any)."""
    path = Path(path)
    log = HopLog(path)
    seen_header = False
    size = path.stat().st_size
    end = 0
    for rec, offset in iter_records(path):
        end = offset
        kind = rec.get("r")
        if kind == "header":
            fields = header_tables(rec, path)
            if seen_header:  # a restarted service continued the log
                if fields != log.fields:
                    raise HopLogError(f"{path}: a restart changed the tables")
                log.restarts += 1
                log.complete = False
                log.meta.update({k: v for k, v in (rec.get("meta") or {}).items() if v})
                continue
            seen_header = True
            log.role = str(rec.get("role", ""))
            log.meta = dict(rec.get("meta") or {})
            log.fields = fields
            log.rows = {k: [] for k in log.fields}
        elif kind == "rows" and seen_header:
            log.rows.setdefault(rec["table"], []).extend(rec["rows"])
        elif kind == "meta" and seen_header:
            log.meta.update(rec.get("meta") or {})
        elif kind == "counters" and seen_header:
            log.counters = dict(rec.get("counters") or {})
        elif kind == "footer" and seen_header:
            log.final = dict(rec.get("final") or {})
            log.complete = True
    if not seen_header:
        raise HopLogError(f"{path}: no hop-log header")
    log.truncated = end < size
    return log


def crashed_log(path: str | Path) -> HopLog | None:
    """The log a crashed predecessor left at ``path`` (a run under way: an epoch, no footer),
    which a restarted service continues; None for no file or a finished log (a new run)."""
    try:
        log = read_hoplog(path)
    except (OSError, ValueError):
        return None
    if log.complete or not log.meta.get("epoch_ns"):
        return None
    return log
