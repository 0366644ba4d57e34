"""The offline simulator: batch equals single, determinism, delay and reordering, run folder,
a user controller by import path, Ctrl-C keeps what was computed."""

from __future__ import annotations

import json
import math
import tomllib
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from controller_service.laws.base import ControlOutput, DesignContext, ReferenceSample, RobotState
from hil.cli import main
from hil.scenario import build_loop, loads_scenario
from hil.sim import RobotVariation, jitter_samples_from, simulate, simulate_batch, write_run_folder
from runtime.mathns import namespace_for
from tests.scenario_text import NEAR, circle


def tracking(duration: float) -> str:
    return circle(NEAR, run={"duration": duration})


class SaturatedPD:
    """A user controller for tests: a saturated PD on the tracking errors (no memory)."""

    name = "saturated_pd"

    def __init__(self, params: Mapping[str, Any], context: DesignContext) -> None:
        self.kp = float(params.get("kp", 2.0))
        self.varpi1 = context.limits.varpi1
        self.varpi2 = context.limits.varpi2

    def initial_memory(self, n: int | None = None, z1: float = 0.0, z2: float = 0.0) -> Any:
        return None

    def update(
        self, t: float, dt: float, state: RobotState, ref: ReferenceSample, memory: Any
    ) -> tuple[ControlOutput, Any]:
        ns = namespace_for(*state, *ref)
        ex, ey = ref.xd - state.x, ref.yd - state.y
        along = ex * ns.cos(state.theta) + ey * ns.sin(state.theta)
        heading = ns.atan2(ns.sin(ref.thetad - state.theta), ns.cos(ref.thetad - state.theta))
        tau1 = ns.clip(self.kp * along + 2.0 * (ref.vd - state.v), -self.varpi1, self.varpi1)
        tau2 = ns.clip(self.kp * heading + 2.0 * (ref.wd - state.omega), -self.varpi2, self.varpi2)
        return ControlOutput(tau1, tau2, {"along": along}), memory


class SequenceEcho:
    """Commands a torque that encodes the sample index, to see which command is applied."""

    name = "sequence_echo"

    def __init__(self, params: Mapping[str, Any], context: DesignContext) -> None:
        self.ts = float(params.get("ts", 0.001))

    def initial_memory(self, n: int | None = None, z1: float = 0.0, z2: float = 0.0) -> Any:
        return None

    def update(self, t, dt, state, ref, memory):  # type: ignore[no-untyped-def]
        k = round(t / self.ts)
        return ControlOutput(1e-3 * k, 0.0, {}), memory


def _scenario(extra: str = "", duration: float = 2.0, tmp: Path | None = None):  # type: ignore[no-untyped-def]
    return loads_scenario(tracking(duration) + extra, tmp)


MIXED = """
[disturbance]
kind = "random"
s1 = 0.2
s2 = 0.5
period = 0.0137
seed = 4
[plant]
noise_std = [0.001, 0.001, 0.002, 0.005, 0.005]
noise_seed = 9
lag = 0.002
[timing]
ts = 0.002
delay = 0.0005
jitter = 0.003
jitter_kind = "uniform"
seed = 5
"""


@pytest.mark.parametrize("law", ["unified", "unified_boundary", "jiang1997"])
def test_batch_equals_single_runs(law: str) -> None:
    extra = MIXED + f'[controller]\nlaw = "{law}"\n'
    sc = _scenario(extra, duration=1.5)
    variations = [
        RobotVariation(),
        RobotVariation(x=-0.5, y=0.3, theta=-0.2, jitter_seed=11, disturbance_seed=12),
        RobotVariation(delay=0.0, jitter=0.0, sensor_seed=3),
        RobotVariation(delay=0.004, jitter=0.006, jitter_seed=2, v=0.2),
    ]
    batch = simulate_batch(sc, variations, record=range(4))
    for i, var in enumerate(variations):
        single = simulate(sc, var)
        assert single.columns == batch.columns
        np.testing.assert_allclose(batch.traces[i], single.trace, rtol=0, atol=1e-9)
        for key in (
            "max_abs_v",
            "max_abs_omega",
            "max_abs_tau1",
            "max_abs_tau2",
            "final_position_error",
            "rms_position_error",
        ):
            assert batch.summaries[i][key] == pytest.approx(single.summary[key], abs=1e-9)
        assert batch.summaries[i]["violations"] == single.summary["violations"]
        assert batch.summaries[i]["commands_dropped"] == single.summary["commands_dropped"]
    assert batch.summaries[3]["commands_dropped"] > 0  # jitter > ts reordered some commands


def test_deterministic_for_a_seed() -> None:
    sc = _scenario(MIXED, duration=1.0)
    a, b = simulate(sc), simulate(sc)
    assert np.array_equal(a.trace, b.trace) and a.summary == b.summary
    c = simulate(sc, RobotVariation(jitter_seed=6))
    assert not np.array_equal(a.trace, c.trace)


def test_constant_delay_applies_the_command_of_an_earlier_sample() -> None:
    law = '[controller]\nlaw = "tests.test_sim_loop:SequenceEcho"\nts = 0.001\n'
    sc = _scenario(law + "[timing]\ndelay = 0.003\n", duration=0.05)
    r = simulate(sc)
    k = np.arange(len(r.trace))
    applied = r.column("tau1")
    np.testing.assert_allclose(applied[3:], 1e-3 * (k[3:] - 3), atol=1e-15)
    assert np.all(applied[:3] == 0.0)  # nothing has landed yet: zero torque


def test_newest_command_wins_and_older_ones_are_dropped() -> None:
    law = '[controller]\nlaw = "tests.test_sim_loop:SequenceEcho"\nts = 0.001\n'
    timing = '[timing]\ndelay = 0.0\njitter = 0.004\njitter_kind = "normal"\nseed = 1\n'
    r = simulate(_scenario(law + timing, duration=0.5))
    applied_seq = np.rint(r.column("tau1") / 1e-3)
    assert np.all(np.diff(applied_seq) >= 0)  # never goes back to an older command
    assert r.summary["commands_dropped"] > 10
    lands = set(applied_seq.astype(int))
    assert len(lands) + r.summary["commands_dropped"] <= len(r.trace)


def test_replay_latencies_from_file(tmp_path: Path) -> None:
    (tmp_path / "lat.json").write_text(json.dumps([0.002, 0.0, 0.001]))
    (tmp_path / "lat.csv").write_text("latency\n0.002\n0.0\n0.001\n")
    assert list(jitter_samples_from(tmp_path / "lat.csv")) == [0.002, 0.0, 0.001]
    law = '[controller]\nlaw = "tests.test_sim_loop:SequenceEcho"\nts = 0.001\n'
    timing = '[timing]\njitter_kind = "replay"\nreplay = "lat.json"\n'
    r = simulate(_scenario(law + timing, duration=0.02, tmp=tmp_path))
    assert r.summary["commands_dropped"] > 0
    (tmp_path / "bad.json").write_text("[-1]")
    bad = _scenario(law + timing.replace("lat.json", "bad.json"), duration=0.02, tmp=tmp_path)
    from hil.errors import BadInputError

    with pytest.raises(BadInputError, match="replay"):
        simulate(bad)


def test_user_controller_by_import_path_runs_and_folder_is_complete(tmp_path: Path) -> None:
    scen = tmp_path / "pd.toml"
    scen.write_text(
        tracking(3.0) + '[controller]\nlaw = "tests.test_sim_loop:SaturatedPD"\nkp = 3.0\n'
    )
    out = tmp_path / "run"
    assert main(["sim", str(scen), "--out", str(out), "--duration", "2", "--ts", "0.002"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    for key in (
        "schema_version",
        "final_position_error",
        "final_heading_error",
        "rms_position_error",
        "max_abs_v",
        "max_abs_omega",
        "max_abs_tau1",
        "max_abs_tau2",
        "violations",
    ):
        assert key in summary
    assert -math.pi < summary["final_heading_error"] <= math.pi
    assert summary["samples"] == 1000 and summary["plant_steps"] == 10000
    header = (out / "trace.csv").read_text().splitlines()[0].split(",")
    assert header[:13] == [
        "t",
        "x",
        "y",
        "theta",
        "v",
        "omega",
        "xd",
        "yd",
        "thetad",
        "tau1",
        "tau2",
        "tau1_cmd",
        "tau2_cmd",
    ]
    assert "along" in header
    resolved = tomllib.loads((out / "scenario.resolved.toml").read_text())
    assert resolved["controller"]["kp"] == 3.0 and resolved["timing"]["ts"] == 0.002
    assert resolved["run"]["duration"] == 2.0 and "provenance" in resolved


def test_broken_limit_gives_exit_1(tmp_path: Path) -> None:
    scen = tmp_path / "j7.toml"
    scen.write_text(tracking(4.0) + '[controller]\nlaw = "jiang1997"\n')
    assert main(["sim", str(scen), "--out", str(tmp_path / "o")]) == 1
    summary = json.loads((tmp_path / "o" / "summary.json").read_text())
    assert summary["violations"]["v"] > 0 and summary["max_abs_v"] > 1.6


def test_ctrl_c_keeps_what_was_computed(tmp_path: Path) -> None:
    sc = _scenario(duration=5.0)

    def stop_at(k: int, total: int) -> None:
        if k >= 1000:
            raise KeyboardInterrupt

    r = simulate(sc, progress=stop_at)
    assert r.interrupted and r.summary["interrupted"]
    assert 1000 <= len(r.trace) < 5000 and r.summary["samples"] == len(r.trace)
    write_run_folder(r, tmp_path / "partial")
    rows = (tmp_path / "partial" / "trace.csv").read_text().splitlines()
    assert len(rows) == len(r.trace) + 1


def test_batch_of_identical_robots_agrees_and_scales() -> None:
    sc = _scenario(duration=0.5)
    b = simulate_batch(sc, 64)
    finals = {round(s["final_position_error"], 12) for s in b.summaries}
    assert len(finals) == 1 and len(b.summaries) == 64


def test_a_loop_started_at_t0_runs_the_reference_and_the_law_from_there(tmp_path: Path) -> None:
    """simulate(t0=): the ideal trajectory of a run whose first sample came late."""
    sc = loads_scenario(tracking(0.2), tmp_path)
    late = simulate(sc, t0=0.5)
    t = late.column("t")
    assert t[0] == 0.5 and t[1] == pytest.approx(0.5 + sc.timing.ts)
    _, reference, _ = build_loop(sc)
    ref = reference.sample(0.5)
    assert late.column("xd")[0] == ref.xd and late.column("yd")[0] == ref.yd
    assert late.column("x")[0] == sc.initial.x  # the initial state is the state at t0
    # the same loop from t0 = 0 differs (the reference has moved on), and t0 = 0 is the default
    assert not np.allclose(late.column("xd"), simulate(sc).column("xd"))
    assert np.array_equal(simulate(sc, t0=0.0).trace, simulate(sc).trace)
