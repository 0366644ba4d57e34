"""SIGINT/SIGTERM as a flag: a service's main loop ends cleanly at its next check instead of
unwinding from wherever the signal landed (hop logs flushed, drives disarmed, session closed)."""

from __future__ import annotations

import contextlib
import signal
from collections.abc import Iterator, Sequence
from types import FrameType


class StopRequested:
    """A flag set by SIGINT/SIGTERM so a main loop ends cleanly instead of unwinding anywhere."""

    def __init__(self) -> None:
        self.requested = False
        self.signal: int | None = None

    def __bool__(self) -> bool:
        return self.requested

    def _handler(self, signum: int, frame: FrameType | None) -> None:
        self.requested = True
        self.signal = signum


@contextlib.contextmanager
def stop_on_signals(
    signals: Sequence[int] = (signal.SIGINT, signal.SIGTERM),
) -> Iterator[StopRequested]:
    """Install handlers that set a :class:`StopRequested` flag; restore the old ones after."""
    flag = StopRequested()
    old = {s: signal.signal(s, flag._handler) for s in signals}
    try:
        yield flag
    finally:
        for s, h in old.items():
            signal.signal(s, h)
