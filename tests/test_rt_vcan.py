"""The pair over a real SocketCAN vcan0 (the QEMU guest lane, or a native Linux with vcan).

Python runs ~25x slower in the guest, so the loop runs at 50 Hz: the plant applies the torques
it receives as Set_Input_Torque frames on vcan0 (drive lifecycle honoured), Zenoh carries State.
"""

from __future__ import annotations

import pytest

from tests.run_helpers import (
    PASSES,
    check_certified_bound,
    clean_scenario,
    fails,
    hil_run,
    inconclusive,
)

# Enough commands for the hop's statistics; the slowest guest seen sent 65 in 6 s.
MIN_COMMANDS = 40
#: The guest runs Python ~25x slower than its host (TCG): the loop misses slots (each a sample
#: without a command), stalls of a second age a command past D* (seen: D = 1.7 s, the
#: controller 1.07 s late), and its slow controller misses a few States (seen: 8 of 257; the
#: CAN frames, checked below, none). The guest's timing is not the system's under test here:
#: its verdict is PASS, or those, each count explained by the run's own logs; never a frame
#: matched to another torque, never a torque limit, and a velocity limit only past D*: (2)
#: holds for D <= D*, beyond it only the sampled-data bound at the measured D (a slow host's
#: guest: D = 981 ms > D* = 498 ms, |omega| 5 % past phi2, within the bound at D).
_GUEST_KINDS = ("deadline_misses", "samples_without_command", "certificate_system",
                "certificate_unknown_stall", "bench_stalled", "lost_messages")  # fmt: skip
GUEST = (
    PASSES,
    fails(also=_GUEST_KINDS),
    fails("certificate_system", "limits", also=_GUEST_KINDS),
    # the guest's plant woke late: the samples it left without a command are the bench's
    inconclusive(also=_GUEST_KINDS),
)

pytestmark = [pytest.mark.vcan, pytest.mark.realtime, pytest.mark.timeout(900)]


def test_pair_over_socketcan_vcan0_at_50hz(tmp_path):
    # A clean 50 Hz loop (CLEAN_50HZ: D* = 498 ms). The emulated guest stalls a process for
    # longer than a real drive's 0.5 s heartbeat timeout now and then; a fault there would only
    # re-arm the drives, so relax it.
    scenario = str(clean_scenario(tmp_path, "\n[can]\nheartbeat_timeout = 5.0\n"))
    args = ["--duration", "10", "--cmd-path", "can", "--can-interface", "socketcan"]
    s = hil_run(tmp_path / "run", scenario, *args, "--can-channel", "vcan0", timeout=800,
                expect=GUEST)  # fmt: skip
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
    # none dropped unexplained. The latency figure counts the changes of the command in force
    # (every wheel's frame of it landed, newest wins) whose sample is in the window: at most one
    # per command applied, or sent after the message window closed (its sample inside the
    # window, its frames put in the last settle period: CI saw 470 against 469 applied).
    assert can["refused_by_drive"] == 0 and can["unaccounted"] == 0, can
    assert can["applied"] + can["arrived_after_plant_stopped"] == can["received"], can
    landed_changes = s["timing"]["sample_to_apply_can"]["count"]
    assert 0 < landed_changes <= can["applied"] + can["sent_after_window"], can
    check_certified_bound(s, scenario)
    cert = s["certificate"]
    past = cert["d_max_s"] > cert["d_star_s"]
    broken = {k for k, n in s["violations"].items() if n}
    assert broken <= ({"v", "omega"} if past else set()), (s["violations"], cert["d_max_s"])
