"""Zenoh key expressions of the bench: ``hil/<robot_id>/{state,cmd/torque,telemetry,status}``
and each service's tap of them, ``hil/<robot_id>/tap/<role>`` (:mod:`protocol.tap`).

A robot id is one key chunk: 1 to 64 characters from ``[A-Za-z0-9_.-]``. That excludes every
character with a meaning in Zenoh key expressions (``/`` separates chunks, ``*`` and ``$*`` are
wildcards, ``#`` and ``?`` are reserved for selectors, ``@`` starts verbatim chunks) and keeps
ids printable in file names and logs. The same rule is enforced when messages are decoded.
"""

from __future__ import annotations

import re

PREFIX = "hil"
ROBOT_ID_MAX_LEN = 64
ROBOT_ID_RE = re.compile(r"[A-Za-z0-9_.\-]{1,64}")

# Suffixes after ``hil/<robot_id>/``; the dictionary maps a suffix back to its stream name.
STATE = "state"
TORQUE = "cmd/torque"
TELEMETRY = "telemetry"
STATUS = "status"
STREAMS: dict[str, str] = {
    STATE: "state",
    TORQUE: "torque",
    TELEMETRY: "telemetry",
    STATUS: "status",
}


class InvalidRobotIdError(ValueError):
    """A robot id that cannot be one Zenoh key chunk (see the module docstring)."""


def is_valid_robot_id(robot_id: object) -> bool:
    """True when ``robot_id`` is a str matching ``[A-Za-z0-9_.-]{1,64}`` and not ``.``/``..``."""
    return (
        type(robot_id) is str
        and ROBOT_ID_RE.fullmatch(robot_id) is not None
        and robot_id not in (".", "..")
    )


def validate_robot_id(robot_id: object) -> str:
    """Return ``robot_id`` unchanged or raise :class:`InvalidRobotIdError` saying why."""
    if not is_valid_robot_id(robot_id):
        raise InvalidRobotIdError(
            f"robot id {robot_id!r} is not 1-64 characters of [A-Za-z0-9_.-] "
            "(no '/', '*', '$', '#', '?', '@', spaces; not '.' or '..')"
        )
    return robot_id  # type: ignore[return-value]


def _key(robot_id: str, suffix: str) -> str:
    return f"{PREFIX}/{validate_robot_id(robot_id)}/{suffix}"


def state_key(robot_id: str) -> str:
    """``hil/<robot_id>/state``: the plant's measured state (message State)."""
    return _key(robot_id, STATE)


def torque_key(robot_id: str) -> str:
    """``hil/<robot_id>/cmd/torque``: the controller's torques (message TorqueCommand)."""
    return _key(robot_id, TORQUE)


def telemetry_key(robot_id: str) -> str:
    """``hil/<robot_id>/telemetry``: the law's internal signals (message Telemetry)."""
    return _key(robot_id, TELEMETRY)


def status_key(robot_id: str) -> str:
    """``hil/<robot_id>/status``: health and counters of each process (message Status)."""
    return _key(robot_id, STATUS)


def robot_prefix(robot_id: str) -> str:
    """``hil/<robot_id>/**``: every stream of one robot."""
    return _key(robot_id, "**")


TAP = "tap"


def tap_key(robot_id: str, role: str) -> str:
    """``hil/<robot_id>/tap/<role>``: the batches of what the service ``role`` sent
    (:mod:`protocol.tap`)."""
    return _key(robot_id, f"{TAP}/{role}")


def observed_keys(robot_id: str) -> tuple[str, str]:
    """What an observer of one robot (a recorder, a live view) subscribes to: the status key
    and every service's tap, never the loop's own keys (an observer there would receive every
    State and command as the loop does; :mod:`protocol.tap` says what that cost)."""
    return status_key(robot_id), _key(robot_id, f"{TAP}/*")


def is_tap_key(key: str) -> bool:
    """Whether a concrete key is a tap's (``hil/<robot_id>/tap/<role>``)."""
    parts = str(key).split("/")
    return len(parts) == 4 and parts[0] == PREFIX and parts[2] == TAP


ALL_ROBOTS = f"{PREFIX}/**"


def parse_key(key: str) -> tuple[str, str]:
    """Split a concrete key into ``(robot_id, stream)`` with stream one of ``STREAMS`` values.

    Raises ValueError for a key outside the bench's key space.
    """
    parts = str(key).split("/", 2)
    if len(parts) != 3 or parts[0] != PREFIX or parts[2] not in STREAMS:
        raise ValueError(f"{key!r} is not a hil/<robot_id>/<stream> key")
    return validate_robot_id(parts[1]), STREAMS[parts[2]]
