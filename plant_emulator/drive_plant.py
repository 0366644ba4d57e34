"""Where the robot meets its two drives: wheel motion to the motors, motor torques to (1).

Pure (explicit time, no I/O). :class:`WheelOdometry` integrates the arc length ``S = int v dt``
of the plant's motion, so each motor's position follows from the heading theta (unwrapped,
part of the plant's state) without a new state in the dynamics:

    theta_R = (S + b (theta - theta0)) / r,   theta_L = (S - b (theta - theta0)) / r,

and a motor turns ``G theta_wheel / (2 pi)`` revolutions (:mod:`protocol.can.wheel_mapping`).
``S`` is integrated with the trapezoid rule between the plant's events (at most one control
period apart), exact while the acceleration is constant.

:func:`bench_drive_settings` is what the bench sets on its virtual drives (as a user saves it with
odrivetool), :func:`bench_drive_config` the configuration they run with.
"""

from __future__ import annotations

import math
from typing import Any

from plant_emulator.odrive import DriveConfig, VirtualDrivePair
from protocol.can.codec import Cmd
from protocol.can.wheel_mapping import (
    TWO_PI,
    RobotGeometry,
    decode_torques,
    motor_torque_limit,
    wheel_rates,
)

# A legal command's float32 on the wire may round a hair past the largest legal motor torque:
# the drives' torque limit sits this much above it, and (2) is enforced after decoding.
FLOAT32_HAIR = 1e-6


def bench_drive_settings(geometry: RobotGeometry, limits: Any) -> dict[str, float]:
    """What the bench configures on its drives from the scenario, as a user does on real ones
    to suit the robot (docs/can.md, "Defaults"); everything else stays the firmware's.

    - ``torque_limit`` (torque_soft_max): the largest motor torque the constraints (2) ask,
      :func:`motor_torque_limit` of ``[limits]`` varpi1, varpi2 and ``[robot]``, plus a float32
      hair.
    - ``current_limit`` (current_soft_max): the firmware's 10 A, raised to torque_limit /
      torque_constant when 10 A would cap that torque (0.401 Nm > 10 A x 0.04 Nm/A by default).
    - ``vel_limit``: the motor speed at the corner of (2), |v| = phi1 with |omega| = phi2
      (:func:`motor_speed_limit`: ``[limits]`` phi1, phi2 through ``[robot]`` wheel_radius,
      half_track, gear_ratio), plus the width of the firmware's torque-mode ramp,
      torque_limit / vel_gain: the smallest limit that leaves every motion within (2) its full
      torque. A wheel cannot be limited in v and omega apart, so straight ahead the robot can
      reach vel_limit's speed (2.70 m/s by default, phi1 is 1.6), never more under its own
      torque; beyond vel_limit_tolerance x vel_limit the drive trips its overspeed error."""
    fw = DriveConfig()
    legal = motor_torque_limit(geometry, limits.varpi1, limits.varpi2)
    torque_limit = legal * (1.0 + FLOAT32_HAIR)
    return {
        "torque_limit": torque_limit,
        "current_limit": max(fw.current_limit, torque_limit / fw.torque_constant),
        "vel_limit": motor_speed_limit(geometry, limits) + torque_limit / fw.vel_gain,
    }


def bench_drive_config(
    settings: dict[str, Any],
    watchdog_timeout: float = 0.0,
    msg_rates_ms: dict[int, float] | None = None,
) -> DriveConfig:
    """The drives' configuration: the firmware's defaults with ``settings`` (a run's
    ``drives``: :func:`bench_drive_settings`, or what a user put there), the ``[can]`` watchdog
    and the cyclic messages' rates. A key that is no :class:`DriveConfig` field, or a value
    that is no finite number >= 0 (a flag: a bool), raises ValueError."""
    known = {k: type(v) for k, v in vars(DriveConfig()).items() if k != "watchdog_timeout"}
    for key, value in settings.items():
        if known.get(key) not in (float, bool):
            raise ValueError(f"drives: {key!r} is not a drive setting the bench can set")
        flag = known[key] is bool
        if isinstance(value, bool) != flag or not (
            flag or (isinstance(value, int | float) and math.isfinite(value) and value >= 0.0)
        ):
            want = "true or false" if flag else "a finite number >= 0"
            raise ValueError(f"drives: {key} must be {want}, got {value!r}")
    return DriveConfig(
        **settings,
        watchdog_timeout=watchdog_timeout,
        msg_rates_ms=dict(
            msg_rates_ms
            if msg_rates_ms is not None
            else {Cmd.HEARTBEAT: 100.0, Cmd.GET_ENCODER_ESTIMATES: 10.0}
        ),
    )


class WheelOdometry:
    """Arc length travelled, integrated from the plant's speed at its events."""

    def __init__(self, t0: float, v0: float, theta0: float) -> None:
        self.t = t0
        self.v = v0
        self.theta0 = theta0
        self.s = 0.0

    def advance(self, t1: float, v1: float) -> None:
        if t1 > self.t:
            self.s += 0.5 * (self.v + v1) * (t1 - self.t)
            self.t = t1
        self.v = v1


class DrivePlant:
    """The two drives of ``pair`` on the robot of ``geometry`` (right wheel node_right).

    Two clocks: the plant's time ``t`` (the odometry integrates over it) and the drives'
    ``now`` (CLOCK_MONOTONIC seconds, the clock their frames and watchdog run on)."""

    def __init__(
        self,
        pair: VirtualDrivePair,
        geometry: RobotGeometry,
        limits: Any,
        t0: float,
        state: Any,
        now: float,
    ) -> None:
        self.pair = pair
        self.geometry = geometry
        self.limits = limits
        self.odometry = WheelOdometry(t0, float(state.v), float(state.theta))
        self.feedback(now, t0, state)

    def motion(self, t: float, state: Any) -> dict[int, tuple[float, float]]:
        """Each motor's (position rev, velocity rev/s) at plant time ``t`` in ``state``."""
        g = self.geometry
        self.odometry.advance(t, float(state.v))
        k = g.gear_ratio / (TWO_PI * g.wheel_radius)
        turn = g.half_track * (float(state.theta) - self.odometry.theta0)
        rates = wheel_rates(g, float(state.v), float(state.omega))
        return {
            self.pair.node_right: (k * (self.odometry.s + turn), rates.right),
            self.pair.node_left: (k * (self.odometry.s - turn), rates.left),
        }

    def feedback(self, now: float, t: float, state: Any) -> None:
        """The drives' feedback only (no controller step)."""
        self.pair.feedback(now, self.motion(t, state))

    def update(self, now: float, t: float, state: Any) -> None:
        """Feedback and one controller step of each drive (watchdog, loops)."""
        self.pair.update(now, self.motion(t, state))

    def torques(self) -> tuple[float, float]:
        """(tau1, tau2) of model (1) from the drives' torques, clamped to (2)."""
        q_right, q_left = self.pair.torques()
        return decode_torques(
            self.geometry, q_right, q_left, self.limits.varpi1, self.limits.varpi2
        )


def run_drive_config(settings: Any, msg_rates_ms: dict[int, float] | None = None) -> DriveConfig:
    """The drives' configuration of a run (:class:`protocol.settings.RunSettings`): its
    ``drives`` as hil resolved them (a settings file written before they were: derived here,
    the same way), its ``[can]`` watchdog."""
    geometry, limits = RobotGeometry(**settings.robot), settings.limits_value
    values = settings.drives or bench_drive_settings(geometry, limits)
    watchdog = settings.can_settings().watchdog_timeout
    return bench_drive_config(values, watchdog, msg_rates_ms)


def motor_speed_limit(geometry: RobotGeometry, limits: Any) -> float:
    """The largest motor speed (rev/s) within the constraints (2)."""
    corner = wheel_rates(geometry, limits.phi1, limits.phi2)
    return max(abs(corner.right), abs(corner.left))
