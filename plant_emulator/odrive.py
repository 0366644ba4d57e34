"""Virtual ODrives (firmware 0.6, CANSimple) as a pure model: frames in, frames out, state.

One :class:`ODriveAxis` per CAN node, :class:`VirtualDrivePair` for the robot's two wheels.
Time is explicit (seconds, any monotonic origin); nothing here does I/O. The plant feeds each
axis its motor's position and velocity (:meth:`ODriveAxis.update`), the axis runs the
firmware's controller (:meth:`ODriveAxis._control`) and the plant applies
:attr:`ODriveAxis.torque`. docs/can.md lists every message's effect, the firmware pages and
sources each behaviour follows, and what was chosen where the firmware is not documented.

Controller (as in the firmware's ``Controller::update``, controller.cpp:143-451 at fw-v0.5.6):
input mode -> setpoints (passthrough, velocity ramp, torque ramp, 2nd-order position filter,
trapezoidal trajectory); position loop ``vel_des = vel_setpoint + pos_gain (pos_setpoint - pos)``;
velocity loop ``torque = torque_setpoint + vel_gain (vel_des - vel) + integrator``; limits:
velocity setpoints to ``vel_limit``, torque to ``min(torque_limit, current_limit *
torque_constant)``; in torque control the torque is kept within ``[(-vel_limit - vel),
(vel_limit - vel)] x vel_gain`` (``limitVel``, controller.cpp:137-141, 387-394: it tapers to 0 at
vel_limit and brakes beyond it); ``|vel| > vel_limit_tolerance x vel_limit`` in any mode is the
overspeed error (controller.cpp:331-341), which disarms the axis (main.cpp:413-420, 443-444;
axis.cpp:343-350, 594-596) with VELOCITY_LIMIT_VIOLATION until Clear_Errors and a new state
request; the integrator decays while the torque is limited. Every default is the firmware's
(:class:`DriveConfig`, cited line by line).

Every frame is either applied, answered, or counted: ``rejections`` (frames or commands refused,
by reason), ``ignored`` (frames for other nodes), ``events`` (what happened: watchdog expiries,
estops, clamped torques, ...). Nothing raises, and no torque beyond the limit is ever applied.
"""

from __future__ import annotations

import copy
import math
from collections import Counter
from dataclasses import dataclass, field

from protocol.can import codec
from protocol.can.codec import (
    Address,
    AxisState,
    BusVoltageCurrent,
    CanDecodeError,
    ClearErrors,
    Cmd,
    ControlMode,
    EncoderEstimates,
    EnterDfuMode,
    ErrorStatus,
    Estop,
    Frame,
    Heartbeat,
    InputMode,
    Iq,
    ODriveError,
    Powers,
    ProcedureResult,
    Reboot,
    Request,
    RxSdo,
    SetAbsolutePosition,
    SetAxisState,
    SetControllerMode,
    SetInputPos,
    SetInputTorque,
    SetInputVel,
    SetLimits,
    SetPosGain,
    SetTrajAccelLimits,
    SetTrajInertia,
    SetTrajVelLimit,
    SetVelGains,
    Temperature,
    Torques,
    Version,
)
from protocol.rejections import RejectionCounter

CALIBRATION_STATES = frozenset(
    {
        AxisState.STARTUP_SEQUENCE,
        AxisState.FULL_CALIBRATION_SEQUENCE,
        AxisState.MOTOR_CALIBRATION,
        AxisState.ENCODER_INDEX_SEARCH,
        AxisState.ENCODER_OFFSET_CALIBRATION,
        AxisState.ENCODER_DIR_FIND,
        AxisState.ENCODER_HALL_POLARITY_CALIBRATION,
        AxisState.ENCODER_HALL_PHASE_CALIBRATION,
    }
)
UNSUPPORTED_STATES = frozenset(
    {AxisState.SENSORLESS_CONTROL, AxisState.LOCKIN_SPIN, AxisState.ANTICOGGING_CALIBRATION}
)
SUPPORTED_INPUT_MODES = frozenset(
    {
        InputMode.INACTIVE,
        InputMode.PASSTHROUGH,
        InputMode.VEL_RAMP,
        InputMode.POS_FILTER,
        InputMode.TRAP_TRAJ,
        InputMode.TORQUE_RAMP,
        InputMode.TUNING,
    }
)
# The messages an axis can send cyclically, and their <axis>.config.can.*_msg_rate_ms names.
CYCLIC = {
    Cmd.HEARTBEAT: "heartbeat",
    Cmd.GET_ENCODER_ESTIMATES: "encoder",
    Cmd.GET_ERROR: "error",
    Cmd.GET_IQ: "iq",
    Cmd.GET_TEMPERATURE: "temperature",
    Cmd.GET_BUS_VOLTAGE_CURRENT: "bus_voltage",
    Cmd.GET_TORQUES: "torques",
    Cmd.GET_POWERS: "powers",
}
INTEGRATOR_DECAY_PER_S = 0.99**8000  # the firmware's 0.99 per 125 us step while limited
_SLACK = 1e-9  # a tick that lands a rounding error early is on time
CATCH_UP = 5  # cyclic frames missed by a stall of up to 5 periods are still sent


# Where each default comes from: the last open firmware source, tag fw-v0.5.6 (commit a308314e of
# odriverobotics/ODrive; 0.6's source is closed, its API reference keeps these names):
# C = Firmware/MotorControl/controller.hpp, M = motor.hpp, A = axis.hpp, T = trapTraj.hpp, with
# the line. docs/can.md has the same table, with what the bench sets and why.


@dataclass
class DriveConfig:
    """One axis' configuration, as an ODrive ships (docs/can.md, "Defaults"); the bench sets a
    few to suit its robot, as a user does with odrivetool (drive_plant.bench_drive_settings)."""

    torque_limit: float = math.inf  # Nm, motor.config.torque_lim (M:30; 0.6: torque_soft_max)
    torque_constant: float = 0.04  # Nm/A (M:24): Iq = torque / torque_constant
    current_limit: float = 10.0  # A, motor.config.current_lim (M:28; 0.6: current_soft_max)
    vel_limit: float = 2.0  # rev/s (C:31)
    vel_limit_tolerance: float = 1.2  # overspeed error beyond this x vel_limit (C:32)
    enable_vel_limit: bool = True  # (C:45)
    enable_overspeed_error: bool = True  # (C:46)
    enable_torque_mode_vel_limit: bool = True  # (C:47)
    pos_gain: float = 20.0  # (rev/s)/rev (C:27)
    vel_gain: float = 1.0 / 6.0  # Nm/(rev/s) (C:28)
    vel_integrator_gain: float = 2.0 / 6.0  # Nm/rev (C:30)
    vel_integrator_limit: float = math.inf  # Nm (C:33)
    vel_ramp_rate: float = 1.0  # (rev/s)/s (C:34)
    torque_ramp_rate: float = 0.01  # Nm/s (C:35)
    inertia: float = 0.0  # Nm/(rev/s^2) (C:39)
    input_filter_bandwidth: float = 2.0  # 1/s (C:40)
    traj_vel_limit: float = 2.0  # rev/s (T:7)
    traj_accel_limit: float = 0.5  # rev/s^2 (T:8)
    traj_decel_limit: float = 0.5  # rev/s^2 (T:9)
    watchdog_timeout: float = 0.0  # s; 0: off (A:86-87, enable_watchdog = False)
    msg_rates_ms: dict[int, float] = field(  # heartbeat_rate_ms, encoder_rate_ms (A:57-58)
        default_factory=lambda: {Cmd.HEARTBEAT: 100.0, Cmd.GET_ENCODER_ESTIMATES: 10.0}
    )
    # The bench's own (a virtual motor and supply; no firmware default applies):
    vbus_voltage: float = 24.0  # V, an ideal supply
    phase_resistance: float = 0.05  # ohm (copper losses 1.5 R Iq^2; firmware: measured)
    fet_temperature: float = 25.0  # deg C: no thermal model, ambient
    motor_temperature: float = 25.0
    hw_version: tuple[int, int, int] = (4, 4, 58)  # major, minor, variant
    fw_version: tuple[int, int, int] = (0, 6, 10)  # the protocol version implemented
    fw_unreleased: int = 1  # 1: not an official ODrive firmware (it is a model)
    serial_number: int = 0  # 0: derived from the node id

    @property
    def max_torque(self) -> float:
        """The torque limit in force: min(torque_limit, current_limit * torque_constant)."""
        return max(0.0, min(self.torque_limit, self.current_limit * self.torque_constant))


@dataclass
class Trajectory:
    """A trapezoidal move from xi (speed vi) to xf (the firmware's TrapezoidalTrajectory)."""

    xi: float
    xf: float
    vi: float
    ar: float = 0.0
    vr: float = 0.0
    dr: float = 0.0
    ta: float = 0.0
    tv: float = 0.0
    td: float = 0.0
    y_accel: float = 0.0

    @classmethod
    def plan(
        cls, xf: float, xi: float, vi: float, vmax: float, amax: float, dmax: float
    ) -> Trajectory:
        tr = cls(xi, xf, vi)
        amax, dmax, vmax = max(amax, 1e-9), max(dmax, 1e-9), max(vmax, 1e-9)
        dx = xf - xi
        dx_stop = math.copysign(vi * vi / (2.0 * dmax), vi)
        s = 1.0 if dx - dx_stop >= 0.0 else -1.0
        ar, dr, vr = s * amax, -s * dmax, s * vmax
        if s * vi > s * vr:  # faster than allowed: slow down first
            ar = -s * amax
        ta = (vr - vi) / ar
        td = -vr / dr
        dx_min = 0.5 * ta * (vr + vi) + 0.5 * td * vr
        if s * dx < s * dx_min:  # no cruise: a triangle
            vr = s * math.sqrt(max(0.0, (dr * vi * vi + 2.0 * ar * dr * dx) / (dr - ar)))
            ta = max(0.0, (vr - vi) / ar)
            td = max(0.0, -vr / dr)
            tv = 0.0
        else:
            tv = (dx - dx_min) / vr
        tr.ar, tr.vr, tr.dr, tr.ta, tr.tv, tr.td = ar, vr, dr, ta, tv, td
        tr.y_accel = xi + vi * ta + 0.5 * ar * ta * ta
        return tr

    @property
    def duration(self) -> float:
        return self.ta + self.tv + self.td

    def at(self, t: float) -> tuple[float, float, float]:
        """(position, velocity, acceleration) at ``t`` seconds into the move."""
        if t < 0.0:
            return self.xi, self.vi, 0.0
        if t < self.ta:
            return self.xi + self.vi * t + 0.5 * self.ar * t * t, self.vi + self.ar * t, self.ar
        if t < self.ta + self.tv:
            return self.y_accel + self.vr * (t - self.ta), self.vr, 0.0
        if t < self.duration:
            td = t - self.duration
            return self.xf + 0.5 * self.dr * td * td, self.dr * td, self.dr
        return self.xf, 0.0, 0.0


# Messages that set a limit, gain or inertia (ODriveAxis._setting): refused when negative.
SETTING_MESSAGES = (
    SetLimits,
    SetTrajVelLimit,
    SetTrajAccelLimits,
    SetTrajInertia,
    SetPosGain,
    SetVelGains,
)


def _clamp(x: float, lo: float, hi: float) -> float:
    return lo if x < lo else (hi if x > hi else x)


class ODriveAxis:
    """One axis of an ODrive (firmware 0.6) on CANSimple node ``node``."""

    def __init__(
        self,
        node: int,
        config: DriveConfig | None = None,
        rejections: RejectionCounter | None = None,
        events: Counter | None = None,
    ) -> None:
        codec.frame_id(node, 0)  # validates the node id
        self.node = node
        # What erase_configuration restores: the configuration the axis was built with (the
        # bench's), not the firmware's defaults as on a real ODrive, so that no client can lift
        # the bench's torque limit (docs/can.md, Reboot); saved, and in force at every boot.
        self.factory = copy.deepcopy(config or DriveConfig())
        self.saved = copy.deepcopy(self.factory)
        self.config = copy.deepcopy(self.factory)
        self.rejections = rejections if rejections is not None else RejectionCounter()
        self.events = events if events is not None else Counter()
        self.serial = self.config.serial_number or (0x3A5E00000000 + node)
        # feedback from the plant: motor position (rev, before the offset) and velocity
        self.t_fb = 0.0
        self.pos_motor = 0.0
        self.vel = 0.0
        self.t_control: float | None = None
        # What happened, when (drives' clock, s): (time, event, detail), drained into the
        # plant's hop log (protocol.hoplog.DriveEventRow) so that a device's reaction to a
        # disarm can be timed. ``_now``: the time of the step or frame being handled.
        self.log: list[tuple[float, str, int]] = []
        self._now = 0.0
        self._inputs_refused = False  # an input refused since the last disarm was logged
        self._boot()
        self.identify = 0
        self.reboots = 0

    def _boot(self) -> None:
        self.axis_state = AxisState.IDLE
        self.procedure_result = ProcedureResult.SUCCESS
        self.active_errors = 0
        self.disarm_reason = 0
        self.control_mode = ControlMode.POSITION_CONTROL
        self.input_mode = InputMode.PASSTHROUGH
        self.pos_offset = -self.pos_motor  # an incremental encoder reads 0 at boot
        self._zero_inputs()
        self.last_feed: float | None = None

    def _zero_inputs(self, now: float | None = None) -> None:
        self.input_pos = self.pos_estimate_at(self.t_fb if now is None else now)
        self.input_vel = 0.0
        self.input_torque = 0.0
        self.input_pos_updated = False
        self.pos_setpoint = self.input_pos
        self.vel_setpoint = 0.0
        self.torque_setpoint = 0.0
        self.vel_integrator = 0.0
        self.torque_output = 0.0
        self.trajectory: Trajectory | None = None
        self.traj_t0 = 0.0
        self.trajectory_done = True

    # --- state ---------------------------------------------------------------------------
    @property
    def armed(self) -> bool:
        return self.axis_state == AxisState.CLOSED_LOOP_CONTROL

    @property
    def axis_error(self) -> int:
        """Heartbeat's Axis_Error: active_errors | disarm_reason."""
        return self.active_errors | self.disarm_reason

    @property
    def torque(self) -> float:
        """The torque the motor applies now (Nm): 0 unless in closed loop."""
        return self.torque_output if self.armed else 0.0

    @property
    def iq(self) -> float:
        return self.torque / self.config.torque_constant

    @property
    def mechanical_power(self) -> float:
        return self.torque * self.vel * 2.0 * math.pi

    @property
    def electrical_power(self) -> float:
        return self.mechanical_power + 1.5 * self.config.phase_resistance * self.iq**2

    def pos_estimate_at(self, now: float) -> float:
        """Pos_Estimate at ``now``: the last feedback, extrapolated at its velocity."""
        return self.pos_motor + self.vel * max(0.0, now - self.t_fb) + self.pos_offset

    def supported_config(self) -> bool:
        return (
            self.control_mode != ControlMode.VOLTAGE_CONTROL
            and self.input_mode in SUPPORTED_INPUT_MODES
        )

    # --- the plant's side ------------------------------------------------------------------
    def feedback(self, now: float, pos_motor: float, vel: float) -> None:
        """The motor's position (rev) and velocity (rev/s) at ``now``."""
        if math.isfinite(pos_motor) and math.isfinite(vel):
            self.t_fb, self.pos_motor, self.vel = now, pos_motor, vel
        else:
            self.rejections.count("non_finite_feedback")

    def update(self, now: float, pos_motor: float, vel: float) -> None:
        """Feedback at ``now``, then one controller step (watchdog, limits, loops)."""
        self._now = now
        self.feedback(now, pos_motor, vel)
        dt = 0.0 if self.t_control is None else max(0.0, now - self.t_control)
        self.t_control = now
        if self.armed:
            timeout = self.config.watchdog_timeout
            if timeout > 0.0 and self.last_feed is not None and now - self.last_feed > timeout:
                self.disarm(ODriveError.WATCHDOG_TIMER_EXPIRED, "watchdog_expired")
                return
        self._control(now, dt)

    def disarm(self, error: int, event: str, now: float | None = None) -> None:
        """Leave closed loop with ``error`` latched (active and as the disarm reason)."""
        if now is not None:
            self._now = now
        self.active_errors |= int(error)
        self.disarm_reason |= int(error)
        was_armed = self.armed
        self.axis_state = AxisState.IDLE
        self.events[event] += 1
        if was_armed:
            self.log.append((self._now, "disarmed", int(error)))
            self._inputs_refused = False
        self._zero_inputs()

    def _arm(self, now: float) -> None:
        self.axis_state = AxisState.CLOSED_LOOP_CONTROL
        self.procedure_result = ProcedureResult.SUCCESS
        self._zero_inputs(now)  # start at rest where the motor is: no stale set point acts
        self.last_feed = now
        self.t_control = now
        self.events["armed"] += 1
        self.log.append((now, "armed", 0))

    def _control(self, now: float, dt: float) -> None:
        """One step of the firmware's controller over ``dt`` seconds (0: outputs only)."""
        if not self.armed:
            self.torque_output = 0.0
            self.vel_integrator = 0.0
            return
        if not self.supported_config():
            self.disarm(ODriveError.BAD_CONFIG, "bad_config")
            return
        self._follow_input(now, dt)
        self._run_loops(now, dt)

    def _follow_input(self, now: float, dt: float) -> None:
        """The set points from the inputs through the input mode's filter over ``dt``."""
        cfg = self.config
        mode = self.input_mode
        if mode in (InputMode.PASSTHROUGH, InputMode.TUNING):
            self.pos_setpoint = self.input_pos
            self.vel_setpoint = self.input_vel
            self.torque_setpoint = self.input_torque
        elif mode == InputMode.VEL_RAMP and dt > 0.0:
            max_step = abs(dt * cfg.vel_ramp_rate)
            step = _clamp(self.input_vel - self.vel_setpoint, -max_step, max_step)
            self.vel_setpoint += step
            self.torque_setpoint = (step / dt) * cfg.inertia
        elif mode == InputMode.TORQUE_RAMP and dt > 0.0:
            max_step = abs(dt * cfg.torque_ramp_rate)
            step = _clamp(self.input_torque - self.torque_setpoint, -max_step, max_step)
            self.torque_setpoint += step
        elif mode == InputMode.POS_FILTER and dt > 0.0:
            bandwidth = min(cfg.input_filter_bandwidth, 0.25 / dt)
            ki = 2.0 * bandwidth
            kp = 0.25 * ki * ki
            accel = kp * (self.input_pos - self.pos_setpoint) + ki * (
                self.input_vel - self.vel_setpoint
            )
            self.torque_setpoint = accel * cfg.inertia
            self.vel_setpoint += dt * accel
            self.pos_setpoint += dt * self.vel_setpoint
        elif mode == InputMode.TRAP_TRAJ:
            self._follow_trajectory(now)

    def _follow_trajectory(self, now: float) -> None:
        """TRAP_TRAJ: plan a move on a new input position, then follow it."""
        cfg = self.config
        if self.input_pos_updated:
            self.trajectory = Trajectory.plan(
                self.input_pos,
                self.pos_setpoint,
                self.vel_setpoint,
                cfg.traj_vel_limit,
                cfg.traj_accel_limit,
                cfg.traj_decel_limit,
            )
            self.traj_t0 = now
            self.trajectory_done = False
            self.input_pos_updated = False
        if not self.trajectory_done and self.trajectory is not None:
            t = now - self.traj_t0
            if t > self.trajectory.duration:
                self.pos_setpoint, self.vel_setpoint = self.trajectory.xf, 0.0
                self.torque_setpoint = 0.0
                self.trajectory_done = True
            else:
                y, yd, ydd = self.trajectory.at(t)
                self.pos_setpoint, self.vel_setpoint = y, yd
                self.torque_setpoint = ydd * cfg.inertia

    def _run_loops(self, now: float, dt: float) -> None:
        """Limits, the position and velocity loops and the integrator: the output torque."""
        cfg = self.config
        tlim = cfg.max_torque
        vlim = cfg.vel_limit
        if cfg.enable_vel_limit:
            self.vel_setpoint = _clamp(self.vel_setpoint, -vlim, vlim)
        self.torque_setpoint = _clamp(self.torque_setpoint, -tlim, tlim)
        vel_des = self.vel_setpoint
        if self.control_mode >= ControlMode.POSITION_CONTROL:
            vel_des += cfg.pos_gain * (self.pos_setpoint - self.pos_estimate_at(now))
        if cfg.enable_vel_limit:
            vel_des = _clamp(vel_des, -vlim, vlim)
        # the overspeed error, in every control mode (controller.cpp:331-341); the firmware's
        # controller fails and its axis disarms to IDLE (main.cpp:413-420, 443-444; axis.cpp:594)
        if cfg.enable_overspeed_error and abs(self.vel) > cfg.vel_limit_tolerance * vlim:
            self.disarm(ODriveError.VELOCITY_LIMIT_VIOLATION, "overspeed")
            return
        torque = self.torque_setpoint
        v_err = 0.0
        if self.control_mode >= ControlMode.VELOCITY_CONTROL:
            v_err = vel_des - self.vel
            torque += cfg.vel_gain * v_err + self.vel_integrator
        elif cfg.enable_torque_mode_vel_limit:
            # limitVel (controller.cpp:137-141, 387-394): a ramp of slope vel_gain that reaches
            # 0 at +-vel_limit and brakes beyond it, before the torque limit
            torque = _clamp(
                torque, (-vlim - self.vel) * cfg.vel_gain, (vlim - self.vel) * cfg.vel_gain
            )
        if not math.isfinite(torque):  # e.g. extreme gains times extreme set points
            self.events["non_finite_torque"] += 1
            torque, self.vel_integrator = 0.0, 0.0
        limited = abs(torque) > tlim
        torque = _clamp(torque, -tlim, tlim)
        if self.control_mode < ControlMode.VELOCITY_CONTROL:
            self.vel_integrator = 0.0
        elif dt > 0.0:
            if limited:
                self.vel_integrator *= INTEGRATOR_DECAY_PER_S**dt
            else:
                self.vel_integrator += cfg.vel_integrator_gain * dt * v_err
            lim = cfg.vel_integrator_limit
            self.vel_integrator = _clamp(self.vel_integrator, -lim, lim)
            if not math.isfinite(self.vel_integrator):
                self.vel_integrator = 0.0
        self.torque_output = torque

    # --- the bus' side -----------------------------------------------------------------------
    def receive(self, now: float, msg: codec.Message) -> tuple[list[Frame], bool]:
        """Apply one decoded message addressed to this node.

        Returns (frames to answer with, whether it fed the watchdog: every accepted
        host -> drive command does; requests and refused frames do not)."""
        self._now = now
        if isinstance(msg, Request):
            return [self.answer(now, msg.cmd)], False
        if isinstance(msg, codec.DRIVE_TO_HOST):
            # our node id in a drive -> host frame that is not our own echo: another device
            # with the same node id, or a host replaying drive frames
            self.rejections.count("wrong_direction")
            return [], False
        ok = self._command(now, msg)
        if ok:
            self.last_feed = now
        self._control(now, 0.0)  # the new inputs act at once (landing time), no time passes
        return [], ok

    def _command(self, now: float, msg: codec.Message) -> bool:
        """Apply one host -> drive command; False when refused (counted in ``rejections``)."""
        for value in vars(msg).values():  # the codec refuses them; a direct caller may not
            if isinstance(value, float) and not math.isfinite(value):
                self.rejections.count("non_finite")
                return False
        if isinstance(msg, Estop):
            self.disarm(ODriveError.ESTOP_REQUESTED, "estop")
        elif isinstance(msg, ClearErrors):
            self.active_errors = 0
            self.disarm_reason = 0
            self.identify = msg.identify
            self.events["clear_errors"] += 1
            self.log.append((now, "clear_errors", 0))
        elif isinstance(msg, SetAxisState):
            self.log.append((now, "state_request", int(msg.requested_state)))
            return self._request_state(now, msg.requested_state)
        elif isinstance(msg, SetControllerMode):
            self.control_mode = ControlMode(msg.control_mode)
            self.input_mode = InputMode(msg.input_mode)
            if self.armed and self.control_mode >= ControlMode.POSITION_CONTROL:
                self.pos_setpoint = self.input_pos = self.pos_estimate_at(now)
            if not self.supported_config():
                self.rejections.count("unsupported_mode")
        elif isinstance(msg, SetInputTorque):
            return self._inputs(now, torque=msg.torque_nm)
        elif isinstance(msg, SetInputVel):
            return self._inputs(now, vel=msg.input_vel, torque=msg.torque_ff)
        elif isinstance(msg, SetInputPos):
            return self._inputs(now, pos=msg.input_pos, vel=msg.vel_ff, torque=msg.torque_ff)
        elif isinstance(msg, SETTING_MESSAGES):
            return self._setting(msg)
        elif isinstance(msg, SetAbsolutePosition):
            self._set_absolute_position(now, msg.position)
        elif isinstance(msg, Reboot):
            return self._reboot(msg.action)
        elif isinstance(msg, EnterDfuMode):
            self.rejections.count("dfu_refused")
            return False
        elif isinstance(msg, RxSdo):
            self.rejections.count("sdo_unsupported")
            return False
        elif (
            isinstance(msg, Address)
            and msg.serial_number in (self.serial, 0)
            and msg.node_id != self.node
        ):
            self.rejections.count("node_id_change_refused")
            return False
        return True

    def _setting(self, msg: codec.Message) -> bool:
        """A limit, gain or inertia message: refused (and counted) when negative."""
        cfg = self.config
        if isinstance(msg, SetLimits):
            if msg.velocity_limit < 0.0 or msg.current_limit < 0.0:
                self.rejections.count("negative_limit")
                return False
            cfg.vel_limit, cfg.current_limit = msg.velocity_limit, msg.current_limit
        elif isinstance(msg, SetTrajVelLimit):
            if msg.traj_vel_limit < 0.0:
                self.rejections.count("negative_limit")
                return False
            cfg.traj_vel_limit = msg.traj_vel_limit
        elif isinstance(msg, SetTrajAccelLimits):
            if msg.accel_limit < 0.0 or msg.decel_limit < 0.0:
                self.rejections.count("negative_limit")
                return False
            cfg.traj_accel_limit, cfg.traj_decel_limit = msg.accel_limit, msg.decel_limit
        elif isinstance(msg, SetTrajInertia):
            if msg.inertia < 0.0:
                self.rejections.count("negative_limit")
                return False
            cfg.inertia = msg.inertia
        elif isinstance(msg, SetPosGain):
            if msg.pos_gain < 0.0:
                self.rejections.count("negative_gain")
                return False
            cfg.pos_gain = msg.pos_gain
        elif isinstance(msg, SetVelGains):
            if msg.vel_gain < 0.0 or msg.vel_integrator_gain < 0.0:
                self.rejections.count("negative_gain")
                return False
            cfg.vel_gain, cfg.vel_integrator_gain = msg.vel_gain, msg.vel_integrator_gain
        return True

    def _set_absolute_position(self, now: float, position: float) -> None:
        """Move the frame of reference so that Pos_Estimate reads ``position`` now."""
        delta = position - self.pos_estimate_at(now)
        self.pos_offset += delta
        # the set points move with the frame of reference: the motor does not jump
        self.input_pos += delta
        self.pos_setpoint += delta
        if self.trajectory is not None:
            self.trajectory.xi += delta
            self.trajectory.xf += delta
            self.trajectory.y_accel += delta
        self.events["absolute_position"] += 1

    def _inputs(
        self,
        now: float,
        pos: float | None = None,
        vel: float | None = None,
        torque: float | None = None,
    ) -> bool:
        if not self.armed:
            if any(v for v in (vel, torque)) or pos is not None:
                self.rejections.count("input_while_disarmed")  # would be stale when armed
                if not self._inputs_refused:  # the first after a disarm: the device kept on
                    self.log.append((now, "input_while_disarmed", 0))
                    self._inputs_refused = True
                return False
            return True  # a zero (a host's "no torque" before arming): nothing to ignore
        if pos is not None:
            self.input_pos = pos
            self.input_pos_updated = True
        if vel is not None:
            self.input_vel = vel
        if torque is not None:
            if abs(torque) > self.config.max_torque:
                self.events["torque_clamped"] += 1  # the firmware clamps, so does the model
            self.input_torque = torque
        return True

    def _request_state(self, now: float, state: int) -> bool:
        self.events["state_requests"] += 1  # every Set_Axis_State, granted or not
        if state == AxisState.UNDEFINED:
            return True
        if state == AxisState.IDLE:
            if self.armed:
                self.axis_state = AxisState.IDLE
                self._zero_inputs()
            return True
        if state == AxisState.CLOSED_LOOP_CONTROL:
            if self.armed:
                return True
            if self.axis_error:
                self.rejections.count("arm_with_error")
                self.procedure_result = ProcedureResult.INVALID_STATE
                return True
            if not self.supported_config():
                self.disarm(ODriveError.BAD_CONFIG, "bad_config")
                self.procedure_result = ProcedureResult.INVALID_STATE
                return True
            self._arm(now)
            return True
        if state in CALIBRATION_STATES:
            # a virtual motor is calibrated: the procedure succeeds at once, the axis idles
            self.axis_state = AxisState.IDLE
            self._zero_inputs()
            self.procedure_result = ProcedureResult.SUCCESS
            self.events["calibration"] += 1
            return True
        if state == AxisState.HOMING:
            self.axis_state = AxisState.IDLE
            self._zero_inputs()
            self.procedure_result = ProcedureResult.HOMING_WITHOUT_ENDSTOP
            self.rejections.count("homing_without_endstop")
            return True
        self.rejections.count("unsupported_state")
        self.procedure_result = ProcedureResult.INVALID_STATE
        return True

    def _reboot(self, action: int) -> bool:
        if action == 3:
            self.rejections.count("dfu_refused")
            return False
        if self.armed:
            self.rejections.count("reboot_while_armed")  # the protocol requires IDLE
            return False
        if action == 1:
            self.saved = copy.deepcopy(self.config)
        elif action == 2:
            self.saved = copy.deepcopy(self.factory)
        self.config = copy.deepcopy(self.saved)
        self._boot()
        self.t_control = None
        self.reboots += 1
        self.events["reboot"] += 1
        return True

    # --- frames --------------------------------------------------------------------------
    def heartbeat(self) -> Frame:
        return codec.encode(
            Heartbeat(
                self.node,
                self.axis_error,
                int(self.axis_state),
                int(self.procedure_result),
                self.trajectory_done,
            )
        )

    def encoder_estimates(self, now: float) -> Frame:
        return codec.encode(EncoderEstimates(self.node, self.pos_estimate_at(now), self.vel))

    def answer(self, now: float, cmd: Cmd) -> Frame:
        """The frame a request for ``cmd`` is answered with (current values)."""
        cfg = self.config
        if cmd == Cmd.HEARTBEAT:
            return self.heartbeat()
        if cmd == Cmd.GET_ENCODER_ESTIMATES:
            return self.encoder_estimates(now)
        if cmd == Cmd.GET_VERSION:
            hw, fw = cfg.hw_version, cfg.fw_version
            msg: codec.Message = Version(
                self.node, 2, hw[0], hw[1], hw[2], fw[0], fw[1], fw[2], cfg.fw_unreleased
            )
        elif cmd == Cmd.GET_ERROR:
            msg = ErrorStatus(self.node, self.active_errors, self.disarm_reason)
        elif cmd == Cmd.GET_IQ:
            msg = Iq(self.node, self.iq, self.iq)
        elif cmd == Cmd.GET_TEMPERATURE:
            msg = Temperature(self.node, cfg.fet_temperature, cfg.motor_temperature)
        elif cmd == Cmd.GET_BUS_VOLTAGE_CURRENT:
            msg = BusVoltageCurrent(
                self.node, cfg.vbus_voltage, self.electrical_power / cfg.vbus_voltage
            )
        elif cmd == Cmd.GET_TORQUES:
            msg = Torques(self.node, self.torque, self.torque)
        elif cmd == Cmd.GET_POWERS:
            msg = Powers(self.node, self.electrical_power, self.mechanical_power)
        elif cmd == Cmd.ADDRESS:
            msg = Address(self.node, self.node, self.serial)
        else:  # not requestable: the codec never makes such a Request
            raise ValueError(f"cannot answer {cmd!r}")
        return codec.encode(msg)


@dataclass
class VirtualDrivePair:
    """The robot's two drives (right and left wheel) behind one CAN bus.

    ``config`` sets both axes' configuration. Without it: the firmware's defaults (so
    ``vel_limit`` 2 rev/s, its overspeed error and its torque-mode velocity limiter, as an
    ODrive ships) with ``torque_limit`` (Nm, torque_soft_max) and ``heartbeat_period`` /
    ``encoder_period`` as cyclic rates (firmware defaults 100 ms, 10 ms; 0 turns a message
    off). The bench's configuration is :func:`plant_emulator.drive_plant.run_drive_config`.
    """

    node_right: int
    node_left: int
    torque_limit: float = math.inf
    heartbeat_period: float = 0.1
    encoder_period: float = 0.01
    config: DriveConfig | None = None
    rejections: RejectionCounter = field(default_factory=RejectionCounter)
    ignored: Counter = field(default_factory=Counter)
    events: Counter = field(default_factory=Counter)
    drives: dict[int, ODriveAxis] = field(default_factory=dict)
    last_fed: bool = False
    _next_due: dict[int, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.node_left == self.node_right:
            raise ValueError("node_left and node_right must differ")
        if self.config is None:
            self.config = DriveConfig(torque_limit=self.torque_limit)
            self.config.msg_rates_ms = {
                Cmd.HEARTBEAT: 1000.0 * self.heartbeat_period,
                Cmd.GET_ENCODER_ESTIMATES: 1000.0 * self.encoder_period,
            }
        for node in (self.node_right, self.node_left):
            self.drives[node] = ODriveAxis(node, self.config, self.rejections, self.events)
        self.nodes = frozenset(self.drives)

    @property
    def right(self) -> ODriveAxis:
        return self.drives[self.node_right]

    @property
    def left(self) -> ODriveAxis:
        return self.drives[self.node_left]

    def torques(self) -> tuple[float, float]:
        """(right, left) motor torques in force (Nm)."""
        return self.right.torque, self.left.torque

    def receive(self, now: float, frame: Frame) -> list[Frame]:
        """Take one received frame; returns the answers. ``last_fed`` tells whether it was
        an accepted command (it fed the watchdog)."""
        self.last_fed = False
        if frame.is_extended:
            self.ignored["extended_id"] += 1  # CANSimple is 11-bit: another protocol's frame
            return []
        if 0 <= frame.arbitration_id <= 0x7FF:
            node, cmd = codec.split_id(frame.arbitration_id)
            if node == codec.BROADCAST_NODE and cmd == Cmd.ADDRESS and codec.is_request(frame):
                return [d.answer(now, Cmd.ADDRESS) for d in self.drives.values()]
            if node not in self.nodes:
                self.ignore_other_node()
                return []
        try:
            msg = codec.decode(frame)
        except CanDecodeError as exc:
            self.rejections.count(exc.reason)
            return []
        answers, self.last_fed = self.drives[msg.node].receive(now, msg)
        return answers

    def answer_request(self, now: float, node: int, cmd: Cmd) -> list[Frame]:
        """The answer to a request (RTR) for requestable ``cmd`` to ``node``, one of these
        drives: what :meth:`receive` answers the request's frame with, without decoding it
        (the bus edge's table of these ids, :class:`plant_emulator.can_drives.CanDrives`)."""
        self.last_fed = False
        answers, _ = self.drives[node].receive(now, Request(node, cmd))
        return answers

    def ignore_other_node(self) -> None:
        """Count a frame of another node, as :meth:`receive` counts it (it changes nothing)."""
        self.last_fed = False
        self.ignored["other_node"] += 1

    def feedback(self, now: float, motion: dict[int, tuple[float, float]]) -> None:
        for node, (pos, vel) in motion.items():
            self.drives[node].feedback(now, pos, vel)

    def drain_log(self) -> list[tuple[int, float, str, int]]:
        """Every axis' events since the last drain: (node, time s, event, detail)."""
        out = []
        for node, d in self.drives.items():
            out += [(node, *e) for e in d.log]
            d.log.clear()
        return sorted(out, key=lambda e: e[1])

    def update(self, now: float, motion: dict[int, tuple[float, float]]) -> None:
        """Each axis' motor (position rev, velocity rev/s) at ``now`` and a controller step."""
        for node, (pos, vel) in motion.items():
            self.drives[node].update(now, pos, vel)

    def zero_inputs(self, now: float) -> None:
        """Zero every armed axis' torque and velocity inputs (the bench's command timeout)."""
        for d in self.drives.values():
            if d.armed:
                d.input_torque = 0.0
                d.input_vel = 0.0
                d._control(now, 0.0)

    def next_due(self) -> float:
        """When the next cyclic frame is due (``-inf`` before the first call of due_frames)."""
        if not self._next_due:
            return -math.inf
        return min(self._next_due.values())

    def due_frames(self, now: float) -> list[Frame]:
        """The cyclic frames due at ``now``, every axis at once. Deadlines stay on the period's
        grid: a late call sends one frame, and the next is due at once when more were missed
        (so the rate holds through a short stall); later than ``CATCH_UP`` periods the grid
        restarts from ``now``."""
        out: list[Frame] = []
        rates = self.config.msg_rates_ms if self.config else {}
        for cmd, ms in rates.items():
            if not ms or ms <= 0:
                continue
            period = ms / 1000.0
            due = self._next_due.get(cmd, -math.inf)
            if now < due - _SLACK:
                continue
            # on the grid; after a stall the missed frames go out back to back (the rate holds),
            # up to CATCH_UP periods late, beyond which the grid restarts from now
            nxt = due + period
            self._next_due[cmd] = nxt if nxt > now - CATCH_UP * period else now + period
            for d in self.drives.values():
                out.append(d.answer(now, Cmd(cmd)))
        return out

    def counters(self) -> dict[str, object]:
        """Every counter, for Status and summaries."""
        return {
            "rejections": self.rejections.snapshot(),
            "ignored": dict(sorted(self.ignored.items())),
            "events": dict(sorted(self.events.items())),
            "drives": {
                str(n): {
                    "axis_state": int(d.axis_state),
                    "axis_error": d.axis_error,
                    "active_errors": d.active_errors,
                    "disarm_reason": d.disarm_reason,
                    "procedure_result": int(d.procedure_result),
                    "control_mode": int(d.control_mode),
                    "input_mode": int(d.input_mode),
                    "torque_nm": d.torque,
                    "pos_rev": d.pos_estimate_at(d.t_fb),
                    "vel_rev_s": d.vel,
                    # the limits in force (the bench's, or what a client set with Set_Limits)
                    "vel_limit_rev_s": d.config.vel_limit,
                    "torque_limit_nm": d.config.max_torque,
                }
                for n, d in self.drives.items()
            },
        }
