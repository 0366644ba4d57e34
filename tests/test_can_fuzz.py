"""100,000+ random and mutated CAN frames through the CAN decoders (seeded loop).

Only :class:`CanDecodeError` may escape ``codec.decode``; the drive and host state machines
never raise, count every decoding rejection under its reason (the drives: of the frames
addressed to them; frames for other nodes and extended ids are counted as ignored), and no drive
ever applies a torque beyond its limit, whatever set points, limits and gains arrive.
"""

from __future__ import annotations

import math
import random
import struct
from collections import Counter

from plant_emulator.odrive import VirtualDrivePair
from protocol.can import codec
from protocol.can.codec import (
    AxisState,
    CanDecodeError,
    ClearErrors,
    ControlMode,
    EncoderEstimates,
    Frame,
    Heartbeat,
    InputMode,
    SetAxisState,
    SetControllerMode,
    SetInputTorque,
)
from protocol.can.drive_profile import HostLifecycle
from protocol.can.zenoh_bus import unpack_frame

N_FRAMES = 100_000
TORQUE_LIMIT = 0.5
SPECIAL_FLOATS = [math.nan, -math.nan, math.inf, -math.inf, 1e30, -1e30, 0.5, 0.50001, -0.6]


def _valid_frames() -> list[Frame]:
    msgs = []
    for node in (0, 1, 2):
        msgs += [
            SetInputTorque(node, 0.25),
            SetInputTorque(node, -0.5),
            SetAxisState(node, AxisState.CLOSED_LOOP_CONTROL),
            SetAxisState(node, AxisState.IDLE),
            SetControllerMode(node, ControlMode.TORQUE_CONTROL, InputMode.PASSTHROUGH),
            ClearErrors(node),
            Heartbeat(node, 0, AxisState.CLOSED_LOOP_CONTROL, 0, True),
            EncoderEstimates(node, 12.5, -3.0),
            codec.SetInputVel(node, 3.0, 0.1),
            codec.SetInputPos(node, 2.0, 0.5, 0.05),
            codec.SetLimits(node, 10.0, 5.0),
            codec.SetPosGain(node, 20.0),
            codec.SetVelGains(node, 0.2, 0.3),
            codec.SetAbsolutePosition(node, 1.0),
            codec.SetTrajVelLimit(node, 2.0),
            codec.SetTrajAccelLimits(node, 1.0, 1.0),
            codec.SetTrajInertia(node, 0.01),
            SetControllerMode(node, ControlMode.VELOCITY_CONTROL, InputMode.VEL_RAMP),
            SetControllerMode(node, ControlMode.POSITION_CONTROL, InputMode.TRAP_TRAJ),
            codec.Reboot(node, 0),
            codec.Estop(node),
            codec.Request(node, codec.Cmd.GET_IQ),
        ]
    return [codec.encode(m) for m in msgs]


def _mutate(rng: random.Random, frame: Frame) -> Frame:
    data = bytearray(frame.data)
    kind = rng.randrange(7)
    if kind == 0 and data:  # flip bits
        for _ in range(rng.randint(1, 4)):
            i = rng.randrange(len(data))
            data[i] ^= 1 << rng.randrange(8)
    elif kind == 1:  # truncate
        data = data[: rng.randrange(len(data) + 1)]
    elif kind == 2:  # extend (up to 10 bytes: beyond classical CAN too)
        data += bytes(rng.randrange(256) for _ in range(rng.randint(1, 10 - len(data))))
    elif kind == 3:  # a special float in the first or second slot
        slot = rng.choice((0, 4))
        data = data.ljust(8, b"\x00")
        data[slot : slot + 4] = struct.pack("<f", rng.choice(SPECIAL_FLOATS))
    elif kind == 4:  # another node or command
        return Frame(frame.arbitration_id ^ (1 << rng.randrange(11)), bytes(data))
    elif kind == 5:  # flags
        return Frame(frame.arbitration_id, bytes(data), rng.random() < 0.5, rng.random() < 0.5)
    else:  # random u32 in the first slot (axis states, modes)
        data = data.ljust(8, b"\x00")
        data[0:4] = struct.pack("<I", rng.choice((0, 1, 8, 14, 15, 255, 2**32 - 1)))
    return Frame(frame.arbitration_id, bytes(data))


def _random_frame(rng: random.Random) -> Frame:
    arb = rng.randrange(0x800) if rng.random() < 0.9 else rng.randrange(1 << 29)
    data = bytes(rng.randrange(256) for _ in range(rng.randint(0, 8)))
    return Frame(arb, data, rng.random() < 0.05, rng.random() < 0.05)


def test_can_fuzz_decoders_reject_only_with_typed_counted_errors():
    rng = random.Random(20240613)
    valid = _valid_frames()
    pair = VirtualDrivePair(node_right=1, node_left=0, torque_limit=TORQUE_LIMIT)
    host = HostLifecycle(node_right=1, node_left=0)
    host.start(0.0)
    arm = [
        codec.encode(m)
        for n in (0, 1)
        for m in (
            ClearErrors(n),
            SetControllerMode(n, ControlMode.TORQUE_CONTROL, InputMode.PASSTHROUGH),
            SetAxisState(n, AxisState.CLOSED_LOOP_CONTROL),
        )
    ]
    expected: Counter[str] = Counter()  # every frame (the host decodes all)
    expected_drives: Counter[str] = Counter()  # frames of nodes 0, 1 (standard ids)
    accepted = 0
    max_torque = 0.0
    for i in range(N_FRAMES):
        if i % 500 == 0:
            for f in arm:
                pair.receive(i * 1e-4, f)
        roll = rng.random()
        if roll < 0.4:
            frame = _random_frame(rng)
        elif roll < 0.9:
            frame = _mutate(rng, rng.choice(valid))
        else:
            frame = rng.choice(valid)
        ours = not frame.is_extended and (
            frame.arbitration_id > 0x7FF or codec.split_id(frame.arbitration_id)[0] in (0, 1)
        )
        try:
            codec.decode(frame)
            accepted += 1
        except CanDecodeError as exc:
            expected[exc.reason] += 1
            if ours:
                expected_drives[exc.reason] += 1
        pair.receive(i * 1e-4, frame)
        pair.update(i * 1e-4, {1: (0.0, 0.0), 0: (0.0, 0.0)})
        host.receive(i * 1e-4, frame)
        for drive in pair.drives.values():
            max_torque = max(max_torque, abs(drive.torque))
            assert abs(drive.torque) <= TORQUE_LIMIT
    assert accepted + sum(expected.values()) == N_FRAMES
    assert accepted > 10_000 and sum(expected.values()) > 10_000  # both paths exercised
    for reason in ("wrong_dlc", "non_finite", "unknown_cmd", "extended_id", "out_of_range"):
        assert expected[reason] > 100, reason
    for reason in ("wrong_dlc", "non_finite", "unknown_cmd", "out_of_range"):
        assert expected_drives[reason] > 50, reason
    host_counts, drive_counts = host.rejections.snapshot(), pair.rejections.snapshot()
    for reason, n in expected.items():
        assert host_counts.get(reason) == n, reason
        assert drive_counts.get(reason, 0) == expected_drives[reason], reason
    assert pair.ignored["extended_id"] == expected["extended_id"]
    assert pair.ignored["other_node"] > 1000
    assert pair.events["torque_clamped"] > 0  # 0.50001, -0.6, 1e30 reached the drives
    assert 0.0 < max_torque <= TORQUE_LIMIT


def test_can_fuzz_zenoh_payloads_only_raise_value_error():
    rng = random.Random(7)
    for _ in range(20_000):
        payload = bytes(rng.randrange(256) for _ in range(rng.randint(0, 40)))
        try:
            msg, _, _ = unpack_frame(payload)
        except ValueError:
            continue
        assert msg.dlc <= 8
