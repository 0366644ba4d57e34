"""A delay line: items held until their release time, then handed on in a thread of its own.

The plant's feedback toward the controller (States on Zenoh, encoder-estimate frames on CAN)
passes through one when the scenario's ``[faults]`` adds a delay or jitter on that path
(``feedback_delay``, ``feedback_jitter``): the item keeps the content of its sample time and
reaches the wire that much later, in release order (a jitter can reorder items, as a network
can). The plant's loop never waits on it.
"""

from __future__ import annotations

import heapq
import itertools
import threading
import time
from collections.abc import Callable
from typing import Any

# The release is awaited with the condition variable until this close, then spun: a sleep's
# wake-up lateness (tens to hundreds of microseconds) would add to the delay asked for.
SPIN_NS = 300_000


class DelayLine:
    def __init__(self, send: Callable[[Any], None], name: str = "delay-line") -> None:
        self._send = send
        self._heap: list[tuple[int, int, Any]] = []
        self._order = itertools.count()
        self._cv = threading.Condition()
        self._closed = False
        self.sent = 0
        self.dropped_at_close = 0  # held when the line closed: never sent
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    def put(self, release_ns: int, item: Any) -> None:
        """Send ``item`` at ``release_ns`` (time.monotonic_ns); at once if that has passed."""
        with self._cv:
            heapq.heappush(self._heap, (release_ns, next(self._order), item))
            self._cv.notify()

    def _run(self) -> None:
        while True:
            with self._cv:
                while not self._closed and not self._heap:
                    self._cv.wait()
                if self._closed:
                    return
                release_ns = self._heap[0][0]
                wait_ns = release_ns - time.monotonic_ns() - SPIN_NS
                if wait_ns > 0:
                    self._cv.wait(wait_ns / 1e9)  # woken early by a sooner item, or on time
                    continue
            while time.monotonic_ns() < release_ns:
                pass
            with self._cv:
                if not self._heap or self._heap[0][0] != release_ns:
                    continue
                _, _, item = heapq.heappop(self._heap)
            self._send(item)
            self.sent += 1

    def close(self) -> None:
        """Stop; what is still held is counted in ``dropped_at_close`` and never sent."""
        with self._cv:
            self._closed = True
            self.dropped_at_close = len(self._heap)
            self._heap.clear()
            self._cv.notify()
        self._thread.join(timeout=1.0)
