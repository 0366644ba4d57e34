"""The unified law's eta re-arm (controller_service.laws.eta_rearm): off by default, fires once
per stop, never faster than its dwell, one source on floats and arrays, and what it does after
a 60 s tracking phase (batch simulator, no real time)."""

from __future__ import annotations

import dataclasses
import itertools

import numpy as np
import pytest

from controller_service.laws.base import DesignContext, ReferenceSample, RobotState
from controller_service.laws.eta_rearm import EtaRearmController, RearmMemory
from controller_service.laws.unified import UnifiedController, UnifiedMemory
from controller_service.registry import build_controller, resolved_controller_table
from hil.bundled import resolve_scenario
from hil.scenario import load_scenario
from hil.sim import simulate_batch

CONTEXT = DesignContext()
STATE = RobotState(0.0, 0.3, 0.1, 0.0, 0.0)
AT_REST = ReferenceSample(0.0, 0.0, 0.0, 0.0, 0.0)
MOVING = ReferenceSample(0.0, 0.0, 0.0, 0.5, 0.2)


def test_default_is_the_papers_law_and_the_option_wraps_it():
    assert type(build_controller({}, CONTEXT)) is UnifiedController
    law = build_controller({"eta_rearm": True, "eta_rearm_dwell": 2.0}, CONTEXT)
    assert isinstance(law, EtaRearmController) and law.name == "unified"
    table = resolved_controller_table(law)
    assert table["eta_rearm"] is True and table["eta_rearm_dwell"] == 2.0
    assert type(build_controller(table, CONTEXT)) is EtaRearmController  # the table rebuilds it


@pytest.mark.parametrize(
    ("table", "words"),
    [
        ({"eta_rearm": 1}, "true or false"),
        ({"eta_rearm_dwell": 2.0}, "need eta_rearm = true"),
        ({"eta_rearm": True, "eta_rearm_dwell": 0.0}, "eta_rearm_dwell must be > 0"),
        ({"eta_rearm": True, "eta_rearm_below": 1.5}, "eta_rearm_below must be in (0, 1]"),
    ],
)
def test_bad_options_are_refused_by_name(table, words):
    with pytest.raises(ValueError, match=words.replace("(", r"\(").replace("]", r"\]")):
        build_controller(table, CONTEXT)


def _run(law: EtaRearmController, refs: list[ReferenceSample], eta0: float, dt: float) -> list:
    memory = law.initial_memory()._replace(eta=eta0)
    fired = []
    for k, ref in enumerate(refs):
        out, memory = law.update(k * dt, dt, STATE, ref, memory)
        fired.append(out.telemetry["eta_rearmed"])
        assert 0.0 <= memory.eta <= 1.0
    return fired


def test_fires_once_per_stop_and_never_within_the_dwell():
    law = EtaRearmController(UnifiedController(build_controller({}, CONTEXT).params, CONTEXT), 1.0)
    # At rest eta no longer decays: one reset for the whole stop.
    assert sum(_run(law, [AT_REST] * 500, 1e-9, 0.01)) == 1
    # A reference that stops and starts every 20 ms for 5 s: eta decays while moving, yet at
    # most one reset per second of dwell (at 0, 1, 2, 3, 4 s at the most).
    flicker = [AT_REST if k % 4 < 2 else MOVING for k in range(500)]
    fired = _run(law, flicker, 1e-9, 0.01)
    times = [k * 0.01 for k, f in enumerate(fired) if f]
    assert 1 <= len(times) <= 5
    assert all(b - a >= 1.0 - 1e-9 for a, b in itertools.pairwise(times))
    # eta above the threshold is left alone (a reference at rest from the start never fires).
    assert sum(_run(law, [AT_REST] * 100, 1.0, 0.01)) == 0


def test_float_and_array_paths_agree():
    law = EtaRearmController(UnifiedController(build_controller({}, CONTEXT).params, CONTEXT))
    rng = np.random.default_rng(3)
    n = 64
    state = RobotState(*(rng.uniform(-1, 1, n) for _ in range(5)))
    rest = rng.random(n) < 0.5
    ref = ReferenceSample(
        np.zeros(n), np.zeros(n), np.zeros(n), np.where(rest, 0.0, 0.5), np.where(rest, 0.0, 0.2)
    )
    memory = RearmMemory(
        rng.uniform(0, 1, n),
        rng.uniform(-0.5, 0.5, n),
        rng.uniform(-0.5, 0.5, n),
        rng.uniform(0, 9, n),
    )
    out_a, mem_a = law.update(1.0, 1e-3, state, ref, memory)
    assert out_a.telemetry["eta_rearmed"].any() and not out_a.telemetry["eta_rearmed"].all()
    for i in range(n):

        def pick(tup, i=i):
            return type(tup)(*(float(v[i]) if np.ndim(v) else float(v) for v in tup))

        out_f, mem_f = law.update(1.0, 1e-3, pick(state), pick(ref), pick(memory))
        assert out_f.tau1 == out_a.tau1[i] and out_f.tau2 == out_a.tau2[i]
        assert out_f.telemetry["eta_rearmed"] == out_a.telemetry["eta_rearmed"][i]
        assert tuple(mem_f) == pytest.approx(tuple(float(v[i]) for v in mem_a), abs=1e-12)
    # Rejected input keeps the paper's rule: zero torque, memory unchanged.
    bad, _ = law.update(1.0, 1e-3, STATE._replace(x=float("nan")), AT_REST, RearmMemory(1, 0, 0, 0))
    assert bad.tau1 == 0.0 and bad.telemetry["nonfinite"] == 1.0
    assert isinstance(law.signals(0.0, STATE, MOVING, memory=(1.0, 0.0, 0.0, 0.0)).xi, float)
    assert UnifiedMemory(*law.initial_memory()[:3]) == UnifiedMemory(1.0, 0.0, 0.0)


STOP = 60.0  # s of circle; the bundled stop then ramps for 5 s (k1 = 0.1, k2 = 0.04)
AFTER = 30.0  # s after the reference has come to rest


def _circle_then_stop(rearm: bool) -> tuple[np.ndarray, list[str], dict]:
    """The bundled circle_then_stop at Ts = 10 ms (coarse, so that 60 s of tracking leaves a
    lateral error of about 0.28 m at the stop, and fast: about 2 s on the batch path)."""
    sc = load_scenario(resolve_scenario("paper_circle_then_stop_unified"))
    controller = {**sc.controller, **({"eta_rearm": True} if rearm else {})}
    sc = dataclasses.replace(
        sc,
        controller=controller,
        reference={**sc.reference, "stop_time": STOP},
        timing=dataclasses.replace(sc.timing, ts=0.01),
        run=dataclasses.replace(sc.run, duration=STOP + 5.0 + AFTER),
    )
    result = simulate_batch(sc, 1, record=[0])
    return result.traces[0], result.columns, result.summaries[0]


def test_after_60_s_of_tracking_the_rearm_resumes_the_stabilization_the_papers_eta_lost():
    """Without the re-arm eta is ~1e-8 at the stop and the lateral error stays where it is;
    with it eta is back to 1 once, at the end of the stop ramp, and the error decreases. The
    issue's tolerance (0.05 m, 0.05 rad within 30 s) is NOT reached with Table 1 gains: the
    law's excitation rho tanh(r - 1) sin t is of the order of the squared error, so at rest the
    paper's law removes a lateral error of 0.3 m only over minutes (docs/laws.md)."""
    rest_at = STOP + 5.0
    curves = {}
    for rearm in (False, True):
        trace, cols, summary = _circle_then_stop(rearm)
        assert summary["limits_held"]
        t = trace[:, cols.index("t")]
        pos = trace[:, cols.index("position_error")]
        eta = trace[:, cols.index("eta")]
        i0, i1 = np.searchsorted(t, rest_at), len(t) - 1
        curves[rearm] = (pos[i0], pos[i1], eta[i1])
        if rearm:
            fired = t[trace[:, cols.index("eta_rearmed")] > 0]
            assert fired.tolist() == pytest.approx([rest_at], abs=0.011)  # once, at rest
    (p0, p1, eta_end) = curves[False]
    assert eta_end < 1e-6 and p0 > 0.2
    assert abs(p1 - p0) < 0.005  # stuck: no excitation left
    (q0, q1, eta_end) = curves[True]
    assert eta_end == 1.0
    assert q0 == pytest.approx(p0, abs=1e-9)  # the same loop up to the reset
    assert q1 < q0 - 0.03  # the lateral error is being removed again
