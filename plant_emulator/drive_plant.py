"""Where the robot meets its two drives: wheel motion to the motors, motor torques to (1).

Pure (explicit time, no I/O). :class:`WheelOdometry` integrates the arc length ``S = int v dt``
of the plant's motion, so each motor's position follows from the heading theta (unwrapped,
part of the plant's state) without a new state in the dynamics:

    theta_R = (S + b (theta - theta0)) / r,   theta_L = (S - b (theta - theta0)) / r,

and a motor turns ``G theta_wheel / (2 pi)`` revolutions (:mod:`protocol.can.wheel_mapping`).
``S`` is integrated with the trapezoid rule between the plant's events (at most one control
period apart), exact while the acceleration is constant.

:func:`bench_drive_config` is the configuration the bench gives its virtual drives.
"""

from __future__ import annotations

from typing import Any

from plant_emulator.odrive import DriveConfig, VirtualDrivePair
from protocol.can.codec import Cmd
from protocol.can.wheel_mapping import (
    TWO_PI,
    RobotGeometry,
    decode_torques,
    wheel_rates,
)

VEL_LIMIT_MARGIN = 2.0  # vel_limit = this x the motor speed at |v| = phi1 with |omega| = phi2


def bench_drive_config(
    geometry: RobotGeometry,
    limits: Any,
    torque_limit: float,
    watchdog_timeout: float = 0.0,
    msg_rates_ms: dict[int, float] | None = None,
) -> DriveConfig:
    """The drives' configuration on the bench (what a user would save on real drives).

    Firmware defaults, except: the torque limit is the largest motor torque (2) allows;
    ``vel_limit`` is twice the motor speed of the constraint's corner (|v| = phi1 and
    |omega| = phi2 at once; the firmware's 2 rev/s would stop the robot at 4 cm/s); torque mode
    has no velocity limiter (model (1) has none; the overspeed error at 1.2 vel_limit stays)."""
    return DriveConfig(
        torque_limit=torque_limit,
        vel_limit=VEL_LIMIT_MARGIN * motor_speed_limit(geometry, limits),
        enable_torque_mode_vel_limit=False,
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


def motor_speed_limit(geometry: RobotGeometry, limits: Any) -> float:
    """The largest motor speed (rev/s) within the constraints (2)."""
    corner = wheel_rates(geometry, limits.phi1, limits.phi2)
    return max(abs(corner.right), abs(corner.left))
