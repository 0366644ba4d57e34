"""Plant model (1): one RK4 on floats and on arrays, both equal to an independent textbook RK4,
its accuracy, the actuator lag, the seeded disturbances and the sensor model."""

from __future__ import annotations

import math

import numpy as np
import pytest

from controller_service.laws.base import Limits, RobotState
from plant_emulator.disturbances import Disturbance, disturbance_at, hash_unit
from plant_emulator.dynamics import Extremes, PlantState, rk4_array, rk4_float
from plant_emulator.sensors import Sensor, measure
from protocol.angles import wrap_angle

DISTURBANCES = [
    Disturbance(),
    Disturbance(kind="constant", s1=0.2, s2=0.3, value1=0.2, value2=-0.3),
    Disturbance(kind="sine", s1=0.3, s2=0.5, amplitude1=0.3, amplitude2=0.5, freq=3.0, phase=0.4),
    Disturbance(kind="random", s1=0.3, s2=0.4, period=0.00035, seed=11),
]
START = PlantState(0.1, -0.2, 0.3, 0.5, 1.0, 0.4, -2.0)


NO_DISTURBANCE = Disturbance()


def textbook_rk4(s, cmd1, cmd2, t, h, dist=NO_DISTURBANCE, lag=0.0, seed=None):
    """One classical RK4 step of model (1) written from the textbook, independently of
    :mod:`plant_emulator.dynamics`: f evaluated at the four stages, the applied torques
    tau(s) = cmd + (tau0 - cmd) exp(-s/T) known exactly at the stage times (T = 0: cmd)."""
    xp = np if isinstance(s.x, np.ndarray) else math

    def applied(tau0, cmd, dt):
        return cmd if lag <= 0.0 else cmd + (tau0 - cmd) * math.exp(-dt / lag)

    def f(q, dt):
        _x, _y, th, v, w = q
        d1, d2 = disturbance_at(dist, t + dt, seed)
        u1, u2 = applied(s.tau1, cmd1, dt) + d1, applied(s.tau2, cmd2, dt) + d2
        return (v * xp.cos(th), v * xp.sin(th), w, u1, u2)

    q0 = tuple(s[:5])
    k1 = f(q0, 0.0)
    k2 = f(tuple(a + 0.5 * h * b for a, b in zip(q0, k1, strict=True)), 0.5 * h)
    k3 = f(tuple(a + 0.5 * h * b for a, b in zip(q0, k2, strict=True)), 0.5 * h)
    k4 = f(tuple(a + h * b for a, b in zip(q0, k3, strict=True)), h)
    q = tuple(
        a + h / 6.0 * (b1 + 2.0 * b2 + 2.0 * b3 + b4)
        for a, b1, b2, b3, b4 in zip(q0, k1, k2, k3, k4, strict=True)
    )
    return PlantState(*q, applied(s.tau1, cmd1, h), applied(s.tau2, cmd2, h))


def advance(s, cmd1, cmd2, t0, t1, h, lag=0.0):
    """Integrate from t0 to t1 in equal steps of at most h (the real-time plant's lazy steps)."""
    n = max(1, math.ceil((t1 - t0) / h - 1e-9))
    ext = Extremes.zeros()
    return rk4_float(s, cmd1, cmd2, t0, (t1 - t0) / n, n, NO_DISTURBANCE, lag, None, Limits(), ext)


@pytest.mark.parametrize("lag", [0.0, 0.003])
@pytest.mark.parametrize("dist", DISTURBANCES, ids=lambda d: d.kind)
def test_float_kernel_equals_textbook_rk4(dist: Disturbance, lag: float) -> None:
    ext = Extremes.zeros()
    fast = rk4_float(START, 3.3, -51.0, 0.2, 1e-4, 40, dist, lag, None, Limits(), ext)
    ref = START
    for i in range(40):
        ref = textbook_rk4(ref, 3.3, -51.0, 0.2 + i * 1e-4, 1e-4, dist, lag)
    assert max(abs(a - b) for a, b in zip(fast, ref, strict=True)) < 1e-14
    assert ext.steps == 40


@pytest.mark.parametrize("h", [1e-4, 2e-3])  # Taylor-rotation path and exact-trig fallback
@pytest.mark.parametrize("lag", [0.0, 0.003])
@pytest.mark.parametrize("dist", DISTURBANCES, ids=lambda d: d.kind)
def test_array_kernel_equals_textbook_rk4(dist: Disturbance, lag: float, h: float) -> None:
    rng = np.random.default_rng(3)
    n = 7
    s = PlantState(*(rng.uniform(-2, 2, n) for _ in range(7)))
    c1 = rng.uniform(-3.3, 3.3, n)
    c2 = rng.uniform(-51, 51, n)
    seeds = np.arange(n, dtype=np.int64) + 5
    ext = Extremes.zeros(n)
    fast = rk4_array(s, c1, c2, 0.1, h, 25, dist, lag, seeds, Limits(), ext)
    ref = s
    for i in range(25):
        ref = textbook_rk4(ref, c1, c2, 0.1 + i * h, h, dist, lag, seeds)
    for a, b in zip(fast, ref, strict=True):
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-12)
    for i in range(n):  # each robot equals its own float run
        one = rk4_float(
            PlantState(*(float(q[i]) for q in s)),
            float(c1[i]),
            float(c2[i]),
            0.1,
            h,
            25,
            dist,
            lag,
            int(seeds[i]),
            Limits(),
            Extremes.zeros(),
        )
        assert max(abs(float(a[i]) - b) for a, b in zip(fast, one, strict=True)) < 1e-12


def test_rk4_is_exact_on_polynomial_states_and_fourth_order_on_position() -> None:
    s0 = PlantState(0.0, 0.0, 0.2, 0.3, 0.5)
    tau1, tau2, t_end = 0.7, -0.4, 2.0
    ends = {}
    for n in (50, 100, 200):
        ends[n] = advance(s0, tau1, tau2, 0.0, t_end, t_end / n)
    s = ends[200]
    assert s.v == pytest.approx(0.3 + tau1 * t_end, abs=1e-13)
    assert s.omega == pytest.approx(0.5 + tau2 * t_end, abs=1e-13)
    assert s.theta == pytest.approx(0.2 + 0.5 * t_end + 0.5 * tau2 * t_end**2, abs=1e-13)
    fine = advance(s0, tau1, tau2, 0.0, t_end, t_end / 3200)
    err = {n: math.hypot(ends[n].x - fine.x, ends[n].y - fine.y) for n in ends}
    assert 12.0 < err[50] / err[100] < 20.0  # halving h divides the error by ~2**4
    assert err[200] < 1e-9


def test_advance_lands_exactly_and_lag_is_first_order() -> None:
    lag = 0.05
    s = advance(PlantState(0, 0, 0, 0, 0, 0.0, 0.0), 2.0, -1.0, 0.0, 0.123, 1e-3, lag=lag)
    decay = math.exp(-0.123 / lag)
    assert s.tau1 == pytest.approx(2.0 * (1 - decay), rel=1e-12)
    assert s.tau2 == pytest.approx(-1.0 * (1 - decay), rel=1e-12)
    # v' = tau1(t): v(T) = 2 (T - lag (1 - e^{-T/lag}))
    assert s.v == pytest.approx(2.0 * (0.123 - lag * (1 - decay)), rel=1e-9)
    # A lag far below the step stays stable (the torque is solved exactly, not by RK4): the
    # only error is the first step's quadrature of the torque's jump, at most h/6 in v.
    s = advance(PlantState(0, 0, 0, 0, 0), 1.0, 1.0, 0.0, 1.0, 0.1, lag=1e-6)
    assert s.tau1 == pytest.approx(1.0) and abs(s.v - 1.0) <= 0.1 / 6 + 1e-9


def test_extremes_count_every_step_beyond_limit() -> None:
    # v = 3.3 t from rest: beyond phi1 = 1.6 after t = 1.6/3.3; steps end at j h.
    ext = Extremes.zeros()
    rk4_float(
        PlantState(0, 0, 0, 0, 0),
        3.3,
        0.0,
        0.0,
        1e-3,
        1000,
        Disturbance(),
        0.0,
        None,
        Limits(),
        ext,
    )
    expected = sum(1 for j in range(1, 1001) if 3.3 * j * 1e-3 > 1.6 * (1 + 1e-9))
    assert ext.violations_v == expected
    assert ext.max_abs_v == pytest.approx(3.3)
    assert ext.violations_tau1 == 0 and ext.violations_omega == 0


def test_random_disturbance_is_a_pure_bounded_function_of_seed_and_hold() -> None:
    d = Disturbance(kind="random", s1=0.3, s2=0.1, period=0.05, seed=42)
    a = disturbance_at(d, 0.071)
    assert a == disturbance_at(d, 0.09)  # same hold interval
    assert a != disturbance_at(d, 0.11)  # next hold
    assert a == disturbance_at(Disturbance(kind="random", s1=0.3, s2=0.1, period=0.05), 0.071, 42)
    seeds = np.array([42, 43, 42], dtype=np.int64)
    arr = disturbance_at(d, 0.071, seeds)
    assert arr[0][0] == a[0] and arr[0][2] == a[0] and arr[0][1] != a[0]
    vals = np.array([disturbance_at(d, j * 0.05)[0] for j in range(4000)])
    assert np.all(np.abs(vals) <= 0.3) and abs(vals.mean()) < 0.02
    assert vals.std() == pytest.approx(0.3 / math.sqrt(3), rel=0.05)  # uniform on [-s, s]
    u = hash_unit(np.array([7, 7]), 3, np.array([10, 11]))
    assert u[0] == hash_unit(7, 3, 10) and u[1] == hash_unit(7, 3, 11)


def test_sensor_noise_is_seeded_and_quantization_rounds() -> None:
    sensor = Sensor(noise_std=(0.01, 0.0, 0.0, 0.0, 0.0), quantization=(0, 0, 0, 0.25, 0), seed=3)
    true = RobotState(1.0, 2.0, 0.5, 0.6, 0.1)
    m1 = measure(sensor, true, 17)
    assert m1 == measure(sensor, true, 17)
    assert m1.x != measure(sensor, true, 18).x and m1.y == 2.0
    assert m1.v == 0.5  # 0.6 rounded to a 0.25 step
    xs = np.array([measure(sensor, true, k).x for k in range(4000)]) - 1.0
    assert xs.std() == pytest.approx(0.01, rel=0.06) and abs(xs.mean()) < 1e-3
    batch = measure(sensor, RobotState(*(np.full(2, q) for q in true)), 17, np.array([3, 4]))
    assert batch.x[0] == pytest.approx(m1.x, abs=1e-15) and batch.x[1] != batch.x[0]


def test_wrap_angle_is_half_open() -> None:
    assert wrap_angle(math.pi) == math.pi
    assert wrap_angle(-math.pi) == math.pi
    assert wrap_angle(3 * math.pi / 2) == pytest.approx(-math.pi / 2)
    np.testing.assert_allclose(wrap_angle(np.array([-math.pi, 7.0])), [math.pi, 7.0 - 2 * math.pi])
