"""The kill matrix: each failure injected into real runs, repeated, reported as counts.

    python bench/kill_matrix.py [--trials 20] [--kinds controller_kill_zenoh ...] [--out FILE]

Kinds (each trial is one ``hil run`` of 3 s at 200 Hz, the failure injected by PID):

- ``controller_kill_zenoh`` / ``controller_kill_can``: SIGKILL of the controller; safe state =
  the plant holds zero torque (its command timeout), on the wall clock at most
  command_timeout + 2 periods after the last command arrived; on the CAN path the drives'
  watchdog is armed (``[can] watchdog_timeout`` = 1 s) and both drives must also end IDLE
  with WATCHDOG_TIMER_EXPIRED latched as their disarm reason;
- ``plant_kill``: SIGKILL of the plant; safe state = the controller's stale-state watchdog sends
  zero torque flagged WATCHDOG_ZERO, at most state_timeout + 2 periods after the last state;
- ``controller_restart``: SIGKILL of the controller, then a new one started with the run's
  settings; it rejoins the run: commands land again, none computed from a sample older than
  the restart, and the run's certificate lists the outage as a stall;
- ``router_restart``: router mode; the Zenoh router is SIGKILLed and started again on its
  port; both services (clients) reconnect by themselves, commands land again, none computed
  from a sample taken before the router came back, and the outage is measured.
- ``hil_run_kill``: SIGKILL of ``hil run`` itself at a seeded random moment of a 2 s run at
  1 kHz (trial i draws from ``random.Random(1000 + i)``), up to 0.5 s after its end; safe state
  = every process it started has exited by itself (checked by PID), the time given is from
  the kill to the last one gone; the recording lost no State sent more than 0.1 s before the
  kill; ``hil report`` on the folder recovers it (exit 0 or 1, never 2).

Prints a table (trials, passed, worst time to the safe state or outage) and JSON; the test
tests/test_kill_matrix.py runs the same trials and asserts that every one passes.
"""

from __future__ import annotations

import argparse
import json
import os
import random
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

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


@dataclass
class Trial:
    kind: str
    ok: bool = False
    safe_s: float | None = None  # time to the safe state, or the outage for restarts
    detail: dict[str, Any] = field(default_factory=dict)


def _rows(path: Path, table: str) -> int:
    try:
        return len(read_hoplog(path).rows.get(table, []))
    except (OSError, ValueError):
        return 0


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

    def started(self, table: str = "apply", rows: int = 100) -> bool:
        return wait_until(lambda: _rows(self.out / "plant.hoplog", table) >= rows, 90)

    def pid(self, name: str) -> int:
        return int(json.loads((self.out / "processes.json").read_text())[name])

    def kill(self, name: str) -> int:
        pid = self.pid(name)
        t = time.monotonic_ns()
        os.kill(pid, signal.SIGKILL)
        if not wait_until(lambda: not alive(pid), 10):
            raise RuntimeError(f"{name} (pid {pid}) survived SIGKILL")
        return t

    def start(self, argv: list[str], log: str) -> subprocess.Popen:
        with open(self.out / log, "wb") as f:
            p = subprocess.Popen(argv, cwd=ROOT, stdout=f, stderr=subprocess.STDOUT,
                                 start_new_session=True)  # fmt: skip
        self.extra.append(p)
        return p

    def finish(self) -> dict[str, Any]:
        self.proc.wait(timeout=240)
        return json.loads((self.out / "summary.json").read_text())


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


def controller_kill(tmp: Path, path: str) -> Trial:
    t = Trial(f"controller_kill_{path}")
    scenario = None
    if path == "can":
        # The drives' own watchdog, as on a real ODrive (axis.config.watchdog_timeout): it
        # disarms them when the controller's frames stop, whatever the plant does.
        scenario = _with_tables(tmp, "watchdog.toml", f"\n[can]\nwatchdog_timeout = {WATCHDOG_S}\n")
    with _Run(tmp / "run", "--cmd-path", path, scenario=scenario) as run:
        if not run.started():
            t.detail["error"] = "no closed loop before the kill"
            return t
        run.kill("controller")
        summary = run.finish()
    plant = read_hoplog(tmp / "run" / "plant.hoplog")
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
    )
    if path == "can":
        t.ok = _drives_disarmed_by_watchdog(plant, t) and t.ok
    t.detail["zeroed_after_ms"] = t.safe_s * 1e3
    t.detail["watchdog"] = summary.get("watchdog")
    return t


def plant_kill(tmp: Path) -> Trial:
    t = Trial("plant_kill")
    with _Run(tmp / "run") as run:
        if not run.started():
            t.detail["error"] = "no closed loop before the kill"
            return t
        run.kill("plant")
        run.proc.wait(timeout=240)
    ctrl = read_hoplog(tmp / "run" / "controller.hoplog")
    timeout_ns = int(ctrl.meta["state_timeout_s"] * 1e9)
    last = max(r["recv_ns"] for r in ctrl.table("state_rx"))
    zero = [
        r for r in ctrl.table("ticks") if r["flags"] & FLAG_WATCHDOG_ZERO and r["wake_ns"] > last
    ]
    if not zero:
        t.detail["error"] = "the controller never sent a watchdog zero"
        return t
    t.safe_s = (zero[0]["zenoh_send_ns"] - last) / 1e9
    t.ok = zero[0]["tau1"] == 0.0 and zero[0]["tau2"] == 0.0
    t.ok = t.ok and zero[0]["zenoh_send_ns"] - last <= timeout_ns + 2 * PERIOD_NS
    t.detail["flagged_zero_after_ms"] = t.safe_s * 1e3
    return t


def _resumed(tmp: Path, since_ns: int, t: Trial) -> Trial:
    """Commands land again after ``since_ns``; none was computed from an older sample; the
    run's measurement (taken once every process has stopped: a restarted service outlives
    ``hil run``'s own analysis) shows the outage as a stall."""
    from hil.measure.folder import measure_folder

    ctrl = read_hoplog(tmp / "run" / "controller.hoplog")
    plant = read_hoplog(tmp / "run" / "plant.hoplog")
    sample_of = {
        r["cmd_seq"]: r["state_sample_ns"] for r in ctrl.table("ticks") if r["cmd_seq"] >= 0
    }
    after = [a for a in plant.table("apply") if a["apply_ns"] > since_ns and a["outcome"] == 0]
    stale = [a for a in after if sample_of.get(a["seq"], 0) < since_ns]
    t.detail["landed_after"] = len(after)
    t.detail["stale_after"] = len(stale)
    if after:
        t.safe_s = (after[0]["apply_ns"] - since_ns) / 1e9
    m = measure_folder(tmp / "run")
    stalls = ((m.certificate if m is not None else None) or {}).get("stalls") or []
    t.detail["worst_stall"] = stalls[0] if stalls else None
    t.ok = len(after) >= 20 and not stale and bool(stalls)
    return t


def controller_restart(tmp: Path) -> Trial:
    t = Trial("controller_restart")
    with _Run(tmp / "run") as run:
        if not run.started():
            t.detail["error"] = "no closed loop before the kill"
            return t
        run.kill("controller")
        restart = time.monotonic_ns()
        settings = str(tmp / "run" / "run_settings.json")
        run.start([sys.executable, "-m", "controller_service", "--settings", settings],
                  "controller-restarted.log")  # fmt: skip
        run.finish()
    t.detail["restarts_logged"] = read_hoplog(tmp / "run" / "controller.hoplog").restarts
    _resumed(tmp, restart, t)
    t.ok = t.ok and t.detail["restarts_logged"] == 1
    return t


def router_restart(tmp: Path) -> Trial:
    t = Trial("router_restart")
    scen = _with_tables(tmp, "router.toml", '\n[zenoh]\nmode = "router"\n')
    with _Run(tmp / "run", "--no-can", scenario=scen) as run:
        if not run.started():
            t.detail["error"] = "no closed loop before the router restart"
            return t
        settings = json.loads((tmp / "run" / "run_settings.json").read_text())
        run.kill("router")
        back = run.start([sys.executable, "-m", "hil.run.router", settings["zenoh_endpoint"]],
                         "router-restarted.log")  # fmt: skip
        wait_until(lambda: b"router up" in (tmp / "run" / "router-restarted.log").read_bytes(), 30)
        restart = time.monotonic_ns()
        run.finish()
        _stop(back)
    return _resumed(tmp, restart, t)


HIL_RUN_KILL_DURATION_S = 2.0
FLUSH_BOUND_S = 0.1  # the recording may lose what was received in the last 0.1 s


def _epoch_ns(out: Path) -> int | None:
    try:
        return int(read_hoplog(out / "plant.hoplog").meta.get("epoch_ns") or 0) or None
    except (OSError, ValueError):
        return None


def _states_lost_before(out: Path, kill_ns: int) -> int:
    """States the plant sent more than FLUSH_BOUND_S before the kill that the (truncated)
    recording does not hold."""
    from hil.recording import read_messages

    plant = read_hoplog(out / "plant.hoplog")
    bound = kill_ns - FLUSH_BOUND_S * 1e9
    sent = {r[0] for r in plant.rows["samples"] if r[3] <= bound}
    recorded = {m.data["seq"] for m in read_messages(out / "recording.mcap", ["hil/robot0/state"])}
    return len(sent - recorded)


def _report_recovers(out: Path, t: Trial) -> bool:
    """``hil report`` on the killed folder: exit 0 or 1, a complete MCAP with the hop logs
    attached, summary.json marked recovered, report.html written."""
    from hil.recording import is_complete, read_attachments

    rep = subprocess.run(
        [sys.executable, "-m", "hil", "report", str(out), "--no-ideal"],
        cwd=ROOT, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    t.detail["report_exit"] = rep.returncode
    if rep.returncode not in (0, 1):
        t.detail["error"] = rep.stderr[-2000:]
        return False
    summary = json.loads((out / "summary.json").read_text())
    attached = set(read_attachments(out / "recording.mcap"))
    return (
        is_complete(out / "recording.mcap")
        and attached >= {"plant.hoplog", "controller.hoplog"}
        and summary.get("recovered") is True
        and summary.get("samples", 0) > 0
        and (out / "report.html").is_file()
    )


def hil_run_kill(tmp: Path, seed: int) -> Trial:
    t = Trial("hil_run_kill")
    at_s = random.Random(1000 + seed).uniform(0.1, HIL_RUN_KILL_DURATION_S + 0.5)
    out = tmp / "run"
    t.detail["kill_at_s"] = round(at_s, 3)
    with _Run(out, duration_s=HIL_RUN_KILL_DURATION_S, rate=1000) as run:
        if not wait_until(lambda: _epoch_ns(out) is not None, 120):
            t.detail["error"] = "the run never started"
            return t
        kids = children_of(run.proc.pid)
        target = (_epoch_ns(out) or 0) + int(at_s * 1e9)
        time.sleep(max(0.0, (target - time.monotonic_ns()) / 1e9))  # to the seeded moment
        if run.proc.poll() is not None:
            t.detail["error"] = "hil run had already finished at the chosen moment"
            return t
        kill_ns = time.monotonic_ns()
        run.proc.send_signal(signal.SIGKILL)
        run.proc.wait(timeout=10)
        gone = wait_until(lambda: not any(alive(k) for k in kids), 15)
        t.safe_s = (time.monotonic_ns() - kill_ns) / 1e9
        t.detail["children"] = len(kids)
        if not gone:
            t.detail["error"] = "children left behind"
            return t
    t.detail["states_lost"] = _states_lost_before(out, kill_ns)
    t.ok = len(kids) >= 2 and t.detail["states_lost"] == 0 and _report_recovers(out, t)
    return t


TRIALS: dict[str, Callable[[Path, int], Trial]] = {
    "controller_kill_zenoh": lambda tmp, _: controller_kill(tmp, "zenoh"),
    "controller_kill_can": lambda tmp, _: controller_kill(tmp, "can"),
    "plant_kill": lambda tmp, _: plant_kill(tmp),
    "controller_restart": lambda tmp, _: controller_restart(tmp),
    "router_restart": lambda tmp, _: router_restart(tmp),
    "hil_run_kill": hil_run_kill,
}


def run_trial(kind: str, seed: int = 0) -> Trial:
    """One trial of ``kind`` (``seed`` picks its random moment where it has one)."""
    with tempfile.TemporaryDirectory(prefix=f"hil-kill-{kind}-") as tmp:
        try:
            return TRIALS[kind](Path(tmp), seed)
        except Exception as exc:  # a trial that crashes is a failed trial, with its reason
            return Trial(kind, False, None, {"error": repr(exc)})


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--trials", type=int, default=20, help="trials of each kind (default 20)")
    ap.add_argument("--kinds", nargs="+", choices=KINDS, default=list(KINDS),
                    help="which failures to inject (default: all)")  # fmt: skip
    ap.add_argument("--out", type=Path, help="also write the table as JSON here")
    a = ap.parse_args(argv)
    table: dict[str, Any] = {}
    for kind in a.kinds:
        results = []
        for i in range(a.trials):
            r = run_trial(kind, i)
            results.append(r)
            safe = f"{r.safe_s * 1e3:.1f} ms" if r.safe_s is not None else "-"
            print(f"{kind} {i + 1}/{a.trials}: {'ok' if r.ok else 'FAIL'} {safe} {r.detail}",
                  file=sys.stderr, flush=True)  # fmt: skip
        safe = [r.safe_s for r in results if r.safe_s is not None]
        table[kind] = {
            "trials": len(results),
            "passed": sum(r.ok for r in results),
            "worst_s": max(safe) if safe else None,
            "median_s": sorted(safe)[len(safe) // 2] if safe else None,
            "failures": [r.detail for r in results if not r.ok],
        }
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
