"""The codec's CANSimple tables come from one table, ``dbc.MESSAGES``: every message round-trips
through the codec and, byte for byte, through cantools reading the shipped DBC; the derived
tables equal the ones that were written out by hand; a class that does not fit its message is
refused when it is declared."""

from __future__ import annotations

import struct
from dataclasses import dataclass, fields
from importlib import resources

import cantools
import pytest

from protocol.can import codec
from protocol.can.codec import Cmd, Frame, Message, Request
from protocol.can.dbc import CHOICES, MESSAGES, MessageSpec, Signal

# --- the hand-written tables as they were before they were derived (the known answer) -----
OLD_CMD = {
    "GET_VERSION": 0x00,
    "HEARTBEAT": 0x01,
    "ESTOP": 0x02,
    "GET_ERROR": 0x03,
    "RX_SDO": 0x04,
    "TX_SDO": 0x05,
    "ADDRESS": 0x06,
    "SET_AXIS_STATE": 0x07,
    "GET_ENCODER_ESTIMATES": 0x09,
    "SET_CONTROLLER_MODE": 0x0B,
    "SET_INPUT_POS": 0x0C,
    "SET_INPUT_VEL": 0x0D,
    "SET_INPUT_TORQUE": 0x0E,
    "SET_LIMITS": 0x0F,
    "SET_TRAJ_VEL_LIMIT": 0x11,
    "SET_TRAJ_ACCEL_LIMITS": 0x12,
    "SET_TRAJ_INERTIA": 0x13,
    "GET_IQ": 0x14,
    "GET_TEMPERATURE": 0x15,
    "REBOOT": 0x16,
    "GET_BUS_VOLTAGE_CURRENT": 0x17,
    "CLEAR_ERRORS": 0x18,
    "SET_ABSOLUTE_POSITION": 0x19,
    "SET_POS_GAIN": 0x1A,
    "SET_VEL_GAINS": 0x1B,
    "GET_TORQUES": 0x1C,
    "GET_POWERS": 0x1D,
    "ENTER_DFU_MODE": 0x1F,
}
# class -> (cmd, ((field, DBC signal), ...)) in the field order of the class
OLD_LAYOUT = {
    "Version": (
        "GET_VERSION",
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
    "Heartbeat": (
        "HEARTBEAT",
        (
            ("axis_error", "Axis_Error"),
            ("axis_state", "Axis_State"),
            ("procedure_result", "Procedure_Result"),
            ("trajectory_done", "Trajectory_Done_Flag"),
        ),
    ),
    "Estop": ("ESTOP", ()),
    "ErrorStatus": (
        "GET_ERROR",
        (("active_errors", "Active_Errors"), ("disarm_reason", "Disarm_Reason")),
    ),
    "RxSdo": (
        "RX_SDO",
        (
            ("opcode", "Opcode"),
            ("endpoint_id", "Endpoint_ID"),
            ("value", "Value"),
            ("reserved", "Reserved"),
        ),
    ),
    "TxSdo": (
        "TX_SDO",
        (
            ("endpoint_id", "Endpoint_ID"),
            ("value", "Value"),
            ("reserved0", "Reserved0"),
            ("reserved1", "Reserved1"),
        ),
    ),
    "Address": ("ADDRESS", (("node_id", "Node_ID"), ("serial_number", "Serial_Number"))),
    "SetAxisState": ("SET_AXIS_STATE", (("requested_state", "Axis_Requested_State"),)),
    "EncoderEstimates": (
        "GET_ENCODER_ESTIMATES",
        (("pos_rev", "Pos_Estimate"), ("vel_rev_s", "Vel_Estimate")),
    ),
    "SetControllerMode": (
        "SET_CONTROLLER_MODE",
        (("control_mode", "Control_Mode"), ("input_mode", "Input_Mode")),
    ),
    "SetInputPos": (
        "SET_INPUT_POS",
        (("input_pos", "Input_Pos"), ("vel_ff", "Vel_FF"), ("torque_ff", "Torque_FF")),
    ),
    "SetInputVel": (
        "SET_INPUT_VEL",
        (("input_vel", "Input_Vel"), ("torque_ff", "Input_Torque_FF")),
    ),
    "SetInputTorque": ("SET_INPUT_TORQUE", (("torque_nm", "Input_Torque"),)),
    "SetLimits": (
        "SET_LIMITS",
        (("velocity_limit", "Velocity_Limit"), ("current_limit", "Current_Limit")),
    ),
    "SetTrajVelLimit": ("SET_TRAJ_VEL_LIMIT", (("traj_vel_limit", "Traj_Vel_Limit"),)),
    "SetTrajAccelLimits": (
        "SET_TRAJ_ACCEL_LIMITS",
        (("accel_limit", "Traj_Accel_Limit"), ("decel_limit", "Traj_Decel_Limit")),
    ),
    "SetTrajInertia": ("SET_TRAJ_INERTIA", (("inertia", "Traj_Inertia"),)),
    "Iq": ("GET_IQ", (("iq_setpoint", "Iq_Setpoint"), ("iq_measured", "Iq_Measured"))),
    "Temperature": (
        "GET_TEMPERATURE",
        (("fet_temperature", "FET_Temperature"), ("motor_temperature", "Motor_Temperature")),
    ),
    "Reboot": ("REBOOT", (("action", "Action"),)),
    "BusVoltageCurrent": (
        "GET_BUS_VOLTAGE_CURRENT",
        (("bus_voltage", "Bus_Voltage"), ("bus_current", "Bus_Current")),
    ),
    "ClearErrors": ("CLEAR_ERRORS", (("identify", "Identify"),)),
    "SetAbsolutePosition": ("SET_ABSOLUTE_POSITION", (("position", "Position"),)),
    "SetPosGain": ("SET_POS_GAIN", (("pos_gain", "Pos_Gain"),)),
    "SetVelGains": (
        "SET_VEL_GAINS",
        (("vel_gain", "Vel_Gain"), ("vel_integrator_gain", "Vel_Integrator_Gain")),
    ),
    "Torques": (
        "GET_TORQUES",
        (("torque_target", "Torque_Target"), ("torque_estimate", "Torque_Estimate")),
    ),
    "Powers": (
        "GET_POWERS",
        (("electrical_power", "Electrical_Power"), ("mechanical_power", "Mechanical_Power")),
    ),
    "EnterDfuMode": ("ENTER_DFU_MODE", ()),
}
OLD_REQUESTABLE = {
    "GET_VERSION",
    "HEARTBEAT",
    "GET_ERROR",
    "ADDRESS",
    "GET_ENCODER_ESTIMATES",
    "GET_IQ",
    "GET_TEMPERATURE",
    "GET_BUS_VOLTAGE_CURRENT",
    "GET_TORQUES",
    "GET_POWERS",
}
OLD_DRIVE_TO_HOST = (
    "Version",
    "Heartbeat",
    "ErrorStatus",
    "TxSdo",
    "EncoderEstimates",
    "Iq",
    "Temperature",
    "BusVoltageCurrent",
    "Torques",
    "Powers",
)
OLD_HOST_TO_DRIVE = (
    "Estop",
    "RxSdo",
    "SetAxisState",
    "SetControllerMode",
    "SetInputPos",
    "SetInputVel",
    "SetInputTorque",
    "SetLimits",
    "SetTrajVelLimit",
    "SetTrajAccelLimits",
    "SetTrajInertia",
    "Reboot",
    "ClearErrors",
    "SetAbsolutePosition",
    "SetPosGain",
    "SetVelGains",
    "EnterDfuMode",
    "Request",
)
# the members of the old ``Message`` union: now the subclasses of ``Message``
OLD_MESSAGE = set(OLD_LAYOUT) | {"Request"}


def test_can_derived_tables_equal_the_hand_written_ones():
    assert {m.name: m.value for m in Cmd} == OLD_CMD
    assert list(Cmd) == sorted(Cmd)  # iteration in cmd order, as the class listed them
    layout = {cls.__name__: (cmd.name, pairs) for cls, (cmd, pairs) in codec._LAYOUT.items()}
    assert layout == OLD_LAYOUT
    assert {c.name for c in codec.REQUESTABLE} == OLD_REQUESTABLE
    assert tuple(c.__name__ for c in codec.DRIVE_TO_HOST) == OLD_DRIVE_TO_HOST
    assert tuple(c.__name__ for c in codec.HOST_TO_DRIVE) == OLD_HOST_TO_DRIVE
    classes = {
        name
        for name, obj in vars(codec).items()
        if isinstance(obj, type) and issubclass(obj, Message) and obj is not Message
    }
    assert classes == OLD_MESSAGE


@pytest.mark.parametrize(
    ("enum", "choices"),
    [
        (codec.AxisState, "axis_state"),
        (codec.ControlMode, "control_mode"),
        (codec.InputMode, "input_mode"),
        (codec.ProcedureResult, "procedure_result"),
        (codec.ODriveError, "error"),
    ],
)
def test_can_codec_enums_are_the_dbc_value_tables(enum, choices):
    # the typed enums stay classes (for type checkers), so they are checked, not derived
    assert {m.value: name for name, m in enum.__members__.items()} == CHOICES[choices]


# --- every message, every signal at its edges, through the codec and through cantools -----
def _f32(x: float) -> float:
    return struct.unpack("<f", struct.pack("<f", x))[0]


def _values(s: Signal) -> tuple[float | int, float | int, float | int]:
    """(low, high, middle) values of a signal that the codec accepts and carries exactly."""
    if s.is_float:
        top = _f32(3.4028234e38)  # the largest finite float32
        return -top, top, _f32(-1.0 / 3.0)
    if s.scale != 1.0:  # a scaled integer: the raw values at its edges, times the scale
        lo, hi = -(2 ** (s.length - 1)), 2 ** (s.length - 1) - 1
        return lo * s.scale, hi * s.scale, 1234 * s.scale
    if s.choices and s.choices != "error":  # the codec refuses values outside a choice table
        keys = sorted(CHOICES[s.choices])
        return keys[0], keys[-1], keys[len(keys) // 2]
    top = 2**s.length - 1
    return 0, top, 0x5A5A5A5A5A5A5A5A & top


def _samples(spec: MessageSpec) -> list[Message]:
    cls = codec._CLASS_OF[Cmd(spec.cmd)]
    casts = {f.name: f.type for f in fields(cls)}
    out = []
    for node, pick in ((0, 0), (7, 1), (1, 2)):
        kwargs = {}
        for s in spec.signals:
            v = _values(s)[pick]
            kwargs[s.field] = bool(v) if casts[s.field] in ("bool", bool) else v
        out.append(cls(node, **kwargs))
    return out


SAMPLES = [(spec, msg) for spec in MESSAGES for msg in _samples(spec)]


@pytest.fixture(scope="module")
def shipped() -> cantools.database.can.Database:
    path = resources.files("protocol.can").joinpath(codec.DBC_NAME)
    return cantools.database.load_file(str(path))


@pytest.mark.parametrize(("spec", "msg"), SAMPLES, ids=lambda v: repr(v)[:48])
def test_can_every_message_round_trips_through_codec_and_cantools(spec, msg, shipped):
    frame = codec.encode(msg)
    assert frame.arbitration_id == msg.node << 5 | spec.cmd
    assert len(frame.data) == spec.dlc
    assert codec.decode(frame) == msg
    # cantools, from the shipped DBC alone, writes the same bytes from the same values...
    dbc_msg = shipped.get_message_by_frame_id(frame.arbitration_id)
    assert dbc_msg.name == f"Axis{msg.node}_{spec.name}"
    values = {s.name: getattr(msg, s.field) for s in spec.signals}
    values = {k: int(v) if isinstance(v, bool) else v for k, v in values.items()}
    if spec.signals:
        assert dbc_msg.encode(values, scaling=True, strict=True) == frame.data
    # ...and reads the codec's bytes back as those values
    assert dbc_msg.decode(frame.data, decode_choices=False) == pytest.approx(values, rel=1e-12)


@pytest.mark.parametrize("spec", [m for m in MESSAGES if m.requestable], ids=lambda m: m.name)
def test_can_every_requestable_message_round_trips_as_a_request(spec):
    req = Request(3, Cmd(spec.cmd))
    frame = codec.encode(req)
    assert frame == Frame(3 << 5 | spec.cmd, b"", is_remote=True)
    assert codec.decode(frame) == req
    assert codec.decode(frame._replace(is_remote=False)) == req  # the empty data frame


# --- a class that does not fit its message fails where it is declared -----------------------
def test_can_a_class_whose_fields_are_not_its_signals_is_refused():
    with pytest.raises(TypeError, match="Iq_Setpoint"):

        @codec._carries("Get_Iq")
        @dataclass(frozen=True)
        class MissingOne(Message):
            iq_measured: float

    with pytest.raises(TypeError, match="Iq_Measured"):

        @codec._carries("Get_Iq")
        @dataclass(frozen=True)
        class Misnamed(Message):
            iq_setpoint: float
            iq_measure: float

    with pytest.raises(TypeError, match="must be float"):

        @codec._carries("Get_Iq")
        @dataclass(frozen=True)
        class WrongType(Message):
            iq_setpoint: float
            iq_measured: int

    assert codec._CLASS_OF[Cmd.GET_IQ] is codec.Iq  # nothing refused was registered


def test_can_a_message_carried_twice_or_unknown_is_refused():
    with pytest.raises(TypeError, match="one class"):

        @codec._carries("Get_Iq")
        @dataclass(frozen=True)
        class SecondIq(Message):
            iq_setpoint: float
            iq_measured: float

    with pytest.raises(TypeError, match="Get_Nothing"):
        codec._carries("Get_Nothing")
    with pytest.raises(TypeError, match="subclass of Message"):

        @codec._carries("Estop")
        @dataclass(frozen=True)
        class Loose:
            node: int
