"""The virtual ODrive (plant_emulator.odrive) as a pure model: each CANSimple 0.6 message has its
documented effect or a counted refusal the host can see (docs/can.md lists them)."""

from __future__ import annotations

import math
import uuid
from fractions import Fraction
from pathlib import Path

import can
import pytest

from hil.bench.defaults import PAPER_TRACKING_TOML
from hil.bench.drives import DrivesOptions, drives_settings
from hil.bench.settings import scenario_settings
from hil.scenario import loads_scenario
from plant_emulator.can_drives import EchoFilter
from plant_emulator.drive_plant import (
    DrivePlant,
    bench_drive_config,
    bench_drive_settings,
    run_drive_config,
)
from plant_emulator.drives import DrivesRunner
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
from protocol.can.wheel_mapping import RobotGeometry, motor_torque_limit, wheel_rates
from protocol.robot import Limits

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


# --- as an ODrive ships, and as the bench configures it (docs/can.md, "Defaults") ---------------

REPO = Path(__file__).resolve().parents[1]
PAPER = Limits()  # the paper's phi1, phi2, varpi1, varpi2
VEL_GAIN = 1.0 / 6.0  # Nm/(rev/s): the firmware's vel_gain, the slope of its torque-mode ramp
OVERSPEED = (AxisState.IDLE, ODriveError.VELOCITY_LIMIT_VIOLATION)  # a heartbeat's (state, error)


def _defaults_table() -> dict[str, tuple[str, str]]:
    """docs/can.md's defaults table: setting -> (firmware default, what the bench sets)."""
    text = (REPO / "docs" / "can.md").read_text()
    table = text[text.index("### Defaults") : text.index("**Why these three.**")]
    rows = {}
    for line in table.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) == 7 and cells[0].startswith("`"):
            rows[cells[0].strip("`")] = (cells[2], cells[5])
    return rows


def _number(text: str) -> float | bool:
    word = text.split()[0]
    if word in ("true", "false"):
        return word == "true"
    return math.inf if word == "inf" else float(Fraction(word))


def _vel_limit_of(geom: RobotGeometry, limits: Limits) -> float:
    """docs/can.md's rule for the bench's vel_limit: the motor speed at the corner of (2),
    |v| = phi1 with |omega| = phi2, plus torque_limit / vel_gain."""
    corner = max(abs(w) for w in wheel_rates(geom, limits.phi1, limits.phi2))
    torque_limit = motor_torque_limit(geom, limits.varpi1, limits.varpi2) * (1.0 + 1e-6)
    return corner + torque_limit / VEL_GAIN


def test_can_drive_defaults_are_the_firmware_s_and_docs_can_md_says_which():
    """Every default of a virtual drive is the firmware's value that docs/can.md's table gives
    with its source line (fw-v0.5.6), and the bench's values there are what it sets."""
    rows = _defaults_table()
    assert len(rows) == 20, sorted(rows)
    fw = DriveConfig()
    for name, (firmware, _) in rows.items():
        assert getattr(fw, name) == pytest.approx(_number(firmware)), name
    # the values the ODrive firmware ships (controller.hpp, motor.hpp), known answers
    assert (fw.vel_limit, fw.vel_limit_tolerance, fw.torque_constant, fw.current_limit) == (
        2.0,
        1.2,
        0.04,
        10.0,
    )
    assert fw.enable_torque_mode_vel_limit and fw.enable_overspeed_error and fw.enable_vel_limit
    assert fw.torque_limit == math.inf and fw.max_torque == pytest.approx(0.4)  # 10 A x kt
    # what the bench sets on hil run's default robot, as the table's column says
    settings = scenario_settings(loads_scenario(PAPER_TRACKING_TOML))
    bench = settings.drives
    assert set(bench) == {"vel_limit", "torque_limit", "current_limit"}
    for name, value in bench.items():
        assert value == pytest.approx(_number(rows[name][1]), rel=1e-3), name
    assert bench["vel_limit"] == pytest.approx(_vel_limit_of(RobotGeometry(), PAPER), rel=1e-12)
    # the plant builds its drives from the run's settings: an edit there is what runs
    config = run_drive_config(settings)
    assert (config.vel_limit, config.max_torque) == (bench["vel_limit"], bench["torque_limit"])
    settings.drives = {**bench, "vel_limit": 50.0}
    assert run_drive_config(settings).vel_limit == 50.0
    with pytest.raises(ValueError, match="not a drive setting"):
        bench_drive_config({"vel_limt": 50.0})
    with pytest.raises(ValueError, match="finite number"):
        bench_drive_config({"vel_limit": -1.0})


class PairOnRotors:
    """A VirtualDrivePair as built without a configuration, each axis on a bare rotor (J), with
    an outside torque on the rotors."""

    def __init__(self) -> None:
        self.pair = VirtualDrivePair(1, 0)
        self.t = 0.0
        self.motion = {n: (0.0, 0.0) for n in (0, 1)}
        self.outside = 0.0  # Nm on each rotor, from outside the drive

    def send(self, msg) -> list:
        return [codec.decode(f) for f in self.pair.receive(self.t, codec.encode(msg))]

    def run(self, seconds: float, dt: float = 1e-3) -> list[tuple[float, float]]:
        """Step; returns the right axis' (velocity, torque) at each step."""
        seen = []
        for _ in range(round(seconds / dt)):
            self.pair.update(self.t, self.motion)
            for n, d in self.pair.drives.items():
                pos, vel = self.motion[n]
                acc = (d.torque + self.outside) / J
                self.motion[n] = (pos + vel * dt + 0.5 * acc * dt * dt, vel + acc * dt)
            self.t += dt
            seen.append((self.pair.right.vel, self.pair.right.torque))
        return seen


def test_can_a_drive_pair_without_configuration_ships_as_an_odrive():
    """VirtualDrivePair(1, 0) is a new ODrive: 2 rev/s, its torque-mode velocity limit and its
    overspeed error. A held torque cannot drive a wheel past vel_limit; an outside torque
    beyond what the drive can brake pushes it on, and past 1.2 vel_limit the drive disarms with
    VELOCITY_LIMIT_VIOLATION, on the heartbeat and in Get_Error, until Clear_Errors."""
    rig = PairOnRotors()
    for n in (0, 1):
        rig.send(codec.SetControllerMode(n, ControlMode.TORQUE_CONTROL, InputMode.PASSTHROUGH))
        rig.send(codec.SetAxisState(n, AxisState.CLOSED_LOOP_CONTROL))
        rig.send(codec.SetInputTorque(n, 0.3))
    held = rig.run(2.0)
    assert max(v for v, _ in held) <= 2.0  # firmware vel_limit, reached within 1 % ...
    assert held[-1][0] > 0.99 * 2.0 and rig.pair.right.armed  # ... and held, no overspeed
    assert held[-1][1] == pytest.approx(0.0, abs=0.01)  # the ramp left no torque at the limit
    # Nm: more than the drive brakes with up to 1.2 vel_limit, (0.2 x 2 rev/s) x vel_gain
    rig.outside = 0.1
    pushed = rig.run(1.0)
    beyond = [(v, q) for v, q in pushed if 2.0 < v <= 2.4 and q != 0.0]
    # it brakes along the firmware's ramp: (vel_limit - vel) x vel_gain < 0
    assert beyond and all(q < 0 and q == pytest.approx((2.0 - v) * VEL_GAIN) for v, q in beyond)
    trip = next(i for i, (_, q) in enumerate(pushed) if q == 0.0 and pushed[i - 1][1] != 0.0)
    assert pushed[trip - 1][0] <= 1.2 * 2.0 < pushed[trip][0]  # tripped at 1.2 x vel_limit
    hb = rig.send(Request(1, Cmd.HEARTBEAT))[0]
    assert (hb.axis_state, hb.axis_error) == OVERSPEED
    err = rig.send(Request(1, Cmd.GET_ERROR))[0]
    assert (err.active_errors, err.disarm_reason) == (ODriveError.VELOCITY_LIMIT_VIOLATION,) * 2
    rig.send(codec.ClearErrors(1))
    assert rig.send(Request(1, Cmd.GET_ERROR))[0] == codec.ErrorStatus(1, 0, 0)
    rig.send(codec.SetAxisState(1, AxisState.CLOSED_LOOP_CONTROL))  # still too fast: again
    hb = rig.send(Request(1, Cmd.HEARTBEAT))[0]
    assert (hb.axis_state, hb.axis_error) == OVERSPEED


class BenchDrives:
    """``hil drives``' plant and drives (the bench's configuration, the scenario's robot),
    stepped at 1 kHz on explicit times, no thread: a host's frames land on the edge's callback
    (the plant runs up to them first), as they do from the bus."""

    def __init__(self, scenario: Path | None = None) -> None:

        opts = DrivesOptions(scenario=None if scenario is None else str(scenario))
        self.bus = can.Bus(interface="virtual", channel=f"t{uuid.uuid4().hex}")
        self.runner = DrivesRunner(opts, drives_settings(opts), bus=self.bus)
        self.k = 0

    @property
    def now_ns(self) -> int:
        return self.runner.t0_ns + self.k * 1_000_000

    def send(self, msg) -> list:
        answers = self.runner.can.on_frame(self.now_ns, codec.encode(msg))
        return [codec.decode(f) for f in answers]

    def arm(self) -> None:
        for n in (0, 1):
            self.send(codec.ClearErrors(n))
            self.send(codec.SetControllerMode(n, ControlMode.TORQUE_CONTROL, InputMode.PASSTHROUGH))
            self.send(codec.SetAxisState(n, AxisState.CLOSED_LOOP_CONTROL))

    def hold(self, torque: float, seconds: float) -> list[tuple[float, float, float, bool]]:
        """A host's loop at 50 Hz (it feeds the watchdog); each step's right motor (velocity,
        torque), the robot's v and whether the right drive is armed."""
        seen = []
        for _ in range(round(seconds * 1000)):
            if self.k % 20 == 0:
                for n in (0, 1):
                    self.send(codec.SetInputTorque(n, torque))
            self.k += 1
            self.runner.step(self.now_ns)
            d = self.runner.pair.right
            seen.append((d.vel, d.torque, float(self.runner.core.state.v), d.armed))
        return seen

    def close(self) -> None:
        self.runner.close()


def test_can_a_held_torque_cannot_drive_the_bench_s_robot_past_vel_limit():
    """The coasting case: a clamped torque held on both drives of ``hil drives``'
    robot. The drives' torque-mode velocity limit (the firmware's, with the bench's vel_limit:
    the corner of (2) plus the ramp, 85.80 rev/s) holds each wheel at vel_limit, 2.70 m/s
    straight ahead: before, the limiter was off and the robot ran on to 3.3 m/s."""
    vel_limit = _vel_limit_of(RobotGeometry(), PAPER)
    assert vel_limit == pytest.approx(85.80, abs=0.005)
    rig = BenchDrives()
    try:
        rig.arm()
        seen = rig.hold(1.0, 3.0)  # 1 Nm: clamped to the 0.401 Nm torque limit
    finally:
        rig.close()
    k = 2 * math.pi * RobotGeometry().wheel_radius / RobotGeometry().gear_ratio  # m per rev
    assert max(v for v, *_ in seen) <= vel_limit * (1 + 1e-9)
    assert max(v for _, _, v, _ in seen) <= vel_limit * k * (1 + 1e-9)  # 2.70 m/s
    assert seen[-1][0] > 0.995 * vel_limit  # it got there: the limit held it, not the time
    assert all(armed for *_, armed in seen)  # a torque alone never trips the overspeed error
    assert rig.runner.pair.events["overspeed"] == 0


def test_can_an_outside_force_past_the_bench_s_vel_limit_trips_the_overspeed_error(tmp_path):
    """A constant disturbance d1 = 5 m/s^2, more than varpi1 = 3.3 m/s^2 the drives can brake
    with: armed, commanded zero torque, the wheels are pushed to vel_limit (no torque before
    it), beyond it the drives brake with their full torque, and at 1.2 vel_limit they disarm with
    VELOCITY_LIMIT_VIOLATION (heartbeat and Get_Error), as the firmware's controller does;
    Clear_Errors clears it, and re-arming while the wheel is still that fast trips again."""

    scenario = tmp_path / "pushed.toml"
    scenario.write_text(
        PAPER_TRACKING_TOML + '\n[disturbance]\nkind = "constant"\ns1 = 5.0\nvalue1 = 5.0\n'
    )
    vel_limit = _vel_limit_of(RobotGeometry(), PAPER)
    tlim = motor_torque_limit(RobotGeometry(), PAPER.varpi1, PAPER.varpi2)
    rig = BenchDrives(scenario)
    try:
        rig.arm()
        seen = rig.hold(0.0, 1.5)
        trip = next(i for i, s in enumerate(seen) if not s[3])
        assert seen[trip - 1][0] <= 1.2 * vel_limit < seen[trip][0]  # at 1.2 x vel_limit
        assert all(q == 0.0 for v, q, _, _ in seen[:trip] if v < vel_limit)
        braking = [q for v, q, _, _ in seen[:trip] if v > vel_limit + tlim / VEL_GAIN]
        assert braking and all(q == pytest.approx(-tlim, rel=1e-5) for q in braking)
        hb = rig.send(Request(1, Cmd.HEARTBEAT))[0]
        assert (hb.axis_state, hb.axis_error) == (
            AxisState.IDLE,
            ODriveError.VELOCITY_LIMIT_VIOLATION,
        )
        err = rig.send(Request(1, Cmd.GET_ERROR))[0]
        assert (err.active_errors, err.disarm_reason) == (ODriveError.VELOCITY_LIMIT_VIOLATION,) * 2
        rig.send(codec.ClearErrors(1))
        assert rig.send(Request(1, Cmd.GET_ERROR))[0] == codec.ErrorStatus(1, 0, 0)
        rig.send(codec.SetAxisState(1, AxisState.CLOSED_LOOP_CONTROL))
        hb = rig.send(Request(1, Cmd.HEARTBEAT))[0]
        assert (hb.axis_state, hb.axis_error) == (
            AxisState.IDLE,
            ODriveError.VELOCITY_LIMIT_VIOLATION,
        )
        assert rig.runner.pair.events["overspeed"] == 3  # both drives, then the right again
    finally:
        rig.close()
