"""The kill matrix: each failure injected into real runs, repeated, reported as counts.

    python bench/kill_matrix.py [--trials 20] [--kinds controller_kill_zenoh ...] [--out FILE]

Kinds (each trial is one ``hil run`` of 3 s at 200 Hz, ``controller_restart``'s longer:
RESTART_DURATION_S; the failure injected by PID at the trial's seeded moment: trial i of a kind
strikes at ``fault_at_s(kind, i)`` after the epoch, drawn from ``random.Random(f"{kind}/{i}")``
over the kind's window, FAULT_WINDOW_S; the trial fails if the fault struck more than 0.25 s
after it, or before 20 commands had landed):

- ``controller_kill_zenoh`` / ``controller_kill_can``: SIGKILL of the controller; safe state =
  the plant holds zero torque (its command timeout), on the wall clock at most
  command_timeout + 2 periods after the last command arrived; on the CAN path the drives'
  watchdog is armed (``[can] watchdog_timeout`` = 1 s) and both drives must also end IDLE
  with WATCHDOG_TIMER_EXPIRED latched as their disarm reason;
- ``plant_kill``: SIGKILL of the plant; safe state = the controller's stale-state watchdog sends
  zero torque flagged WATCHDOG_ZERO, at most state_timeout + 2 periods after the last state;
- ``controller_restart``: SIGKILL of the controller, then a new one started with the run's
  settings (a process started with the trial, its modules imported, let go at the kill: what
  is timed is the service's restart, not the host's Python imports); it rejoins the run:
  commands land again, none computed from a sample older than the restart;
- ``router_restart``: router mode; the Zenoh router is SIGKILLed and started again on its
  port; both services (clients) reconnect by themselves, commands land again, none computed
  from a sample taken before the router came back;
- for both restarts the outage is timed from the kill to the first landing (plant hop log
  ``apply``) of a command computed from a sample taken after the kill, and the worst stall the
  run's summary.json names (``certificate.stalls``) must be that outage: in time, it starts
  within ±50 ms of the kill and ends (where its age peaks) within ±50 ms of that first
  landing; in size, its largest command age is within ±20 % of the outage;
- ``hil_run_kill``: SIGKILL of ``hil run`` itself in a 2 s run at 1 kHz, from 0.1 s in to
  0.5 s after its end; safe state = every process it started has exited by itself (checked by
  PID), the time given is from the kill to the last one gone; ``hil report`` on the folder
  recovers it (exit 0 or 1, never 2), and after recovery no State the plant sent before the
  kill is missing from the recording (what the recorder's queue held is restored from the
  plant's hop log by ``hil recover``). tests/test_kill_matrix.py runs these trials beside a CPU
  hog (``--hog N`` here).

Prints a table (trials, passed, worst time to the safe state or outage) and JSON; the test
tests/test_kill_matrix.py runs the same trials and asserts that every one passes.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import random
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from hil.bench.lifecycle import GONE_GRACE_S  # noqa: E402  (how long hil run awaits a restart)
from hil.verdict import EXIT_CODE  # noqa: E402  (a verdict's codes: the command worked)
from protocol.can.codec import AxisState, ODriveError  # noqa: E402
from protocol.hoplog import read_hoplog  # noqa: E402
from protocol.messages import FLAG_WATCHDOG_ZERO  # noqa: E402
from tests.procs import stop_pid, wait_until  # noqa: E402
from tests.run_helpers import alive, children_of  # noqa: E402

RATE = 200
PERIOD_NS = round(1e9 / RATE)
DURATION_S = 3.0
# The drives' watchdog on the CAN path. The controller arms the drives before the run's epoch
# and feeds them from its first command, up to ~0.4 s later: a watchdog shorter than that gap
# trips at start-up (a 50 ms one did, in about a third of the trials). After the kill it trips
# 1 s after the last frame, well inside the 3 s run, after the plant's 50 ms command timeout.
WATCHDOG_S = 1.0
KINDS = (
    "controller_kill_zenoh",
    "controller_kill_can",
    "plant_kill",
    "controller_restart",
    "router_restart",
    "hil_run_kill",
)


# When each kind's fault strikes, in seconds after the run's epoch: trial i draws its moment
# uniformly from this window with ``random.Random(f"{kind}/{i}")`` (:func:`fault_at_s`). Each
# window starts after the closed loop has run (0.3 s: 60 commands at 200 Hz) and ends early
# enough for the safe state to be observed inside the run: 20 zero-torque samples after the
# command timeout (controller killed, Zenoh), the drives' 1 s watchdog (CAN), the state timeout
# (plant killed), and for the restarts time for a restart and 20 landings after it (the router's:
# at least 1.8 s; the controller's: hil run's whole grace, RESTART_DURATION_S).
FAULT_WINDOW_S: dict[str, tuple[float, float]] = {
    "controller_kill_zenoh": (0.3, 2.5),
    "controller_kill_can": (0.3, 1.6),
    "plant_kill": (0.3, 2.5),
    "controller_restart": (0.3, 1.0),
    "router_restart": (0.3, 1.2),
    "hil_run_kill": (0.1, 2.5),  # 2 s run at 1 kHz: from 0.1 s in to 0.5 s after its end
}
# The bench's own sleep to the moment may overshoot on a loaded host; later than this AND
# past the kind's window (whose end leaves the run time to show the safe state) and the trial
# did not test what it is for.
FAULT_LATE_MAX_S = 0.25
# Restart trials: the stall the run's summary names must match the measured outage.
STALL_TIME_TOL_S = 0.050
STALL_SIZE_TOL = 0.20


def fault_at_s(kind: str, seed: int) -> float:
    """Trial ``seed``'s moment of the fault for ``kind`` (s after the epoch, 0.1 ms resolution):
    reproducible from the seed, spread over the kind's window across trials."""
    lo, hi = FAULT_WINDOW_S[kind]
    return round(random.Random(f"{kind}/{seed}").uniform(lo, hi), 4)


@dataclass
class Trial:
    kind: str
    ok: bool = False
    safe_s: float | None = None  # time to the safe state, or the outage for restarts
    detail: dict[str, Any] = field(default_factory=dict)


def _stop(proc: subprocess.Popen) -> None:
    stop_pid(proc, grace=10.0)


class _Run:
    """One ``hil run`` and whatever the trial starts beside it, all stopped by PID."""

    def __init__(
        self,
        out: Path,
        *args: str,
        scenario: str | None = None,
        duration_s: float = DURATION_S,
        rate: float = RATE,
    ) -> None:
        self.out = out
        self.extra: list[subprocess.Popen] = []
        argv = [sys.executable, "-m", "hil", "run"]
        if scenario is not None:
            argv.append(scenario)
        argv += ["--duration", str(duration_s), "--rate", str(rate), "--quiet", "--no-report"]
        argv += ["--out", str(out), *args]
        self.proc = subprocess.Popen(
            argv, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
            start_new_session=True,
        )  # fmt: skip

    def __enter__(self) -> _Run:
        return self

    def __exit__(self, *exc: object) -> None:
        for p in [*self.extra, self.proc]:
            _stop(p)

    def epoch(self, t: Trial) -> int | None:
        """The run's epoch once the plant has logged it (None, with the reason in ``t``)."""
        if not wait_until(lambda: _epoch_ns(self.out) is not None, 120):
            t.detail["error"] = "the run never started"
            return None
        return _epoch_ns(self.out)

    def sleep_until(self, epoch: int, at_s: float, t: Trial) -> bool:
        """Sleep until ``at_s`` after ``epoch`` (the trial's seeded moment); False (with the
        reason in ``t``) when ``hil run`` has already ended by then."""
        t.detail["fault_at_s"] = at_s
        time.sleep(max(0.0, (epoch + int(at_s * 1e9) - time.monotonic_ns()) / 1e9))
        if self.proc.poll() is not None:
            t.detail["error"] = "hil run had already finished at the chosen moment"
            return False
        return True

    def pid(self, name: str) -> int:
        return int(json.loads((self.out / "processes.json").read_text())[name])

    def kill(self, name: str) -> int:
        pid = self.pid(name)
        t = time.monotonic_ns()
        os.kill(pid, signal.SIGKILL)
        if not wait_until(lambda: not alive(pid), 10):
            raise RuntimeError(f"{name} (pid {pid}) survived SIGKILL")
        return t

    def kill_at(self, name: str, at_s: float, t: Trial) -> int | None:
        """SIGKILL of ``name`` at ``at_s`` after the epoch; the kill's time (None: no kill)."""
        epoch = self.epoch(t)
        if epoch is None or not self.sleep_until(epoch, at_s, t):
            return None
        kill_ns = self.kill(name)
        _mark_fault(t, epoch, kill_ns)
        return kill_ns

    def start(self, argv: list[str], log: str) -> subprocess.Popen:
        with open(self.out / log, "wb") as f:
            p = subprocess.Popen(argv, cwd=ROOT, stdout=f, stderr=subprocess.STDOUT,
                                 start_new_session=True)  # fmt: skip
        self.extra.append(p)
        return p

    def finish(self) -> dict[str, Any]:
        self.proc.wait(timeout=240)
        return json.loads((self.out / "summary.json").read_text())


def _mark_fault(t: Trial, epoch: int, fault_ns: int) -> None:
    """Record when the fault really struck; too late after the seeded moment and past the
    kind's window fails the trial (a late strike inside the window still tests the kind: the
    run goes on long enough to show the safe state after any moment of it)."""
    done = t.detail["fault_done_at_s"] = round((fault_ns - epoch) / 1e9, 4)
    late = t.detail["fault_late_s"] = round(done - t.detail["fault_at_s"], 4)
    if late > FAULT_LATE_MAX_S and done > FAULT_WINDOW_S[t.kind][1]:
        t.detail["error"] = "the fault struck too late after its seeded moment"


def _looped_before(stamps: list[int], kill_ns: int, t: Trial, least: int = 20) -> bool:
    """The closed loop ran before the fault: at least ``least`` of ``stamps`` (landings, or
    states received) before it."""
    before = sum(1 for x in stamps if x < kill_ns)
    t.detail["loop_before_fault"] = before
    if before < least:
        t.detail["error"] = f"no closed loop before the fault ({before} before it)"
    return before >= least


def _with_tables(tmp: Path, name: str, tables: str) -> str:
    """The paper's scenario with extra TOML tables, as a file for ``hil run``."""
    scen = tmp / name
    scen.write_text((ROOT / "hil" / "scenarios" / "paper_tracking.toml").read_text() + tables)
    return str(scen)


def _drives_disarmed_by_watchdog(plant: Any, t: Trial) -> bool:
    """Every virtual drive left closed loop with ODrive's WATCHDOG_TIMER_EXPIRED latched (its
    footer, written when the plant exits: the drives' own state, not the plant's zeroing)."""
    drives = ((plant.final or {}).get("can") or {}).get("drives") or {}
    events = ((plant.final or {}).get("can") or {}).get("events") or {}
    t.detail["drives"] = {
        n: {"axis_state": d.get("axis_state"), "disarm_reason": d.get("disarm_reason")}
        for n, d in drives.items()
    }
    t.detail["watchdog_expired_events"] = events.get("watchdog_expired", 0)
    return (
        len(drives) == 2
        and all(
            d.get("axis_state") == AxisState.IDLE
            and int(d.get("disarm_reason") or 0) & ODriveError.WATCHDOG_TIMER_EXPIRED
            for d in drives.values()
        )
        and events.get("watchdog_expired", 0) >= len(drives)
    )


def controller_kill(tmp: Path, path: str, seed: int) -> Trial:
    t = Trial(f"controller_kill_{path}")
    scenario = None
    if path == "can":
        # The drives' own watchdog, as on a real ODrive (axis.config.watchdog_timeout): it
        # disarms them when the controller's frames stop, whatever the plant does.
        scenario = _with_tables(tmp, "watchdog.toml", f"\n[can]\nwatchdog_timeout = {WATCHDOG_S}\n")
    with _Run(tmp / "run", "--cmd-path", path, scenario=scenario) as run:
        kill_ns = run.kill_at("controller", fault_at_s(t.kind, seed), t)
        if kill_ns is None:
            return t
        summary = run.finish()
    plant = read_hoplog(tmp / "run" / "plant.hoplog")
    if not _looped_before([a["apply_ns"] for a in plant.table("apply")], kill_ns, t):
        return t
    timeout_ns = int(plant.meta["command_timeout_s"] * 1e9)
    last = max(r["recv_ns"] for r in plant.table("apply"))
    zeros = [z for z in plant.table("zero") if z["timeout_ns"] >= last]
    if not zeros:
        t.detail["error"] = "the plant never zeroed the torque"
        return t
    t.safe_s = (zeros[0]["applied_ns"] - last) / 1e9
    after = [s for s in plant.table("samples") if s["sample_ns"] > last + timeout_ns]
    t.ok = (
        zeros[0]["timeout_ns"] - last == timeout_ns
        and zeros[0]["applied_ns"] - last <= timeout_ns + 2 * PERIOD_NS
        and len(after) > 20
        and all(s["cmd1"] == 0.0 and s["cmd2"] == 0.0 for s in after)
        and "error" not in t.detail
    )
    if path == "can":
        t.ok = _drives_disarmed_by_watchdog(plant, t) and t.ok
    t.detail["zeroed_after_ms"] = t.safe_s * 1e3
    t.detail["watchdog"] = summary.get("watchdog")
    return t


def plant_kill(tmp: Path, seed: int) -> Trial:
    t = Trial("plant_kill")
    with _Run(tmp / "run") as run:
        kill_ns = run.kill_at("plant", fault_at_s(t.kind, seed), t)
        if kill_ns is None:
            return t
        run.proc.wait(timeout=240)
    # The controller's log (complete: it exits cleanly), not the killed plant's: states arrived.
    ctrl = read_hoplog(tmp / "run" / "controller.hoplog")
    if not _looped_before([r["recv_ns"] for r in ctrl.table("state_rx")], kill_ns, t):
        return t
    timeout_ns = int(ctrl.meta["state_timeout_s"] * 1e9)
    last = max(r["recv_ns"] for r in ctrl.table("state_rx"))
    zero = [
        r for r in ctrl.table("ticks") if r["flags"] & FLAG_WATCHDOG_ZERO and r["wake_ns"] > last
    ]
    if not zero:
        t.detail["error"] = "the controller never sent a watchdog zero"
        return t
    t.safe_s = (zero[0]["zenoh_send_ns"] - last) / 1e9
    t.ok = zero[0]["tau1"] == 0.0 and zero[0]["tau2"] == 0.0 and "error" not in t.detail
    t.ok = t.ok and zero[0]["zenoh_send_ns"] - last <= timeout_ns + 2 * PERIOD_NS
    t.detail["flagged_zero_after_ms"] = t.safe_s * 1e3
    return t


def _stall_matches(cert: dict[str, Any], epoch: int, kill_ns: int, back_ns: int,
                   t: Trial) -> bool:  # fmt: skip
    """The worst stall the run's summary names is the outage [kill, back]: in time, it starts
    within STALL_TIME_TOL_S of the kill and ends (where its age peaks: the landing that ends it)
    within STALL_TIME_TOL_S of ``back_ns``; in size, its largest command age is the outage's
    within STALL_SIZE_TOL (the age also counts the last command's sample-to-landing time before
    the kill, a few ms). A stall's ``t_s`` is when the age crossed ``stall_threshold_s``, so
    the excursion started that much earlier (hil.analysis.measure's find_stalls)."""
    stalls = cert.get("stalls") or []
    threshold = cert.get("stall_threshold_s")
    if not stalls or threshold is None:
        t.detail["error"] = "the run's summary names no stall"
        return False
    worst = stalls[0]
    start_ns = epoch + round((worst["t_s"] - threshold) * 1e9)
    end_ns = start_ns + round(worst["age_s"] * 1e9)
    outage = back_ns - kill_ns
    t.detail["stall"] = {
        **{k: worst.get(k) for k in ("t_s", "age_s", "cause")},
        "starts_after_kill_ms": round((start_ns - kill_ns) / 1e6, 2),
        "ends_after_back_ms": round((end_ns - back_ns) / 1e6, 2),
        "size_to_outage": round(worst["age_s"] * 1e9 / outage, 3),
        "stalls_listed": len(stalls),
    }
    return (
        abs(start_ns - kill_ns) <= STALL_TIME_TOL_S * 1e9
        and abs(end_ns - back_ns) <= STALL_TIME_TOL_S * 1e9
        and abs(worst["age_s"] * 1e9 - outage) <= STALL_SIZE_TOL * outage
    )


def _resumed(tmp: Path, kill_ns: int, since_ns: int, t: Trial) -> Trial:
    """Commands land again after the kill; none landing after ``since_ns`` (the service back)
    was computed from an older sample; the outage (``safe_s``), from the kill to the first
    landing of a command computed from a sample taken after it (commands in flight at the kill
    may land just after it), is the worst stall named in the run's summary.json."""
    ctrl = read_hoplog(tmp / "run" / "controller.hoplog")
    plant = read_hoplog(tmp / "run" / "plant.hoplog")
    sample_of = {
        r["cmd_seq"]: r["state_sample_ns"] for r in ctrl.table("ticks") if r["cmd_seq"] >= 0
    }
    landed = [a for a in plant.table("apply") if a["outcome"] == 0]
    if not _looped_before([a["apply_ns"] for a in landed], kill_ns, t):
        return t
    after = [a for a in landed if a["apply_ns"] > since_ns]
    stale = [a for a in after if sample_of.get(a["seq"], 0) < since_ns]
    again = [a for a in landed if a["apply_ns"] > kill_ns and sample_of.get(a["seq"], 0) > kill_ns]
    t.detail["landed_after"] = len(after)
    t.detail["stale_after"] = len(stale)
    if not again:
        t.detail["error"] = "no command landed again after the kill"
        return t
    back = min(int(a["apply_ns"]) for a in again)
    t.safe_s = (back - kill_ns) / 1e9
    summary = json.loads((tmp / "run" / "summary.json").read_text())
    epoch = int(plant.meta["epoch_ns"])
    matched = _stall_matches(summary.get("certificate") or {}, epoch, kill_ns, back, t)
    t.ok = len(after) >= 20 and not stale and matched and "error" not in t.detail
    return t


# hil run follows a restarted controller to the run's end only if it rejoins within
# GONE_GRACE_S of the kill (hil.bench.lifecycle; else it ends the run, as documented). So the
# restart trial's run lasts past the latest kill (the window's end, plus how late the kill may
# strike) by that whole grace and the trial's 20 landings after it (and 2 periods for the
# first to land): a replacement back within the grace always has its landings inside the run.
RESTART_DURATION_S = round(
    FAULT_WINDOW_S["controller_restart"][1] + FAULT_LATE_MAX_S + GONE_GRACE_S + 22 / RATE, 2
)
# The replacement is a new process started before the kill with the service's modules already
# imported (numpy, Zenoh, the laws), idle until the trial lets it go after the kill: then it
# runs the service's whole entry (settings, session, the crashed log continued, scheduling).
# What the trial times is that restart, not how fast the host imports Python modules: that
# took 0.7-0.9 s beside two `yes` hogs on 2 cores, 1.7-3.6 s when other work shared the host
# too, past the grace (the run had ended before the replacement was up).
_PREWARMED = (
    "import sys\n"
    "import controller_service.from_settings, controller_service.registry\n"
    "import controller_service.service\n"
    "import runtime.clocksync, runtime.realtime, runtime.signals, runtime.startgate\n"
    "import runtime.zsession\n"
    "from controller_service.__main__ import main\n"
    "print('imported', flush=True)\n"
    "sys.stdin.readline()\n"
    "sys.exit(main(sys.argv[1:]))\n"
)


def controller_restart(tmp: Path, seed: int) -> Trial:
    t = Trial("controller_restart")
    with _Run(tmp / "run", duration_s=RESTART_DURATION_S) as run:
        settings = str(tmp / "run" / "run_settings.json")
        # Beside the run folder (made by hil run, later), its imports under way at once.
        log = tmp / "controller-restarted.log"
        with open(log, "wb") as f:
            back = subprocess.Popen(
                [sys.executable, "-c", _PREWARMED, "--settings", settings], cwd=ROOT,
                stdout=f, stderr=subprocess.STDOUT, stdin=subprocess.PIPE, start_new_session=True,
            )  # fmt: skip
        run.extra.append(back)

        def said(what: bytes) -> bool:
            return what in log.read_bytes()

        def ended() -> bool:
            return back.poll() is not None or run.proc.poll() is not None

        kill_ns = run.kill_at("controller", fault_at_s(t.kind, seed), t)
        if kill_ns is None:
            return t
        # Let it go (read once its imports are done, if they were not by the kill).
        assert back.stdin is not None
        back.stdin.write(b"go\n")
        back.stdin.flush()
        wait_until(lambda: said(b"imported") or ended(), 240)
        restart = time.monotonic_ns()  # its entry runs from here (or ran from the kill)
        t.detail["let_go_after_kill_s"] = round((restart - kill_ns) / 1e9, 3)
        # When the replacement is up (its "running" line), or why it never was.
        wait_until(lambda: said(b"running") or ended(), 240)
        if said(b"running"):
            t.detail["restart_running_after_s"] = round((time.monotonic_ns() - kill_ns) / 1e9, 3)
        run.finish()
        t.detail["restart_exit"] = back.poll()
        t.detail["restart_output"] = log.read_text(errors="replace")[-500:]
    t.detail["restarts_logged"] = read_hoplog(tmp / "run" / "controller.hoplog").restarts
    _resumed(tmp, kill_ns, restart, t)
    t.ok = t.ok and t.detail["restarts_logged"] == 1
    up = t.detail.get("restart_running_after_s")
    if not t.ok and (up is None or up > GONE_GRACE_S):
        # Not the rejoin failing: the replacement was not up within the grace.
        t.detail["error"] = (
            f"the replacement was {'never up' if up is None else f'up only {up} s after the kill'}"
            f", past hil run's {GONE_GRACE_S} s grace (which ended the run, as documented): "
            f"{t.detail.get('error', '')}"
        )
    return t


def router_restart(tmp: Path, seed: int) -> Trial:
    t = Trial("router_restart")
    scen = _with_tables(tmp, "router.toml", '\n[zenoh]\nmode = "router"\n')
    with _Run(tmp / "run", "--no-can", scenario=scen) as run:
        kill_ns = run.kill_at("router", fault_at_s(t.kind, seed), t)
        if kill_ns is None:
            return t
        settings = json.loads((tmp / "run" / "run_settings.json").read_text())
        back = run.start([sys.executable, "-m", "hil.bench.router", settings["zenoh_endpoint"]],
                         "router-restarted.log")  # fmt: skip
        wait_until(lambda: b"router up" in (tmp / "run" / "router-restarted.log").read_bytes(), 30)
        up = time.monotonic_ns()
        t.detail["router_up_after_ms"] = round((up - kill_ns) / 1e6, 1)
        run.finish()
        _stop(back)
    # The outage is timed from the kill (not from "router up") to the first landing again.
    return _resumed(tmp, kill_ns, up, t)


HIL_RUN_KILL_DURATION_S = 2.0


def _epoch_ns(out: Path) -> int | None:
    try:
        return int(read_hoplog(out / "plant.hoplog").meta.get("epoch_ns") or 0) or None
    except (OSError, ValueError):
        return None


def _states_missing(out: Path, kill_ns: int) -> tuple[int, int]:
    """(States the plant sent before the kill that the recording does not hold, States in the
    recording restored from the plant's hop log)."""
    from hil.folder.recording import read_messages
    from protocol.hoplog import SAMPLE_DROPPED

    plant = read_hoplog(out / "plant.hoplog")
    sent = {
        r["seq"] for r in plant.table("samples")
        if r["send_ns"] < kill_ns and not r["flags"] & SAMPLE_DROPPED
    }  # fmt: skip
    recorded: set[int] = set()
    restored = 0
    for m in read_messages(out / "recording.mcap", [f"hil/{plant.meta['robot_id']}/state"]):
        recorded.add(m.data["seq"])
        restored += "restored_from" in m.data
    return len(sent - recorded), restored


def _report_recovers(out: Path, t: Trial) -> bool:
    """``hil report`` on the killed folder: exit 0 or 1, a complete MCAP with the hop logs
    attached, summary.json marked recovered (unless the kill came after hil run had written
    the folder whole: nothing to recover), report.html written."""
    from hil.bench.repair import needs_recovery
    from hil.folder.recording import is_complete, read_attachments

    t.detail["needed_recovery"] = needs_recovery(out)

    rep = subprocess.run(
        [sys.executable, "-m", "hil", "report", str(out), "--no-ideal"],
        cwd=ROOT, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    t.detail["report_exit"] = rep.returncode
    if rep.returncode not in EXIT_CODE.values():
        t.detail["error"] = rep.stderr[-2000:]
        return False
    summary = json.loads((out / "summary.json").read_text())
    attached = set(read_attachments(out / "recording.mcap"))
    return (
        is_complete(out / "recording.mcap")
        and attached >= {"plant.hoplog", "controller.hoplog"}
        and (summary.get("recovered") is True or not t.detail["needed_recovery"])
        and summary.get("samples", 0) > 0
        and (out / "report.html").is_file()
    )


def hil_run_kill(tmp: Path, seed: int) -> Trial:
    t = Trial("hil_run_kill")
    out = tmp / "run"
    with _Run(out, duration_s=HIL_RUN_KILL_DURATION_S, rate=1000) as run:
        epoch = run.epoch(t)
        if epoch is None:
            return t
        kids = children_of(run.proc.pid)
        if not run.sleep_until(epoch, fault_at_s(t.kind, seed), t):
            return t
        kill_ns = time.monotonic_ns()
        run.proc.send_signal(signal.SIGKILL)
        _mark_fault(t, epoch, kill_ns)
        run.proc.wait(timeout=10)
        gone = wait_until(lambda: not any(alive(k) for k in kids), 15)
        t.safe_s = (time.monotonic_ns() - kill_ns) / 1e9
        t.detail["children"] = len(kids)
        if not gone:
            t.detail["error"] = "children left behind"
            return t
    # What the recorder's queue held at the kill is missing from the recording until
    # recovery restores it from the plant's hop log.
    t.detail["states_missing_before_recovery"] = _states_missing(out, kill_ns)[0]
    recovered = _report_recovers(out, t)
    t.detail["states_lost"], t.detail["states_restored"] = _states_missing(out, kill_ns)
    t.ok = len(kids) >= 2 and recovered and t.detail["states_lost"] == 0
    t.ok = t.ok and "error" not in t.detail
    return t


TRIALS: dict[str, Callable[[Path, int], Trial]] = {
    "controller_kill_zenoh": lambda tmp, seed: controller_kill(tmp, "zenoh", seed),
    "controller_kill_can": lambda tmp, seed: controller_kill(tmp, "can", seed),
    "plant_kill": plant_kill,
    "controller_restart": controller_restart,
    "router_restart": router_restart,
    "hil_run_kill": hil_run_kill,
}


@contextlib.contextmanager
def cpu_hog(n: int) -> Iterator[list[subprocess.Popen]]:
    """``n`` busy processes (``yes > /dev/null``) for the duration, stopped by PID after."""
    procs: list[subprocess.Popen] = []
    try:
        for _ in range(n):
            procs.append(
                subprocess.Popen(["yes"], stdout=subprocess.DEVNULL, start_new_session=True)
            )
        yield procs
    finally:
        for p in procs:
            _stop(p)


def run_trial(kind: str, seed: int = 0) -> Trial:
    """One trial of ``kind`` (``seed`` picks its random moment where it has one)."""
    with tempfile.TemporaryDirectory(prefix=f"hil-kill-{kind}-") as tmp:
        try:
            return TRIALS[kind](Path(tmp), seed)
        except Exception as exc:  # a trial that crashes is a failed trial, with its reason
            return Trial(kind, False, None, {"error": repr(exc)})


def _matrix(kinds: list[str], trials: int) -> dict[str, Any]:
    table: dict[str, Any] = {}
    for kind in kinds:
        results = []
        for i in range(trials):
            r = run_trial(kind, i)
            results.append(r)
            safe = f"{r.safe_s * 1e3:.1f} ms" if r.safe_s is not None else "-"
            print(f"{kind} {i + 1}/{trials}: {'ok' if r.ok else 'FAIL'} {safe} {r.detail}",
                  file=sys.stderr, flush=True)  # fmt: skip
        safe = [r.safe_s for r in results if r.safe_s is not None]
        table[kind] = {
            "trials": len(results),
            "passed": sum(r.ok for r in results),
            "worst_s": max(safe) if safe else None,
            "median_s": sorted(safe)[len(safe) // 2] if safe else None,
            "fault_at_s": [r.detail.get("fault_done_at_s") for r in results],
            "failures": [r.detail for r in results if not r.ok],
        }
    return table


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--trials", type=int, default=20, help="trials of each kind (default 20)")
    ap.add_argument("--kinds", nargs="+", choices=KINDS, default=list(KINDS),
                    help="which failures to inject (default: all)")  # fmt: skip
    ap.add_argument("--out", type=Path, help="also write the table as JSON here")
    ap.add_argument("--hog", type=int, default=0, metavar="N",
                    help="run the trials beside N busy processes (yes > /dev/null)")  # fmt: skip
    a = ap.parse_args(argv)
    with cpu_hog(a.hog):
        table = _matrix(a.kinds, a.trials)
    print(f"{'kind':24} {'passed':>10} {'worst to safe/outage':>22} {'median':>10}")
    for kind, row in table.items():
        worst = f"{row['worst_s'] * 1e3:.1f} ms" if row["worst_s"] is not None else "-"
        med = f"{row['median_s'] * 1e3:.1f} ms" if row["median_s"] is not None else "-"
        print(f"{kind:24} {row['passed']:>4} / {row['trials']:<4} {worst:>22} {med:>10}")
    text = json.dumps(table, indent=2)
    if a.out:
        a.out.write_text(text)
    return 0 if all(r["passed"] == r["trials"] for r in table.values()) else 1


if __name__ == "__main__":
    sys.exit(main())
