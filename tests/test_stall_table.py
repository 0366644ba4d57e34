"""The stall table (hil/analysis/measure/stalls.py) on synthetic evidence: every row, the precedence
between rows, two misattributions seen on loaded hosts rebuilt from hop logs, and the docs
holding the table the code runs.

Two layers: :func:`decide` on an :class:`Evidence` written by hand (each row and each pair of
rows whose order matters), and the whole pipeline (hil.analysis.measure.measure) on hop logs
scripted by tests/synthetic_run.py, so the evidence is what the joins find in logs, not what a test
assumed. The same rows on real processes beside CPU hogs are in tests/test_stall_rows.py.
"""

from __future__ import annotations

import tomllib
from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from hil.analysis.measure import load_folder_logs, measure
from hil.analysis.measure.stalls import (
    BENCH,
    OWNER,
    SYSTEM,
    TABLE,
    TABLE_BEGIN,
    TABLE_END,
    Evidence,
    Stretches,
    decide,
    starved,
    table_markdown,
    table_text,
)
from hil.folder.scenario_view import BoundInputs, bound_inputs
from tests.scenario_text import CLEAN_50HZ
from tests.synthetic_run import MS, US, Loop, write

ROOT = Path(__file__).resolve().parent.parent
P = 2 * MS
THETA = 10 * MS
# A stall of 40 ms age against a 10 ms threshold: a cause accounts for it with 30 ms or more.
BASE = Evidence(age_ns=40 * MS, threshold_ns=THETA, period_ns=P, sensor_period_ns=P)


def _row(cause: str, accounts: bool) -> int:
    return next(i for i, r in enumerate(TABLE, 1) if (r.cause, r.accounts) == (cause, accounts))


# --- the table: one written order, documented where the code says -------------------------


def test_the_table_is_ordered_bench_that_accounts_then_system_then_partial_bench():
    kinds = [(r.cause, r.accounts) for r in TABLE]
    assert kinds == [
        *((c, True) for c in BENCH),
        *((c, True) for c in SYSTEM),
        *((c, False) for c in SYSTEM),
        *((c, False) for c in BENCH),
        ("unknown", False),
    ]
    assert {OWNER[c] for c in BENCH} == {"bench"} and {OWNER[c] for c in SYSTEM} == {"system"}
    assert BENCH == ("host_stalled", "host_overloaded", "plant_late", "bench_dropped")
    assert SYSTEM == (
        "controller_late", "state_lost", "command_lost", "transport_late", "command_delayed",
    )  # fmt: skip


def test_the_docstring_and_docs_reports_hold_the_table_the_code_runs():
    import hil.analysis.measure.stalls as stalls

    doc = stalls.__doc__ or ""
    assert f"{TABLE_BEGIN}\n{table_text()}\n{TABLE_END}" in doc
    reports = (ROOT / "docs" / "reports.md").read_text()
    assert f"{TABLE_BEGIN}\n{table_markdown()}\n{TABLE_END}" in reports
    assert reports.count(TABLE_BEGIN) == 1
    # docs/realtime.md points to that one table instead of keeping a list of its own.
    realtime = (ROOT / "docs" / "realtime.md").read_text()
    assert "the largest evidence wins" not in realtime and "largest score" not in realtime
    assert "docs/reports.md" in realtime and "stall table" in realtime


# --- every row on evidence written by hand --------------------------------------------------

ROWS = [
    # (evidence, the row expected): each the smallest evidence that row needs
    (replace(BASE, controller_ns=35 * MS, plant_ns=35 * MS, both_ns=35 * MS, bench_ns=35 * MS),
     ("host_stalled", True)),
    (replace(BASE, controller_ns=35 * MS, starved=True, bench_ns=35 * MS),
     ("host_overloaded", True)),
    (replace(BASE, plant_ns=35 * MS, bench_ns=35 * MS), ("plant_late", True)),
    (replace(BASE, bench_dropped=12, bench_ns=35 * MS), ("bench_dropped", True)),
    (replace(BASE, controller_ns=35 * MS, controller_own_ns=35 * MS), ("controller_late", True)),
    (replace(BASE, states_lost_ns=32 * MS), ("state_lost", True)),
    (replace(BASE, commands_lost_ns=32 * MS), ("command_lost", True)),
    (replace(BASE, wire_ns=31 * MS), ("transport_late", True)),
    (replace(BASE, burst_ns=30 * MS), ("command_delayed", True)),
    (replace(BASE, controller_ns=P, controller_own_ns=P), ("controller_late", False)),
    (replace(BASE, states_lost_ns=P), ("state_lost", False)),
    (replace(BASE, commands_lost_ns=P), ("command_lost", False)),
    (replace(BASE, wire_ns=P), ("transport_late", False)),
    (replace(BASE, burst_ns=1), ("command_delayed", False)),
    (replace(BASE, controller_ns=P, plant_ns=P, both_ns=P, bench_ns=P), ("host_stalled", False)),
    (replace(BASE, controller_ns=P, starved=True, bench_ns=P), ("host_overloaded", False)),
    (replace(BASE, plant_ns=P, bench_ns=P), ("plant_late", False)),
    (replace(BASE, bench_dropped=1, bench_ns=P), ("bench_dropped", False)),
    (BASE, ("unknown", False)),
]  # fmt: skip


@pytest.mark.parametrize(("e", "want"), ROWS, ids=[f"{c}-{a}" for _, (c, a) in ROWS])
def test_each_row_matches_its_own_evidence(e: Evidence, want: tuple[str, bool]):
    cause, owner, row = decide(e)
    assert (cause, row) == (want[0], _row(*want)), (cause, row)
    assert owner == OWNER[want[0]]
    # Just short of what the row needs, it does not match (the next one down does).
    if want[1] and want[0] != "unknown":
        short = replace(e, age_ns=e.age_ns + 10 * MS)  # A - θ now beyond the stretch
        assert decide(short)[2] > row


def test_every_row_is_reached_by_some_evidence():
    assert sorted({decide(e)[2] for e, _ in ROWS}) == list(range(1, len(TABLE) + 1))


def test_the_same_evidence_always_gets_the_same_answer():
    for e, _ in ROWS:
        assert len({decide(e) for _ in range(5)}) == 1
        assert decide(replace(e)) == decide(e)


# --- precedence between rows ----------------------------------------------------------------


def test_a_stall_the_bench_accounts_for_is_the_bench_s_even_with_the_system_s_evidence_there():
    """A 40 ms plant stall with a [faults] drop and a slow hop inside it: the bench alone made
    the stall (without it the age stays under θ), so nothing of the system's is blamed."""
    e = replace(BASE, plant_ns=38 * MS, bench_ns=38 * MS, states_lost_ns=2 * P, wire_ns=P)
    assert decide(e)[:2] == ("plant_late", "bench")


def test_the_system_s_own_stall_is_the_system_s_when_the_bench_does_not_account_for_it():
    """A 20 ms plant stall and a 20 ms controller stall apart, in a 45 ms excursion: without
    the bench's part the age (25 ms) is still over θ, and the controller's part is its own."""
    e = replace(BASE, age_ns=45 * MS, plant_ns=20 * MS, bench_ns=20 * MS,
                controller_ns=20 * MS, controller_own_ns=20 * MS)  # fmt: skip
    assert decide(e)[:2] == ("controller_late", "system")


def test_controller_and_plant_late_together_is_the_host_before_the_plant_alone():
    e = replace(BASE, controller_ns=30 * MS, plant_ns=38 * MS, both_ns=30 * MS, bench_ns=38 * MS)
    assert decide(e)[:2] == ("host_stalled", "bench")
    assert decide(replace(e, both_ns=P - 1))[:2] == ("plant_late", "bench")


def test_a_system_cause_that_accounts_beats_one_merely_there():
    """A 200 ms retransmission with one dropped State in it: the wire, not the drop."""
    e = replace(BASE, age_ns=200 * MS, states_lost_ns=2 * P, wire_ns=195 * MS)
    assert decide(e)[0] == "transport_late"
    e = replace(BASE, age_ns=200 * MS, states_lost_ns=2 * P, wire_ns=5 * MS)
    assert decide(e)[0] == "state_lost"  # neither accounts: the first there, in order


def test_a_starved_controller_is_the_host_s_a_stopped_one_its_own():
    host = {"from_s": 0.2, "busy_pct": 100.0, "steal_pct": 0.0, "cpus": 2,
            "plant_cpu_pct": 10.0, "controller_cpu_pct": 5.0, "recorder_cpu_pct": 5.0}  # fmt: skip
    assert starved({**host, "controller_wait_s": 0.030}, 40 * MS)  # waited 30 of 40 ms
    assert not starved({**host, "controller_wait_s": 0.001}, 40 * MS)  # stopped: no wait
    assert not starved({**host, "busy_pct": 60.0, "controller_wait_s": 0.030}, 40 * MS)
    # Busy with this run's own processes only: not the host's others.
    ours = {**host, "busy_pct": 95.0, "plant_cpu_pct": 80.0, "controller_cpu_pct": 60.0,
            "recorder_cpu_pct": 50.0, "controller_wait_s": 0.030}  # fmt: skip
    assert not starved(ours, 40 * MS)
    # The hypervisor took 10 % of 2 CPUs over 0.2 s = 40 ms of CPU time: at least half of it.
    assert starved({**host, "busy_pct": 50.0, "steal_pct": 10.0}, 40 * MS)
    assert not starved(None, 40 * MS) and not starved({**host, "controller_wait_s": 1.0}, 0)


# --- stretches ----------------------------------------------------------------------------


def test_stretches_union_intersection_and_difference():
    a = Stretches.of(np.array([0, 10, 5]), np.array([4, 20, 12]))
    assert (a.lo.tolist(), a.hi.tolist()) == ([0, 5], [4, 20])
    b = Stretches.of(np.array([3, 15]), np.array([6, 30]))
    assert a.intersect(b).total() == (4 - 3) + (6 - 5) + (20 - 15)
    assert a.minus(b).total() == a.total() - a.intersect(b).total()
    assert a.union(b).total() == 30 - 0 - 0  # [0, 30] whole
    assert a.covered(2, 16) == (4 - 2) + (16 - 5)
    gaps = Stretches.silences(np.array([1, 2, 10, 11, 30]), 5)
    assert (gaps.lo.tolist(), gaps.hi.tolist()) == ([2, 11], [10, 30])


def test_a_lost_stretch_is_measured_between_the_delivered_messages_around_it():
    from hil.analysis.measure.stalls import _gaps

    t = np.arange(10, dtype=np.int64) * 10
    ok = np.ones(10, bool)
    assert _gaps(t, ok, 0, 90) == 0
    ok[3:6] = False  # 30, 40, 50 lost: from 20 to 60
    assert _gaps(t, ok, 0, 90) == 40
    assert _gaps(t, ok, 35, 90) == 60 - 35  # clipped to the stall
    ok[:] = True
    ok[7:] = False  # lost to the end, the last one at the stall's end itself
    assert _gaps(t, ok, 0, 90) == 90 - 60
    ok[:] = False  # nothing delivered at all
    assert _gaps(t, ok, 0, 90) == 90
    ok[:] = True
    ok[0] = False  # the first lost, nothing delivered before the stall
    assert _gaps(t, ok, 0, 90) == 10


def test_a_receiver_s_stall_lasts_until_it_drained_its_queue():
    """A plant stopped over [100, 1100] ms reads the commands queued meanwhile back to back for
    20 ms after it resumes, then a fresh one (hop 0.3 ms): its stall is [100, 1120] ms, and a
    command that waited in that queue is its delay, not the wire's (seen on a real run: 16 ms
    of queue after a 1 s SIGSTOP read as transport_late)."""
    ms = 1_000_000
    stall = Stretches.of(np.array([100 * ms]), np.array([1100 * ms]))
    recv = np.array([1100.5, 1105, 1110, 1119.9, 1120, 1122]) * ms
    hop = np.array([1000, 800, 500, 20, 0.3, 0.3]) * ms
    got = stall.drained(recv.astype(np.int64), hop.astype(np.int64), 2 * ms)
    assert (got.lo.tolist(), got.hi.tolist()) == ([100 * ms], [1120 * ms])
    # Nothing fresh within the stall's own length after it: to the last stale receipt there.
    got = stall.drained(recv[:4].astype(np.int64), hop[:4].astype(np.int64), 2 * ms)
    assert got.hi.tolist() == [int(1119.9 * ms)]
    # A fresh receipt at once: the stall ends there.
    got = stall.drained(np.array([1100_300_000]), np.array([300_000]), 2 * ms)
    assert got.hi.tolist() == [1100_300_000]
    # No receipt at all: the stall keeps its end.
    assert stall.drained(np.zeros(0, np.int64), np.zeros(0, np.int64), 2 * ms).hi.tolist() == [
        1100 * ms
    ]


# --- the pipeline on scripted hop logs: misattributions seen on loaded hosts --------------------


def _bound() -> BoundInputs:
    from controller_service.laws.base import DesignContext

    params = SimpleNamespace(m1=0.5, m2=0.5, l1=0.5, l2=0.5, lam=1.0, rho=1.0)
    return BoundInputs(params, DesignContext(), False)


def _stall_at(tmp_path: Path, loop: Loop, t_ms: float) -> dict:
    write(tmp_path / "run", loop)
    logs = load_folder_logs(tmp_path / "run")
    assert logs is not None
    cert = measure(logs, _bound()).certificate
    assert cert is not None
    near = [s for s in cert["stalls"] if abs(s["t_s"] * 1e3 - t_ms) < 20]
    assert near, cert["stalls"]
    return max(near, key=lambda s: s["age_s"])


def test_a_host_stall_with_a_state_held_across_it_is_host_stalled_not_the_wire(tmp_path):
    """A README run on a loaded host: the controller 48.6 ms late inside a 99.7 ms plant stall (the
    host stopped both), and the State the plant stamped just before it stopped left only when
    it resumed and arrived 5.5 ms later (its receiver catching up). c20de4f compared that
    State's 107 ms hop with the larger lateness plus a period (101.7 ms), named the stall
    ``transport_late`` (system) and failed the run; its hop is the two ends' stalls."""
    loop = Loop(n=1500, plant_stall=(1000 * MS, 99_700 * US),
                controller_stall=(1030 * MS, 48_600 * US),
                hold_states=(998 * MS, 107_100 * US))  # fmt: skip
    stall = _stall_at(tmp_path, loop, 1000)
    ev = stall["evidence"]
    assert ev.get("transport_worst_s", 0.0) < 0.010, ev  # what is left of the hop on the wire
    assert ev["both_stalled_s"] >= 0.045, ev
    assert (stall["cause"], stall["owner"]) == ("host_stalled", "bench"), stall


def test_a_command_held_by_the_stopped_plant_is_the_plant_s_stall_not_the_wire(tmp_path):
    """A 40 ms plant SIGSTOP on a loaded host: the command sent 1 ms before the stop was read by the
    plant's receiver 4 ms after it resumed (its main loop catching up first). c20de4f took
    the 45 ms hop for the wire's (more than the plant's 42 ms silence plus a period) and
    blamed ``transport_late`` (system); the plant held that command while stopped."""
    loop = Loop(n=1500, plant_stall=(1000 * MS, 40 * MS), late_command=(499, 44_800 * US))
    stall = _stall_at(tmp_path, loop, 1000)
    assert (stall["cause"], stall["owner"]) == ("plant_late", "bench"), stall
    assert stall["evidence"]["plant_stalled_s"] >= 0.040


def test_a_hop_the_ends_do_not_cover_is_the_wire_s(tmp_path):
    """States held 60 ms on the wire while both ends ran (a TCP retransmission): the
    system's ``transport_late``."""
    stall = _stall_at(tmp_path, Loop(n=1500, hold_states=(1000 * MS, 60 * MS)), 1000)
    assert (stall["cause"], stall["owner"]) == ("transport_late", "system"), stall
    assert stall["evidence"]["transport_worst_s"] >= 0.058


def test_a_controller_stall_is_the_controller_s_and_both_together_the_host_s(tmp_path):
    stall = _stall_at(tmp_path / "c", Loop(n=1500, controller_stall=(1000 * MS, 40 * MS)), 1000)
    assert (stall["cause"], stall["owner"]) == ("controller_late", "system"), stall
    both = Loop(n=1500, controller_stall=(1000 * MS, 40 * MS), plant_stall=(1000 * MS, 40 * MS))
    stall = _stall_at(tmp_path / "b", both, 1000)
    assert (stall["cause"], stall["owner"]) == ("host_stalled", "bench"), stall


def test_an_outside_device_s_silence_is_its_stall_never_lost_states(tmp_path):
    """An outside device (its run folder without controller.hoplog: the bench sees only what
    reached the plant) silent 40 ms: its own stall, ``controller_late`` (system), from its
    commands' silence at the plant; the States it may not have received are never called lost
    (before, every State of an outside device counted as lost and its stall read
    ``state_lost``). A plant stall there stays the bench's ``plant_late``."""

    def outside_stall(name: str, loop: Loop) -> dict:
        write(tmp_path / name, loop)
        (tmp_path / name / "controller.hoplog").unlink()
        logs = load_folder_logs(tmp_path / name)
        assert logs is not None and logs.controller is None
        cert = measure(logs, _bound()).certificate
        assert cert is not None
        near = [s for s in cert["stalls"] if abs(s["t_s"] - 1.0) < 0.02]
        assert near, cert["stalls"]
        return max(near, key=lambda s: s["age_s"])

    stall = outside_stall("device", Loop(n=1500, controller_stall=(1000 * MS, 40 * MS)))
    assert (stall["cause"], stall["owner"]) == ("controller_late", "system"), stall
    assert stall["evidence"]["controller_stalled_s"] >= 0.040, stall
    assert "states_lost" not in stall["evidence"], stall
    stall = outside_stall("plant", Loop(n=1500, plant_stall=(1000 * MS, 40 * MS)))
    assert (stall["cause"], stall["owner"]) == ("plant_late", "bench"), stall


def test_lost_states_and_commands_are_the_system_s(tmp_path):
    states = Loop(n=1500, lose_states=set(range(500, 515)))  # 30 ms of States lost
    stall = _stall_at(tmp_path / "s", states, 1000)
    assert (stall["cause"], stall["owner"]) == ("state_lost", "system"), stall
    assert stall["evidence"]["states_lost"] == 15
    write(tmp_path / "m", states)
    logs = load_folder_logs(tmp_path / "m")
    assert logs is not None
    st = measure(logs, _bound()).messages["state"]
    assert st["lost_not_injected"] == 15 and st["injected_drops"] == 0
    assert st["lost_not_injected_t_s"] == [1.0, 1.028]  # samples 500..514 at 2 ms
    cmds = Loop(n=1500, cmd_path="can", lose_can_frames=set(range(499, 514)))
    stall = _stall_at(tmp_path / "c", cmds, 1000)
    assert (stall["cause"], stall["owner"]) == ("command_lost", "system"), stall


def test_frames_the_drives_socket_dropped_are_the_bench_s(tmp_path):
    """The same 15 commands' frames lost, but the drives' own socket counted 30 frames dropped
    (its queue full: the plant's ``socket_drops`` log) between two reads that bracket them (sent
    999.06 .. 1027.06 ms after the epoch): the bench's loss, not the wire's."""
    loop = Loop(n=1500, cmd_path="can", lose_can_frames=set(range(499, 514)),
                socket_drops=((998 * MS, 1028 * MS, 30),))  # fmt: skip
    write(tmp_path / "run", loop)
    logs = load_folder_logs(tmp_path / "run")
    assert logs is not None
    m = measure(logs, _bound())
    assert m.certificate is not None
    stall = max((s for s in m.certificate["stalls"] if abs(s["t_s"] - 1.0) < 0.02),
                key=lambda s: s["age_s"])  # fmt: skip
    assert (stall["cause"], stall["owner"]) == ("bench_dropped", "bench"), stall
    can = m.messages["torque_can"]
    assert can["frames_dropped_by_bench_socket"] == 30
    assert can["frames_lost_by_bench"] == 30 and can["lost_by_bench"] == 15, can
    assert can["frames_lost_on_wire"] == 0, can
    # Without the drop log the same loss is the wire's.
    plain = Loop(n=1500, cmd_path="can", lose_can_frames=set(range(499, 514)))
    write(tmp_path / "plain", plain)
    logs = load_folder_logs(tmp_path / "plain")
    assert logs is not None
    can = measure(logs, _bound()).messages["torque_can"]
    assert can["frames_lost_on_wire"] == 30 and can["lost_by_bench"] == 0, can


def test_a_frame_lost_among_identical_frames_is_the_bench_s_if_the_socket_dropped_there(tmp_path):
    """Unnamed CAN frames all of the same bytes (a held torque) while the plant stopped for
    100 ms (1.0 .. 1.1 s): its socket queued what was sent then and dropped the last 15
    commands' frames (queue full), 30 drops counted by its first read after (1.08 .. 1.1 s).
    The logs cannot tell which frames of a run of identical frames were lost (the matcher
    here puts the losses at the start of the stop, outside the drops' window), so the drops
    explain them: the bench's, none the wire's. Frames of other bytes stay apart: with
    varying torques and no stop, drops counted a second after the loss explain none of it."""

    def torque_can(name: str, loop: Loop) -> dict:
        write(tmp_path / name, loop)
        logs = load_folder_logs(tmp_path / name)
        assert logs is not None
        return measure(logs, _bound()).messages["torque_can"]

    held = Loop(n=1500, cmd_path="can", named_frames=False, constant_can_values=True,
                hold_can_frames=(1000 * MS, 100 * MS), lose_can_frames=set(range(535, 550)),
                socket_drops=((1080 * MS, 1100 * MS + 10 * US, 30),))  # fmt: skip
    can = torque_can("held", held)
    assert can["frames_lost"] == 30 and can["frames_dropped_by_bench_socket"] == 30, can
    assert can["frames_lost_by_bench"] == 30 and can["lost_by_bench"] == 15, can
    assert can["frames_lost_on_wire"] == 0, can
    varying = Loop(n=1500, cmd_path="can", named_frames=False,
                   lose_can_frames=set(range(499, 514)),
                   socket_drops=((1998 * MS, 2028 * MS, 30),))  # fmt: skip
    can = torque_can("varying", varying)
    assert can["frames_lost"] == 30 and can["frames_lost_by_bench"] == 0, can
    assert can["frames_lost_on_wire"] == 30, can


def test_lost_messages_the_bench_dropped_are_not_the_system_s():
    """The lost-messages rule counts the system's losses only: 30 of 1,000 CAN commands lost
    (1.5 % of the 2,000 messages with the States), 25 of them dropped by the drives' own socket,
    is INCONCLUSIVE; the same 30 on the wire FAIL."""
    from hil.verdict import FAIL, INCONCLUSIVE, judge

    def lost(by_bench: int) -> str:
        can = {"sent": 1000, "lost": 30, "lost_by_bench": by_bench}
        messages = {"state": {"sent": 1000, "lost": 0}, "torque_can": can}
        return judge({}, {}, {"path": "can"}, {}, messages).outcome

    assert lost(25) == INCONCLUSIVE
    assert lost(0) == FAIL
    assert lost(5) == FAIL  # 25 of 2,000 is still 1.25 % > 1 %: the system's


def test_a_lost_and_ambiguous_can_stretch_leaves_the_certificate_unknown(tmp_path):
    """Unnamed CAN frames (SocketCAN, udp_multicast) of a saturated law (every frame the same
    bytes), the arming zeros and the first two commands' frames lost on the wire: nothing
    before the first arrival anchors the match, so "these are the first sends, 2 periods late"
    and "the first two were lost" fit alike (hil.analysis.measure.can_match). Every CAN figure they
    feed says ``not_relatable``, D is known only between 5.3 and 7.3 ms, and with D* = 5.7 ms
    between (the gains' m = 0.9) the certificate is unknown: ``held`` null, INCONCLUSIVE.
    Reached from hop logs through the whole pipeline, not from a certificate written by hand."""
    from controller_service.laws.base import DesignContext
    from hil.verdict import INCONCLUSIVE, judge
    from protocol.hoplog import NO_SEQ

    loop = Loop(cmd_path="can", named_frames=False, constant_can_values=True,
                lose_can_frames={NO_SEQ, 0, 1})  # fmt: skip
    write(tmp_path / "run", loop)
    params = SimpleNamespace(m1=0.9, m2=0.9, l1=0.5, l2=0.5, lam=1.0, rho=1.0)
    logs = load_folder_logs(tmp_path / "run")
    assert logs is not None
    m = measure(logs, BoundInputs(params, DesignContext(), False))
    c = m.certificate
    assert c is not None and c["held"] is None, c
    assert c["d_max_s"] <= c["d_star_s"] < c["d_max_upper_s"], c
    assert m.timing["hop_cmd_can"]["not_relatable"] > 0
    assert m.timing["command_age_can"]["not_relatable"] > 0
    assert m.messages["torque_can"]["frames_ambiguous"] > 0
    v = judge({}, {}, c, m.timing, m.messages)
    assert v.outcome == INCONCLUSIVE and v.certificate == "unknown", v
    assert v.inconclusive_reasons[0].startswith("certificate unknown: the CAN logs allow D")


def test_a_host_stop_too_short_to_be_a_stall_still_owns_the_slots_it_missed(tmp_path):
    """At 100 Hz (D* about 0.5 s: stall threshold 0.25 s) a 30 ms stop of the whole machine
    raises no stall of the table, yet misses about 3 slots in 200 (3 %, a FAIL's count when
    laid on the system). Both services stopped at once: the bench's (``host_stalled``'s
    evidence), found again in ``deadline_misses_in_bench_stalls``; the controller alone stopped
    the same 30 ms: its own, none of them the bench's. (A fleet in a fresh clone's CI: steal
    35 %, both services 30 ms late together twice, FAIL on 6 missed slots of 200.)"""
    period = 10 * MS
    bound = bound_inputs(tomllib.loads(CLEAN_50HZ))  # the fleet's scenario: D* = 498 ms

    def timing(name: str, loop: Loop) -> dict:
        write(tmp_path / name, loop)
        logs = load_folder_logs(tmp_path / name)
        assert logs is not None
        m = measure(logs, bound)
        assert m.certificate is not None and m.certificate["stall_count"] == 0, m.certificate
        return m.timing

    stop = (1000 * MS + period // 2, 30 * MS)  # from the controller's tick at 1.005 s
    both = timing("both", Loop(n=200, period=period, controller_stall=stop, plant_stall=stop))
    alone = timing("alone", Loop(n=200, period=period, controller_stall=stop))
    for t in (both, alone):
        assert 3 <= t["deadline_misses"] <= 4, t
    assert both["deadline_misses_in_bench_stalls"] == both["deadline_misses"], both
    assert alone.get("deadline_misses_in_bench_stalls", 0) == 0, alone
