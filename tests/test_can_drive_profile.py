"""The drive lifecycle: the host (protocol.can.drive_profile) against the virtual drives
(plant_emulator.odrive), as pure state machines (no bus)."""

from __future__ import annotations

import math
import struct

from plant_emulator.odrive import DriveConfig, VirtualDrivePair
from protocol.can import codec
from protocol.can.codec import (
    AxisError,
    AxisState,
    Cmd,
    ControlMode,
    Estop,
    Frame,
    Request,
    SetInputTorque,
)
from protocol.can.drive_profile import HostLifecycle, Phase
from protocol.can.wheel_mapping import to_float32

LIMIT = 0.4


def _exchange(host: HostLifecycle, pair: VirtualDrivePair, frames: list[Frame], now: float):
    """Deliver host frames to the drives, then the drives' heartbeats to the host."""
    for f in frames:
        pair.receive(now, f)
    for f in pair.due_frames(now):
        host.receive(now, f)


def test_can_lifecycle_arms_both_drives_before_any_torque():
    host, pair = HostLifecycle(node_right=1, node_left=0), VirtualDrivePair(1, 0, LIMIT)
    assert host.torque_frames(0.1, 0.1) == []  # nothing before start
    frames = host.start(0.0)
    cmds = [codec.split_id(f.arbitration_id) for f in frames]
    # per node: Clear_Errors, Set_Controller_Mode, zero torque, then closed loop, in that order
    assert [c for n, c in cmds if n == 1] == [0x18, 0x0B, 0x0E, 0x07]
    assert host.torque_frames(0.1, 0.1) == []  # arming: still nothing
    _exchange(host, pair, frames, 0.0)
    assert host.phase is Phase.ACTIVE
    assert pair.right.control_mode == ControlMode.TORQUE_CONTROL
    for f in host.torque_frames(0.3, -0.2):
        pair.receive(0.0, f)
    assert (pair.right.torque, pair.left.torque) == (to_float32(0.3), to_float32(-0.2))
    for f in host.stop():
        pair.receive(0.0, f)
    assert pair.right.axis_state == AxisState.IDLE and pair.right.torque == 0.0
    assert host.phase is Phase.STOPPED and host.torque_frames(0.1, 0.1) == []


def test_can_lifecycle_waits_for_both_heartbeats_and_retries():
    host, pair = (
        HostLifecycle(node_right=1, node_left=0, retry_period=0.5),
        VirtualDrivePair(1, 0, LIMIT),
    )
    frames = host.start(0.0)
    for f in frames:  # the left drive is not there yet: only the right one hears the sequence
        if codec.split_id(f.arbitration_id)[0] == 1:
            pair.receive(0.0, f)
    for f in pair.due_frames(0.0):
        host.receive(0.0, f)
    assert host.phase is Phase.ARMING
    assert host.tick(0.2) == []
    again = host.tick(0.6)
    assert again == frames  # re-sent after retry_period
    _exchange(host, pair, again, 0.7)
    assert host.phase is Phase.ACTIVE


def test_can_drive_ignores_inputs_unless_closed_loop():
    pair = VirtualDrivePair(1, 0, LIMIT)
    pair.receive(0.0, codec.encode(SetInputTorque(1, 0.2)))
    assert pair.right.torque == 0.0 and not pair.last_fed  # refused: feeds no watchdog
    pair.receive(0.0, codec.encode(SetInputTorque(1, 0.0)))
    assert pair.last_fed  # a zero before arming is what hosts send: accepted
    assert pair.rejections.snapshot() == {"input_while_disarmed": 1}
    pair.receive(0.0, codec.encode(codec.SetAxisState(1, AxisState.CLOSED_LOOP_CONTROL)))
    assert pair.right.input_torque == 0.0  # nothing stale acts after arming


def test_can_estop_latches_error_with_zero_torque_until_cleared():
    host, pair = HostLifecycle(node_right=1, node_left=0), VirtualDrivePair(1, 0, LIMIT)
    _exchange(host, pair, host.start(0.0), 0.0)
    for f in host.torque_frames(0.3, 0.3):
        pair.receive(0.0, f)
    pair.receive(0.0, codec.encode(Estop(0)))
    assert pair.left.torque == 0.0 and pair.left.axis_error & AxisError.ESTOP_REQUESTED
    for f in pair.due_frames(1.0):
        host.receive(1.0, f)
    assert host.phase is Phase.FAULT and "node 0" in host.fault_reason
    assert host.torque_frames(0.3, 0.3) == []
    # re-arming without Clear_Errors is refused; the lifecycle sends it first, so it works
    pair.receive(1.0, codec.encode(codec.SetAxisState(0, AxisState.CLOSED_LOOP_CONTROL)))
    assert pair.left.axis_state == AxisState.IDLE
    assert pair.rejections.snapshot()["arm_with_error"] == 1
    _exchange(host, pair, host.start(2.0), 2.0)
    assert host.phase is Phase.ACTIVE


def test_can_heartbeat_timeout_is_a_fault():
    host, pair = (
        HostLifecycle(node_right=1, node_left=0, heartbeat_timeout=0.5),
        (VirtualDrivePair(1, 0, LIMIT)),
    )
    _exchange(host, pair, host.start(0.0), 0.0)
    assert host.phase is Phase.ACTIVE
    host.tick(0.4)
    assert host.phase is Phase.ACTIVE
    host.tick(0.6)
    assert host.phase is Phase.FAULT and "timeout" in host.fault_reason


def test_a_rearm_after_a_heartbeat_timeout_waits_for_a_new_heartbeat():
    """A drive silent past the timeout faults; the re-arm must not go ACTIVE on the heartbeat
    heard before it (then fault again at once and re-arm again: a storm of arming frames that
    overflowed the drives' and the recorder's receive queues)."""
    host, pair = HostLifecycle(node_right=1, node_left=0), VirtualDrivePair(1, 0, LIMIT)
    _exchange(host, pair, host.start(0.0), 0.0)
    host.tick(0.6)
    assert host.phase is Phase.FAULT
    rearm = host.start(0.6)
    host.tick(0.61)
    assert host.phase is Phase.ARMING and host.tick(0.62) == []  # no storm, no fault
    _exchange(host, pair, rearm, 0.7)  # the drives answer: a fresh heartbeat
    assert host.phase is Phase.ACTIVE


def test_can_torque_beyond_limit_is_clamped_and_non_finite_never_applies():
    # a vel_limit set for the motor, as a user does: with the firmware's 2 rev/s, torque
    # control at rest is capped at 2 rev/s x vel_gain = 0.33 Nm (the torque-mode limiter)
    config = DriveConfig(torque_limit=LIMIT, vel_limit=50.0)
    host, pair = HostLifecycle(node_right=1, node_left=0), VirtualDrivePair(1, 0, config=config)
    _exchange(host, pair, host.start(0.0), 0.0)
    for f in host.torque_frames(0.1, 0.1):
        pair.receive(0.0, f)
    # the firmware clamps the torque set point to its limit; so does the virtual drive
    pair.receive(0.0, codec.encode(SetInputTorque(1, LIMIT * 1.01)))
    assert pair.right.torque == LIMIT and pair.last_fed
    assert pair.events["torque_clamped"] == 1
    pair.receive(0.0, Frame(0x02E, struct.pack("<f", math.nan)))  # NaN: refused, counted
    assert pair.right.torque == LIMIT and not pair.last_fed
    assert pair.rejections.snapshot() == {"non_finite": 1}
    host.torque_limit = LIMIT
    frames = host.torque_frames(math.nan, 5.0)
    sent = [codec.decode(f).torque_nm for f in frames]
    assert sent[0] == 0.0 and LIMIT - 1e-7 < sent[1] <= LIMIT  # float32 rounded inward
    pair.receive(0.0, frames[1])
    assert pair.left.torque == sent[1]
    assert host.rejections.snapshot()["non_finite_command"] == 1


def test_can_drive_answers_remote_requests():
    pair = VirtualDrivePair(1, 0, LIMIT)
    pair.feedback(0.0, {1: (2.0, -1.0), 0: (0.0, 0.0)})
    answers = pair.receive(0.5, codec.encode(Request(1, Cmd.GET_ENCODER_ESTIMATES)))
    # the position is the motor's (offset 0 at boot), extrapolated to the request's time
    assert [codec.decode(f) for f in answers] == [codec.EncoderEstimates(1, 1.5, -1.0)]
    answers = pair.receive(0.5, codec.encode(Request(0, Cmd.HEARTBEAT)))
    assert codec.decode(answers[0]).axis_state == AxisState.IDLE


def test_can_periodic_frames_follow_their_rates():
    pair = VirtualDrivePair(1, 0, LIMIT, heartbeat_period=0.1, encoder_period=0.01)
    kinds = []
    for k in range(100):  # one second in 10 ms steps
        kinds += [codec.split_id(f.arbitration_id)[1] for f in pair.due_frames(k * 0.01)]
    assert kinds.count(Cmd.HEARTBEAT) == 2 * 10
    assert kinds.count(Cmd.GET_ENCODER_ESTIMATES) == 2 * 100


def test_can_host_ignores_other_nodes_and_flags_other_masters():
    host = HostLifecycle(node_right=1, node_left=0)
    host.receive(0.0, codec.encode(codec.Heartbeat(7, 0, AxisState.IDLE)))
    host.receive(0.0, codec.encode(SetInputTorque(0, 0.1)))
    assert host.ignored["other_node"] == 1
    assert host.rejections.snapshot() == {"wrong_direction": 1}
