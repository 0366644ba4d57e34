"""The fleet report: per robot its verdict and D against D*; for the fleet its outcome (the
exit rule) and each robot's figure aggregated by one written rule (docs/fleet.md, "The fleet
report"): rates pooled as a run pools them (:mod:`hil.folder.rates`), the command age's p99 as
its worst and its median robot (``fleet.json``, ``fleet.md``, ``fleet.png``)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import matplotlib
import matplotlib.pyplot as plt

from hil.folder.rates import RATES, pooled
from hil.measure.stats import exact_percentile
from hil.verdict import FAIL, INCONCLUSIVE, PASS

NO_RUN = "NO RUN"  # a robot whose folder has no summary.json: it has no verdict


def _robot(folder: Path, code: int | None) -> dict[str, Any]:
    """A robot's row: its verdict, D against D*, its applied path's command age p99, and the
    counts and rates of RATES from its summary.json."""
    row: dict[str, Any] = {"robot": folder.name, "folder": folder.name, "exit_code": code}
    try:
        s = json.loads((folder / "summary.json").read_text())
    except (OSError, ValueError):
        return {**row, "verdict": NO_RUN, "error": "no summary.json"}
    t, cert = s.get("timing") or {}, s.get("certificate") or {}
    row["verdict"] = (s.get("verdict") or {}).get("outcome")
    row.update({k: cert.get(k) for k in ("d_max_s", "d_star_s", "held")})
    age = t.get(f"command_age_{cert.get('path') or s.get('cmd_path') or 'zenoh'}") or {}
    row["command_age_p99_us"] = age.get("p99_us")
    for rate, (count, over) in RATES.items():
        row.update({k: t.get(k) for k in (count, over, rate)})
    return {**row, "error": s.get("error")}


def fleet_outcome(rows: list[dict[str, Any]]) -> str:
    """The fleet's verdict: FAIL when a robot's verdict is FAIL; else INCONCLUSIVE when a
    robot's is INCONCLUSIVE or it has none (its run wrote no verdict); else PASS."""
    verdicts = [r.get("verdict") for r in rows]
    if FAIL in verdicts:
        return FAIL
    if any(v != PASS for v in verdicts):
        return INCONCLUSIVE
    return PASS


def fleet_summary(out: Path, codes: dict[str, int | None], facts: dict[str, Any]) -> dict[str, Any]:
    rows = [_robot(out / robot, code) for robot, code in codes.items()]
    p99 = [r["command_age_p99_us"] for r in rows if r.get("command_age_p99_us") is not None]
    fleet: dict[str, Any] = {
        "robots": len(rows),
        "outcome": fleet_outcome(rows),
        "passed": sum(r.get("verdict") == PASS for r in rows),
        # robots whose run wrote no summary, or one that says the run itself failed
        "without_verdict": [r["robot"] for r in rows if r.get("verdict") == NO_RUN or r["error"]],
        "certificates_held": sum(bool(r.get("held")) for r in rows),
        "command_age_p99_us_max": max(p99, default=None),
        "command_age_p99_us_median": exact_percentile(p99, 50.0),
    }
    fleet.update({rate: pooled(rows, rate) for rate in RATES})
    return {**facts, "fleet": fleet, "per_robot": rows}


def negative(summary: dict[str, Any]) -> str | None:
    """Why ``hil fleet`` exits 1 (None: it does not): the fleet's outcome is FAIL, or a robot
    has no verdict. An INCONCLUSIVE fleet exits as an INCONCLUSIVE run does."""
    fleet = summary["fleet"]
    if fleet["outcome"] != FAIL and not fleet["without_verdict"]:
        return None
    bad = [f"{r['robot']} ({r.get('verdict')})" for r in summary["per_robot"]
           if r.get("verdict") != PASS]  # fmt: skip
    return f"fleet {fleet['outcome']}: {', '.join(bad)}"


def _ms(x: float | None) -> str:
    return "-" if x is None else f"{x * 1e3:.2f}"


def markdown(summary: dict[str, Any]) -> str:
    f = summary["fleet"]
    lines = [
        f"# Fleet of {f['robots']} robots",
        "",
        f"Outcome {f['outcome']}: PASS {f['passed']} of {f['robots']}; certificates held "
        f"{f['certificates_held']}.",
        f"Command age p99 (max over robots) {f['command_age_p99_us_max']} us; samples without "
        f"a command {f['samples_without_command_rate']}; deadline miss rate "
        f"{f['deadline_miss_rate']}; late commands {f['late_commands_rate']}.",
        "",
        "| robot | verdict | D (ms) | D* (ms) | held | command age p99 (us) |",
        "|---|---|---|---|---|---|",
    ]
    for r in summary["per_robot"]:
        lines.append(
            f"| {r['robot']} | {r.get('verdict')} | {_ms(r.get('d_max_s'))} | "
            f"{_ms(r.get('d_star_s'))} | {r.get('held')} | {r.get('command_age_p99_us')} |"
        )
    return "\n".join(lines) + "\n"


def plot(summary: dict[str, Any], path: Path) -> None:
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


def write(out: Path, codes: dict[str, int | None], facts: dict[str, Any]) -> dict[str, Any]:
    summary = fleet_summary(out, codes, facts)
    (out / "fleet.json").write_text(json.dumps(summary, indent=2) + "\n")
    (out / "fleet.md").write_text(markdown(summary))
    plot(summary, out / "fleet.png")
    return summary
