"""Child processes of ``hil run``: started so they die with their parent, stopped by PID.

Linux's ``PR_SET_PDEATHSIG`` (set with ``prctl`` through ctypes in the child between fork and
exec) makes the kernel send the child a signal when the parent thread that forked it dies, even
if that parent is SIGKILLed. SIGINT stops a child first: the services then flush their logs.
"""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import os
import signal
import subprocess
import sys
from collections.abc import Callable, Mapping, Sequence
from typing import Any

PR_SET_PDEATHSIG = 1


def _die_with_parent(parent_pid: int, sig: int = signal.SIGTERM) -> Callable[[], None]:
    """A ``preexec_fn`` that asks the kernel for ``sig`` when the parent dies."""

    def preexec() -> None:
        with contextlib.suppress(OSError):  # no libc to load: no signal asked
            libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
            libc.prctl(PR_SET_PDEATHSIG, int(sig), 0, 0, 0)
        # The parent may have died between fork and prctl: then no signal would ever come.
        if os.getppid() != parent_pid:
            os._exit(1)

    return preexec


class Child:
    """One supervised process."""

    def __init__(self, name: str, proc: subprocess.Popen[bytes]) -> None:
        self.name = name
        self.proc = proc

    @property
    def pid(self) -> int:
        return self.proc.pid

    def alive(self) -> bool:
        return self.proc.poll() is None

    def stop(self, grace: float = 5.0) -> int | None:
        """SIGINT, then SIGTERM, then SIGKILL, each to this PID only; returns the exit code."""
        for sig, wait in ((signal.SIGINT, grace), (signal.SIGTERM, 2.0), (signal.SIGKILL, 2.0)):
            if self.proc.poll() is not None:
                break
            with contextlib.suppress(ProcessLookupError):
                os.kill(self.proc.pid, sig)
            with contextlib.suppress(subprocess.TimeoutExpired):
                self.proc.wait(timeout=wait)
                break
        return self.proc.poll()


class Supervisor:
    """Starts children that die with this process and stops them by PID, newest first."""

    def __init__(self) -> None:
        self.children: list[Child] = []

    def start(
        self,
        name: str,
        argv: Sequence[str],
        env: Mapping[str, str] | None = None,
        stdout: Any = None,
        stderr: Any = None,
    ) -> Child:
        proc = subprocess.Popen(
            list(argv),
            env={**os.environ, **(env or {})},
            stdout=stdout,
            stderr=stderr,
            # A new session: a Ctrl-C in the terminal reaches only ``hil run``, which then
            # stops the children in order (controller first) instead of all at once.
            start_new_session=True,
            preexec_fn=_die_with_parent(os.getpid()),
        )
        child = Child(name, proc)
        self.children.append(child)
        return child

    def start_python(self, name: str, module_args: Sequence[str], **kw: Any) -> Child:
        return self.start(name, [sys.executable, *module_args], **kw)

    def stop_all(self, grace: float = 5.0) -> dict[str, int | None]:
        return {c.name: c.stop(grace) for c in reversed(self.children)}
