"""What the report says, section by section, as blocks that report.md and report.html both
render (paragraphs, lists, tables, figures): one text, two formats."""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

from hil.margin.record import report_lines as margin_lines

SECTION_TITLES: dict[str, str] = {
    "headline": "The answers first",
    "terms": "What the words mean",
    "verdict": "Verdict",
    "certificate": "Command age and the certificate",
    "trajectory": "Trajectory in the plane",
    "velocities": "Velocities v and ω against (2)",
    "torques": "Inputs τ1 and τ2 of model (1) against (2)",
    "drives": "CAN and drives: motor torques, drive states, rejections",
    "tracking_error": "Tracking error (4) and deviation from the ideal trajectory",
    "bands": "Quasi-sliding bands, switching and saturation",
    "latency": "Sample-to-apply latency per path (histogram and CDF)",
    "lateness": "Wake-up lateness over time",
    "messages": "Messages per stream",
    "timing_summary": "Every timing figure (summary.json `timing`, from hil.measure)",
}

NORMALIZED = (
    "Model (1) is normalized: v' = τ1 + d1 and ω' = τ2 + d2, so τ1 is an acceleration (m/s²) "
    "and τ2 an angular acceleration (rad/s²), per unit mass and yaw inertia, although the "
    "paper labels τ1, τ2 in N·m. The torques that really go to the drives, in N·m, are in the "
    "section on CAN and drives."
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

    def table(self, header: list[str], rows: list[list[Any]]) -> None:
        if rows:
            self.blocks.append(("table", header, rows))

    def figure(self, name: str) -> None:
        self.blocks.append(("figure", name))


def fmt(value: Any) -> str:
    if value is None:
        return "–"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        if not math.isfinite(value):
            return str(value)
        return f"{value:.6g}"
    if isinstance(value, dict):
        return ", ".join(f"{k} {fmt(v)}" for k, v in value.items()) or "none"
    return str(value)


def _ms(x: Any) -> Any:
    return x * 1e3 if isinstance(x, int | float) and not isinstance(x, bool) else None


PCT_KEYS = ("p50_us", "p90_us", "p99_us", "p999_us", "max_us", "count")


NOT_MEASURED = "n/a"


def _pct_rows(
    timing: dict[str, Any], names: list[tuple[str, str]], always: tuple[str, ...] = ()
) -> list[list[Any]]:
    """Percentile rows; a figure in ``always`` that the run did not measure (its trigger mode
    has none) shows as n/a, never as 0."""
    rows = []
    for key, label in names:
        f = timing.get(key)
        if isinstance(f, dict):
            rows.append([label, *(f.get(q) for q in PCT_KEYS)])
        elif key in always:
            rows.append([label, *(NOT_MEASURED for _ in PCT_KEYS)])
    return rows


def sections(data: dict[str, Any]) -> Iterator[Section]:
    for sid in data["sections"]:
        s = Section(sid, SECTION_TITLES[sid])
        BUILDERS[sid](s, data)
        yield s


def _headline(s: Section, data: dict[str, Any]) -> None:
    s.items([line["text"] for line in data["headline"]["lines"]])


def _terms(s: Section, data: dict[str, Any]) -> None:
    for text in (NORMALIZED, WHAT_2, WHAT_4, WHAT_CERT):
        s.p(text)


def _na(value: Any) -> Any:
    return NOT_MEASURED if value is None else value


def _verdict(s: Section, data: dict[str, Any]) -> None:
    v = data["verdict"]
    s.title = f"Verdict: {v.get('outcome', 'PASS' if v['ok'] else 'FAIL')}"
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
        s.p("INCONCLUSIVE: the bench, or logs that cannot relate a figure, not your system:")
        s.items(list(v["inconclusive_reasons"]))
    if not v["reasons"]:
        s.p("No reason for a negative verdict.")
    for line in (*v.get("advice", ()), *v.get("notes", ())):
        s.p(line)
    th = v["thresholds"]
    s.p(
        "Negative when a limit of (2) is broken, the certificate is not held, or deadline "
        f"misses exceed {th['max_deadline_miss_ratio']:.2%} of ticks, samples without a "
        f"command {th['max_samples_without_command_ratio']:.2%} of samples, lost messages "
        f"{th['max_lost_ratio']:.2%} of those sent (State and the applied path; a shadow path "
        "never counts)."
    )


def _certificate(s: Section, data: dict[str, Any]) -> None:
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
            ["stall threshold max(3 Ts, D*/2) [ms]", _ms(c.get("stall_threshold_s"))],
            ["failed design conditions", ", ".join(c.get("failed_conditions") or []) or "none"],
        ],
    )
    for line in margin_lines(data.get("folder")):  # hil margin's margin.json, when it ran
        s.p(line)
    timing = (data.get("timing") or {}).get("summary") or {}
    if timing:
        path = c.get("path")
        names = [
            (f"command_age_{p}", f"{p} ({'applied' if p == path else 'shadow'})")
            for p in ("zenoh", "can")
        ]
        rows = _pct_rows(timing, names)
        if rows:
            s.p(
                "Command age at every plant step (age of information, per path); the applied "
                f"path's max is D. Start-up hold: {fmt(timing.get('startup_hold_s'))} s."
            )
            s.table(["path", *PCT_KEYS], rows)
    stalls = c.get("stalls") or []
    if stalls:
        s.table(
            ["t [s]", "age [ms]", "cause", "evidence"],
            [
                [st.get("t_s"), _ms(st.get("age_s")), st.get("cause"), st.get("evidence")]
                for st in stalls
            ],
        )
    s.figure("command_age")


def _trajectory(s: Section, data: dict[str, Any]) -> None:
    s.p(
        "Robot (wide light-blue solid line), reference (black, dashed) and, when computed, the "
        "ideal trajectory (dark-green dots): the same scenario simulated at Ts/10 with no "
        f"delay ({data['metrics']['deviation_from_ideal_note']})."
    )
    s.figure("trajectory")


def _constraint_rows(data: dict[str, Any], names: tuple[str, ...]) -> list[list[Any]]:
    rows = []
    for n in names:
        c = data["metrics"]["constraints"][n]
        rows.append(
            [n, c["peak"], c["limit"], c["ratio"], c["held"], c["bound"], c["within_bound"]]
        )
    return rows


CONSTRAINT_HEADER = ["signal", "max |·|", "limit", "max/limit", "held", "sampled-data bound"]
CONSTRAINT_HEADER.append("within bound")


def _velocities(s: Section, data: dict[str, Any]) -> None:
    s.table(CONSTRAINT_HEADER, _constraint_rows(data, ("v", "omega")))
    s.figure("v")
    s.figure("omega")


def _torques(s: Section, data: dict[str, Any]) -> None:
    s.p("τ1 in m/s², τ2 in rad/s²: the normalized inputs of model (1) (see above).")
    s.table(CONSTRAINT_HEADER, _constraint_rows(data, ("tau1", "tau2")))
    s.figure("tau1")
    s.figure("tau2")


def _drives(s: Section, data: dict[str, Any]) -> None:
    d = data["drives"]
    if d.get("geometry"):
        g = d["geometry"]
        s.p(
            "Motor torques q_R, q_L = (r/G) (m τ1/2 ± J τ2/(2b)) of the applied τ1, τ2 "
            "(protocol/can/wheel_mapping.py) with the scenario's [robot]: "
            + ", ".join(f"{k} {fmt(v)}" for k, v in g.items())
            + "."
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
            if isinstance(st, dict):
                rows += [[side, k, st[k]] for k in st]
        s.table(["side", "drive/bus state", "value"], rows)
    else:
        s.p("No CAN bus in this folder (a simulation, or a run without CAN).")
    counts = d.get("rejection_counts")
    if isinstance(counts, dict):
        rej = d.get("rejections") or {}
        s.table(
            ["where", "rejections", "by reason"],
            [[k, n, rej.get(k)] for k, n in counts.items()],
        )
    s.figure("motor_torques")


def _tracking_error(s: Section, data: dict[str, Any]) -> None:
    m = data["metrics"]
    s.p(
        "(4): the position and heading error of the robot against the reference, seen from "
        "the robot; positions in m, headings in rad."
    )
    rows = [[k, v, _unit_of(k)] for k, v in m["tracking"].items()]
    dev = m.get("deviation_from_ideal")
    if dev:
        rows += [[f"deviation from ideal, {k}", v, "m"] for k, v in dev.items()]
    rows.append(["deviation from ideal", m.get("deviation_from_ideal_note", ""), ""])
    s.table(["figure", "value", "unit"], rows)
    s.figure("tracking_error")


def _unit_of(key: str) -> str:
    """The unit of a figure from its name (every table says its units)."""
    if "heading" in key:
        return "rad"
    if "position" in key or "deviation" in key:
        return "m"
    if key.endswith("_s") or key in ("window_s",):
        return "s"
    if key.endswith(("_rate", "_share")):
        return "fraction"
    return "count"


def _bands(s: Section, data: dict[str, Any]) -> None:
    m = data["metrics"]
    rows = []
    for name, b in m["bands"].items():
        if b is None:
            rows.append([name, "not available", None, None, None])
        else:
            rows.append([name, b["reaching_time"], b["band_p99"], b["band_max"], b["band_spread"]])
    s.p(f"v~ and w~ from: {m.get('bands_source')}.")
    s.table(["variable", "reaching time [s]", "band p99 |·|", "band max |·|", "max - min"], rows)
    sw, sat = m["switching_rate"], m["saturation_share"]
    s.table(
        ["torque", "switching rate [1/s]", "saturation share (|τ| ≥ 0.999 ϖ)"],
        [[k, sw[k], sat[k]] for k in ("tau1", "tau2")],
    )
    s.figure("bands")


def _latency(s: Section, data: dict[str, Any]) -> None:
    timing = data["timing"]["summary"] or {}
    path = data["timing"].get("applied_path")
    names = [
        (f"sample_to_apply_{p}", f"{p} ({'applied' if p == path else 'shadow: receive'})")
        for p in ("zenoh", "can")
    ] + [("hop_cmd_zenoh", "command hop zenoh"), ("hop_cmd_can", "command hop can")]
    s.table(["figure", *PCT_KEYS], _pct_rows(timing, names))
    s.figure("latency")


def _lateness(s: Section, data: dict[str, Any]) -> None:
    timing = data["timing"]["summary"] or {}
    names = [
        ("wakeup_lateness", "controller wake-up lateness"),
        ("period_jitter", "controller period jitter"),
        ("plant_wakeup_lateness", "plant wake-up lateness"),
    ]
    measured_here = ("wakeup_lateness", "period_jitter") if timing else ()
    s.table(["figure", *PCT_KEYS], _pct_rows(timing, names, measured_here))
    # Missed slots: a stall of N periods misses N slots (late wake-ups + slots never run).
    keys = ("ticks", "slots", "deadline_misses", "late_ticks", "skipped_slots")
    keys += ("deadline_miss_rate", "plant_slots", "plant_deadline_misses", "plant_skipped_slots")
    counts = [[k, _na(timing.get(k)), _unit_of(k)] for k in keys] if timing else []
    s.table(["figure", "value", "unit"], counts)
    sched = data["timing"].get("scheduling") or {}
    for role, got in sched.items():
        if isinstance(got, dict):
            s.p(
                f"Scheduling of the {role}: asked {got.get('requested')}, got {got.get('policy')}"
                f" (priority {got.get('priority')}); the policy changes wake-up lateness, "
                "deadline misses and the command age."
            )
    s.figure("lateness")


def _messages(s: Section, data: dict[str, Any]) -> None:
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
    if isinstance(impair, dict):
        s.p(
            f"The link was impaired on purpose ([impair], docs/impair.md): {impair.get('packets')}"
            f" in a {impair.get('namespace')}; nftables matched {impair.get('matched_packets')} "
            f"packets and dropped {impair.get('dropped_packets')}. The lost counts below can only "
            "be those (and any the faults above injected)."
        )
    msgs = data["timing"].get("messages") or {}
    keys = ("sent", "received", "lost", "duplicated", "reordered")
    s.table(
        ["stream", *keys, "more"],
        [
            [name, *(st.get(k) for k in keys), {k: v for k, v in st.items() if k not in keys}]
            for name, st in msgs.items()
            if isinstance(st, dict)
        ],
    )


def _tick_phase_line(p: dict[str, Any]) -> str:
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


def _timing_summary(s: Section, data: dict[str, Any]) -> None:
    timing = data["timing"]["summary"] or {}
    s.p(f"From {data['timing'].get('source')}; definitions in docs/realtime.md.")
    phase = timing.get("tick_phase")
    if isinstance(phase, dict):
        s.p(_tick_phase_line(phase))
    s.table(
        ["figure", *PCT_KEYS],
        [
            [k, *(f.get(q) for q in PCT_KEYS)]
            for k, f in timing.items()
            if isinstance(f, dict) and "p50_us" in f
        ],
    )
    s.table(
        ["figure", "value", "unit"],
        [[k, f, _unit_of(k)] for k, f in timing.items() if not isinstance(f, dict | str)],
    )


BUILDERS = {
    "headline": _headline,
    "terms": _terms,
    "verdict": _verdict,
    "certificate": _certificate,
    "trajectory": _trajectory,
    "velocities": _velocities,
    "torques": _torques,
    "drives": _drives,
    "tracking_error": _tracking_error,
    "bands": _bands,
    "latency": _latency,
    "lateness": _lateness,
    "messages": _messages,
    "timing_summary": _timing_summary,
}
