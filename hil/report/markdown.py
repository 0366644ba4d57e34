"""report.md: the same sections as the HTML, figures as PNG files beside it."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

SECTION_TITLES: dict[str, str] = {
    "trajectory": "Trajectory in the plane",
    "velocities": "Velocities v and ω against (2)",
    "torques": "Torques τ1 and τ2 against (2)",
    "tracking_error": "Tracking error and deviation from the ideal trajectory",
    "bands": "Quasi-sliding bands and switching",
    "latency": "Latency per path (histogram and CDF)",
    "lateness": "Wake-up lateness and jitter over time",
    "timing_summary": "Timing summary (summary.json)",
    "verdict": "Verdict",
}
SECTION_FIGURES: dict[str, tuple[str, ...]] = {
    "trajectory": ("trajectory",),
    "velocities": ("v", "omega"),
    "torques": ("tau1", "tau2"),
    "tracking_error": ("tracking_error",),
    "bands": ("bands",),
    "latency": ("latency",),
    "lateness": ("lateness",),
}


def fmt(value: Any) -> str:
    if value is None:
        return "–"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        if not math.isfinite(value):
            return str(value)
        return f"{value:.6g}"
    return str(value)


Rows = list[tuple[list[str], list[list[Any]]]]


def metric_rows(data: dict[str, Any], section: str) -> Rows:
    """The tables of one section, as (header, rows) pairs."""
    m = data["metrics"]
    if section in ("velocities", "torques"):
        names = ("v", "omega") if section == "velocities" else ("tau1", "tau2")
        rows = []
        for n in names:
            c = m["constraints"][n]
            rows.append(
                [n, c["peak"], c["limit"], c["ratio"], c["held"], c["bound"], c["within_bound"]]
            )
        header = [
            "signal",
            "max |·|",
            "limit",
            "max/limit",
            "held",
            "sampled-data bound",
            "within bound",
        ]
        out: Rows = [(header, rows)]
        if section == "velocities":
            cert = data["certificate"]
            out.append(
                (
                    ["certificate", "value"],
                    [
                        ["evaluated at Ts [s]", cert["ts"]],
                        ["evaluated at delay [s]", cert["delay"]],
                        ["timing from", cert.get("timing_source")],
                        ["v bound", cert["v_bound"]],
                        ["ω bound", cert["w_bound"]],
                        ["held", cert["held"]],
                        ["source", cert["source"]],
                    ],
                )
            )
        return out
    if section == "tracking_error":
        rows = [[k, v] for k, v in m["tracking"].items()]
        dev = m.get("deviation_from_ideal")
        if dev:
            rows += [[f"deviation from ideal, {k}", v] for k, v in dev.items()]
        rows.append(["deviation from ideal", m.get("deviation_from_ideal_note", "")])
        return [(["figure", "value"], rows)]
    if section == "bands":
        rows = []
        for name, b in m["bands"].items():
            if b is None:
                rows.append([name, "not in trace", None, None, None])
            else:
                rows.append(
                    [name, b["reaching_time"], b["band_p99"], b["band_max"], b["band_spread"]]
                )
        out = [
            (["variable", "reaching time [s]", "band p99 |·|", "band max |·|", "max - min"], rows)
        ]
        sw = m["switching_rate"]
        out.append(
            (["torque", "switching rate [1/s]"], [["tau1", sw["tau1"]], ["tau2", sw["tau2"]]])
        )
        return out
    if section == "latency":
        rows = [
            [k, *(p.get(q) for q in ("p50", "p90", "p99", "p999", "max"))]
            for k, p in data["timing"]["latency_percentiles_us"].items()
        ]
        return [(["path", "p50 µs", "p90 µs", "p99 µs", "p99.9 µs", "max µs"], rows)]
    if section == "lateness":
        rows = [
            [k, *(p.get(q) for q in ("p50", "p90", "p99", "p999", "max"))]
            for k, p in data["timing"]["lateness_percentiles_us"].items()
        ]
        return [(["figure", "p50 µs", "p90 µs", "p99 µs", "p99.9 µs", "max µs"], rows)]
    if section == "timing_summary":
        timing = data["timing"]["summary"] or {}
        keys = ("p50_us", "p90_us", "p99_us", "p999_us", "max_us", "count")
        rows = [[k, *(f.get(q) for q in keys)] for k, f in timing.items() if isinstance(f, dict)]
        return [(["figure", *keys], rows)]
    return []


def _md_table(header: Sequence[str], rows: Sequence[Sequence[Any]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(fmt(c) for c in row) + " |" for row in rows]
    return "\n".join(lines)


def render_markdown(data: dict[str, Any], files: Sequence[dict[str, str]]) -> str:
    by_name = {f["name"]: f for f in files}
    v = data["verdict"]
    s = data["scenario"]
    out = [
        f"# What timing did to the law: {data['folder']}",
        "",
        f"{data['kind']} · law `{s['law']}` · Ts {fmt(s['ts'])} s · delay {fmt(s['delay'])} s "
        f"· jitter {fmt(s['jitter'])} s ({s['jitter_kind']})",
        "",
        f"## {SECTION_TITLES['verdict']}: {'PASS' if v['ok'] else 'FAIL'}",
        "",
        _md_table(
            ["item", "state"],
            [
                ["limits (2)", v["limits"]],
                ["certificate", v["certificate"]],
                ["deadline misses", v["deadline_misses"]],
                ["lost messages", v["lost_messages"]],
            ],
        ),
        "",
    ]
    out += [f"- {r}" for r in v["reasons"]]
    for section in data["sections"]:
        if section == "verdict":
            continue
        out += ["", f"## {SECTION_TITLES[section]}", ""]
        for header, rows in metric_rows(data, section):
            out += [_md_table(header, rows), ""]
        for name in SECTION_FIGURES.get(section, ()):
            f = by_name.get(name)
            if f:
                out += [f"![{f['title']}]({f['png']})", "", f"Data: [{f['data']}]({f['data']})", ""]
    return "\n".join(out) + "\n"
