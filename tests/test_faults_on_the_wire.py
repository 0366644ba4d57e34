"""Faults on the wire ([faults]), injected into real runs and found again, each seeded.

Duplicates and reorders of States and commands on Zenoh, delay bursts on the applied path,
CAN frame loss at the drives' receivers and CAN bus-off bursts at the controller: the run's
counts equal what the services injected, and the certificate's stalls name the burst faults.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from hil.bundled import bundled_path
from tests.run_helpers import Expect, fails, hil_run

pytestmark = [pytest.mark.realtime, pytest.mark.slow]
#: At 500 Hz a loaded host may add these to what the faults cause (tests/run_helpers.py
#: LOADED_HOST), each explained by the run's own logs; nothing else.
LOAD = ("deadline_misses", "bench_stalled")


def _run(tmp_path: Path, faults: str, *args: str, expect: Expect | tuple[Expect, ...]) -> dict:
    scenario = tmp_path / "scenario.toml"
    scenario.write_text(bundled_path("paper_tracking").read_text() + "\n[faults]\n" + faults)
    return hil_run(tmp_path / "run", str(scenario), "--rate", "500", "--duration", "4", *args,
                   expect=expect)  # fmt: skip


def test_duplicates_and_reorders_are_counted_as_injected(tmp_path):
    s = _run(tmp_path, "state_duplicate_every = 10\ncommand_duplicate_every = 9\n"
                       "command_reorder_every = 13\nseed = 3\n",
             # A reordered command arrives after the next one and is dropped as older: its
             # sample has no command (1 in 13, 7.7 %); duplicates change nothing.
             expect=fails("samples_without_command", also=LOAD))  # fmt: skip
    st, cmd = s["messages"]["state"], s["messages"]["torque_zenoh"]
    assert st["injected_duplicates"] > 150 and st["duplicated"] == st["injected_duplicates"]
    assert cmd["injected_duplicates"] > 150 and cmd["duplicated"] == cmd["injected_duplicates"]
    assert cmd["injected_reorders"] > 100 and cmd["reordered"] == cmd["injected_reorders"]
    # Each reordered command, dropped as older, left its sample without a command.
    assert s["timing"]["samples_without_command"] >= cmd["injected_reorders"], s["timing"]
    assert st["lost"] == 0 and cmd["lost"] == 0
    injected = s["faults"]["injected"]
    assert injected["plant"]["state_duplicates"] >= st["injected_duplicates"]
    assert injected["controller"]["command_reorders"] >= cmd["injected_reorders"]


def test_delay_bursts_are_named_in_the_stalls(tmp_path):
    s = _run(tmp_path, "delay_burst_every = 1.0\ndelay_burst_length = 0.05\n"
                       "delay_burst_extra = 0.03\nseed = 5\n",
             # 30 ms more on the applied path in each burst: D > D* = 20 ms by the system's
             # own timing (a wire's delay), and the first command after a burst overtakes the
             # delayed ones (their samples without a command, ~15 a burst: 3 %).
             expect=fails("certificate_system", "samples_without_command",
                          also=LOAD))  # fmt: skip
    assert s["faults"]["injected"]["plant"]["delay_bursts"] > 0
    stalls = s["certificate"]["stalls"]
    delayed = [st for st in stalls if st["cause"] == "command_delayed"]
    assert len(delayed) >= 3, stalls  # one burst a second over 4 s
    assert all(st["age_s"] >= 0.030 for st in delayed)


def test_can_frame_loss_and_bus_off_are_the_lost_frames_exactly(tmp_path):
    s = _run(tmp_path, "can_frame_loss = 0.02\ncan_bus_off_every = 1.0\n"
                       "can_bus_off_length = 0.05\nseed = 11\n", "--cmd-path", "can",
             # Frames lost (2 % and 50 ms of bus-off a second): lost commands, their samples
             # without one, and D > D* across a bus-off, all the system's.
             expect=fails("certificate_system", "samples_without_command", "lost_messages",
                          also=LOAD))  # fmt: skip
    can = s["messages"]["torque_can"]
    assert can["injected_frame_losses"] > 20 and can["frames_not_on_bus"] > 20, can
    assert can["frames_lost"] == can["injected_frame_losses"] + can["frames_not_on_bus"], can
    assert can["unmatched_frames_received"] == 0  # losses never shift the matching
    assert can["unaccounted"] == 0, can  # no received command dropped unexplained
    lost = [st for st in s["certificate"]["stalls"] if st["cause"] == "command_lost"]
    assert lost and any(st["evidence"].get("frames_not_on_bus", 0) > 0 for st in lost), lost
