"""What a long command says on stderr: one start line (what runs, for how long, where it
writes), then progress that a log file or CI also gets.

On a terminal the commands draw progress bars; off one (a pipe, a CI log, ``nohup``) a bar
prints nothing, so :class:`Ticker` prints a plain line instead, at most one per interval
(:data:`INTERVAL_S`, or ``HIL_PROGRESS_INTERVAL_S`` from the environment), so that a long run
never reads as a hang.
"""

from __future__ import annotations

import os
import sys
import time
from typing import TextIO

#: Seconds between two progress lines off a terminal.
INTERVAL_S = 5.0
INTERVAL_ENV = "HIL_PROGRESS_INTERVAL_S"


def interval_s() -> float:
    """The interval between progress lines (the environment's, when it is a positive number)."""
    try:
        value = float(os.environ.get(INTERVAL_ENV, ""))
    except ValueError:
        return INTERVAL_S
    return value if value > 0 else INTERVAL_S


def on_terminal(stream: TextIO | None = None) -> bool:
    stream = stream or sys.stderr
    return bool(getattr(stream, "isatty", lambda: False)())


def say(line: str) -> None:
    """One line on stderr, at once (a pipe buffers otherwise)."""
    print(line, file=sys.stderr, flush=True)


def start_line(command: str, what: str, how_long: str, where: str | os.PathLike[str]) -> str:
    """``hil COMMAND: WHAT, HOW_LONG; writes WHERE``, said on stderr and returned."""
    line = f"hil {command}: {what}, {how_long}; writes {where}"
    say(line)
    return line


class Ticker:
    """Calls of ``tick(text)`` print ``LABEL: text`` off a terminal, at most once per interval
    (the first call prints at once); on a terminal (a bar shows progress) nothing."""

    def __init__(self, label: str, *, enabled: bool | None = None) -> None:
        self.label = label
        self.enabled = (not on_terminal()) if enabled is None else enabled
        self.every = interval_s()
        self._last: float | None = None

    def tick(self, text: str) -> None:
        if not self.enabled:
            return
        now = time.monotonic()
        if self._last is not None and now - self._last < self.every:
            return
        self._last = now
        say(f"{self.label}: {text}")
