"""How the device reacted when a drive disarmed (an over-speed trip, the watchdog, an estop).

One definition, from the plant's hop log alone (the drives' CLOCK_MONOTONIC, the plant's
clock): for each ``disarmed`` event of a virtual drive (protocol.hoplog.DriveEventRow), what
the device did to that drive until it was armed again or the run ended:

- ``clear_errors_after_ms``: from the disarm to the first Clear_Errors it sent that drive;
- ``rearm_request_after_ms``: to its first Set_Axis_State 8 (closed loop) request;
- ``armed_after_ms``: to the drive being in closed loop again (None: it never was);
- ``inputs_while_disarmed``: the torque frames it sent the drive in between (cmd_rx rows of
  that node, before the re-arm), and ``kept_commanding``: whether any came after the disarm
  had been reported in a heartbeat (100 ms at most; before that the device could not know);
- ``last_input_after_ms``: the last of those, from the disarm (the device stopped then).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from protocol.can.codec import AxisState, ODriveError
from protocol.hoplog import CmdPath, DriveEvent

#: The drives' heartbeat period (firmware default): a disarm is known on the bus this late.
HEARTBEAT_S = 0.1


@dataclass(frozen=True)
class DriveReaction:
    node: int
    t_s: float  # the disarm, since the run's epoch
    error: int
    error_names: str
    clear_errors_after_ms: float | None
    rearm_request_after_ms: float | None
    armed_after_ms: float | None
    inputs_while_disarmed: int
    kept_commanding: bool
    last_input_after_ms: float | None

    def sentence(self) -> str:
        """What the device did, in one sentence the report and the summary quote."""
        head = f"node {self.node} disarmed at t = {self.t_s:.3f} s ({self.error_names})"
        did = []
        if self.clear_errors_after_ms is not None:
            did.append(f"Clear_Errors after {self.clear_errors_after_ms:.0f} ms")
        if self.rearm_request_after_ms is not None:
            did.append(f"closed loop asked after {self.rearm_request_after_ms:.0f} ms")
        if self.armed_after_ms is not None:
            did.append(f"armed again after {self.armed_after_ms:.0f} ms")
        else:
            did.append("never re-armed")
        if self.kept_commanding:
            did.append(f"kept commanding the disarmed drive ({self.inputs_while_disarmed} frames)")
        elif self.last_input_after_ms is None:
            did.append("sent it no torque until re-armed")
        elif self.armed_after_ms is not None:
            did.append(
                f"sent it {self.inputs_while_disarmed} torque frames before re-arming (the last "
                f"{self.last_input_after_ms:.0f} ms after the disarm)"
            )
        else:
            did.append(f"stopped commanding it after {self.last_input_after_ms:.0f} ms")
        return f"{head}: the device " + ", ".join(did)

    def as_dict(self) -> dict[str, Any]:
        return {**asdict(self), "sentence": self.sentence()}


def _error_names(bits: int) -> str:
    names = [e.name for e in ODriveError if e.value and bits & e.value]
    return " | ".join(n for n in names if n) or f"error 0x{bits:x}"


def reactions(tables: dict[str, dict[str, np.ndarray]], epoch_ns: int) -> list[DriveReaction]:
    """Every drive disarm of the run and the device's reaction (module docstring)."""
    ev = tables.get("drive_events") or {}
    if not len(ev.get("time_ns", ())):
        return []
    node, t, kind, detail = (ev[c] for c in ("node", "time_ns", "event", "detail"))
    rx = tables.get("cmd_rx") or {}
    can = rx["path"] == CmdPath.CAN if len(rx.get("path", ())) else np.zeros(0, bool)
    rx_node, rx_t = rx.get("node", np.zeros(0))[can], rx.get("recv_ns", np.zeros(0))[can]
    out = []
    for i in np.flatnonzero(kind == DriveEvent.DISARMED):
        n, t0 = int(node[i]), int(t[i])
        later = (node == n) & (t > t0)

        def first(event: DriveEvent, want: int | None = None, mask: Any = later) -> int | None:
            hit = mask & (kind == event)
            if want is not None:
                hit &= detail == want
            idx = np.flatnonzero(hit)
            return int(t[idx[0]]) if idx.size else None

        armed = first(DriveEvent.ARMED)
        end = armed if armed is not None else np.iinfo(np.int64).max
        window = (rx_node == n) & (rx_t > t0) & (rx_t < end)
        sent = rx_t[window]
        known = t0 + HEARTBEAT_S * 1e9

        def ms(x: int | None, t0: int = t0) -> float | None:
            return None if x is None else (x - t0) / 1e6

        out.append(
            DriveReaction(
                node=n,
                t_s=(t0 - epoch_ns) / 1e9,
                error=int(detail[i]),
                error_names=_error_names(int(detail[i])),
                clear_errors_after_ms=ms(first(DriveEvent.CLEAR_ERRORS)),
                rearm_request_after_ms=ms(
                    first(DriveEvent.STATE_REQUEST, int(AxisState.CLOSED_LOOP_CONTROL))
                ),
                armed_after_ms=ms(armed),
                inputs_while_disarmed=int(sent.size),
                kept_commanding=bool((sent > known).any()),
                last_input_after_ms=ms(int(sent.max())) if sent.size else None,
            )
        )
    return out
