"""The drive lifecycle a real ODrive (firmware 0.6, CANSimple) needs, as pure state machines.

Host side (:class:`HostLifecycle`, the controller): for each drive it sends Clear_Errors,
Set_Controller_Mode(TORQUE_CONTROL, PASSTHROUGH) and Set_Axis_State(CLOSED_LOOP_CONTROL), then
waits for heartbeats that report CLOSED_LOOP_CONTROL with no error on BOTH drives before any
torque leaves it: a torque sent earlier would be ignored by a real drive (or act on one wheel
only). On exit it sends zero torque and IDLE (or Estop).

The drive side (virtual ODrives) is the plant emulator's: :mod:`plant_emulator.odrive`.

The host takes explicit time (seconds, any monotonic origin) and returns the frames to send; it
does no I/O. Every frame that is not a valid message for this side is a counted rejection
(``RejectionCounter.count(reason)``), never an exception.
"""

from __future__ import annotations

import math
import struct
from collections import Counter
from dataclasses import dataclass, field
from enum import Enum

from protocol.can import codec
from protocol.can.codec import (
    AxisState,
    CanDecodeError,
    ClearErrors,
    ControlMode,
    EncoderEstimates,
    Estop,
    Frame,
    Heartbeat,
    InputMode,
    SetAxisState,
    SetControllerMode,
    SetInputTorque,
)
from protocol.rejections import RejectionCounter

_HOST_TO_DRIVE = codec.HOST_TO_DRIVE


class Phase(Enum):
    IDLE = "idle"  # nothing sent yet
    ARMING = "arming"  # lifecycle sent, waiting for closed-loop heartbeats
    ACTIVE = "active"  # both drives in closed loop: torques go out
    FAULT = "fault"  # a drive reported an error, left closed loop or went silent
    STOPPED = "stopped"  # IDLE or Estop sent


def _float32_within(q: float, limit: float) -> float:
    """The float32 nearest ``q`` whose magnitude does not exceed ``limit`` (the wire rounds to
    nearest, which may step just past the limit a drive enforces)."""
    f = struct.unpack("<f", struct.pack("<f", q))[0]
    if abs(f) <= limit:
        return f
    bits = struct.unpack("<I", struct.pack("<f", f))[0] - 1  # one ulp toward zero
    return struct.unpack("<f", struct.pack("<I", bits))[0]


@dataclass
class DriveView:
    """What the host last heard from one drive."""

    axis_state: int = AxisState.UNDEFINED
    axis_error: int = 0
    last_heartbeat: float | None = None
    pos_rev: float | None = None
    vel_rev_s: float | None = None
    last_estimate: float | None = None
    heartbeats: int = 0
    estimates: int = 0


@dataclass
class HostLifecycle:
    """Host side of the lifecycle for the two drives (``node_right``, ``node_left``).

    ``heartbeat_timeout``: an ACTIVE drive silent for longer is a FAULT (the firmware's default
    heartbeat period is 100 ms). ``retry_period``: while ARMING, the sequence is re-sent this
    often (a drive may boot after the host).
    """

    node_right: int = 1
    node_left: int = 0
    heartbeat_timeout: float = 0.5
    retry_period: float = 0.5
    torque_limit: float = math.inf
    phase: Phase = Phase.IDLE
    fault_reason: str = ""
    rejections: RejectionCounter = field(default_factory=RejectionCounter)
    ignored: Counter = field(default_factory=Counter)
    drives: dict[int, DriveView] = field(default_factory=dict)
    _last_arm: float = -math.inf

    def __post_init__(self) -> None:
        if self.node_left == self.node_right:
            raise ValueError("node_left and node_right must differ")
        for node in (self.node_left, self.node_right):
            codec.frame_id(node, 0)  # validates the node id
            self.drives.setdefault(node, DriveView())

    @property
    def nodes(self) -> frozenset[int]:
        return frozenset((self.node_left, self.node_right))

    def _arm_frames(self) -> list[Frame]:
        frames: list[Frame] = []
        for node in (self.node_right, self.node_left):
            frames += [
                codec.encode(ClearErrors(node)),
                codec.encode(
                    SetControllerMode(node, ControlMode.TORQUE_CONTROL, InputMode.PASSTHROUGH)
                ),
                codec.encode(SetInputTorque(node, 0.0)),
                codec.encode(SetAxisState(node, AxisState.CLOSED_LOOP_CONTROL)),
            ]
        return frames

    def start(self, now: float) -> list[Frame]:
        """Begin arming: the frames of the lifecycle for both drives."""
        self.phase, self.fault_reason, self._last_arm = Phase.ARMING, "", now
        return self._arm_frames()

    def receive(self, now: float, frame: Frame) -> None:
        """Take one received frame; bad frames are counted, never raised."""
        try:
            msg = codec.decode(frame)
        except CanDecodeError as exc:
            self.rejections.count(exc.reason)
            return
        if msg.node not in self.nodes:
            self.ignored["other_node"] += 1
            return
        if isinstance(msg, _HOST_TO_DRIVE):
            # another master on the bus talks to our drives: worth knowing, not acting on
            self.rejections.count("wrong_direction")
            return
        view = self.drives[msg.node]
        if isinstance(msg, Heartbeat):
            view.axis_state, view.axis_error = msg.axis_state, msg.axis_error
            view.last_heartbeat = now
            view.heartbeats += 1
        elif isinstance(msg, EncoderEstimates):
            view.pos_rev, view.vel_rev_s, view.last_estimate = msg.pos_rev, msg.vel_rev_s, now
            view.estimates += 1
        self._update(now)

    def _ready(self, view: DriveView) -> bool:
        """In closed loop without error, by a heartbeat heard since the arming was sent: a view
        from before it (a drive that went silent and faulted) is not its answer. Taken for one,
        a re-arm went ACTIVE at once on the stale heartbeat and faulted again at the next frame
        heard, a re-arm storm (~14,000 frames/s on udp_multicast, which hears its own frames)."""
        fresh = view.last_heartbeat is not None and view.last_heartbeat >= self._last_arm
        return fresh and view.axis_state == AxisState.CLOSED_LOOP_CONTROL and view.axis_error == 0

    def _update(self, now: float) -> None:
        views = [self.drives[n] for n in (self.node_right, self.node_left)]
        if self.phase is Phase.ARMING and all(self._ready(v) for v in views):
            self.phase = Phase.ACTIVE
        elif self.phase is Phase.ACTIVE:
            for node, view in self.drives.items():
                if view.axis_error:
                    self._fault(f"node {node} axis_error 0x{view.axis_error:08x}")
                elif view.axis_state != AxisState.CLOSED_LOOP_CONTROL:
                    self._fault(f"node {node} left closed loop (state {view.axis_state})")
                elif view.last_heartbeat is None or now - view.last_heartbeat > (
                    self.heartbeat_timeout
                ):
                    self._fault(f"node {node} heartbeat timeout")

    def _fault(self, reason: str) -> None:
        self.phase, self.fault_reason = Phase.FAULT, reason

    def tick(self, now: float) -> list[Frame]:
        """Time passes: heartbeat timeouts, and re-sending the lifecycle while arming."""
        self._update(now)
        if self.phase is Phase.ARMING and now - self._last_arm >= self.retry_period:
            self._last_arm = now
            return self._arm_frames()
        return []

    def torque_frames(self, q_right: float, q_left: float) -> list[Frame]:
        """Set_Input_Torque for both drives, only when ACTIVE (else nothing: a drive not in
        closed loop would ignore it). Non-finite torques become 0 and are counted; finite
        ones are clamped to ``torque_limit``."""
        if self.phase is not Phase.ACTIVE:
            return []
        out = []
        for node, q in ((self.node_right, q_right), (self.node_left, q_left)):
            if not math.isfinite(q):
                self.rejections.count("non_finite_command")
                q = 0.0
            limit = self.torque_limit
            q = _float32_within(max(-limit, min(limit, q)), limit)
            out.append(codec.encode(SetInputTorque(node, q)))
        return out

    def stop(self, estop: bool = False) -> list[Frame]:
        """Zero torque, then IDLE (or Estop) for both drives."""
        self.phase = Phase.STOPPED
        frames: list[Frame] = []
        for node in (self.node_right, self.node_left):
            frames.append(codec.encode(SetInputTorque(node, 0.0)))
            frames.append(
                codec.encode(Estop(node) if estop else SetAxisState(node, AxisState.IDLE))
            )
        return frames
