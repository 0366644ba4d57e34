"""A service's tap (:mod:`protocol.tap`): what it sent, and what it refused, for observers.

The service hands every payload it puts on the wire to :meth:`Tap.sent` (an append) and every
payload it refuses to :meth:`Tap.rejected`; it calls :meth:`Tap.flush_if_due` at a quiet point
of its loop (after its own message left, long before the next is due), which puts one batch
every :data:`protocol.tap.TAP_INTERVAL_NS`, and :meth:`Tap.close` when it stops. An entry that
comes after the close (a refusal by a callback still running while the service shuts down) is
put at once, so nothing the service counted is missing from the tap. Observers (``hil run``'s
recorder, the live view) subscribe to the tap instead of the loop's keys.
"""

from __future__ import annotations

import threading
import time
from typing import Any

from protocol.keys import tap_key
from protocol.messages import MAX_MESSAGE_BYTES
from protocol.tap import (
    MAX_BATCH_BYTES,
    MAX_BATCH_ENTRIES,
    TAP_INTERVAL_NS,
    TapEntry,
    encode_batch,
)

# Room for the batch's header and each entry's framing within MAX_BATCH_BYTES.
_ENTRY_OVERHEAD = 32
_BATCH_ROOM = MAX_BATCH_BYTES - 1024


class Tap:
    """Collects a service's entries and puts them as batches on ``hil/<robot_id>/tap/<role>``.

    ``sent`` and ``rejected`` are called from the control thread and from Zenoh's callback
    threads (a lock of its own, held for an append); ``flush_if_due`` from one thread."""

    def __init__(
        self, session: Any, robot_id: str, role: str, interval_ns: int = TAP_INTERVAL_NS
    ) -> None:
        from runtime.zsession import publisher

        self.robot_id = robot_id
        self.role = role
        self.interval_ns = int(interval_ns)
        self._pub = publisher(session, tap_key(robot_id, role))
        self._lock = threading.Lock()
        self._flush_lock = threading.Lock()  # batch numbers in order, also after the close
        self._closed = False
        self._entries: list[TapEntry] = []
        self._bytes = 0
        self._next_ns = 0
        self.batches = 0  # the next batch's sequence number
        self.entries = 0
        self.put_errors = 0

    def sent(self, stream: str, stamp_ns: int, payload: bytes) -> None:
        """``payload`` left on ``hil/<robot_id>/<stream>`` at ``stamp_ns``."""
        self._add(TapEntry(stream, stamp_ns, payload))

    def rejected(self, stream: str, recv_ns: int, payload: bytes, reason: str) -> None:
        """A payload received on ``stream`` at ``recv_ns`` and refused for ``reason``."""
        self._add(TapEntry(stream, recv_ns, bytes(payload[:MAX_MESSAGE_BYTES]), reason))

    def _add(self, entry: TapEntry) -> None:
        with self._lock:
            self._entries.append(entry)
            self._bytes += len(entry.payload) + _ENTRY_OVERHEAD
        if self._closed:  # no regular batch will come: put it now
            self.flush()

    def flush_if_due(self, now_ns: int) -> None:
        """Put a batch when the interval has passed, or earlier when a batch is full."""
        if now_ns >= self._next_ns or len(self._entries) >= MAX_BATCH_ENTRIES:
            self.flush(now_ns)

    def flush_if_late(self, now_ns: int) -> None:
        """Put a batch when the service missed its quiet points for several intervals (a
        loop that never reaches them still hands its entries on)."""
        if now_ns >= self._next_ns + 2 * self.interval_ns:
            self.flush(now_ns)

    def flush(self, now_ns: int | None = None) -> None:
        """Put everything collected, in batches that each fit a decoder's limits."""
        now_ns = time.monotonic_ns() if now_ns is None else now_ns
        self._next_ns = now_ns + self.interval_ns
        with self._flush_lock:
            with self._lock:
                entries, self._entries, self._bytes = self._entries, [], 0
            start = 0
            while start < len(entries):
                end, size = start, 0
                while end < len(entries) and end - start < MAX_BATCH_ENTRIES:
                    size += len(entries[end].payload) + _ENTRY_OVERHEAD
                    if size > _BATCH_ROOM and end > start:
                        break
                    end += 1
                self._put(entries[start:end])
                start = end

    def _put(self, entries: list[TapEntry]) -> None:
        seq = self.batches
        self.batches += 1
        try:
            self._pub.put(encode_batch(self.robot_id, self.role, seq, time.monotonic_ns(), entries))
            self.entries += len(entries)
        except Exception:  # a closed session at shutdown: the observer counts the gap
            self.put_errors += 1

    def close(self) -> None:
        """The last regular batch; from now on each entry is put as it comes."""
        self._closed = True
        self.flush()

    def counters(self) -> dict[str, int]:
        return {
            "tap_batches": self.batches,
            "tap_entries": self.entries,
            "tap_put_errors": self.put_errors,
        }
