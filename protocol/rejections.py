"""Counted rejections: every decoder and receiver in the project reports what it refused here.

docs/design.md, section 3: bad input gets a clear, counted rejection, never a crash. One counter per
receiver (or one shared by a process); reasons are short snake_case words such as
``"wrong_type"`` or ``"out_of_range"`` (see :mod:`protocol.messages` for the message reasons).
"""

from __future__ import annotations

import threading


class RejectionCounter:
    """Counts rejections by reason; safe to call from Zenoh and python-can callback threads.

    The lock is held only for a dictionary update, so a 1-2 kHz receiver pays well under a
    microsecond per rejection and readers always see a consistent snapshot.
    """

    __slots__ = ("_counts", "_lock", "_total")

    def __init__(self) -> None:
        self._counts: dict[str, int] = {}
        self._total = 0
        self._lock = threading.Lock()

    def count(self, reason: str, n: int = 1) -> None:
        """Record ``n`` rejections for ``reason``."""
        with self._lock:
            self._counts[reason] = self._counts.get(reason, 0) + n
            self._total += n

    def snapshot(self) -> dict[str, int]:
        """A copy of the counts by reason (sorted by reason, for stable output)."""
        with self._lock:
            return dict(sorted(self._counts.items()))

    @property
    def total(self) -> int:
        """The number of rejections over every reason."""
        return self._total

    def get(self, reason: str) -> int:
        """The number of rejections for one reason (0 if never seen)."""
        with self._lock:
            return self._counts.get(reason, 0)

    def __repr__(self) -> str:
        return f"RejectionCounter(total={self._total}, by_reason={self.snapshot()})"
