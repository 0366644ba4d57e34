"""The pair as real processes on the wall clock: the paper's circle over Zenoh and over CAN.

Checks: the tracking error falls, and |v|, |omega| stay within the sampled-data bound of
docs/sampled_data_bound.md evaluated at the run's measured D (the applied path's largest
command age). The verdict at 500 Hz and 2 kHz: PASS, or what a loaded host does to a loop of
that period (tests/run_helpers.py ``LOADED_HOST``), each count explained by the run's own
logs; tests/test_clean_run.py requires PASS where the timing cannot honestly fail.
"""

from __future__ import annotations

import os

import pytest

from hil.bundled import bundled_path
from tests.run_helpers import LOADED_HOST, PASSES, check_certified_bound, hil_run

pytestmark = pytest.mark.realtime


def _scenario(tmp_path) -> str:
    """The paper's tracking scenario with SCHED_FIFO asked for (used where permitted)."""
    text = bundled_path("paper_tracking").read_text()
    path = tmp_path / "paper_tracking_fifo.toml"
    path.write_text(text + '\n[realtime]\nscheduling = "fifo"\n')
    return str(path)


def _check_bound(summary: dict, scenario_path: str) -> None:
    check_certified_bound(summary, scenario_path)
    assert summary["certificate"]["d_max_s"] >= 1.0 / 500 * 0.99  # at least one period


def _check_tracking(summary: dict) -> None:
    assert summary["samples"] >= 0.8 * 5 * 500
    # The offline simulator at Ts = 2 ms reaches 0.60 m from 1.17 m in 5 s; a loaded host's
    # real loop (late wake-ups, skipped samples) gets less far, but the error must fall.
    assert summary["final_position_error"] < 0.85 * summary["initial_position_error"], summary


@pytest.mark.slow
def test_paper_circle_over_zenoh_at_500hz(tmp_path):
    scenario = _scenario(tmp_path)
    s = hil_run(tmp_path / "run", scenario, "--rate", "500", "--duration", "5", "--cmd-path",
                "zenoh", expect=(PASSES, *LOADED_HOST))  # fmt: skip
    _check_tracking(s)
    _check_bound(s, scenario)
    t = s["timing"]
    # Most samples produced an applied command and most ticks ran (a loaded host skips some).
    assert t["sample_to_apply_zenoh"]["count"] >= 0.4 * 2500
    assert t["wakeup_lateness"]["count"] >= 0.5 * 2500
    # The law's compute time, measured on every tick: its percentiles in order, each a
    # positive time (a column of zeros or a quantile of the wrong stamps would break this).
    compute = [t["compute"][k] for k in ("p50_us", "p90_us", "p99_us", "p999_us", "max_us")]
    assert compute[0] > 0 and compute == sorted(compute), t["compute"]
    assert t["compute"]["count"] >= t["sample_to_apply_zenoh"]["count"], t["compute"]
    # The CAN path was live as a shadow and measured too.
    assert s["messages"]["torque_can"]["received"] > 0
    # The policy asked for (fifo): got where permitted (root here, as in CI), else refused
    # with the reason.
    got = s["scheduling"]["controller"]
    if os.geteuid() == 0:
        assert got["policy"] == "SCHED_FIFO" and got["priority"] == 80, got
    else:
        assert got["policy"] == "SCHED_OTHER" and got["errors"]["fifo"], got
    # [realtime] idle = "poll" by default: held by both services, or refused with the reason.
    for role in ("controller", "plant"):
        got = s["scheduling"][role]
        assert got["idle"] == "poll" or got["errors"]["idle"], got


@pytest.mark.slow
def test_paper_circle_over_can_at_500hz(tmp_path):
    scenario = _scenario(tmp_path)
    s = hil_run(tmp_path / "run", scenario, "--rate", "500", "--duration", "5", "--cmd-path",
                "can", expect=(PASSES, *LOADED_HOST))  # fmt: skip
    _check_tracking(s)
    _check_bound(s, scenario)
    assert s["timing"]["sample_to_apply_can"]["count"] > 0.4 * 2 * 2500


def test_a_command_landing_just_before_a_sample_lands_at_its_own_time(tmp_path):
    """The plant integrates each period before its sample while it waits, all but the last
    INTEGRATE_AFTER_SAMPLE_NS (plant_emulator.service.run_realtime). A command that arrives in
    that last part must still land at its own time (its receive time: no [timing] delay), never
    at the sample or at the early point. The controller ticks at 1,990 Hz against the plant's
    2,000 Hz samples: its ticks slide 2.5 us a period against the samples, so its commands
    arrive at every phase of the 500 us period (a sweep every 0.1 s), 30 % of them in the last
    150 us, whatever the host's load does to the hop."""
    from hil.analysis.measure.logs import load_folder_logs
    from plant_emulator.service import INTEGRATE_AFTER_SAMPLE_NS
    from protocol.hoplog import ApplyOutcome

    path = tmp_path / "sliding.toml"
    path.write_text(
        bundled_path("paper_tracking").read_text()
        + '\n[realtime]\nscheduling = "fifo"\nsensor_rate = 2000.0\n'
    )
    hil_run(tmp_path / "run", str(path), "--rate", "1990", "--duration", "4", "--cmd-path",
            "zenoh", "--no-can", expect=(PASSES, *LOADED_HOST))  # fmt: skip
    logs = load_folder_logs(tmp_path / "run")
    a, s = logs["apply"], logs["samples"]
    landed = a["outcome"] == ApplyOutcome.LANDED
    apply_ns, recv_ns = a["apply_ns"][landed], a["recv_ns"][landed]
    assert apply_ns.size > 2000
    # Where each arrival falls in its sensor period (the plant's samples are on the grid).
    period = int(s["sample_ns"][1] - s["sample_ns"][0])
    assert period == 500_000, period
    phase = (recv_ns - int(s["sample_ns"][0])) % period
    in_last_part = phase >= period - INTEGRATE_AFTER_SAMPLE_NS
    # The slide puts ~30 % there (landed commands x 150 / 500); half of that is still hundreds.
    assert in_last_part.sum() >= 0.15 * apply_ns.size, "the ticks did not slide over the period"
    exact = apply_ns == recv_ns
    # Not all: a command stamped while the plant's loop preempts its receiving thread is taken
    # at the next step and lands (truthfully logged) a little later.
    assert exact[in_last_part].mean() >= 0.95, (apply_ns - recv_ns)[in_last_part & ~exact][:10]
    assert exact.mean() >= 0.95
