"""Wheel mapping (tau1, tau2) <-> motor torques: limits (2) hold exactly after float32."""

from __future__ import annotations

import math
import random

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from protocol.can.wheel_mapping import (
    RobotGeometry,
    body_velocities,
    decode_torques,
    generalized_torques,
    motor_torque_limit,
    motor_torques,
    to_float32,
    wheel_rates,
)

VARPI1, VARPI2 = 3.3, 51.0
F32_EPS = 2.0**-24  # float32 round-to-nearest: relative error <= 2^-24

geometries = st.builds(
    RobotGeometry,
    mass=st.floats(0.5, 200.0),
    yaw_inertia=st.floats(0.01, 50.0),
    wheel_radius=st.floats(0.01, 0.5),
    half_track=st.floats(0.05, 1.0),
    gear_ratio=st.floats(1.0, 100.0),
)


def _round_trip(g, tau1, tau2):
    q = motor_torques(g, tau1, tau2)
    return q, decode_torques(g, to_float32(q.right), to_float32(q.left), VARPI1, VARPI2)


def _tolerances(g, q):
    # tau1 = G (qR + qL)/(r m), tau2 = G b (qR - qL)/(r J): each q carries <= 2^-24 |q|
    rounding = F32_EPS * (abs(q.right) + abs(q.left))
    k = g.gear_ratio / g.wheel_radius
    return k * rounding / g.mass, k * g.half_track * rounding / g.yaw_inertia


@settings(max_examples=400, deadline=None)
@given(
    g=geometries,
    tau1=st.floats(-VARPI1, VARPI1),
    tau2=st.floats(-VARPI2, VARPI2),
)
def test_can_wheel_mapping_stays_within_limits_and_inverts(g, tau1, tau2):
    q, (t1, t2) = _round_trip(g, tau1, tau2)
    assert abs(t1) <= VARPI1 and abs(t2) <= VARPI2
    tol1, tol2 = _tolerances(g, q)
    assert abs(t1 - tau1) <= 2 * tol1 + 1e-15
    assert abs(t2 - tau2) <= 2 * tol2 + 1e-15


def test_can_wheel_mapping_corners_hold_exactly_where_float32_overshoots():
    rng = random.Random(3)
    overshoots = 0
    for _ in range(5000):
        g = RobotGeometry(
            rng.uniform(1, 50), rng.uniform(0.05, 5), rng.uniform(0.02, 0.3),
            rng.uniform(0.1, 0.5), rng.uniform(1, 50),
        )  # fmt: skip
        for tau1, tau2 in ((VARPI1, VARPI2), (-VARPI1, VARPI2), (VARPI1, -VARPI2)):
            q = motor_torques(g, tau1, tau2)
            raw = generalized_torques(g, to_float32(q.right), to_float32(q.left))
            overshoots += abs(raw[0]) > VARPI1 or abs(raw[1]) > VARPI2
            t1, t2 = decode_torques(g, to_float32(q.right), to_float32(q.left), VARPI1, VARPI2)
            assert abs(t1) <= VARPI1 and abs(t2) <= VARPI2
            assert max(abs(q.right), abs(q.left)) <= motor_torque_limit(g, VARPI1, VARPI2) * (
                1 + 1e-12
            )
    assert overshoots > 0  # the clamp after decoding is needed, not decorative


def test_can_wheel_mapping_hand_values():
    g = RobotGeometry(mass=10, yaw_inertia=0.5, wheel_radius=0.05, half_track=0.2, gear_ratio=10)
    # F = 10 N, M = 0: each wheel 5 N * 0.05 m = 0.25 Nm, motor 0.025 Nm
    assert motor_torques(g, 1.0, 0.0) == pytest.approx((0.025, 0.025))
    # M = 0.5 Nm: F_R = -F_L = M/(2b) = 1.25 N -> 0.0625 Nm wheel -> 0.00625 Nm motor
    assert motor_torques(g, 0.0, 1.0) == pytest.approx((0.00625, -0.00625))
    assert motor_torque_limit(g, VARPI1, VARPI2) == pytest.approx(0.40125)
    # v = 1 m/s: wheel 20 rad/s, motor 200/(2 pi) rev/s
    assert wheel_rates(g, 1.0, 0.0) == pytest.approx((200 / (2 * math.pi),) * 2)
    assert wheel_rates(g, 0.0, 1.0) == pytest.approx((40 / (2 * math.pi), -40 / (2 * math.pi)))


@settings(max_examples=200, deadline=None)
@given(g=geometries, v=st.floats(-2, 2), omega=st.floats(-6, 6))
def test_can_wheel_speeds_invert(g, v, omega):
    v2, w2 = body_velocities(g, *wheel_rates(g, v, omega))
    assert v2 == pytest.approx(v, abs=1e-12) and w2 == pytest.approx(omega, abs=1e-12)


def test_can_decode_torques_nan_is_zero():
    g = RobotGeometry()
    assert decode_torques(g, math.nan, 0.0, VARPI1, VARPI2) == (0.0, 0.0)


@pytest.mark.parametrize("bad", [0.0, -1.0, math.nan, math.inf])
def test_can_robot_geometry_rejects_bad_values(bad):
    with pytest.raises(ValueError):
        RobotGeometry(mass=bad)
