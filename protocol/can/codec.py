"""ODrive CANSimple (firmware 0.6) frames <-> typed messages, through ``odrive_cansimple.dbc``.

The arbitration id is 11 bits: ``node_id << 5 | cmd_id`` (node 0..63, cmd 0..31). The DBC holds
one message set, for node 0 (its frame ids are the cmd ids), as ODrive's own DBC does; the codec
computes the id of any node and looks the message up by ``cmd_id``. Generating one message per
node would change nothing on the wire and would tie the DBC file to a node assignment that the
scenario's ``[can]`` table owns.

Decoding is strict: every frame is either one typed message or one :class:`CanDecodeError` with
a ``reason`` (a short stable word, used as the rejection counter's key). Nothing half-decoded is
returned. Following the firmware, a payload may be longer than the bytes its signals need (up
to 8) but never shorter; missing trailing bytes are the commonest real wiring/tool mistake.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from enum import IntEnum
from functools import cache, lru_cache
from importlib import resources
from typing import NamedTuple

import cantools

DBC_NAME = "odrive_cansimple.dbc"
MAX_NODE_ID = 0x3F


class Cmd(IntEnum):
    """CANSimple command ids used by the profile."""

    HEARTBEAT = 0x01
    ESTOP = 0x02
    SET_AXIS_STATE = 0x07
    GET_ENCODER_ESTIMATES = 0x09
    SET_CONTROLLER_MODE = 0x0B
    SET_INPUT_TORQUE = 0x0E
    CLEAR_ERRORS = 0x18


class AxisState(IntEnum):
    UNDEFINED = 0
    IDLE = 1
    STARTUP_SEQUENCE = 2
    FULL_CALIBRATION_SEQUENCE = 3
    MOTOR_CALIBRATION = 4
    SENSORLESS_CONTROL = 5
    ENCODER_INDEX_SEARCH = 6
    ENCODER_OFFSET_CALIBRATION = 7
    CLOSED_LOOP_CONTROL = 8
    LOCKIN_SPIN = 9
    ENCODER_DIR_FIND = 10
    HOMING = 11
    ENCODER_HALL_POLARITY_CALIBRATION = 12
    ENCODER_HALL_PHASE_CALIBRATION = 13
    ANTICOGGING_CALIBRATION = 14


class ControlMode(IntEnum):
    VOLTAGE_CONTROL = 0
    TORQUE_CONTROL = 1
    VELOCITY_CONTROL = 2
    POSITION_CONTROL = 3


class InputMode(IntEnum):
    INACTIVE = 0
    PASSTHROUGH = 1
    VEL_RAMP = 2
    POS_FILTER = 3
    MIX_CHANNELS = 4
    TRAP_TRAJ = 5
    TORQUE_RAMP = 6
    MIRROR = 7
    TUNING = 8


class AxisError(IntEnum):
    """The firmware 0.6 ODriveError bits this profile sets itself."""

    NONE = 0
    ESTOP_REQUESTED = 0x02000000


class CanDecodeError(ValueError):
    """A frame that is not a valid message of the profile; ``reason`` keys the counter."""

    def __init__(self, reason: str, detail: str = "") -> None:
        super().__init__(f"{reason}: {detail}" if detail else reason)
        self.reason = reason


class CanEncodeError(ValueError):
    """A message that cannot be put on the wire (bad node id, non-finite float)."""


class Frame(NamedTuple):
    """A classical CAN frame, transport free (python-can's ``Message`` lives at the edges)."""

    arbitration_id: int
    data: bytes
    is_remote: bool = False
    is_extended: bool = False


# Typed messages. ``node`` is the CANSimple node id of the axis the frame is about.
@dataclass(frozen=True)
class Heartbeat:
    node: int
    axis_error: int
    axis_state: int
    procedure_result: int = 0
    trajectory_done: bool = False


@dataclass(frozen=True)
class Estop:
    node: int


@dataclass(frozen=True)
class SetAxisState:
    node: int
    requested_state: int


@dataclass(frozen=True)
class EncoderEstimates:
    node: int
    pos_rev: float
    vel_rev_s: float


@dataclass(frozen=True)
class SetControllerMode:
    node: int
    control_mode: int
    input_mode: int


@dataclass(frozen=True)
class SetInputTorque:
    node: int
    torque_nm: float


@dataclass(frozen=True)
class ClearErrors:
    node: int
    identify: int = 0


@dataclass(frozen=True)
class Request:
    """A remote (RTR) frame asking the drive for ``cmd`` (Heartbeat or Encoder estimates)."""

    node: int
    cmd: Cmd


Message = (
    Heartbeat
    | Estop
    | SetAxisState
    | EncoderEstimates
    | SetControllerMode
    | SetInputTorque
    | ClearErrors
    | Request
)

_NAMES = {
    Cmd.HEARTBEAT: "Axis0_Heartbeat",
    Cmd.ESTOP: "Axis0_Estop",
    Cmd.SET_AXIS_STATE: "Axis0_Set_Axis_State",
    Cmd.GET_ENCODER_ESTIMATES: "Axis0_Get_Encoder_Estimates",
    Cmd.SET_CONTROLLER_MODE: "Axis0_Set_Controller_Mode",
    Cmd.SET_INPUT_TORQUE: "Axis0_Set_Input_Torque",
    Cmd.CLEAR_ERRORS: "Axis0_Clear_Errors",
}
_REQUESTABLE = frozenset({Cmd.HEARTBEAT, Cmd.GET_ENCODER_ESTIMATES})
_ENUMS = {
    "Axis_State": AxisState,
    "Axis_Requested_State": AxisState,
    "Control_Mode": ControlMode,
    "Input_Mode": InputMode,
}


@lru_cache(maxsize=1)
def database() -> cantools.database.can.Database:
    """The profile's DBC, loaded once."""
    text = resources.files("protocol.can").joinpath(DBC_NAME).read_text(encoding="utf-8")
    return cantools.database.load_string(text, database_format="dbc")


@cache
def _message(cmd: Cmd):
    return database().get_message_by_name(_NAMES[cmd])


@cache
def min_payload(cmd: Cmd) -> int:
    """Bytes the signals of ``cmd`` need (a longer payload, up to 8, is accepted)."""
    if cmd is Cmd.CLEAR_ERRORS:
        return 0  # Identify is optional: firmware before 0.6 took Clear_Errors with no data
    msg = _message(cmd)
    end_bits = [s.start + s.length for s in msg.signals]
    return (max(end_bits) + 7) // 8 if end_bits else 0


def frame_id(node: int, cmd: int) -> int:
    """``node_id << 5 | cmd_id``, the CANSimple 11-bit arbitration id."""
    if not 0 <= node <= MAX_NODE_ID:
        raise CanEncodeError(f"node id {node} outside 0..{MAX_NODE_ID}")
    return (node << 5) | (int(cmd) & 0x1F)


def split_id(arbitration_id: int) -> tuple[int, int]:
    """(node_id, cmd_id) of an 11-bit arbitration id."""
    return arbitration_id >> 5, arbitration_id & 0x1F


def _finite32(name: str, value: float) -> float:
    if not math.isfinite(value):
        raise CanEncodeError(f"{name} must be finite, got {value!r}")
    try:
        struct.pack("<f", value)
    except OverflowError as exc:
        raise CanEncodeError(f"{name} {value!r} does not fit a float32") from exc
    return value


def encode(msg: Message) -> Frame:
    """The frame of a typed message (lengths as in the DBC, unused bytes zero)."""
    if isinstance(msg, Request):
        return Frame(frame_id(msg.node, msg.cmd), b"", is_remote=True)
    if isinstance(msg, Heartbeat):
        cmd, sig = (
            Cmd.HEARTBEAT,
            {
                "Axis_Error": msg.axis_error,
                "Axis_State": msg.axis_state,
                "Procedure_Result": msg.procedure_result,
                "Trajectory_Done_Flag": int(msg.trajectory_done),
            },
        )
    elif isinstance(msg, Estop):
        cmd, sig = Cmd.ESTOP, {}
    elif isinstance(msg, SetAxisState):
        cmd, sig = Cmd.SET_AXIS_STATE, {"Axis_Requested_State": msg.requested_state}
    elif isinstance(msg, EncoderEstimates):
        cmd, sig = (
            Cmd.GET_ENCODER_ESTIMATES,
            {
                "Pos_Estimate": _finite32("pos_rev", msg.pos_rev),
                "Vel_Estimate": _finite32("vel_rev_s", msg.vel_rev_s),
            },
        )
    elif isinstance(msg, SetControllerMode):
        cmd, sig = (
            Cmd.SET_CONTROLLER_MODE,
            {
                "Control_Mode": msg.control_mode,
                "Input_Mode": msg.input_mode,
            },
        )
    elif isinstance(msg, SetInputTorque):
        cmd, sig = Cmd.SET_INPUT_TORQUE, {"Input_Torque": _finite32("torque_nm", msg.torque_nm)}
    elif isinstance(msg, ClearErrors):
        cmd, sig = Cmd.CLEAR_ERRORS, {"Identify": msg.identify}
    else:
        raise CanEncodeError(f"not a CANSimple message: {msg!r}")
    try:
        data = _message(cmd).encode(sig, scaling=False, strict=True)
    except Exception as exc:  # cantools raises several types for out-of-range values
        raise CanEncodeError(f"{_NAMES[cmd]}: {exc}") from exc
    return Frame(frame_id(msg.node, cmd), bytes(data))


def decode(frame: Frame, nodes: frozenset[int] | None = None) -> Message:
    """The typed message of ``frame`` or :class:`CanDecodeError` (never anything else).

    ``nodes``: the node ids this side talks to; frames of other nodes are rejected.
    """
    try:
        return _decode(frame, nodes)
    except CanDecodeError:
        raise
    except Exception as exc:  # a cantools surprise must still be a counted rejection
        raise CanDecodeError("malformed", repr(exc)) from exc


def _decode(frame: Frame, nodes: frozenset[int] | None) -> Message:
    if frame.is_extended:
        raise CanDecodeError("extended_id", hex(frame.arbitration_id))
    if not 0 <= frame.arbitration_id <= 0x7FF:
        raise CanDecodeError("bad_id", hex(frame.arbitration_id))
    node, cmd_id = split_id(frame.arbitration_id)
    try:
        cmd = Cmd(cmd_id)
    except ValueError:
        raise CanDecodeError("unknown_cmd", hex(frame.arbitration_id)) from None
    if nodes is not None and node not in nodes:
        raise CanDecodeError("unknown_node", f"node {node}")
    data = bytes(frame.data)
    if frame.is_remote:
        if cmd not in _REQUESTABLE:
            raise CanDecodeError("unexpected_rtr", cmd.name)
        return Request(node, cmd)
    if not min_payload(cmd) <= len(data) <= 8:
        raise CanDecodeError("wrong_dlc", f"{cmd.name} with {len(data)} bytes")
    msg = _message(cmd)
    padded = data[: msg.length].ljust(msg.length, b"\x00")
    sig = msg.decode(padded, decode_choices=False, scaling=False) if msg.length else {}
    for name, enum in _ENUMS.items():
        if name in sig and int(sig[name]) not in enum._value2member_map_:
            raise CanDecodeError("out_of_range", f"{name}={sig[name]}")
    for name, value in sig.items():
        if isinstance(value, float) and not math.isfinite(value):
            raise CanDecodeError("non_finite", f"{name}={value}")
    if cmd is Cmd.HEARTBEAT:
        return Heartbeat(
            node,
            int(sig["Axis_Error"]),
            int(sig["Axis_State"]),
            int(sig["Procedure_Result"]),
            bool(sig["Trajectory_Done_Flag"]),
        )
    if cmd is Cmd.ESTOP:
        return Estop(node)
    if cmd is Cmd.SET_AXIS_STATE:
        return SetAxisState(node, int(sig["Axis_Requested_State"]))
    if cmd is Cmd.GET_ENCODER_ESTIMATES:
        return EncoderEstimates(node, float(sig["Pos_Estimate"]), float(sig["Vel_Estimate"]))
    if cmd is Cmd.SET_CONTROLLER_MODE:
        return SetControllerMode(node, int(sig["Control_Mode"]), int(sig["Input_Mode"]))
    if cmd is Cmd.SET_INPUT_TORQUE:
        return SetInputTorque(node, float(sig["Input_Torque"]))
    return ClearErrors(node, int(sig.get("Identify", 0)))
