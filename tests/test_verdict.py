"""The verdict's rules (hil.verdict.judge): whose failure each finding is.

FAIL is the system under test's (controller, its host, the transport); INCONCLUSIVE the bench's
(plant emulator, recorder, the bench's host) or logs that cannot relate a figure; PASS neither.
The same stalls and thresholds land on different sides by their owner, and every command's exit
code follows the outcome (hil.verdict.EXIT_CODE: PASS 0, FAIL 1 whatever made it, INCONCLUSIVE
4; --strict changes nothing)."""

from __future__ import annotations

import pytest

from hil.commands.run import _raise_on_negative
from hil.errors import NegativeVerdictError
from hil.verdict import (
    BENCH_ADVICE,
    EXIT_CODE,
    FAIL,
    INCONCLUSIVE,
    PASS,
    RunFacts,
    constraints_from_peaks,
    exit_code,
    judge,
)

LIMITS = {"phi1": 1.6, "phi2": 5.1, "varpi1": 3.3, "varpi2": 51.0}
PEAKS = {"max_abs_v": 0.8, "max_abs_omega": 1.0, "max_abs_tau1": 3.3, "max_abs_tau2": 51.0}
D_STAR = 0.0204


def _stall(age: float, cause: str, owner: str, t: float = 2.0) -> dict:
    return {"t_s": t, "age_s": age, "cause": cause, "owner": owner, "evidence": {}}


def _cert(d: float, d_system: float, stalls: list[dict], held: object = "auto") -> dict:
    return {
        "path": "zenoh",
        "d_max_s": d,
        "d_star_s": D_STAR,
        "margin_s": D_STAR - d,
        "held": (d <= D_STAR) if held == "auto" else held,
        "v_bound": 1.59,
        "omega_bound": 5.0,
        "d_system_s": d_system,
        "stalls": stalls,
    }


def _judge(cert: dict, peaks: dict = PEAKS, violations=None, timing=None, messages=None, **kw):
    return judge(
        constraints_from_peaks(peaks, LIMITS),
        violations or {},
        cert,
        timing if timing is not None else {},
        messages or {},
        RunFacts(**kw) if kw else None,
    )


def test_a_clean_run_passes():
    v = _judge(_cert(0.003, 0.003, []))
    assert v.outcome == PASS and v.reasons == [] and v.certificate == "held"


def test_a_plant_stall_past_d_star_is_inconclusive_and_names_the_plant():
    v = _judge(_cert(0.043, 0.0035, [_stall(0.043, "plant_late", "bench")]))
    assert v.outcome == INCONCLUSIVE and not v.fail_reasons
    (reason,) = v.inconclusive_reasons
    assert "the plant emulator stalled at t = 2.000 s" in reason and "3.500 ms <= D*" in reason
    assert v.advice and "fifo" in v.advice[0]


def test_the_same_stall_of_the_controller_fails_the_system():
    v = _judge(_cert(0.045, 0.045, [_stall(0.045, "controller_late", "system")]))
    assert v.outcome == FAIL and len(v.fail_reasons) == 1
    assert (
        "by the system's own timing; worst: t = 2.000 s, 45.000 ms, controller_late"
        in (v.fail_reasons[0])
    )


def test_a_system_stall_beside_a_bench_stall_still_fails():
    stalls = [_stall(0.06, "plant_late", "bench"), _stall(0.03, "command_lost", "system", 3.0)]
    v = _judge(_cert(0.06, 0.03, stalls))
    assert v.outcome == FAIL and "command_lost" in v.fail_reasons[0]


def test_a_stall_of_unknown_cause_past_d_star_is_inconclusive():
    v = _judge(_cert(0.03, 0.03, [_stall(0.03, "unknown", "unknown")]))
    assert v.outcome == INCONCLUSIVE and "cannot tell" in v.inconclusive_reasons[0]


def test_a_limit_broken_while_only_the_bench_stalled_is_inconclusive():
    peaks = {**PEAKS, "max_abs_v": 1.7}
    cert = _cert(0.05, 0.004, [_stall(0.05, "host_stalled", "bench")])
    cert["v_bound"] = 2.2  # the bound at D = 50 ms: the break stays within it
    v = _judge(cert, peaks, violations={"v": 12})
    assert v.limits == "broken" and v.limits_broken == ["v"]
    assert v.outcome == INCONCLUSIVE and not v.fail_reasons
    assert any("the bench's host stalled" in r for r in v.inconclusive_reasons)
    # Without the bench's stall the same break is the system's.
    v = _judge(_cert(0.004, 0.004, []), peaks, violations={"v": 12})
    assert v.outcome == FAIL and v.fail_reasons[0].startswith("limits of (2) broken: |v|")


def test_a_can_matching_the_logs_cannot_decide_is_unknown_never_held():
    cert = _cert(0.018, 0.018, [], held=None)
    cert["d_max_upper_s"] = 0.024
    v = _judge(cert)
    assert v.certificate == "unknown" and v.outcome == INCONCLUSIVE
    assert "from 18.000 ms to 24.000 ms" in v.inconclusive_reasons[0]


def test_frames_carrying_another_torque_make_the_figures_untrusted():
    v = _judge(_cert(0.003, 0.003, []), messages={"torque_can": {"value_mismatches": 3}})
    assert v.outcome == INCONCLUSIVE and "3 received frames" in v.inconclusive_reasons[0]


# 40 missed slots of 2000 (2 %): the system's share alone decides (threshold 1 % = 20 slots).
@pytest.mark.parametrize(("in_bench", "outcome"), [(0, FAIL), (19, FAIL), (25, INCONCLUSIVE)])
def test_missed_slots_inside_the_bench_stalls_are_not_the_systems(in_bench, outcome):
    timing = {"deadline_misses": 40, "slots": 2000, "deadline_miss_rate": 0.02}
    timing["deadline_misses_in_bench_stalls"] = in_bench
    v = _judge(_cert(0.003, 0.003, []), timing=timing)
    assert v.outcome == outcome
    assert v.timing["deadline_misses"] == {"count": 40, "slots": 2000, "rate": 0.02}


def test_a_run_cut_short_and_a_refused_real_time_policy_say_so():
    sched = {"controller": {"requested": "fifo", "policy": "SCHED_OTHER"}}
    v = _judge(
        _cert(0.003, 0.003, []),
        interrupted=True,
        duration_s=10.0,
        duration_run_s=1.234,
        scheduling=sched,
    )
    assert v.outcome == PASS
    assert v.notes[0] == (
        "interrupted after 1.234 s of 10 s: the verdict covers only those 1.234 s and makes no "
        "claim about the 8.766 s not run"
    )
    assert "asked for SCHED_FIFO and got SCHED_OTHER" in v.notes[1]


def test_a_refused_cpu_latency_request_is_said():
    refused = {"errors": {"idle": "[Errno 13] Permission denied"}}
    sched = {"plant": {"requested": "fifo", "policy": "SCHED_FIFO", "idle": "os", **refused}}
    v = _judge(_cert(0.003, 0.003, []), scheduling=sched)
    assert v.outcome == PASS
    assert len(v.notes) == 1
    assert "plant could not hold the CPUs out of slow idle states" in v.notes[0]
    assert "Permission denied" in v.notes[0]
    held = {"plant": {"requested": "fifo", "policy": "SCHED_FIFO", "idle": "poll", "errors": {}}}
    assert _judge(_cert(0.003, 0.003, []), scheduling=held).notes == []


def test_a_run_not_measured_is_never_a_pass(tmp_path):
    """A plant log the bench cannot read (once: a foreign node number in a column) left every
    figure unmeasured, and the verdict said PASS, limits held. Now the unread log is named and
    the verdict is the bench's INCONCLUSIVE; a run that stopped on an error stays a FAIL."""
    from hil.analysis.measure.logs import RunLogs

    bad = tmp_path / "plant.hoplog"
    bad.write_bytes(b"\x00not a hop log\xff" * 64)
    logs = RunLogs.read(None, bad)
    assert logs.plant is None and "plant" in logs.unreadable
    summary = {"kind": "run", "timing": {}, "logs_unreadable": logs.unreadable}
    v = judge(constraints_from_peaks({}, LIMITS), {}, None, {}, {}, RunFacts.of(summary))
    assert v.outcome == INCONCLUSIVE and v.limits == "not measured", v
    assert v.inconclusive_reasons[0].startswith("the bench could not read its own logs")
    assert "plant: " in v.inconclusive_reasons[0]
    no_sample = {"kind": "run", "timing": {"note": "no plant samples: the plant never ran"}}
    v = judge(constraints_from_peaks({}, LIMITS), {}, None, {}, {}, RunFacts.of(no_sample))
    assert v.outcome == INCONCLUSIVE and "not measured" in v.inconclusive_reasons[0]
    failed = {**no_sample, "error": "no device connected within 2 s"}
    assert judge({}, {}, None, {}, {}, RunFacts.of(failed)).outcome == FAIL
    # steps counted beyond a limit whose peak is not known: broken all the same
    v = judge({}, {"omega": 761}, None, {}, {}, RunFacts.of(no_sample))
    assert v.outcome == FAIL and v.limits_broken == ["omega"], v
    measured = {"kind": "run", "timing": {"window_s": 5.0}}
    v = judge(constraints_from_peaks(PEAKS, LIMITS), {}, None, {}, {}, RunFacts.of(measured))
    assert v.outcome == PASS and v.limits == "held"


def test_the_exit_code_table():
    assert EXIT_CODE == {PASS: 0, FAIL: 1, INCONCLUSIVE: 4}
    assert [exit_code(o) for o in (PASS, FAIL, INCONCLUSIVE)] == [0, 1, 4]


def test_hil_run_exits_with_its_verdicts_code_every_fail_included():
    """On c20de4f only "blocking" FAILs (a limit, the certificate) exited 1: a FAIL from missed
    slots or samples without a command exited 0, and INCONCLUSIVE 0 unless --strict."""
    inconclusive = {"verdict": _judge(
        _cert(0.043, 0.0035, [_stall(0.043, "plant_late", "bench")])
    ).as_dict()}  # fmt: skip
    fail = {"verdict": _judge(
        _cert(0.045, 0.045, [_stall(0.045, "controller_late", "system")])
    ).as_dict()}  # fmt: skip
    timing = {"deadline_misses": 40, "slots": 2000, "deadline_miss_rate": 0.02}
    misses = {"verdict": _judge(_cert(0.003, 0.003, []), timing=timing).as_dict()}
    passed = {"verdict": _judge(_cert(0.003, 0.003, [])).as_dict()}
    assert "blocking" not in passed["verdict"]
    _raise_on_negative(passed)
    for summary, outcome, words in (
        (inconclusive, INCONCLUSIVE, "the plant emulator stalled"),
        (fail, FAIL, "certificate not held"),
        (misses, FAIL, "deadline misses: 40 of 2000 slots"),
        ({**passed, "error": "no device connected within 5 s"}, FAIL, "no device connected"),
        ({"verdict": _judge(_cert(0.003, 0.003, []), bench_error="the bench did not start "
          "the run").as_dict(), "bench_error": "the bench did not start the run"},
         INCONCLUSIVE, "the bench did not start the run"),
    ):  # fmt: skip
        with pytest.raises(NegativeVerdictError, match=words) as caught:
            _raise_on_negative(summary)
        assert caught.value.outcome == outcome


def test_a_run_the_bench_did_not_start_is_its_inconclusive_never_a_fail():
    """Services that never said ready (summary.json's ``bench_error``): INCONCLUSIVE with that
    sentence alone; what the empty figures would have failed on is a note, not judged. No
    outside device coming (``error``) is the system's FAIL."""
    from hil.verdict import run_outcome

    why = "the bench did not start the run: the plant exited with code 1 before it was ready"
    timing = {"deadline_misses": 40, "slots": 2000, "deadline_miss_rate": 0.02}
    v = _judge(_cert(0.003, 0.003, []), timing=timing, bench_error=why, unmeasured="no sample")
    assert (v.outcome, v.fail_reasons, v.inconclusive_reasons) == (INCONCLUSIVE, [], [why])
    assert any(n.startswith("not judged, the run did not start: deadline misses") for n in v.notes)
    assert run_outcome({"bench_error": why, "verdict": v.as_dict()}) == INCONCLUSIVE
    came = _judge(_cert(0.003, 0.003, []), error="no device connected within 5 s")
    assert came.outcome == FAIL and came.fail_reasons == ["no device connected within 5 s"]
    assert run_outcome({"error": "no device connected", "verdict": {"outcome": PASS}}) == FAIL


def test_the_bench_advice_stands_only_under_inconclusive():
    """ "the bench stalled, not your system" under a FAIL (c20de4f: beside any bench stall)."""
    bench = _stall(0.043, "plant_late", "bench")
    v = _judge(_cert(0.043, 0.0035, [bench]))
    assert v.outcome == INCONCLUSIVE and v.advice == [BENCH_ADVICE]
    # The same bench stall beside the system's own failure: FAIL, and no such advice.
    system = _stall(0.03, "command_lost", "system", 3.0)
    v = _judge(_cert(0.043, 0.03, [bench, system]))
    assert v.outcome == FAIL and v.advice == []
    timing = {"deadline_misses": 40, "slots": 2000, "deadline_miss_rate": 0.02}
    v = _judge(_cert(0.003, 0.003, [bench]), timing=timing)
    assert v.outcome == FAIL and v.advice == []
    # INCONCLUSIVE for another reason than a stall of the bench: no stall advice either.
    v = _judge(_cert(0.003, 0.003, []), messages={"torque_can": {"value_mismatches": 3}})
    assert v.outcome == INCONCLUSIVE and v.advice == []


def test_the_report_shows_figures_a_trigger_does_not_measure_as_n_a_never_0():
    from hil.analysis.report.content import Section, _lateness

    on_state = {"plant_wakeup_lateness": {"p50_us": 20.0}, "plant_deadline_misses": 0}
    s = Section("lateness", "")
    sched = {"controller": {"requested": "fifo", "policy": "SCHED_FIFO", "priority": 80}}
    _lateness(s, {"timing": {"summary": on_state, "scheduling": sched}})
    tables = [b for b in s.blocks if b[0] == "table"]
    rows = {r[0]: r[1:] for block in tables for r in block[2]}
    assert set(rows["controller wake-up lateness"]) == {"n/a"}
    assert rows["deadline misses"] == ["n/a", "count"] and rows["skipped slots"] == ["n/a", "count"]
    assert rows["plant deadline misses"] == [0, "count"]
    assert any("asked fifo, got SCHED_FIFO" in b[1] for b in s.blocks if b[0] == "p")
    assert any("CPU idle os" in b[1] for b in s.blocks if b[0] == "p")  # an old folder's


@pytest.mark.parametrize("outside, who", [(True, "the device"), (False, "the controller")])
def test_the_bus_note_names_whose_commands_were_refused(outside: bool, who: str) -> None:
    """A refused command is noted as the device's when the device is outside, as the
    controller's when the bench hosts the law (never "the device" for a law it runs)."""
    from hil.folder.device import BusActivity, DeviceFigures
    from hil.verdict import DEFAULT_THRESHOLDS, Verdict, _device

    bus = BusActivity(None, None, None, None, malformed=0, unknown=0, refused=1,
                      command_timeouts=0)  # fmt: skip
    dev = DeviceFigures("zenoh", outside, 0.002, [], {}, 0, {}, False, None, 0, [], bus, 100, 0, 0)
    v = Verdict()
    _device(v, dev, {}, DEFAULT_THRESHOLDS)
    assert f"{who} on the bus: refused 1 (counted, never fatal)" in v.notes, v.notes
