"""Baselines [7] and [19]: velocity commands behind a clamped inner loop, transport-free."""

from __future__ import annotations

import math

import numpy as np
import pytest

from controller_service.laws.base import DesignContext, ReferenceSample, RobotState
from controller_service.laws.jiang1997 import Jiang1997Controller, VelocityLoopMemory
from controller_service.laws.jiang2001 import Jiang2001Controller
from controller_service.references import Circle, CircleThenStop, Point

CONTEXT = DesignContext()
J97 = Jiang1997Controller({}, CONTEXT)
J01 = Jiang2001Controller({}, CONTEXT)


def euler_loop(controller, reference, init, duration, ts=1e-3, sub=4):
    """A tiny local plant (1), Euler at ts/sub, law at ts with zero-order hold."""
    x, y, th, v, w = init
    memory = controller.initial_memory()
    h = ts / sub
    trace = []
    for k in range(round(duration / ts)):
        t = k * ts
        ref = reference.sample(t)
        out, memory = controller.update(t, ts, RobotState(x, y, th, v, w), ref, memory)
        assert abs(out.tau1) <= 3.3 and abs(out.tau2) <= 51.0
        for _ in range(sub):
            x, y, th = x + h * v * math.cos(th), y + h * v * math.sin(th), th + h * w
            v, w = v + h * out.tau1, w + h * out.tau2
        trace.append((t, x, y, v, w, out.telemetry["mode"]))
    return np.array(trace)


@pytest.mark.slow
def test_jiang1997_breaks_the_velocity_limit_while_tracking():
    """The point of [7] in the paper (Figure 16): |v| beyond phi1 = 1.6, yet it tracks."""
    circle = Circle()
    trace = euler_loop(J97, circle, (0.0, -1.0, 0.0, 0.0, 0.0), 30.0)
    assert np.max(np.abs(trace[:, 3])) > 1.6
    ref = circle.sample(30.0 - 1e-3)
    assert math.hypot(trace[-1, 1] - ref.xd, trace[-1, 2] - ref.yd) < 0.01


@pytest.mark.slow
def test_jiang2001_tracks_within_limits_then_switches_to_the_stabilizer():
    reference = CircleThenStop(stop_time=20.0)
    trace = euler_loop(J01, reference, (0.0, -1.0, 0.0, 0.0, 0.0), 40.0)
    t, mode = trace[:, 0], trace[:, 5]
    assert np.all(mode[t < 20.0] == 0.0)
    assert np.all(mode[t >= 20.0 + reference.ramp] == 1.0)
    assert np.max(np.abs(trace[:, 3])) <= 1.6 and np.max(np.abs(trace[:, 4])) <= 5.1
    at_stop = reference.sample(19.999)
    before = trace[np.searchsorted(t, 19.999)]
    assert math.hypot(before[1] - at_stop.xd, before[2] - at_stop.yd) < 0.02


@pytest.mark.slow
def test_jiang2001_stabilizer_reduces_a_lateral_error():
    trace = euler_loop(J01, Point(), (0.0, 1.0, 0.0, 0.0, 0.0), 60.0)
    assert math.hypot(trace[-1, 1], trace[-1, 2]) < 0.6
    assert np.max(np.abs(trace[:, 3])) <= 1.6 and np.max(np.abs(trace[:, 4])) <= 5.1


def test_inner_loop_is_the_stated_form():
    state = RobotState(0.0, 0.0, 0.0, 0.45, 0.1)
    ref = ReferenceSample(0.0, 0.0, 0.0, 0.5, 0.2)
    out, memory = J97.update(0.0, 1e-3, state, ref, J97.initial_memory())
    v_c, w_c = out.telemetry["v_c"], out.telemetry["w_c"]
    assert (v_c, w_c) == pytest.approx((0.5, 0.2))
    # First sample: no feed-forward yet; then the backward difference of the commands.
    assert out.tau1 == pytest.approx(-20.0 * (0.45 - 0.5))
    assert memory == VelocityLoopMemory(v_c, w_c, 1.0)
    ref2 = ReferenceSample(0.0, 0.0, 0.0, 0.501, 0.2)
    out2, _ = J97.update(1e-3, 1e-3, state, ref2, memory)
    assert out2.tau1 == pytest.approx((0.501 - 0.5) / 1e-3 - 20.0 * (0.45 - 0.501))
    big, _ = J97.update(0.0, 1e-3, RobotState(5.0, 0.0, 0.0, 0.0, 0.0), ref, memory)
    assert big.tau1 == -3.3


@pytest.mark.parametrize("controller", [J97, J01], ids=lambda c: c.name)
def test_float_and_array_paths_agree_and_bad_input_gives_zero(controller):
    rng = np.random.default_rng(11)
    n = 100
    state = RobotState(*(rng.uniform(-2, 2, n) for _ in range(5)))
    vd = np.where(rng.uniform(size=n) < 0.3, 0.0, rng.uniform(-0.5, 0.5, n))
    wd = np.where(vd == 0.0, 0.0, rng.uniform(-0.2, 0.2, n))
    ref = ReferenceSample(
        rng.uniform(-2, 2, n), rng.uniform(-2, 2, n), rng.uniform(-3, 3, n), vd, wd
    )
    memory = VelocityLoopMemory(rng.uniform(-1, 1, n), rng.uniform(-1, 1, n), np.ones(n))
    bad = state.x.copy()
    bad[3] = math.nan
    state = state._replace(x=bad)
    out, new = controller.update(2.0, 1e-3, state, ref, memory)
    assert out.tau1[3] == 0.0 and out.telemetry["nonfinite"][3] == 1.0
    assert new.v_c[3] == memory.v_c[3]
    for i in range(n):

        def pick(tup, i=i):
            return type(tup)(*(float(v[i]) if np.ndim(v) else float(v) for v in tup))

        out_f, new_f = controller.update(2.0, 1e-3, pick(state), pick(ref), pick(memory))
        assert out_f.tau1 == pytest.approx(out.tau1[i], abs=1e-12)
        assert out_f.tau2 == pytest.approx(out.tau2[i], abs=1e-12)
        assert out_f.telemetry["mode"] == out.telemetry["mode"][i]
        assert new_f.w_c == pytest.approx(new.w_c[i], abs=1e-12)
        assert abs(out_f.tau1) <= 3.3 and abs(out_f.tau2) <= 51.0


@pytest.mark.parametrize("controller", [J97, J01], ids=lambda c: c.name)
@pytest.mark.parametrize("bad", [math.nan, math.inf, 1e308])
def test_huge_or_non_finite_float_input_never_exceeds_the_limits(controller, bad):
    for i in range(5):
        values = [0.1] * 5
        values[i] = bad
        out, _ = controller.update(
            1.0,
            1e-3,
            RobotState(*values),
            ReferenceSample(0.0, 0.0, 0.0, 0.5, 0.2),
            controller.initial_memory(),
        )
        assert math.isfinite(out.tau1) and abs(out.tau1) <= 3.3
        assert math.isfinite(out.tau2) and abs(out.tau2) <= 51.0
