"""The controller's command paths: how a computed command leaves for the plant.

The service computes one :class:`protocol.messages.TorqueCommand` per tick and hands it to each
of its paths (:class:`CommandPath`), which say when it left: :class:`ZenohCommandPath` (the
message on Zenoh, through the [faults] drop, duplicate and reorder injections) and
:class:`controller_service.service.CanCommandPath` (Set_Input_Torque frames to the drives, after
their lifecycle). Which path the plant applies is the plant's business; the controller sends on
every path it has.
"""

from __future__ import annotations

from typing import Any, NamedTuple, Protocol

from protocol import keys
from protocol.faults import Faults, every_nth
from protocol.hoplog import NO_STAMP, TICK_DROPPED, TICK_DUPLICATED, TICK_REORDERED, CmdPath
from protocol.messages import FLAG_STOP, TorqueCommand, encode


class Sent(NamedTuple):
    """One command on one path: when it left (``NO_STAMP``: it did not, e.g. drives not armed)
    and the tick flags of the [faults] injections it met."""

    send_ns: int
    flags: int = 0


NOT_SENT = Sent(NO_STAMP)


class CommandPath(Protocol):
    """One way the controller's commands reach the plant."""

    path: CmdPath

    def send(self, cmd: TorqueCommand) -> Sent:
        """Send ``cmd`` now (called by the control loop: cheap, no waiting)."""
        ...


class ZenohCommandPath:
    """TorqueCommand on Zenoh, through the [faults] injections (:mod:`protocol.faults`); its
    send time is the message's own ``send_time_ns``."""

    path = CmdPath.ZENOH

    def __init__(self, session: Any, robot_id: str, faults: Faults | None = None) -> None:
        from runtime.zsession import publisher

        self._pub = publisher(session, keys.torque_key(robot_id))
        self.faults = faults or Faults()
        self.injected = {"drops": 0, "duplicates": 0, "reorders": 0}
        self._held: bytes | None = None  # a command a [faults] reorder publishes after the next
        self._last: bytes | None = None

    def send(self, cmd: TorqueCommand) -> Sent:
        self._last = encode(cmd)
        return Sent(cmd.send_time_ns, self._put(self._last, cmd.seq, cmd.flags))

    def resend_last(self) -> bool:
        """Publish the last command again, unchanged (lockstep: the plant re-sent the state
        because the command was lost); False when there is none."""
        if not self._last:
            return False
        self._pub.put(self._last)
        return True

    def _put(self, payload: bytes, seq: int, flags: int) -> int:
        """Put one command through the [faults] injections; returns the tick's fault flags."""
        f = self.faults
        held, self._held = self._held, None
        out_flags = 0
        if flags & FLAG_STOP:
            pass
        elif every_nth(seq, f.command_drop_every):
            self.injected["drops"] += 1
            if held is not None:
                self._pub.put(held)
            return TICK_DROPPED
        elif every_nth(seq, f.command_reorder_every) and held is None:
            self._held = payload  # published after the next command
            self.injected["reorders"] += 1
            return TICK_REORDERED
        self._pub.put(payload)
        if held is not None:
            self._pub.put(held)
        if not (flags & FLAG_STOP) and every_nth(seq, f.command_duplicate_every):
            self._pub.put(payload)
            self.injected["duplicates"] += 1
            out_flags |= TICK_DUPLICATED
        return out_flags
