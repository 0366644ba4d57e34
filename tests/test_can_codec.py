"""CANSimple frames: hand-computed bytes from the public 0.6 spec, the same frames through the
official ODrive DBC (0.6.10, shipped by the PyPI odrive-can client), and strict decoding."""

from __future__ import annotations

import math
import struct

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from odrive_can import get_dbc

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
from protocol.can.dbc import MESSAGES

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
    (codec.Version(1, 2, 4, 4, 58, 0, 6, 10, 1), 0x020, "02 04 04 3A 00 06 0A 01"),
    (codec.ErrorStatus(0, 0x02000000, 0x01000000), 0x003, "00 00 00 02 00 00 00 01"),
    (codec.RxSdo(1, 0, 0x1234, 7), 0x024, "00 34 12 00 07 00 00 00"),
    (codec.TxSdo(1, 0x1234, 7), 0x025, "00 34 12 00 07 00 00 00"),
    (codec.Address(1, 1, 0xAABBCCDDEEFF), 0x026, "01 FF EE DD CC BB AA 00"),
    # Vel_FF and Torque_FF are int16 in units of 0.001: 1.5 -> 1500 = 0x05DC, -0.25 -> 0xFF06
    (codec.SetInputPos(0, 1.0, 1.5, -0.25), 0x00C, "00 00 80 3F DC 05 06 FF"),
    (codec.SetInputVel(1, 2.0, -0.5), 0x02D, "00 00 00 40 00 00 00 BF"),
    (codec.SetLimits(0, 10.0, 5.0), 0x00F, "00 00 20 41 00 00 A0 40"),
    (codec.SetTrajVelLimit(1, 2.0), 0x031, "00 00 00 40 00 00 00 00"),
    (codec.SetTrajAccelLimits(1, 0.5, 0.25), 0x032, "00 00 00 3F 00 00 80 3E"),
    (codec.SetTrajInertia(0, 0.0), 0x013, "00 00 00 00 00 00 00 00"),
    (codec.Iq(1, 1.0, -1.0), 0x034, "00 00 80 3F 00 00 80 BF"),
    (codec.Temperature(0, 25.0, 30.0), 0x015, "00 00 C8 41 00 00 F0 41"),
    (codec.Reboot(1, 0), 0x036, "00"),
    (codec.BusVoltageCurrent(0, 24.0, 0.5), 0x017, "00 00 C0 41 00 00 00 3F"),
    (codec.SetAbsolutePosition(1, 100.0), 0x039, "00 00 C8 42 00 00 00 00"),
    (codec.SetPosGain(0, 20.0), 0x01A, "00 00 A0 41 00 00 00 00"),
    (codec.SetVelGains(1, 0.5, 1.0), 0x03B, "00 00 00 3F 00 00 80 3F"),
    (codec.Torques(0, 0.5, 0.25), 0x01C, "00 00 00 3F 00 00 80 3E"),
    (codec.Powers(1, 2.0, 1.5), 0x03D, "00 00 00 40 00 00 C0 3F"),
    (codec.EnterDfuMode(1), 0x03F, ""),
]


@pytest.mark.parametrize(("msg", "arb", "hexdata"), VECTORS, ids=lambda v: repr(v)[:40])
def test_can_frame_equals_hand_bytes_and_round_trips(msg, arb, hexdata):
    frame = codec.encode(msg)
    assert frame.arbitration_id == arb
    assert frame.data == bytes.fromhex(hexdata)
    assert not frame.is_remote and not frame.is_extended
    assert codec.decode(frame) == msg
    # and through cantools directly, by the shipped DBC's message of that very id (both DBCs
    # hold axes 0-7; node 63's frame is read by node 0's message of that cmd)
    dbc_id = arb if arb >> 5 < 8 else arb & 0x1F
    dbc_msg = codec.database().get_message_by_frame_id(dbc_id)
    assert dbc_msg.encode(dbc_msg.decode(frame.data, decode_choices=False)) == frame.data
    # and ODrive's own DBC reads the same values (scaled, float32-rounded)
    official = get_dbc().get_message_by_frame_id(dbc_id)
    assert official.length == len(frame.data)
    ours = dbc_msg.decode(frame.data, decode_choices=False)
    theirs = official.decode(frame.data, decode_choices=False)
    assert theirs.keys() == ours.keys()
    for name, value in ours.items():
        assert theirs[name] == pytest.approx(value, rel=0, abs=1e-9), name


def test_can_every_profile_command_has_a_vector():
    assert {codec.split_id(arb)[1] for _, arb, _ in VECTORS} == {int(c) for c in Cmd}


def test_can_remote_requests_for_heartbeat_and_estimates():
    frame = codec.encode(Request(0, Cmd.GET_ENCODER_ESTIMATES))
    assert frame == Frame(0x009, b"", is_remote=True)
    assert codec.decode(frame) == Request(0, Cmd.GET_ENCODER_ESTIMATES)
    # the protocol's alternative: a data frame of the id with no payload
    assert codec.decode(Frame(0x020, b"")) == Request(1, Cmd.GET_VERSION)
    assert codec.decode(Frame(0x037, b"", is_remote=True)) == Request(
        1, Cmd.GET_BUS_VOLTAGE_CURRENT
    )
    for cmd in codec.REQUESTABLE:
        assert codec.is_request(Frame(0x20 | cmd, b"", is_remote=True))
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
        (Frame(0x02A, bytes(8)), "unknown_cmd"),
        (Frame(0x030, bytes(8)), "unknown_cmd"),
        (Frame(0x036, b"\x04"), "out_of_range"),
        (Frame(0x024, b"\x02" + bytes(7)), "out_of_range"),
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


def _signal_values(cmd: Cmd) -> st.SearchStrategy[dict]:
    """Values for every signal of ``cmd``: doubles within float32's range (they round) for the
    floats, integers in and out of each integer signal's range."""
    parts = {}
    for s in codec._message(cmd).signals:
        if s.is_float:
            parts[s.name] = st.floats(-3.4e38, 3.4e38, allow_nan=False)
        else:
            half = 1 << (s.length - 1)
            lo, hi = (-half, half - 1) if s.is_signed else (0, 2 * half - 1)
            parts[s.name] = st.integers(lo - 2, hi + 2)
    return st.fixed_dictionaries(parts)


@pytest.mark.parametrize("cmd", [c for c in Cmd if codec._packing(c) is not None], ids=str)
@settings(max_examples=200, deadline=None)
@given(data=st.data())
def test_can_fast_packing_is_cantools_encoding_of_every_message(cmd, data):
    """The drives' fast encoder (codec._pack, read from the DBC) writes the bytes cantools'
    strict encoding writes, for every message it packs; where cantools refuses a value (an
    integer out of its signal's range) it declines, and encode() gets cantools' refusal."""
    sig = data.draw(_signal_values(cmd))
    packed = codec._pack(codec._packing(cmd), sig)
    try:
        reference = codec._encode_dbc(cmd, sig)
    except CanEncodeError:
        assert packed is None, (sig, packed)
    else:
        assert packed == reference, sig


F32_EDGES = [3.4028234663852886e38, 3.4028235e38, 3.4028236e38, 1e39, math.inf, math.nan]


@pytest.mark.parametrize(
    "cls", [c for c in codec._LAYOUT if codec._aligned(c) is not None], ids=lambda c: c.__name__
)
@settings(max_examples=200, deadline=None)
@given(data=st.data())
def test_can_aligned_packing_writes_what_the_general_encoding_writes(cls, data):
    """encode() packs a byte-aligned message with one struct (codec._aligned): the same frame
    as its general path for every value that path takes, and for every value it refuses
    (non-finite, beyond float32, an integer out of range) the general path's refusal."""
    cmd, names = codec._LAYOUT[cls]
    values = data.draw(_signal_values(cmd))
    for _, signal in names:  # the float32 edges and the non-finite, either sign
        if isinstance(values[signal], float) and data.draw(st.booleans()):
            values[signal] = data.draw(st.sampled_from(F32_EDGES)) * data.draw(
                st.sampled_from([1.0, -1.0])
            )
    msg = cls(1, **{attr: values[signal] for attr, signal in names})
    try:
        want = codec._encode_general(msg)
    except CanEncodeError:
        with pytest.raises(CanEncodeError):
            codec.encode(msg)
    else:
        assert codec.encode(msg) == want, values


def test_can_aligned_packing_takes_every_answer_but_the_bit_fields():
    """The drives' answers pack with one struct but Heartbeat (bit fields) and Address (a
    48-bit serial number), which codec._pack packs."""
    drive_to_host = {codec._CLASS_OF[Cmd(m.cmd)] for m in MESSAGES if m.sender == "drive"}
    drive_to_host.add(codec.Address)  # a host's request, and the drive's answer to it
    bit_fields = {c.__name__ for c in drive_to_host if codec._aligned(c) is None}
    assert bit_fields == {"Heartbeat", "Address"}


def test_can_fast_packing_covers_every_answer_of_a_drive():
    """Every drive -> host message is packed without cantools (the drives' answers and cyclic
    frames); only Set_Input_Pos (scaled 16-bit feed-forwards) is left to cantools."""
    drive_to_host = {Cmd(m.cmd) for m in MESSAGES if m.sender == "drive"}
    assert all(codec._packing(c) is not None for c in drive_to_host)
    assert [c for c in Cmd if codec._packing(c) is None] == [Cmd.SET_INPUT_POS]
