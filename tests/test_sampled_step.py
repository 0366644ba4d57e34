"""One sampled-data step (hold, delayed landing, RK4 to the next event) for every user.

The same delayed, reordering scenario (Ts = 2 ms, delay 3 ms, jitter 3 ms: commands overtake
each other and some are dropped; a sine disturbance, so the plant's clock matters) runs through
the single-run simulator, the batch simulator (robots landing together and apart) and the plant
emulator's lockstep period fed the simulator's commands. The emulator must reproduce the
simulator's states and applied torques exactly (bit for bit), the batch path to rounding.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import hil.sim.core as sim_core
import plant_emulator.sampled as sampled
import plant_emulator.service as service
from hil.bundled import bundled_path
from hil.scenario import load_scenario
from hil.sim.core import RobotVariation, simulate, simulate_batch
from plant_emulator.dynamics import Extremes, PlantState, track_initial
from plant_emulator.landing import extra_delays, landing_offsets
from plant_emulator.sampled import Hold
from plant_emulator.service import PlantCore

STATE = ("x", "y", "theta", "v", "omega")


@pytest.fixture(scope="module")
def scenario():
    sc = load_scenario(bundled_path("paper_tracking")).with_overrides(duration=0.4)
    timing = dataclasses.replace(sc.timing, ts=0.002, delay=0.003, jitter=0.003, seed=7)
    dist = dataclasses.replace(
        sc.disturbance, kind="sine", s1=0.3, s2=0.5, amplitude1=0.3, amplitude2=0.5, freq=3.0
    )
    return dataclasses.replace(sc, timing=timing, disturbance=dist)


@pytest.fixture(scope="module")
def single(scenario):
    result = simulate(scenario)
    assert result.summary["commands_dropped"] > 0  # the scenario does reorder commands
    return result


def test_the_users_bind_the_one_step() -> None:
    assert sim_core.advance_period is sampled.advance_period
    assert service.advance_period is sampled.advance_period
    assert sim_core.Hold is service.Hold is sampled.Hold


def test_plant_emulator_lockstep_period_reproduces_the_simulator_bit_for_bit(
    scenario, single
) -> None:
    i = scenario.initial
    core = PlantCore(
        PlantState(i.x, i.y, i.theta, i.v, i.omega, 0.0, 0.0),
        h=scenario.plant_step,
        limits=scenario.limits,
        disturbance=scenario.disturbance,
        lag=scenario.plant.lag,
        extremes=Extremes(),
    )
    track_initial(core.extremes, core.state, scenario.limits)
    t = scenario.timing
    n = len(single.trace)
    extra = extra_delays(t.jitter_kind, t.jitter, t.seed, n, None)
    offsets = landing_offsets(extra, t.delay, core.h).tolist()
    hold = Hold()
    cmd = np.column_stack([single.column("tau1_cmd"), single.column("tau2_cmd")])
    for k in range(n):
        row = {name: single.column(name)[k] for name in (*STATE, "tau1", "tau2")}
        assert tuple(core.state[:5]) == tuple(row[name] for name in STATE), k
        applied = core.lockstep_period(
            hold, k, scenario.substeps, offsets[k], float(cmd[k, 0]), float(cmd[k, 1])
        )
        assert applied == (row["tau1"], row["tau2"]), k
    summary = single.summary
    assert hold.dropped == summary["commands_dropped"]
    assert core.extremes.steps == summary["plant_steps"]
    assert core.extremes.max_abs_omega == summary["max_abs_omega"]


@pytest.mark.parametrize(
    "variations",
    [3, [RobotVariation(), RobotVariation(delay=0.001), RobotVariation(jitter=0.0)]],
    ids=["together", "apart"],
)
def test_batch_robots_land_and_drop_as_the_single_run(scenario, single, variations) -> None:
    batch = simulate_batch(scenario, variations, record=[0])
    np.testing.assert_allclose(batch.traces[0], single.trace, rtol=0, atol=1e-9)
    assert batch.summaries[0]["commands_dropped"] == single.summary["commands_dropped"]
    if not isinstance(variations, int):  # without jitter, in order: nothing is overtaken
        assert batch.summaries[2]["commands_dropped"] == 0
