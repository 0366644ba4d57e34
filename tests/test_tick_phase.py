"""The periodic controller's tick phase (controller_service/tick_phase.py): the window's
middle from known arrivals, and a real run that learns it, moves its ticks there once and
reports it."""

from __future__ import annotations

import numpy as np
import pytest

from controller_service.tick_phase import PhaseLearner, choose_phase
from hil.analysis.measure import load_folder_logs
from hil.bundled import bundled_path
from tests.run_helpers import LOADED_HOST_CERTIFICATE, PASSES, fails, hil_run

US = 1000
P = 500 * US  # 2 kHz
RUN_P = 1000 * US  # the real run: 1 kHz


def test_the_phase_is_the_middle_of_the_window_between_arrival_and_the_commands_need():
    arrivals = np.full(1000, 200 * US)
    arrivals[-5:] = 300 * US  # the top 0.5 %: p99 stays 200 µs
    c = choose_phase(P, arrivals, np.full(1000, 100 * US), np.full(1000, 40 * US))
    # window [200, 500 - 140 = 360] µs: the middle, 280 µs
    assert (c.phase_ns, c.arrival_q_ns, c.path_q_ns, c.window_open) == (280 * US, 200 * US,
                                                                        140 * US, True)  # fmt: skip


def test_a_shut_window_and_unrelated_clocks_are_said_and_the_phase_stays_in_bounds():
    shut = choose_phase(P, np.full(50, 450 * US), np.full(50, 300 * US), np.full(50, 60 * US))
    assert not shut.window_open and shut.phase_ns == (450 + 500 - 360) * US // 2
    late = choose_phase(P, np.full(50, 480 * US), np.full(50, 5 * US), np.full(50, 5 * US))
    assert late.window_open and late.phase_ns == P - P // 8  # (480 + 490) / 2, clipped
    for arrivals in (np.full(50, -3 * US), np.full(50, 5 * P)):  # clocks seconds apart
        far = choose_phase(P, arrivals, arrivals, np.full(50, 60 * US))
        assert not far.clocks_related and far.phase_ns == P // 2


def test_the_learner_answers_once_after_enough_states_and_computes():
    learner = PhaseLearner(P, warm=3)
    for _ in range(3):
        assert learner.choice() is None
        learner.state(150 * US, 90 * US)
    assert learner.choice() is None  # no compute seen yet
    for _ in range(5):
        learner.compute(30 * US)
    assert learner.choice().phase_ns == (150 + 500 - 120) * US // 2
    assert learner.choice() is None


#: At 1 or 2 kHz the run alone can saturate a 2-core host (a fresh clone's CI: busy 98 %, run queue
#: up to 26, other processes 0.00 CPUs, the controller 50 ms without a CPU): Zenoh then drops
#: States it cannot deliver in time (93 of 4637, counted lost: the system's FAIL, as the verdict
#: says). That verdict is right and not this test's subject; its counts are still explained by
#: the run's own logs (check_verdict).
SATURATED = fails(
    "certificate_system",
    "lost_messages",
    also=("samples_without_command", "deadline_misses", "bench_stalled"),
)


@pytest.mark.realtime
def test_a_run_learns_its_phase_moves_its_ticks_there_once_and_reports_it(tmp_path):
    scenario = tmp_path / "auto.toml"
    scenario.write_text(
        bundled_path("paper_tracking").read_text() + '\n[realtime]\ntick_phase = "auto"\n'
    )
    out = tmp_path / "run"
    # The phase, not the verdict: at 1 kHz a loaded host may break the certificate through the
    # system's timing (CI at 2 kHz: D = 49 ms), which the verdict lays on the system; the phase
    # holds. 1 kHz, not 2: at 2 kHz the run alone took both cores (plant 103 %, controller 83 %
    # of a CPU), missed 29 % of its slots, and saw fewer than the learner's 2000 fresh States in
    # 3 s, so it never chose a phase. 4 s: 2 s to learn, 2 s after the move.
    s = hil_run(out, str(scenario), "--rate", "1000", "--duration", "4", "--cmd-path", "zenoh",
                expect=(PASSES, *LOADED_HOST_CERTIFICATE, SATURATED))  # fmt: skip
    phase = s["timing"]["tick_phase"]
    assert phase["rule"] == "auto" and phase["clocks_related"], phase
    assert RUN_P // 8 <= phase["phase_us"] * US <= RUN_P - RUN_P // 8
    logs = load_folder_logs(out)
    ticks, epoch = logs["ticks"], logs.epoch_ns
    # Every deadline sits at epoch + k Ts + the phase: half a period before the move, the
    # learnt phase from the slot it took effect at (whole slots: nothing skipped by it).
    offset = ticks["deadline_ns"] - epoch - ticks["k"].astype(np.int64) * RUN_P
    moved = ticks["k"] >= phase["from_tick"]
    assert moved.any() and (~moved).any()
    assert set(offset[~moved].tolist()) == {RUN_P // 2}
    assert set(offset[moved].tolist()) == {round(phase["phase_us"] * US)}
    # The one move is not period jitter: the jitter is of the wake-ups alone.
    shift = abs(round(phase["phase_us"] * US) - RUN_P // 2)
    late_max = s["timing"]["wakeup_lateness"]["max_us"] * US
    if shift > 2 * late_max:
        assert s["timing"]["period_jitter"]["max_us"] * US < shift
