"""Lockstep over real Zenoh between two real processes equals the offline simulator to 1e-9."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from hil.bundled import bundled_path
from hil.scenario import load_scenario
from hil.sim.core import simulate

COLUMNS = ("t", "x", "y", "theta", "v", "omega", "tau1", "tau2", "tau1_cmd", "tau2_cmd")


def _run(tmp_path, *args: str) -> dict:
    out = tmp_path / "run"
    proc = subprocess.run(
        [sys.executable, "-m", "hil", "run", *args, "--quiet", "--no-report", "--out", str(out)],
        capture_output=True,
        text=True,
        timeout=240,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    return json.loads((out / "summary.json").read_text())


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
    _run(tmp_path, str(scen), "--lockstep", "--no-can", "--duration", "0.4")
    sim = simulate(load_scenario(scen).with_overrides(duration=0.4))
    run = np.genfromtxt(tmp_path / "run" / "trace.csv", delimiter=",", names=True)
    assert len(run) == sim.trace.shape[0]
    for name in COLUMNS:
        assert np.max(np.abs(run[name] - sim.column(name))) <= 1e-9, name
