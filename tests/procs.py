"""Processes started by tests: always stopped by their PID, also when the test fails."""

from __future__ import annotations

import contextlib
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from typing import IO


def free_tcp_port() -> int:
    """A TCP port on 127.0.0.1 that nothing listens on right now."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def stop_pid(proc: subprocess.Popen, grace: float = 5.0) -> None:
    """SIGINT, then SIGTERM, then SIGKILL to the process group of ``proc`` (by its PID).

    A leader that already exited may have left members of its group running (a shell's
    background jobs): they get SIGKILL."""
    if proc.poll() is not None:
        with contextlib.suppress(ProcessLookupError, PermissionError):
            os.killpg(proc.pid, signal.SIGKILL)
        return
    for sig, wait in ((signal.SIGINT, grace), (signal.SIGTERM, 2.0), (signal.SIGKILL, 2.0)):
        try:
            os.killpg(proc.pid, sig)
        except ProcessLookupError:
            return
        try:
            proc.wait(timeout=wait)
            return
        except subprocess.TimeoutExpired:
            continue


class Spawner:
    """Starts processes in their own process group and remembers their PIDs."""

    def __init__(self) -> None:
        self.procs: list[subprocess.Popen] = []

    def python(self, args: Sequence[str], **kw) -> subprocess.Popen:
        return self.start([sys.executable, *args], **kw)

    def start(self, argv: Sequence[str], **kw) -> subprocess.Popen:
        kw.setdefault("stdout", subprocess.PIPE)
        kw.setdefault("stderr", subprocess.PIPE)
        proc = subprocess.Popen(list(argv), start_new_session=True, **kw)
        self.procs.append(proc)
        return proc

    def stop_all(self) -> None:
        for proc in reversed(self.procs):
            stop_pid(proc)


@contextmanager
def spawned() -> Iterator[Spawner]:
    spawner = Spawner()
    try:
        yield spawner
    finally:
        spawner.stop_all()


def wait_until(predicate, timeout: float, interval: float = 0.02) -> bool:
    """Poll ``predicate`` until it is true or ``timeout`` seconds pass (a bounded wait on an
    observable condition, not a sleep on luck)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(interval)
    return bool(predicate())


class Lines:
    """The lines of a child's output stream, read by a thread: a test can wait for a line
    with :func:`wait_until` without ever blocking on the pipe, and the pipe never fills."""

    def __init__(self, stream: IO) -> None:
        self.lines: list[str] = []
        self._thread = threading.Thread(target=self._read, args=(stream,), daemon=True)
        self._thread.start()

    def _read(self, stream: IO) -> None:
        with contextlib.suppress(ValueError, OSError):  # the pipe closed under us
            for line in stream:
                self.lines.append(line if isinstance(line, str) else line.decode(errors="replace"))

    def seen(self, text: str) -> bool:
        return any(text in line for line in list(self.lines))

    def text(self, join_timeout: float = 0.0) -> str:
        """Everything read so far (after waiting up to ``join_timeout`` for the stream's end)."""
        self._thread.join(join_timeout)
        return "".join(self.lines)
