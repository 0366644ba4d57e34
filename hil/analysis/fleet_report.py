"""The fleet report: per robot its verdict and D against D*; for the fleet its verdict and each
robot's figure aggregated by one written rule (docs/fleet.md, "The fleet report"): rates pooled
as a run pools them (:mod:`hil.folder.rates`), the command age's p99 as its worst and its median
robot (``fleet.json``, ``fleet.md``, ``fleet.png``).

The fleet's verdict is its robots': FAIL when a robot's is FAIL or its run left no verdict
(no summary.json, or a run stopped by its own error), else INCONCLUSIVE when a robot's is,
else PASS; ``hil fleet`` exits with its code (hil.verdict.EXIT_CODE)."""

from __future__ import annotations

import base64
import io
import json
from pathlib import Path
from typing import TypedDict

import matplotlib
import matplotlib.pyplot as plt
from matplotlib.figure import Figure

from hil.analysis.measure.stats import exact_percentile
from hil.analysis.report import content as ct
from hil.analysis.report.build import build_report, write_report
from hil.folder import layout, load_folder
from hil.folder.rates import RATES, pooled
from hil.units import ms_or
from hil.verdict import FAIL, INCONCLUSIVE, PASS, Verdict, run_outcome

NO_RUN = "NO RUN"  # a robot whose folder has no summary.json: it has no verdict


class _Rates(TypedDict, total=False):
    """The counts and rates of hil.folder.rates.RATES (a robot's, or pooled over the fleet)."""

    deadline_misses: int | None
    slots: int | None
    deadline_miss_rate: float | None
    plant_deadline_misses: int | None
    plant_slots: int | None
    plant_deadline_miss_rate: float | None
    samples_without_command: int | None
    samples_judged: int | None
    samples_without_command_rate: float | None
    late_commands: int | None
    late_commands_rate: float | None


class RobotRow(_Rates, total=False):
    """One robot of fleet.json's ``per_robot``: its verdict, D against D*, its applied path's
    command age p99, and the counts and rates of its summary.json."""

    robot: str
    folder: str
    exit_code: int | None
    verdict: str
    reason: str | None
    error: str | None
    d_max_s: float | None
    d_star_s: float | None
    held: bool | None
    command_age_p99_us: float | None


class FleetFigures(_Rates, total=False):
    """fleet.json's ``fleet``: the fleet's verdict and its figures over the robots."""

    verdict: str
    verdict_robots: list[str]
    robots: int
    passed: int
    certificates_held: int
    command_age_p99_us_max: float | None
    command_age_p99_us_median: float | None


class FleetFacts(TypedDict, total=False):
    """What ``hil fleet`` ran: fleet.json's first keys (none for a fleet built in a test)."""

    scenario: str
    rate_hz: float | None  # --rate (None: the scenario's)
    duration_s: float | None  # --duration (None: the scenario's)
    lab: str | None  # --lab
    per_process: int  # robots a process (--per-process)


class FleetSummary(FleetFacts, total=False):
    """fleet.json: what the fleet ran, then its figures and one row per robot."""

    fleet: FleetFigures
    per_robot: list[RobotRow]


def _robot(folder: Path, code: int | None) -> RobotRow:
    """A robot's row: its verdict, D against D*, its applied path's command age p99, and the
    counts and rates of RATES from its summary.json."""
    row: RobotRow = {"robot": folder.name, "folder": folder.name, "exit_code": code}
    try:
        s = json.loads((folder / layout.SUMMARY).read_text())
    except (OSError, ValueError):
        return {**row, "verdict": NO_RUN, "error": "no summary.json"}
    t, cert = s.get("timing") or {}, s.get("certificate") or {}
    row["verdict"] = run_outcome(s)  # as that robot's hil run exits
    reasons = (s.get("verdict") or {}).get("reasons") or []
    row["reason"] = str(s["error"]) if s.get("error") else next(iter(reasons), None)
    row.update({k: cert.get(k) for k in ("d_max_s", "d_star_s", "held")})
    age = t.get(f"command_age_{cert.get('path') or s.get('cmd_path') or 'zenoh'}") or {}
    row["command_age_p99_us"] = age.get("p99_us")
    for rate, (count, over) in RATES.items():
        row.update({k: t.get(k) for k in (count, over, rate)})
    return {**row, "error": s.get("error")}


def fleet_outcome(rows: list[RobotRow]) -> tuple[str, list[str]]:
    """The fleet's verdict from its robots' (module docstring) and the robots that made it
    (those FAIL or without a verdict, or, for INCONCLUSIVE, those INCONCLUSIVE)."""
    failed = [r["robot"] for r in rows if r.get("verdict") not in (PASS, INCONCLUSIVE)]
    if failed:
        return FAIL, failed
    unsure = [r["robot"] for r in rows if r.get("verdict") == INCONCLUSIVE]
    return (INCONCLUSIVE, unsure) if unsure else (PASS, [])


def fleet_summary(out: Path, codes: dict[str, int | None], facts: FleetFacts) -> FleetSummary:
    rows = [_robot(out / robot, code) for robot, code in codes.items()]
    p99 = [r["command_age_p99_us"] for r in rows if r.get("command_age_p99_us") is not None]
    outcome, robots = fleet_outcome(rows)
    fleet: FleetFigures = {
        "verdict": outcome,
        "verdict_robots": robots,
        "robots": len(rows),
        "passed": sum(r.get("verdict") == PASS for r in rows),
        "certificates_held": sum(bool(r.get("held")) for r in rows),
        "command_age_p99_us_max": max(p99, default=None),
        "command_age_p99_us_median": exact_percentile(p99, 50.0),
    }
    fleet.update({rate: pooled(rows, rate) for rate in RATES})
    return {**facts, "fleet": fleet, "per_robot": rows}


def _pct(x: float | None) -> str:
    return "n/a" if x is None else f"{100.0 * x:.3f} %"


def _us(x: float | None) -> str:
    return "n/a" if x is None else f"{x:.0f}"


def negative_reason(summary: FleetSummary) -> str:
    """Why the fleet is not PASS, for its exit line: the robots that made its verdict, each with
    its first reason (a law's fault sentence names the law, the time and the input)."""
    f = summary["fleet"]
    made = set(f["verdict_robots"])
    why = [f"{r['robot']}: {r['reason']}" for r in summary["per_robot"]
           if r["robot"] in made and r.get("reason")]  # fmt: skip
    return verdict_sentence(f).removeprefix("Verdict: ") + (f" {'; '.join(why)}" if why else "")


def verdict_sentence(f: FleetFigures) -> str:
    """The fleet's verdict in one sentence, from its robots' (the table below it)."""
    names = ", ".join(f["verdict_robots"])
    if f["verdict"] == FAIL:
        return f"Verdict: FAIL (robots FAIL or without a verdict: {names})."
    if f["verdict"] == INCONCLUSIVE:
        return f"Verdict: INCONCLUSIVE (robots INCONCLUSIVE: {names}; none FAIL)."
    return f"Verdict: PASS (every robot of {f['robots']})."


def _lines(f: FleetFigures) -> list[str]:
    """The fleet's answer, first on both pages: its verdict and its figures over the robots."""
    return [
        verdict_sentence(f),
        f"PASS {f['passed']} of {f['robots']}; certificates held {f['certificates_held']}.",
        f"Command age p99 (max over robots) {_us(f['command_age_p99_us_max'])} µs; "
        f"samples without a command {_pct(f['samples_without_command_rate'])} of those judged; "
        f"deadline misses {_pct(f['deadline_miss_rate'])} of the slots; late commands "
        f"{_pct(f['late_commands_rate'])} of those judged.",
    ]


#: The per-robot table's columns (both pages), each with its unit.
HEADER = ["robot", "verdict", "D [ms]", "D* [ms]", "certificate held", "command age p99 [µs]"]
HEADER += ["samples without a command", "deadline misses"]


def _cells(r: RobotRow) -> list[str]:
    """A robot's row, every number formatted in its unit (never a raw float)."""
    held = {True: "yes", False: "no"}.get(r.get("held"), "n/a")  # type: ignore[arg-type]
    return [
        r.get("verdict") or NO_RUN,
        ms_or(r.get("d_max_s"), "n/a", 2, ""),
        ms_or(r.get("d_star_s"), "n/a", 2, ""),
        held,
        _us(r.get("command_age_p99_us")),
        _pct(r.get("samples_without_command_rate")),
        _pct(r.get("deadline_miss_rate")),
    ]


def _why(summary: FleetSummary) -> list[RobotRow]:
    return [r for r in summary["per_robot"] if r.get("verdict") != PASS and r.get("reason")]


def markdown(summary: FleetSummary) -> str:
    f = summary["fleet"]
    lines = [f"# Fleet of {f['robots']} robots", "", *_lines(f), ""]
    lines += ["| " + " | ".join(HEADER) + " |", "|" + "---|" * len(HEADER)]
    for r in summary["per_robot"]:
        name = f"[{r['robot']}]({r['robot']}/{layout.REPORT_HTML})"  # its report (hil fleet's)
        lines.append("| " + " | ".join([name, *_cells(r)]) + " |")
    if why := _why(summary):
        lines += ["", "Why (each robot's first reason):", ""]
        lines += [f"- {r['robot']}: {r['reason']}" for r in why]
    lines += ["", f"![D of each robot against its D*]({layout.FLEET_PNG})"]
    return "\n".join(lines) + "\n"


def html_page(summary: FleetSummary, png: bytes) -> str:
    """fleet.html: self-contained as the run report (inline CSS, the plot as a data URI), the
    answer first, each robot linked to its report.html."""
    f = summary["fleet"]
    cls = {PASS: "ok", INCONCLUSIVE: "unsure"}.get(f["verdict"], "bad")
    rows = []
    for r in summary["per_robot"]:
        link = f'<a href="{ct.esc(r["robot"])}/{layout.REPORT_HTML}">{ct.esc(r["robot"])}</a>'
        rows.append(
            "<tr><td>"
            + link
            + "</td>"
            + "".join(f"<td>{ct.esc(c)}</td>" for c in _cells(r))
            + "</tr>"
        )
    head = "".join(f"<th>{ct.esc(h)}</th>" for h in HEADER)
    why = "".join(f"<li>{ct.esc(r['robot'])}: {ct.esc(r['reason'])}</li>" for r in _why(summary))
    b64 = base64.b64encode(png).decode("ascii")
    return "\n".join(
        [
            "<!DOCTYPE html>",
            '<html lang="en"><head><meta charset="utf-8">',
            f"<title>Fleet of {f['robots']} robots</title><style>{ct.CSS}</style></head><body>",
            f"<h1>Fleet of {f['robots']} robots</h1>",
            f'<div class="verdict {cls}"><strong>{ct.esc(f["verdict"])}</strong><ul>',
            *(f"<li>{ct.esc(line)}</li>" for line in _lines(f)),
            "</ul></div>",
            "<h2>Each robot</h2>",
            "<p>D: the longest a command stayed in force after the sample it was computed from; "
            "D*: the longest the paper's bound allows while still guaranteeing the limits (2). "
            "Each robot's name links to its own report.</p>",
            f"<table><thead><tr>{head}</tr></thead><tbody>{''.join(rows)}</tbody></table>",
            *([f"<h2>Why</h2><ul>{why}</ul>"] if why else []),
            "<h2>D of each robot against its D*</h2>",
            f'<figure><img alt="D of each robot against its D*" src="data:image/png;base64,{b64}">'
            f"<figcaption>data: fleet.json</figcaption></figure>",
            "</body></html>",
        ]
    )


def figure(summary: FleetSummary) -> Figure:
    """D of each robot against its D*; the legend above the axes, never over a bar."""
    matplotlib.use("Agg")
    rows = summary["per_robot"]
    names = [r["robot"] for r in rows]
    d = [(r.get("d_max_s") or 0) * 1e3 for r in rows]
    ds = [(r.get("d_star_s") or 0) * 1e3 for r in rows]
    fig, ax = plt.subplots(figsize=(max(6.0, 0.35 * len(rows) + 2), 3.6))
    ax.bar(names, d, label="D (measured)")
    ax.plot(names, ds, "r_", markersize=14, markeredgewidth=2, label="D* (the bound's)")
    ax.set_ylabel("command age (ms)")
    ax.set_ylim(0, 1.05 * max([*d, *ds, 1e-3]))
    ax.tick_params(axis="x", rotation=90 if len(rows) > 8 else 0)
    ax.legend(loc="lower left", bbox_to_anchor=(0.0, 1.02), ncol=2, frameon=False)
    fig.tight_layout()
    return fig


def plot(summary: FleetSummary, path: Path) -> bytes:
    fig = figure(summary)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100)
    plt.close(fig)
    path.write_bytes(buf.getvalue())
    return buf.getvalue()


def write_robot_reports(out: Path, summary: FleetSummary) -> list[Path]:
    """Each robot's report.html (and report.md, report.json), as ``hil run`` writes it, from its
    folder and the verdict its run judged; without the ideal trajectory (``hil report
    OUT/robotI`` adds it). A robot without summary.json has no run to report."""
    written = []
    for r in summary["per_robot"]:
        folder = out / r["robot"]
        if r.get("verdict") == NO_RUN:
            continue
        loaded = load_folder(folder, lazy=True)
        saved = loaded.summary.get("verdict")
        judged = Verdict.from_dict(saved) if isinstance(saved, dict) else None
        written.append(write_report(build_report(loaded, verdict=judged), folder)["html"])
    return written


def write(out: Path, codes: dict[str, int | None], facts: FleetFacts) -> FleetSummary:
    summary = fleet_summary(out, codes, facts)
    (out / layout.FLEET_JSON).write_text(json.dumps(summary, indent=2) + "\n")
    (out / layout.FLEET_MD).write_text(markdown(summary))
    png = plot(summary, out / layout.FLEET_PNG)
    (out / layout.FLEET_HTML).write_text(html_page(summary, png))
    write_robot_reports(out, summary)
    return summary
