"""What an observer of a run (``hil run``'s recorder, the live view) receives, unpacked.

Observers subscribe to :func:`protocol.keys.observed_keys`: each robot's status key and its
services' taps (:mod:`protocol.tap`), never the loop's own keys. :class:`TapReader` turns what
arrives into :class:`Observed` messages, each on the topic it travelled on.

The log time of a tapped message (when the observer "saw" it): on one host, the sender's own
stamp of its put, exact (one clock); across hosts (a lab run), that stamp carried onto the
observer's clock by its batch's transit: ``batch receive time - (batch send time - stamp)``,
which is late by that transit (about 0.1-1 ms) and never earlier than the put.
"""

from __future__ import annotations

import heapq
from typing import Any, NamedTuple

from hil.recording import to_jsonable
from protocol.can.codec import CanDecodeError
from protocol.can.codec import decode as can_decode
from protocol.can.drive_link import from_message
from protocol.keys import is_tap_key
from protocol.messages import DecodeError
from protocol.rejections import RejectionCounter
from protocol.tap import TAP_INTERVAL_NS, decode_batch


class Observed(NamedTuple):
    topic: str
    log_time_ns: int
    payload: bytes
    rejected: str = ""  # the reason a service refused it on receipt ("" : it was sent)
    by: str = ""  # the service whose tap carried it ("" : received directly)


class TapReader:
    """Unpacks tap batches (and passes other messages through), counting losses."""

    def __init__(self, same_clock: bool = True) -> None:
        self.same_clock = same_clock
        self._next: dict[tuple[str, str], int] = {}
        self.batches = 0
        self.entries = 0
        self.lost_batches = 0
        self.restarts = 0
        self.refused = RejectionCounter()

    def read(self, key: str, recv_ns: int, payload: bytes) -> list[Observed]:
        """What one Zenoh sample on ``key``, received at ``recv_ns``, carried."""
        if not is_tap_key(key):
            return [Observed(key, recv_ns, payload)]
        try:
            batch = decode_batch(payload)
        except DecodeError as exc:
            self.refused.count(exc.reason)
            return []
        _, robot, _, role = key.split("/")
        if (batch.robot_id, batch.role) != (robot, role):
            self.refused.count("wrong_key")
            return []
        self.batches += 1
        expected = self._next.get((robot, role), batch.seq)  # the first batch: no gap
        if batch.seq > expected:
            self.lost_batches += batch.seq - expected
        elif batch.seq < expected:  # the service restarted and numbers from 0 again
            self.restarts += 1
        self._next[(robot, role)] = batch.seq + 1
        shift = 0 if self.same_clock else recv_ns - batch.send_time_ns
        base = f"{key.split('/', 1)[0]}/{robot}/"
        self.entries += len(batch.entries)
        return [
            Observed(base + e.stream, e.stamp_ns + shift, e.payload, e.rejected, role)
            for e in batch.entries
        ]

    def counts(self) -> dict[str, object]:
        """For the run's summary: what the taps delivered and what was lost on the way."""
        return {
            "tap_batches": self.batches,
            "tap_entries": self.entries,
            "tap_batches_lost": self.lost_batches,
            "tap_restarts": self.restarts,
            "tap_batches_refused": self.refused.snapshot(),
        }


class InTimeOrder:
    """Observed messages given back in log-time order once ``hold_ns`` old: taps hand on each
    service's messages every 50 ms, so they arrive grouped by sender; the live view's command
    age at each State needs their order across services. The hold covers a batch's interval and
    transit; a message older than what was given back still comes out (late, counted)."""

    def __init__(self, hold_ns: int = 3 * TAP_INTERVAL_NS) -> None:
        self.hold_ns = hold_ns
        self._heap: list[tuple[int, int, Observed]] = []
        self._n = 0
        self._released_ns = 0
        self.late = 0

    def push(self, m: Observed) -> None:
        if m.log_time_ns < self._released_ns:
            self.late += 1
        heapq.heappush(self._heap, (m.log_time_ns, self._n, m))
        self._n += 1

    def ready(self, now_ns: int | None) -> list[Observed]:
        """What is at least ``hold_ns`` older than ``now_ns`` (None: everything), in order."""
        out = []
        heap = self._heap
        while heap and (now_ns is None or heap[0][0] <= now_ns - self.hold_ns):
            t, _, m = heapq.heappop(heap)
            self._released_ns = max(self._released_ns, t)
            out.append(m)
        return out

    def __len__(self) -> int:
        return len(self._heap)


def can_frame_record(msg: Any) -> dict[str, Any]:
    """A python-can message as the recording and the live view show it (schema
    ``hil.CanFrame``): its fields, and the CANSimple message it decodes to (or why not)."""
    data: dict[str, Any] = {
        "arbitration_id": msg.arbitration_id,
        "data": bytes(msg.data).hex(),
        "dlc": msg.dlc,
        "is_remote_frame": bool(msg.is_remote_frame),
    }
    try:
        m = can_decode(from_message(msg))
        data["message"] = type(m).__name__
        data["fields"] = to_jsonable(m)  # finite numbers: the codec refuses non-finite ones
    except Exception as exc:  # a frame the codec refuses is still recorded, with why
        data["decode_reason"] = exc.reason if isinstance(exc, CanDecodeError) else "malformed"
        data["decode_error"] = str(exc)
    return data
