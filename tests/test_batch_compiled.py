"""The compiled batch path (hil/sim/compiled.py) equals the numpy batch path, its reference.

Each scenario runs the same robots through both paths and compares every robot's summary: the
floats to 1e-12 (final errors, rms error, peaks of |v|, |omega|, |tau|), the counts exactly
(limit violations, dropped commands, plant steps).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from hil.bundled import bundled_path
from hil.scenario import load_scenario, loads_scenario
from hil.sim import compiled, simulate_batch
from hil.sim.core import RobotVariation
from hil.sweep.runner import scenario_at
from tests.scenario_text import circle


def _scenario(law: str = "unified", delay: float = 0.0, extra: str = "") -> object:
    eps = {"eps1": 0.1, "eps2": 0.1} if law == "unified_boundary" else {}
    text = circle(
        controller={"law": law, **eps}, timing={"ts": 0.001, "delay": delay}, run={"duration": 0.4}
    )
    text += extra
    return loads_scenario(text, Path.cwd())


def _both(scenario: object, variations: list[RobotVariation], monkeypatch) -> tuple:
    assert compiled.numba is not None  # a declared dependency: its absence is a failure here
    monkeypatch.setattr(compiled, "MIN_WORK", 0)
    monkeypatch.setenv("HIL_NO_COMPILED", "1")
    reference = simulate_batch(scenario, variations)
    monkeypatch.setenv("HIL_NO_COMPILED", "0")
    fast = simulate_batch(scenario, variations)
    return reference.summaries, fast.summaries


def _assert_equal(reference: list[dict], fast: list[dict]) -> None:
    assert len(reference) == len(fast)
    for a, b in zip(reference, fast, strict=True):
        assert a.keys() == b.keys()
        for key, value in a.items():
            if isinstance(value, float):
                assert b[key] == pytest.approx(value, abs=1e-12, rel=0), key
            else:
                assert b[key] == value, key


def test_delays_and_jitter_reorder_and_drop_commands_alike(monkeypatch):
    """Robots with their own delay and jitter draws: commands land between samples, overtake
    each other and are dropped; some robots start beyond phi1 (violations counted)."""
    variations = [
        RobotVariation(
            x=-1.0 + 0.05 * i,
            v=2.0 if i % 5 == 0 else None,
            delay=0.00035 * (i % 4),
            jitter=0.0012 * (i % 3),
            jitter_seed=i,
        )
        for i in range(24)
    ]
    reference, fast = _both(_scenario(), variations, monkeypatch)
    assert sum(s["commands_dropped"] for s in reference) > 0  # the scenario reorders commands
    assert sum(s["violations"]["v"] for s in reference) > 0  # and counts violations
    _assert_equal(reference, fast)


def test_boundary_law_with_a_constant_disturbance_and_one_delay(monkeypatch):
    """(19) under a constant matched disturbance, every robot landing its commands 2.5 ms late
    (the same landing steps for all: the numpy path's shared hold)."""
    extra = '[disturbance]\nkind = "constant"\ns1 = 0.2\ns2 = 0.2\nvalue1 = 0.15\nvalue2 = -0.1'
    sc = _scenario("unified_boundary", delay=0.0025, extra=extra)
    variations = [RobotVariation(y=1.0 - 0.1 * i, theta=0.3 * i) for i in range(16)]
    reference, fast = _both(sc, variations, monkeypatch)
    _assert_equal(reference, fast)


@pytest.mark.parametrize("name", ["paper_tracking", "paper_stabilization", "paper_chattering"])
def test_the_papers_set_ups_with_delays_per_robot(name, monkeypatch):
    """The bundled scenarios of the unified law, 0.5 s, robots with their own delay and seed."""
    sc = load_scenario(bundled_path(name))
    sc = scenario_at(sc, sc.timing.ts, 0.5)
    variations = [
        RobotVariation(delay=0.0004 * i, jitter=0.0005, jitter_seed=7 * i) for i in range(8)
    ]
    reference, fast = _both(sc, variations, monkeypatch)
    _assert_equal(reference, fast)


def test_what_the_kernel_does_not_cover_stays_on_the_numpy_path(monkeypatch):
    """A lagged actuator or a time-varying disturbance is not compiled: applies() says no."""
    monkeypatch.setattr(compiled, "MIN_WORK", 0)
    monkeypatch.delenv("HIL_NO_COMPILED", raising=False)
    sine = '[disturbance]\nkind = "sine"\ns1 = 0.1\ns2 = 0.1\namplitude1 = 0.1\nfreq = 1.0'
    for extra in ("[plant]\nlag = 0.01", sine):
        sc = _scenario(extra=extra)
        calls = []
        monkeypatch.setattr(compiled, "run", lambda *a, calls=calls: calls.append(a))
        simulate_batch(sc, 3)
        assert calls == []


def test_robots_with_their_own_start_memory_and_a_per_sample_callback(monkeypatch):
    """A long run's windowed ideal on the kernel: each robot starts at its own time (its own
    reference samples and law clock) from its own law memory, and the callback gets every
    sample's state (all seven fields) as the numpy path hands it, then the final one."""
    from hil.scenario import build_loop
    from hil.sim.core import _initial_memory

    sc = _scenario(delay=0.0003)
    n = 12
    variations = [RobotVariation(x=-1.0 + 0.1 * i, theta=0.2 * i) for i in range(n)]
    t0 = np.linspace(0.0, 37.3, n)
    controller = build_loop(sc)[0]
    start = _initial_memory(controller, n, sc)
    memory = type(start)(*(np.asarray(f, dtype=float) + 0.05 * np.arange(n) for f in start))
    monkeypatch.setattr(compiled, "MIN_WORK", 0)
    seen: dict[str, dict[int, tuple]] = {"0": {}, "1": {}}
    runs = {}
    for flag in ("1", "0"):
        monkeypatch.setenv("HIL_NO_COMPILED", flag)
        calls: list = []
        monkeypatch.setattr(compiled, "run", _spy(calls))
        book = seen[flag]

        def hook(k, state, book=book):
            book[k] = tuple(np.array(q, dtype=float, copy=True) for q in state)

        runs[flag] = simulate_batch(sc, variations, t0=t0, memory=memory, on_sample=hook)
        assert bool(calls) == (flag == "0")  # the kernel ran exactly when allowed
    _assert_equal(runs["1"].summaries, runs["0"].summaries)
    assert sorted(seen["0"]) == sorted(seen["1"]) == list(range(401))
    for k, fields in seen["1"].items():
        for a, b in zip(fields, seen["0"][k], strict=True):
            assert np.allclose(b, a, rtol=0, atol=1e-12), k
    # the start times mattered: the same robots from t = 0 end elsewhere
    plain = simulate_batch(sc, variations, memory=memory)
    assert plain.summaries[-1]["final_position_error"] != pytest.approx(
        runs["0"].summaries[-1]["final_position_error"], abs=1e-6
    )


def _spy(calls: list):
    real = compiled.run

    def spy(*args, **kwargs):
        calls.append(1)
        return real(*args, **kwargs)

    return spy


@pytest.mark.filterwarnings("ignore:invalid value encountered:RuntimeWarning")  # inf - inf
def test_a_state_that_is_not_finite_is_counted_alike(monkeypatch):
    """Robots started with v = inf (the unified law's bad-input rule then holds zero torque):
    both paths count every plant step as non-finite from the first, with the same first time,
    and neither calls the limits held; the finite robots are untouched."""
    variations = [RobotVariation(v=np.inf if i % 2 else None, delay=0.0003 * i) for i in range(4)]
    reference, fast = _both(_scenario(), variations, monkeypatch)
    steps = reference[0]["plant_steps"]
    for i, (a, b) in enumerate(zip(reference, fast, strict=True)):
        assert a["nonfinite_steps"] == b["nonfinite_steps"] == (steps if i % 2 else 0), i
        assert a["nonfinite_first_t_s"] == b["nonfinite_first_t_s"], i
        assert a["limits_held"] is b["limits_held"] is (i % 2 == 0), i
        assert (a["nonfinite_first_t_s"] is None) == (i % 2 == 0), i
