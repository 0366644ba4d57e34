"""The window the virtual drives log for each rise of their socket's drop count
(plant_emulator.can_drives, the hop log's ``socket_drops``): every drop a read counts happened
inside [since_ns, seen_ns]. hil.analysis.measure names a lost frame the bench's only when it
was sent in such a window, so a drop outside it is called lost on the wire (seen: 4 of 178
frames on a loaded host). The thread switch that did it (the GIL handed to the plant's loop
catching up after a 1 s stop) is made here inside the read itself: a known answer, no luck."""

from __future__ import annotations

import itertools
import time

from plant_emulator.can_drives import CanDrives


class _Log:
    def __init__(self) -> None:
        self.rows: list = []

    def append(self, table: str, row) -> None:
        self.rows.append((table, row))


class _SlowCount:
    """The socket's drop count, read by a thread that loses the CPU for ``stall_ns`` before
    the read, during which one more frame is dropped (stamped when it is)."""

    def __init__(self, stall_ns: int) -> None:
        self.count = 0
        self.stall_ns = stall_ns
        self.dropped_at: list[int] = []

    def read(self) -> int:
        until = time.monotonic_ns() + self.stall_ns
        while time.monotonic_ns() < until:
            pass
        self.count += 1
        self.dropped_at.append(time.monotonic_ns())
        return self.count

    def close(self) -> None:
        pass


def test_each_drop_a_read_counts_is_inside_its_window():
    log = _Log()
    drives = CanDrives(bus=object(), pair=object(), hoplog=log)
    slow = _SlowCount(stall_ns=5_000_000)  # 5 ms: 2.5 periods of frames at 500 Hz
    drives._rx_drops, drives.socket_drops, drives._drops_base = slow, 0, 0
    for _ in range(3):  # as the reader does after every receive
        drives._count_drops()
    rows = [row for table, row in log.rows if table == "socket_drops"]
    assert [r.dropped for r in rows] == [1, 1, 1]
    for r, at in zip(rows, slow.dropped_at, strict=True):
        assert r.since_ns <= at <= r.seen_ns, (r, at)
    # Consecutive windows meet or overlap (a drop between two reads is in one of them).
    for a, b in itertools.pairwise(rows):
        assert b.since_ns <= a.seen_ns
