"""Ctrl-C as the project sees it, whatever the CLI library does with a KeyboardInterrupt.

:func:`hil.cli.main` installs :func:`handler` for SIGINT (:func:`installed`): it records the
interrupt and raises KeyboardInterrupt, so a command's loop can catch it and keep what it
computed. Whatever then happens (a normal return, SystemExit, or the CLI library's own
exception), ``main`` sees the record and exits 130 after one line ``interrupted: ...``. Code with
its own signal handler (``hil run``'s :func:`runtime.signals.stop_on_signals`) calls
:func:`record`. A command says what it kept with :func:`note`; :func:`shielded` makes a second
Ctrl-C while results are written only recorded, so no file is left half-written.
"""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Iterator
from types import FrameType

_signum: int | None = None
_note: str | None = None
_shield_depth = 0


def record(signum: int = signal.SIGINT) -> None:
    """Remember that the process was interrupted (by ``signum``)."""
    global _signum
    if _signum is None:
        _signum = int(signum)


def happened() -> bool:
    """True once an interrupt was recorded since :func:`reset`."""
    return _signum is not None


def note(text: str) -> None:
    """Say what the interrupted command kept (printed by ``main`` after ``interrupted:``)."""
    global _note
    _note = text


def message() -> str:
    """The one line ``main`` prints: ``interrupted: <what was kept>`` (by default, the signal)."""
    if _note:
        return f"interrupted: {_note}"
    try:
        name = signal.Signals(_signum or signal.SIGINT).name
    except ValueError:
        name = f"signal {_signum}"
    return f"interrupted: stopped by {name}"


def reset() -> None:
    global _signum, _note
    _signum, _note = None, None


def handler(signum: int, frame: FrameType | None) -> None:
    """The SIGINT handler: record, then raise KeyboardInterrupt (unless :func:`shielded`)."""
    record(signum)
    if _shield_depth == 0:
        raise KeyboardInterrupt


@contextlib.contextmanager
def shielded() -> Iterator[None]:
    """Inside, SIGINT is recorded but raises nothing: for writing what was computed."""
    global _shield_depth
    _shield_depth += 1
    try:
        yield
    finally:
        _shield_depth -= 1


@contextlib.contextmanager
def installed() -> Iterator[None]:
    """Install :func:`handler` for SIGINT with a clear record; restore both on leaving. An
    ignored SIGINT (``nohup``, or ``&`` in a non-interactive shell) stays ignored; off the main
    thread (no signals there) nothing is installed and ``main`` still maps a KeyboardInterrupt."""
    reset()
    main = threading.current_thread() is threading.main_thread()
    previous = signal.getsignal(signal.SIGINT) if main else None
    ours = main and previous != signal.SIG_IGN
    if ours:
        signal.signal(signal.SIGINT, handler)
    try:
        yield
    finally:
        if ours:  # None: a handler not set from Python; the default is the closest
            signal.signal(signal.SIGINT, signal.SIG_DFL if previous is None else previous)
        reset()
