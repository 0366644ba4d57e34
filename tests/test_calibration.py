"""Known-answer calibration on real processes: inject what a figure measures, find it again.

``hil run`` runs the real pair (Zenoh on loopback, the zenoh_can bus) under SCHED_FIFO; the test
injects, at moments it aims at on the run's own clock: a SIGSTOP/SIGCONT of a service by its
PID, a spin at a higher real-time priority on the controller's CPU (its loop cannot run, its
Zenoh threads can), a constant ``[timing] delay``, a law that busy-waits on every other sample,
``[faults]`` drops, a CAN re-arm. Every action is stamped just before and just after it
(CLOCK_MONOTONIC, the services' clock).

Each test reads the truth without hil.analysis.measure: the services' hop logs parsed by
tests/raw_hoplogs.py (the figures evaluated from their written definitions) and the outside
stamps of the injection. Two sides for each figure:

- the figure in summary.json equals the raw logs' evaluation of its definition, exactly
  (count, percentiles, max: each percentile is a measured value);
- at the injection, the raw stamps show the injected amount within a causal tolerance: no
  stamp of a stopped process between its SIGSTOP and its SIGCONT, and a SCHED_FIFO service runs
  within RESUME_NS of being let go (the only allowance; a wake-up later than that is a host
  that stalled by itself, and the assertion prints the host's own samples of that moment);
- the control does not show it: the same slot of a clean run, or the samples and commands of
  the same run the injection did not touch.

docs/realtime.md's calibration table is generated from the ``@calibrates`` declarations here
and in tests/test_known_answers.py (tools/calibration_table.py). CI cost: six runs of 4-5 s
(each calibrating several figures whose injections do not mask each other) and one of 2 s.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from hil.bundled import bundled_path
from protocol.hoplog import SAMPLE_DROPPED, TICK_DROPPED, TICK_NO_SEND, CmdPath, read_hoplog
from tests.calibrates import calibrates
from tests.procs import Spawner, spawned, wait_until
from tests.raw_hoplogs import (
    FIGURES,
    LANDED,
    RawRun,
    assert_same,
    check_summary_against_raw,
    stats,
)
from tests.run_helpers import expected_exit

pytestmark = [
    pytest.mark.realtime,
    pytest.mark.slow,
    pytest.mark.skipif(
        os.geteuid() != 0 or len(os.sched_getaffinity(0)) < 2,
        reason="aims its injections at SCHED_FIFO 90 on a CPU of its own: needs root and 2 CPUs",
    ),
]

RATE = 500
P = 2_000_000  # the period (ns): control and sensor at 500 Hz
MS = 1_000_000
# A SCHED_FIFO service runs within this of its SIGCONT (or a spin's end). Let go, a Python
# service first catches up what it slept through (its loop, its Zenoh threads, its CAN edge,
# one GIL) before a given thread takes its next stamp: on a host half as fast as the one 3 ms
# was set on, a CAN frame was read 3.03 ms, then 5.3 ms, after the plant's SIGCONT.
RESUME_NS = 8 * MS
AIM_NS = 300_000  # the test spins this long before an action's moment (a sleep wakes late)
STOP_NS = 40 * MS  # the 40 ms SIGSTOPs
LEAD_NS = 500_000  # a SIGSTOP lands this long before the stopped service's next deadline
BUSY_US = 200.0  # the slow law's busy wait on every other sample (tests/busy_law.py)
DELAY_NS = 600_000  # [timing] delay: 3 plant steps; Ts - delay cuts the arrivals' tail


# --- the scenario, the run ---------------------------------------------------------------------


def _scenario(tmp: Path, extra: str = "", timing: str = "", controller: str = "") -> Path:
    """The paper's circle at SCHED_FIFO; ``timing`` adds keys to its [timing] table,
    ``controller`` replaces its law, ``extra`` adds tables."""
    tmp.mkdir(parents=True, exist_ok=True)
    text = bundled_path("paper_tracking").read_text()
    if controller:
        assert 'law = "unified"\n' in text
        text = text.replace('law = "unified"\n', "", 1)
    for table, keys in (("[timing]\n", timing), ("[controller]\n", controller)):
        assert table in text
        text = text.replace(table, table + keys, 1)
    path = tmp / "scenario.toml"
    path.write_text(text + '\n[realtime]\nscheduling = "fifo"\n\n' + extra)
    return path


def _start(spawn: Spawner, out: Path, scenario: Path, *args: str, duration: float = 5.0):
    argv = ["-m", "hil", "run", str(scenario), "--rate", str(RATE), "--duration", str(duration)]
    return spawn.python([*argv, "--quiet", "--out", str(out), *args])


def _finish(proc: subprocess.Popen, out: Path) -> dict:
    """The run's summary (with ``_exit_code``); a FAIL only with its reason in the summary."""
    code = proc.wait(timeout=240)
    err = proc.stderr.read().decode(errors="replace")
    summary = json.loads((out / "summary.json").read_text())
    # The verdict's own exit code; which verdict each injection makes, its test pins.
    assert code == expected_exit(summary["verdict"]["outcome"]), (code, err[-3000:])
    summary["_exit_code"] = code
    return summary


@dataclass(frozen=True)
class Run:
    summary: dict
    raw: RawRun
    acts: dict[str, Act]

    @property
    def timing(self) -> dict:
        return self.summary["timing"]


def _run(tmp: Path, scenario: Path, *args: str, plan=None, duration: float = 5.0) -> Run:
    """``hil run`` with ``plan(injector)`` acting on it while it runs."""
    out = tmp / "run"
    with spawned() as spawn:
        proc = _start(spawn, out, scenario, "--no-report", *args, duration=duration)
        acts = plan(Injector(out, proc)) if plan else {}
        summary = _finish(proc, out)
    return Run(summary, RawRun(out), acts)


# --- the injections ----------------------------------------------------------------------------


@dataclass(frozen=True)
class Act:
    """One action of the test on a run: stamped just before it (``at``) and just after it
    (``by``), CLOCK_MONOTONIC ns. A spin: ``at`` when the CPU was taken, ``by`` its last
    stamp before the CPU was given back."""

    at: int
    by: int


class Injector:
    """Acts on a running ``hil run``'s services at moments of its own clock (t = 0 the
    epoch), from this thread at SCHED_FIFO 90, above the services' 80."""

    def __init__(self, out: Path, proc: subprocess.Popen) -> None:
        self.out, self.proc = out, proc
        self.epoch = self._epoch()
        self.pids = json.loads((out / "processes.json").read_text())
        self.cpu = {who: os.sched_getaffinity(self.pids[who]) for who in ("controller", "plant")}

    def _epoch(self) -> int:
        def known() -> bool:
            if self.proc.poll() is not None:
                err = self.proc.stderr.read().decode(errors="replace") if self.proc.stderr else ""
                raise AssertionError(f"hil run exited {self.proc.returncode}: {err[-2000:]}")
            try:
                return bool(read_hoplog(self.out / "controller.hoplog").meta.get("epoch_ns"))
            except (OSError, ValueError):
                return False

        assert wait_until(known, 120), "the run never started"
        return int(read_hoplog(self.out / "controller.hoplog").meta["epoch_ns"])

    def ns(self, t_s: float) -> int:
        return self.epoch + round(t_s * 1e9)

    @contextmanager
    def realtime(self) -> Iterator[None]:
        """SCHED_FIFO 90 for the plan: at SCHED_OTHER the services' real-time threads can keep
        this thread off the CPU past the moment it aims at."""
        cpus, policy, param = (
            os.sched_getaffinity(0),
            os.sched_getscheduler(0),
            os.sched_getparam(0),
        )
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(90))
        try:
            yield
        finally:
            os.sched_setscheduler(0, policy, param)
            os.sched_setaffinity(0, cpus)

    def _aim(self, at: int, on: str) -> None:
        """On the CPU of service ``on`` (one whose work this cannot disturb at that moment),
        sleep to just before ``at``, then spin to it."""
        os.sched_setaffinity(0, self.cpu[on])
        delay = (at - AIM_NS - time.monotonic_ns()) / 1e9
        assert delay > -AIM_NS / 1e9, f"the moment {(at - self.epoch) / 1e9:.4f} s had passed"
        time.sleep(max(0.0, delay))
        while time.monotonic_ns() < at:
            pass

    def signal(self, who: str, sig: signal.Signals, at: int, on: str) -> Act:
        self._aim(at, on)
        t0 = time.monotonic_ns()
        os.kill(self.pids[who], sig)
        return Act(t0, time.monotonic_ns())

    def spin(self, until: int) -> Act:
        """Keep the CPU this thread is on until ``until`` (its lower-priority threads wait)."""
        t0 = t = time.monotonic_ns()
        while t < until:
            t = time.monotonic_ns()
        return Act(t0, t)

    def stop(self, who: str, at: int, length: int, on: str, cont_on: str) -> tuple[Act, Act]:
        a = self.signal(who, signal.SIGSTOP, at, on)
        return a, self.signal(who, signal.SIGCONT, a.at + length, cont_on)


# --- what a test reads at an injection -------------------------------------------------------


def _row(cols: dict[str, np.ndarray], key: str, value: int) -> dict[str, int]:
    """The one row of a raw table whose ``key`` is ``value``."""
    i = np.nonzero(cols[key] == value)[0]
    assert i.size == 1, (key, value, i.size)
    return {k: v[i[0]].item() for k, v in cols.items()}


def _within(name: str, got: int, lo: int, hi: int, raw: RawRun) -> None:
    """``lo <= got <= hi`` (ns); on failure, with the host's own samples around ``got``."""
    if lo <= got <= hi:
        return
    host = ""
    try:
        rows = read_hoplog(raw.folder / "host.hoplog").table("host")
        near = [r for r in rows if abs(r["time_ns"] - got) <= 300 * MS]
        host = f"; the host's samples within 0.3 s: {near}"
    except (OSError, ValueError):
        pass
    raise AssertionError(
        f"{name} = {got / MS:.3f} ms, outside [{lo / MS:.3f}, {hi / MS:.3f}] ms{host}"
    )


def _threshold(raw: RawRun) -> int:
    """The stall threshold max(3 Ts, D*/2) (docs/realtime.md), D* from the run's scenario by
    controller_service.certificate, not read from the output it is checked against."""
    from controller_service.certificate import critical_age
    from hil.scenario import build_loop, load_scenario

    sc = load_scenario(raw.folder / "scenario.resolved.toml")
    _, _, context = build_loop(sc)
    boundary = sc.controller.get("law") == "unified_boundary"
    params = SimpleNamespace(**dict(sc.controller))
    d_star = critical_age(params, context, boundary, v0=sc.initial.v, w0=sc.initial.omega)
    return int(max(3 * raw.ts, 0.5 * d_star * 1e9))


def _stall_at(run: Run, before: int) -> tuple[dict, int]:
    """The stall made by an injection that left the command of the newest sample landed
    before ``before`` in force: (summary.json's stall, that sample). Its entry is checked
    against the raw landings: it crossed the threshold at that sample + the threshold, and its
    age is the largest of the stretch above the threshold (a landing whose own age is still
    above it continues the stretch): the peak before each next landing."""
    raw = run.raw
    lg = raw.landings(raw.cmd_path)
    thr = _threshold(raw)
    i = int(np.searchsorted(lg.land, before)) - 1
    ends = np.r_[lg.land[1:], raw.w1]
    peak, j = 0, i
    while True:
        peak = max(peak, int(ends[j] - lg.sample[j]))
        if j + 1 >= lg.land.size or lg.land[j + 1] - lg.sample[j + 1] <= thr:
            break
        j += 1
    assert run.summary["certificate"]["stall_threshold_s"] == thr / 1e9
    cross = (int(lg.sample[i]) + thr - raw.epoch) / 1e9
    found = [s for s in run.summary["certificate"]["stalls"] if abs(s["t_s"] - cross) < 1e-6]
    assert found, ("no stall entered at", cross, run.summary["certificate"]["stalls"])
    assert found[0]["age_s"] == pytest.approx(peak / 1e9, abs=1e-9), (found[0], peak)
    return found[0], int(lg.sample[i])


# --- the runs (module-scoped: each run serves several tests) -----------------------------------


@pytest.fixture(scope="module")
def base(tmp_path_factory) -> Run:
    """The control: a clean run."""
    tmp = tmp_path_factory.mktemp("base")
    return _run(tmp, _scenario(tmp))


def _stop_plan(who: str, deadline_s: float):
    """A 40 ms SIGSTOP of ``who`` LEAD_NS before its deadline at ``deadline_s``, aimed from the
    other service's CPU (its work is not due then), the SIGCONT from the stopped one's."""
    other = "plant" if who == "controller" else "controller"

    def plan(inj: Injector) -> dict[str, Act]:
        with inj.realtime():
            stop, cont = inj.stop(who, inj.ns(deadline_s) - LEAD_NS, STOP_NS, other, who)
        return {"stop": stop, "cont": cont}

    return plan


@pytest.fixture(scope="module")
def controller_stop(tmp_path_factory) -> Run:
    tmp = tmp_path_factory.mktemp("controller_stop")
    return _run(tmp, _scenario(tmp), plan=_stop_plan("controller", 2.0 + P / 2e9))


@pytest.fixture(scope="module")
def plant_stop(tmp_path_factory) -> Run:
    tmp = tmp_path_factory.mktemp("plant_stop")
    return _run(tmp, _scenario(tmp), plan=_stop_plan("plant", 2.0))


T0_A = 1.5  # s: the sample of injection (a) of the held run
T0_B = 3.0  # s: the sample of injection (b)
#: Injection (b) at each of these samples (by name): the test takes the first, in time, whose
#: State m arrived while the loop was held (a slow host's controller can be preempted holding
#: the GIL its Zenoh thread needs: State m then arrives only after the spin, and there is
#: nothing to measure; CI beside the vcan lane: at 3.0 s and at 3.5 s both)
T0_B_TRIES = (("b_early", 2.5), ("b", T0_B), ("b_again", 3.5), ("b_late", 3.75))
L_START, L_CTRL, L_PLANT, L_SPIN, L_PLANT_B = 16 * MS, 10 * MS, 14 * MS, 12 * MS, 8 * MS


def _held_plan(inj: Injector) -> dict[str, Act]:
    """Each action is aimed from a CPU whose service is stopped, or idle at that moment (the
    plant works from 0.15 ms before its even-ms samples, the controller from its odd-ms ticks).

    (0) The controller stopped across t = 0 (from -1 ms for L_START): the plant holds zero
    torque until its first command lands. (a) A State held by its receiver and the command
    computed from it held by its own: the controller stopped LEAD_NS before sample k (t0 =
    T0_A), the plant stopped LEAD_NS before sample k + 1 (State k has left, none after it);
    the controller let go L_CTRL after its stop receives State k and sends its command, which
    the plant, let go L_PLANT later, receives. (b) A State held in hand: the plant stopped
    LEAD_NS after sample m (t1: each of T0_B_TRIES); this thread spins on the controller's CPU
    from AIM_NS before that until L_SPIN after it: the controller's Zenoh threads receive State
    m on the other CPU, its loop (pinned) cannot tick until the spin ends; the plant is let go
    L_PLANT_B later."""
    t0 = inj.ns(T0_A)
    acts: dict[str, Act] = {}
    with inj.realtime():
        acts["start_stop"], acts["start_cont"] = inj.stop(
            "controller", inj.ns(0) - MS, L_START, "plant", "controller"
        )
        acts["a_ctrl_stop"] = inj.signal("controller", signal.SIGSTOP, t0 - LEAD_NS, "plant")
        # late enough for State k to have left the plant's process (its Zenoh thread sends it),
        # before the plant's next sample (CI: stopped 0.5 ms after, it held State k)
        acts["a_plant_stop"] = inj.signal("plant", signal.SIGSTOP, t0 + P - LEAD_NS, "controller")
        acts["a_ctrl_cont"] = inj.signal(
            "controller", signal.SIGCONT, acts["a_ctrl_stop"].at + L_CTRL, "controller"
        )
        acts["a_plant_cont"] = inj.signal(
            "plant", signal.SIGCONT, acts["a_ctrl_cont"].at + L_PLANT, "plant"
        )
        for b, t in ((b, inj.ns(t_s)) for b, t_s in T0_B_TRIES):
            acts[f"{b}_plant_stop"] = inj.signal("plant", signal.SIGSTOP, t + LEAD_NS, "controller")
            acts[f"{b}_spin"] = inj.spin(acts[f"{b}_plant_stop"].at + L_SPIN)
            acts[f"{b}_plant_cont"] = inj.signal(
                "plant", signal.SIGCONT, acts[f"{b}_spin"].by + L_PLANT_B, "plant"
            )
    return acts


@pytest.fixture(scope="module")
def held(tmp_path_factory) -> Run:
    tmp = tmp_path_factory.mktemp("held")
    return _run(tmp, _scenario(tmp), plan=_held_plan, duration=4.0)


@pytest.fixture(scope="module")
def loaded(tmp_path_factory) -> Run:
    """A constant delay on the applied path, a law 200 µs slower on every other sample, and
    seeded drops of States and commands: each moves figures the others do not."""
    tmp = tmp_path_factory.mktemp("loaded")
    law = f'law = "tests.busy_law:BusyUnified"\nbusy_us = {BUSY_US}\nbusy_every = 2\n'
    faults = "[faults]\nstate_drop_every = 10\ncommand_drop_every = 7\n"
    scenario = _scenario(tmp, faults, timing=f"delay = {DELAY_NS / 1e9}\n", controller=law)
    return _run(tmp, scenario)


# =================================================================================================
# Every figure in summary.json is the raw logs' evaluation of its definition
# =================================================================================================


def _check_against_raw(run: Run) -> None:
    check_summary_against_raw(run.summary, run.raw)


@pytest.mark.parametrize("name", ["base", "controller_stop", "plant_stop", "held", "loaded"])
def test_every_figure_is_its_definition_on_the_raw_logs(name, request):
    _check_against_raw(request.getfixturevalue(name))


# =================================================================================================
# A 40 ms SIGSTOP of the controller, LEAD_NS before its deadline at 2.001 s
# =================================================================================================


@dataclass(frozen=True)
class Held:
    """The slot a stop held (the first to wake after the SIGCONT), from the stopped service's
    raw log: its row index, deadline, wake-up, and the slots skipped after it."""

    i: int
    due: int
    wake: int
    skipped: int


def _held_slot(due: np.ndarray, wake: np.ndarray, skipped: np.ndarray, cont: Act) -> Held:
    i = int(np.searchsorted(wake, cont.at))
    assert i < wake.size and due[i] < cont.at, "no slot held by the stop"
    return Held(i, int(due[i]), int(wake[i]), int(skipped[i]))


def _check_held(run: Run, h: Held, what: str) -> None:
    """The held slot woke no earlier than the SIGCONT (a stopped process stamps nothing) and
    within RESUME_NS of it; its lateness is the stop's length less at most one period (a stop
    that lands just after a deadline holds the next slot, due up to a period into the stop;
    1 ms more for a signal's delivery on a loaded host); every slot due until it woke was
    skipped."""
    stop, cont = run.acts["stop"], run.acts["cont"]
    L = cont.at - stop.at
    lateness = h.wake - h.due
    print(
        f"\ncalibration {what} SIGSTOP L = {L / MS:.3f} ms: held slot due "
        f"{(h.due - run.raw.epoch) / 1e9:.4f} s woke {lateness / MS:.3f} ms late, "
        f"{h.skipped} slots skipped"
    )
    _within(
        f"{what} held slot's lateness",
        lateness,
        cont.at - h.due,
        cont.by + RESUME_NS - h.due,
        run.raw,
    )
    _within(f"{what} held slot's lateness against L", lateness, L - P - MS, L + RESUME_NS, run.raw)
    lo, hi = (cont.at - h.due) // P, (cont.by + RESUME_NS - h.due) // P
    assert lo <= h.skipped <= hi, (h.skipped, lo, hi)


@calibrates(
    "wakeup_lateness",
    injects="a 40 ms SIGSTOP of the controller (L: SIGSTOP to SIGCONT, measured), sent 0.5 ms "
    "before its deadline at 2.001 s",
    found="the held tick's lateness in [SIGCONT - its deadline, + 8 ms] and in [L - Ts - 1 ms, "
    "L + 8 ms] (a stop landing just after a deadline holds the next slot); the clean run's "
    "tick of that slot under Ts",
)
@calibrates(
    "skipped_slots",
    injects="a 40 ms SIGSTOP of the controller, sent 0.5 ms before its deadline at 2.001 s",
    found="at the held tick: (SIGCONT - its deadline) // Ts to (SIGCONT + 8 ms - its deadline) "
    "// Ts",
)
@calibrates(
    "period_jitter",
    injects="a 40 ms SIGSTOP of the controller, sent 0.5 ms before its deadline at 2.001 s",
    found="the held tick's jitter = its lateness - the previous tick's (both raw), so in "
    "[L - Ts - 1 ms - the previous lateness, L + 8 ms]; the next tick's is the held lateness "
    "less its own; the clean run's jitter there under Ts",
)
def test_a_controller_sigstop_is_its_held_ticks_lateness_and_jitter(controller_stop, base):
    raw, t = controller_stop.raw, controller_stop.timing
    tk = raw.ticks
    h = _held_slot(tk["deadline_ns"], tk["wake_ns"], tk["skipped"], controller_stop.acts["cont"])
    # The deadline is the grid's, epoch + k Ts + Ts/2: the stamp the lateness counts from.
    assert h.due == raw.epoch + int(tk["k"][h.i]) * P + P // 2
    _check_held(controller_stop, h, "controller")
    # The summary's figures are the raw log's: the held tick's lateness is among them.
    assert_same("wakeup_lateness", t["wakeup_lateness"], raw.wakeup_lateness())
    assert t["wakeup_lateness"]["max_us"] * 1000 >= h.wake - h.due
    assert t["skipped_slots"] == raw.ticks["skipped"][raw.win_ticks].sum() >= h.skipped
    # period_jitter: |wake_k - wake_(k-1) - (k - (k-1)) Ts| is the lateness's step.
    w = raw.win_ticks
    jit = raw.period_jitter()
    j = int(np.nonzero(np.nonzero(w)[0] == h.i)[0][0]) - 1  # the held tick's jitter entry
    prev = int(tk["wake_ns"][h.i - 1] - tk["deadline_ns"][h.i - 1])
    nxt = int(tk["wake_ns"][h.i + 1] - tk["deadline_ns"][h.i + 1])
    assert jit[j] == abs((h.wake - h.due) - prev) and jit[j + 1] == abs(nxt - (h.wake - h.due))
    L = controller_stop.acts["cont"].at - controller_stop.acts["stop"].at
    _within("the held tick's jitter", int(jit[j]), L - P - MS - prev, L + RESUME_NS, raw)
    assert_same("period_jitter", t["period_jitter"], jit)
    # Control: the clean run's tick of the same slot.
    b = base.raw.ticks
    same = np.nonzero(b["k"] == tk["k"][h.i])[0]
    assert same.size == 1 and b["wake_ns"][same[0]] - b["deadline_ns"][same[0]] < P, (
        "the clean run's tick of that slot was late too: the host stalled by itself"
    )


@calibrates(
    "deadline_misses",
    "slots",
    "deadline_miss_rate",
    injects="a 40 ms SIGSTOP of the controller, sent 0.5 ms before its deadline at 2.001 s",
    found="the held tick and the slots it skipped are the slots due until the SIGCONT, +0/+2; "
    "the totals are the raw log's late ticks plus skipped slots over its slots, exactly",
)
def test_a_controller_sigstop_misses_its_slots_and_fails_the_controller(controller_stop):
    raw, t, cont = controller_stop.raw, controller_stop.timing, controller_stop.acts["cont"]
    tk = raw.ticks
    h = _held_slot(tk["deadline_ns"], tk["wake_ns"], tk["skipped"], cont)
    passed = (cont.at - h.due) // P + 1  # its slots due until the SIGCONT
    assert passed <= 1 + h.skipped <= passed + 2, (h, passed)
    late, skipped = raw.wakeup_lateness(), raw.ticks["skipped"][raw.win_ticks]
    assert t["deadline_misses"] == (late >= P).sum() + skipped.sum() >= 1 + h.skipped
    assert t["slots"] == late.size + skipped.sum()
    assert t["deadline_miss_rate"] == t["deadline_misses"] / t["slots"]
    stall, _ = _stall_at(controller_stop, controller_stop.acts["cont"].at)
    assert (stall["cause"], stall["owner"]) == ("controller_late", "system"), stall
    verdict = controller_stop.summary["verdict"]
    assert verdict["outcome"] == "FAIL", verdict
    assert any("controller" in reason for reason in verdict["reasons"]), verdict


@calibrates(
    "command_age_zenoh (applied)",
    injects="a 40 ms SIGSTOP of the controller, sent 0.5 ms before its deadline at 2.001 s",
    found="the stall's age is the raw next landing - the sample in force, within [L, L + 2 Ts "
    "+ 8 ms + that command's own sample_to_apply]; it crossed the threshold max(3 Ts, D*/2) "
    "(D* from the scenario) after that sample; D = the raw largest age",
)
@calibrates(
    "samples_without_command",
    "samples_without_command_rate",
    injects="a 40 ms SIGSTOP of the controller, sent 0.5 ms before its deadline at 2.001 s",
    found="every judged sample taken while it was stopped is without a command, but for at "
    "most one per tick that woke from the SIGCONT until the newest was taken (each tick "
    "computes from one State); the rest are exactly the raw log's",
)
@calibrates(
    "sample_gap",
    injects="a 40 ms SIGSTOP of the controller, sent 0.5 ms before its deadline at 2.001 s",
    found="the gaps from the newest sample computed before the stop to the first landed at or "
    "after the last taken while stopped sum to [L - 2 Ts, L + 3 Ts + 8 ms], split only by "
    "samples computed after the SIGCONT; all gaps the raw log's",
)
def test_a_controller_sigstop_is_the_age_the_gap_and_the_samples_it_left(controller_stop):
    raw, t = controller_stop.raw, controller_stop.timing
    stop, cont = controller_stop.acts["stop"], controller_stop.acts["cont"]
    L = cont.at - stop.at
    stall, sample = _stall_at(controller_stop, cont.at)
    lg = raw.landings("zenoh")
    in_force = int(np.searchsorted(lg.sample, sample))
    own_s2a = int(lg.land[in_force] - sample)  # the command in force's own latency
    _within("the stall's age", round(stall["age_s"] * 1e9), L, L + 2 * P + RESUME_NS + own_s2a, raw)
    _, peak = raw.command_age("zenoh")
    assert t["command_age_zenoh"]["max_us"] == peak / 1000.0 >= stall["age_s"] * 1e6 - 1e-3
    assert controller_stop.summary["certificate"]["d_max_s"] == pytest.approx(peak / 1e9, abs=1e-9)
    # The samples taken while it was stopped: their States waited in its socket. Nothing was
    # computed while it was stopped, and each tick after the resume computes from one State
    # (the newest delivered by then: the Zenoh thread delivers the held ones as the loop ticks),
    # so those samples got no command but for as many as ticks woke from the SIGCONT to the
    # tick that took the last of them or a newer one.
    without = raw.samples_without_command()
    assert t["samples_without_command"] == without.size
    assert t["samples_without_command_rate"] == without.size / int(raw.judged().sum())
    s = raw.samples["sample_ns"]
    during = s[(s > stop.by) & (s < cont.at)]
    assert during.size >= (L - MS) // P - 1  # the plant kept sampling
    landed = np.unique(lg.sample)
    before = int(np.searchsorted(landed, stop.at)) - 1  # the newest computed before the stop
    after = int(np.searchsorted(landed, during[-1]))  # the first landed of the last or newer
    s_a, s_b = int(landed[before]), int(landed[after])
    tk = raw.ticks
    took = _row(tk, "state_seq", int(raw.samples["seq"][s == s_b][0]))
    woke = int(((tk["wake_ns"] >= cont.at) & (tk["wake_ns"] <= took["wake_ns"])).sum())
    between = landed[before + 1 : after]
    rows = [_row(tk, "state_sample_ns", int(x)) for x in between]
    assert all(r["compute_start_ns"] >= cont.at for r in rows)  # none computed while stopped
    print(f"calibration controller SIGSTOP: {during.size} samples while stopped, "
          f"{int(np.isin(during, landed).sum())} got a command ({woke} ticks woke until the "
          f"newest was taken)")  # fmt: skip
    assert np.isin(during, without).sum() >= during.size - woke
    assert between.size <= woke - 1
    # The sample gap: the gaps from the newest sample computed before the stop (its tick, Ts/2
    # after it, woke before the stop; its State may have come a period late) to the first
    # landed sample at or after the last one taken while stopped (sent before the SIGCONT, at
    # most a period before it; or a newer one, taken by a tick within a period of the resume)
    # span the stop; only the few samples counted above split it.
    gaps = raw.sample_gap()
    assert_same("sample_gap", t["sample_gap"], gaps)
    _within("the gaps across the stop", s_b - s_a, L - 2 * P, L + 3 * P + RESUME_NS, raw)
    if between.size == 0:
        assert t["sample_gap"]["max_us"] * 1000 >= s_b - s_a


# =================================================================================================
# A 40 ms SIGSTOP of the plant, LEAD_NS before its sample at 2.0 s
# =================================================================================================


@calibrates(
    "plant_wakeup_lateness",
    "plant_skipped_slots",
    injects="a 40 ms SIGSTOP of the plant, sent 0.5 ms before its sample at 2.0 s",
    found="as the controller's: the held sample's lateness in [SIGCONT - its slot, + 8 ms] "
    "and [L - Ts - 1 ms, L + 8 ms], its skipped slots those due until it woke",
)
@calibrates(
    "plant_sample_to_send",
    injects="a 40 ms SIGSTOP of the plant, sent 0.5 ms before its sample at 2.0 s",
    found="the held sample's State leaves in [SIGCONT - its slot, + 8 ms]; the clean run's "
    "State of that slot left within Ts",
)
@calibrates(
    "plant_deadline_misses",
    "plant_slots",
    "plant_deadline_miss_rate",
    injects="a 40 ms SIGSTOP of the plant, sent 0.5 ms before its sample at 2.0 s",
    found="the held sample and the slots skipped are those due until the SIGCONT, +0/+2; the "
    "totals the raw log's, exactly",
)
def test_a_plant_sigstop_is_its_held_samples_lateness_and_blamed_on_the_plant(plant_stop, base):
    raw, t, cont = plant_stop.raw, plant_stop.timing, plant_stop.acts["cont"]
    s = raw.samples
    h = _held_slot(s["sample_ns"], s["wake_ns"], raw.plant_skipped(), cont)
    assert h.due == raw.epoch + (h.due - raw.epoch) // P * P  # a slot of the epoch's grid
    _check_held(plant_stop, h, "plant")
    sent = int(s["send_ns"][h.i])
    _within(
        "the held State's sample_to_send",
        sent - h.due,
        cont.at - h.due,
        cont.by + RESUME_NS - h.due,
        raw,
    )
    for name in ("plant_wakeup_lateness", "plant_sample_to_send"):
        assert_same(name, t[name], FIGURES[name](raw))
    passed = (cont.at - h.due) // P + 1
    assert passed <= 1 + h.skipped <= passed + 2, (h, passed)
    plate, pskip = raw.plant_wakeup_lateness(), raw.plant_skipped()
    assert t["plant_deadline_misses"] == (plate >= P).sum() + pskip.sum() >= 1 + h.skipped
    assert t["plant_skipped_slots"] == pskip.sum() >= h.skipped
    assert t["plant_slots"] == plate.size + pskip.sum()
    assert t["plant_deadline_miss_rate"] == t["plant_deadline_misses"] / t["plant_slots"]
    stall, _ = _stall_at(plant_stop, cont.at)
    assert (stall["cause"], stall["owner"]) == ("plant_late", "bench"), stall
    verdict = plant_stop.summary["verdict"]
    assert verdict["outcome"] == "INCONCLUSIVE", verdict
    assert any("plant" in reason for reason in verdict["reasons"]), verdict
    # Control: the clean run's sample of that slot woke and sent on time.
    b = base.raw.samples
    same = np.nonzero(b["sample_ns"] - base.raw.epoch == h.due - raw.epoch)[0]
    assert same.size == 1 and b["send_ns"][same[0]] - b["sample_ns"][same[0]] < P, (
        "the clean run's sample of that slot was late too: the host stalled by itself"
    )


# =================================================================================================
# The held run: a late start, a State and a command held by their receivers, a State in hand
# =================================================================================================


@calibrates(
    "startup_hold_s",
    injects="the controller SIGSTOPped from t = -1 ms for 15 ms: no command before it resumes",
    found="first landing - first sample in [SIGCONT, SIGCONT + Ts + 8 ms] - first sample (its "
    "first tick computes the State in hand at the next slot); the clean run's under that floor",
)
def test_a_late_controller_start_is_the_startup_hold(held, base):
    raw, cont = held.raw, held.acts["start_cont"]
    assert raw.w0 == raw.epoch  # the plant's first sample is t = 0
    hold = round(held.timing["startup_hold_s"] * 1e9)
    _within("startup_hold", hold, cont.at - raw.w0, cont.by + P + RESUME_NS - raw.w0, raw)
    assert base.timing["startup_hold_s"] * 1e9 < cont.at - raw.w0, (
        "the clean run started as late: the host stalled by itself"
    )


@calibrates(
    "hop_state",
    injects="State k (sample at 1.5 s) sent while the controller was SIGSTOPped (10 ms, from "
    "0.5 ms before the sample) and none after it (the plant SIGSTOPped 1.5 ms after it)",
    found="its hop (controller receive - plant send) in [SIGCONT - send, SIGCONT + 8 ms - "
    "send]; the tick that computed from it carries that hop; the clean run's hops under Ts",
)
@calibrates(
    "hop_cmd_zenoh",
    "hop_cmd_can",
    injects="the command computed from State k, sent while the plant was SIGSTOPped (its "
    "SIGCONT 14 ms after the controller's); in the same run, the command of injection (b)",
    found="the Zenoh command's and both CAN frames' hops in [plant SIGCONT - send, + 8 ms]",
)
@calibrates(
    "state_send_to_cmd_recv",
    "loop_transport_compute",
    injects="State k (sample at 1.5 s) held by the SIGSTOPped controller, its command by the "
    "SIGSTOPped plant (let go 10 ms and 24 ms after the first stop)",
    found="plant receive - State send in [plant SIGCONT - send, + 8 ms]; the loop figure = "
    "its raw hop_state + compute + hop_cmd_zenoh, each within its own bounds",
)
@calibrates(
    "sample_to_apply_zenoh (applied)",
    "sample_to_apply_can (shadow)",
    injects="the command of State k held by the SIGSTOPped plant; delay 0, so it lands as it "
    "arrives",
    found="landing (Zenoh) and both frames' arrival (CAN shadow) - sample k in [plant "
    "SIGCONT - sample, + 8 ms]",
)
@calibrates(
    "command_age_can (shadow)",
    "sample_gap",
    injects="the command of State k held by the SIGSTOPped plant",
    found="the stall's age: next landing - the sample in force, in [plant SIGCONT - that "
    "sample, + 8 ms]; the gap from the last landed sample before the plant's SIGCONT (k, or "
    "k + 1, the slot it slept toward) to the next in [SIGCONT - k - Ts, SIGCONT + 8 ms + Ts - k]",
)
def test_a_held_state_and_command_are_their_hops(held, base):
    raw, a = held.raw, held.acts
    c_stop, p_stop, c_cont, p_cont = (
        a[k] for k in ("a_ctrl_stop", "a_plant_stop", "a_ctrl_cont", "a_plant_cont")
    )
    t0 = held.raw.epoch + round(T0_A * 1e9)
    state = _row(raw.samples, "sample_ns", t0)
    send = state["send_ns"]
    assert c_stop.by < send < p_stop.at, "State k did not leave between the two stops"
    rx = _row(raw.state_rx, "seq", state["seq"])
    _within("State k's receive", rx["recv_ns"], c_cont.at, c_cont.by + RESUME_NS, raw)
    tick = _row(raw.ticks, "state_seq", state["seq"])
    assert not tick["flags"] & TICK_NO_SEND
    hop_state = tick["state_recv_ns"] - tick["state_send_ns"]
    assert hop_state == rx["recv_ns"] - send
    _within("hop_state", hop_state, c_cont.at - send, c_cont.by + RESUME_NS - send, raw)
    # Its command left after the controller's SIGCONT, by the next slot, while the plant slept.
    zsend = tick["zenoh_send_ns"]
    _within("its command's send", zsend, c_cont.at, c_cont.by + P + RESUME_NS, raw)
    assert zsend < p_cont.at
    cmd = tick["cmd_seq"]
    z = raw.cmd_rx["path"] == int(CmdPath.ZENOH)
    recv = int(raw.cmd_rx["recv_ns"][z][raw.cmd_rx["seq"][z] == cmd].min())
    _within("hop_cmd_zenoh", recv - zsend, p_cont.at - zsend, p_cont.by + RESUME_NS - zsend, raw)
    _within(
        "state_send_to_cmd_recv", recv - send, p_cont.at - send, p_cont.by + RESUME_NS - send, raw
    )
    frames = raw.can_frames
    mine = np.nonzero((frames["cmd"] == cmd) & ~frames["duplicated"])[0]
    assert mine.size == 2, "both wheels' frames of the held command arrived"
    for i in mine.tolist():
        fs, fr = int(frames["send"][i]), int(frames["recv"][i])
        _within("hop_cmd_can", fr - fs, p_cont.at - fs, p_cont.by + RESUME_NS - fs, raw)
    # It landed as it arrived; the CAN shadow's arrival of both frames likewise.
    for path, land in (("zenoh", raw.landings("zenoh")), ("can", raw.landings("can"))):
        k = np.nonzero(land.cmd == cmd)[0]
        assert k.size == 1 and land.sample[k[0]] == t0, path
        _within(
            f"sample_to_apply_{path}",
            int(land.land[k[0]]) - t0,
            p_cont.at - t0,
            p_cont.by + RESUME_NS - t0,
            raw,
        )
    # The stall on the shadow path: the command of sample k - 1 in force until it arrived.
    shadow = raw.landings("can")
    i = int(np.searchsorted(shadow.land, p_cont.at)) - 1
    prev = int(shadow.sample[i])
    peak = int(shadow.land[i + 1] - prev)
    _within("command_age_can's stall", peak, p_cont.at - prev, p_cont.by + RESUME_NS - prev, raw)
    _, can_peak = raw.command_age("can")
    assert held.timing["command_age_can"]["max_us"] == can_peak / 1000.0 >= peak / 1000.0
    # The plant took sample k + 1 (the slot it slept toward) late and skipped the slots due
    # until it woke: the landed samples jump from k or k + 1 (whether k + 1's command landed or
    # a newer sample's superseded it) to the first slot after its wake.
    landed = np.unique(raw.landings("zenoh").sample)
    nxt = int(np.searchsorted(landed, p_cont.at))
    prev = int(landed[nxt - 1])
    assert prev in (t0, t0 + P), (prev - t0) / MS
    _within("the gap across the plant's stop", int(landed[nxt]) - prev, p_cont.at - t0 - P,
            p_cont.by + RESUME_NS + P - t0, raw)  # fmt: skip
    # Every figure is the raw logs' (the held values are in them).
    t = held.timing
    for name in (
        "hop_state",
        "hop_cmd_zenoh",
        "hop_cmd_can",
        "state_send_to_cmd_recv",
        "loop_transport_compute",
        "sample_to_apply_zenoh",
        "sample_to_apply_can",
        "sample_gap",
    ):
        assert_same(name, t[name], FIGURES[name](raw))
    assert t["hop_state"]["max_us"] * 1000 >= hop_state
    assert t["loop_transport_compute"]["max_us"] * 1000 >= (
        hop_state + tick["compute_end_ns"] - tick["compute_start_ns"] + recv - zsend
    )
    # Control: the clean run's hops are the transport's, under a period at the median.
    for name in ("hop_state", "hop_cmd_zenoh", "hop_cmd_can"):
        assert base.timing[name]["p50_us"] * 1000 < P < hop_state, name


def _in_hand(held: Run) -> tuple[int, dict, dict, Act, Act]:
    """(t1, State m, its receive, the spin, the plant's SIGCONT) of the first
    injection (b) whose State m left before the plant stopped and arrived while the loop was
    held: what the figures are then checked on."""
    raw, a, missed = held.raw, held.acts, []
    for b, t_s in T0_B_TRIES:
        stop, spin, cont = a[f"{b}_plant_stop"], a[f"{b}_spin"], a[f"{b}_plant_cont"]
        t1 = raw.epoch + round(t_s * 1e9)
        state = _row(raw.samples, "sample_ns", t1)
        rx = _row(raw.state_rx, "seq", state["seq"])
        if state["send_ns"] >= stop.at:
            missed.append(f"at {t_s} s State m had not left when the plant stopped")
        elif rx["recv_ns"] >= spin.by:
            missed.append(f"at {t_s} s State m arrived {rx['recv_ns'] - spin.by} ns after the spin")
        else:
            return t1, state, rx, spin, cont
    raise AssertionError("; ".join(missed))


@calibrates(
    "wait_for_tick",
    injects="State m (the first sample of 2.5, 3.0, 3.5, 3.75 s whose State came during the spin) "
    "in hand "
    "while the controller's loop cannot tick: the "
    "plant SIGSTOPped 0.5 ms after the sample (no newer State), this thread spinning at FIFO 90 "
    "on the controller's CPU for 12 ms (its Zenoh threads receive on the other CPU)",
    found="the tick that computed from State m: compute start - its receive in [spin end - "
    "receive, spin end + 8 ms - receive]; its lateness in [spin end - its deadline, + 8 ms]; "
    "the clean run's wait under Ts",
)
@calibrates(
    "hop_cmd_zenoh",
    injects="the command of State m, sent while the plant was still SIGSTOPped (8 ms after "
    "the spin)",
    found="its hop in [plant SIGCONT - send, + 8 ms]",
)
def test_a_state_in_hand_while_the_loop_is_held_is_the_wait_for_the_tick(held, base):
    raw = held.raw
    t1, state, rx, spin, cont = _in_hand(held)
    tick = _row(raw.ticks, "state_seq", state["seq"])
    assert tick["deadline_ns"] == t1 + P // 2  # the slot due during the spin
    wait = tick["compute_start_ns"] - tick["state_recv_ns"]
    assert tick["state_recv_ns"] == rx["recv_ns"]
    _within(
        "wait_for_tick", wait, spin.by - rx["recv_ns"], spin.by + RESUME_NS - rx["recv_ns"], raw
    )
    _within(
        "the held tick's lateness",
        tick["wake_ns"] - tick["deadline_ns"],
        spin.by - tick["deadline_ns"],
        spin.by + RESUME_NS - tick["deadline_ns"],
        raw,
    )
    zsend = tick["zenoh_send_ns"]
    assert zsend < cont.at
    z = raw.cmd_rx["path"] == int(CmdPath.ZENOH)
    recv = int(raw.cmd_rx["recv_ns"][z][raw.cmd_rx["seq"][z] == tick["cmd_seq"]].min())
    _within("hop_cmd_zenoh", recv - zsend, cont.at - zsend, cont.by + RESUME_NS - zsend, raw)
    assert_same("wait_for_tick", held.timing["wait_for_tick"], raw.wait_for_tick())
    assert held.timing["wait_for_tick"]["max_us"] * 1000 >= wait
    assert base.timing["wait_for_tick"]["p50_us"] * 1000 < P < wait


# =================================================================================================
# A constant delay, a law slower on every other sample, drops: one run, figures apart
# =================================================================================================


def _check_delay(raw: RawRun, path: CmdPath, delay: int) -> tuple[np.ndarray, np.ndarray]:
    """Every landing of ``path`` is its arrival + ``delay`` (the plant's model time), or later
    only where the plant's own time had already passed that (an arrival stamped by its reader
    but handed to the loop after the loop integrated past it): then it lands at the point the
    plant had reached, one of its processing points, a sensor slot or INTEGRATE_AFTER before
    one. Returns (apply, recv) of the landings."""
    from plant_emulator.service import INTEGRATE_AFTER_SAMPLE_NS

    ap = raw.apply
    m = (ap["path"] == int(path)) & np.isin(ap["outcome"], LANDED)
    apply, recv = ap["apply_ns"][m], ap["recv_ns"][m]
    later = apply != recv + delay
    phase = (apply[later] - raw.epoch) % raw.sensor_ts
    lead = min(INTEGRATE_AFTER_SAMPLE_NS, raw.sensor_ts // 2)
    print(
        f"\ncalibration delay {delay / MS} ms on {path.name}: {int((~later).sum())} of "
        f"{apply.size} landings exactly their arrival + delay; later, at the plant's own time: "
        f"{((apply[later] - recv[later] - delay) / MS).round(3).tolist()} ms"
    )
    assert (apply >= recv + delay).all()
    assert np.isin(phase, [0, raw.sensor_ts - lead]).all(), phase
    assert later.sum() <= 5, "more than a handful of landings at the plant's own time"
    return apply, recv


@calibrates(
    "sample_to_apply_zenoh (applied)",
    "late_commands",
    "late_commands_rate",
    injects="[timing] delay = 0.6 ms on the applied (Zenoh) path",
    found="every landing = its arrival + 0.6 ms (the plant's model time; later only at the "
    "plant's own time past it, at one of its processing points: a handful); the figure = the "
    "raw landing - sample; late commands at least those whose arrival - sample exceeds "
    "Ts - 0.6 ms, at most those and the ones landed later; in the clean run every landing is "
    "its arrival",
)
@calibrates(
    "command_age_zenoh (applied)",
    injects="[timing] delay = 0.6 ms (three plant steps) on the applied (Zenoh) path",
    found="the age's p50 = the p50 of the age computed from the arrivals (the test's own) + "
    "0.6 ms, within one plant step (the window's ends move a few steps)",
)
@calibrates(
    "sample_to_apply_can (shadow)",
    injects="[timing] delay = 0.6 ms on the applied (Zenoh) path: after the arrival, applied path "
    "only",
    found="the CAN shadow's arrival - sample is the raw log's, unmoved: no 0.6 ms in it",
)
def test_a_constant_delay_is_in_every_landing_and_in_no_arrival(loaded, base):
    raw, t = loaded.raw, loaded.timing
    assert raw.delay == DELAY_NS
    _check_delay(raw, CmdPath.ZENOH, DELAY_NS)
    _check_delay(base.raw, CmdPath.ZENOH, 0)  # control: no delay, each lands as it arrives
    # The figure: landing - sample, per command in force; its arrival, from the raw cmd_rx.
    lg = raw.landings("zenoh")
    w = raw.in_window(lg.sample)
    s2a = lg.land[w] - lg.sample[w]
    assert_same("sample_to_apply_zenoh", t["sample_to_apply_zenoh"], s2a)
    z = raw.cmd_rx["path"] == int(CmdPath.ZENOH)
    seq, first = np.unique(raw.cmd_rx["seq"][z], return_index=True)
    arr = raw.cmd_rx["recv_ns"][z][first][np.searchsorted(seq, lg.cmd[w])]
    assert (seq[np.searchsorted(seq, lg.cmd[w])] == lg.cmd[w]).all()
    judged = lg.sample[w] <= raw.w1 - raw.settle
    floor = int(((arr - lg.sample[w] > P - DELAY_NS) & judged).sum())
    later = int(((s2a != arr + DELAY_NS - lg.sample[w]) & judged).sum())
    print(
        f"calibration delay: late commands {t['late_commands']} (arrival > Ts - delay: "
        f"{floor}; > Ts: {int(((arr - lg.sample[w] > P) & judged).sum())})"
    )
    assert floor <= t["late_commands"] <= floor + later
    assert t["late_commands"] == raw.late_commands().size
    assert t["late_commands_rate"] == t["late_commands"] / int(raw.judged().sum())
    # The age, against the age of the same commands at their arrivals (computed here).
    ages, _ = raw.command_age("zenoh")
    at_arrival = _ages(raw, arr, lg.sample[w])
    p50 = np.percentile(ages, 50, method="inverted_cdf")
    moved = p50 - np.percentile(at_arrival, 50, method="inverted_cdf")
    assert abs(moved - DELAY_NS) <= raw.h, moved
    assert t["command_age_zenoh"]["p50_us"] * 1000 == p50
    # The CAN shadow is the arrival's: the delay is not in it.
    assert_same("sample_to_apply_can", t["sample_to_apply_can"], raw.sample_to_apply("can"))


def _ages(raw: RawRun, land: np.ndarray, sample: np.ndarray) -> np.ndarray:
    """The age at the plant's steps of the window had the commands landed at ``land``."""
    order = np.argsort(land, kind="stable")
    land, sample = np.r_[raw.w0, land[order]], np.r_[raw.w0, sample[order]]
    grid = np.arange(raw.w0, raw.w1, raw.h, dtype=np.int64)
    return grid - sample[np.searchsorted(land, grid, side="right") - 1]


@calibrates(
    "compute",
    injects="a user's law that busy-waits 200 µs after the unified law on every other sample "
    "(tests/busy_law.py, busy_every = 2)",
    found="every busy tick's compute >= 200 µs (a spin of perf_counter); their p50 - 200 µs "
    "between the other ticks' p10 and p90 (the same law without the wait, a tick away); the "
    "other ticks' p50 under 200 µs",
)
def test_a_law_slower_on_every_other_sample_is_200us_more_compute_there(loaded):
    raw, t = loaded.raw, loaded.timing
    tk, f = raw.ticks, raw.fresh
    compute = tk["compute_end_ns"][f] - tk["compute_start_ns"][f]
    k = np.rint((tk["state_sample_ns"][f] - raw.epoch) / P).astype(np.int64)
    busy, idle = compute[k % 2 == 0], compute[k % 2 == 1]
    q = lambda v, p: np.percentile(v, p, method="inverted_cdf")  # noqa: E731
    print(
        f"\ncalibration law +{BUSY_US:.0f} us on even samples: compute p50 busy "
        f"{q(busy, 50) / 1e3:.1f} us, idle {q(idle, 50) / 1e3:.1f} us (p10-p90 "
        f"{q(idle, 10) / 1e3:.1f}-{q(idle, 90) / 1e3:.1f})"
    )
    assert busy.size > 800 and idle.size > 800
    assert busy.min() >= BUSY_US * 1000
    assert q(idle, 10) <= q(busy, 50) - BUSY_US * 1000 <= q(idle, 90)
    assert q(idle, 50) < BUSY_US * 1000
    assert_same("compute", t["compute"], compute)


@calibrates(
    "samples_without_command",
    "samples_without_command_rate",
    injects="[faults] state_drop_every = 10, command_drop_every = 7 (the services log each)",
    found="every judged sample whose State or command was dropped is without a command; the "
    "others without one are exactly those the raw logs show",
)
@calibrates(
    "sample_gap",
    injects="[faults] state_drop_every = 10, command_drop_every = 7",
    found="each dropped sample whose neighbours landed is one gap of exactly 2 Ts",
)
def test_dropped_states_and_commands_are_the_samples_without_command(loaded):
    raw, t = loaded.raw, loaded.timing
    s = raw.samples
    judged = raw.judged()
    dropped_states = s["sample_ns"][judged & ((s["flags"] & SAMPLE_DROPPED) != 0)]
    tk = raw.ticks
    dropped_cmds = tk["state_sample_ns"][(tk["flags"] & TICK_DROPPED) != 0]
    # (a watchdog's zero torque, computed from no sample, can be dropped too: not a sample's)
    dropped_cmds = dropped_cmds[raw.in_window(dropped_cmds) & (dropped_cmds <= raw.w1 - raw.settle)]
    injected = np.union1d(dropped_states, dropped_cmds)
    without = raw.samples_without_command()
    print(
        f"\ncalibration drops: {dropped_states.size} States and {dropped_cmds.size} commands "
        f"dropped among judged samples; samples without a command {t['samples_without_command']}"
    )
    assert dropped_states.size > 150 and dropped_cmds.size > 150
    assert np.isin(injected, without).all()
    assert t["samples_without_command"] == without.size >= injected.size
    assert t["samples_without_command_rate"] == without.size / int(judged.sum())
    landed = set(np.unique(raw.landings("zenoh").sample).tolist())
    gaps = raw.sample_gap()
    assert_same("sample_gap", t["sample_gap"], gaps)
    singles = [x for x in injected.tolist() if x - P in landed and x + P in landed]
    assert len(singles) > 200
    pairs = set(
        zip(
            np.unique(list(landed))[:-1].tolist(),
            np.diff(np.unique(list(landed))).tolist(),
            strict=True,
        )
    )
    assert all((x - P, 2 * P) in pairs for x in singles)


def test_injected_drops_are_the_lost_counts_exactly(loaded):
    st, cmd = loaded.summary["messages"]["state"], loaded.summary["messages"]["torque_zenoh"]
    assert st["injected_drops"] > 200 and cmd["injected_drops"] > 100
    print(
        f"\ncalibration drops: states injected {st['injected_drops']} lost {st['lost']}; "
        f"commands injected {cmd['injected_drops']} lost {cmd['lost']}"
    )
    assert st["lost"] == st["injected_drops"], st
    assert cmd["lost"] == cmd["injected_drops"], cmd


# =================================================================================================
# The applied CAN path: a delay, and a re-arm mid-run
# =================================================================================================


@calibrates(
    "sample_to_apply_can (applied)",
    "command_age_can (applied)",
    injects="[timing] delay = 0.6 ms on the applied CAN path (--cmd-path can), and a 0.3 s "
    "plant SIGSTOP past the drives' heartbeat timeout (a re-arm)",
    found="every frame lands its arrival + 0.6 ms (later only at the plant's own time past it, "
    "at one of its processing points: a handful); a command lands when both wheels' "
    "frames have: the figure = the raw latest landing of its two frames - its sample; the "
    "age = the raw grid's; the Zenoh shadow's arrival has no delay in it",
)
def test_the_applied_can_path_lands_each_frame_its_delay_after_its_arrival(spawn, tmp_path):
    """Also: a plant stalled past the drives' heartbeat timeout makes the controller re-arm
    them mid-run: the lifecycle's zero torques must not count as commands nor shift the
    matching."""
    out = tmp_path / "run"
    scenario = _scenario(
        tmp_path, "[can]\nheartbeat_timeout = 0.1\n", timing=f"delay = {DELAY_NS / 1e9}\n"
    )
    proc = _start(spawn, out, scenario, "--no-report", "--cmd-path", "can")
    inj = Injector(out, proc)
    with inj.realtime():
        inj.stop("plant", inj.ns(2.0), 300 * MS, "controller", "plant")
    s = _finish(proc, out)
    raw = RawRun(out)
    _check_delay(raw, CmdPath.CAN, DELAY_NS)
    t = s["timing"]
    assert_same("sample_to_apply_can", t["sample_to_apply_can"], raw.sample_to_apply("can"))
    ages, peak = raw.command_age("can")
    want = stats(ages)
    assert (t["command_age_can"]["p50_us"], t["command_age_can"]["max_us"]) == (
        want["p50_us"],
        peak / 1000.0,
    )
    assert_same("sample_to_apply_zenoh", t["sample_to_apply_zenoh"], raw.sample_to_apply("zenoh"))
    assert_same("hop_cmd_can", t["hop_cmd_can"], raw.hop_cmd_can())
    assert s["can"]["controller"]["rearms"] >= 1, s["can"]
    can = s["messages"]["torque_can"]
    assert can["lifecycle_frames_sent"] > 4  # the re-arm's zeros were sent ...
    assert can["unmatched_frames_received"] == 0  # ... and every arrival matched its send
    assert can["frames_received"] == can["frames_sent"] and can["lost"] == 0, can
    assert can["value_mismatches"] == 0  # every arrival matched the send of its own torque
    assert can["unaccounted"] == 0, can  # every received command applied, refused or late
    assert "negative" not in t["hop_cmd_can"]  # nor a send after its arrival
    _every_frame_carries_its_commands_torque(raw, scenario)


def _every_frame_carries_its_commands_torque(raw: RawRun, scenario: Path) -> None:
    """The torque in each frame a drive received is the one the controller computed for the
    command of the send of its name (via the wheel mapping)."""
    import math

    from hil.scenario import load_scenario
    from protocol.can.wheel_mapping import RobotGeometry, motor_torques

    sc = load_scenario(scenario)
    geom = RobotGeometry(
        **{
            k: getattr(sc.robot, k)
            for k in ("mass", "yaw_inertia", "wheel_radius", "half_track", "gear_ratio")
        }
    )
    frames, rx = raw.can_frames, raw.cmd_rx
    value = rx["tau1"][(rx["path"] == int(CmdPath.CAN)) & (rx["verdict"] != 3)]
    tau = {
        int(q): (a, b)
        for q, a, b in zip(raw.ticks["cmd_seq"], raw.ticks["tau1"], raw.ticks["tau2"], strict=True)
        if q >= 0
    }
    right, checked = int(sc.can.node_right), 0
    for i in np.nonzero(frames["cmd"] >= 0)[0].tolist():
        q = motor_torques(geom, *tau[int(frames["cmd"][i])])
        want = q.right if int(frames["node"][i]) == right else q.left
        assert math.isclose(value[i], want, rel_tol=1e-5, abs_tol=1e-6), (i, value[i], want)
        checked += 1
    assert checked > 1000


# =================================================================================================
# Replay reads the same latencies from the folder and from the recording
# =================================================================================================


def test_replay_from_the_recording_equals_replay_from_the_folder(tmp_path):
    from hil.analysis.replay import latencies_from_run

    out = tmp_path / "run"
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "hil",
            "run",
            "--duration",
            "2",
            "--quiet",
            "--no-report",
            "--out",
            str(out),
        ],
        capture_output=True,
        text=True,
        timeout=240,
    )
    outcome = json.loads((out / "summary.json").read_text())["verdict"]["outcome"]
    assert proc.returncode == expected_exit(outcome), proc.stderr[-3000:]
    for path in ("zenoh", "can"):
        a = latencies_from_run(f"{out}::{path}")
        b = latencies_from_run(f"{out / 'recording.mcap'}::{path}")
        assert a.size > 500 and (a == b).all(), path


def test_the_command_age_covers_every_plant_step_from_the_first_sample(base):
    age = base.timing["command_age_zenoh"]
    steps = -(-(base.raw.w1 - base.raw.w0) // base.raw.h)  # the plant's steps in the window
    assert age["count"] == steps, (age["count"], steps)
    assert base.summary["certificate"]["d_max_s"] >= base.timing["startup_hold_s"]
