"""The virtual drives' bus edge takes the two frames a busy bus is made of without decoding them
(plant_emulator.can_drives.CanDrives._fast): a request (RTR) to one of its drives, and another
node's frame. What it does with them must be what the general path did: the same answer, bit
for bit, to every requestable message of both drives, the same counts, and nothing taken that
is not one of those two (an RTR the protocol does not allow, a CAN FD or extended frame, a frame
of its own nodes, another node's frame while frames are queued for the plant's loop).

Real python-can buses (the ``virtual`` interface: one in-process channel); the edge's threads
are not started, its ``_take`` is called as its reader calls it, so every answer read back is
the one that frame caused."""

from __future__ import annotations

import uuid

import can
import pytest

from plant_emulator.can_drives import CanDrives
from plant_emulator.odrive import VirtualDrivePair
from protocol.can import codec
from protocol.can.codec import REQUESTABLE, AxisState, Cmd, Frame, frame_id
from protocol.can.drive_link import from_message

RIGHT, LEFT, OTHER = 1, 0, 16
NOW_NS = 2_000_000_000


def _armed_pair() -> VirtualDrivePair:
    """Two drives in closed loop with a torque each, so every answer carries a value."""
    pair = VirtualDrivePair(RIGHT, LEFT, 0.5)
    for node, torque in ((RIGHT, 0.1), (LEFT, -0.05)):
        for msg in (
            codec.SetAxisState(node, AxisState.CLOSED_LOOP_CONTROL),
            codec.SetInputTorque(node, torque),
        ):
            pair.receive(1.0, codec.encode(msg))
        pair.feedback(1.5, {node: (0.25 * (node + 1), 0.5)})
    return pair


@pytest.fixture
def edge():
    channel = f"fast-{uuid.uuid4().hex}"
    drives_bus = can.Bus(interface="virtual", channel=channel)
    client = can.Bus(interface="virtual", channel=channel)
    drives = CanDrives(drives_bus, _armed_pair())
    try:
        yield drives, client
    finally:
        drives_bus.shutdown()
        client.shutdown()


def _rtr(arb: int) -> can.Message:
    return can.Message(arbitration_id=arb, is_remote_frame=True, is_extended_id=False)


def _data(arb: int, **kw) -> can.Message:
    """An 8-byte data frame, an 11-bit id unless ``is_extended_id`` (python-can's default)."""
    return can.Message(arbitration_id=arb, data=bytes(8), **{"is_extended_id": False, **kw})


def _answers(client: can.BusABC) -> list[Frame]:
    out = []
    while (msg := client.recv(0.0)) is not None:
        out.append(from_message(msg))
    return out


def _general_path_refused(monkeypatch) -> list[Frame]:
    """The frames the edge's general path took (its first step, ``from_message``, recorded)."""
    taken: list[Frame] = []

    def recorded(msg: can.Message) -> Frame:
        taken.append(from_message(msg))
        return taken[-1]

    monkeypatch.setattr("plant_emulator.can_drives.from_message", recorded)
    return taken


@pytest.mark.parametrize("cmd", sorted(REQUESTABLE))
@pytest.mark.parametrize("node", [RIGHT, LEFT])
def test_a_request_is_answered_as_the_general_path_answers_it(edge, node, cmd, monkeypatch):
    drives, client = edge
    general = _general_path_refused(monkeypatch)
    reference = _armed_pair()  # the same drives, built the same way
    arb = frame_id(node, cmd)
    want = reference.receive(NOW_NS / 1e9, Frame(arb, b"", is_remote=True))
    drives._take(_rtr(arb), NOW_NS)
    got = _answers(client)
    assert got == want and len(got) == 1 and not got[0].is_remote
    assert general == []  # taken without the general path's decoding
    assert (drives.requests, drives.frames_in, drives.frames_out) == (1, 1, 1)
    assert drives.pair.rejections.snapshot() == {} and dict(drives.pair.ignored) == {}
    # the request fed no watchdog, as the general path's answer does not
    assert drives.pair.last_fed is False


def test_an_encoder_estimate_answer_is_the_position_at_the_request_s_arrival(edge):
    drives, client = edge
    arb = frame_id(RIGHT, Cmd.GET_ENCODER_ESTIMATES)
    drives._take(_rtr(arb), NOW_NS)
    drives._take(_rtr(arb), NOW_NS + 100_000_000)
    first, later = (codec.decode(f) for f in _answers(client))
    assert later.pos_rev == pytest.approx(first.pos_rev + 0.1 * first.vel_rev_s, rel=1e-6)
    assert first.vel_rev_s != 0.0


def test_another_node_s_frame_is_counted_as_the_general_path_counts_it(edge, monkeypatch):
    drives, client = edge
    general = _general_path_refused(monkeypatch)
    reference = _armed_pair()  # the same drives, built the same way
    frames = [
        _data(frame_id(OTHER, Cmd.HEARTBEAT)),
        _rtr(frame_id(OTHER, Cmd.GET_BUS_VOLTAGE_CURRENT)),
        _data(frame_id(OTHER, Cmd.SET_INPUT_TORQUE)),
    ]
    for msg in frames:
        reference.receive(NOW_NS / 1e9, from_message(msg))
        drives._take(msg, NOW_NS)
    assert dict(drives.pair.ignored) == dict(reference.ignored) == {"other_node": 3}
    assert general == []
    assert drives.frames_in == 3 and drives.requests == 0
    assert _answers(client) == []


def test_what_is_not_a_plain_request_or_another_node_s_frame_takes_the_general_path(edge):
    drives, client = edge
    # an RTR of a message the protocol does not let a host request: a counted refusal
    drives._take(_rtr(frame_id(RIGHT, Cmd.SET_INPUT_TORQUE)), NOW_NS)
    assert drives.pair.rejections.snapshot() == {"unexpected_rtr": 1}
    # an extended frame, and a CAN FD frame of another node: another protocol's
    drives._take(_data(frame_id(OTHER, Cmd.HEARTBEAT), is_fd=True), NOW_NS)
    drives._take(_data(0x12345, is_extended_id=True), NOW_NS)
    assert dict(drives.pair.ignored) == {"extended_id": 2}
    assert drives.requests == 0 and _answers(client) == []
    # queued for the plant's loop (a run's applied path after its epoch): another node's frame
    # is queued as every frame is, not counted here
    drives.immediate = False
    drives._take(_data(frame_id(OTHER, Cmd.HEARTBEAT)), NOW_NS)
    assert len(drives.inbox) == 1 and "other_node" not in drives.pair.ignored
    # a request is answered at once whatever the mode
    drives._take(_rtr(frame_id(LEFT, Cmd.GET_TORQUES)), NOW_NS)
    assert drives.requests == 1 and len(_answers(client)) == 1
