"""The worst-disturbance search (hil.sim.adversary): its loop is the simulator's loop, each mode is
the bang-bang it names, and, over more than 10,000 adversarial loops, nothing breaks (2) below
the certificate's D* while the same search does break it above (the soundness check of the
sampled-data bound, docs/sampled_data_bound.md)."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from controller_service.certificate import certify, critical_age
from hil.cli import main
from hil.scenario import build_loop, loads_scenario
from hil.sim import RobotVariation, simulate_batch
from hil.sim.adversary import MODES, Schedule, run_loops, scenario_schedule, worst_disturbance
from hil.sim.adversary.loop import LOST, initial_states
from plant_emulator.dynamics import PlantState
from tests.scenario_text import NEAR, circle

# The paper's limits, circle and gains but rho = 0.5, so that (12) holds with disturbance bounds
# s1 = 0.3, s2 = 3 (tests/test_certified_bound_montecarlo.py's set-up): D* = 44.9 ms.
DISTURBANCE = {"s1": 0.3, "s2": 3.0}
TIMING = {"ts": 0.02, "delay": 0.02, "jitter": 0.004}
CONTROLLER = {"law": "unified", "rho": 0.5}
RUN = {"duration": 3.0}
TEXT = circle(
    NEAR, controller=CONTROLLER, disturbance={"kind": "constant", **DISTURBANCE},
    timing=TIMING, run=RUN,
)  # fmt: skip
SCENARIO = loads_scenario(TEXT)


def _with(**timing) -> object:
    return dataclasses.replace(SCENARIO, timing=dataclasses.replace(SCENARIO.timing, **timing))


@pytest.mark.parametrize("noise", [0.0, 0.01], ids=["exact", "noisy_sensor"])
def test_without_disturbance_the_loop_is_the_simulators(noise):
    sc = _with(jitter_kind="uniform")
    sc = dataclasses.replace(sc, plant=dataclasses.replace(sc.plant, noise_std=(noise,) * 5))
    n = 6
    seeds = np.arange(n) % 3
    init = initial_states(sc, n, 0.3, 4)
    schedule = scenario_schedule(sc, n, seeds + sc.timing.seed)
    peaks = run_loops(sc, schedule, np.zeros((n, 2, 4), dtype=np.int8), init)
    variations = [
        RobotVariation(
            x=init.x[i],
            y=init.y[i],
            theta=init.theta[i],
            v=init.v[i],
            omega=init.omega[i],
            jitter_seed=int(seeds[i] + sc.timing.seed),
        )
        for i in range(n)
    ]
    no_d = dataclasses.replace(sc, disturbance=dataclasses.replace(sc.disturbance, s1=0.0, s2=0.0))
    ref = simulate_batch(no_d, variations).summaries
    assert peaks.max_abs_v == pytest.approx([s["max_abs_v"] for s in ref], rel=1e-12)
    assert peaks.max_abs_omega == pytest.approx([s["max_abs_omega"] for s in ref], rel=1e-12)


def test_the_scenarios_own_disturbance_is_the_simulators():
    sc = dataclasses.replace(
        _with(jitter=0.0),
        disturbance=dataclasses.replace(SCENARIO.disturbance, kind="random", period=0.05),
    )
    n = 5
    init = initial_states(sc, n, 0.3, 2)
    seeds = 10 + np.arange(n, dtype=np.int64)
    modes = np.zeros((n, 2, 1), dtype=np.int8)
    peaks = run_loops(sc, scenario_schedule(sc, n), modes, init, own_seeds=seeds)
    variations = [
        RobotVariation(
            x=init.x[i],
            y=init.y[i],
            theta=init.theta[i],
            v=init.v[i],
            omega=init.omega[i],
            disturbance_seed=int(seeds[i]),
        )
        for i in range(n)
    ]
    ref = simulate_batch(sc, variations).summaries
    assert peaks.max_abs_v == pytest.approx([s["max_abs_v"] for s in ref], rel=1e-12)
    assert peaks.max_abs_omega == pytest.approx([s["max_abs_omega"] for s in ref], rel=1e-12)


@pytest.mark.parametrize(
    ("mode", "v_end", "w_end"),
    [
        ("none", 1.0, 0.1),
        ("aligned", 0.7, 2.9),  # v' = 1 - 0.3, omega' = 0.1 - 3
        ("with_command", 1.3, 3.1),
        ("outward", 1.0 + 0.3 * 0.99, 0.1 + 3.0 * 0.99),  # sign(0) = 0 over the first 10 ms
    ],
)
def test_each_mode_is_the_bang_bang_it_names(mode, v_end, w_end):
    """A law pushing tau1 = +1, tau2 = 0.1 for 1 s from rest, s1 = 0.3, s2 = 3: d against the
    command, along it, or outward (along v, omega once they are positive)."""
    sc = dataclasses.replace(
        _with(ts=0.01, delay=0.0, jitter=0.0),
        controller={"law": "tests.margin_user_law:ConstantPush", "push": 1.0},
        run=dataclasses.replace(SCENARIO.run, duration=1.0),
        initial=dataclasses.replace(SCENARIO.initial, v=0.0, omega=0.0),
    )
    i = MODES.index(mode)
    peaks = run_loops(
        sc, scenario_schedule(sc, 1), np.full((1, 2, 1), i, np.int8), initial_states(sc, 1, 0, 0)
    )
    assert peaks.max_abs_v[0] == pytest.approx(v_end, rel=1e-9)
    assert peaks.max_abs_omega[0] == pytest.approx(w_end, rel=1e-9)


def _stress_states(n: int, seed: int) -> tuple[PlantState, object]:
    """Half the loops from around the scenario's start, half 20 m behind the circle's start with
    z1(0) = -m1: alpha_v then sits at its bound mu1 + m1, the proof's worst case."""
    controller = build_loop(SCENARIO)[0]
    rng = np.random.default_rng(seed)
    init = initial_states(SCENARIO, n, 0.5, seed)
    far = np.arange(n) % 2 == 1
    x = np.where(far, -20.0, init.x)
    y = np.where(far, rng.uniform(-0.5, 0.5, n), init.y)
    th = np.where(far, rng.uniform(-0.2, 0.2, n), init.theta)
    state = PlantState(x, y, th, init.v, init.omega, np.zeros(n), np.zeros(n))
    memory = controller.initial_memory(n)
    memory = memory._replace(z1=np.where(far, -0.5, memory.z1))
    return state, memory


def _search(sc, n: int, rounds: int, seed: int):
    schedule = scenario_schedule(sc, n, sc.timing.seed + np.arange(n) % 7)
    state, memory = _stress_states(n, seed)
    best = worst_disturbance(sc, schedule, state, rounds=rounds, seed=seed, memory=memory)
    return schedule, best


@pytest.mark.parametrize(
    ("controller", "d_star_expected"),
    [
        ({"law": "unified", "rho": 0.5}, 0.0449),
        # (19): the push threshold b1 = eps1 s1 / varpi1 moves the bound (section 2).
        ({"law": "unified_boundary", "rho": 0.5, "eps1": 0.1, "eps2": 0.5}, 0.0443),
    ],
    ids=["sign", "boundary_layer"],
)
def test_no_break_below_d_star_in_10000_adversarial_loops(controller, d_star_expected):
    sc = dataclasses.replace(SCENARIO, controller=controller)
    law, _ref, context = build_loop(sc)
    boundary = controller["law"] == "unified_boundary"
    d_star = critical_age(law.params, context, boundary, v0=0.5, w0=0.5)
    assert d_star == pytest.approx(d_star_expected, abs=2e-4)
    n, rounds = 2500, 4
    schedule, best = _search(sc, n, rounds, seed=1)
    age = schedule.max_age()
    assert 0.9 * d_star <= age <= d_star  # just below D*, landing rounded to the plant step
    assert best.loops >= 10_000
    cert = certify(law.params, context, age, 0.0, boundary, v0=0.5, w0=0.5)
    assert not best.broke, best.as_dict()
    # Not only inside (2): inside the bound the certificate proves at that age.
    assert best.peaks["max_abs_v"] <= cert.v_bound and best.peaks["max_abs_omega"] <= cert.w_bound
    if not boundary:
        # And it finds the proof's worst case: |v| comes within 10% of the certified excess
        # over the alpha bound mu1 + m1 = 1 (the sign law's v bound is tight, section 2).
        assert best.peaks["max_abs_v"] - 1.0 >= 0.9 * (cert.v_bound - 1.0)


def test_the_same_search_breaks_the_limits_beyond_d_star_and_beats_random():
    sc = _with(ts=0.05, delay=0.05, jitter=0.0)  # age 0.1 s, 2.2 D*
    _schedule, best = _search(sc, 400, 3, seed=2)
    assert best.broke and best.limit == "|omega|"
    random = dataclasses.replace(
        sc,
        disturbance=dataclasses.replace(sc.disturbance, kind="random", period=0.1),
    )
    state, memory = _stress_states(400, 2)
    variations = [
        RobotVariation(
            x=state.x[i],
            y=state.y[i],
            theta=state.theta[i],
            v=state.v[i],
            omega=state.omega[i],
            disturbance_seed=i,
        )
        for i in range(400)
    ]
    rand = simulate_batch(random, variations, memory=memory).summaries
    worst_random = max(max(s["max_abs_v"] / 1.6, s["max_abs_omega"] / 5.1) for s in rand)
    assert best.score > worst_random


def test_sweep_worst_disturbance_breaks_no_later_than_random(tmp_path):
    path = tmp_path / "dist.toml"
    random = {"kind": "random", **DISTURBANCE, "period": 0.1}
    path.write_text(circle(NEAR, controller=CONTROLLER, disturbance=random, timing=TIMING, run=RUN))
    grid = ["--ts", "0.05", "--delay", "0,0.05", "--duration", "2"]
    assert main(["sweep", str(path), "--out", str(tmp_path / "r"), *grid, "--seeds", "8"]) == 0
    out = tmp_path / "w"
    assert main(["sweep", str(path), "--out", str(out), *grid, "--worst-disturbance"]) == 0
    worst = json.loads((out / "sweep.json").read_text())
    rand = json.loads((tmp_path / "r" / "sweep.json").read_text())
    assert worst["disturbance"] == "worst searched"

    def peak(doc, delay):
        rows = [r for r in doc["rows"] if r["delay"] == delay]
        return max(max(r["overshoot_v"], r["overshoot_omega"]) for r in rows)

    for delay in (0.0, 0.05):
        assert peak(worst, delay) >= peak(rand, delay)
    broke = [r for r in worst["rows"] if r["violation"]]
    assert broke and all("worst of 192 loops" in r["disturbance"] for r in broke)


def test_schedule_age_counts_lost_commands_and_the_start():
    land = np.array([[2, LOST, 1, 0]])
    sched = Schedule(0.01, 0.001, land, np.zeros(1, np.intp))
    # Samples at steps 0, 10, 20, 30 land at 2, (lost), 21, 30: in force 0 from 0..2 (age 2),
    # sample 0 until 21 (age 21), sample 20 until 30 (age 10), sample 30 until 40 (age 10).
    assert sched.max_age() == pytest.approx(0.021)
