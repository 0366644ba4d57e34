"""The live view's verdict is the final verdict's function on the same evidence (the
live view said INCONCLUSIVE for a run whose final verdict was FAIL).

Each scripted run (tests/synthetic_run.py) is judged twice: finally, as ``hil run`` does
(hil.analysis.measure on its hop logs, then hil.verdict.judge), and live, by replaying the same
run's messages into hil.bench.live.timing.LiveTiming in the order the view would receive them (every
State the controller received, every command the plant received, each at that arrival). The two
outcomes must be the same: a controller stall past D*, commands dropped below the plant's
sample rate, and the clean loops at both rates.
"""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import pytest

from hil.analysis.measure import load_folder_logs, measure
from hil.bench.live.timing import Bounds, LiveTiming
from hil.folder.scenario_view import BoundInputs
from hil.verdict import FAIL, PASS, constraints_from_peaks, judge
from protocol.hoplog import CmdPath, read_hoplog
from protocol.messages import State, TorqueCommand
from tests.synthetic_run import MS, Loop, write

LIMITS = {"phi1": 1.6, "phi2": 5.1, "varpi1": 3.3, "varpi2": 51.0}
PEAKS = {"max_abs_v": 0.0, "max_abs_omega": 0.0}  # the scripted plant stands still


def _bound() -> BoundInputs:
    from controller_service.laws.base import DesignContext

    params = SimpleNamespace(m1=0.5, m2=0.5, l1=0.5, l2=0.5, lam=1.0, rho=1.0)
    return BoundInputs(params, DesignContext(), False)


def _final(folder: Path):
    logs = load_folder_logs(folder)
    assert logs is not None
    m = measure(logs, _bound())
    cons = constraints_from_peaks(PEAKS, LIMITS)
    return judge(cons, {}, m.certificate, m.timing, m.messages, None), m


def _live(folder: Path, loop: Loop, d_star_s: float) -> LiveTiming:
    """The run's messages as the view receives them: the States the controller received and
    the Zenoh commands the plant received, in arrival order."""
    ctrl, plant = read_hoplog(folder / "controller.hoplog"), read_hoplog(folder / "plant.hoplog")
    ticks = {t["cmd_seq"]: t for t in ctrl.table("ticks") if t["cmd_seq"] >= 0}
    events: list[tuple[int, object]] = []
    for r in ctrl.table("state_rx"):
        st = State("r", r["seq"], r["sample_ns"], r["send_ns"], 0.0, 0.0, 0.0, 0.0, 0.0)
        events.append((r["recv_ns"], st))
    seen = set()
    for r in plant.table("cmd_rx"):
        if r["path"] != CmdPath.ZENOH or r["seq"] in seen:
            continue
        seen.add(r["seq"])
        t = ticks[r["seq"]]
        cmd = TorqueCommand("r", r["seq"], t["state_seq"], t["state_sample_ns"],
                            t["compute_start_ns"], t["zenoh_send_ns"], 0.1, 0.2, "u")  # fmt: skip
        events.append((r["recv_ns"], cmd))
    extra = {}  # the plant's sample period and the trigger, where they are not the default
    if loop.sensor_period or loop.trigger != "periodic":
        sensor = loop.sensor_period or loop.period
        extra = {"sensor_ts_s": sensor / 1e9, "periodic": loop.trigger == "periodic"}
    bounds = Bounds(d_star_s, loop.period / 1e9, LIMITS["phi1"], LIMITS["phi2"], **extra)
    live = LiveTiming(bounds)
    for at, msg in sorted(events, key=lambda e: e[0]):
        if isinstance(msg, State):
            live.on_state(msg, at)
        else:
            live.on_command(msg, at)  # type: ignore[arg-type]
    live.snapshot(max(at for at, _ in events) + 1_000 * MS)  # every State given up on by now
    return live


CASES = {
    # a 40 ms stall of the controller: D > D*, missed slots, samples without a command
    "controller stall": (Loop(controller_stall=(400 * MS, 40 * MS)), FAIL),
    "clean 500 Hz": (Loop(), PASS),
    # hil run --rate 100 on the 500 Hz plant (c20de4f: live INCONCLUSIVE, final FAIL)
    "clean 100 Hz on a 500 Hz plant": (Loop(period=10 * MS, sensor_period=2 * MS), PASS),
    "every 7th command dropped at 100 Hz": (
        Loop(period=10 * MS, sensor_period=2 * MS, drop_command_every=7),
        FAIL,
    ),
}


@pytest.mark.parametrize("case", list(CASES))
def test_the_live_verdict_is_the_final_one_on_the_same_run(tmp_path, case):
    loop, expected = CASES[case]
    write(tmp_path / "run", loop)
    final, m = _final(tmp_path / "run")
    live = _live(tmp_path / "run", loop, m.certificate["d_star_s"])
    outcome, reasons = live.verdict()
    print(f"\n{case}: final {final.outcome} {final.reasons}; live {outcome} {reasons}")
    assert final.outcome == expected, final.reasons
    assert outcome == final.outcome, (outcome, reasons, final.reasons)
    if case == "controller stall":  # D past D* live too, as the system's
        assert "by the system's own timing" in reasons


def test_the_live_view_counts_one_state_per_control_period_below_the_sample_rate(tmp_path):
    loop = Loop(period=10 * MS, sensor_period=2 * MS, drop_command_every=7)
    write(tmp_path / "run", loop)
    _, m = _final(tmp_path / "run")
    live = _live(tmp_path / "run", loop, m.certificate["d_star_s"])
    # The final figure counts 14 of the 98 slots judged; the view judges every slot it saw,
    # to the run's end (101 slots: samples 0 .. 998 ms), with the same 14 dropped commands
    # (cmd_seq 6, 13, ..., 97; the last command, of slot 100, is cmd_seq 100). On c20de4f it
    # counted every State: 4 of 5 unanswered.
    assert (m.timing["samples_without_command"], m.timing["samples_judged"]) == (14, 98)
    assert (live.unanswered, live.judged) == (14, 101)
