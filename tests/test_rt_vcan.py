"""The pair over a real SocketCAN vcan0 (the QEMU guest lane, or a native Linux with vcan).

Python runs ~25x slower in the guest, so the loop runs at 50 Hz: the plant applies the torques
it receives as Set_Input_Torque frames on vcan0 (drive lifecycle honoured), Zenoh carries State.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from hil.bundled import bundled_path
from hil.scenario import load_scenario
from tests.run_helpers import check_certified_bound, hil_run

pytestmark = [pytest.mark.vcan, pytest.mark.realtime, pytest.mark.timeout(900)]


def test_pair_over_socketcan_vcan0_at_50hz(tmp_path):
    # The emulated guest stalls a process for longer than a real drive's 0.5 s heartbeat
    # timeout now and then; a fault there would only re-arm the drives, so relax it.
    scenario = str(tmp_path / "tracking_slow_host.toml")
    text = bundled_path("paper_tracking").read_text()
    Path(scenario).write_text(text + "\n[can]\nheartbeat_timeout = 5.0\n")
    s = hil_run(
        tmp_path / "run",
        scenario,
        "--rate",
        "50",
        "--duration",
        "6",
        "--cmd-path",
        "can",
        "--can-interface",
        "socketcan",
        "--can-channel",
        "vcan0",
        timeout=800,
        # At 50 Hz, with the guest's delays, the sampled-data bound on omega exceeds phi2: the
        # run may break |omega| <= phi2 (exit 1); it must stay within the bound below.
        ok_codes=(0, 1),
    )
    can = s["messages"]["torque_can"]
    # Torques reached the plant as frames on vcan0 and were applied (the guest is slow and
    # may re-arm a drive after a late heartbeat, so not every cycle's pair lands).
    assert can["received"] > 100, can
    assert s["timing"]["sample_to_apply_can"]["count"] > 100
    check_certified_bound(s, scenario)
    sc = load_scenario(scenario)
    assert s["violations"]["tau1"] == 0 and s["violations"]["tau2"] == 0
    if s["_exit_code"] == 1:
        # Exit 1 here has one allowed reason: |v| or |omega| beyond phi at 50 Hz, within the
        # bound at the measured D (checked above), which then must exceed phi itself.
        assert s["certificate"]["v_bound"] > sc.limits.phi1 or (
            s["certificate"]["omega_bound"] > sc.limits.phi2
        ), s["certificate"]
