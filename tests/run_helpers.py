"""Helpers for the tests that start ``hil run`` (real processes, real Zenoh, real CAN bus).

Every real run states the verdict it expects (:class:`Expect`: the outcome and the kinds of
its reasons) and :func:`hil_run` asserts it, with the exit code through :func:`expected_exit`
only. A run that is not what it should be fails with what the run's own host samples say the
machine did meanwhile (:func:`machine_report`), so a stalled machine is named, never guessed."""

from __future__ import annotations

import json
import os
import re
import subprocess
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from hil.analysis.measure.host import host_figures
from hil.verdict import EXIT_CODE
from protocol.hoplog import (
    TICK_DROPPED,
    TICK_NO_SEND,
    ApplyOutcome,
    CmdPath,
    HopLog,
    read_hoplog,
)
from protocol.messages import FLAG_WATCHDOG_ZERO
from tests.procs import spawned
from tests.scenario_text import CLEAN_50HZ, CLEAN_D_STAR_S, CLEAN_RATE_HZ


def expected_exit(outcome: str, *, command: str = "run") -> int:
    """The exit code of ``hil COMMAND`` whose verdict is ``outcome``: one per verdict, the same
    for every command (hil.verdict.EXIT_CODE; docs/reports.md, "Verdict and exit code")."""
    del command  # every command maps its verdict the same way
    return EXIT_CODE[outcome]


#: The kind of each verdict reason (hil/verdict.py's sentences, docs/reports.md's list), by
#: how the sentence starts: a test pins the kinds, never a whole sentence.
REASON_KINDS: dict[str, re.Pattern[str]] = {
    kind: re.compile(pattern)
    for kind, pattern in {
        "limits": r"limits of \(2\) broken",
        "beyond_bound": r"measured beyond the sampled-data bound",
        "no_command": r"certificate not held: no command ever landed",
        "design": r"certificate not held: design conditions broken",
        "certificate_unknown_stall": r"certificate not held: .* by a stall whose cause",
        "certificate_system": r"certificate not held: command age D = .* by the system's own",
        "bench_stalled": r"the bench stalled",
        "certificate_undecided": r"certificate unknown",
        "deadline_misses": r"deadline misses",
        "samples_without_command": r"samples without a command",
        "lost_messages": r"lost messages",
        "can_untrusted": r"the CAN figures cannot be trusted",
        "law_fault": r"the law ",
        "controller_exited": r"the controller process ",
    }.items()
}


def reason_kind(reason: str) -> str:
    """The kind of one verdict reason ("unknown" for a sentence no kind starts)."""
    for kind, pattern in REASON_KINDS.items():
        if pattern.match(reason):
            return kind
    return "unknown"


@dataclass(frozen=True)
class Expect:
    """The verdict a run must have: ``outcome`` with every reason kind in ``kinds`` among its
    reasons and no reason of another kind than ``kinds`` and ``also``."""

    outcome: str
    kinds: frozenset[str] = frozenset()
    also: frozenset[str] = frozenset()

    def check(self, verdict: dict[str, Any]) -> str | None:
        """Why ``verdict`` (summary.json's) is not this, or None."""
        got = [reason_kind(r) for r in verdict.get("reasons") or []]
        if verdict.get("outcome") != self.outcome:
            return f"outcome {verdict.get('outcome')} (reasons {got}), expected {self}"
        missing = self.kinds - set(got)
        extra = set(got) - self.kinds - self.also
        if missing or extra:
            return f"{self.outcome} with reasons {got}: missing {missing}, unexpected {extra}"
        return None

    def __str__(self) -> str:
        also = f" (also allowed: {sorted(self.also)})" if self.also else ""
        return f"{self.outcome} {sorted(self.kinds)}{also}"


PASSES = Expect("PASS")


def fails(*kinds: str, also: tuple[str, ...] = ()) -> Expect:
    return Expect("FAIL", frozenset(kinds), frozenset(also))


def inconclusive(*kinds: str, also: tuple[str, ...] = ()) -> Expect:
    return Expect("INCONCLUSIVE", frozenset(kinds), frozenset(also))


_TIMING = ("samples_without_command", "deadline_misses")
#: What a loaded host legitimately does to a loop whose period is a millisecond or two (500 Hz
#: to 2 kHz, D* = 20 ms): States that arrive after the controller's tick (samples without a
#: command), wake-ups a period late (deadline misses), the bench's own stall past D*
#: (INCONCLUSIVE). Only for a test of something else than the verdict at such a rate, and only
#: with each count explained by the run's own logs (:func:`explain_timing`, which
#: :func:`check_verdict` applies to every verdict). Never a limit, the certificate through the
#: system's timing, or a lost message: those fail the test whatever the load.
LOADED_HOST = (
    fails(also=(*_TIMING, "bench_stalled")),
    inconclusive(also=(*_TIMING, "bench_stalled")),
)

#: As LOADED_HOST, for a test of something else than the verdict at a kilohertz or two (the
#: tick phase at 2 kHz): also a certificate broken by the system's own timing, as the verdict
#: lays a loaded host's late controller or late transport on the system (CI: D = 49 ms, the
#: controller late; this host: D = 82 ms, Zenoh hops and the host). The counts are still
#: explained by the run's own logs; never a limit or a lost message.
LOADED_HOST_CERTIFICATE = (
    *LOADED_HOST,
    fails("certificate_system", also=(*_TIMING, "bench_stalled")),
)

#: A clean run (nothing injected) for a test of something else than its verdict: PASS, or
#: INCONCLUSIVE when only the bench was late (its stalls, or a plant woken so late that its
#: State came after the tick meant to answer it: the verdict's bench shares, docs/reports.md),
#: never FAIL: nothing of the system was late.
BENCH_LATE_OR_PASS = (PASSES, inconclusive(also=(*_TIMING, "bench_stalled")))


def fleet_outcome(outcomes: list[str]) -> str:
    """A fleet's verdict from its robots' (hil fleet's rule): FAIL when one is (or left none),
    else INCONCLUSIVE when one is, else PASS."""
    if any(o not in ("PASS", "INCONCLUSIVE") for o in outcomes):
        return "FAIL"
    return "INCONCLUSIVE" if "INCONCLUSIVE" in outcomes else "PASS"


def check_fleet(
    out: Path, robots: int, done: subprocess.CompletedProcess, expect: Expect | tuple[Expect, ...]
) -> None:
    """Every robot's verdict under ``out`` is ``expect`` and ``hil fleet``'s exit code that of
    its robots' verdicts (:func:`fleet_outcome`)."""
    outcomes = []
    for i in range(1, robots + 1):
        folder = out / f"robot{i}"
        summary = json.loads((folder / "summary.json").read_text())
        check_verdict(summary, expect, None, folder, context=done.stderr[-3000:])
        outcomes.append(str((summary.get("verdict") or {}).get("outcome")))
    assert done.returncode == expected_exit(fleet_outcome(outcomes)), done.stderr[-3000:]


def explain_timing(run_dir: Path, summary: dict[str, Any]) -> list[str]:
    """Where summary.json's timing counts are more than the services' own logs explain, why:
    every deadline miss is a slot the controller woke a period or more late for (a late tick
    or a slot it skipped), every sample without a command one no tick computed a command from
    that went out on the applied path (on CAN none goes out while the drives are not armed: a
    guest stalled at start arms them late), or whose command was lost or never landed (a newer
    one was there first)."""
    t = summary.get("timing") or {}
    try:
        log = read_hoplog(run_dir / "controller.hoplog")
        plant = read_hoplog(run_dir / "plant.hoplog")
    except (OSError, ValueError):
        return []
    ticks = {k: np.asarray(v, dtype=np.int64) for k, v in log.columns("ticks").items()}
    period = int(log.meta.get("period_ns") or 0)
    if not ticks or not period:
        return []
    wrong = []
    skipped = int(ticks["skipped"].sum())
    # Counted over the run's window, these are at most what the whole logs hold.
    missed = int((ticks["wake_ns"] - ticks["deadline_ns"] >= period).sum()) + skipped
    if isinstance(t.get("deadline_misses"), int) and t["deadline_misses"] > missed:
        wrong.append(
            f"deadline misses {t['deadline_misses']}, but the controller's log has only {missed} "
            f"(ticks a period late and the slots they skipped)"
        )
    # A sample gets no command when no tick computed from its State (it came late, or with
    # newer ones, or a slot was skipped), or when that command was lost, or never landed: it
    # arrived after a newer one, or with a newer one within the same plant step.
    # Sent on the applied path: not a [faults] drop nor a watchdog's zero (computed from no
    # sample), and stamped on that path (CAN: not sent while the drives were not yet armed).
    on_can = summary.get("cmd_path") == "can"
    sent = (ticks["flags"] & (TICK_NO_SEND | TICK_DROPPED | FLAG_WATCHDOG_ZERO)) == 0
    sent &= ticks["can_send_ns" if on_can else "zenoh_send_ns"] > 0
    used = set(ticks["state_seq"][sent & (ticks["state_seq"] >= 0)].tolist())
    unused = len(set(plant.columns("samples").get("seq", [])) - used)
    messages = summary.get("messages") or {}
    torque = messages.get(f"torque_{summary.get('cmd_path')}") or {}
    # Never arrived: lost, or held by the transport when the plant stopped (in flight).
    lost = int(torque.get("lost") or 0) + int(torque.get("in_flight_at_stop") or 0)
    path = int(CmdPath.CAN if on_can else CmdPath.ZENOH)
    rx, ap = plant.columns("cmd_rx"), plant.columns("apply")
    arrived = {
        (n, q) for p, n, q in zip(rx["path"], rx["node"], rx["seq"], strict=True) if p == path
    }
    landed = {
        (n, q)
        for p, n, q, o in zip(ap["path"], ap["node"], ap["seq"], ap["outcome"], strict=True)
        if p == path and o in (ApplyOutcome.LANDED, ApplyOutcome.BURST)
    }
    unlanded = len(arrived - landed)  # CAN: frames, two a command (an upper bound)
    swc = t.get("samples_without_command")
    if isinstance(swc, int) and swc > unused + lost + unlanded:
        wrong.append(
            f"{swc} samples without a command, but only {unused} samples fed no tick, "
            f"{lost} commands never arrived and {unlanded} arrived and never landed"
        )
    return wrong


def check_verdict(
    summary: dict[str, Any],
    expect: Expect | tuple[Expect, ...],
    code: int | None,
    run_dir: Path,
    command: str = "run",
    context: str = "",
) -> None:
    """``summary``'s verdict is ``expect`` (or one of the alternatives, each with its reason
    written by the caller) and ``code`` is its exit code (:func:`expected_exit`)."""
    verdict = summary.get("verdict") or {}
    options = expect if isinstance(expect, tuple) else (expect,)
    why = [w for w in (e.check(verdict) for e in options) if w is not None]
    wrong = len(why) == len(options)
    if not wrong and verdict.get("outcome") != "PASS":
        why = explain_timing(run_dir, summary)
        wrong = bool(why)
    want = expected_exit(str(verdict.get("outcome")), command=command)
    if wrong or (code is not None and code != want):
        head = "; ".join(why) if wrong else f"exit code {code}, expected {want}"
        raise AssertionError(
            f"{head}\nreasons: {verdict.get('reasons')}\n{machine_report(run_dir, summary)}"
            + (f"\n{context}" if context else "")
        )


def hil_run(
    out: Path,
    *args: str,
    expect: Expect | tuple[Expect, ...],
    timeout: float = 240,
) -> dict:
    """``hil run ARGS`` into ``out``; its summary (with ``_exit_code``). Its verdict must be
    ``expect`` and its exit code that verdict's (:func:`check_verdict`)."""
    argv = ["-m", "hil", "run", *args, "--quiet", "--no-report", "--out", str(out)]
    with spawned() as spawn:
        proc = spawn.python(argv, text=True)
        try:
            stdout, stderr = proc.communicate(timeout=timeout)
        except subprocess.TimeoutExpired as exc:
            raise AssertionError(f"hil run did not end within {timeout} s") from exc
    logs = {p.name: p.read_text()[-2000:] for p in out.glob("*.log")}
    context = f"exit {proc.returncode}\nstdout: {stdout[-1500:]}\nstderr: {stderr[-3000:]}"
    if not (out / "summary.json").is_file():
        raise AssertionError(f"no summary.json\n{context}\nlogs: {logs}")
    summary = json.loads((out / "summary.json").read_text())
    check_verdict(summary, expect, proc.returncode, out, context=f"{context}\nlogs: {logs}")
    summary["_exit_code"] = proc.returncode
    return summary


#: A wake-up this late is named in a failure (a SCHED_FIFO wake-up takes tens of µs).
LATE_NS = 2_000_000
#: The host's measures that make a late wake-up the machine's stall: the hypervisor took this
#: share of the CPUs (steal), or the late process waited runnable for a CPU for at least half
#: its lateness, or the controller and the plant were late at the same time.
STEAL_PCT = 10.0


def _late_wakeups(path: Path, table: str, due: str) -> tuple[list[tuple[int, int]], int | None]:
    """(due, lateness) of every wake-up of ``table`` at least LATE_NS late, worst first, and
    the log's epoch (None when the log is unreadable)."""
    try:
        log = read_hoplog(path)
    except (OSError, ValueError):
        return [], None
    cols = log.columns(table)
    pairs = [(d, w - d) for d, w in zip(cols.get(due, []), cols.get("wake_ns", []), strict=True)]
    late = sorted((p for p in pairs if p[1] >= LATE_NS), key=lambda p: -p[1])
    return late, log.meta.get("epoch_ns")


def _host_words(h: dict[str, Any]) -> str:
    ours = sum(h.get(f"{p}_cpu_pct", 0.0) for p in ("plant", "controller", "recorder"))
    others = h["busy_pct"] * h["cpus"] / 100.0 - ours / 100.0
    waits = ", ".join(
        f"the {p} waited {1e3 * h[f'{p}_wait_s']:.0f} ms for a CPU"
        for p in ("controller", "plant")
        if h.get(f"{p}_wait_s") is not None
    )
    return (
        f"busy {h['busy_pct']:.0f} %, steal {h['steal_pct']:.0f} %, run queue up to "
        f"{h['runnable_max']}, other processes {max(others, 0.0):.2f} CPUs"
        + (f", {waits}" if waits else "")
    )


def machine_report(run_dir: Path, summary: dict[str, Any]) -> str:
    """What the run's host samples (host.hoplog, summary.json's ``host``) say the machine did
    while the controller or the plant woke late: "THE MACHINE STALLED: ..." when they show it
    (steal, a CPU waited for, both services late together), else that they do not."""
    lines = []
    whole = summary.get("host")
    if whole:
        lines.append(f"host over the run ({whole['from_s']:.1f} s): {_host_words(whole)}")
    try:
        host = read_hoplog(run_dir / "host.hoplog")
        cols = {k: np.asarray(v) for k, v in host.columns("host").items()}
    except (OSError, ValueError):
        host, cols = None, {}
    late = {
        "controller": _late_wakeups(run_dir / "controller.hoplog", "ticks", "deadline_ns"),
        "plant": _late_wakeups(run_dir / "plant.hoplog", "samples", "sample_ns"),
    }
    windows = {who: [(d, d + n) for d, n in got] for who, (got, _) in late.items()}
    stalled = []
    for who, (got, epoch) in late.items():
        other = windows["plant" if who == "controller" else "controller"]
        for due, n in got[:5]:
            t = f"t = {(due - epoch) / 1e9:.3f} s" if epoch else "t = ?"
            words = f"the {who} woke {n / 1e6:.1f} ms late at {t}"
            together = any(lo < due + n and due < hi for lo, hi in other)
            h = host_figures(cols, host.meta, due, due + n) if host is not None else None
            on_clock = host is not None and cols["time_ns"][0] <= due <= cols["time_ns"][-1]
            if h is not None and on_clock:
                words += f" ({_host_words(h)}"
                waited = h.get(f"{who}_wait_s") or 0.0
                if h["steal_pct"] >= STEAL_PCT or waited * 1e9 >= n / 2 or together:
                    stalled.append(words + ")")
                words += ")"
            elif together:
                stalled.append(words + " (the other service late at the same time)")
            if together:
                words += ", the other service late at the same time"
            lines.append(words)
        if len(got) > 5:
            lines.append(f"... and {len(got) - 5} more {who} wake-ups over {LATE_NS / 1e6:g} ms")
    for s in (summary.get("certificate") or {}).get("stalls") or []:
        h = (s.get("evidence") or {}).get("host")
        if h:
            lines.append(
                f"stall at t = {s['t_s']:.3f} s ({s['cause']}, {s['owner']}): {_host_words(h)}"
            )
    if stalled:
        head = "THE MACHINE STALLED (its own host samples say so): " + "; ".join(stalled[:3])
    elif any(got for got, _ in late.values()):
        head = (
            "no measured stall of the machine: the late wake-ups below had no steal, no CPU "
            "waited for and not both services late at once"
        )
    else:
        head = f"no wake-up of the controller or the plant was {LATE_NS / 1e6:g} ms late"
    return "\n".join([head, *lines])


# A clean run (tests/scenario_text.py CLEAN_50HZ: 50 Hz, D* = 498 ms, nothing injected) and
# the largest value each figure may take in it, with why.
CLEAN_DURATION_S = 3.0
CLEAN_P_US = 1e6 / CLEAN_RATE_HZ  # 20 ms: the control and the sensor period
#: The host's allowance: how late a SCHED_FIFO service may run on a loaded 2-core host. The
#: kernel wakes a FIFO thread within tens of µs (cyclictest, docs/realtime.md); Python, the
#: GIL handed between the loop and Zenoh's threads (switch interval 0.5 ms) and Zenoh's own
#: threads make it a millisecond or two; 10 ms is half a period, so a run within it misses no
#: deadline and leaves no sample without its command.
HOST_US = 10_000.0


def clean_scenario(folder: Path, extra: str = "") -> Path:
    """CLEAN_50HZ (and ``extra`` TOML after it) as ``folder``/clean.toml."""
    path = folder / "clean.toml"
    path.write_text(CLEAN_50HZ + extra)
    return path


def clean_bounds(
    path: str, clock_us: float = 0.0, rate_hz: float = CLEAN_RATE_HZ
) -> dict[str, tuple[float, str]]:
    """Each figure's largest value in a clean run on the ``path`` command path at ``rate_hz``
    (µs), and why. ``clock_us``: how far the controller's clock may be from the plant's once
    related (a lab run's offset uncertainty; 0 on one host), for the figures relating the two."""
    p, clock = 1e6 / rate_hz, f" and the clock relation's {clock_us:.0f} µs" if clock_us else ""
    return {
        "wakeup_lateness": (HOST_US, "the controller's wake-up: the host's allowance"),
        "plant_wakeup_lateness": (HOST_US, "the plant's wake-up: the host's allowance"),
        "hop_state": (HOST_US + clock_us, f"a State's flight: the host's allowance{clock}"),
        f"hop_cmd_{path}": (HOST_US + clock_us, f"a command's flight: the host's allowance{clock}"),
        f"sample_to_apply_{path}": (
            p / 2 + HOST_US + clock_us,
            "the controller ticks half a period after the sample ([realtime] tick_phase "
            f"'half'), then computes and sends within the host's allowance{clock}",
        ),
        f"command_age_{path}": (
            p + p / 2 + HOST_US + clock_us,
            "a command is in force until the next sample's command lands: one period of "
            f"sampling, then that command's sample-to-apply (half a period, the allowance{clock})",
        ),
    }


def check_clean_run(
    s: dict[str, Any],
    path: str,
    run_dir: Path,
    clock_us: float = 0.0,
    duration_s: float = CLEAN_DURATION_S,
    rate_hz: float = CLEAN_RATE_HZ,
) -> dict[str, float]:
    """Every bound of a clean run of ``duration_s`` at ``rate_hz`` on ``path``
    (:func:`clean_bounds`; the host's allowance must stay under half a period), and nothing
    lost; the measured maxima (µs, D as "D"). A broken bound fails with :func:`machine_report`."""
    cert, t = s["certificate"], s["timing"]
    assert cert["path"] == path, cert["path"]
    # The scenario is what CLEAN_50HZ says it is: D* many periods away.
    assert abs(cert["d_star_s"] - CLEAN_D_STAR_S) < 1e-3, cert["d_star_s"]
    period_us = 1e6 / rate_hz
    assert period_us / 2 >= HOST_US, "the host's allowance must fit in half a period"
    bounds = clean_bounds(path, clock_us, rate_hz)
    broken, seen = [], {}
    for figure, (limit, why) in bounds.items():
        got = t[figure]
        seen[figure] = got["max_us"]
        # Measured on (nearly) every period: a clean run loses nothing.
        if got["count"] < 0.8 * duration_s * rate_hz:
            broken.append(f"{figure}: only {got['count']} measured")
        if not 0 <= got["max_us"] <= limit:
            broken.append(f"{figure} max {got['max_us']:.0f} µs > {limit:.0f} µs ({why})")
    d_us = cert["d_max_s"] * 1e6
    seen["D"] = d_us
    # D is the applied path's largest command age (one definition): at least a whole period
    # (a command is never replaced before the next sample's), at most the command age's bound.
    d_limit = bounds[f"command_age_{path}"][0]
    if not period_us <= d_us <= d_limit:
        broken.append(f"D = {d_us:.0f} µs outside [{period_us:.0f}, {d_limit:.0f}] µs")
    if t["deadline_misses"] or t["samples_without_command"]:
        broken.append(
            f"{t['deadline_misses']} deadline misses, {t['samples_without_command']} samples "
            "without a command (none within the host's allowance of half a period)"
        )
    for stream in ("state", f"torque_{path}"):
        if s["messages"][stream]["lost"]:  # nothing injected: nothing to lose
            broken.append(f"{stream}: {s['messages'][stream]['lost']} lost")
    assert not broken, "\n".join([*broken, machine_report(run_dir, s)])
    return seen


def check_certified_bound(summary: dict, scenario_path: str) -> None:
    """|v|, |omega| within the sampled-data bound at the run's measured D (the applied path's
    largest command age), recomputed here from the scenario rather than trusted."""
    from types import SimpleNamespace

    from controller_service.certificate import certify
    from hil.scenario import build_loop, load_scenario

    sc = load_scenario(scenario_path)
    _, _, context = build_loop(sc)
    cert = summary["certificate"]
    assert cert["path"] == summary["cmd_path"], "the certificate must be the applied path's"
    d = cert["d_max_s"]
    assert d >= summary["timing"]["sample_gap"]["max_us"] * 1e-6 * 0.99  # D covers a period
    params = SimpleNamespace(**dict(sc.controller))
    ind = certify(
        params, context, d, 0.0, sc.controller.get("law") == "unified_boundary",
        v0=sc.initial.v, w0=sc.initial.omega,
    )  # fmt: skip
    assert (
        abs(ind.v_bound - cert["v_bound"]) < 1e-9 and abs(ind.w_bound - cert["omega_bound"]) < 1e-9
    )
    assert summary["max_abs_v"] <= ind.v_bound, (summary["max_abs_v"], ind.v_bound)
    assert summary["max_abs_omega"] <= ind.w_bound, (summary["max_abs_omega"], ind.w_bound)
    assert summary["max_abs_tau1"] <= sc.limits.varpi1
    assert summary["max_abs_tau2"] <= sc.limits.varpi2


def load_log(path: Path) -> HopLog:
    """A service's hop log (streamed: readable while the service runs)."""
    return read_hoplog(path)


def rows_in(path: Path, table: str) -> int:
    """Rows of ``table`` in a hop log written so far (0 before the file exists)."""
    try:
        return len(read_hoplog(path).rows.get(table, []))
    except (OSError, ValueError):
        return 0


def children_of(pid: int) -> list[int]:
    """PIDs whose parent is ``pid`` (from /proc)."""
    out = []
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            with open(f"/proc/{entry}/stat") as f:
                stat = f.read()
        except OSError:
            continue
        ppid = int(stat.rsplit(")", 1)[1].split()[1])
        if ppid == pid:
            out.append(int(entry))
    return out


def cmdline(pid: int) -> str:
    try:
        with open(f"/proc/{pid}/cmdline", "rb") as f:
            return f.read().replace(b"\0", b" ").decode()
    except OSError:
        return ""


def alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False
