"""ODrive CANSimple (firmware 0.6) frames <-> typed messages, through ``odrive_cansimple.dbc``.

The arbitration id is 11 bits: ``node_id << 5 | cmd_id`` (node 0..63, cmd 0..31). Every
message of the 0.6 protocol has a typed class here (the table of signals is
:mod:`protocol.can.dbc`, which also renders the DBC). The shipped DBC holds the message sets of
axes 0-7, as ODrive's own DBC does; the codec computes the id of any node and looks the
message layout up by ``cmd_id`` (node 0's message of that cmd).

Requests. A ``Get_*`` message (and Heartbeat, Address) is requested with a remote (RTR) frame of
its id, or, as the protocol page allows, with a data frame of that id and no payload: both
decode to :class:`Request`.

Decoding is strict: every frame is either one typed message or one :class:`CanDecodeError` with
a ``reason`` (a short stable word, used as the rejection counter's key). Nothing half-decoded is
returned. Following the firmware, a payload may be longer than the bytes its signals need (up
to 8) but never shorter; missing trailing bytes are the commonest real wiring/tool mistake.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass, fields
from enum import IntEnum, IntFlag
from functools import cache, lru_cache
from importlib import resources
from typing import Any, NamedTuple

import cantools

from protocol.can.dbc import BY_CMD

DBC_NAME = "odrive_cansimple.dbc"
MAX_NODE_ID = 0x3F
BROADCAST_NODE = 0x3F  # Address (discovery) requests to every drive


class Cmd(IntEnum):
    """CANSimple 0.6 command ids."""

    GET_VERSION = 0x00
    HEARTBEAT = 0x01
    ESTOP = 0x02
    GET_ERROR = 0x03
    RX_SDO = 0x04
    TX_SDO = 0x05
    ADDRESS = 0x06
    SET_AXIS_STATE = 0x07
    GET_ENCODER_ESTIMATES = 0x09
    SET_CONTROLLER_MODE = 0x0B
    SET_INPUT_POS = 0x0C
    SET_INPUT_VEL = 0x0D
    SET_INPUT_TORQUE = 0x0E
    SET_LIMITS = 0x0F
    SET_TRAJ_VEL_LIMIT = 0x11
    SET_TRAJ_ACCEL_LIMITS = 0x12
    SET_TRAJ_INERTIA = 0x13
    GET_IQ = 0x14
    GET_TEMPERATURE = 0x15
    REBOOT = 0x16
    GET_BUS_VOLTAGE_CURRENT = 0x17
    CLEAR_ERRORS = 0x18
    SET_ABSOLUTE_POSITION = 0x19
    SET_POS_GAIN = 0x1A
    SET_VEL_GAINS = 0x1B
    GET_TORQUES = 0x1C
    GET_POWERS = 0x1D
    ENTER_DFU_MODE = 0x1F


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


class ProcedureResult(IntEnum):
    SUCCESS = 0
    BUSY = 1
    CANCELLED = 2
    DISARMED = 3
    NO_RESPONSE = 4
    POLE_PAIR_CPR_MISMATCH = 5
    PHASE_RESISTANCE_OUT_OF_RANGE = 6
    PHASE_INDUCTANCE_OUT_OF_RANGE = 7
    UNBALANCED_PHASES = 8
    INVALID_MOTOR_TYPE = 9
    ILLEGAL_HALL_STATE = 10
    TIMEOUT = 11
    HOMING_WITHOUT_ENDSTOP = 12
    INVALID_STATE = 13
    NOT_CALIBRATED = 14
    NOT_CONVERGING = 15


class ODriveError(IntFlag):
    """ODrive.Error of firmware 0.6 (Heartbeat's Axis_Error, Get_Error's two fields)."""

    NONE = 0
    INITIALIZING = 0x1
    SYSTEM_LEVEL = 0x2
    TIMING_ERROR = 0x4
    MISSING_ESTIMATE = 0x8
    BAD_CONFIG = 0x10
    DRV_FAULT = 0x20
    MISSING_INPUT = 0x40
    DC_BUS_OVER_VOLTAGE = 0x100
    DC_BUS_UNDER_VOLTAGE = 0x200
    DC_BUS_OVER_CURRENT = 0x400
    DC_BUS_OVER_REGEN_CURRENT = 0x800
    CURRENT_LIMIT_VIOLATION = 0x1000
    MOTOR_OVER_TEMP = 0x2000
    INVERTER_OVER_TEMP = 0x4000
    VELOCITY_LIMIT_VIOLATION = 0x8000
    POSITION_LIMIT_VIOLATION = 0x10000
    WATCHDOG_TIMER_EXPIRED = 0x1000000
    ESTOP_REQUESTED = 0x2000000
    SPINOUT_DETECTED = 0x4000000
    BRAKE_RESISTOR_DISARMED = 0x8000000
    THERMISTOR_DISCONNECTED = 0x10000000
    CALIBRATION_ERROR = 0x40000000


AxisError = ODriveError  # the name the profile used before the full 0.6 set


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


# --- typed messages. ``node`` is the CANSimple node id of the axis the frame is about. ------
# Drive -> host.
@dataclass(frozen=True)
class Version:
    node: int
    protocol_version: int = 2
    hw_version_major: int = 0
    hw_version_minor: int = 0
    hw_version_variant: int = 0
    fw_version_major: int = 0
    fw_version_minor: int = 0
    fw_version_revision: int = 0
    fw_version_unreleased: int = 0


@dataclass(frozen=True)
class Heartbeat:
    node: int
    axis_error: int
    axis_state: int
    procedure_result: int = 0
    trajectory_done: bool = False


@dataclass(frozen=True)
class ErrorStatus:
    """Get_Error: the axis' active errors and the reason of its last disarm."""

    node: int
    active_errors: int
    disarm_reason: int


@dataclass(frozen=True)
class TxSdo:
    node: int
    endpoint_id: int
    value: int
    reserved0: int = 0
    reserved1: int = 0


@dataclass(frozen=True)
class EncoderEstimates:
    node: int
    pos_rev: float
    vel_rev_s: float


@dataclass(frozen=True)
class Iq:
    node: int
    iq_setpoint: float
    iq_measured: float


@dataclass(frozen=True)
class Temperature:
    node: int
    fet_temperature: float
    motor_temperature: float


@dataclass(frozen=True)
class BusVoltageCurrent:
    node: int
    bus_voltage: float
    bus_current: float


@dataclass(frozen=True)
class Torques:
    node: int
    torque_target: float
    torque_estimate: float


@dataclass(frozen=True)
class Powers:
    node: int
    electrical_power: float
    mechanical_power: float


# Host -> drive (Address goes both ways: a data frame asks a drive to take a node id, the
# drive answers a discovery request with one).
@dataclass(frozen=True)
class Estop:
    node: int


@dataclass(frozen=True)
class RxSdo:
    node: int
    opcode: int
    endpoint_id: int
    value: int
    reserved: int = 0


@dataclass(frozen=True)
class Address:
    node: int
    node_id: int
    serial_number: int


@dataclass(frozen=True)
class SetAxisState:
    node: int
    requested_state: int


@dataclass(frozen=True)
class SetControllerMode:
    node: int
    control_mode: int
    input_mode: int


@dataclass(frozen=True)
class SetInputPos:
    node: int
    input_pos: float
    vel_ff: float = 0.0
    torque_ff: float = 0.0


@dataclass(frozen=True)
class SetInputVel:
    node: int
    input_vel: float
    torque_ff: float = 0.0


@dataclass(frozen=True)
class SetInputTorque:
    node: int
    torque_nm: float


@dataclass(frozen=True)
class SetLimits:
    node: int
    velocity_limit: float
    current_limit: float


@dataclass(frozen=True)
class SetTrajVelLimit:
    node: int
    traj_vel_limit: float


@dataclass(frozen=True)
class SetTrajAccelLimits:
    node: int
    accel_limit: float
    decel_limit: float


@dataclass(frozen=True)
class SetTrajInertia:
    node: int
    inertia: float


@dataclass(frozen=True)
class Reboot:
    node: int
    action: int = 0


@dataclass(frozen=True)
class ClearErrors:
    node: int
    identify: int = 0


@dataclass(frozen=True)
class SetAbsolutePosition:
    node: int
    position: float


@dataclass(frozen=True)
class SetPosGain:
    node: int
    pos_gain: float


@dataclass(frozen=True)
class SetVelGains:
    node: int
    vel_gain: float
    vel_integrator_gain: float


@dataclass(frozen=True)
class EnterDfuMode:
    node: int


@dataclass(frozen=True)
class Request:
    """A request (RTR frame, or a data frame with no payload) for the drive's ``cmd`` message."""

    node: int
    cmd: Cmd


Message = (
    Version
    | Heartbeat
    | ErrorStatus
    | TxSdo
    | EncoderEstimates
    | Iq
    | Temperature
    | BusVoltageCurrent
    | Torques
    | Powers
    | Estop
    | RxSdo
    | Address
    | SetAxisState
    | SetControllerMode
    | SetInputPos
    | SetInputVel
    | SetInputTorque
    | SetLimits
    | SetTrajVelLimit
    | SetTrajAccelLimits
    | SetTrajInertia
    | Reboot
    | ClearErrors
    | SetAbsolutePosition
    | SetPosGain
    | SetVelGains
    | EnterDfuMode
    | Request
)

# class -> (cmd, ((field, DBC signal), ...)) in the field order of the class (after node).
_LAYOUT: dict[type, tuple[Cmd, tuple[tuple[str, str], ...]]] = {
    Version: (
        Cmd.GET_VERSION,
        (
            ("protocol_version", "Protocol_Version"),
            ("hw_version_major", "Hw_Version_Major"),
            ("hw_version_minor", "Hw_Version_Minor"),
            ("hw_version_variant", "Hw_Version_Variant"),
            ("fw_version_major", "Fw_Version_Major"),
            ("fw_version_minor", "Fw_Version_Minor"),
            ("fw_version_revision", "Fw_Version_Revision"),
            ("fw_version_unreleased", "Fw_Version_Unreleased"),
        ),
    ),
    Heartbeat: (
        Cmd.HEARTBEAT,
        (
            ("axis_error", "Axis_Error"),
            ("axis_state", "Axis_State"),
            ("procedure_result", "Procedure_Result"),
            ("trajectory_done", "Trajectory_Done_Flag"),
        ),
    ),
    Estop: (Cmd.ESTOP, ()),
    ErrorStatus: (
        Cmd.GET_ERROR,
        (("active_errors", "Active_Errors"), ("disarm_reason", "Disarm_Reason")),
    ),
    RxSdo: (
        Cmd.RX_SDO,
        (
            ("opcode", "Opcode"),
            ("endpoint_id", "Endpoint_ID"),
            ("value", "Value"),
            ("reserved", "Reserved"),
        ),
    ),
    TxSdo: (
        Cmd.TX_SDO,
        (
            ("endpoint_id", "Endpoint_ID"),
            ("value", "Value"),
            ("reserved0", "Reserved0"),
            ("reserved1", "Reserved1"),
        ),
    ),
    Address: (Cmd.ADDRESS, (("node_id", "Node_ID"), ("serial_number", "Serial_Number"))),
    SetAxisState: (Cmd.SET_AXIS_STATE, (("requested_state", "Axis_Requested_State"),)),
    EncoderEstimates: (
        Cmd.GET_ENCODER_ESTIMATES,
        (("pos_rev", "Pos_Estimate"), ("vel_rev_s", "Vel_Estimate")),
    ),
    SetControllerMode: (
        Cmd.SET_CONTROLLER_MODE,
        (("control_mode", "Control_Mode"), ("input_mode", "Input_Mode")),
    ),
    SetInputPos: (
        Cmd.SET_INPUT_POS,
        (("input_pos", "Input_Pos"), ("vel_ff", "Vel_FF"), ("torque_ff", "Torque_FF")),
    ),
    SetInputVel: (
        Cmd.SET_INPUT_VEL,
        (("input_vel", "Input_Vel"), ("torque_ff", "Input_Torque_FF")),
    ),
    SetInputTorque: (Cmd.SET_INPUT_TORQUE, (("torque_nm", "Input_Torque"),)),
    SetLimits: (
        Cmd.SET_LIMITS,
        (("velocity_limit", "Velocity_Limit"), ("current_limit", "Current_Limit")),
    ),
    SetTrajVelLimit: (Cmd.SET_TRAJ_VEL_LIMIT, (("traj_vel_limit", "Traj_Vel_Limit"),)),
    SetTrajAccelLimits: (
        Cmd.SET_TRAJ_ACCEL_LIMITS,
        (("accel_limit", "Traj_Accel_Limit"), ("decel_limit", "Traj_Decel_Limit")),
    ),
    SetTrajInertia: (Cmd.SET_TRAJ_INERTIA, (("inertia", "Traj_Inertia"),)),
    Iq: (Cmd.GET_IQ, (("iq_setpoint", "Iq_Setpoint"), ("iq_measured", "Iq_Measured"))),
    Temperature: (
        Cmd.GET_TEMPERATURE,
        (("fet_temperature", "FET_Temperature"), ("motor_temperature", "Motor_Temperature")),
    ),
    Reboot: (Cmd.REBOOT, (("action", "Action"),)),
    BusVoltageCurrent: (
        Cmd.GET_BUS_VOLTAGE_CURRENT,
        (("bus_voltage", "Bus_Voltage"), ("bus_current", "Bus_Current")),
    ),
    ClearErrors: (Cmd.CLEAR_ERRORS, (("identify", "Identify"),)),
    SetAbsolutePosition: (Cmd.SET_ABSOLUTE_POSITION, (("position", "Position"),)),
    SetPosGain: (Cmd.SET_POS_GAIN, (("pos_gain", "Pos_Gain"),)),
    SetVelGains: (
        Cmd.SET_VEL_GAINS,
        (("vel_gain", "Vel_Gain"), ("vel_integrator_gain", "Vel_Integrator_Gain")),
    ),
    Torques: (
        Cmd.GET_TORQUES,
        (("torque_target", "Torque_Target"), ("torque_estimate", "Torque_Estimate")),
    ),
    Powers: (
        Cmd.GET_POWERS,
        (("electrical_power", "Electrical_Power"), ("mechanical_power", "Mechanical_Power")),
    ),
    EnterDfuMode: (Cmd.ENTER_DFU_MODE, ()),
}
_CLASS_OF = {cmd: cls for cls, (cmd, _) in _LAYOUT.items()}

# What a drive can be asked for (RTR or empty data frame): its drive -> host messages, plus
# Address (discovery). TxSdo is only ever an answer to an RxSdo.
REQUESTABLE = frozenset(
    {
        Cmd.GET_VERSION,
        Cmd.HEARTBEAT,
        Cmd.GET_ERROR,
        Cmd.ADDRESS,
        Cmd.GET_ENCODER_ESTIMATES,
        Cmd.GET_IQ,
        Cmd.GET_TEMPERATURE,
        Cmd.GET_BUS_VOLTAGE_CURRENT,
        Cmd.GET_TORQUES,
        Cmd.GET_POWERS,
    }
)
DRIVE_TO_HOST = (
    Version,
    Heartbeat,
    ErrorStatus,
    TxSdo,
    EncoderEstimates,
    Iq,
    Temperature,
    BusVoltageCurrent,
    Torques,
    Powers,
)
HOST_TO_DRIVE = (
    Estop,
    RxSdo,
    SetAxisState,
    SetControllerMode,
    SetInputPos,
    SetInputVel,
    SetInputTorque,
    SetLimits,
    SetTrajVelLimit,
    SetTrajAccelLimits,
    SetTrajInertia,
    Reboot,
    ClearErrors,
    SetAbsolutePosition,
    SetPosGain,
    SetVelGains,
    EnterDfuMode,
    Request,
)
_ENUMS: dict[str, type[IntEnum]] = {
    "Axis_State": AxisState,
    "Axis_Requested_State": AxisState,
    "Control_Mode": ControlMode,
    "Input_Mode": InputMode,
}
_SMALL_ENUMS = {"Action": 3, "Opcode": 1}  # largest valid value


@lru_cache(maxsize=1)
def database() -> cantools.database.can.Database:
    """The profile's DBC, loaded once."""
    text = resources.files("protocol.can").joinpath(DBC_NAME).read_text(encoding="utf-8")
    return cantools.database.load_string(text, database_format="dbc")


@cache
def _message(cmd: Cmd):
    return database().get_message_by_frame_id(int(cmd))  # node 0's message of that cmd


def message_name(cmd: int) -> str:
    """The protocol's name of ``cmd`` (``Set_Input_Torque``), or ``cmd_0x..`` if unknown."""
    spec = BY_CMD.get(int(cmd))
    return spec.name if spec else f"cmd_0x{int(cmd):02x}"


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


def is_request(frame: Frame) -> bool:
    """True for a standard-id frame asking for a requestable message (RTR, or no payload)."""
    if frame.is_extended or not 0 <= frame.arbitration_id <= 0x7FF:
        return False
    cmd = frame.arbitration_id & 0x1F
    return cmd in REQUESTABLE and (frame.is_remote or len(frame.data) == 0)


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
    layout = _LAYOUT.get(type(msg))
    if layout is None:
        raise CanEncodeError(f"not a CANSimple message: {msg!r}")
    cmd, names = layout
    dbc_msg = _message(cmd)
    sig: dict[str, Any] = {}
    for attr, signal in names:
        value = getattr(msg, attr)
        if dbc_msg.get_signal_by_name(signal).is_float:
            value = _finite32(attr, float(value))
        elif isinstance(value, float) and not math.isfinite(value):
            raise CanEncodeError(f"{attr} must be finite, got {value!r}")
        elif isinstance(value, bool):
            value = int(value)
        sig[signal] = value
    try:
        data = dbc_msg.encode(sig, scaling=True, strict=True) if names else b""
    except Exception as exc:  # cantools raises several types for out-of-range values
        raise CanEncodeError(f"{dbc_msg.name}: {exc}") from exc
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
        if cmd not in REQUESTABLE:
            raise CanDecodeError("unexpected_rtr", cmd.name)
        return Request(node, cmd)
    if not data and cmd in REQUESTABLE:
        return Request(node, cmd)  # the protocol's alternative to RTR: same id, no payload
    if not min_payload(cmd) <= len(data) <= 8:
        raise CanDecodeError("wrong_dlc", f"{cmd.name} with {len(data)} bytes")
    cls = _CLASS_OF[cmd]
    _, names = _LAYOUT[cls]
    if not names:
        return cls(node)
    msg = _message(cmd)
    padded = data[: msg.length].ljust(msg.length, b"\x00")
    sig = msg.decode(padded, decode_choices=False, scaling=True)
    for name, enum in _ENUMS.items():
        if name in sig and int(sig[name]) not in enum._value2member_map_:
            raise CanDecodeError("out_of_range", f"{name}={sig[name]}")
    for name, top in _SMALL_ENUMS.items():
        if name in sig and not 0 <= int(sig[name]) <= top:
            raise CanDecodeError("out_of_range", f"{name}={sig[name]}")
    for name, value in sig.items():
        if isinstance(value, float) and not math.isfinite(value):
            raise CanDecodeError("non_finite", f"{name}={value}")
    kwargs: dict[str, Any] = {}
    float_fields = {f.name for f in fields(cls) if f.type in ("float", float)}
    for attr, signal in names:
        value = sig[signal]
        if attr in float_fields:
            kwargs[attr] = float(value)
        elif attr == "trajectory_done":
            kwargs[attr] = bool(value)
        else:
            kwargs[attr] = int(value)
    return cls(node, **kwargs)
