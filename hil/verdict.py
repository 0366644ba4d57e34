"""The verdict: one answer for the user's system (the controller, its host, the transport).

Did timing keep the law within the limits of (2), and with how much room? Three outcomes, each
with its reasons (docs/reports.md, "The verdict"):

- **FAIL**: a limit of (2) broke, the certificate is not held because of the system's own timing
  (controller late, messages lost or late on the wire: ``certificate.d_system_s`` > D*), the
  design conditions fail, or deadline misses, samples without a command or lost messages exceed
  their thresholds.
- **INCONCLUSIVE**: the bench itself (the plant emulator standing in for a robot that never
  stalls, the recorder, the bench's host) stalled enough to matter (D > D* only through the
  bench's stalls, or a limit broken while a bench stall was in force), a stall whose cause the
  logs cannot tell pushed D past D*, or the logs cannot relate a figure (CAN frames matched to
  the wrong torque, or ambiguous between two sends with D* between the two bounds of D). Never
  the user's fault; the advice says what to change.
- **PASS**: neither, with the margin D* - D.

Before all of these (:class:`LawEnd`, the first reasons of a FAIL): the law failed (raised,
returned the wrong type or a non-finite torque: its sentence, from ``law_fault``), the
controller process ended before the plant (its exit code or signal), or the robot's state
became non-finite (``nonfinite_steps``: the limits of (2) cannot hold). Each is the user's
system's, never the bench's: after the controller ended, no stall of the bench is a reason.

A run cut short is judged over what ran, and says so. A figure that was not measured is absent
from the evidence, never 0.

Every command that gives a verdict exits with that verdict's code (:data:`EXIT_CODE`,
:func:`exit_code`; the whole table, docs/reports.md "Verdict and exit code"): every FAIL exits
1, whatever made it, and INCONCLUSIVE exits 4, so a script can tell the two apart. The live view
judges with the same :func:`judge` (:func:`judge_evidence`), from the figures it has.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict, dataclass, field, fields
from typing import Any, cast

from controller_service.laws.guard import LawFault
from hil.errors import (  # noqa: F401 (the exit table, re-exported: hil.verdict.EXIT_CODE)
    BAD_INPUT,
    EXIT_CODE,
    FAIL,
    INCONCLUSIVE,
    INTERNAL_ERROR,
    INTERRUPTED,
    PASS,
    exit_code,
)
from hil.folder import layout
from hil.folder.device import DeviceFigures
from hil.folder.records import (
    Certificate,
    Constraint,
    ControllerExit,
    Messages,
    Scheduling,
    Stall,
    Summary,
    Timing,
    VerdictRecord,
)
from hil.limits import (
    LIMIT_NAMES,
    LIMIT_REL_TOL,
    PEAK_KEYS,
    SIGNALS,
    SYMBOLS,
    UNITS,
    ConstraintFigure,
    in_symbols,
)
from hil.units import ms

BENCH_ADVICE = (
    "the bench stalled, not your system: run fewer processes beside it, keep the real-time "
    'policy (scheduling = "fifo", as root or with CAP_SYS_NICE), use a quieter host, or lower '
    "the rate; then run again"
)


def control_slot(sample_ns: Any, origin_ns: int, period_ns: int) -> Any:
    """The control slot meant to answer a plant sample taken at ``sample_ns`` (an int or an
    array), on a controller's grid of deadlines ``origin_ns + k period_ns``: the first slot
    whose deadline is at or after the sample (docs/realtime.md, ``samples_without_command``)."""
    return -((origin_ns - sample_ns) // period_ns)


@dataclass(frozen=True)
class Thresholds:
    """When timing trouble turns the verdict negative (limits and certificate always do)."""

    max_deadline_miss_ratio: float = 0.01
    max_lost_ratio: float = 0.01
    max_samples_without_command_ratio: float = 0.01


DEFAULT_THRESHOLDS = Thresholds()


@dataclass(frozen=True)
class RunFacts:
    """What the verdict needs to know of how the run went (absent for a simulation)."""

    interrupted: bool = False
    duration_s: float | None = None  # planned
    duration_run_s: float | None = None  # the plant's window actually run
    scheduling: dict[str, Scheduling | None] | None = None  # requested and obtained, per service
    # What stopped the run before it ran (summary.json's ``error``: the services never became
    # ready, no outside device connected): a FAIL whatever the figures say.
    error: str | None = None
    # Why the bench did not start the run (summary.json's ``bench_error``: its own services
    # never said ready): the bench's INCONCLUSIVE, never the system's FAIL.
    bench_error: str | None = None
    # What the device did when a drive disarmed (hil.analysis.measure.reactions): notes.
    reactions: tuple[str, ...] = ()
    # Why nothing of the run could be measured (a log the bench could not read, no plant
    # sample): never a PASS, the bench's INCONCLUSIVE (a FAIL when ``error`` says more).
    unmeasured: str | None = None

    @classmethod
    def of(cls, summary: Summary) -> RunFacts | None:
        """How a run went, from its summary (None for a simulation, unless it was cut short:
        then what it covered)."""
        if summary.get("kind") != "run":
            if not summary.get("interrupted"):
                return None
            ran = summary.get("duration")
            return cls(
                interrupted=True, duration_run_s=ran if isinstance(ran, int | float) else None
            )
        sched = summary.get("scheduling")
        return cls(
            interrupted=bool(summary.get("interrupted")),
            duration_s=summary.get("duration_planned_s", summary.get("duration")),
            duration_run_s=summary.get("duration_run_s"),
            scheduling=sched if isinstance(sched, dict) else None,
            error=str(summary["error"]) if summary.get("error") else None,
            bench_error=str(summary["bench_error"]) if summary.get("bench_error") else None,
            reactions=tuple(str(r.get("sentence")) for r in summary.get("drive_reactions") or []),
            unmeasured=_unmeasured(summary),
        )


def _unmeasured(summary: Summary) -> str | None:
    """Why a run's figures are absent (None: they were measured)."""
    unreadable = summary.get("logs_unreadable") or {}
    if unreadable:
        why = "; ".join(f"{role}: {text}" for role, text in sorted(unreadable.items()))
        return f"the bench could not read its own logs, so the run was not measured ({why})"
    if "window_s" not in (summary.get("timing") or {}):
        return "the run was not measured: the plant took no sample the bench could read"
    return None


@dataclass(frozen=True)
class LawEnd:
    """How the law's loop ended before its time, from a summary (each part absent when it did
    not happen): the law's fault, the controller process's early exit, the plant steps whose
    state was not finite."""

    law_fault: LawFault | None = None
    controller_exit: ControllerExit | None = None
    nonfinite_steps: int = 0
    nonfinite_first_t_s: float | None = None

    @classmethod
    def of(cls, summary: Summary) -> LawEnd:
        fault = summary.get("law_fault")
        stop = summary.get("controller_exit")
        steps = summary.get("nonfinite_steps")
        first = summary.get("nonfinite_first_t_s")
        return cls(
            law_fault=LawFault.from_dict(fault) if isinstance(fault, dict) else None,
            controller_exit=stop if isinstance(stop, dict) else None,
            nonfinite_steps=steps if isinstance(steps, int) and not isinstance(steps, bool) else 0,
            nonfinite_first_t_s=float(first) if isinstance(first, int | float) else None,
        )

    @property
    def controller_ended(self) -> bool:
        """The law stopped commanding before the run's end (its fault or its process's end)."""
        return self.law_fault is not None or self.controller_exit is not None

    def reasons(self) -> list[str]:
        """The sentences, the law's own first."""
        out = []
        if self.law_fault is not None:
            out.append(self.law_fault.sentence())
        elif self.controller_exit is not None:
            out.append(_exit_words(self.controller_exit))
        if self.nonfinite_steps > 0:
            at = self.nonfinite_first_t_s
            when = f"at t = {at:.6g} s" if at is not None else "during the run"
            out.append(
                f"the robot's state became non-finite {when} ({self.nonfinite_steps} plant "
                "steps): the limits of (2) cannot hold"
            )
        return out


def _exit_words(stop: ControllerExit) -> str:
    """ "the controller process exited with code N (was killed by signal S) at t = X s; ..."."""
    how = (
        f"was killed by signal {stop['signal']}"
        if stop.get("signal")
        else f"exited with code {stop.get('code')}"
    )
    at = stop.get("t_s")
    when = f"at t = {at:.3f} s" if isinstance(at, int | float) else "before the run's end"
    output = stop.get("output") or layout.CONTROLLER_OUTPUT
    return f"the controller process {how} {when}; its output: {output}"


def law_ended(summary: Summary) -> str | None:
    """The first reason of :class:`LawEnd` for a summary (None: the law ran to the end)."""
    reasons = LawEnd.of(summary).reasons()
    return reasons[0] if reasons else None


@dataclass
class Verdict:
    outcome: str = PASS
    fail_reasons: list[str] = field(default_factory=list)
    inconclusive_reasons: list[str] = field(default_factory=list)
    advice: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    limits: str = "held"  # "broken", or "not measured" (no peak known)
    limits_broken: list[str] = field(default_factory=list)
    certificate: str = "not applicable"
    timing: Timing = field(default_factory=lambda: Timing())
    thresholds: dict[str, float] = field(default_factory=dict)

    @property
    def reasons(self) -> list[str]:
        return [*self.fail_reasons, *self.inconclusive_reasons]

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> Verdict:
        """The verdict summary.json holds (:meth:`as_dict`), judged once by the analysis."""
        return cls(**{f.name: data[f.name] for f in fields(cls) if f.name in data})

    def as_dict(self) -> VerdictRecord:
        out = cast(VerdictRecord, asdict(self))
        out["ok"] = self.outcome == PASS
        out["reasons"] = self.reasons
        for key in ("deadline_misses", "samples_without_command", "lost_messages"):
            found = self.timing.get(key) or {}
            out[key] = found.get("count", found.get("lost"))
        return out


def constraints_from_peaks(summary: Summary, limits: dict[str, float]) -> dict[str, Constraint]:
    """Per limit of (2) its peak over every plant step (summary.json's ``max_abs_*``), the
    limit and whether it held (peaks not measured are left out)."""
    out = {}
    for key, skey in PEAK_KEYS.items():
        peak, limit = summary.get(skey), limits.get(LIMIT_NAMES[key])
        if isinstance(peak, int | float) and isinstance(limit, int | float) and limit > 0:
            c = ConstraintFigure(key, float(peak), float(limit), None)
            out[key] = {"peak": c.peak, "limit": c.limit, "ratio": c.ratio, "held": c.held}
    return out


def _pct(x: float) -> str:
    return f"{100.0 * x:.3f} %"


def _bench_stalls(cert: Certificate | None) -> list[Stall]:
    return [s for s in (cert or {}).get("stalls") or [] if s.get("owner") == "bench"]


def _stall_words(s: Stall) -> str:
    who = {
        "plant_late": "the plant emulator",
        "host_stalled": "the bench's host",
        "host_overloaded": "the bench's host (busy with other processes)",
        "bench_dropped": "the bench's own socket (frames dropped, its queue full)",
    }.get(s.get("cause", ""), s.get("cause", ""))
    return f"{who} stalled at t = {s['t_s']:.3f} s (command age {ms(s['age_s'])}, {s['cause']})"


def judge(
    cons: dict[str, Constraint],
    violations: dict[str, int],
    cert: Certificate | None,
    timing: Timing | None,
    messages: Messages | None,
    facts: RunFacts | None = None,
    thresholds: Thresholds = DEFAULT_THRESHOLDS,
    ended: LawEnd | None = None,
    device: DeviceFigures | None = None,
) -> Verdict:
    """The verdict (module docstring). ``cons``: per limit of (2) its peak, limit and whether
    it held; ``violations``: plant steps beyond each limit; ``cert``: the certificate object
    (summary.json's, or a simulation's); ``timing``/``messages``: the run's (None for a
    simulation); ``ended``: how the law's loop ended early (:meth:`LawEnd.of` the summary);
    ``device``: the device's figures at the bus (summary.json's ``device``)."""
    v = Verdict(thresholds=asdict(thresholds))
    _law_ended(v, ended)
    _limits(v, cons, violations, cert)
    _certificate(v, cons, cert, outside=device is not None and device.outside)
    if timing is not None:
        _thresholds(v, timing, messages or {}, (cert or {}).get("path"), thresholds)
    if device is not None:
        _device(v, device, timing or {}, thresholds)
    _relatable(v, messages or {})
    _facts(v, facts)
    _after_the_controller_ended(v, ended)
    if v.fail_reasons:
        v.outcome = FAIL
    elif v.inconclusive_reasons:
        v.outcome = INCONCLUSIVE
    if v.outcome != INCONCLUSIVE:
        # "The bench stalled, not your system" never stands beside a FAIL of the system.
        v.advice = [a for a in v.advice if a != BENCH_ADVICE]
    return v


def _law_ended(v: Verdict, ended: LawEnd | None) -> None:
    """The law's fault, the controller's early end, a non-finite state: the first reasons."""
    for text in ended.reasons() if ended is not None else []:
        v.fail_reasons.append(text)
    if ended is not None and ended.nonfinite_steps > 0:
        v.limits = "broken"


def _after_the_controller_ended(v: Verdict, ended: LawEnd | None) -> None:
    """Once the controller stopped commanding, the command age grows until the run is stopped:
    a stall then is the controller's end, never the bench's. What would blame the bench is kept
    as a note, and the bench's advice is not given."""
    if ended is None or not ended.controller_ended or not v.inconclusive_reasons:
        return
    moved = "; ".join(short_reason(r, 100) for r in v.inconclusive_reasons)
    v.notes.append(f"not judged, the controller had ended: {moved}")
    v.inconclusive_reasons.clear()


def run_started(summary: Summary) -> bool:
    """Whether the run started: neither the system (``error``) nor the bench
    (``bench_error``) kept it from starting."""
    return not summary.get("error") and not summary.get("bench_error")


def run_outcome(summary: Summary) -> str:
    """The outcome ``hil run`` (and each robot of ``hil fleet``) exits with for its summary:
    its verdict's; a run the system kept from starting (``error``: no outside device came) is
    a FAIL whatever its figures say (one the bench did not start, ``bench_error``, is its
    verdict's INCONCLUSIVE)."""
    if summary.get("error"):
        return FAIL
    return str((summary.get("verdict") or {}).get("outcome") or FAIL)


@dataclass(frozen=True)
class Evidence:
    """What a verdict is judged from, as far as it is known: what the live view has while the
    run goes (hil.bench.live.timing), the same figures the final verdict reads from summary.json.
    Each figure not known is None: absent from the verdict, never 0."""

    #: max |x| of each signal of (2) seen ("v", "omega", "tau1", "tau2"), and the limits
    #: ("phi1", "phi2", "varpi1", "varpi2")
    peaks: dict[str, float]
    limits: dict[str, float]
    d_max_s: float | None = None  # the longest command age D
    d_star_s: float | None = None  # the certificate's D* (None: the law has none)
    path: str | None = None  # the applied command path
    samples_without_command: int | None = None
    samples_judged: int | None = None  # the samples the controller was meant to answer
    deadline_misses: int | None = None
    slots: int | None = None


def judge_evidence(ev: Evidence, thresholds: Thresholds = DEFAULT_THRESHOLDS) -> Verdict:
    """:func:`judge` on an :class:`Evidence` record. Without the stalls' owners (the live
    view has none) all of D is the system's, as for a simulation: D > D* is a FAIL."""
    cons = constraints_from_peaks({PEAK_KEYS[k]: p for k, p in ev.peaks.items()}, ev.limits)
    cert = None
    if ev.d_star_s is not None:
        held = ev.d_max_s is not None and ev.d_max_s <= ev.d_star_s
        cert = {"path": ev.path, "d_max_s": ev.d_max_s, "d_star_s": ev.d_star_s, "held": held}
    timing: Timing = {}
    for n, over, names in (
        (ev.samples_without_command, ev.samples_judged,
         ("samples_without_command", "samples_judged", "samples_without_command_rate")),
        (ev.deadline_misses, ev.slots, ("deadline_misses", "slots", "deadline_miss_rate")),
    ):  # fmt: skip
        if n is not None and over:
            timing.update(zip(names, (n, over, n / over), strict=True))
    return judge(cons, {}, cert, timing, {}, None, thresholds)


def _bench_stalled(v: Verdict, text: str) -> None:
    """An INCONCLUSIVE reason that is a stall of the bench: with it comes the advice (given
    only when the verdict is INCONCLUSIVE, :func:`judge`)."""
    v.inconclusive_reasons.append(text)
    if BENCH_ADVICE not in v.advice:
        v.advice.append(BENCH_ADVICE)


def _limits(
    v: Verdict, cons: dict[str, Constraint], violations: dict[str, int], cert: Certificate | None
) -> None:
    broken = []
    for key in (k for k in SIGNALS if k in cons or k in violations):
        n = violations.get(key)
        n = int(n) if isinstance(n, int | float) and not isinstance(n, bool) else 0
        c = cons.get(key)
        if n <= 0 and (c is None or c["held"]):
            continue
        broken.append(key)
        if c is None:  # steps counted beyond the limit, its peak not known
            v.fail_reasons.append(
                f"limits of (2) broken: |{SIGNALS[key]}| beyond {SYMBOLS[key]} at {n} plant steps"
            )
            continue
        where = f"at {n} plant steps" if n > 0 else "at its peak sample"
        sig, sym = SIGNALS[key], SYMBOLS[key]  # the pages' one symbol style (hil.limits)
        text = (
            f"limits of (2) broken: |{sig}| beyond {sym} = {c['limit']:.4g} "
            f"{UNITS[key]} {where} (max |{sig}| = {c['peak']:.4g} {UNITS[key]}, "
            f"{100 * c['ratio']:.1f} % of {sym})"
        )
        bench = _bench_stalls(cert)
        d_sys, d_star = (cert or {}).get("d_system_s"), (cert or {}).get("d_star_s")
        if bench and d_sys is not None and d_star is not None and d_sys <= d_star:
            # The bound guarantees (2) at the system's own D: the bench's stall broke it.
            _bench_stalled(v, f"{text}, while {_stall_words(bench[0])}")
        else:
            v.fail_reasons.append(text)
    v.limits_broken = sorted(broken)
    # No peak measured (the plant's log unread): the limits are not known to have held.
    v.limits = "broken" if broken else ("held" if cons else "not measured")


def _certificate(
    v: Verdict, cons: dict[str, Constraint], cert: Certificate | None, outside: bool = False
) -> None:
    if not cert or cert.get("d_star_s") is None:
        return
    held = cert.get("held")
    d, ds = cert.get("d_max_s"), cert.get("d_star_s")
    where = f" on the {cert['path']} path" if cert.get("path") else ""
    beyond = [
        (k, b)
        for k, b in (("v", cert.get("v_bound")), ("omega", cert.get("omega_bound")))
        if b is not None and k in cons and cons[k]["peak"] > b * (1.0 + LIMIT_REL_TOL)
    ]
    for k, b in beyond:
        v.fail_reasons.append(
            f"measured beyond the sampled-data bound: max |{SIGNALS[k]}| = {cons[k]['peak']:.4g} "
            f"{UNITS[k]} > {b:.4g} {UNITS[k]}",
        )
    v.certificate = "broken" if beyond else {True: "held", False: "not held"}.get(held, "unknown")
    if held is None:
        up = cert.get("d_max_upper_s")
        v.inconclusive_reasons.append(
            f"certificate unknown: the CAN logs allow D from {ms(d)} to {ms(up)}{where}, and "
            f"D* = {ms(ds)} lies between (frames that could match more than one send)"
        )
        return
    if held:
        return
    if d is None:
        v.fail_reasons.append(f"certificate not held: no command ever landed{where} (D unknown)")
    elif d > ds:
        _age_beyond(v, cert, where, outside)
    else:
        failed = in_symbols(", ".join(cert.get("failed_conditions") or [])) or "see the certificate"
        v.fail_reasons.append(
            f"certificate not held: design conditions broken ({failed}) at D = {ms(d)}"
        )


def _age_beyond(v: Verdict, cert: Certificate, where: str, outside: bool = False) -> None:
    """D > D*: whose stalls pushed it there. For an outside device (no controller log), a
    stall that is not the bench's is the device's: nothing else sits between the States the
    bench sent and the commands it received."""
    d, ds = cert["d_max_s"], cert["d_star_s"]
    # Without the stalls' owners (a simulation, an older summary) all of D is the system's.
    d_sys = cert["d_system_s"] if cert.get("d_system_s") is not None else d
    stalls = cert.get("stalls") or []
    failed = cert.get("failed_conditions") or []
    also = f"; failing: {in_symbols(', '.join(failed))}" if failed else ""
    head = f"command age D = {ms(d)} > D* = {ms(ds)}{where} (margin {ms(ds - d)}{also})"
    if d_sys > ds:
        mine = [s for s in stalls if s.get("owner") == "system" and s["age_s"] > ds]
        unknown = [s for s in stalls if s.get("owner") == "unknown" and s["age_s"] > ds]
        if outside:
            mine += unknown
        elif not mine and unknown:
            v.inconclusive_reasons.append(
                f"certificate not held: {head}, by a stall whose cause the logs cannot tell "
                f"(t = {unknown[0]['t_s']:.3f} s, {ms(unknown[0]['age_s'])})"
            )
            return
        text = f"certificate not held: {head} by the system's own timing"
        if mine:
            w = mine[0]
            text += f"; worst: t = {w['t_s']:.3f} s, {ms(w['age_s'])}, {w['cause']}"
        v.fail_reasons.append(text)
        return
    bench = [st for st in _bench_stalls(cert) if st["age_s"] > ds] or _bench_stalls(cert)
    what = "; ".join(_stall_words(st) for st in bench[:3]) or "the bench stalled"
    more = f" (and {len(bench) - 3} more)" if len(bench) > 3 else ""
    _bench_stalled(
        v,
        f"the bench stalled: {head} only because {what}{more}; without the "
        f"bench's stalls D = {ms(d_sys)} <= D*",
    )


def _thresholds(
    v: Verdict, timing: Timing, messages: Messages, path: str | None, th: Thresholds
) -> None:
    """Deadline misses, samples without a command and lost messages of the applied path and
    the State stream against their thresholds (the shadow path never counts)."""
    counts = (
        # (count key, over key, rate key, the text, the over's name, threshold)
        ("deadline_misses", "slots", "deadline_miss_rate",
         "deadline misses: {n} of {over} slots", "slots", th.max_deadline_miss_ratio),
        ("samples_without_command", "samples_judged", "samples_without_command_rate",
         "samples without a command: {n} of {over}", "judged",
         th.max_samples_without_command_ratio),
    )  # fmt: skip
    for key, over_key, rate_key, text, over_name, limit in counts:
        n, over, rate = timing.get(key), timing.get(over_key), timing.get(rate_key)
        if not isinstance(n, int) or not isinstance(rate, int | float):
            continue  # not measured in this run: absent, never 0
        v.timing[key] = {"count": n, over_name: over, "rate": rate}
        if rate <= limit:
            continue
        # Over its threshold: the system's failure, unless only the bench's share put it over:
        # those inside the bench's stalls, and samples the plant's (the bench's emulator's)
        # own late wake-up left without a command (hil.analysis.measure.figures._bench_shares).
        stalled = int(timing.get(f"{key}_in_bench_stalls") or 0)
        plant_late = int(timing.get(f"{key}_plant_late") or 0)
        bench = stalled + plant_late
        system_rate = (n - bench) / over if over else 0.0
        words = text.format(n=n, over=over) + f" ({_pct(rate)}) > {_pct(limit)}"
        if system_rate > limit:
            v.fail_reasons.append(words)
        else:
            shares = [f"{stalled} of them fell inside the bench's stalls"] if stalled else []
            if plant_late:
                shares.append(
                    f"the plant's late wake-ups left {plant_late} of them: their States came "
                    "after the tick meant to answer them, in time had the plant been on time"
                )
            _bench_stalled(
                v, f"{words}, but {' and '.join(shares)}; without them {_pct(system_rate)}"
            )
    streams = [s for s in ("state", f"torque_{path}" if path else "") if s in messages]
    if streams:
        lost = sum(int(messages[s].get("lost", 0)) for s in streams)
        sent = sum(int(messages[s].get("sent", 0)) for s in streams)
        ratio = lost / sent if sent else (1.0 if lost else 0.0)
        v.timing["lost_messages"] = {"lost": lost, "sent": sent, "rate": ratio, "streams": streams}
        if ratio > th.max_lost_ratio:
            per = ", ".join(
                f"{s} {messages[s].get('lost', 0)} of {messages[s].get('sent', 0)}" for s in streams
            )
            words = (
                f"lost messages: {lost} of {sent} ({_pct(ratio)}) > {_pct(th.max_lost_ratio)} "
                f"({per})"
            )
            # Those the bench's own sockets dropped are not the system's (docs/reports.md).
            bench = sum(int(messages[s].get("lost_by_bench") or 0) for s in streams)
            system_ratio = (lost - bench) / sent if sent else 0.0
            if bench and system_ratio <= th.max_lost_ratio:
                v.inconclusive_reasons.append(
                    f"{words}, but the bench's own socket dropped {bench} of them; without "
                    f"them {_pct(system_ratio)}"
                )
            else:
                v.fail_reasons.append(words)


def _device(v: Verdict, dev: DeviceFigures, timing: Timing, th: Thresholds) -> None:
    """The device's own figures at the bus (hil.analysis.measure.device): torques asked beyond
    the limits of (2) (FAIL, even though the bench clamped them); its command gaps, where the
    hosted figure ``samples_without_command`` is not measured (an outside device on CAN): the
    samples inside its own gaps over the threshold FAIL, those inside gaps the bench's stalls
    made are the bench's; what it did on the bus and the States it named that were never sent
    are counted, never fatal (notes)."""
    commands = sum(s.commands for s in dev.streams)
    if dev.outside and commands == 0:
        v.fail_reasons.append("the device sent no command the bench received in the run")
    elif dev.outside and dev.path == "can" and dev.bus.armed == 0:
        v.fail_reasons.append(
            f"the device never armed the drives (no closed-loop control accepted): its "
            f"{commands} input frames moved nothing"
        )
    for b in dev.beyond_limits:
        name = b.signal if b.signal.startswith("q ") else f"|{b.signal}|"
        v.fail_reasons.append(
            f"the device asked torques beyond the limits of (2): {name} up to "
            f"{b.worst_words()} > {b.limit:.4g} in {b.count} commands (the bench clamped them)"
        )
    n, bench, over = dev.samples_in_gaps, dev.samples_in_bench_gaps, dev.samples_judged
    if "samples_without_command" not in timing and over > 0:
        limit = th.max_samples_without_command_ratio
        gaps = sorted(dev.gaps, key=lambda g: -g.length_s)
        worst = next((g for g in gaps if g.owner == "device"), gaps[0] if gaps else None)
        at = f"; longest gap {ms(worst.length_s)} at t = {worst.start_s:.3f} s" if worst else ""
        words = (
            f"the device stalled: {n} of {over} samples fell in its command gaps "
            f"({_pct(n / over)}) > {_pct(limit)}{at}"
        )
        if n / over > limit:
            v.fail_reasons.append(words)
        elif (n + bench) / over > limit:
            _bench_stalled(
                v,
                f"samples without a device command: {n + bench} of {over} "
                f"({_pct((n + bench) / over)}) > {_pct(limit)}, but {bench} of them fell in gaps "
                f"the bench's stalls made; without them {_pct(n / over)}",
            )
    if dev.unnamed:
        v.notes.append(
            f"the device named {dev.unnamed} States the bench never sent (counted, refused "
            "as a name: their age is not known)"
        )
    bus = dev.bus
    said = [
        f"{k} {x}"
        for k, x in (("malformed", bus.malformed), ("unknown", bus.unknown),
                     ("refused", bus.refused), ("watchdog trips", bus.watchdog_trips))
        if x
    ]  # fmt: skip
    if said:
        who = "the device" if dev.outside else "the controller"  # yours, or the law hosted
        v.notes.append(f"{who} on the bus: {', '.join(said)} (counted, never fatal)")
    if dev.outside and dev.age_is_bound and dev.d_max_s is not None:
        v.notes.append(
            f"the command age D is not measured on CAN for an outside device (a torque frame "
            f"names no encoder estimate); at landing it was at least {ms(dev.d_max_s)} "
            "(a lower bound), so the certificate is not judged"
        )


def _relatable(v: Verdict, messages: Messages) -> None:
    """Figures the logs cannot relate: CAN frames whose torque differs from their send's."""
    can = messages.get("torque_can") or {}
    if int(can.get("value_mismatches") or 0) > 0:
        v.inconclusive_reasons.append(
            f"the CAN figures cannot be trusted: {can['value_mismatches']} received frames carry "
            "another torque than the send they were matched to"
        )


def _facts(v: Verdict, facts: RunFacts | None) -> None:
    if facts is None:
        return
    if facts.error:
        v.fail_reasons.insert(0, facts.error)
    elif facts.bench_error:  # a run that never started says only why
        if v.fail_reasons:
            moved = "; ".join(short_reason(r, 100) for r in v.fail_reasons)
            v.notes.append(f"not judged, the run did not start: {moved}")
            v.fail_reasons.clear()
        v.inconclusive_reasons[:] = [facts.bench_error]
    elif facts.unmeasured:
        v.inconclusive_reasons.insert(0, facts.unmeasured)
    v.notes.extend(facts.reactions)
    if facts.interrupted:
        ran = f"{facts.duration_run_s:.3f} s" if facts.duration_run_s is not None else "?"
        planned = f" of {facts.duration_s:g} s" if facts.duration_s is not None else ""
        text = f"interrupted after {ran}{planned}: the verdict covers only that"
        if facts.duration_run_s is not None and facts.duration_s is not None:
            rest = max(0.0, facts.duration_s - facts.duration_run_s)
            text = (
                f"interrupted after {ran}{planned}: the verdict covers only those {ran} "
                f"and makes no claim about the {rest:.3f} s not run"
            )
        v.notes.append(text)
    for role, sched in (facts.scheduling or {}).items():
        if not isinstance(sched, dict):
            continue
        if sched.get("requested") == "fifo" and sched.get("policy") != "SCHED_FIFO":
            v.notes.append(
                f"the {role} asked for SCHED_FIFO and got {sched.get('policy')}: wake-up "
                "lateness, deadline misses and command age are those of a time-shared host"
            )
        refused = (sched.get("errors") or {}).get("idle")
        if refused:
            v.notes.append(
                f"the {role} could not hold the CPUs out of slow idle states ({refused}): every "
                "hop and wake-up also pays the CPUs' wake-up from idle ([realtime] idle)"
            )


def short_reason(text: str, limit: int | None = None) -> str:
    """A reason as one line quotes it: up to its first "; " outside parentheses (the rest are
    its details, which the report keeps), whole: a sentence cut mid-way ("at t = (…)") reads as
    a bug. ``limit`` (a note's quote of another reason) cuts it at a word within as many
    characters."""
    depth = 0
    for i, ch in enumerate(text):
        depth += {"(": 1, ")": -1}.get(ch, 0)
        if depth == 0 and text.startswith("; ", i):
            text = text[:i]
            break
    if limit is None or len(text) <= limit:
        return text
    return text[:limit].rsplit(" ", 1)[0] + " (…)"
