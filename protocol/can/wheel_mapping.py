"""Wheel mapping: the paper's generalized torques (tau1, tau2) <-> the two drives' motor torques.

Model (1) of Li et al. 2024 writes the dynamics per unit mass and inertia: v' = tau1 + d1,
omega' = tau2 + d2. For a differential-drive robot of mass ``m`` and yaw inertia ``J`` (wheel
and rotor inertia neglected, no slip), the physical force along the heading and the yaw moment are

    F = m tau1,        M = J tau2.

Each wheel pushes the ground with F_R, F_L at lateral distance +-b (half track), so
F = F_R + F_L and M = b (F_R - F_L), which gives F_R = F/2 + M/(2b), F_L = F/2 - M/(2b).
A wheel of radius r needs the torque T = r F_wheel, and a gear of ratio G (motor turns per wheel
turn) divides it: q = T / G. Hence, motor torques (what Set_Input_Torque carries):

    q_R = (r / G) (m tau1 / 2 + J tau2 / (2 b)),
    q_L = (r / G) (m tau1 / 2 - J tau2 / (2 b)),

and the inverse:

    tau1 = G (q_R + q_L) / (r m),      tau2 = G b (q_R - q_L) / (r J).

Speeds (no slip), wheel rates w_R, w_L in rad/s:

    v = r (w_R + w_L) / 2,   omega = r (w_R - w_L) / (2 b),
    w_R = (v + b omega) / r,   w_L = (v - b omega) / r,

and a motor reports G w / (2 pi) rev/s (Get_Encoder_Estimates' Vel_Estimate), its position
G theta_wheel / (2 pi) rev.

The float32 of the wire rounds q_R, q_L, so the decoded (tau1, tau2) may exceed varpi1, varpi2 by
a rounding error: :func:`decode_torques` clamps in (tau1, tau2) space, after decoding, so the
constraints (2) hold exactly where commands are applied.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from typing import NamedTuple

TWO_PI = 2.0 * math.pi


@dataclass(frozen=True)
class RobotGeometry:
    """The scenario's ``[robot]`` table (SI units).

    Defaults: a 10 kg robot, 0.5 kg m^2 about its vertical axis, 5 cm wheels, 0.2 m half track
    and a 10:1 gear, so the paper's varpi1 = 3.3, varpi2 = 51 need at most 0.40 Nm per motor.
    """

    mass: float = 10.0
    yaw_inertia: float = 0.5
    wheel_radius: float = 0.05
    half_track: float = 0.2
    gear_ratio: float = 10.0

    def __post_init__(self) -> None:
        for name in ("mass", "yaw_inertia", "wheel_radius", "half_track", "gear_ratio"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
                raise ValueError(f"[robot] {name} must be a positive finite number, got {value!r}")


class MotorTorques(NamedTuple):
    """Motor-side torques in Nm for the right and left drive."""

    right: float
    left: float


class WheelRates(NamedTuple):
    """Motor-side velocities in rev/s for the right and left drive."""

    right: float
    left: float


def motor_torques(g: RobotGeometry, tau1: float, tau2: float) -> MotorTorques:
    """(tau1, tau2) of model (1) -> motor torques (q_R, q_L)."""
    force_half = 0.5 * g.mass * tau1
    moment_part = g.yaw_inertia * tau2 / (2.0 * g.half_track)
    k = g.wheel_radius / g.gear_ratio
    return MotorTorques(k * (force_half + moment_part), k * (force_half - moment_part))


def generalized_torques(g: RobotGeometry, q_right: float, q_left: float) -> tuple[float, float]:
    """Motor torques (q_R, q_L) -> (tau1, tau2) of model (1); the inverse of
    :func:`motor_torques`."""
    k = g.gear_ratio / g.wheel_radius
    tau1 = k * (q_right + q_left) / g.mass
    tau2 = k * g.half_track * (q_right - q_left) / g.yaw_inertia
    return tau1, tau2


def motor_torque_limit(g: RobotGeometry, varpi1: float, varpi2: float) -> float:
    """The largest |q| any (tau1, tau2) within (2) asks of one motor (both at their limits)."""
    return (g.wheel_radius / g.gear_ratio) * (
        0.5 * g.mass * varpi1 + g.yaw_inertia * varpi2 / (2.0 * g.half_track)
    )


def clamp(value: float, limit: float) -> float:
    """``value`` within [-limit, limit]; NaN becomes 0 (no torque is the safe command)."""
    if value != value:
        return 0.0
    return -limit if value < -limit else (limit if value > limit else value)


def to_float32(value: float) -> float:
    """The float32 the wire carries (round to nearest, as struct/cantools do)."""
    return struct.unpack("<f", struct.pack("<f", value))[0]


def decode_torques(
    g: RobotGeometry, q_right: float, q_left: float, varpi1: float, varpi2: float
) -> tuple[float, float]:
    """Decoded motor torques -> (tau1, tau2), clamped to |tau1| <= varpi1, |tau2| <= varpi2 (2)."""
    tau1, tau2 = generalized_torques(g, q_right, q_left)
    return clamp(tau1, varpi1), clamp(tau2, varpi2)


def wheel_rates(g: RobotGeometry, v: float, omega: float) -> WheelRates:
    """Body velocities (v, omega) -> motor rev/s of the right and left drive."""
    k = g.gear_ratio / (TWO_PI * g.wheel_radius)
    return WheelRates(k * (v + g.half_track * omega), k * (v - g.half_track * omega))


def body_velocities(g: RobotGeometry, rev_s_right: float, rev_s_left: float) -> tuple[float, float]:
    """Motor rev/s of the right and left drive -> (v, omega); the inverse of
    :func:`wheel_rates`."""
    k = TWO_PI * g.wheel_radius / g.gear_ratio
    w_r, w_l = k * rev_s_right, k * rev_s_left
    return 0.5 * (w_r + w_l), (w_r - w_l) / (2.0 * g.half_track)
