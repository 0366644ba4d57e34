"""The bench's messages (State, TorqueCommand, Status, Telemetry) and their msgpack encoding.

Every message is one msgpack array ``[type_tag, schema_version, field_1, ..., field_n]`` with the
fields in the order of the dataclass below (docs/protocol.md says why an array and not a map).
Times are integer nanoseconds of ``time.monotonic_ns()`` on one host (docs/design.md, section 3);
units are SI. The names follow the paper: tau1, tau2 are the torques of model (1), xe, ye,
theta_e the tracking errors (4), xi = eta f the time-varying signal (Section 3, unnumbered),
v_tilde, w_tilde the sliding variables of (10), z1, z2 the adaptive states of (8), eta the
decaying gain of xi.

Decoding is strict. Each of these raises exactly one :class:`DecodeError` (never any other
exception, never a half-decoded message):

- ``not_bytes``: the input is not bytes, bytearray or memoryview;
- ``too_large``: more than ``MAX_MESSAGE_BYTES`` bytes;
- ``malformed``: not valid msgpack (truncated, bad UTF-8, too deep);
- ``trailing_bytes``: valid msgpack followed by more bytes;
- ``not_array``: the top-level object is not an array;
- ``bad_header``: no room for tag and version, or either is not an int;
- ``unknown_type`` / ``unknown_version``: a tag or version this build does not speak;
- ``unexpected_type``: a valid message of another type than the caller asked for;
- ``missing_field`` / ``extra_field``: fewer or more fields than the version defines;
- ``wrong_type``: a field of the wrong msgpack type. Integer fields take msgpack integers only
  (a bool is not an int); float fields take msgpack float32/float64 only (an integer is not
  accepted for a float field: the encoder always writes float64, so an int there means another
  writer got the schema wrong);
- ``non_finite``: NaN or +-inf in a float field;
- ``out_of_range``: a number outside the protocol's range (``RANGES`` below and the docs);
- ``bad_identifier``: a robot id, law, role, state or counter name outside its pattern.

Clamping to a scenario's limits is not done here: it happens where commands are applied.
"""

from __future__ import annotations

import math
import numbers
import re
from collections.abc import Callable
from dataclasses import dataclass, field
from operator import attrgetter
from typing import Any, ClassVar, TypeVar

import msgpack

from protocol.keys import is_valid_robot_id
from protocol.rejections import RejectionCounter
from protocol.versions import MESSAGE_SCHEMA_VERSION

MAX_MESSAGE_BYTES = 4096

# Protocol ranges: wide sanity bounds, far outside any scenario's limits, so a receiver never
# has to reason about absurd magnitudes; the scenario's own limits (2) are applied later.
SEQ_MAX = 2**63 - 1  # fits int64 and uint64 in every msgpack implementation
TIME_MAX = 2**63 - 1
FLAGS_MAX = 2**32 - 1
POSITION_MAX = 1.0e6  # m
ANGLE_MAX = 1.0e6  # rad; theta is unwrapped, so it is not confined to (-pi, pi]
SPEED_MAX = 1.0e3  # m/s
TURN_RATE_MAX = 1.0e4  # rad/s
TORQUE_MAX = 1.0e4  # |tau1|, |tau2|
SIGNAL_MAX = 1.0e6  # telemetry signals other than eta
MAX_COUNTERS = 64

_NAME_RE = re.compile(r"[a-z][a-z0-9_]{0,31}")  # role, state, counter names
_LAW_RE = re.compile(r"[A-Za-z0-9_.:\-]{1,128}")  # "unified" or "package.module:Class"

# Field kinds (small ints so the hot loop compares cheaply).
_INT, _FLOAT, _ROBOT_ID, _NAME, _LAW, _COUNTERS = range(6)


class DecodeError(ValueError):
    """The one error a decoder raises: ``reason`` is a short word, ``detail`` says where."""

    def __init__(self, reason: str, detail: Any = None) -> None:
        super().__init__(f"{reason}: {detail}" if detail is not None else reason)
        self.reason = reason
        self.detail = detail


class EncodeError(ValueError):
    """A message that would not decode (a value out of range, NaN, a bad id): never sent."""

    def __init__(self, reason: str, detail: Any = None) -> None:
        super().__init__(f"{reason}: {detail}")
        self.reason = reason
        self.detail = detail


@dataclass(frozen=True, slots=True)
class State:
    """The plant's measured state, model (1): pose (x, y, theta) and body velocities (v, omega).

    ``sample_time_ns`` is when the state was sampled, ``send_time_ns`` when it was published.
    """

    TAG: ClassVar[int] = 1
    robot_id: str
    seq: int
    sample_time_ns: int
    send_time_ns: int
    x: float
    y: float
    theta: float
    v: float
    omega: float


@dataclass(frozen=True, slots=True)
class TorqueCommand:
    """Torques (10)/(19) computed by the controller from the State numbered ``state_seq``.

    ``state_sample_time_ns`` is that state's sample time (sample-to-apply latency is measured
    from it), ``compute_start_ns`` when the law started, ``send_time_ns`` when it was published.
    ``flags`` is a bit set (``FLAG_*`` below).
    """

    TAG: ClassVar[int] = 2
    robot_id: str
    seq: int
    state_seq: int
    state_sample_time_ns: int
    compute_start_ns: int
    send_time_ns: int
    tau1: float
    tau2: float
    law: str
    flags: int = 0


@dataclass(frozen=True, slots=True)
class Status:
    """Health of one process: its ``role`` ("controller", "plant", ...), a ``state`` word
    ("running", "stopped", ...), ``flags`` (``STATUS_*`` bits) and counters by name."""

    TAG: ClassVar[int] = 3
    robot_id: str
    seq: int
    time_ns: int
    role: str
    state: str
    flags: int = 0
    counters: dict[str, int] = field(default_factory=dict)


@dataclass(frozen=True, slots=True)
class Telemetry:
    """The unified law's internal signals at one control sample: errors (4), xi = eta f
    (Section 3), the sliding variables v~, w~ of (10), the adaptive states z1, z2 of (8), eta."""

    TAG: ClassVar[int] = 4
    robot_id: str
    seq: int
    time_ns: int
    xe: float
    ye: float
    theta_e: float
    xi: float
    v_tilde: float
    w_tilde: float
    z1: float
    z2: float
    eta: float


Message = State | TorqueCommand | Status | Telemetry
M = TypeVar("M", State, TorqueCommand, Status, Telemetry)

# TorqueCommand.flags bits.
FLAG_WATCHDOG_ZERO = 1 << 0  # zero torque sent because the state was stale or missing
FLAG_BOUNDARY_LAYER = 1 << 1  # computed with the boundary layer (19)
FLAG_STOP = 1 << 2  # the controller is stopping: the receiver should idle the drives

# Status.flags bits.
STATUS_WATCHDOG_TRIPPED = 1 << 0
STATUS_ESTOP = 1 << 1
STATUS_FAULT = 1 << 2


def _spec(**kinds: tuple[int, float, float]) -> tuple[tuple[str, int, float, float], ...]:
    return tuple((name, *k) for name, k in kinds.items())


_ID = (_ROBOT_ID, 0, 0)
_SEQ = (_INT, 0, SEQ_MAX)
_TIME = (_INT, 0, TIME_MAX)
_FLAGS = (_INT, 0, FLAGS_MAX)


def _f(bound: float) -> tuple[int, float, float]:
    return (_FLOAT, -bound, bound)


SPECS: dict[type, tuple[tuple[str, int, float, float], ...]] = {
    State: _spec(
        robot_id=_ID,
        seq=_SEQ,
        sample_time_ns=_TIME,
        send_time_ns=_TIME,
        x=_f(POSITION_MAX),
        y=_f(POSITION_MAX),
        theta=_f(ANGLE_MAX),
        v=_f(SPEED_MAX),
        omega=_f(TURN_RATE_MAX),
    ),
    TorqueCommand: _spec(
        robot_id=_ID,
        seq=_SEQ,
        state_seq=_SEQ,
        state_sample_time_ns=_TIME,
        compute_start_ns=_TIME,
        send_time_ns=_TIME,
        tau1=_f(TORQUE_MAX),
        tau2=_f(TORQUE_MAX),
        law=(_LAW, 0, 0),
        flags=_FLAGS,
    ),
    Status: _spec(
        robot_id=_ID,
        seq=_SEQ,
        time_ns=_TIME,
        role=(_NAME, 0, 0),
        state=(_NAME, 0, 0),
        flags=_FLAGS,
        counters=(_COUNTERS, 0, SEQ_MAX),
    ),
    Telemetry: _spec(
        robot_id=_ID,
        seq=_SEQ,
        time_ns=_TIME,
        xe=_f(SIGNAL_MAX),
        ye=_f(SIGNAL_MAX),
        theta_e=_f(SIGNAL_MAX),
        xi=_f(SIGNAL_MAX),
        v_tilde=_f(SIGNAL_MAX),
        w_tilde=_f(SIGNAL_MAX),
        z1=_f(SIGNAL_MAX),
        z2=_f(SIGNAL_MAX),
        # eta' = -(vd^2 + wd^2) eta with eta(0) = 1 keeps eta in (0, 1].
        eta=(_FLOAT, 0.0, 1.0),
    ),
}
RANGES: dict[str, dict[str, tuple[float, float]]] = {
    cls.__name__: {n: (lo, hi) for n, k, lo, hi in spec if k in (_INT, _FLOAT)}
    for cls, spec in SPECS.items()
}
MESSAGE_TYPES: dict[int, type] = {cls.TAG: cls for cls in SPECS}
_GETTERS = {cls: attrgetter(*(n for n, *_ in spec)) for cls, spec in SPECS.items()}


def _check_counters(value: Any, name: str) -> dict[str, int]:
    if type(value) is not dict:
        raise DecodeError("wrong_type", f"{name} must be a map")
    if len(value) > MAX_COUNTERS:
        raise DecodeError("out_of_range", f"{name} has {len(value)} > {MAX_COUNTERS} entries")
    out: dict[str, int] = {}
    for key, count in value.items():
        if type(key) is not str or _NAME_RE.fullmatch(key) is None:
            raise DecodeError("bad_identifier", f"{name} key {key!r}")
        if type(count) is not int:
            if isinstance(count, numbers.Integral) and type(count) is not bool:
                count = int(count)
            else:
                raise DecodeError("wrong_type", f"{name}[{key}] must be an int")
        if not 0 <= count <= SEQ_MAX:
            raise DecodeError("out_of_range", f"{name}[{key}] = {count}")
        out[key] = count
    return out


def _check(spec: tuple, values: tuple | list, offset: int, lenient: bool) -> list[Any]:
    """Validate ``values[offset:]`` against ``spec``; ``lenient`` (encoding only) converts
    numpy scalars and ints in float fields, which the decoder never accepts."""
    out: list[Any] = []
    append = out.append
    i = offset
    for name, kind, lo, hi in spec:
        v = values[i]
        i += 1
        if kind == _FLOAT:
            if type(v) is not float:
                if lenient and isinstance(v, numbers.Real) and not isinstance(v, bool):
                    v = float(v)
                else:
                    raise DecodeError("wrong_type", f"{name} must be a float, got {type(v)}")
            if not lo <= v <= hi:
                if math.isfinite(v):
                    raise DecodeError("out_of_range", f"{name} = {v!r} not in [{lo}, {hi}]")
                raise DecodeError("non_finite", f"{name} = {v!r}")
        elif kind == _INT:
            if type(v) is not int:
                if lenient and isinstance(v, numbers.Integral) and not isinstance(v, bool):
                    v = int(v)
                else:
                    raise DecodeError("wrong_type", f"{name} must be an int, got {type(v)}")
            if not lo <= v <= hi:
                raise DecodeError("out_of_range", f"{name} = {v} not in [{lo}, {hi}]")
        elif kind == _ROBOT_ID:
            if type(v) is not str:
                raise DecodeError("wrong_type", f"{name} must be a str, got {type(v)}")
            if not is_valid_robot_id(v):
                raise DecodeError("bad_identifier", f"{name} = {v!r}")
        elif kind in (_NAME, _LAW):
            if type(v) is not str:
                raise DecodeError("wrong_type", f"{name} must be a str, got {type(v)}")
            if (_NAME_RE if kind == _NAME else _LAW_RE).fullmatch(v) is None:
                raise DecodeError("bad_identifier", f"{name} = {v!r}")
        else:
            v = _check_counters(v, name)
        append(v)
    return out


def encode(msg: Message) -> bytes:
    """Encode a message as ``[tag, version, *fields]`` (floats as float64).

    Raises :class:`EncodeError` for a message the decoder would reject, so a sender learns of
    a NaN torque or a bad robot id instead of the receiver silently counting it.
    """
    cls = type(msg)
    spec = SPECS.get(cls)
    if spec is None:
        raise EncodeError("unknown_type", cls.__name__)
    try:
        values = _check(spec, _GETTERS[cls](msg), 0, True)
    except DecodeError as e:
        raise EncodeError(e.reason, e.detail) from None
    return msgpack.packb([cls.TAG, MESSAGE_SCHEMA_VERSION, *values], use_bin_type=True)


def unpack_array(data: Any, max_bytes: int) -> list[Any]:
    """The msgpack array ``[tag, version, ...]`` in ``data`` (at most ``max_bytes``), its
    header checked for two ints, or one :class:`DecodeError` (``not_bytes``, ``too_large``,
    ``malformed``, ``trailing_bytes``, ``not_array``, ``bad_header``); what the tag and
    version mean is the caller's."""
    if type(data) is not bytes:
        if not isinstance(data, (bytes, bytearray, memoryview)):
            raise DecodeError("not_bytes", type(data).__name__)
        data = bytes(data)
    if len(data) > max_bytes:
        raise DecodeError("too_large", f"{len(data)} > {max_bytes} bytes")
    try:
        obj = msgpack.unpackb(data, raw=False, strict_map_key=True, timestamp=0)
    except msgpack.ExtraData:
        raise DecodeError("trailing_bytes", None) from None
    except Exception as e:  # msgpack raises several types (ValueError, FormatError, ...)
        raise DecodeError("malformed", type(e).__name__) from None
    if type(obj) is not list:
        raise DecodeError("not_array", type(obj).__name__)
    if len(obj) < 2 or type(obj[0]) is not int or type(obj[1]) is not int:
        raise DecodeError("bad_header", None)
    return obj


def decode(data: Any) -> Message:
    """Decode any message; raises only :class:`DecodeError` (reasons in the module docstring)."""
    obj = unpack_array(data, MAX_MESSAGE_BYTES)
    n = len(obj)
    cls = MESSAGE_TYPES.get(obj[0])
    if cls is None:
        raise DecodeError("unknown_type", obj[0])
    if obj[1] != MESSAGE_SCHEMA_VERSION:
        raise DecodeError("unknown_version", obj[1])
    spec = SPECS[cls]
    expected = len(spec) + 2
    if n != expected:
        reason = "missing_field" if n < expected else "extra_field"
        raise DecodeError(reason, f"{cls.__name__} has {len(spec)} fields, got {n - 2}")
    return cls(*_check(spec, obj, 2, False))


def decode_as(cls: type[M], data: Any) -> M:
    """Decode a message that must be of type ``cls`` (else ``unexpected_type``)."""
    msg = decode(data)
    if type(msg) is not cls:
        raise DecodeError("unexpected_type", f"wanted {cls.__name__}, got {type(msg).__name__}")
    return msg  # type: ignore[return-value]


def decode_counted(
    data: Any,
    rejections: RejectionCounter,
    expected: type[M] | None = None,
    on_reject: Callable[[str], None] | None = None,
) -> M | None:
    """Decode for a receiver: the message, or None with the rejection counted by reason (and
    the reason handed to ``on_reject``: a service's tap keeps the refused payload)."""
    try:
        return decode(data) if expected is None else decode_as(expected, data)  # type: ignore[return-value]
    except DecodeError as e:
        rejections.count(e.reason)
        if on_reject is not None:
            on_reject(e.reason)
        return None
