"""CANSimple frames: hand-computed bytes from the public 0.6 spec, and strict decoding."""

from __future__ import annotations

import math
import struct

import pytest

from protocol.can import codec
from protocol.can.codec import (
    AxisState,
    CanDecodeError,
    CanEncodeError,
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

# (message, arbitration id, data) written by hand: id = node << 5 | cmd, little-endian fields,
# floats as IEEE-754 single (1.5 = 0x3FC00000, -2.0 = 0xC0000000, 1.0 = 0x3F800000,
# -0.5 = 0xBF000000), DLC as in ODrive's odrive-cansimple-0.6 DBC.
VECTORS = [
    (SetInputTorque(1, 1.5), 0x02E, "00 00 C0 3F 00 00 00 00"),
    (SetInputTorque(0, -2.0), 0x00E, "00 00 00 C0 00 00 00 00"),
    (SetInputTorque(63, 0.0), 0x7EE, "00 00 00 00 00 00 00 00"),
    (Heartbeat(1, 0, AxisState.CLOSED_LOOP_CONTROL, 0, True), 0x021, "00 00 00 00 08 00 01 00"),
    (Heartbeat(0, 0x02000000, AxisState.IDLE, 0, False), 0x001, "00 00 00 02 01 00 00 00"),
    (Estop(1), 0x022, ""),
    (SetAxisState(0, AxisState.CLOSED_LOOP_CONTROL), 0x007, "08 00 00 00 00 00 00 00"),
    (SetAxisState(1, AxisState.IDLE), 0x027, "01 00 00 00 00 00 00 00"),
    (EncoderEstimates(1, 1.0, -0.5), 0x029, "00 00 80 3F 00 00 00 BF"),
    (
        SetControllerMode(0, ControlMode.TORQUE_CONTROL, InputMode.PASSTHROUGH),
        0x00B,
        "01 00 00 00 01 00 00 00",
    ),
    (ClearErrors(1), 0x038, "00"),
]


@pytest.mark.parametrize(("msg", "arb", "hexdata"), VECTORS, ids=lambda v: repr(v)[:40])
def test_can_frame_equals_hand_bytes_and_round_trips(msg, arb, hexdata):
    frame = codec.encode(msg)
    assert frame.arbitration_id == arb
    assert frame.data == bytes.fromhex(hexdata)
    assert not frame.is_remote and not frame.is_extended
    assert codec.decode(frame) == msg
    # and through cantools directly, by the DBC's node-0 message of that cmd id
    dbc_msg = codec.database().get_message_by_frame_id(arb & 0x1F)
    assert dbc_msg.encode(dbc_msg.decode(frame.data, decode_choices=False)) == frame.data


def test_can_every_profile_command_has_a_vector():
    assert {codec.split_id(arb)[1] for _, arb, _ in VECTORS} == {int(c) for c in Cmd}


def test_can_remote_requests_for_heartbeat_and_estimates():
    frame = codec.encode(Request(0, Cmd.GET_ENCODER_ESTIMATES))
    assert frame == Frame(0x009, b"", is_remote=True)
    assert codec.decode(frame) == Request(0, Cmd.GET_ENCODER_ESTIMATES)
    with pytest.raises(CanDecodeError) as err:
        codec.decode(Frame(0x00E, b"", is_remote=True))
    assert err.value.reason == "unexpected_rtr"


def test_can_short_payloads_from_other_tools_are_accepted_when_complete():
    # ODrive's own can_simple example sends Set_Input_Torque as struct.pack("<f"): 4 bytes
    assert codec.decode(Frame(0x02E, struct.pack("<f", 1.5))) == SetInputTorque(1, 1.5)
    assert codec.decode(Frame(0x027, struct.pack("<I", 8))) == SetAxisState(1, 8)
    assert codec.decode(Frame(0x038, b"")) == ClearErrors(1, 0)


@pytest.mark.parametrize(
    ("frame", "reason"),
    [
        (Frame(0x02E, b"\x00\x00\xc0"), "wrong_dlc"),
        (Frame(0x02E, bytes(9)), "wrong_dlc"),
        (Frame(0x029, bytes(7)), "wrong_dlc"),
        (Frame(0x02E, struct.pack("<f", math.nan)), "non_finite"),
        (Frame(0x02E, struct.pack("<f", math.inf)), "non_finite"),
        (Frame(0x029, struct.pack("<ff", 0.0, -math.inf)), "non_finite"),
        (Frame(0x02F, bytes(8)), "unknown_cmd"),
        (Frame(0x02E, bytes(8), is_extended=True), "extended_id"),
        (Frame(0x800, bytes(8)), "bad_id"),
        (Frame(0x027, struct.pack("<I", 99)), "out_of_range"),
        (Frame(0x00B, struct.pack("<II", 1, 42)), "out_of_range"),
        (Frame(0x001, bytes([0, 0, 0, 0, 200, 0, 0, 0])), "out_of_range"),
    ],
)
def test_can_bad_frames_are_one_typed_error_with_a_reason(frame, reason):
    with pytest.raises(CanDecodeError) as err:
        codec.decode(frame)
    assert err.value.reason == reason


def test_can_node_filter_rejects_other_nodes():
    frame = codec.encode(SetInputTorque(5, 0.0))
    with pytest.raises(CanDecodeError) as err:
        codec.decode(frame, nodes=frozenset({0, 1}))
    assert err.value.reason == "unknown_node"


@pytest.mark.parametrize(
    "msg",
    [SetInputTorque(0, math.nan), SetInputTorque(0, 1e39), EncoderEstimates(0, math.inf, 0.0)],
)
def test_can_encoder_refuses_what_the_wire_cannot_carry(msg):
    with pytest.raises(CanEncodeError):
        codec.encode(msg)


def test_can_encoder_refuses_bad_node_ids():
    with pytest.raises(CanEncodeError):
        codec.encode(SetInputTorque(64, 0.0))
