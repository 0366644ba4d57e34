"""Typed hop-log rows write the same bytes as the positional tuples logs were written with, and
hil.analysis.measure reads both: logs written before the row types read unchanged."""

from __future__ import annotations

from pathlib import Path

import msgpack
import numpy as np

from hil.analysis.measure.logs import ALL_COLUMNS, RunLogs
from protocol.hoplog import (
    CONTROLLER_TABLES,
    HOST_TABLES,
    NO_NODE,
    NO_SEQ,
    NO_STAMP,
    PLANT_TABLES,
    TICK_NO_SEND,
    ApplyOutcome,
    ApplyRow,
    CanTxRow,
    CmdPath,
    CmdRxRow,
    DriveEvent,
    DriveEventRow,
    EncTxRow,
    HopLogWriter,
    HostRow,
    RxVerdict,
    SampleRow,
    StateRxRow,
    TickRow,
    ZeroRow,
    read_hoplog,
)

# The tables as the logs of earlier versions declare them in their headers (written out here,
# not derived from the row types, so a renamed or reordered field fails this file).
OLD_CONTROLLER = {
    "ticks": ["k", "deadline_ns", "wake_ns", "skipped", "state_seq", "state_sample_ns",
              "state_send_ns", "state_recv_ns", "compute_start_ns", "compute_end_ns",
              "zenoh_send_ns", "can_send_ns", "cmd_seq", "tau1", "tau2", "flags"],
    "state_rx": ["seq", "sample_ns", "send_ns", "recv_ns", "verdict"],
    "can_tx": ["node", "send_ns", "cmd_seq", "value", "bus_end_ns"],
}  # fmt: skip
OLD_PLANT = {
    "samples": ["seq", "sample_ns", "wake_ns", "send_ns", "x", "y", "theta", "v", "omega",
                "tau1", "tau2", "cmd1", "cmd2", "flags"],
    "cmd_rx": ["path", "seq", "state_seq", "state_sample_ns", "compute_start_ns", "send_ns",
               "recv_ns", "tau1", "tau2", "node", "verdict"],
    # the encoder estimates the drives sent (a log without it reads as empty: the device's
    # figures, tests/test_device_figures.py)
    "enc_tx": ["node", "sample_ns", "send_ns"],
    "apply": ["path", "seq", "node", "recv_ns", "apply_ns", "tau1", "tau2", "outcome"],
    "zero": ["timeout_ns", "applied_ns"],
    "socket_drops": ["since_ns", "seen_ns", "dropped"],  # the bench's socket drops
    "drive_events": ["node", "time_ns", "event", "detail"],  # what the virtual drives did
}  # fmt: skip
OLD_HOST = {
    "host": ["time_ns", "cpu_total", "cpu_idle", "cpu_steal", "runnable", "plant_cpu",
             "controller_cpu", "recorder_cpu", "plant_wait_ns", "controller_wait_ns"],
}  # fmt: skip
# host logs since the sampler's second stamp: one column appended, the rest unchanged
HOST_SINCE_READ_NS = {"host": [*OLD_HOST["host"], "read_ns"]}

T0 = 1_000_000_000
TYPED_CONTROLLER = [
    ("ticks", TickRow(k=0, deadline_ns=T0, wake_ns=T0 + 20, skipped=0, state_seq=NO_SEQ,
                      state_sample_ns=NO_STAMP, state_send_ns=NO_STAMP, state_recv_ns=NO_STAMP,
                      compute_start_ns=NO_STAMP, compute_end_ns=NO_STAMP,
                      zenoh_send_ns=NO_STAMP, can_send_ns=NO_STAMP, cmd_seq=NO_SEQ, tau1=0.0,
                      tau2=0.0, flags=TICK_NO_SEND)),
    ("ticks", TickRow(k=1, deadline_ns=T0 + 2000, wake_ns=T0 + 2030, skipped=0, state_seq=0,
                      state_sample_ns=T0, state_send_ns=T0 + 300, state_recv_ns=T0 + 400,
                      compute_start_ns=T0 + 2040, compute_end_ns=T0 + 2090,
                      zenoh_send_ns=T0 + 2100, can_send_ns=T0 + 2110, cmd_seq=0, tau1=0.25,
                      tau2=-1.5, flags=0)),
    ("state_rx", StateRxRow(seq=0, sample_ns=T0, send_ns=T0 + 300, recv_ns=T0 + 400,
                            verdict=RxVerdict.ACCEPTED)),
    ("state_rx", StateRxRow(seq=0, sample_ns=T0, send_ns=T0 + 300, recv_ns=T0 + 450,
                            verdict=RxVerdict.DUPLICATE)),
    ("can_tx", CanTxRow(node=1, send_ns=T0 + 2110, cmd_seq=0, value=0.125, bus_end_ns=NO_STAMP)),
    ("can_tx", CanTxRow(node=2, send_ns=NO_STAMP, cmd_seq=NO_SEQ, value=0.0,
                        bus_end_ns=NO_STAMP)),
]  # fmt: skip
TYPED_PLANT = [
    ("samples", SampleRow(seq=0, sample_ns=T0, wake_ns=T0 + 10, send_ns=T0 + 300, x=0.5, y=-0.5,
                          theta=0.3, v=0.0, omega=0.0, tau1=0.0, tau2=0.0, cmd1=0.0, cmd2=0.0,
                          flags=0)),
    ("cmd_rx", CmdRxRow(path=CmdPath.ZENOH, seq=0, state_seq=0, state_sample_ns=T0,
                        compute_start_ns=T0 + 2040, send_ns=T0 + 2100, recv_ns=T0 + 2300,
                        tau1=0.25, tau2=-1.5, node=NO_NODE, verdict=RxVerdict.ACCEPTED)),
    ("cmd_rx", CmdRxRow(path=CmdPath.CAN, seq=3, state_seq=NO_SEQ, state_sample_ns=NO_STAMP,
                        compute_start_ns=NO_STAMP, send_ns=NO_STAMP, recv_ns=T0 + 2400,
                        tau1=0.125, tau2=0.0, node=1, verdict=RxVerdict.LOST_BY_FAULT)),
    ("enc_tx", EncTxRow(node=1, sample_ns=T0 + 1000, send_ns=T0 + 1030)),
    ("apply", ApplyRow(path=CmdPath.ZENOH, seq=0, node=NO_NODE, recv_ns=T0 + 2300,
                       apply_ns=T0 + 2500, tau1=0.25, tau2=-1.5,
                       outcome=ApplyOutcome.LANDED)),
    ("apply", ApplyRow(path=CmdPath.CAN, seq=4, node=2, recv_ns=T0 + 2400, apply_ns=T0 + 2600,
                       tau1=0.0, tau2=0.0, outcome=ApplyOutcome.REFUSED)),
    ("apply", ApplyRow(path=CmdPath.ZENOH, seq=1, node=NO_NODE, recv_ns=T0 + 2700,
                       apply_ns=T0 + 9000, tau1=0.0, tau2=0.0, outcome=ApplyOutcome.BURST)),
    ("zero", ZeroRow(timeout_ns=T0 + 60_000, applied_ns=T0 + 60_100)),
    ("drive_events", DriveEventRow(node=0, time_ns=T0 + 70_000, event=DriveEvent.DISARMED,
                                   detail=0x8000)),
]  # fmt: skip
TYPED_HOST = [
    ("host", HostRow(time_ns=T0, cpu_total=100, cpu_idle=40, cpu_steal=1, runnable=3,
                     plant_cpu=7, controller_cpu=8, recorder_cpu=2, plant_wait_ns=5,
                     controller_wait_ns=6, read_ns=T0 + 40_000)),
]  # fmt: skip


def _untyped(row: tuple) -> tuple:
    """The row as the services appended it before the row types: a plain tuple of plain
    ints and floats (no IntEnum)."""
    return tuple(int(v) if isinstance(v, int) else v for v in row)


def _write(path: Path, role: str, tables: dict, rows: list, untyped: bool) -> Path:
    w = HopLogWriter(path, role, tables, {"epoch_ns": T0}, flush_interval=3600.0)
    for table, row in rows:
        w.append(table, _untyped(row) if untyped else row)
    w.close({"samples": 1})
    return path


def _both(tmp_path: Path, untyped: bool) -> dict[str, Path]:
    d = tmp_path / ("old" if untyped else "typed")
    old = untyped
    return {
        "controller": _write(d / "controller.hoplog", "controller",
                             OLD_CONTROLLER if old else CONTROLLER_TABLES, TYPED_CONTROLLER, old),
        "plant": _write(d / "plant.hoplog", "plant", OLD_PLANT if old else PLANT_TABLES,
                        TYPED_PLANT, old),
        "host": _write(d / "host.hoplog", "host", HOST_SINCE_READ_NS if old else HOST_TABLES,
                       TYPED_HOST, old),
    }  # fmt: skip


def test_row_types_are_the_declared_tables():
    """Each table's columns are its row type's fields, in the order older logs have them."""
    assert {k: list(v) for k, v in CONTROLLER_TABLES.items()} == OLD_CONTROLLER
    assert {k: list(v) for k, v in PLANT_TABLES.items()} == OLD_PLANT
    assert {k: list(v) for k, v in HOST_TABLES.items()} == HOST_SINCE_READ_NS


def test_a_host_log_from_before_read_ns_reads_its_columns_and_no_read_ns(tmp_path):
    """A host log written before the sampler's second stamp (its header without ``read_ns``)
    reads every column it has to its values and ``read_ns`` as empty, which the host figures
    take as "stamped only before the reads" (tests/test_host_figures.py)."""
    (name, row), *_ = TYPED_HOST
    w = HopLogWriter(tmp_path / "host.hoplog", "host", OLD_HOST, {"epoch_ns": T0}, 3600.0)
    w.append(name, _untyped(row)[: len(OLD_HOST["host"])])
    w.close({"samples": 1})
    logs = RunLogs.read(None, None, ALL_COLUMNS, tmp_path / "host.hoplog")
    for c in OLD_HOST["host"]:
        np.testing.assert_array_equal(logs["host"][c], [getattr(row, c)], err_msg=c)
    assert logs["host"]["read_ns"].size == 0


def test_typed_rows_write_the_bytes_of_positional_tuples(tmp_path):
    """A typed row packs as the msgpack array of its values and an IntEnum as its int: the
    file is byte-for-byte the one the positional tuples wrote."""
    typed, old = _both(tmp_path, untyped=False), _both(tmp_path, untyped=True)
    for role in typed:
        assert typed[role].read_bytes() == old[role].read_bytes(), role
    # and the enums are plain msgpack ints on disk
    assert msgpack.packb(ApplyOutcome.REFUSED) == msgpack.packb(3)
    assert msgpack.packb(CmdPath.CAN) == msgpack.packb(1)


def test_measure_reads_typed_and_old_logs_alike(tmp_path):
    """hil.analysis.measure reads every column of both logs to the same values, and the enums
    compare with what it read."""
    runs = {}
    for untyped in (False, True):
        p = _both(tmp_path, untyped)
        runs[untyped] = RunLogs.read(p["controller"], p["plant"], ALL_COLUMNS, p["host"])
    typed, old = runs[False], runs[True]
    for table, cols in ALL_COLUMNS.items():
        for c in cols:
            np.testing.assert_array_equal(typed[table][c], old[table][c], err_msg=f"{table}.{c}")
    rows = {t: [r for name, r in TYPED_CONTROLLER + TYPED_PLANT + TYPED_HOST if name == t]
            for t in ALL_COLUMNS}  # fmt: skip
    for table, cols in ALL_COLUMNS.items():
        for c in cols:
            want = [getattr(r, c) for r in rows[table]]
            np.testing.assert_array_equal(old[table][c], np.asarray(want, old[table][c].dtype))
    ap = old["apply"]
    assert list(ap["outcome"] == ApplyOutcome.REFUSED) == [False, True, False]
    assert list(ap["path"] == CmdPath.CAN) == [False, True, False]
    assert list(old["cmd_rx"]["verdict"] == RxVerdict.LOST_BY_FAULT) == [False, True]
    assert old.complete == {"controller": True, "plant": True}


def test_read_back_rows_rebuild_their_types(tmp_path):
    """A row read back (a list of plain values) is its type again with ``_make``, and the
    enums come back from the ints."""
    p = _both(tmp_path, untyped=True)
    log = read_hoplog(p["plant"])
    got = [ApplyRow._make(r) for r in log.rows["apply"]]
    want = [r for name, r in TYPED_PLANT if name == "apply"]
    assert got == want
    assert [ApplyOutcome(r.outcome) for r in got] == [r.outcome for r in want]
