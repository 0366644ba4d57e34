"""The virtual ODrive (plant_emulator.odrive) as a pure model: each CANSimple 0.6 message has its
documented effect or a counted refusal the host can see (docs/can.md lists them)."""

from __future__ import annotations

import math

import pytest

from plant_emulator.can_drives import EchoFilter
from plant_emulator.drive_plant import DrivePlant, bench_drive_config, bench_drive_settings
from plant_emulator.dynamics import Extremes, PlantState
from plant_emulator.odrive import DriveConfig, ODriveAxis, VirtualDrivePair
from plant_emulator.service import PlantCore
from protocol.can import codec
from protocol.can.codec import (
    AxisState,
    Cmd,
    ControlMode,
    Frame,
    InputMode,
    ODriveError,
    ProcedureResult,
    Request,
)
from protocol.can.wheel_mapping import RobotGeometry

J = 1e-3  # Nm per rev/s^2: a toy rotor for one axis


class Rotor:
    """One axis driving a bare rotor, stepped at ``dt``."""

    def __init__(self, config: DriveConfig | None = None, node: int = 3) -> None:
        default = DriveConfig(torque_limit=0.5, vel_limit=50.0, enable_torque_mode_vel_limit=False)
        self.axis = ODriveAxis(node, config or default)
        self.t, self.pos, self.vel = 0.0, 0.0, 0.0

    def send(self, msg) -> list:
        answers, _ = self.axis.receive(self.t, codec.decode(codec.encode(msg)))
        return [codec.decode(f) for f in answers]

    def ask(self, cmd: Cmd):
        return self.send(Request(self.axis.node, cmd))[0]

    def run(self, seconds: float, dt: float = 1e-3) -> None:
        for _ in range(round(seconds / dt)):
            self.axis.update(self.t, self.pos, self.vel)
            acc = self.axis.torque / J
            self.pos += self.vel * dt + 0.5 * acc * dt * dt
            self.vel += acc * dt
            self.t += dt

    def arm(self, control: int, input_mode: int = InputMode.PASSTHROUGH) -> None:
        n = self.axis.node
        self.send(codec.SetControllerMode(n, control, input_mode))
        self.send(codec.SetAxisState(n, AxisState.CLOSED_LOOP_CONTROL))
        assert self.axis.armed


def robot_drives(watchdog: float = 0.0):
    """The bench's robot (paper limits, default geometry) with its two drives."""
    from controller_service.laws.base import Limits

    limits = Limits()
    geom = RobotGeometry()
    config = bench_drive_config(bench_drive_settings(geom, limits), watchdog)
    pair = VirtualDrivePair(1, 0, config=config)
    core = PlantCore(PlantState(0.0, 0.0, 0.0, 0.0, 0.0), 1e-4, limits, extremes=Extremes())
    return pair, core, DrivePlant(pair, geom, limits, 0.0, core.state, 0.0), geom


def arm_both(pair: VirtualDrivePair, t: float = 0.0) -> None:
    for n in (0, 1):
        for m in (
            codec.ClearErrors(n),
            codec.SetControllerMode(n, ControlMode.TORQUE_CONTROL, InputMode.PASSTHROUGH),
            codec.SetAxisState(n, AxisState.CLOSED_LOOP_CONTROL),
        ):
            pair.receive(t, codec.encode(m))


def test_can_pos_estimate_integrates_the_wheels_motion():
    pair, core, link, geom = robot_drives()
    arm_both(pair)
    t, dt = 0.0, 1e-3
    integral = {0: 0.0, 1: 0.0}
    for k in range(1500):
        if k == 0:
            pair.receive(t, codec.encode(codec.SetInputTorque(1, 0.05)))
            pair.receive(t, codec.encode(codec.SetInputTorque(0, 0.01)))
        if k == 700:
            pair.receive(t, codec.encode(codec.SetInputTorque(1, -0.02)))
        before = {n: d.vel for n, d in pair.drives.items()}
        core.hold(*link.torques())
        core.advance_to(t + dt)
        t += dt
        link.update(t, core.t, core.state)
        for n, d in pair.drives.items():
            integral[n] += 0.5 * (before[n] + d.vel) * dt
    assert core.state.omega != 0.0 and core.state.v > 0.0  # it turned and went forward
    for n, d in pair.drives.items():
        pos = codec.decode(d.encoder_estimates(t)).pos_rev
        assert abs(integral[n]) > 5.0
        assert pos == pytest.approx(integral[n], rel=1e-4, abs=1e-4)  # float32 of the wire
    # and it is the robot's own odometry: S = ((pos_R + pos_L) / 2) 2 pi r / G
    k = geom.gear_ratio / (2 * math.pi * geom.wheel_radius)
    s = (pair.right.pos_estimate_at(t) + pair.left.pos_estimate_at(t)) / (2 * k)
    heading = (pair.right.pos_estimate_at(t) - pair.left.pos_estimate_at(t)) / (
        2 * k * geom.half_track
    )
    assert heading == pytest.approx(core.state.theta, rel=1e-9, abs=1e-9)
    assert s == pytest.approx(link.odometry.s, rel=1e-12)


def test_can_requests_carry_the_current_values():
    pair, core, link, _ = robot_drives()
    arm_both(pair)
    pair.receive(0.0, codec.encode(codec.SetInputTorque(1, 0.1)))
    pair.receive(0.0, codec.encode(codec.SetInputTorque(0, 0.1)))
    core.hold(*link.torques())
    core.advance_to(0.2)
    link.update(0.2, core.t, core.state)
    right = pair.right
    enc = codec.decode(pair.receive(0.2, codec.encode(Request(1, Cmd.GET_ENCODER_ESTIMATES)))[0])
    assert enc.vel_rev_s == pytest.approx(right.vel, rel=1e-6) and enc.vel_rev_s > 1.0
    assert enc.pos_rev == pytest.approx(right.pos_estimate_at(0.2), rel=1e-6)
    later = codec.decode(pair.receive(0.25, codec.encode(Request(1, Cmd.GET_ENCODER_ESTIMATES)))[0])
    assert later.pos_rev == pytest.approx(enc.pos_rev + 0.05 * enc.vel_rev_s, rel=1e-5)

    def ask(cmd):
        return codec.decode(pair.receive(0.2, codec.encode(Request(1, cmd)))[0])

    kt = right.config.torque_constant
    assert ask(Cmd.GET_IQ) == codec.Iq(1, pytest.approx(0.1 / kt), pytest.approx(0.1 / kt))
    tq = ask(Cmd.GET_TORQUES)
    assert tq.torque_target == pytest.approx(0.1) and tq.torque_estimate == pytest.approx(0.1)
    pw = ask(Cmd.GET_POWERS)
    mech = 0.1 * right.vel * 2 * math.pi
    assert pw.mechanical_power == pytest.approx(mech, rel=1e-6)
    loss = 1.5 * right.config.phase_resistance * (0.1 / kt) ** 2
    assert pw.electrical_power == pytest.approx(mech + loss, rel=1e-6)
    bus = ask(Cmd.GET_BUS_VOLTAGE_CURRENT)
    assert bus.bus_voltage == 24.0 and bus.bus_current == pytest.approx((mech + loss) / 24.0)
    assert ask(Cmd.GET_ERROR) == codec.ErrorStatus(1, 0, 0)
    assert ask(Cmd.GET_TEMPERATURE) == codec.Temperature(1, 25.0, 25.0)
    assert ask(Cmd.GET_VERSION) == codec.Version(1, 2, 4, 4, 58, 0, 6, 10, 1)
    hb = ask(Cmd.HEARTBEAT)
    assert (hb.axis_state, hb.axis_error) == (AxisState.CLOSED_LOOP_CONTROL, 0)
    # discovery: to the node, and to every node (0x3F)
    assert ask(Cmd.ADDRESS) == codec.Address(1, 1, right.serial)
    everyone = pair.receive(0.2, Frame(0x3F << 5 | Cmd.ADDRESS, b"", is_remote=True))
    assert {codec.decode(f).node_id for f in everyone} == {0, 1}


def test_can_set_limits_clamp_the_torque_and_negative_ones_are_refused():
    rotor = Rotor()
    rotor.arm(ControlMode.TORQUE_CONTROL)
    rotor.send(codec.SetInputTorque(3, 0.3))
    assert rotor.axis.torque == pytest.approx(0.3)
    rotor.send(codec.SetLimits(3, 100.0, 2.0))  # 2 A x 0.04 Nm/A (the firmware's constant)
    assert rotor.axis.torque == pytest.approx(0.08)
    assert rotor.ask(Cmd.GET_TORQUES).torque_target == pytest.approx(0.08)
    rotor.send(codec.SetInputTorque(3, 5.0))  # beyond the drive's own limit: clamped too
    assert rotor.axis.torque == pytest.approx(0.08)
    assert rotor.axis.events["torque_clamped"] == 1
    rotor.send(codec.SetLimits(3, -1.0, 2.0))
    assert rotor.axis.rejections.snapshot() == {"negative_limit": 1}


def test_can_velocity_control_through_the_drive_loop():
    rotor = Rotor(DriveConfig(torque_limit=0.5, vel_limit=50.0))
    rotor.arm(ControlMode.VELOCITY_CONTROL)
    rotor.send(codec.SetInputVel(3, 10.0, 0.0))
    rotor.run(1.0)  # the firmware's gains put the PI zero at ki / kp = 2 /s: a slow tail
    assert rotor.vel == pytest.approx(10.0, rel=2e-3)
    # the velocity limit caps the set point (not below 1/1.2 of the speed: overspeed error)
    rotor.send(codec.SetLimits(3, 9.0, 100.0))
    rotor.run(1.0)
    assert rotor.vel == pytest.approx(9.0, rel=2e-3)
    # VEL_RAMP: the set point moves at vel_ramp_rate (firmware default 1 rev/s^2)
    rotor.send(codec.SetControllerMode(3, ControlMode.VELOCITY_CONTROL, InputMode.VEL_RAMP))
    rotor.send(codec.SetLimits(3, 50.0, 100.0))
    rotor.send(codec.SetInputVel(3, 12.0, 0.0))
    rotor.run(1.0)
    assert rotor.axis.vel_setpoint == pytest.approx(10.0, abs=2e-3)  # 9 + 1 rev/s^2 x 1 s


def test_can_position_control_and_trapezoidal_trajectory():
    rotor = Rotor(DriveConfig(torque_limit=0.5, vel_limit=50.0))
    rotor.arm(ControlMode.POSITION_CONTROL)
    rotor.send(codec.SetInputPos(3, 2.0, 0.0, 0.0))
    rotor.run(1.5)
    assert rotor.ask(Cmd.GET_ENCODER_ESTIMATES).pos_rev == pytest.approx(2.0, abs=3e-3)
    rotor.send(codec.SetControllerMode(3, ControlMode.POSITION_CONTROL, InputMode.TRAP_TRAJ))
    rotor.send(codec.SetTrajVelLimit(3, 2.0))
    rotor.send(codec.SetTrajAccelLimits(3, 4.0, 4.0))
    rotor.send(codec.SetInputPos(3, 4.0, 0.0, 0.0))
    rotor.run(0.3)
    assert not rotor.ask(Cmd.HEARTBEAT).trajectory_done
    assert 0.0 < rotor.vel <= 2.0 * 1.05
    rotor.run(1.5)  # 2 rev at 2 rev/s with 0.5 s ramps: 1.5 s, then settle
    assert rotor.ask(Cmd.HEARTBEAT).trajectory_done
    assert rotor.pos == pytest.approx(4.0, abs=3e-3)


def test_can_absolute_position_moves_the_frame_not_the_motor():
    rotor = Rotor(DriveConfig(torque_limit=0.5, vel_limit=50.0))
    rotor.arm(ControlMode.POSITION_CONTROL)
    rotor.run(0.1)
    rotor.send(codec.SetAbsolutePosition(3, 100.0))
    assert rotor.ask(Cmd.GET_ENCODER_ESTIMATES).pos_rev == pytest.approx(100.0)
    rotor.run(0.5)
    assert rotor.pos == pytest.approx(0.0, abs=1e-6)  # held where it was
    rotor.send(codec.SetInputPos(3, 101.0, 0.0, 0.0))
    rotor.run(1.5)
    assert rotor.pos == pytest.approx(1.0, abs=3e-3)


def test_can_watchdog_expiry_disarms_with_an_error_fed_by_accepted_commands_only():
    rotor = Rotor(DriveConfig(torque_limit=0.5, vel_limit=50.0, watchdog_timeout=0.1))
    rotor.arm(ControlMode.TORQUE_CONTROL)
    for _ in range(10):  # a host at 20 Hz keeps it armed
        rotor.send(codec.SetInputTorque(3, 0.01))
        rotor.run(0.05)
    assert rotor.axis.armed
    # requests and refused frames do not feed it
    for _ in range(6):
        rotor.ask(Cmd.GET_ENCODER_ESTIMATES)
        rotor.axis.receive(rotor.t, codec.SetInputTorque(3, math.nan))  # the codec's job...
        rotor.run(0.02)
    assert not rotor.axis.armed
    hb = rotor.ask(Cmd.HEARTBEAT)
    assert hb.axis_state == AxisState.IDLE and hb.axis_error == ODriveError.WATCHDOG_TIMER_EXPIRED
    assert rotor.ask(Cmd.GET_ERROR).disarm_reason == ODriveError.WATCHDOG_TIMER_EXPIRED
    assert rotor.axis.torque == 0.0 and rotor.axis.events["watchdog_expired"] == 1
    rotor.send(codec.ClearErrors(3))
    rotor.arm(ControlMode.TORQUE_CONTROL)


def test_can_estop_latches_until_clear_errors():
    rotor = Rotor()
    rotor.arm(ControlMode.TORQUE_CONTROL)
    rotor.send(codec.SetInputTorque(3, 0.2))
    rotor.send(codec.Estop(3))
    assert rotor.axis.torque == 0.0 and rotor.axis.axis_state == AxisState.IDLE
    assert rotor.ask(Cmd.GET_ERROR) == codec.ErrorStatus(
        3, ODriveError.ESTOP_REQUESTED, ODriveError.ESTOP_REQUESTED
    )
    rotor.send(codec.SetAxisState(3, AxisState.CLOSED_LOOP_CONTROL))
    assert not rotor.axis.armed and rotor.axis.procedure_result == ProcedureResult.INVALID_STATE
    rotor.send(codec.ClearErrors(3))
    rotor.arm(ControlMode.TORQUE_CONTROL)
    assert rotor.axis.input_torque == 0.0  # the torque before the estop does not come back


def test_can_states_and_modes_without_a_virtual_equivalent_are_visible_refusals():
    rotor = Rotor()
    rotor.send(codec.SetAxisState(3, AxisState.FULL_CALIBRATION_SEQUENCE))
    assert rotor.ask(Cmd.HEARTBEAT).procedure_result == ProcedureResult.SUCCESS
    rotor.send(codec.SetAxisState(3, AxisState.HOMING))
    assert rotor.ask(Cmd.HEARTBEAT).procedure_result == ProcedureResult.HOMING_WITHOUT_ENDSTOP
    rotor.send(codec.SetAxisState(3, AxisState.SENSORLESS_CONTROL))
    assert rotor.ask(Cmd.HEARTBEAT).procedure_result == ProcedureResult.INVALID_STATE
    rotor.arm(ControlMode.TORQUE_CONTROL)
    rotor.send(codec.SetControllerMode(3, ControlMode.TORQUE_CONTROL, InputMode.MIRROR))
    hb = rotor.ask(Cmd.HEARTBEAT)
    assert hb.axis_state == AxisState.IDLE and hb.axis_error == ODriveError.BAD_CONFIG
    rotor.send(codec.EnterDfuMode(3))
    rotor.send(codec.RxSdo(3, 0, 0x10, 0))
    rotor.send(codec.Address(3, 9, rotor.axis.serial))
    assert rotor.axis.rejections.snapshot() == {
        "dfu_refused": 1,
        "homing_without_endstop": 1,
        "node_id_change_refused": 1,
        "sdo_unsupported": 1,
        "unsupported_mode": 1,
        "unsupported_state": 1,
    }


def test_can_reboot_and_saved_configuration():
    rotor = Rotor()
    rotor.arm(ControlMode.TORQUE_CONTROL)
    rotor.send(codec.Reboot(3, 0))
    assert rotor.axis.rejections.get("reboot_while_armed") == 1 and rotor.axis.armed
    rotor.send(codec.SetAxisState(3, AxisState.IDLE))
    rotor.send(codec.SetLimits(3, 7.0, 3.0))
    rotor.send(codec.Reboot(3, 1))  # save_configuration, then reboot
    assert rotor.axis.config.vel_limit == 7.0 and rotor.axis.control_mode == 3
    rotor.send(codec.SetLimits(3, 9.0, 3.0))
    rotor.send(codec.Reboot(3, 0))  # not saved: back to the saved 7
    assert rotor.axis.config.vel_limit == 7.0
    rotor.send(codec.Reboot(3, 2))  # erase_configuration: the configuration it was built with
    assert rotor.axis.config.vel_limit == 50.0 and rotor.axis.reboots == 3


def test_can_overspeed_disarms_with_velocity_limit_violation():
    rotor = Rotor(DriveConfig(torque_limit=0.5, vel_limit=5.0, enable_torque_mode_vel_limit=False))
    rotor.arm(ControlMode.TORQUE_CONTROL)
    rotor.send(codec.SetInputTorque(3, 0.1))
    rotor.run(0.2)
    assert rotor.ask(Cmd.HEARTBEAT).axis_error == ODriveError.VELOCITY_LIMIT_VIOLATION
    assert 6.0 <= rotor.vel <= 6.2  # tripped at 1.2 x vel_limit


@pytest.mark.parametrize("error", ["overspeed", "bad_config", "watchdog", "estop"])
def test_can_clear_errors_then_a_state_request_rearms_after_any_error(error):
    """As the firmware: Clear_Errors, then Set_Axis_State CLOSED_LOOP_CONTROL re-arms the axis
    once the cause has gone; while it lasts (a motor still beyond 1.2 vel_limit, a mode it
    cannot run) the axis disarms again at once with the same error."""
    config = DriveConfig(
        torque_limit=0.5, vel_limit=5.0, enable_torque_mode_vel_limit=False, watchdog_timeout=0.1
    )
    rotor = Rotor(config)
    rotor.arm(ControlMode.TORQUE_CONTROL)
    if error == "overspeed":
        rotor.send(codec.SetInputTorque(3, 0.1))
        rotor.run(0.2)
        want = ODriveError.VELOCITY_LIMIT_VIOLATION

        def cause_gone() -> None:  # the motor has slowed down (friction, a hand)
            rotor.vel = 1.0
            rotor.axis.feedback(rotor.t, rotor.pos, rotor.vel)

        mode = ControlMode.TORQUE_CONTROL, InputMode.PASSTHROUGH
    elif error == "bad_config":
        rotor.send(codec.SetControllerMode(3, ControlMode.TORQUE_CONTROL, InputMode.MIRROR))
        want, cause_gone = ODriveError.BAD_CONFIG, lambda: None
        mode = ControlMode.TORQUE_CONTROL, InputMode.MIRROR
    elif error == "watchdog":
        rotor.run(0.3)  # no command for longer than the watchdog's 0.1 s
        want, cause_gone = ODriveError.WATCHDOG_TIMER_EXPIRED, lambda: None
        mode = ControlMode.TORQUE_CONTROL, InputMode.PASSTHROUGH
    else:
        rotor.send(codec.Estop(3))
        want, cause_gone = ODriveError.ESTOP_REQUESTED, lambda: None
        mode = ControlMode.TORQUE_CONTROL, InputMode.PASSTHROUGH
    assert not rotor.axis.armed and rotor.ask(Cmd.HEARTBEAT).axis_error == want

    def rearm(input_mode: int) -> codec.Heartbeat:
        rotor.send(codec.ClearErrors(3))
        rotor.send(codec.SetControllerMode(3, mode[0], input_mode))
        rotor.send(codec.SetAxisState(3, AxisState.CLOSED_LOOP_CONTROL))
        return rotor.ask(Cmd.HEARTBEAT)

    if error in ("overspeed", "bad_config"):  # the cause still there: tripped again at once
        hb = rearm(mode[1])
        assert (hb.axis_state, hb.axis_error) == (AxisState.IDLE, want)
    cause_gone()
    hb = rearm(InputMode.PASSTHROUGH)
    assert (hb.axis_state, hb.axis_error) == (AxisState.CLOSED_LOOP_CONTROL, 0)


def test_can_torque_mode_velocity_limiter_of_the_firmware_defaults():
    rotor = Rotor(DriveConfig(torque_limit=0.5))  # firmware: 2 rev/s, limiter on
    rotor.arm(ControlMode.TORQUE_CONTROL)
    rotor.send(codec.SetInputTorque(3, 0.05))
    rotor.run(1.0)
    assert 1.9 < rotor.vel < 2.0 and rotor.axis.armed


def test_can_drive_pair_counts_what_is_not_for_it():
    pair = VirtualDrivePair(1, 0, 0.5)
    pair.receive(0.0, codec.encode(codec.SetInputTorque(5, 0.1)))
    pair.receive(0.0, Frame(0x12345, b"", is_extended=True))
    pair.receive(0.0, codec.encode(codec.Heartbeat(1, 0, AxisState.IDLE)))  # another drive 1
    pair.receive(0.0, Frame(0x02A, bytes(8)))  # cmd 0x0A does not exist in 0.6
    assert dict(pair.ignored) == {"other_node": 1, "extended_id": 1}
    assert pair.rejections.snapshot() == {"unknown_cmd": 1, "wrong_direction": 1}


def test_can_echo_filter_recognizes_own_frames_once_and_forgets_them():
    echo = EchoFilter(window_ns=1000)
    f = Frame(0x021, bytes(8))
    echo.sent(f, 0)
    echo.sent(f, 10)
    assert echo.take(f, 20) and echo.take(f, 20) and not echo.take(f, 20)
    echo.sent(f, 100)
    assert not echo.take(f, 2000)  # too old: someone else's identical frame
    assert not echo.take(Frame(0x029, bytes(8)), 2000)
