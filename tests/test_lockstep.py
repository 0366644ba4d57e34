"""Lockstep over real Zenoh between two real processes equals the offline simulator to 1e-9."""

from __future__ import annotations

import numpy as np
import pytest

from hil.bundled import bundled_path
from hil.scenario import load_scenario
from hil.sim.core import simulate
from tests.run_helpers import PASSES, hil_run

COLUMNS = ("t", "x", "y", "theta", "v", "omega", "tau1", "tau2", "tau1_cmd", "tau2_cmd")


def _run(tmp_path, *args: str) -> dict:
    """A lockstep run: its timing is the scenario's, simulated (D = ts + delay + jitter, well
    under D*), so its verdict is PASS wherever it runs."""
    return hil_run(tmp_path / "run", *args, expect=PASSES)


@pytest.mark.realtime
def test_lockstep_over_zenoh_equals_offline_simulator(tmp_path):
    duration = 0.6
    summary = _run(
        tmp_path,
        "paper_tracking",  # a bundled scenario, by name
        "--lockstep",
        "--no-can",
        "--duration",
        str(duration),
    )
    sc = load_scenario(bundled_path("paper_tracking"))
    sim = simulate(sc.with_overrides(duration=duration))
    run = np.genfromtxt(tmp_path / "run" / "trace.csv", delimiter=",", names=True)
    assert len(run) == sim.trace.shape[0] == 600
    for name in COLUMNS:
        diff = np.max(np.abs(run[name] - sim.column(name)))
        assert diff <= 1e-9, f"{name} differs by {diff}"
    # The torques moved (the comparison is not between two idle robots).
    assert np.max(np.abs(run["tau2"])) > 1.0
    assert summary["max_abs_v"] == pytest.approx(sim.summary["max_abs_v"], abs=1e-9)
    assert summary["violations"] == sim.summary["violations"]
    assert summary["messages"]["state"]["lost"] == 0


@pytest.mark.realtime
def test_lockstep_with_delay_and_jitter_equals_simulator(tmp_path):
    scen = tmp_path / "delayed.toml"
    text = (
        bundled_path("paper_tracking")
        .read_text()
        .replace(
            "[timing]\nts = 0.001", "[timing]\nts = 0.002\ndelay = 0.003\njitter = 0.001\nseed = 7"
        )
    )
    scen.write_text(text)
    timing = load_scenario(scen).timing  # the replacement took: the run is the delayed one
    assert (timing.ts, timing.delay, timing.jitter, timing.seed) == (0.002, 0.003, 0.001, 7)
    _run(tmp_path, str(scen), "--lockstep", "--no-can", "--duration", "0.4")
    sim = simulate(load_scenario(scen).with_overrides(duration=0.4))
    run = np.genfromtxt(tmp_path / "run" / "trace.csv", delimiter=",", names=True)
    assert len(run) == sim.trace.shape[0]
    for name in COLUMNS:
        assert np.max(np.abs(run[name] - sim.column(name))) <= 1e-9, name
