"""An outside device under test (``hil run --controller external``, ``hil drives``): how it
connects, and waiting until it has.

The bench runs the plant, the recorder and (on CAN) the virtual drives, but no controller of
its own: the device is somebody else's process, in any language, on this host or another. What
it must connect to is printed before the run and written into the folder (``device.json``);
the run's epoch is announced only once the device is there:

- Zenoh: a subscriber of the robot's State key matches (zenoh's publisher matching status, seen
  from a publisher ``hil run`` declares on that key; nothing of the bench subscribes to it).
- CAN: the device has put both drives in closed-loop control (Set_Axis_State 8), or sent a
  first input (torque, velocity or position) to either: a device that drives without arming is
  let in and refused by the disarmed drives, counted.
"""

from __future__ import annotations

import json
import threading
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from hil.errors import BadInputError
from hil.folder import layout
from protocol.can.codec import AxisState, Cmd, split_id
from protocol.keys import state_key, torque_key
from protocol.settings import RunSettings

#: ``hil run --controller``: the bench's own controller process, or an outside device.
CONTROLLERS = ("bench", "external")
#: How long a run waits for its device by default (``--wait-device``).
WAIT_DEVICE_S = 60.0
#: The frames by which a device commands a drive (CANSimple 0.6).
_INPUTS = frozenset({Cmd.SET_INPUT_TORQUE, Cmd.SET_INPUT_VEL, Cmd.SET_INPUT_POS})


@dataclass(frozen=True)
class ZenohConnection:
    """Where a Zenoh device connects (docs/protocol.md says what each message holds)."""

    endpoint: str  # connect to it: the bench listens there
    state_key: str  # the device subscribes: State, one per plant sample
    command_key: str  # the device publishes: TorqueCommand
    docs: str = "docs/protocol.md"
    # --lab: the lab and the host the device runs on (endpoint: that host's own router)
    lab: str = ""
    lab_host: str = ""


@dataclass(frozen=True)
class CanConnection:
    """Where a CAN device connects: the bus and the two virtual ODrives (CANSimple 0.6)."""

    interface: str
    channel: str
    bitrate: int
    node_left: int
    node_right: int
    zenoh_can_endpoint: str  # interface zenoh_can only: the bus's Zenoh endpoint
    docs: str = "docs/can.md"


@dataclass(frozen=True)
class DeviceConnection:
    """``device.json``: how the run's outside device connects, and how long it was waited
    for. ``connected_after_s`` is filled in when it connected (None: it never did)."""

    robot_id: str
    path: str  # "zenoh" or "can": the path its commands take to the plant
    wait_s: float
    zenoh: ZenohConnection | None = None
    can: CanConnection | None = None
    connected_after_s: float | None = None
    how: str = ""  # what showed the device was there
    # [impair]: the PID whose private network namespace the run is in (the device must join
    # it: the run's loopback and its udp_multicast bus are not reachable from outside)
    netns_pid: int | None = None

    def lines(self) -> list[str]:
        """What a user reads before the run: one thing to do per line."""
        out = [f"waiting up to {self.wait_s:g} s for your device (robot {self.robot_id}):"]
        if self.netns_pid is not None:
            out.append(
                f"  in this run's own network namespace ([impair]): nsenter "
                f"--net=/proc/{self.netns_pid}/ns/net -- YOUR-DEVICE (docs/impair.md)"
            )
        if self.zenoh is not None:
            z = self.zenoh
            if z.lab:
                out.append(
                    f"  on lab {z.lab}'s host {z.lab_host}: hil lab exec {z.lab_host} --name "
                    f"{z.lab} -- YOUR-DEVICE (its router below; docs/lab.md)"
                )
            out += [
                f"  zenoh: connect to {z.endpoint} (mode peer or client, scouting off)",
                f"  subscribe {z.state_key} (State), publish {z.command_key} (TorqueCommand);"
                f" messages: {z.docs}",
            ]
        if self.can is not None:
            c = self.can
            bus = f"interface {c.interface}, channel {c.channel}, bitrate {c.bitrate}"
            if c.interface == "zenoh_can":
                bus += f", endpoint {c.zenoh_can_endpoint}"
            out += [
                f"  can: {bus}",
                f"  ODrive CANSimple 0.6 nodes {c.node_left} (left) and {c.node_right} (right):"
                f" arm both (Set_Axis_State 8), then send inputs; {c.docs}",
            ]
        return out

    def save(self, run_dir: Path) -> None:
        (run_dir / layout.DEVICE).write_text(json.dumps(asdict(self), indent=2) + "\n")


def connection(
    settings: RunSettings,
    wait_s: float,
    lab: tuple[str, str] | None = None,
    netns_pid: int | None = None,
) -> DeviceConnection:
    """The device's connection for a run's settings (its applied path decides which);
    ``lab``: (the lab, the device's host) of a run across lab hosts (Zenoh only);
    ``netns_pid``: the run's own network namespace's process ([impair])."""
    rid = settings.robot_id
    if settings.cmd_path == "can":
        c = settings.can
        can = CanConnection(
            interface=str(c["interface"]),
            channel=str(c.get("channel", "")),
            bitrate=int(c.get("bitrate", 0)),
            node_left=int(c["node_left"]),
            node_right=int(c["node_right"]),
            zenoh_can_endpoint=settings.can_endpoint if c["interface"] == "zenoh_can" else "",
        )
        return DeviceConnection(rid, "can", wait_s, can=can, netns_pid=netns_pid)
    lab_name, lab_host = lab or ("", "")
    z = ZenohConnection(
        settings.zenoh_endpoint, state_key(rid), torque_key(rid), lab=lab_name, lab_host=lab_host
    )
    return DeviceConnection(rid, "zenoh", wait_s, zenoh=z, netns_pid=netns_pid)


class ZenohArrival:
    """Whether a subscriber of the State key has appeared (the device, on Zenoh)."""

    def __init__(self, session: Any, key: str) -> None:
        self.key = key
        # A publisher that never puts: only its matching status is read.
        self._pub = session.declare_publisher(key)

    def arrived(self) -> str | None:
        if self._pub.matching_status.matching:
            return f"a subscriber of {self.key}"
        return None

    def nobody(self, endpoint: str) -> str:
        return f"nothing subscribed to {self.key} on {endpoint}"

    def close(self) -> None:
        self._pub.undeclare()


class CanArrival:
    """Whether the device has armed both drives or sent a first input (fed every frame of the
    bus by the recorder's notifier thread)."""

    def __init__(self, nodes: tuple[int, int]) -> None:
        self.nodes = frozenset(nodes)
        self._armed: set[int] = set()
        self._input: str | None = None
        self._lock = threading.Lock()

    def on_frame(self, msg: Any) -> None:
        if msg.is_error_frame or msg.is_remote_frame or msg.is_extended_id:
            return
        node, cmd = split_id(msg.arbitration_id)
        if node not in self.nodes:
            return
        with self._lock:
            if cmd == Cmd.SET_AXIS_STATE and len(msg.data) >= 4:
                if int.from_bytes(bytes(msg.data[:4]), "little") == AxisState.CLOSED_LOOP_CONTROL:
                    self._armed.add(node)
            elif cmd in _INPUTS and self._input is None:
                self._input = f"a {Cmd(cmd).name} frame to node {node}"

    def arrived(self) -> str | None:
        with self._lock:
            if self._armed >= self.nodes:
                return f"closed-loop control asked of nodes {sorted(self.nodes)}"
            return self._input

    def nobody(self, endpoint: str) -> str:
        with self._lock:
            armed = sorted(self._armed)
        return (
            f"no drive armed (of nodes {sorted(self.nodes)}; armed: {armed or 'none'}) and no "
            f"input frame on {endpoint}"
        )

    def close(self) -> None:
        pass


def wait(arrival: Any, stop: Any, timeout: float, alive: Any) -> tuple[str | None, float]:
    """Until the device has arrived (what showed it), a stop, the timeout, or ``alive()`` is
    False (a service of the bench died); and the seconds waited."""
    t0 = time.monotonic()
    while not stop and time.monotonic() - t0 < timeout and alive():
        how = arrival.arrived()
        if how is not None:
            return how, time.monotonic() - t0
        time.sleep(0.02)
    return None, time.monotonic() - t0


def check_endpoint(option: str, endpoint: str) -> None:
    """``tcp/HOST:PORT`` on a loopback address (no packet leaves the host unless asked)."""
    proto, _, rest = endpoint.partition("/")
    host, _, port = rest.rpartition(":")
    if proto != "tcp" or not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise BadInputError(
            f"{option} {endpoint!r}: expected tcp/HOST:PORT, e.g. tcp/127.0.0.1:7447"
        )
