"""The ODrive CANSimple 0.6 message set as data, and the DBC file rendered from it.

One table (:data:`MESSAGES`) holds every message of the firmware 0.6 protocol: command id,
name, length, which side sends it and its signals (start bit, length, sign, float, scale, unit),
as the ODrive CAN protocol page documents them
(https://docs.odriverobotics.com/v/latest/manual/can-protocol.html), and whether a drive answers
a request for it. The codec (:mod:`protocol.can.codec`: its ``Cmd`` enum, field layouts and
direction tables; ``Signal.field`` names the field that carries a signal) and the shipped DBC
(``odrive_cansimple.dbc``) both come from it.

A CANSimple frame id is ``node_id << 5 | cmd_id``, so a DBC needs one message set per node
for a tool like ``cantools decode`` to name every frame on a bus. ODrive's own DBC covers axes
0-7; the shipped file does the same (``python -m protocol.can.dbc --nodes 0-7``, checked by a
test). ``hil can-dbc --nodes 0,1,12`` writes one for any node ids (0..63).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Iterable
from dataclasses import dataclass

MAX_NODE_ID = 0x3F
DEFAULT_NODES = tuple(range(8))


@dataclass(frozen=True)
class Signal:
    name: str
    start: int
    length: int
    signed: bool = False
    is_float: bool = False
    scale: float = 1.0
    minimum: float | None = None
    maximum: float | None = None
    unit: str = ""
    choices: str | None = None  # a key of CHOICES
    comment: str = ""
    attr: str = ""  # the codec's field for it, when not the lower-cased name

    @property
    def field(self) -> str:
        """The name of the codec dataclass field that carries this signal."""
        return self.attr or self.name.lower()


@dataclass(frozen=True)
class MessageSpec:
    cmd: int
    name: str
    dlc: int
    sender: str  # "drive" (ODrive -> host) or "host" (host -> ODrive)
    signals: tuple[Signal, ...] = ()
    comment: str = ""
    cycle_ms: int = 0  # the firmware's default cyclic rate (0: only on request / not cyclic)
    # The drive answers a remote frame (or an empty data frame) of this id with this message.
    # A requestable "host" message (Address) therefore goes both ways.
    requestable: bool = False


def _f32(name: str, start: int, unit: str = "", attr: str = "") -> Signal:
    return Signal(name, start, 32, False, True, unit=unit, attr=attr)


def _u(
    name: str,
    start: int,
    length: int,
    choices: str | None = None,
    comment: str = "",
    attr: str = "",
) -> Signal:
    return Signal(
        name,
        start,
        length,
        maximum=float(2**length - 1),
        choices=choices,
        comment=comment,
        attr=attr,
    )


AXIS_STATES = {
    0: "UNDEFINED",
    1: "IDLE",
    2: "STARTUP_SEQUENCE",
    3: "FULL_CALIBRATION_SEQUENCE",
    4: "MOTOR_CALIBRATION",
    5: "SENSORLESS_CONTROL",
    6: "ENCODER_INDEX_SEARCH",
    7: "ENCODER_OFFSET_CALIBRATION",
    8: "CLOSED_LOOP_CONTROL",
    9: "LOCKIN_SPIN",
    10: "ENCODER_DIR_FIND",
    11: "HOMING",
    12: "ENCODER_HALL_POLARITY_CALIBRATION",
    13: "ENCODER_HALL_PHASE_CALIBRATION",
    14: "ANTICOGGING_CALIBRATION",
}
ERRORS = {  # ODrive.Error (firmware 0.6): Heartbeat Axis_Error, Get_Error's two fields
    0: "NONE",
    0x1: "INITIALIZING",
    0x2: "SYSTEM_LEVEL",
    0x4: "TIMING_ERROR",
    0x8: "MISSING_ESTIMATE",
    0x10: "BAD_CONFIG",
    0x20: "DRV_FAULT",
    0x40: "MISSING_INPUT",
    0x100: "DC_BUS_OVER_VOLTAGE",
    0x200: "DC_BUS_UNDER_VOLTAGE",
    0x400: "DC_BUS_OVER_CURRENT",
    0x800: "DC_BUS_OVER_REGEN_CURRENT",
    0x1000: "CURRENT_LIMIT_VIOLATION",
    0x2000: "MOTOR_OVER_TEMP",
    0x4000: "INVERTER_OVER_TEMP",
    0x8000: "VELOCITY_LIMIT_VIOLATION",
    0x10000: "POSITION_LIMIT_VIOLATION",
    0x1000000: "WATCHDOG_TIMER_EXPIRED",
    0x2000000: "ESTOP_REQUESTED",
    0x4000000: "SPINOUT_DETECTED",
    0x8000000: "BRAKE_RESISTOR_DISARMED",
    0x10000000: "THERMISTOR_DISCONNECTED",
    0x40000000: "CALIBRATION_ERROR",
}
PROCEDURE_RESULTS = {
    0: "SUCCESS",
    1: "BUSY",
    2: "CANCELLED",
    3: "DISARMED",
    4: "NO_RESPONSE",
    5: "POLE_PAIR_CPR_MISMATCH",
    6: "PHASE_RESISTANCE_OUT_OF_RANGE",
    7: "PHASE_INDUCTANCE_OUT_OF_RANGE",
    8: "UNBALANCED_PHASES",
    9: "INVALID_MOTOR_TYPE",
    10: "ILLEGAL_HALL_STATE",
    11: "TIMEOUT",
    12: "HOMING_WITHOUT_ENDSTOP",
    13: "INVALID_STATE",
    14: "NOT_CALIBRATED",
    15: "NOT_CONVERGING",
}
CONTROL_MODES = {
    0: "VOLTAGE_CONTROL",
    1: "TORQUE_CONTROL",
    2: "VELOCITY_CONTROL",
    3: "POSITION_CONTROL",
}
INPUT_MODES = {
    0: "INACTIVE",
    1: "PASSTHROUGH",
    2: "VEL_RAMP",
    3: "POS_FILTER",
    4: "MIX_CHANNELS",
    5: "TRAP_TRAJ",
    6: "TORQUE_RAMP",
    7: "MIRROR",
    8: "TUNING",
}
CHOICES: dict[str, dict[int, str]] = {
    "axis_state": AXIS_STATES,
    "error": ERRORS,
    "procedure_result": PROCEDURE_RESULTS,
    "control_mode": CONTROL_MODES,
    "input_mode": INPUT_MODES,
    "opcode": {0: "READ", 1: "WRITE"},
    "reboot_action": {
        0: "reboot",
        1: "save_configuration",
        2: "erase_configuration",
        3: "enter_dfu_mode",
    },
}

MESSAGES: tuple[MessageSpec, ...] = (
    MessageSpec(
        0x00,
        "Get_Version",
        8,
        "drive",
        (
            _u("Protocol_Version", 0, 8, comment="Always 2"),
            _u("Hw_Version_Major", 8, 8),
            _u("Hw_Version_Minor", 16, 8),
            _u("Hw_Version_Variant", 24, 8),
            _u("Fw_Version_Major", 32, 8),
            _u("Fw_Version_Minor", 40, 8),
            _u("Fw_Version_Revision", 48, 8),
            _u("Fw_Version_Unreleased", 56, 8, comment="0 for official releases"),
        ),
        "On request (RTR). The virtual drive reports Fw_Version_Unreleased = 1.",
        requestable=True,
    ),
    MessageSpec(
        0x01,
        "Heartbeat",
        8,
        "drive",
        (
            _u("Axis_Error", 0, 32, "error", "active_errors | disarm_reason"),
            _u("Axis_State", 32, 8, "axis_state"),
            _u("Procedure_Result", 40, 8, "procedure_result"),
            _u("Trajectory_Done_Flag", 48, 1, attr="trajectory_done"),
        ),
        "Cyclic (heartbeat_msg_rate_ms, default 100 ms) and on request.",
        cycle_ms=100,
        requestable=True,
    ),
    MessageSpec(0x02, "Estop", 0, "host", (), "Disarms the axis with ESTOP_REQUESTED."),
    MessageSpec(
        0x03,
        "Get_Error",
        8,
        "drive",
        (
            _u("Active_Errors", 0, 32, "error"),
            _u("Disarm_Reason", 32, 32, "error"),
        ),
        "On request (RTR) or cyclic (error_msg_rate_ms, default off).",
        requestable=True,
    ),
    MessageSpec(
        0x04,
        "RxSdo",
        8,
        "host",
        (
            _u("Opcode", 0, 8, "opcode"),
            _u("Endpoint_ID", 8, 16),
            _u("Reserved", 24, 8),
            _u("Value", 32, 32),
        ),
        "Endpoint access (flat_endpoints.json). Refused by the virtual drive (counted).",
    ),
    MessageSpec(
        0x05,
        "TxSdo",
        8,
        "drive",
        (
            _u("Reserved0", 0, 8),
            _u("Endpoint_ID", 8, 16),
            _u("Reserved1", 24, 8),
            _u("Value", 32, 32),
        ),
        "Answer to an RxSdo read (never sent by the virtual drive).",
    ),
    MessageSpec(
        0x06,
        "Address",
        8,
        "host",
        (_u("Node_ID", 0, 8), _u("Serial_Number", 8, 48)),
        "Discovery: an RTR (node id or 0x3F) is answered with the drive's node id and serial.",
        requestable=True,
    ),
    MessageSpec(
        0x07,
        "Set_Axis_State",
        8,
        "host",
        (_u("Axis_Requested_State", 0, 32, "axis_state", attr="requested_state"),),
    ),
    MessageSpec(
        0x09,
        "Get_Encoder_Estimates",
        8,
        "drive",
        (
            _f32("Pos_Estimate", 0, "rev", attr="pos_rev"),
            _f32("Vel_Estimate", 32, "rev/s", attr="vel_rev_s"),
        ),
        "Cyclic (encoder_msg_rate_ms, default 10 ms) and on request.",
        cycle_ms=10,
        requestable=True,
    ),
    MessageSpec(
        0x0B,
        "Set_Controller_Mode",
        8,
        "host",
        (
            _u("Control_Mode", 0, 32, "control_mode"),
            _u("Input_Mode", 32, 32, "input_mode"),
        ),
    ),
    MessageSpec(
        0x0C,
        "Set_Input_Pos",
        8,
        "host",
        (
            _f32("Input_Pos", 0, "rev"),
            Signal(
                "Vel_FF", 32, 16, True, scale=0.001, minimum=-32.768, maximum=32.767, unit="rev/s"
            ),
            Signal(
                "Torque_FF", 48, 16, True, scale=0.001, minimum=-32.768, maximum=32.767, unit="Nm"
            ),
        ),
    ),
    MessageSpec(
        0x0D,
        "Set_Input_Vel",
        8,
        "host",
        (_f32("Input_Vel", 0, "rev/s"), _f32("Input_Torque_FF", 32, "Nm", attr="torque_ff")),
    ),
    MessageSpec(
        0x0E, "Set_Input_Torque", 8, "host", (_f32("Input_Torque", 0, "Nm", attr="torque_nm"),)
    ),
    MessageSpec(
        0x0F,
        "Set_Limits",
        8,
        "host",
        (_f32("Velocity_Limit", 0, "rev/s"), _f32("Current_Limit", 32, "A")),
    ),
    MessageSpec(0x11, "Set_Traj_Vel_Limit", 8, "host", (_f32("Traj_Vel_Limit", 0, "rev/s"),)),
    MessageSpec(
        0x12,
        "Set_Traj_Accel_Limits",
        8,
        "host",
        (
            _f32("Traj_Accel_Limit", 0, "rev/s^2", attr="accel_limit"),
            _f32("Traj_Decel_Limit", 32, "rev/s^2", attr="decel_limit"),
        ),
    ),
    MessageSpec(
        0x13,
        "Set_Traj_Inertia",
        8,
        "host",
        (_f32("Traj_Inertia", 0, "Nm/(rev/s^2)", attr="inertia"),),
    ),
    MessageSpec(
        0x14,
        "Get_Iq",
        8,
        "drive",
        (_f32("Iq_Setpoint", 0, "A"), _f32("Iq_Measured", 32, "A")),
        requestable=True,
    ),
    MessageSpec(
        0x15,
        "Get_Temperature",
        8,
        "drive",
        (_f32("FET_Temperature", 0, "deg C"), _f32("Motor_Temperature", 32, "deg C")),
        requestable=True,
    ),
    MessageSpec(0x16, "Reboot", 1, "host", (_u("Action", 0, 8, "reboot_action"),)),
    MessageSpec(
        0x17,
        "Get_Bus_Voltage_Current",
        8,
        "drive",
        (_f32("Bus_Voltage", 0, "V"), _f32("Bus_Current", 32, "A")),
        requestable=True,
    ),
    MessageSpec(0x18, "Clear_Errors", 1, "host", (_u("Identify", 0, 8),)),
    MessageSpec(0x19, "Set_Absolute_Position", 8, "host", (_f32("Position", 0, "rev"),)),
    MessageSpec(0x1A, "Set_Pos_Gain", 8, "host", (_f32("Pos_Gain", 0, "(rev/s)/rev"),)),
    MessageSpec(
        0x1B,
        "Set_Vel_Gains",
        8,
        "host",
        (_f32("Vel_Gain", 0, "Nm/(rev/s)"), _f32("Vel_Integrator_Gain", 32, "Nm/rev")),
    ),
    MessageSpec(
        0x1C,
        "Get_Torques",
        8,
        "drive",
        (_f32("Torque_Target", 0, "Nm"), _f32("Torque_Estimate", 32, "Nm")),
        requestable=True,
    ),
    MessageSpec(
        0x1D,
        "Get_Powers",
        8,
        "drive",
        (_f32("Electrical_Power", 0, "W"), _f32("Mechanical_Power", 32, "W")),
        requestable=True,
    ),
    MessageSpec(0x1F, "Enter_DFU_Mode", 0, "host", (), "Refused by the virtual drive (counted)."),
)
BY_CMD = {m.cmd: m for m in MESSAGES}


def parse_nodes(text: str) -> tuple[int, ...]:
    """``"0-7"``, ``"0,1,12"`` or a mix -> sorted unique node ids (0..63); ValueError if bad."""
    nodes: set[int] = set()
    for part in text.split(","):
        part = part.strip()
        if not part:
            continue
        lo, sep, hi = part.partition("-")
        try:
            a, b = (int(lo), int(hi)) if sep else (int(lo), int(lo))
        except ValueError:
            raise ValueError(f"bad node list {text!r}: use e.g. 0-7 or 0,1,12") from None
        if not (0 <= a <= b <= MAX_NODE_ID):
            raise ValueError(f"node ids must be in 0..{MAX_NODE_ID}, got {part!r}")
        nodes.update(range(a, b + 1))
    if not nodes:
        raise ValueError("no node ids given")
    return tuple(sorted(nodes))


def _num(x: float) -> str:
    return repr(int(x)) if float(x).is_integer() else repr(float(x))


def _quote(text: str) -> str:
    return text.replace('"', "'")


def render(nodes: Iterable[int] = DEFAULT_NODES) -> str:
    """The DBC text for ``nodes`` (one message set per node, ids ``node << 5 | cmd``)."""
    nodes = tuple(sorted(set(nodes)))
    for n in nodes:
        if not 0 <= n <= MAX_NODE_ID:
            raise ValueError(f"node id {n} outside 0..{MAX_NODE_ID}")
    axes = [f"ODrive_Axis{n}" for n in nodes]
    out = [
        'VERSION "hil-smc-bench ODrive CANSimple 0.6"',
        "",
        "",
        "NS_ :",
        "\tCM_",
        "\tBA_DEF_",
        "\tBA_",
        "\tBA_DEF_DEF_",
        "\tVAL_",
        "\tSIG_VALTYPE_",
        "",
        "BS_:",
        "",
        "BU_: Master " + " ".join(axes),
        "",
    ]
    comments, values, valtypes, attrs = [], [], [], []
    for n in nodes:
        drive = f"ODrive_Axis{n}"
        for m in MESSAGES:
            fid = (n << 5) | m.cmd
            tx, rx = (drive, "Master") if m.sender == "drive" else ("Master", drive)
            out.append(f"BO_ {fid} Axis{n}_{m.name}: {m.dlc} {tx}")
            for s in m.signals:
                sign = "-" if s.signed else "+"
                lo = _num(s.minimum) if s.minimum is not None else "0"
                hi = _num(s.maximum) if s.maximum is not None else "0"
                out.append(
                    f" SG_ {s.name} : {s.start}|{s.length}@1{sign} ({_num(s.scale)},0) "
                    f'[{lo}|{hi}] "{s.unit}" {rx}'
                )
                if s.is_float:
                    valtypes.append(f"SIG_VALTYPE_ {fid} {s.name} : 1;")
                if s.choices:
                    table = " ".join(f'{v} "{k}"' for v, k in CHOICES[s.choices].items())
                    values.append(f"VAL_ {fid} {s.name} {table} ;")
                if s.comment:
                    comments.append(f'CM_ SG_ {fid} {s.name} "{_quote(s.comment)}";')
            out.append("")
            if m.comment:
                comments.append(f'CM_ BO_ {fid} "{_quote(m.comment)}";')
            if m.cycle_ms:
                attrs.append(f'BA_ "GenMsgCycleTime" BO_ {fid} {m.cycle_ms};')
    out.append("")
    out.append(
        'CM_ "ODrive CANSimple (firmware 0.6) for hil-smc-bench, generated by '
        f"python -m protocol.can.dbc --nodes {','.join(map(str, nodes))}. Frame id = "
        'node_id << 5 | cmd_id (11-bit), little-endian (Intel) fields.";'
    )
    out += comments
    out += [
        'BA_DEF_ BO_ "GenMsgCycleTime" INT 0 65535;',
        'BA_DEF_DEF_ "GenMsgCycleTime" 0;',
    ]
    out += attrs
    out += values
    out += valtypes
    return "\n".join(out) + "\n"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description="Write the CANSimple 0.6 DBC for some node ids.")
    p.add_argument("--nodes", default="0-7", help="node ids, e.g. 0-7 or 0,1,12 (default 0-7)")
    p.add_argument("-o", "--output", default="-", help="file to write (default: stdout)")
    a = p.parse_args(argv)
    try:
        text = render(parse_nodes(a.nodes))
    except ValueError as exc:
        p.error(str(exc))
    if a.output == "-":
        sys.stdout.write(text)
    else:
        with open(a.output, "w", encoding="utf-8") as f:
            f.write(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
