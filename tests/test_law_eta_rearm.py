"""The unified law's eta re-arm (controller_service.laws.eta_rearm): off by default, fires once
per stop, never faster than its dwell, one source on floats and arrays, and what it does after
a 60 s tracking phase (batch simulator, no real time)."""

from __future__ import annotations

import dataclasses
import itertools
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from controller_service.laws.base import DesignContext, ReferenceSample, RobotState
from controller_service.laws.eta_rearm import (
    ALIGN_BAND,
    DWELL_DEFAULT,
    EtaRearmController,
    RearmMemory,
)
from controller_service.laws.unified import UnifiedController, UnifiedMemory
from controller_service.registry import build_controller, resolved_controller_table
from hil.bundled import resolve_scenario
from hil.commands.certify import certify_scenario
from hil.scenario import load_scenario
from hil.sim import simulate_batch
from hil.sim.core import RobotVariation

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
    kick = build_controller({"eta_rearm": True, "eta_rearm_tol": 0.02}, CONTEXT)
    assert resolved_controller_table(kick)["eta_rearm_tol"] == 0.02
    assert build_controller(resolved_controller_table(kick), CONTEXT).tol == 0.02
    assert "eta_rearm_tol" not in table  # without the key: the eta-only re-arm


@pytest.mark.parametrize(
    ("table", "words"),
    [
        ({"eta_rearm": 1}, "true or false"),
        ({"eta_rearm_dwell": 2.0}, "need eta_rearm = true"),
        ({"eta_rearm": True, "eta_rearm_dwell": 0.0}, "eta_rearm_dwell must be > 0"),
        ({"eta_rearm": True, "eta_rearm_below": 1.5}, "eta_rearm_below must be in (0, 1]"),
        ({"eta_rearm": True, "eta_rearm_tol": 0.0}, "eta_rearm_tol must be > 0 m"),
        ({"eta_rearm_tol": 0.02}, "need eta_rearm = true"),
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


def test_kick_turns_towards_the_stop_point_align_clears_a_stored_turn_all_within_the_box():
    inner = UnifiedController(build_controller({}, CONTEXT).params, CONTEXT)
    law = EtaRearmController(inner, dwell=1.0, tol=0.02)
    m1, m2 = inner.params.m1, inner.params.m2
    start = RearmMemory(0.3, 0.2, 0.1, 1.0)
    # Robot 0.3 m to the left of the stop point, heading 0.1 rad: xe, ye > 0, so z2 = -m2
    # (w ~ -z2 turns it further anticlockwise, its rear towards the point; v ~ -z1 ~ -xe then
    # backs it up along that axis).
    out, _ = law.update(0.0, 0.0, STATE, AT_REST, start)
    assert out.telemetry["eta_rearmed"] == 1.0
    assert out.telemetry["eta"] == 1.0 and out.telemetry["z1"] == 0.0
    assert out.telemetry["z2"] == -m2
    # xe ye < 0: the full kick of the other sign, whatever the size of the error.
    near = RobotState(0.05, -0.04, 0.0, 0.0, 0.0)  # |p| = 0.064 m
    out, _ = law.update(0.0, 0.0, near, AT_REST, start)
    assert out.telemetry["z2"] == m2
    # Within tol, heading within ALIGN_BAND, a turn stored in z2: the align clears z1 and z2.
    band = m2 * math.sin(0.5 * ALIGN_BAND)  # the most (8) settles at within the band
    inside = RobotState(0.01, 0.01, 0.5 * ALIGN_BAND, 0.0, 0.0)
    out, _ = law.update(0.0, 0.0, inside, AT_REST, start)
    assert out.telemetry["eta_rearmed"] == 1.0
    assert (out.telemetry["eta"], out.telemetry["z1"], out.telemetry["z2"]) == (1.0, 0.0, 0.0)
    # No kick or align within the dwell or while the reference moves; no align outside the
    # band or with no more in z2 than the band accounts for; eta-only rule intact.
    turned = inside._replace(theta=1.5 * ALIGN_BAND)
    for state, ref, memory in (
        (STATE, AT_REST, start._replace(since=0.5)),
        (inside, AT_REST, start._replace(since=0.5)),
        (STATE, MOVING, start),
        (inside, MOVING, start),
        (turned, AT_REST, start._replace(eta=0.9)),
        (inside, AT_REST, start._replace(eta=0.9, z2=0.99 * band)),
    ):
        out, _ = law.update(0.0, 0.0, state, ref, memory)
        assert out.telemetry["eta_rearmed"] == 0.0 and out.telemetry["z2"] == memory.z2
    out, _ = law.update(0.0, 0.0, turned, AT_REST, start)  # eta 0.3 < below: eta only
    assert out.telemetry["eta_rearmed"] == 1.0 and out.telemetry["eta"] == 1.0
    assert (out.telemetry["z1"], out.telemetry["z2"]) == (start.z1, start.z2)
    # Any sequence of states keeps the memory in the box the constraint proofs use.
    rng = np.random.default_rng(7)
    memory = law.initial_memory()
    for k in range(2000):
        state = RobotState(*rng.uniform(-0.05, 0.05, 2), *rng.uniform(-0.1, 0.1, 1), 0.0, 0.0)
        if rng.random() < 0.5:
            state = RobotState(*rng.uniform(-2, 2, 3), *rng.uniform(-1, 1, 2))
        ref = AT_REST if rng.random() < 0.7 else MOVING
        _, memory = law.update(k * 0.01, 0.01, state, ref, memory)
        assert 0.0 <= memory.eta <= 1.0 and abs(memory.z1) <= m1 and abs(memory.z2) <= m2


@pytest.mark.parametrize("tol", [None, 0.02, 2.0])  # 2 m: every robot within tol (align only)
def test_float_and_array_paths_agree(tol):
    inner = UnifiedController(build_controller({}, CONTEXT).params, CONTEXT)
    law = EtaRearmController(inner, tol=tol)
    rng = np.random.default_rng(3)
    n = 64
    state = RobotState(*(rng.uniform(-1, 1, n) for _ in range(5)))
    # Half the headings within ALIGN_BAND of the reference's (0), where the align can fire.
    state = state._replace(
        theta=np.where(rng.random(n) < 0.5, rng.uniform(-0.03, 0.03, n), state.theta)
    )
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
    ready = RearmMemory(0.1, 0.2, 0.3, 9.0)  # at rest, past the dwell: the rule would fire
    for field in ("x", "theta"):
        for value in (float("nan"), float("inf")):
            bad_state = STATE._replace(**{field: value})
            bad, mem = law.update(1.0, 1e-3, bad_state, AT_REST, ready)
            assert bad.tau1 == 0.0 and bad.telemetry["nonfinite"] == 1.0
            assert tuple(mem) == tuple(ready) and bad.telemetry["eta_rearmed"] == 0.0
            # On arrays, element-wise: the good robot is re-armed, the bad one left alone.
            pair = RobotState(*(np.array([g, b]) for g, b in zip(STATE, bad_state, strict=True)))
            both = RearmMemory(*(np.full(2, v) for v in ready))
            bad, mem = law.update(1.0, 1e-3, pair, AT_REST, both)
            assert bad.telemetry["nonfinite"].tolist() == [0.0, 1.0]
            assert bad.telemetry["eta_rearmed"].tolist() == [1.0, 0.0]
            assert [float(v[1]) for v in mem] == list(ready)
    assert isinstance(law.signals(0.0, STATE, MOVING, memory=(1.0, 0.0, 0.0, 0.0)).xi, float)
    assert UnifiedMemory(*law.initial_memory()[:3]) == UnifiedMemory(1.0, 0.0, 0.0)


STOP = 60.0  # s of circle; the bundled stop then ramps for 5 s (k1 = 0.1, k2 = 0.04)
REST = STOP + 5.0  # s: the reference is at rest from here on
AFTER = 30.0  # s after the reference has come to rest
TS = 0.005  # s: why this Ts, see the module fixture
KICK = {"eta_rearm": True, "eta_rearm_dwell": 2.0, "eta_rearm_tol": 0.03}
TARGET = 0.05  # m and rad: the stop is reached when both errors stay below this


def _circle_then_stop(extra: dict, duration: float) -> Any:
    sc = load_scenario(resolve_scenario("paper_circle_then_stop_unified"))
    return dataclasses.replace(
        sc,
        controller={**sc.controller, **extra},
        reference={**sc.reference, "stop_time": STOP},
        timing=dataclasses.replace(sc.timing, ts=TS),
        run=dataclasses.replace(sc.run, duration=duration),
    )


@pytest.fixture(scope="module")
def at_rest() -> tuple[np.ndarray, list[str]]:
    """The bundled circle_then_stop at Ts = 5 ms with the paper's law up to the sample at which
    the reference comes to rest (its last trace row), from the bundled initial pose and 7 others
    within 0.3 m and 0.3 rad of it (seeded): the sampled sign law is sensitive to rounding, so
    one robot alone could pass or fail by luck.

    Ts = 5 ms: 60 s of tracking leave about 0.15 m of lateral error at the stop, which the
    paper's law (eta ~ 1e-8 by then) cannot remove, while the heading limit cycle of the sign
    law sampled at 5 ms stays below 0.05 rad (about 0.03; at 10 ms it is 0.07, see the test
    below). The re-arm cannot act while the reference moves, so this tracking phase is the same
    for every law compared; it is run once and each law continues from its last row (state,
    memory, law clock): the loop continued, equal to a single run up to rounding."""
    sc = _circle_then_stop({}, REST + TS)
    moves = np.vstack([np.zeros(3), np.random.default_rng(5).uniform(-0.3, 0.3, (7, 3))])
    base = np.array([sc.initial.x, sc.initial.y, sc.initial.theta])
    robots = [RobotVariation(*(base + d)) for d in moves]
    result = simulate_batch(sc, robots, record=list(range(len(robots))))
    assert all(summary["limits_held"] for summary in result.summaries)
    rows = np.array([result.traces[i][-1] for i in range(len(robots))])
    assert rows[:, result.columns.index("t")] == pytest.approx(REST)
    return rows, result.columns


def _rest_phase(at_rest: tuple[np.ndarray, list[str]], extra: dict) -> Any:
    """AFTER seconds at rest for the law ``extra`` from the rows of ``at_rest``."""
    rows, cols = at_rest
    col = {name: rows[:, cols.index(name)] for name in cols}
    t0 = col["t"]
    robots = [
        RobotVariation(x=r[0], y=r[1], theta=r[2], v=r[3], omega=r[4])
        for r in zip(col["x"], col["y"], col["theta"], col["v"], col["omega"], strict=True)
    ]
    memory: Any = UnifiedMemory(col["eta"], col["z1"], col["z2"])
    if extra:  # the re-arm's time since the last reset: none yet, so the whole run
        memory = RearmMemory(*memory, extra.get("eta_rearm_dwell", DWELL_DEFAULT) + t0)
    sc = _circle_then_stop(extra, AFTER)
    result = simulate_batch(sc, robots, record=list(range(len(robots))), t0=t0, memory=memory)
    assert all(summary["limits_held"] for summary in result.summaries)
    return [result.traces[i] for i in range(len(robots))], result.columns


def _errors_at_end(traces: list[np.ndarray], cols: list[str]) -> np.ndarray:
    """Per robot: position and heading error 30 s after the stop and their largest values over
    the last 2 s of the 30 (the sign law keeps both in a limit cycle: one instant can flatter)."""
    out = []
    for trace in traces:
        t = trace[:, cols.index("t")]
        pos = trace[:, cols.index("position_error")]
        head = np.abs(trace[:, cols.index("heading_error")])
        last = t >= t[0] + AFTER - 2.0
        out.append((pos[-1], head[-1], pos[last].max(), head[last].max()))
    return np.array(out)


def test_after_60_s_of_tracking_kick_and_align_stabilize_at_the_stop_point_the_paper_does_not(
    at_rest,
):
    """The stop is reached within 30 s after the reference is at rest: position error < 0.05 m AND
    heading error < 0.05 rad (at 30 s and over the last 2 s) with the re-arm (kick and align,
    dwell 2 s, tol 0.03 m) for all 8 robots; the paper's law keeps its ~0.15 m. The limits (2)
    hold in every run (asserted in the fixture and in _rest_phase)."""
    rows, cols = at_rest
    stop_error = rows[:, cols.index("position_error")]
    assert np.all(stop_error > 0.1)  # what the tracking leaves at this Ts
    paper_traces, paper_cols = _rest_phase(at_rest, {})
    paper = _errors_at_end(paper_traces, paper_cols)
    assert np.all(paper[:, [0, 2]] > 0.1)  # stuck: eta ~ 1e-8, no time-varying term left
    for trace in paper_traces:
        assert trace[-1, paper_cols.index("eta")] < 1e-6
    traces, cols = _rest_phase(at_rest, KICK)
    kick = _errors_at_end(traces, cols)
    assert np.all(kick < TARGET)  # both errors, at 30 s and over the last 2 s
    for trace in traces:
        t = trace[:, cols.index("t")] - trace[0, cols.index("t")]
        fired = trace[:, cols.index("eta_rearmed")] > 0
        assert fired[0]  # at the first sample at rest
        assert np.all(np.diff(t[fired]) >= KICK["eta_rearm_dwell"] - 1e-9)
        # Kicks while |p| > tol, then one align that clears the turn still stored in z2.
        pos = trace[fired, cols.index("position_error")]
        tol = KICK["eta_rearm_tol"]
        assert 3 <= np.sum(pos > tol) <= 8 and np.sum(pos <= tol) >= 1
        assert np.all(pos[np.argmax(pos <= tol) :] <= tol)
        # Both errors within target from 25 s on (about 17 s measured).
        pos_all = trace[:, cols.index("position_error")]
        head_all = np.abs(trace[:, cols.index("heading_error")])
        late = t >= 25.0
        assert pos_all[late].max() < TARGET and head_all[late].max() < TARGET


def test_after_60_s_of_tracking_eta_alone_is_too_slow(at_rest):
    """The eta-only re-arm fires once and removes only ~0.01 m of the 0.15 m in 30 s: at rest
    the paper's xi is of the order of the squared error, so eta = 1 adds little."""
    traces, cols = _rest_phase(at_rest, {"eta_rearm": True})
    ends = _errors_at_end(traces, cols)
    stop_error = at_rest[0][:, at_rest[1].index("position_error")]
    assert np.all(ends[:, 2] > 0.1) and np.all(ends[:, 0] < stop_error)
    for trace in traces:
        assert trace[:, cols.index("eta_rearmed")].sum() == 1
        assert trace[0, cols.index("eta_rearmed")] == 1 and trace[-1, cols.index("eta")] == 1.0


@pytest.mark.parametrize(
    ("ts", "low", "high"),
    [(0.01, TARGET, 0.1), (TS, 0.015, TARGET)],
    ids=["10ms", "5ms"],
)
def test_the_sign_laws_heading_limit_cycle_at_rest_exceeds_0_05_rad_at_10_ms_not_at_5_ms(
    ts, low, high
):
    """Why no re-arm can meet 0.05 rad at Ts = 10 ms, and why the test above runs at 5 ms: the
    sign law (10) sampled at Ts moves w by varpi2 Ts per sample (0.51 rad/s at 10 ms), so at
    rest w alternates between 0 and +-varpi2 Ts and the heading turns at varpi2 Ts / 2 on
    average, one way or the other; with the z2 loop's lag this is a limit cycle of about
    +-0.07 rad at 10 ms and +-0.03 rad at 5 ms. Between resets any re-arm runs the paper's
    law, so it cannot do better. Shown from 1 cm of the stop point, eta = 1 (no re-arm needed
    at all), 30 s at rest."""
    sc = load_scenario(resolve_scenario("paper_stabilization"))
    sc = dataclasses.replace(
        sc,
        initial=dataclasses.replace(sc.initial, x=0.01, y=0.0, theta=0.0),
        timing=dataclasses.replace(sc.timing, ts=ts),
        run=dataclasses.replace(sc.run, duration=AFTER),
    )
    result = simulate_batch(sc, 1, record=[0])
    trace, cols = result.traces[0], result.columns
    last = trace[:, cols.index("t")] >= AFTER - 2.0
    assert trace[last, cols.index("position_error")].max() < 0.02
    heading = np.abs(trace[last, cols.index("heading_error")])
    assert low < heading.max() < high
    limits = build_controller({}, CONTEXT).context.limits
    step = np.abs(np.diff(trace[last, cols.index("omega")])).max()
    assert step == pytest.approx(limits.varpi2 * ts)


def test_the_certificate_is_the_papers_with_the_rearm_and_the_kick(tmp_path):
    """The bound of (2) uses the memory only through its box, which every reset keeps: `hil
    certify` accepts the re-arm keys and gives the paper's certificate."""
    bundled = resolve_scenario("paper_circle_then_stop_unified")
    keys = "eta_rearm = true\neta_rearm_dwell = 2.0\neta_rearm_tol = 0.03\n"
    path = tmp_path / "kick.toml"
    path.write_text(Path(bundled).read_text().replace("rho = 1.0\n", "rho = 1.0\n" + keys))
    assert load_scenario(path).controller["eta_rearm_tol"] == 0.03
    assert (
        certify_scenario(str(path), None, None)[0] == certify_scenario(str(bundled), None, None)[0]
    )
