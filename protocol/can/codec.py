"""ODrive CANSimple (firmware 0.6) frames <-> typed messages, through ``odrive_cansimple.dbc``.

The arbitration id is 11 bits: ``node_id << 5 | cmd_id`` (node 0..63, cmd 0..31). The message
set is one table, :data:`protocol.can.dbc.MESSAGES`, which also renders the DBC; :data:`Cmd`,
the field layouts, :data:`REQUESTABLE`, :data:`DRIVE_TO_HOST` and :data:`HOST_TO_DRIVE` are
derived from it, and every message has a typed class here bound to its entry by name (a class
whose fields are not its message's signals fails at import). Adding a message is one
``MessageSpec`` plus one class. The shipped DBC holds the message sets of axes 0-7, as ODrive's
own DBC does; the codec computes the id of any node and looks the message layout up by
``cmd_id`` (node 0's message of that cmd).

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
import re
import struct
from collections.abc import Callable
from dataclasses import dataclass, fields, is_dataclass
from enum import IntEnum, IntFlag
from functools import cache, lru_cache
from importlib import resources
from typing import Any, NamedTuple, TypeVar

import cantools

from protocol.can.dbc import BY_CMD, CHOICES, MESSAGES, Signal

DBC_NAME = "odrive_cansimple.dbc"
MAX_NODE_ID = 0x3F
BROADCAST_NODE = 0x3F  # Address (discovery) requests to every drive


def _member_name(name: str) -> str:
    """``Set_Input_Torque`` -> ``SET_INPUT_TORQUE``, ``RxSdo`` -> ``RX_SDO``."""
    return re.sub(r"(?<=[a-z])(?=[A-Z])", "_", name).upper()


# Built from the table so that a message is added in one place; the member names are the
# protocol's names in upper snake case (Cmd.SET_INPUT_TORQUE, Cmd.GET_ENCODER_ESTIMATES).
Cmd = IntEnum(
    "Cmd", [(_member_name(m.name), m.cmd) for m in MESSAGES], module=__name__, qualname="Cmd"
)
Cmd.__doc__ = "CANSimple 0.6 command ids, one per message of :data:`protocol.can.dbc.MESSAGES`."


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


# --- typed messages ----------------------------------------------------------------------
# Each class carries one message of dbc.MESSAGES (@_carries, by the protocol's name); its
# fields after ``node`` are that message's signals (Signal.field), in any order. The codec's
# tables below are derived from the pairs; a class that does not fit its message fails at import.
@dataclass(frozen=True)
class Message:
    """A CANSimple message; ``node`` is the node id of the axis the frame is about."""

    node: int


_M = TypeVar("_M", bound=Message)
_SPECS = {m.name: m for m in MESSAGES}
# class -> (cmd, ((field, DBC signal), ...)) in the field order of the class (after node)
_LAYOUT: dict[type[Message], tuple[Cmd, tuple[tuple[str, str], ...]]] = {}
_CLASS_OF: dict[Cmd, type[Message]] = {}
_CASTS: dict[type[Message], dict[str, type]] = {}  # field -> float, int or bool


def _field_type(where: str, signal: Signal, annotation: object) -> type:
    """The type the field ``where`` of ``signal`` must have (TypeError if it is annotated
    otherwise): float for a float or scaled signal, bool or int for one bit, else int."""
    name = annotation if isinstance(annotation, str) else getattr(annotation, "__name__", "")
    if signal.is_float or signal.scale != 1.0:
        allowed = {"float": float}
    elif signal.length == 1:
        allowed = {"bool": bool, "int": int}
    else:
        allowed = {"int": int}
    if name not in allowed:
        raise TypeError(f"{where} carries {signal.name}: it must be {' or '.join(allowed)}")
    return allowed[name]


def _carries(name: str) -> Callable[[type[_M]], type[_M]]:
    """Class decorator: the dataclass carries the message ``name`` of dbc.MESSAGES."""
    spec = _SPECS.get(name)
    if spec is None:
        raise TypeError(f"no CANSimple message is called {name!r}")
    cmd = Cmd(spec.cmd)

    def bind(cls: type[_M]) -> type[_M]:
        if not (is_dataclass(cls) and issubclass(cls, Message)):
            raise TypeError(f"{cls.__name__} must be a dataclass subclass of Message")
        own = [f for f in fields(cls) if f.name != "node"]
        by_field = {s.field: s for s in spec.signals}
        if sorted(f.name for f in own) != sorted(by_field) or len(by_field) != len(spec.signals):
            raise TypeError(
                f"{cls.__name__} has fields {[f.name for f in own]}, but {name} has signals "
                f"{[(s.name, s.field) for s in spec.signals]} (Signal.field names each one)"
            )
        casts = {
            f.name: _field_type(f"{cls.__name__}.{f.name}", by_field[f.name], f.type) for f in own
        }
        if cmd in _CLASS_OF or cls in _LAYOUT:
            raise TypeError(f"{cls.__name__} for {name}: each message has one class")
        _LAYOUT[cls] = (cmd, tuple((f.name, by_field[f.name].name) for f in own))
        _CASTS[cls] = casts
        _CLASS_OF[cmd] = cls
        return cls

    return bind


# Drive -> host.
@_carries("Get_Version")
@dataclass(frozen=True)
class Version(Message):
    protocol_version: int = 2
    hw_version_major: int = 0
    hw_version_minor: int = 0
    hw_version_variant: int = 0
    fw_version_major: int = 0
    fw_version_minor: int = 0
    fw_version_revision: int = 0
    fw_version_unreleased: int = 0


@_carries("Heartbeat")
@dataclass(frozen=True)
class Heartbeat(Message):
    axis_error: int
    axis_state: int
    procedure_result: int = 0
    trajectory_done: bool = False


@_carries("Get_Error")
@dataclass(frozen=True)
class ErrorStatus(Message):
    """Get_Error: the axis' active errors and the reason of its last disarm."""

    active_errors: int
    disarm_reason: int


@_carries("TxSdo")
@dataclass(frozen=True)
class TxSdo(Message):
    endpoint_id: int
    value: int
    reserved0: int = 0
    reserved1: int = 0


@_carries("Get_Encoder_Estimates")
@dataclass(frozen=True)
class EncoderEstimates(Message):
    pos_rev: float
    vel_rev_s: float


@_carries("Get_Iq")
@dataclass(frozen=True)
class Iq(Message):
    iq_setpoint: float
    iq_measured: float


@_carries("Get_Temperature")
@dataclass(frozen=True)
class Temperature(Message):
    fet_temperature: float
    motor_temperature: float


@_carries("Get_Bus_Voltage_Current")
@dataclass(frozen=True)
class BusVoltageCurrent(Message):
    bus_voltage: float
    bus_current: float


@_carries("Get_Torques")
@dataclass(frozen=True)
class Torques(Message):
    torque_target: float
    torque_estimate: float


@_carries("Get_Powers")
@dataclass(frozen=True)
class Powers(Message):
    electrical_power: float
    mechanical_power: float


# Host -> drive (Address goes both ways: a data frame asks a drive to take a node id, the
# drive answers a discovery request with one).
@_carries("Estop")
@dataclass(frozen=True)
class Estop(Message):
    pass


@_carries("RxSdo")
@dataclass(frozen=True)
class RxSdo(Message):
    opcode: int
    endpoint_id: int
    value: int
    reserved: int = 0


@_carries("Address")
@dataclass(frozen=True)
class Address(Message):
    node_id: int
    serial_number: int


@_carries("Set_Axis_State")
@dataclass(frozen=True)
class SetAxisState(Message):
    requested_state: int


@_carries("Set_Controller_Mode")
@dataclass(frozen=True)
class SetControllerMode(Message):
    control_mode: int
    input_mode: int


@_carries("Set_Input_Pos")
@dataclass(frozen=True)
class SetInputPos(Message):
    input_pos: float
    vel_ff: float = 0.0
    torque_ff: float = 0.0


@_carries("Set_Input_Vel")
@dataclass(frozen=True)
class SetInputVel(Message):
    input_vel: float
    torque_ff: float = 0.0


@_carries("Set_Input_Torque")
@dataclass(frozen=True)
class SetInputTorque(Message):
    torque_nm: float


@_carries("Set_Limits")
@dataclass(frozen=True)
class SetLimits(Message):
    velocity_limit: float
    current_limit: float


@_carries("Set_Traj_Vel_Limit")
@dataclass(frozen=True)
class SetTrajVelLimit(Message):
    traj_vel_limit: float


@_carries("Set_Traj_Accel_Limits")
@dataclass(frozen=True)
class SetTrajAccelLimits(Message):
    accel_limit: float
    decel_limit: float


@_carries("Set_Traj_Inertia")
@dataclass(frozen=True)
class SetTrajInertia(Message):
    inertia: float


@_carries("Reboot")
@dataclass(frozen=True)
class Reboot(Message):
    action: int = 0


@_carries("Clear_Errors")
@dataclass(frozen=True)
class ClearErrors(Message):
    identify: int = 0


@_carries("Set_Absolute_Position")
@dataclass(frozen=True)
class SetAbsolutePosition(Message):
    position: float


@_carries("Set_Pos_Gain")
@dataclass(frozen=True)
class SetPosGain(Message):
    pos_gain: float


@_carries("Set_Vel_Gains")
@dataclass(frozen=True)
class SetVelGains(Message):
    vel_gain: float
    vel_integrator_gain: float


@_carries("Enter_DFU_Mode")
@dataclass(frozen=True)
class EnterDfuMode(Message):
    pass


@dataclass(frozen=True)
class Request(Message):
    """A request (RTR frame, or a data frame with no payload) for the drive's ``cmd`` message."""

    cmd: Cmd


_UNCARRIED = [m.name for m in MESSAGES if Cmd(m.cmd) not in _CLASS_OF]
if _UNCARRIED:
    raise TypeError(f"no codec class carries {_UNCARRIED}: add one with @_carries")

# What a drive can be asked for (RTR or empty data frame): MessageSpec.requestable, which is
# its drive -> host messages but TxSdo (only ever an answer to an RxSdo), plus Address.
REQUESTABLE = frozenset(Cmd(m.cmd) for m in MESSAGES if m.requestable)
DRIVE_TO_HOST = tuple(_CLASS_OF[Cmd(m.cmd)] for m in MESSAGES if m.sender == "drive")
# a requestable host message (Address) is also the drive's answer: it goes both ways
HOST_TO_DRIVE = (
    *(_CLASS_OF[Cmd(m.cmd)] for m in MESSAGES if m.sender == "host" and not m.requestable),
    Request,
)
_ENUMS: dict[str, type[IntEnum]] = {
    "Axis_State": AxisState,
    "Axis_Requested_State": AxisState,
    "Control_Mode": ControlMode,
    "Input_Mode": InputMode,
}
_SMALL_ENUMS = {  # largest valid value
    "Action": max(CHOICES["reboot_action"]),
    "Opcode": max(CHOICES["opcode"]),
}


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


def frame_for_other_node(frame: Frame, nodes: frozenset[int]) -> bool:
    """True for a standard-id frame of a node that is neither one of ``nodes`` nor the
    broadcast node: the drives of ``nodes`` ignore it (their ``other_node`` count)."""
    arb = frame.arbitration_id
    return (
        not frame.is_extended
        and 0 <= arb <= 0x7FF
        and arb >> 5 not in nodes
        and arb >> 5 != BROADCAST_NODE
    )


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


class _Packed(NamedTuple):
    """One signal of a layout that :func:`_pack` writes (see :func:`_packing`)."""

    name: str
    start: int  # the least significant bit's position in the little-endian payload
    length: int
    is_float: bool
    lo: int  # an integer signal's accepted values, inclusive (cantools' strict range)
    hi: int


_F32 = struct.Struct("<f")


@cache
def _packing(cmd: Cmd) -> tuple[int, tuple[_Packed, ...]] | None:
    """(payload length, signals) of ``cmd`` when cantools' strict encoding of it is plain bit
    packing -- every signal little endian, unscaled, a float32 or an integer -- else None.
    Read from the DBC, as cantools reads it; tests/test_can_codec.py checks the two agree on
    every message. (cantools' generic path costs a few microseconds per frame, on the drives'
    answer to every request and on every cyclic frame: bench/bench_drive_echo.py.)"""
    msg = _message(cmd)
    out = []
    for s in msg.signals:
        if s.byte_order != "little_endian" or s.scale != 1 or s.offset != 0 or s.multiplexer_ids:
            return None
        if s.is_float:
            if s.length != 32 or s.minimum is not None or s.maximum is not None:
                return None
            out.append(_Packed(s.name, s.start, 32, True, 0, 0))
            continue
        half = 1 << (s.length - 1)
        lo, hi = (-half, half - 1) if s.is_signed else (0, 2 * half - 1)
        if s.minimum is not None:
            lo = max(lo, math.ceil(s.minimum))
        if s.maximum is not None:
            hi = min(hi, math.floor(s.maximum))
        out.append(_Packed(s.name, s.start, s.length, False, lo, hi))
    return msg.length, tuple(out)


def _pack(packing: tuple[int, tuple[_Packed, ...]], sig: dict[str, Any]) -> bytes | None:
    """The payload of ``sig`` by ``packing``; None for a value it does not take (an integer
    signal's non-integer or out-of-range value: cantools decides, and refuses)."""
    length, signals = packing
    word = 0
    for s in signals:
        value = sig[s.name]
        if s.is_float:
            raw = int.from_bytes(_F32.pack(value), "little")
        elif isinstance(value, int) and s.lo <= value <= s.hi:
            raw = value & ((1 << s.length) - 1)
        else:
            return None
        word |= raw << s.start
    return word.to_bytes(length, "little")


@cache
def _plan(cls: type[Message]) -> tuple[Cmd, tuple[tuple[str, str, bool], ...], Any]:
    """(cmd, (attribute, signal, is float) for each field, :func:`_packing`) of a class."""
    cmd, names = _LAYOUT[cls]
    floats = {s.name for s in _message(cmd).signals if s.is_float}
    return cmd, tuple((a, sig, sig in floats) for a, sig in names), _packing(cmd)


_F32_MAX = 3.4028234663852886e38  # the largest finite float32


class _Aligned(NamedTuple):
    """A layout whose every signal is a whole, byte-aligned field: one ``struct.Struct``."""

    cmd: Cmd
    packer: struct.Struct
    fields: tuple[tuple[str, bool, int, int], ...]  # (attribute, is float, lo, hi) in order


@cache
def _aligned(cls: type[Message]) -> _Aligned | None:
    """The :class:`_Aligned` form of ``cls``' :func:`_packing` (signals of 8, 16 or 32 bits on
    byte boundaries, gaps and the tail zero), else None (bit fields: :func:`_pack` packs them).
    tests/test_can_codec.py checks :func:`encode` writes with it what its general path writes,
    on every aligned message."""
    cmd, names, packing = _plan(cls)
    if packing is None or not names:
        return None
    length, signals = packing
    attr_of = {signal: attr for attr, signal, _ in names}
    fmt, pos, fields = "<", 0, []
    for s in sorted(signals, key=lambda s: s.start):
        if s.start % 8 or s.start < pos or s.length not in (8, 16, 32):
            return None
        code = "f" if s.is_float else {8: "b", 16: "h", 32: "i"}[s.length]
        fmt += "x" * ((s.start - pos) // 8) + (code if s.is_float or s.lo < 0 else code.upper())
        pos = s.start + s.length
        fields.append((attr_of[s.name], s.is_float, s.lo, s.hi))
    fmt += "x" * (length - pos // 8)
    packer = struct.Struct(fmt)
    return _Aligned(cmd, packer, tuple(fields)) if packer.size == length else None


def _pack_aligned(plan: _Aligned, msg: Message) -> bytes | None:
    """The payload of ``msg`` by ``plan``, or None for any value :func:`encode`'s general path
    must look at (non-finite or beyond float32, an integer out of its range, a non-number):
    it then decides, and refuses with its own message."""
    values: list[float | int] = []
    for attr, is_float, lo, hi in plan.fields:
        value = getattr(msg, attr)
        if is_float:
            if not isinstance(value, (float, int)) or isinstance(value, bool):
                return None
            value = float(value)
            if not -_F32_MAX <= value <= _F32_MAX:  # NaN fails both sides
                return None
        elif not isinstance(value, int) or not lo <= value <= hi:
            return None
        values.append(value if is_float else int(value))
    return plan.packer.pack(*values)


def encode(msg: Message) -> Frame:
    """The frame of a typed message (lengths as in the DBC, unused bytes zero)."""
    plan = _aligned(type(msg)) if type(msg) in _LAYOUT else None
    if plan is not None:
        data = _pack_aligned(plan, msg)
        if data is not None:
            return Frame(frame_id(msg.node, plan.cmd), data)
    return _encode_general(msg)


def _encode_general(msg: Message) -> Frame:
    """:func:`encode` for every message and value (what :func:`_pack_aligned` declines)."""
    if isinstance(msg, Request):
        return Frame(frame_id(msg.node, msg.cmd), b"", is_remote=True)
    if type(msg) not in _LAYOUT:
        raise CanEncodeError(f"not a CANSimple message: {msg!r}")
    cmd, fields_, packing = _plan(type(msg))
    sig: dict[str, Any] = {}
    for attr, signal, is_float in fields_:
        value = getattr(msg, attr)
        if is_float:
            value = _finite32(attr, float(value))
        elif isinstance(value, float) and not math.isfinite(value):
            raise CanEncodeError(f"{attr} must be finite, got {value!r}")
        elif isinstance(value, bool):
            value = int(value)
        sig[signal] = value
    if not fields_:
        return Frame(frame_id(msg.node, cmd), b"")
    data = _pack(packing, sig) if packing is not None else None
    if data is None:
        data = _encode_dbc(cmd, sig)
    return Frame(frame_id(msg.node, cmd), data)


def _encode_dbc(cmd: Cmd, sig: dict[str, Any]) -> bytes:
    """cantools' strict encoding of ``sig`` (the reference :func:`_pack` agrees with)."""
    dbc_msg = _message(cmd)
    try:
        return bytes(dbc_msg.encode(sig, scaling=True, strict=True))
    except Exception as exc:  # cantools raises several types for out-of-range values
        raise CanEncodeError(f"{dbc_msg.name}: {exc}") from exc


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
    casts = _CASTS[cls]
    return cls(node, **{attr: casts[attr](sig[signal]) for attr, signal in names})
