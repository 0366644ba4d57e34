"""The drive lifecycle a real ODrive (firmware 0.6, CANSimple) needs, as pure state machines.

Host side (:class:`HostLifecycle`, the controller): for each drive it sends Clear_Errors,
Set_Controller_Mode(TORQUE_CONTROL, PASSTHROUGH) and Set_Axis_State(CLOSED_LOOP_CONTROL), then
waits for heartbeats that report CLOSED_LOOP_CONTROL with no error on BOTH drives before any
torque leaves it: a torque sent earlier would be ignored by a real drive (or act on one wheel
only). On exit it sends zero torque and IDLE (or Estop).

Drive side (:class:`VirtualDrive`, one per node, used by the plant emulator): holds the axis
state, controller mode, error and last input torque; the torque acts only in closed loop and
torque control; Estop latches ESTOP_REQUESTED with zero torque until Clear_Errors.

Both take explicit time (seconds, any monotonic origin) and return the frames to send; neither
does I/O. Every frame that is not a valid message for this side is a counted rejection
(``RejectionCounter.count(reason)``), never an exception, never a torque beyond the limit.
"""

from __future__ import annotations

import math
import struct
from collections import Counter
from dataclasses import dataclass, field
from enum import Enum

from protocol.can import codec
from protocol.can.codec import (
    AxisError,
    AxisState,
    CanDecodeError,
    ClearErrors,
    Cmd,
    ControlMode,
    EncoderEstimates,
    Estop,
    Frame,
    Heartbeat,
    InputMode,
    Request,
    SetAxisState,
    SetControllerMode,
    SetInputTorque,
)
from protocol.rejections import RejectionCounter

_HOST_TO_DRIVE = (Estop, SetAxisState, SetControllerMode, SetInputTorque, ClearErrors, Request)


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
        return view.axis_state == AxisState.CLOSED_LOOP_CONTROL and view.axis_error == 0

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


@dataclass
class VirtualDrive:
    """Drive side of one ODrive axis, as the firmware 0.6 behaves on CANSimple.

    Starts IDLE in POSITION_CONTROL (the firmware's default mode). ``torque_limit`` is the
    motor torque limit in Nm: a Set_Input_Torque beyond it is rejected (counted) and the last
    valid torque stays, so the applied torque never exceeds the limit.
    """

    node: int
    torque_limit: float
    axis_state: int = AxisState.IDLE
    axis_error: int = 0
    procedure_result: int = 0
    control_mode: int = ControlMode.POSITION_CONTROL
    input_mode: int = InputMode.PASSTHROUGH
    input_torque: float = 0.0
    rejections: RejectionCounter = field(default_factory=RejectionCounter)

    @property
    def torque(self) -> float:
        """The torque the motor applies now (Nm)."""
        if (
            self.axis_state == AxisState.CLOSED_LOOP_CONTROL
            and self.control_mode == ControlMode.TORQUE_CONTROL
        ):
            return self.input_torque
        return 0.0

    def handle(self, msg: codec.Message, pos_rev: float = 0.0, vel_rev_s: float = 0.0):
        """Apply one decoded message addressed to this node; returns frames to answer with."""
        if isinstance(msg, Request):
            if msg.cmd is Cmd.HEARTBEAT:
                return [self.heartbeat()]
            return [self.encoder_estimates(pos_rev, vel_rev_s)]
        if isinstance(msg, Heartbeat | EncoderEstimates):
            self.rejections.count("wrong_direction")
        elif isinstance(msg, Estop):
            self.axis_error |= AxisError.ESTOP_REQUESTED
            self._enter(AxisState.IDLE)
        elif isinstance(msg, ClearErrors):
            self.axis_error = 0
        elif isinstance(msg, SetControllerMode):
            self.control_mode, self.input_mode = msg.control_mode, msg.input_mode
        elif isinstance(msg, SetAxisState):
            self._request_state(msg.requested_state)
        elif isinstance(msg, SetInputTorque):
            self._input_torque(msg.torque_nm)
        return []

    def _enter(self, state: int) -> None:
        self.axis_state = state
        if state != AxisState.CLOSED_LOOP_CONTROL:
            self.input_torque = 0.0  # no stale torque when re-armed

    def _request_state(self, state: int) -> None:
        if state == AxisState.IDLE:
            self._enter(AxisState.IDLE)
        elif state == AxisState.CLOSED_LOOP_CONTROL:
            if self.axis_error:
                self.rejections.count("arm_with_error")
                self.procedure_result = 13  # INVALID_STATE
            else:
                self.procedure_result = 0
                self._enter(AxisState.CLOSED_LOOP_CONTROL)
        else:
            self.rejections.count("unsupported_state")

    def _input_torque(self, torque: float) -> None:
        if not math.isfinite(torque):
            self.rejections.count("non_finite_torque")
        elif abs(torque) > self.torque_limit:
            self.rejections.count("torque_out_of_range")
        elif self.torque_mode_armed():
            self.input_torque = torque
        elif torque != 0.0:
            self.rejections.count("torque_while_disarmed")

    def torque_mode_armed(self) -> bool:
        return (
            self.axis_state == AxisState.CLOSED_LOOP_CONTROL
            and self.control_mode == ControlMode.TORQUE_CONTROL
        )

    def heartbeat(self) -> Frame:
        return codec.encode(
            Heartbeat(self.node, self.axis_error, self.axis_state, self.procedure_result, True)
        )

    def encoder_estimates(self, pos_rev: float, vel_rev_s: float) -> Frame:
        if not (math.isfinite(pos_rev) and math.isfinite(vel_rev_s)):
            self.rejections.count("non_finite_estimate")
            pos_rev, vel_rev_s = 0.0, 0.0
        return codec.encode(EncoderEstimates(self.node, pos_rev, vel_rev_s))


_SLACK = 1e-9  # a tick that lands a rounding error early is on time


def _next_due(due: float, period: float, now: float) -> float:
    """The next due time on the period grid; after a late tick, skip to ``now + period``
    instead of bursting the missed frames."""
    nxt = due + period
    return nxt if nxt > now + _SLACK else now + period


@dataclass
class VirtualDrivePair:
    """The two drives behind one CAN bus, with their periodic messages.

    ``heartbeat_period``/``encoder_period`` are the firmware's heartbeat_rate_ms and
    encoder_rate_ms (defaults 100 ms and 10 ms, as firmware 0.6 ships).
    """

    node_right: int
    node_left: int
    torque_limit: float
    heartbeat_period: float = 0.1
    encoder_period: float = 0.01
    rejections: RejectionCounter = field(default_factory=RejectionCounter)
    ignored: Counter = field(default_factory=Counter)
    drives: dict[int, VirtualDrive] = field(default_factory=dict)
    _next_heartbeat: float = -math.inf
    _next_encoder: float = -math.inf

    def __post_init__(self) -> None:
        if self.node_left == self.node_right:
            raise ValueError("node_left and node_right must differ")
        for node in (self.node_right, self.node_left):
            codec.frame_id(node, 0)
            self.drives[node] = VirtualDrive(node, self.torque_limit, rejections=self.rejections)

    @property
    def right(self) -> VirtualDrive:
        return self.drives[self.node_right]

    @property
    def left(self) -> VirtualDrive:
        return self.drives[self.node_left]

    def receive(
        self, frame: Frame, estimates: dict[int, tuple[float, float]] | None = None
    ) -> list[Frame]:
        """Take one received frame; returns the answers (to RTR requests)."""
        try:
            msg = codec.decode(frame)
        except CanDecodeError as exc:
            self.rejections.count(exc.reason)
            return []
        drive = self.drives.get(msg.node)
        if drive is None:
            self.ignored["other_node"] += 1
            return []
        pos, vel = (estimates or {}).get(msg.node, (0.0, 0.0))
        return drive.handle(msg, pos, vel)

    def due_frames(self, now: float, estimates: dict[int, tuple[float, float]]) -> list[Frame]:
        """Periodic heartbeats and encoder estimates due at ``now``.

        ``estimates``: node -> (pos_rev, vel_rev_s), motor side, from the plant."""
        out: list[Frame] = []
        if now >= self._next_heartbeat - _SLACK:
            self._next_heartbeat = _next_due(self._next_heartbeat, self.heartbeat_period, now)
            out += [d.heartbeat() for d in self.drives.values()]
        if now >= self._next_encoder - _SLACK:
            self._next_encoder = _next_due(self._next_encoder, self.encoder_period, now)
            for node, drive in self.drives.items():
                pos, vel = estimates.get(node, (0.0, 0.0))
                out.append(drive.encoder_estimates(pos, vel))
        return out
