"""What the report says: its first lines (:func:`headline`), then section by section, as blocks
that report.md (:func:`render_markdown`) and report.html (:func:`render_html`) both render
(paragraphs, lists, tables, figures): one text, two formats; and the words and unit of each
figure ``hil compare`` shows. The HTML opens offline: inline CSS, figures as base64 PNG data URIs,
no script, no link."""

from __future__ import annotations

import base64
import html
import math
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from typing import Any, cast

import numpy as np

from hil.analysis.margin.record import MarginRecord, summary_lines
from hil.analysis.report.device import NO_D_ON_CAN, device_section
from hil.analysis.report.device import SECTION as DEVICE_SECTION
from hil.analysis.report.device import TITLE as DEVICE_TITLE
from hil.analysis.report.figures import Figure
from hil.folder.records import (
    AgeAnswer,
    Headline,
    LimitsAnswer,
    ReportData,
    SamplesAnswer,
    StallsAnswer,
    Summary,
    TickPhase,
    Timing,
    Topology,
)
from hil.limits import SIGNALS, SYMBOLS, UNITS, in_symbols
from hil.units import ms
from hil.verdict import EXIT_CODE, LawEnd
from protocol.settings import CMD_PATHS

#: Each signal of (2) and its limit's symbol, the signal's own (hil.limits.LIMITS).
LIMITS, SYMBOL = SYMBOLS, SIGNALS
TOP_STALLS = 3

NORMALIZED = (
    "Model (1) is normalized: v' = τ1 + d1 and ω' = τ2 + d2, so τ1 is an acceleration (m/s²) "
    "and τ2 an angular acceleration (rad/s²), per unit mass and yaw inertia, although the "
    "paper labels τ1, τ2 in N·m."
)
#: Said only on a page that has the drives' section (a run on the CAN path).
DRIVES_NOTE = (
    "The torques that really go to the drives, in N·m, are in the section on CAN and drives."
)
WHAT_2 = (
    "The constraints (2) are the limits the law must never exceed: |v| ≤ φ1 and |ω| ≤ φ2 on "
    "the velocities, |τ1| ≤ ϖ1 and |τ2| ≤ ϖ2 on the inputs of model (1)."
)
WHAT_4 = (
    "The tracking errors (4) are the robot's position error seen from the robot itself (xe "
    "ahead, ye to its left) and its heading error θe = θ − θd, both measured against the "
    "virtual robot (3) that runs the reference."
)
SLIDING = (
    "v~ = v − α_v and w~ = ω − α_ω are the sliding variables of (10): how far the robot's "
    "velocities are from the ones the law steers them to (α_v, α_ω of (7)); the law switches "
    "its torque on their sign. Once they first reach zero (the reaching time) sampling keeps "
    "them in a band around zero instead of on it: the narrower, the closer to the "
    "continuous-time law."
)
WHAT_CERT = (
    "The certificate is the sampled-data bound of docs/sampled_data_bound.md: as long as no "
    "command stays in force longer than D* after the sample it was computed from, |v| and |ω| "
    "stay within (2) despite sampling and delay; it holds when the measured longest command "
    "age D is at most D* and the design conditions of the paper hold."
)


@dataclass
class Section:
    id: str
    title: str
    blocks: list[tuple[Any, ...]] = field(default_factory=list)

    def p(self, text: str) -> None:
        self.blocks.append(("p", text))

    def items(self, texts: list[str]) -> None:
        self.blocks.append(("list", texts))

    def table(self, header: list[str], rows: list[list[Any]], fold: str | None = None) -> None:
        """``fold``: the HTML shows the table folded under this line (whatever its length)."""
        if rows:
            self.blocks.append(("table", header, rows, fold))

    def figure(self, name: str) -> None:
        self.blocks.append(("figure", name))


def fmt(value: Any) -> str:
    if value is None:
        return "–"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        return f"{value:.6g}" if math.isfinite(value) else str(value)
    if isinstance(value, dict):
        return ", ".join(_named(str(k), v) for k, v in value.items()) or "none"
    return str(value)


# A figure's unit from its key's suffix (how summary.json names them): shown in a reader's unit
# (seconds in ms). A rate ("_rev_s": rev/s) is matched before the plain seconds it ends like.
_SUFFIX_UNITS = {"_rev_s": "rev/s", "_rad_s": "rad/s", "_m_s": "m/s", "_per_s": "/s", "_hz": "Hz"}
_SUFFIX_UNITS |= {"_nm": "N·m", "_rev": "rev", "_pct": "%", "_us": "µs", "_ms": "ms", "_s": "ms"}


def _named(key: str, value: Any) -> str:
    """``controller_lateness_s 0.000101`` as "controller lateness 0.101 ms": a dict's entry in
    words and a unit, the nested ones in parentheses."""
    if isinstance(value, dict):
        return f"{key.replace('_', ' ')} ({fmt(value)})"
    number = isinstance(value, int | float) and not isinstance(value, bool)
    for suffix, unit in _SUFFIX_UNITS.items():
        if key.endswith(suffix) and number:
            scale = 1e3 if suffix == "_s" else 1.0
            return f"{key.removesuffix(suffix).replace('_', ' ')} {value * scale:.3g} {unit}"
    return f"{key.replace('_', ' ')} {fmt(value)}"


def _ms(x: Any) -> Any:
    return x * 1e3 if isinstance(x, int | float) and not isinstance(x, bool) else None


#: The percentile figures, and how a table heads them.
PCT = {"p50_us": "p50 [µs]", "p90_us": "p90 [µs]", "p99_us": "p99 [µs]", "p999_us": "p99.9 [µs]"}
PCT |= {"max_us": "max [µs]", "count": "count"}


NOT_MEASURED = "n/a"
# The stall threshold's rule, by whether the law has a D* (index: no D*).
_STALL_RULE = ("stall threshold max(3 Ts, D*/2) [ms]", "stall threshold 3 Ts (no D*) [ms]")


def _pct_rows(
    timing: Timing, names: list[tuple[str, str]], always: tuple[str, ...] = ()
) -> list[list[Any]]:
    """Percentile rows; a figure in ``always`` that the run did not measure (its trigger mode
    has none) shows as n/a, never as 0."""
    rows = []
    for key, label in names:
        f = timing.get(key)
        if isinstance(f, dict):
            rows.append([label, *(f.get(q) for q in PCT)])
        elif key in always:
            rows.append([label, *(NOT_MEASURED for _ in PCT)])
    return rows


def _per_path(prefix: str, applied: str | None, shadow: str) -> list[tuple[str, str]]:
    """The figure ``prefix + path`` of each path, labelled applied or ``shadow``."""
    return [(prefix + p, f"{p} ({'applied' if p == applied else shadow})") for p in CMD_PATHS]


def sections(data: ReportData) -> Iterator[Section]:
    for sid in data["sections"]:
        title, build = SECTIONS[sid]
        s = Section(sid, title)
        build(s, data)
        yield s


def _headline(s: Section, data: ReportData) -> None:
    s.items([line["text"] for line in data["headline"]["lines"]])


def _limits(data: ReportData, summary: Summary) -> tuple[LimitsAnswer, str]:
    cons = data["metrics"]["constraints"]
    violations = summary.get("violations") or {}
    out: LimitsAnswer = {"held": data["verdict"]["limits"] == "held"}
    parts, broken = [], []
    for key, name in LIMITS.items():
        unit, c, sym = UNITS[key], cons[key], SYMBOL[key]
        n = violations.get(key)
        n = int(n) if isinstance(n, int | float) and not isinstance(n, bool) else None
        pct = 100.0 * c["ratio"]
        out[key] = {"max": c["peak"], "limit": c["limit"], "percent_of_limit": pct, "violations": n}
        limit = f"{name} = {c['limit']:.4g} {unit}"
        parts.append(f"max |{sym}| = {c['peak']:.4g} {unit} is {pct:.1f} % of {limit}")
        if (n or 0) > 0:
            broken.append(f"|{sym}| beyond {name} at {n} plant steps")
        elif not c["held"]:
            broken.append(f"|{sym}| beyond {name}")
    every = "over every plant step" if violations else "over the trace's samples"
    ended = LawEnd.of(summary)  # type: ignore[arg-type]
    if ended.nonfinite_steps > 0:  # NaN compares false with every limit: said here instead
        broken.insert(0, f"the state became non-finite at {ended.nonfinite_steps} plant steps")
        out["held"] = False
    state = "held" if not broken else "BROKEN (" + "; ".join(broken) + ")"
    if not broken and ended.controller_ended:  # what ran, not a run that held to its end
        stop = ended.law_fault.t_s if ended.law_fault else (ended.controller_exit or {}).get("t_s")
        when = f" at t = {stop:.3f} s" if isinstance(stop, int | float) else ""
        state = f"held until the law stopped{when} (the verdict says why)"
    return out, f"Limits of (2) {state}, {every}: " + "; ".join(parts) + "."


def _command_age(data: ReportData) -> tuple[AgeAnswer, str]:
    cert = data["certificate"]
    d, ds, margin = cert.get("d_max_s"), cert.get("d_star_s"), cert.get("margin_s")
    path = cert.get("path")
    keys = ("path", "d_max_s", "d_star_s", "margin_s", "held", "source")
    out = cast(AgeAnswer, {k: cert.get(k) for k in keys})
    if data["kind"] != "run" or path is None:
        what = f"Command age D ≤ Ts + worst delay = {ms(d)} (the scenario's timing)"
    elif d is None and cert.get("source") == NO_D_ON_CAN:
        return out, f"Command age D: not measured ({NO_D_ON_CAN})."
    elif d is None:
        return out, f"Command age: no command ever landed on the {path} path (D unknown)."
    else:
        what = f"Command age D = {ms(d)} on the applied path ({path})"
    if ds is None:
        return out, f"{what}; no certificate ({data['scenario']['law']} has none)."
    if cert.get("held"):
        state = "certificate held"
    elif d is not None and d > ds:
        state = "certificate NOT held (D > D*)"
    else:
        failed = in_symbols(", ".join(cert.get("failed_conditions") or [])) or "design conditions"
        state = f"certificate NOT held ({failed})"
    return out, f"{what} against D* = {ms(ds)}: margin {ms(margin)}, {state}."


def _stalls(data: ReportData) -> tuple[StallsAnswer, str]:
    cert = data["certificate"]
    stalls = list(cert.get("stalls") or [])
    thr = cert.get("stall_threshold_s")
    top = [{k: s.get(k) for k in ("t_s", "age_s", "cause", "owner")} for s in stalls[:TOP_STALLS]]
    total, stalled = cert.get("stall_count", len(stalls)), cert.get("stalled_time_s")
    out: StallsAnswer = {"threshold_s": thr, "listed": len(stalls), "count": total, "top": top}
    out["stalled_time_s"] = stalled
    if data["kind"] != "run" or cert.get("path") is None:
        return out, "Stalls: not measured in a simulation (every command lands after its delay)."
    if thr is None:
        return out, "Stalls: no stall threshold without a certificate."
    rule = "max(3 Ts, D*/2)" if cert.get("d_star_s") is not None else "3 Ts"
    if not stalls:
        return out, (
            f"Stalls: none; the command age never exceeded the stall threshold {rule} = {ms(thr)}."
        )
    items = "; ".join(
        f"t = {s['t_s']:.3f} s, age {ms(s['age_s'])}, cause {s['cause']}"
        + (f" ({s['owner']})" if s.get("owner") else "")
        for s in top
    )
    spent = f", {ms(stalled)} in all above it" if stalled is not None else ""
    # A law without a certificate has no D*: its threshold is 3 Ts and the list is the longest.
    which = "closest to D*" if cert.get("d_star_s") is not None else "longest (no D* for this law)"
    return out, f"Stalls {which} (top {len(top)} of {total} above {ms(thr)}{spent}): {items}."


def _samples(data: ReportData, summary: Summary) -> tuple[SamplesAnswer, str]:
    timing = (data.get("timing") or {}).get("summary") or {}
    n, judged = timing.get("samples_without_command"), timing.get("samples_judged")
    rate = timing.get("samples_without_command_rate")
    what = "Samples without a command:"
    if data["kind"] == "run" and isinstance(n, int) and isinstance(rate, int | float):
        text = f"{what} {n} of {judged} ({100.0 * rate:.3f} %)."
        return {"count": n, "judged": judged, "rate": rate}, text
    if data["kind"] == "run":
        text = f"{what} not measured (the run has no such figure)."
        return {"count": None, "judged": None, "rate": None}, text
    dropped = summary.get("commands_dropped")
    extra = f"; {dropped} commands overtaken by a newer one and dropped" if dropped else ""
    text = f"{what} none in a simulation (every sample's command lands{extra})."
    return {"count": 0, "judged": None, "rate": 0.0}, text


def headline(data: ReportData, summary: Summary) -> Headline:
    """The four answers and the verdict, as data and as the report's first lines: the limits of
    (2) and each peak's share of its limit; D against D* and the margin; the stalls closest to
    D* (when, how long, why); the plant samples that never got a command. Every number is one
    already in the report: the peaks (summary.json's and the trace's), certificate and timing."""
    answers = {
        "limits": _limits(data, summary),
        "command_age": _command_age(data),
        "stalls": _stalls(data),
        "samples_without_command": _samples(data, summary),
    }
    v = data["verdict"]
    verdict = v.get("outcome", "PASS" if v["ok"] else "FAIL")
    why = "" if v["ok"] else f": {'; '.join(v['reasons'])}"
    v_text = " ".join([f"Verdict: {verdict}{why}.", *(v.get("notes") or ())])
    lines = [{"key": k, "text": text} for k, (_, text) in answers.items()]
    return {
        "verdict": verdict,
        **{k: facts for k, (facts, _) in answers.items()},
        "lines": [*lines, {"key": "verdict", "text": v_text}],
    }


def _terms(s: Section, data: ReportData) -> None:
    drives = f" {DRIVES_NOTE}" if "drives" in data["sections"] else ""
    for text in (NORMALIZED + drives, WHAT_2, WHAT_4, WHAT_CERT):
        s.p(text)


def _na(value: Any) -> Any:
    return NOT_MEASURED if value is None else value


def _verdict(s: Section, data: ReportData) -> None:
    v = data["verdict"]
    s.title = f"Verdict: {data['headline']['verdict']}"
    s.table(
        ["item", "state"],
        [
            ["limits (2): |v| ≤ φ1, |ω| ≤ φ2, |τ1| ≤ ϖ1, |τ2| ≤ ϖ2", v["limits"]],
            ["certificate: D ≤ D*, so the paper's bound guarantees (2)", v["certificate"]],
            ["deadline misses (missed slots)", _na(v["deadline_misses"])],
            ["samples without a command", _na(v["samples_without_command"])],
            ["lost messages (State and the applied path)", _na(v["lost_messages"])],
        ],
    )
    if v.get("fail_reasons"):
        s.p("FAIL: the system under test (controller, its host, the transport):")
        s.items(list(v["fail_reasons"]))
    if v.get("inconclusive_reasons"):
        # Beside a FAIL these are found too, and do not change it (the system's failure stands).
        s.p(
            "Also found, the bench's or logs that cannot relate a figure (alone they would "
            "make the verdict INCONCLUSIVE):"
            if v.get("fail_reasons")
            else "INCONCLUSIVE: the bench, or logs that cannot relate a figure, not your system:"
        )
        s.items(list(v["inconclusive_reasons"]))
    if not v["reasons"]:
        s.p("No reason for a FAIL or an INCONCLUSIVE: PASS.")
    for line in (*v.get("advice", ()), *v.get("notes", ())):
        s.p(line)
    th = v["thresholds"]
    s.p(
        "FAIL: the law failed or ended early, the state became non-finite, a limit of (2) "
        "broke, the certificate is not held through the system's own timing, or "
        f"missed slots exceed {th['max_deadline_miss_ratio']:.2%}, samples without a command "
        f"{th['max_samples_without_command_ratio']:.2%}, lost messages "
        f"{th['max_lost_ratio']:.2%} (State and the applied path). INCONCLUSIVE: only the "
        "bench's stalls put a figure over, or the logs cannot relate one. Exit code: "
        + ", ".join(f"{k} {c}" for k, c in EXIT_CODE.items())
        + "."
    )


def _certificate(s: Section, data: ReportData) -> None:
    c = data["certificate"]
    s.p(f"Source: {c.get('source')}.")
    s.table(
        ["figure", "value"],
        [
            ["applied path", c.get("path")],
            ["D: longest command age [ms]", _ms(c.get("d_max_s"))],
            ["D*: largest age the bound allows [ms]", _ms(c.get("d_star_s"))],
            ["margin D* - D [ms]", _ms(c.get("margin_s"))],
            ["held", c.get("held")],
            ["v bound [m/s]", c.get("v_bound")],
            ["ω bound [rad/s]", c.get("omega_bound")],
            [_STALL_RULE[c.get("d_star_s") is None], _ms(c.get("stall_threshold_s"))],
            [
                "failed design conditions",
                in_symbols(", ".join(c.get("failed_conditions") or [])) or "none",
            ],
        ],
    )
    if data.get("margin"):  # hil margin's record, when it ran on the folder
        for line in summary_lines(MarginRecord.from_dict(data["margin"])):
            s.p(line)
    timing = (data.get("timing") or {}).get("summary") or {}
    rows = _pct_rows(timing, _per_path("command_age_", c.get("path"), "shadow"))
    if rows:
        s.p(
            "Command age at every plant step (age of information, per path); the applied "
            f"path's max is D. Start-up hold: {fmt(timing.get('startup_hold_s'))} s."
        )
        s.table(["path", *PCT.values()], rows)
    stalls = c.get("stalls") or []
    if stalls:
        s.p(
            "Stalls: the commands that stayed in force longest (above the stall threshold), "
            "each with its cause and what the logs show around it (how late each service "
            "woke, how long it was silent, how busy the host was)."
        )
        header = ["t [s]", "age [ms]", "cause", "evidence"]
        rows = [
            [st.get("t_s"), _ms(st.get("age_s")), st.get("cause"), st.get("evidence")]
            for st in stalls
        ]
        s.table(header, rows)  # one table, folded when long (the headline names the first)
    s.figure("command_age")


def _trajectory(s: Section, data: ReportData) -> None:
    s.p(
        "Robot (wide light-blue solid line), reference (black, dashed) and, when computed, the "
        "ideal trajectory (dark-green dots): the same scenario simulated at Ts/10 with no "
        f"delay ({data['metrics']['deviation_from_ideal_note']})."
    )
    s.figure("trajectory")


#: Each signal of (2) as a table names it, with its unit.
SIGNALS = {k: f"{sym} [{UNITS[k]}]" for k, sym in SYMBOL.items()}
#: Each signal's plot title (report and compare).
TITLES = {"v": "Linear velocity v", "omega": "Angular velocity ω"}
TITLES |= {k: f"{SYMBOL[k]} of model (1) (normalized)" for k in ("tau1", "tau2")}


def _constraints(s: Section, data: ReportData, text: str, names: tuple[str, ...]) -> None:
    """``text``, then the signals' figures against (2) and their bounds, as a table and plots."""
    s.p(text)
    cons = data["metrics"]["constraints"]
    keys = ("peak", "limit", "ratio", "held", "bound", "within_bound")
    s.table(CONSTRAINT_HEADER, [[SIGNALS[n], *(cons[n][k] for k in keys)] for n in names])
    for n in names:
        s.figure(n)


CONSTRAINT_HEADER = ["signal [unit]", "max |·|", "limit", "max/limit (1: at the limit)", "held"]
CONSTRAINT_HEADER += ["sampled-data bound", "within bound"]
BOUND_GLOSS = (
    "max |·| is the largest magnitude over every plant step, limit the bound of (2), both in "
    "the signal's unit; the sampled-data bound is the largest |v|, |ω| the certificate "
    "allows at this folder's Ts and delay (it may exceed the limit when the certificate does "
    "not hold; none for τ1, τ2, which the law clips to ϖ1, ϖ2 itself)."
)


def _velocities(s: Section, data: ReportData) -> None:
    _constraints(s, data, BOUND_GLOSS, ("v", "omega"))


def _torques(s: Section, data: ReportData) -> None:
    text = "τ1 in m/s², τ2 in rad/s²: the normalized inputs of model (1) (see above)."
    _constraints(s, data, text, ("tau1", "tau2"))


def _drives(s: Section, data: ReportData) -> None:
    d = data["drives"]
    if d.get("geometry"):
        robot = ", ".join(f"{k} {fmt(v)}" for k, v in d["geometry"].items())
        s.p(
            "Motor torques q_R, q_L = (r/G) (m τ1/2 ± J τ2/(2b)) of the applied τ1, τ2 "
            f"(protocol/can/wheel_mapping.py) with the scenario's [robot]: {robot}."
        )
        s.table(
            ["figure", "value [N·m]"],
            [
                ["max |q_R| (right drive)", d.get("max_abs_q_right_nm")],
                ["max |q_L| (left drive)", d.get("max_abs_q_left_nm")],
                ["largest |q| within (2)", d.get("motor_torque_limit_nm")],
            ],
        )
    elif d.get("note"):
        s.p(d["note"])
    can = d.get("can")
    if isinstance(can, dict):
        rows = []
        for side in ("controller", "plant"):
            st = can.get(side)
            for k, v in st.items() if isinstance(st, dict) else ():
                # the drives' and the bus's counters are counts; their other states are words
                count = isinstance(v, int) and not isinstance(v, bool)
                rows.append([side, k.replace("_", " "), v, "count" if count else ""])
        s.table(["side", "drive/bus state", "value", "unit"], rows)
    else:
        s.p("No CAN bus in this folder (a simulation, or a run without CAN).")
    _rejections(s, d)
    s.figure("motor_torques")


def _rejections(s: Section, d: Any) -> None:
    """The inputs each side rejected (counted, by reason)."""
    counts = d.get("rejection_counts")
    if isinstance(counts, dict):
        rej = d.get("rejections") or {}
        rows = [[k, n, rej.get(k)] for k, n in counts.items()]
        s.table(["where", "rejections", "by reason"], rows)


def _tracking_error(s: Section, data: ReportData) -> None:
    m = data["metrics"]
    s.p(
        "(4): the position and heading error of the robot against the reference, seen from "
        "the robot; positions in m, headings in rad."
    )
    rows = [[TRACKING.get(k, k.replace("_", " ")), v, unit_of(k)] for k, v in m["tracking"].items()]
    dev = m.get("deviation_from_ideal")
    if dev:
        rows += [[f"deviation from ideal, {k}", v, "m"] for k, v in dev.items()]
    rows.append(["deviation from ideal", m.get("deviation_from_ideal_note", ""), ""])
    s.table(["figure", "value", "unit"], rows)
    s.figure("tracking_error")


#: The tracking figures of hil.analysis.trace_metrics in words.
TRACKING = {
    "final_position_error": "position error at the end",
    "final_heading_error": "heading error θe at the end",
    "max_position_error": "largest position error",
    "rms_position_error_last10": "RMS position error, last 10 % of the run",
}


def _bands(s: Section, data: ReportData) -> None:
    m = data["metrics"]
    keys = ("reaching_time", "band_p99", "band_max", "band_spread")
    names = {"v_tilde": "v~ [m/s]", "w_tilde": "w~ [rad/s]"}
    rows = []
    for n, b in m["bands"].items():
        values = ["not available", None, None, None] if b is None else [b[k] for k in keys]
        rows.append([names.get(n, n), *values])
    s.p(f"{SLIDING} v~ in m/s, w~ in rad/s; from {m.get('bands_source')}.")
    s.table(["variable", "reaching time [s]", "band p99 |·|", "band max |·|", "max − min"], rows)
    sw, sat = m["switching_rate"], m["saturation_share"]
    s.table(
        ["torque", "switching rate [1/s]", "share of samples at the limit (|τ| ≥ 0.999 ϖ)"],
        [[SIGNALS[k], sw[k], sat[k]] for k in ("tau1", "tau2")],
    )
    s.figure("bands")


def _latency(s: Section, data: ReportData) -> None:
    timing = data["timing"]["summary"] or {}
    names = _per_path("sample_to_apply_", data["timing"].get("applied_path"), "shadow: receive")
    names += [("hop_cmd_zenoh", "command hop zenoh"), ("hop_cmd_can", "command hop can")]
    s.p(
        "Sample-to-apply: from the moment the plant sampled the state to the moment the "
        "command computed from it took effect at the plant (a shadow path: arrived). Command "
        "hop: from the controller's send to the plant's receipt. Percentiles over every command "
        "(p99: 99 % took at most this long); definitions in docs/realtime.md."
    )
    s.table(["figure", *PCT.values()], _pct_rows(timing, names))
    s.figure("latency")


def _lateness(s: Section, data: ReportData) -> None:
    timing = data["timing"]["summary"] or {}
    names = [
        ("wakeup_lateness", "controller wake-up lateness"),
        ("period_jitter", "controller period jitter"),
        ("plant_wakeup_lateness", "plant wake-up lateness"),
    ]
    s.p(
        "Wake-up lateness: how long after its due time a service's periodic tick woke (the "
        "controller's ticks, the plant's samples). Period jitter: how far the gap between two "
        "ticks was from their slots' gap. A tick a whole period late or a slot never run is a "
        "missed slot (a deadline miss)."
    )
    measured_here = ("wakeup_lateness", "period_jitter") if timing else ()
    s.table(["figure", *PCT.values()], _pct_rows(timing, names, measured_here))
    # Missed slots: a stall of N periods misses N slots (late wake-ups + slots never run).
    keys = ("ticks", "slots", "deadline_misses", "late_ticks", "skipped_slots")
    keys += ("deadline_miss_rate", "plant_slots", "plant_deadline_misses", "plant_skipped_slots")
    counts = [[k.replace("_", " "), _na(timing.get(k)), unit_of(k)] for k in keys] if timing else []
    s.table(["figure", "value", "unit"], counts)
    sched = data["timing"].get("scheduling") or {}
    for role, got in sched.items():
        if isinstance(got, dict):
            s.p(
                f"Scheduling of the {role}: asked {got.get('requested')}, got {got.get('policy')}"
                f" (priority {got.get('priority')}), CPU idle {got.get('idle', 'os')}; the "
                "policy changes wake-up lateness, deadline misses and the command age, and an "
                "idle policy other than poll adds the CPUs' wake-up from idle to every hop."
            )
    s.figure("lateness")


def _messages(s: Section, data: ReportData) -> None:
    faults = data["timing"].get("faults") or {}
    on = {k: v for k, v in (faults.get("config") or {}).items() if v and k != "seed"}
    if on:
        injected = {
            f"{who}.{k}": v
            for who, counts in (faults.get("injected") or {}).items()
            for k, v in (counts or {}).items()
            if v
        }
        s.p(
            "Faults injected on purpose ([faults], seed "
            f"{(faults.get('config') or {}).get('seed', 0)}): {fmt(on)}; injected: "
            f"{fmt(injected)}. The services logged each one: the lost, duplicated and reordered "
            "counts below include them, and the certificate's stalls name them in their evidence."
        )
    impair = data["timing"].get("impair")
    msgs = data["timing"].get("messages") or {}
    if isinstance(impair, dict):
        # Said as counted, side by side: a dropped packet is not always one lost message (a CAN
        # command is two frames), and whether the two agree is for the reader to see.
        streams = [st for st in msgs.values() if isinstance(st, dict)]
        lost = sum(int(st.get("lost") or 0) for st in streams)
        injected = sum(int(st.get("injected_drops") or 0) for st in streams)
        of_faults = f" ({injected} of them dropped by [faults] on purpose)" if injected else ""
        s.p(
            f"The link was impaired on purpose ([impair], docs/impair.md): {impair.get('packets')}"
            f" in a {impair.get('namespace')}; nftables matched {impair.get('matched_packets')} "
            f"packets and dropped {impair.get('dropped_packets')}. The streams below lost {lost} "
            f"messages in all{of_faults}."
        )
    keys = ("sent", "received", "lost", "duplicated", "reordered")
    rows = []
    for name, st in msgs.items():
        if isinstance(st, dict):
            # What was not measured (None) says nothing here: summary.json keeps it.
            more = {k: v for k, v in st.items() if k not in keys and v is not None}
            rows.append([name, *(st.get(k) for k in keys), more])
    s.table(["stream", *keys, "more"], rows)
    drives = data.get("drives") or {}
    if "drives" not in data["sections"] and any((drives.get("rejection_counts") or {}).values()):
        s.p("Inputs rejected (counted, by reason; this run had no CAN drives):")
        _rejections(s, drives)


def _tick_phase_line(p: TickPhase) -> str:
    """Where the periodic ticks fell after the sample (controller_service.tick_phase)."""
    line = f"The periodic controller ticked {p['phase_us']:.0f} µs after each sample ({p['rule']}"
    if "arrival_p99_us" not in p:
        return line + ")."
    if not p.get("clocks_related", True):
        return line + ": the clocks of the plant and the controller differ, kept at half)."
    shut = "" if p["window_open"] else "; no phase serves every sample: the loop needs more"
    return (
        f"{line}: learnt from States arriving by {p['arrival_p99_us']:.0f} µs at p99 and "
        f"{p['path_p99_us']:.0f} µs of compute and hop after the tick{shut})."
    )


def _timing_summary(s: Section, data: ReportData) -> None:
    timing = data["timing"]["summary"] or {}
    s.p(f"From {data['timing'].get('source')}; definitions in docs/realtime.md.")
    phase = timing.get("tick_phase")
    if isinstance(phase, dict):
        s.p(_tick_phase_line(phase))
    names = [(k, k) for k, f in timing.items() if isinstance(f, dict) and "p50_us" in f]
    s.table(["figure", *PCT.values()], _pct_rows(timing, names))
    s.table(
        ["figure", "value", "unit"],
        [[k, f, unit_of(k)] for k, f in timing.items() if not isinstance(f, dict | str)],
    )


# Each figure: the streams it rides on (router_hops keys, None: no network) and the processes
# its message passes through (docs/realtime.md defines each figure).
HOP_FIGURES: tuple[tuple[str, str | None, tuple[str, ...]], ...] = (
    ("hop_state", "state", ("plant", "controller")),
    ("hop_cmd_zenoh", "command", ("controller", "plant")),
    ("loop_transport_compute", "state+command", ("plant", "controller", "plant")),
    ("command_age_zenoh", "state+command", ("plant", "controller", "plant")),
    ("wakeup_lateness", None, ("controller",)),
    ("compute", None, ("controller",)),
    ("plant_sample_to_send", None, ("plant",)),
)


def _routers(topo: Topology, stream: str | None) -> list[str]:
    hops = topo.get("router_hops") or {}
    out: list[str] = []
    for part in stream.split("+") if stream else ():
        out += [r for r in hops.get(part) or [] if r not in out]
    return out


def _hop_rows(topo: Topology, timing: Timing, unc_us: float | None) -> list[list]:
    """One row per timing figure: hosts, routers crossed, clocks and the correction's bound."""
    procs = topo["processes"]
    cross = set((topo.get("clock") or {}).get("cross_host_figures") or [])
    rows = []
    for name, stream, path in HOP_FIGURES:
        f = timing.get(name)
        if not isinstance(f, dict):
            continue
        two = name in cross
        hosts = " -> ".join(f"{p}@{procs.get(p)}" for p in path)
        routers = " -> ".join(_routers(topo, stream)) or "none (one host)"
        clocks = "two, corrected" if two else f"{procs.get(path[0])}'s alone"
        bound = unc_us if two else 0.0
        rows.append([name, hosts, routers, clocks, f.get("p50_us"), f.get("p99_us"), bound])
    return rows


def _clock_text(f: Topology) -> str:
    clock = f.get("clock") or {}
    if "device" in f["processes"]:  # an outside device: no clock of its is ever read
        return (
            "Every figure of this run is the plant's host's clock alone: the device's clock is "
            "never read (its figures are measured at the bench's edge)."
        )
    if not clock.get("related"):
        warning = clock.get("warning") or "the cross-host figures are not valid"
        return f"The controller's clock was never related to the plant's: {warning}."
    med = clock["offset_ns_median"] / 1e9
    lo, hi = (x / 1e9 for x in clock["offset_ns_range"])
    text = (
        f"Estimated offset (plant clock minus controller clock, {clock['estimates']} exchanges, "
        f"RFC 5905 minimum-delay filter): median {med:.6f} s, range {lo:.6f} to {hi:.6f} s; "
        f"uncertainty (half the round trip of the exchange used) median "
        f"{clock['uncertainty_ns_median'] / 1e3:.1f} us, at most "
        f"{clock['uncertainty_ns_max'] / 1e3:.1f} us."
    )
    diff = f.get("injected_difference_s")
    if diff is not None:
        err = (clock["offset_ns_median"] - diff * 1e9) / 1e3
        text += f" Injected difference {diff:+.6f} s: the estimate is off by {err:+.1f} us."
    return text


def _topology(s: Section, data: ReportData) -> None:
    """Where a run across lab hosts ran: hosts, clocks and the routers each hop figure crossed, so
    that a reader can tell a network delay (through routers, corrected by the clock offset
    estimate within its uncertainty) from a scheduling delay (one host's clock, no correction)."""
    f = data["topology"]
    procs, hosts = f["processes"], f.get("hosts") or {}
    s.p(
        f"Lab {f.get('lab')}: each session is a client of its own host's router "
        f"({f.get('session_endpoint')}), so messages between hosts cross the routers as "
        "between computers."
    )
    runs = {h: [p for p, on in procs.items() if on == h] for h in hosts}
    keys = ("address", "offset_s", "router", "impair")
    s.table(
        ["host", "runs", "address", "injected CLOCK_MONOTONIC offset (s)", "router", "impair"],
        [[h, ", ".join(runs[h]), *(v.get(k) for k in keys)] for h, v in hosts.items()],
    )
    s.p(_clock_text(f))
    s.figure("clock_offset")
    unc = (f.get("clock") or {}).get("uncertainty_ns_max")
    unc_us = None if unc is None else float(np.round(unc / 1e3, 3))
    timing = (data.get("timing") or {}).get("summary") or {}
    s.table(
        ["figure", "from -> to", "routers crossed", "clocks", "p50 (us)", "p99 (us)", "+- (us)"],
        _hop_rows(f, timing, unc_us),
    )
    s.p(
        "A network delay shows in the figures that cross routers (each corrected by the "
        "offset estimate, within its uncertainty); a scheduling delay shows in wakeup_lateness "
        "and compute, each one host's clock with no router and no correction. The command age "
        "D is measured on the plant's clock alone and needs no correction."
    )


#: Each section's title and the function that writes its blocks.
SECTIONS: dict[str, tuple[str, Callable[[Section, ReportData], None]]] = {
    "headline": ("The answers first", _headline),
    "terms": ("What the words mean", _terms),
    "verdict": ("Verdict", _verdict),
    "certificate": ("Command age and the certificate", _certificate),
    DEVICE_SECTION: (DEVICE_TITLE, device_section),  # hil.analysis.report.device
    "trajectory": ("Trajectory in the plane", _trajectory),
    "velocities": ("Velocities v and ω against (2)", _velocities),
    "torques": ("Inputs τ1 and τ2 of model (1) against (2)", _torques),
    "drives": ("CAN and drives: motor torques, drive states, rejections", _drives),
    "tracking_error": (
        "Tracking error (4) and deviation from the ideal trajectory",
        _tracking_error,
    ),
    "bands": ("Quasi-sliding bands, switching and saturation", _bands),
    "latency": ("Sample-to-apply latency per path (histogram and CDF)", _latency),
    "lateness": ("Wake-up lateness over time", _lateness),
    "messages": ("Messages per stream", _messages),
    "topology": ("Where it ran: hosts, clocks and routers", _topology),
    "timing_summary": (
        "Every timing figure (summary.json's timing, from hil.measure)",
        _timing_summary,
    ),
}


# What a compared figure is called on the page and in which unit, from its key (the keys,
# ``timing.hop_cmd_can.p99_us``, stay what compare.json and scripts use).
#: Figures a reader looks for by name, in words (the paper's symbols glossed).
NAMES = {
    "ts": "Ts, the control period",
    "delay": "delay added to every command",
    "jitter": "jitter of the controller's wake-ups",
    "certificate.d_max_s": "D, the longest a command stayed in force",
    "certificate.d_star_s": "D*, the longest the paper's bound allows",
    "certificate.margin_s": "margin D* − D",
    "certificate.held": "certificate held (D ≤ D* and the design conditions)",
    "certificate.stalls": "stalls (commands in force above the stall threshold)",
    "certificate.v_bound": "largest |v| the bound allows",
    "certificate.omega_bound": "largest |ω| the bound allows",
    "timing.startup_hold_s": "start-up hold: first command landed after the first sample",
    "timing.late_commands": "late commands (applied more than Ts after their sample)",
    "timing.late_commands_rate": "late commands, share of the samples",
    "timing.samples_without_command_rate": "samples without a command, share of those judged",
    "timing.deadline_miss_rate": "missed slots, share of the controller's slots",
    "verdict.lost_messages_rate": "lost messages (State and the applied path), share of those sent",
    "band_p99.v_tilde": "band of v~ = v − α_v (p99 of |v~| once reached)",
    "band_p99.w_tilde": "band of w~ = ω − α_ω (p99 of |w~| once reached)",
}
NAMES |= {
    f"max_over_limit.{k}": f"max |{sym}| / {LIMITS[k]} (the limit of (2) on {sym})"
    for k, sym in SYMBOL.items()
}
NAMES |= {f"timing.compute.{q}_us": f"controller compute time, {q}" for q in ("p50", "p99", "max")}
#: Where a figure comes from, as its key's first part names it (else that part in words).
GROUPS = {
    "summary": "",
    "tracking": "",
    "timing": "",
    "violations": "plant steps beyond (2)",
    "saturation_share": "share of samples at the limit",
}


def unit_of(key: str) -> str:
    """The unit of a figure, from its name ("count" for what is counted): the compare page's
    and the report's tables."""
    group, _, last = key.rpartition(".")
    if last.endswith("_us"):
        return "µs"
    if last.endswith("_hz"):
        return "Hz"
    if last.endswith("_s") or last in ("ts", "delay", "jitter", "duration"):
        return "s"
    if group == "max_over_limit":
        return "x limit"
    if last == "held":
        return "yes = 1"
    if "heading" in last:
        return "rad"
    if "position" in last or "deviation" in last or group == "tracking":
        return "m"
    if group == "switching_rate":
        return "1/s"
    if last.endswith(("_rate", "_share")) or group == "saturation_share":
        return "fraction"
    if last.startswith("max_abs_"):
        return UNITS.get(last.removeprefix("max_abs_"), "")
    if last == "v_bound" or last == "v_tilde":
        return "m/s"
    if last in ("omega_bound", "w_tilde"):
        return "rad/s"
    return "" if last == "schema_version" else "count"


def label_of(key: str) -> str:
    """The figure in words: its name where it has one, else its key's words without the unit
    suffix (the unit column says it) and the group it belongs to."""
    if key in NAMES:
        return NAMES[key]
    parts = key.split(".")
    group = parts[0] if len(parts) > 1 else ""
    words = []
    for part in parts[1:] if group else parts:
        if part.startswith("max_abs_"):  # a peak, in the paper's symbols: max |ω|
            part = f"max |{part.removeprefix('max_abs_')}|"
        for suffix in ("_us", "_hz", "_s"):
            part = part.removesuffix(suffix)
        words.append(part.replace("_", " ").replace("p999", "p99.9"))
    name = in_symbols(", ".join(words))
    where = GROUPS.get(group, group.replace("_", " "))
    return f"{where}: {name}" if where else name


def _cell(value: Any) -> str:
    return fmt(value).replace("|", "\\|").replace("\n", " ")


def _md_table(header: Sequence[str], rows: Sequence[Sequence[Any]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(_cell(c) for c in row) + " |" for row in rows]
    return "\n".join(lines)


def render_markdown(data: ReportData, files: Sequence[dict[str, str]]) -> str:
    """report.md: the sections, figures as PNG files beside it; the headline first."""
    by_name = {f["name"]: f for f in files}
    s = data["scenario"]
    out = [f"# What timing did to the law: {data['folder']}", ""]
    listed = list(sections(data))
    for section in listed:
        if section.id != "headline":
            out += [f"## {section.title}", ""]
        for block in section.blocks:
            kind = block[0]
            if kind == "p":
                out += [block[1], ""]
            elif kind == "list":
                out += [f"- {text}" for text in block[1]] + [""]
            elif kind == "table":
                out += [_md_table(block[1], block[2]), ""]
            elif kind == "figure" and (f := by_name.get(block[1])):
                caption = f". {f['caption']}" if f.get("caption") else ""
                data_line = f"Data: [{f['data']}]({f['data']}){caption}"
                out += [f"![{f['title']}]({f['png']})", "", data_line, ""]
        if section.id == "headline":
            out += [
                f"{data['kind']} · law `{s['law']}` · Ts {fmt(s['ts'])} s · delay "
                f"{fmt(s['delay'])} s · jitter {fmt(s['jitter'])} s ({s['jitter_kind']})",
                "",
                "Contents: " + " · ".join(x.title for x in listed[1:]),
                "",
            ]
    return "\n".join(out) + "\n"


CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Helvetica,Arial,sans-serif;margin:2em auto;
max-width:1200px;padding:0 1em;color:#222;line-height:1.4}
.figs{display:grid;grid-template-columns:repeat(auto-fit,minmax(520px,1fr));gap:0 1.2em}
nav.toc{columns:2;font-size:.95em;margin:.5em 0 1em}nav.toc a{text-decoration:none}
h1{font-size:1.6em}h2{border-bottom:1px solid #ccc;padding-bottom:.2em;margin-top:1.6em}
table{border-collapse:collapse;margin:.6em 0}td,th{border:1px solid #ccc;padding:.25em .6em;
text-align:left;font-variant-numeric:tabular-nums}th{background:#f4f4f4}
.ok{background:#e6f4e6;border:2px solid #3a3}.bad{background:#fbe9e9;border:2px solid #c33}
.unsure{background:#fff6dd;border:2px solid #c90}
.verdict{padding:.8em 1.2em;margin:1em 0}figure{margin:1em 0}img{max-width:100%}
figcaption{font-size:.9em;color:#555}code{background:#f4f4f4;padding:0 .2em}
"""


def esc(value: Any) -> str:
    return html.escape(str(value), quote=True)


def table(header: Sequence[str], rows: Iterable[Sequence[Any]]) -> str:
    head = "".join(f"<th>{esc(h)}</th>" for h in header)
    body = "".join(
        "<tr>" + "".join(f"<td>{esc(fmt(c))}</td>" for c in row) + "</tr>" for row in rows
    )
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def figure(f: Figure, prefix: str = "report_") -> str:
    b64 = base64.b64encode(f.png).decode("ascii")
    caption = f" {esc(f.caption)}" if f.caption else ""
    return (
        f'<figure><img alt="{esc(f.title)}" src="data:image/png;base64,{b64}">'
        f"<figcaption>{esc(f.title)} (data: <code>{esc(prefix + f.name)}.csv</code>)"
        f"{caption}</figcaption></figure>"
    )


#: Tables longer than this are folded (a <details> the reader opens): the page answers first.
FOLD_ROWS = 12


def _folded(header: Sequence[str], rows: Sequence[Sequence[Any]], fold: str | None = None) -> str:
    if fold is None and len(rows) <= FOLD_ROWS:
        return table(header, rows)
    summary = fold or f"{len(rows)} rows: {', '.join(header)}"
    return f"<details><summary>{esc(summary)}</summary>{table(header, rows)}</details>"


def _grid(figures: list[str]) -> list[str]:
    return ['<div class="figs">', *figures, "</div>"] if len(figures) > 1 else figures


def render_html(data: ReportData, figs: Sequence[Figure]) -> str:
    by_name = {f.name: f for f in figs}
    s = data["scenario"]
    parts = [
        "<!DOCTYPE html>",
        '<html lang="en"><head><meta charset="utf-8">',
        f"<title>{esc('Report: ' + data['folder'])}</title>",
        f"<style>{CSS}</style></head><body>",
        f"<h1>What timing did to the law: {esc(data['folder'])}</h1>",
    ]
    listed = list(sections(data))
    # the table of contents: a link to each section after the headline
    links = "".join(f'<li><a href="#{esc(x.id)}">{esc(x.title)}</a></li>' for x in listed[1:])
    for section in listed:
        parts.append(f'<section id="{esc(section.id)}">')
        if section.id == "headline":
            outcome = data["headline"]["verdict"]
            cls = {"PASS": "ok", "INCONCLUSIVE": "unsure"}.get(outcome, "bad")
            parts.append(f'<div class="verdict {cls}"><strong>{outcome}</strong>')
        else:
            parts.append(f"<h2>{esc(section.title)}</h2>")
        pending: list[str] = []  # figures in a row share a two-column grid
        for block in section.blocks:
            kind = block[0]
            if kind == "figure":
                if block[1] in by_name:
                    pending.append(figure(by_name[block[1]]))
                continue
            parts.extend(_grid(pending))
            pending = []
            if kind == "p":
                parts.append(f"<p>{esc(block[1])}</p>")
            elif kind == "list":
                parts.append("<ul>" + "".join(f"<li>{esc(t)}</li>" for t in block[1]) + "</ul>")
            elif kind == "table":
                parts.append(_folded(block[1], block[2], block[3]))
        parts.extend(_grid(pending))
        if section.id == "headline":
            parts += [
                "</div>",
                f"<p>{esc(data['kind'])} · law <code>{esc(s['law'])}</code> · "
                f"Ts {esc(fmt(s['ts']))} s · delay {esc(fmt(s['delay']))} s"
                f" · jitter {esc(fmt(s['jitter']))} s ({esc(s['jitter_kind'])})</p>",
                f'<nav class="toc"><strong>Contents</strong><ol>{links}</ol></nav>',
            ]
        parts.append("</section>")
    parts.append("</body></html>")
    return "\n".join(parts)
