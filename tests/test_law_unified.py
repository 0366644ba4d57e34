"""The unified law (7)-(10), (19): one source on floats and arrays, bounded torques, memory rule."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from controller_service.laws.base import Controller, DesignContext, ReferenceSample, RobotState
from controller_service.laws.unified import (
    FLOAT_STEP,
    TELEMETRY_KEYS,
    UnifiedController,
    UnifiedMemory,
    UnifiedParams,
    make_step,
)
from runtime.mathns import FLOAT_MATH

CONTEXT = DesignContext()
SIGN = UnifiedController(UnifiedParams(), CONTEXT)
BOUNDARY = UnifiedController(UnifiedParams(eps1=0.1, eps2=0.1), CONTEXT)


def random_inputs(rng: np.random.Generator, n: int):
    state = RobotState(
        rng.uniform(-3, 3, n),
        rng.uniform(-3, 3, n),
        rng.uniform(-7, 7, n),
        rng.uniform(-1.6, 1.6, n),
        rng.uniform(-5, 5, n),
    )
    ref = ReferenceSample(
        rng.uniform(-3, 3, n),
        rng.uniform(-3, 3, n),
        rng.uniform(-7, 7, n),
        rng.uniform(-0.5, 0.5, n),
        rng.uniform(-0.2, 0.2, n),
    )
    memory = UnifiedMemory(
        rng.uniform(0, 1, n), rng.uniform(-0.5, 0.5, n), rng.uniform(-0.5, 0.5, n)
    )
    return state, ref, memory


@pytest.mark.parametrize("controller", [SIGN, BOUNDARY], ids=lambda c: c.name)
def test_float_and_array_paths_agree(controller):
    rng = np.random.default_rng(7)
    n = 200
    state, ref, memory = random_inputs(rng, n)
    t = rng.uniform(0, 100, n)
    out_a, mem_a = controller.update(t, 1e-3, state, ref, memory)
    for i in range(n):

        def pick(tup, i=i):
            return type(tup)(*(float(v[i]) if np.ndim(v) else float(v) for v in tup))

        out_f, mem_f = controller.update(float(t[i]), 1e-3, pick(state), pick(ref), pick(memory))
        assert isinstance(out_f.tau1, float) and isinstance(mem_f.eta, float)
        assert out_f.tau1 == pytest.approx(out_a.tau1[i], abs=1e-12)
        assert out_f.tau2 == pytest.approx(out_a.tau2[i], abs=1e-12)
        for key in TELEMETRY_KEYS:
            assert out_f.telemetry[key] == pytest.approx(out_a.telemetry[key][i], abs=1e-12)
        for a, b in zip(mem_f, mem_a, strict=True):
            assert a == pytest.approx(b[i], abs=1e-12)


def test_names_protocol_and_telemetry_keys():
    assert SIGN.name == "unified" and BOUNDARY.name == "unified_boundary"
    assert isinstance(SIGN, Controller)
    out, _ = SIGN.update(
        0.0,
        1e-3,
        RobotState(0.0, 1.0, 0.0, 0.0, 0.0),
        ReferenceSample(0.0, 0.0, 0.0, 0.5, 0.2),
        SIGN.initial_memory(),
    )
    assert set(out.telemetry) == set(TELEMETRY_KEYS)


def test_sign_law_torques_are_plus_minus_varpi_with_opposite_sign_to_the_errors():
    rng = np.random.default_rng(3)
    state, ref, memory = random_inputs(rng, 500)
    out, _ = SIGN.update(1.0, 1e-3, state, ref, memory)
    tel = out.telemetry
    assert np.all(np.abs(out.tau1) == 3.3) and np.all(np.abs(out.tau2) == 51.0)
    assert np.all(np.sign(out.tau1) == -np.sign(tel["v_tilde"]))
    assert np.all(np.sign(out.tau2) == -np.sign(tel["w_tilde"]))


def test_boundary_layer_is_linear_inside_eps_and_sign_outside():
    ref = ReferenceSample(0.0, 0.0, 0.0, 0.5, 0.2)
    memory = BOUNDARY.initial_memory()
    base, _ = BOUNDARY.update(0.0, 1e-3, RobotState(0.0, 0.0, 0.0, 0.0, 0.0), ref, memory)
    alpha_v, alpha_w = base.telemetry["alpha_v"], base.telemetry["alpha_w"]
    inside, _ = BOUNDARY.update(
        0.0, 1e-3, RobotState(0.0, 0.0, 0.0, alpha_v + 0.05, alpha_w - 0.02), ref, memory
    )
    assert inside.tau1 == pytest.approx(-3.3 * 0.5)
    assert inside.tau2 == pytest.approx(51.0 * 0.2)
    outside, _ = BOUNDARY.update(
        0.0, 1e-3, RobotState(0.0, 0.0, 0.0, alpha_v + 0.3, alpha_w - 0.2), ref, memory
    )
    assert (outside.tau1, outside.tau2) == (-3.3, 51.0)


def test_memory_rule_eta_exact_and_z_euler_clamped():
    params = UnifiedParams()
    ref = ReferenceSample(0.0, 0.0, 0.0, 0.5, 0.2)
    state = RobotState(2.0, -1.0, 0.3, 0.1, 0.0)
    memory = UnifiedMemory(0.8, 0.1, -0.2)
    dt = 0.01
    out, new = SIGN.update(0.4, dt, state, ref, memory)
    tel = out.telemetry
    r = math.sqrt(1 + tel["xe"] ** 2 + tel["ye"] ** 2)
    assert new.eta == pytest.approx(0.8 * math.exp(-(0.25 + 0.04) * dt), rel=1e-15)
    assert new.z1 == pytest.approx(0.1 + dt * params.l1 / 2 * (tel["xe"] / r - 0.1 / params.m1))
    z2_rate = params.l2 / 2 * (math.sin((tel["theta_e"] - tel["xi"]) / 2) + 0.2 / params.m2)
    assert new.z2 == pytest.approx(-0.2 + dt * z2_rate)
    # A long step would overshoot |z| <= m; the rule clamps it, as (8) guarantees.
    _, far = SIGN.update(0.4, 100.0, RobotState(50.0, 0.0, 0.0, 0.0, 0.0), ref, memory)
    assert abs(far.z1) <= params.m1 and abs(far.z2) <= params.m2


def test_time_varying_signal_follows_the_law_clock():
    ref = ReferenceSample(0.0, 0.0, 0.0, 0.0, 0.0)
    state = RobotState(0.0, 1.0, 0.0, 0.0, 0.0)
    memory = SIGN.initial_memory()
    r = math.sqrt(2.0)
    for t in (0.0, 1.0, 2.5):
        out, _ = SIGN.update(t, 1e-3, state, ref, memory)
        assert out.telemetry["xi"] == pytest.approx(math.tanh(r - 1) * math.sin(t))


BAD = st.sampled_from([math.nan, math.inf, -math.inf, 1e308, -1e308, 1e200])
ANY = st.one_of(st.floats(-10, 10), BAD)


@settings(max_examples=300, deadline=None)
@given(st.lists(ANY, min_size=13, max_size=13), st.sampled_from([SIGN, BOUNDARY]))
# Finite memory whose sum overflows: the float path rejects it; the array path must too.
@example([0.0] * 10 + [1.0, 1e308, 1e308], SIGN)
def test_non_finite_or_huge_input_never_gives_a_torque_beyond_the_limit(values, controller):
    state = RobotState(*values[0:5])
    ref = ReferenceSample(*values[5:10])
    memory = UnifiedMemory(*values[10:13])
    out, new = controller.update(1.0, 1e-3, state, ref, memory)
    assert math.isfinite(out.tau1) and abs(out.tau1) <= 3.3
    assert math.isfinite(out.tau2) and abs(out.tau2) <= 51.0
    if not all(math.isfinite(v) for v in values):
        assert out.telemetry["nonfinite"] == 1.0
        assert (out.tau1, out.tau2) == (0.0, 0.0)
        assert new is memory
    arrays = [np.array([v, 0.5]) for v in values]
    out_a, _ = controller.update(
        1.0,
        1e-3,
        RobotState(*arrays[0:5]),
        ReferenceSample(*arrays[5:10]),
        UnifiedMemory(*arrays[10:13]),
    )
    assert np.all(np.isfinite(out_a.tau1)) and np.all(np.abs(out_a.tau1) <= 3.3)
    assert np.all(np.isfinite(out_a.tau2)) and np.all(np.abs(out_a.tau2) <= 51.0)
    assert out_a.tau1[0] == out.tau1 and out_a.tau2[0] == out.tau2
    assert out_a.telemetry["nonfinite"][1] == 0.0


def test_boundary_needs_both_widths():
    with pytest.raises(ValueError, match="eps1 and eps2"):
        UnifiedController(UnifiedParams(eps1=0.1), CONTEXT)


def test_initial_memory_shapes_and_clamp():
    mem = SIGN.initial_memory(4, z1=2.0, z2=-0.1)
    assert mem.eta.shape == (4,) and np.all(mem.eta == 1.0)
    assert np.all(mem.z1 == 0.5) and np.all(mem.z2 == -0.1)
    assert SIGN.initial_memory() == UnifiedMemory(1.0, 0.0, 0.0)


def euler_loop(controller, ref_of_t, init, duration, ts=1e-3, sub=4):
    """A tiny local plant (1) with no disturbance, Euler at ts/sub, law at ts (zero-order hold)."""
    x, y, th, v, w = init
    memory = controller.initial_memory()
    h = ts / sub
    max_v = max_w = 0.0
    for k in range(round(duration / ts)):
        t = k * ts
        out, memory = controller.update(t, ts, RobotState(x, y, th, v, w), ref_of_t(t), memory)
        for _ in range(sub):
            x, y, th = x + h * v * math.cos(th), y + h * v * math.sin(th), th + h * w
            v, w = v + h * out.tau1, w + h * out.tau2
            max_v, max_w = max(max_v, abs(v)), max(max_w, abs(w))
    ref = ref_of_t(round(duration / ts) * ts)
    return math.hypot(x - ref.xd, y - ref.yd), max_v, max_w


@pytest.mark.slow
def test_closed_loop_sanity_circle_converges_within_limits():
    from controller_service.references import Circle

    circle = Circle()
    error, max_v, max_w = euler_loop(SIGN, circle.sample, (0.0, -1.0, 0.0, 0.0, 0.0), 40.0)
    assert error < 0.05
    assert max_v <= 1.6 and max_w <= 5.1


EDGES = st.sampled_from([0.0, -0.0, 1e-300, -1e-300, 0.1, -0.1, math.nan, math.inf, -math.inf])
SCALAR = st.one_of(st.floats(-4, 4), EDGES)


def _same_bits(a: tuple, b: tuple) -> bool:
    """Equal as IEEE values: signed zeros apart, NaN equal to NaN."""
    return len(a) == len(b) and all(
        (x != x and y != y) or (x == y and math.copysign(1.0, x) == math.copysign(1.0, y))
        for x, y in zip(a, b, strict=True)
    )


@settings(max_examples=500, deadline=None)
@given(
    st.lists(SCALAR, min_size=15, max_size=15),
    st.sampled_from([0.0, 10.0]),  # 1/eps: (10) or the boundary layer (19)
)
def test_the_float_step_is_the_laws_one_definition_with_its_helpers_inline(values, inv_eps):
    """FLOAT_STEP is make_step's own source compiled with sign and clip written inline
    (runtime.mathns.inline_float_helpers): bit for bit the closure that calls FloatMath's
    helpers, on edge values (signed zeros: sign(-0.0) = 0, NaN, inf) and either torque law,
    and it calls neither helper."""
    called = make_step(FLOAT_MATH)
    t, dt = values[0], abs(values[1]) * 1e-3
    state, ref, memory = tuple(values[2:7]), tuple(values[7:12]), tuple(values[12:15])
    p = (1.0, 1.0, 0.5, 0.5, 0.25, 0.25, 3.3, 51.0, inv_eps, inv_eps)
    results = []
    for step in (FLOAT_STEP, called):
        try:
            results.append(step(t, dt, state, ref, memory, p))
        except (ValueError, OverflowError, ZeroDivisionError) as exc:
            results.append(type(exc))
    inline, plain = results
    assert inline == plain if isinstance(plain, type) else _same_bits(inline, plain)
    free = FLOAT_STEP.__code__.co_freevars
    assert "sign" not in free and "clip" not in free and "sin" in free
