"""The fleet report: per robot its verdict and D against D*; for the fleet its verdict and each
robot's figure aggregated by one written rule (docs/fleet.md, "The fleet report"): rates pooled
as a run pools them (:mod:`hil.folder.rates`), the command age's p99 as its worst and its median
robot (``fleet.json``, ``fleet.md``, ``fleet.png``).

The fleet's verdict is its robots': FAIL when a robot's is FAIL or its run left no verdict
(no summary.json, or a run stopped by its own error), else INCONCLUSIVE when a robot's is,
else PASS; ``hil fleet`` exits with its code (hil.verdict.EXIT_CODE)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, TypedDict

import matplotlib
import matplotlib.pyplot as plt

from hil.analysis.measure.stats import exact_percentile
from hil.folder import layout
from hil.folder.rates import RATES, pooled
from hil.units import ms_or
from hil.verdict import FAIL, INCONCLUSIVE, PASS, run_outcome

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


class FleetSummary(TypedDict, total=False):
    """fleet.json: the fleet command's facts (free-form, :func:`write`'s ``facts``), then these."""

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


def fleet_summary(out: Path, codes: dict[str, int | None], facts: dict[str, Any]) -> FleetSummary:
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


def markdown(summary: FleetSummary) -> str:
    f = summary["fleet"]
    p99 = f["command_age_p99_us_max"]
    lines = [
        f"# Fleet of {f['robots']} robots",
        "",
        verdict_sentence(f),
        f"PASS {f['passed']} of {f['robots']}; certificates held {f['certificates_held']}.",
        f"Command age p99 (max over robots) {'n/a' if p99 is None else f'{p99:.0f}'} us; "
        f"samples without a command {_pct(f['samples_without_command_rate'])} of those judged; "
        f"deadline misses {_pct(f['deadline_miss_rate'])} of the slots; late commands "
        f"{_pct(f['late_commands_rate'])} of those judged.",
        "",
        "| robot | verdict | D (ms) | D* (ms) | held | command age p99 (us) |",
        "|---|---|---|---|---|---|",
    ]
    for r in summary["per_robot"]:
        lines.append(
            f"| {r['robot']} | {r.get('verdict')} | {ms_or(r.get('d_max_s'), '-', 2, '')} | "
            f"{ms_or(r.get('d_star_s'), '-', 2, '')} | {r.get('held')} | "
            f"{r.get('command_age_p99_us')} |"
        )
    why = [r for r in summary["per_robot"] if r.get("verdict") != "PASS" and r.get("reason")]
    if why:
        lines += ["", "Why (each robot's first reason):", ""]
        lines += [f"- {r['robot']}: {r['reason']}" for r in why]
    return "\n".join(lines) + "\n"


def plot(summary: FleetSummary, path: Path) -> None:
    """D of each robot against its D*."""
    matplotlib.use("Agg")
    rows = summary["per_robot"]
    names = [r["robot"] for r in rows]
    d = [(r.get("d_max_s") or 0) * 1e3 for r in rows]
    ds = [(r.get("d_star_s") or 0) * 1e3 for r in rows]
    fig, ax = plt.subplots(figsize=(max(4.0, 0.35 * len(rows) + 2), 3.2))
    ax.bar(names, d, label="D (measured)")
    ax.plot(names, ds, "r_", markersize=14, label="D*")
    ax.set_ylabel("command age (ms)")
    ax.tick_params(axis="x", rotation=90)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def write(out: Path, codes: dict[str, int | None], facts: dict[str, Any]) -> FleetSummary:
    summary = fleet_summary(out, codes, facts)
    (out / layout.FLEET_JSON).write_text(json.dumps(summary, indent=2) + "\n")
    (out / layout.FLEET_MD).write_text(markdown(summary))
    plot(summary, out / layout.FLEET_PNG)
    return summary
