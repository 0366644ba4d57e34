"""Checks of command-line options and scenario numbers, shared by the commands.

Each raises :class:`hil.errors.BadInputError` with one line naming the option (``--rate``) or
the scenario key (``[timing] ts``) and what was expected, before a command starts any work:
no folder is created, no process started, no simulation begun for a bad value. The CLI library
parses the types (text where a number goes is its usage error, also exit 2); it lets ``nan``
and ``inf`` through as numbers, which is why every number is checked again here.
"""

from __future__ import annotations

import math
import os
import re
import tempfile
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

from hil.errors import BadInputError

#: The live view's port for a bare ``--live`` (Foxglove's own).
LIVE_DEFAULT_PORT = 8765


def expand_live_flag(argv: Sequence[str]) -> list[str]:
    """``argv`` with each bare ``--live`` (no port number after it) as ``--live=8765``
    (:data:`LIVE_DEFAULT_PORT`)."""
    out = list(argv)
    for i, arg in enumerate(out):
        if arg == "--":
            break
        if arg == "--live" and not (i + 1 < len(out) and out[i + 1].isdigit()):
            out[i] = f"--live={LIVE_DEFAULT_PORT}"
    return out


# A Zenoh locator: protocol/address, e.g. tcp/127.0.0.1:7447.
LOCATOR = re.compile(r"[A-Za-z][A-Za-z0-9+.-]*/\S+")


def type_name(v: Any) -> str:
    """The TOML name of a value's type, for messages."""
    if isinstance(v, dict):
        return "table"
    return {bool: "boolean", int: "integer", float: "number", str: "string", list: "array"}.get(
        type(v), type(v).__name__
    )


def describe(low: float, high: float, positive: bool = False) -> str:
    """The range [low, high] (with > 0 when ``positive``) in words."""
    if positive and low <= 0:
        return f"> 0 and <= {high:g}"
    return f"in [{low:g}, {high:g}]"


def number(where: str, value: Any, low: float, high: float, *, positive: bool = False) -> float:
    """``value`` as a finite float within [low, high] (and > 0 if ``positive``)."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise BadInputError(f"{where} must be a number, got {type_name(value)} {value!r}")
    value = float(value)
    if not math.isfinite(value):
        raise BadInputError(f"{where} must be a finite number, got {value!r}")
    if not (low <= value <= high) or (positive and not value > 0):
        raise BadInputError(f"{where} must be {describe(low, high, positive)}, got {value!r}")
    return value


def optional_number(
    where: str, value: Any, low: float, high: float, *, positive: bool = False
) -> float | None:
    return None if value is None else number(where, value, low, high, positive=positive)


def integer(where: str, value: Any, low: int, high: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise BadInputError(f"{where} must be a whole number, got {type_name(value)} {value!r}")
    if not low <= value <= high:
        raise BadInputError(f"{where} must be in [{low}, {high}], got {value!r}")
    return value


def choice(where: str, value: Any, choices: Iterable[str]) -> str:
    allowed = tuple(choices)
    if value not in allowed:
        raise BadInputError(
            f"{where} must be one of {', '.join(map(repr, allowed))}, got {value!r}"
        )
    return str(value)


def plain_string(where: str, value: str, *, empty: bool = True) -> str:
    """A name or path: no control characters (and not empty unless ``empty``)."""
    if not empty and not value.strip():
        raise BadInputError(f"{where} must not be empty")
    if any(ord(c) < 32 or ord(c) == 127 for c in value):
        raise BadInputError(f"{where} must not hold control characters, got {value!r}")
    return value


def locator(where: str, value: str) -> str:
    if not LOCATOR.fullmatch(value):
        raise BadInputError(
            f"{where} must be a Zenoh locator such as 'tcp/127.0.0.1:7447', got {value!r}"
        )
    return value


def grid(where: str, text: str | None, low: float, high: float) -> tuple[float, ...]:
    """A comma-separated list of numbers in [low, high] (empty: no values)."""
    values = []
    for part in (text or "").split(","):
        if not part.strip():
            continue
        try:
            value = float(part)
        except ValueError:
            raise BadInputError(
                f"{where} must be comma-separated numbers, got {part.strip()!r} in {text!r}"
            ) from None
        values.append(number(where, value, low, high))
    return tuple(values)


def out_dir(where: str, path: Path | str | None, default: Path | str | None = None) -> Path | None:
    """A folder a command may create and write: an existing folder, or a path whose nearest
    existing parent is a writable folder. Without ``path`` the command's ``default`` folder
    (e.g. ``runs``) is checked instead, named as the default in the message."""
    if path is None:
        if default is not None:
            out_dir(f"{where} not given, so its default", default)
        return None
    p = Path(path)
    plain_string(where, str(p), empty=False)
    if p.exists() and not p.is_dir():
        raise BadInputError(f"{where} {p}: exists and is not a folder")
    parent = p
    while not parent.exists() and parent != parent.parent:
        parent = parent.parent
    if not parent.is_dir():
        raise BadInputError(f"{where} {p}: {parent} is not a folder")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise BadInputError(f"{where} {p}: {parent} is not writable")
    # Permission bits do not tell (root may write anywhere, /proc takes no folder, a
    # read-only mount): a folder made and removed at once does, before any work starts.
    try:
        os.rmdir(tempfile.mkdtemp(prefix=".hil-probe-", dir=parent))
    except OSError as exc:
        raise BadInputError(
            f"{where} {p}: cannot write in {parent.resolve()} ({exc.strerror})"
        ) from exc
    return p


def out_file(where: str, path: Path | str) -> Path:
    """A file a command may write (its folder made if missing): not a folder itself, and its
    folder one :func:`out_dir` accepts."""
    p = Path(path)
    plain_string(where, str(p), empty=False)
    if p.is_dir():
        raise BadInputError(f"{where} {p}: is a folder, not a file")
    try:
        out_dir(where, p.parent)
    except BadInputError as exc:  # named by the file the user gave, not by its folder
        raise BadInputError(f"{where} {p}: {str(exc).split(': ', 1)[1]}") from exc
    return p


def existing_file(where: str, path: Path | str) -> Path:
    p = Path(path)
    if not p.is_file():
        raise BadInputError(f"{where} {p}: no such file")
    return p
