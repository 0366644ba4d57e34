"""``hil run --lab``: the controller and the plant on different lab hosts whose clocks differ by
seconds, through the hosts' routers; the cross-host figures corrected by the clock offset
estimate, D measured on the plant's clock alone. A clean run (tests/scenario_text.py
``CLEAN_50HZ``: 50 Hz, D* = 498 ms, nothing injected) must PASS there too, within the clean
run's bounds (tests/run_helpers.py ``clean_bounds``) widened by the clock relation's
uncertainty where a figure relates the two clocks."""

from __future__ import annotations

import json

import pytest

from tests.lab_helpers import lab, lab_name, lab_skip_reason
from tests.run_helpers import CLEAN_DURATION_S, PASSES, check_clean_run, clean_scenario, hil_run
from tests.scenario_text import CLEAN_RATE_HZ

pytestmark = pytest.mark.skipif(lab_skip_reason() is not None, reason=lab_skip_reason() or "")
OFFSET_S = {"h1": 3.2, "h2": -1.7}


def test_a_clean_two_host_run_passes_with_its_hops_corrected(tmp_path):
    name = lab_name("r")
    out = tmp_path / "run"
    scenario = clean_scenario(tmp_path)
    offsets = [f"--offset={h}={o}" for h, o in OFFSET_S.items()]
    with lab(name, "--hosts", "2", *offsets):
        args = ["--lab", name, "--plant-host", "h1", "--controller-host", "h2", "--no-can"]
        summary = hil_run(out, str(scenario), *args, "--duration", str(CLEAN_DURATION_S),
                          expect=PASSES, timeout=180)  # fmt: skip
    topo = json.loads((out / "topology.json").read_text())
    assert topo["processes"] == {"plant": "h1", "controller": "h2", "recorder": "h1"}
    assert topo["router_hops"]["command"] == ["router@h2", "router@h1"]
    clock = topo["clock"]
    injected_ns = (OFFSET_S["h1"] - OFFSET_S["h2"]) * 1e9
    assert clock["related"] and clock["converted"]
    assert abs(clock["offset_ns_median"] - injected_ns) <= clock["uncertainty_ns_max"]
    # The loop closed through the routers: every command reached the plant.
    torque = summary["messages"]["torque_zenoh"]
    assert torque["sent"] >= 0.9 * CLEAN_DURATION_S * CLEAN_RATE_HZ, torque
    assert torque["received"] == torque["sent"], torque
    # Uncorrected, a hop across these hosts would read -4.9 s or +4.9 s: corrected, each is a
    # flight (positive, as a flight must be: the median well above the clock's uncertainty)
    # within the clean run's bounds and the uncertainty of the clocks' relation.
    t = summary["timing"]
    for figure in ("hop_state", "hop_cmd_zenoh"):
        assert t[figure]["p50_us"] > 0, (figure, t[figure])
    assert summary["certificate"]["path"] == "zenoh"  # D on the plant's clock alone
    check_clean_run(summary, "zenoh", out, clock_us=clock["uncertainty_ns_max"] / 1e3)
