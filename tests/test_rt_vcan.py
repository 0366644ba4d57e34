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

# Enough commands for the hop's statistics; the slowest guest seen sent 65 in 6 s.
MIN_COMMANDS = 40

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
        "10",
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
    # Torques reached the plant as frames on vcan0 and every one was applied. How many the
    # controller sends depends on the guest's speed, not on the code under test: in the
    # emulated guest it misses slots (counted as skipped) and the drives arm seconds after
    # the epoch, so 83 to 116 of the 300 slots of a 6 s run carried one here, and 65 in a
    # slower CI guest. What must hold is that none of those sent is lost, and that enough
    # are sent to measure the hop.
    assert can["sent"] >= MIN_COMMANDS, (can, s["timing"]["skipped_slots"])
    assert can["received"] == can["sent"] and can["lost"] == 0, can
    assert can["frames_received"] == can["frames_sent"] and can["value_mismatches"] == 0, can
    # Every received command was applied, or came after the plant's last sample (a guest stall
    # longer than 2 Ts between send and receive at the window's end; CI saw one): none refused,
    # none dropped unexplained, and the latency figure covers every one applied.
    assert can["refused_by_drive"] == 0 and can["unaccounted"] == 0, can
    assert can["applied"] + can["arrived_after_plant_stopped"] == can["received"], can
    assert s["timing"]["sample_to_apply_can"]["count"] >= can["applied"]
    check_certified_bound(s, scenario)
    sc = load_scenario(scenario)
    assert s["violations"]["tau1"] == 0 and s["violations"]["tau2"] == 0
    if s["_exit_code"] == 1:
        # Exit 1 here has one allowed reason: |v| or |omega| beyond phi at 50 Hz, within the
        # bound at the measured D (checked above), which then must exceed phi itself.
        assert s["certificate"]["v_bound"] > sc.limits.phi1 or (
            s["certificate"]["omega_bound"] > sc.limits.phi2
        ), s["certificate"]
