"""The fleet report: per robot the verdict and D against D*, for the fleet the command age's
p99, the samples without a command and the deadline misses (``fleet.json``, ``fleet.md``,
``fleet.png``)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import matplotlib
import matplotlib.pyplot as plt


def _robot(folder: Path, code: int | None) -> dict[str, Any]:
    row: dict[str, Any] = {"robot": folder.name, "folder": folder.name, "exit_code": code}
    try:
        s = json.loads((folder / "summary.json").read_text())
    except (OSError, ValueError):
        return {**row, "verdict": "NO RUN", "error": "no summary.json"}
    t, cert = s.get("timing") or {}, s.get("certificate") or {}
    verdict = s.get("verdict") or {}
    row["verdict"] = verdict.get("outcome")
    row["reason"] = next(iter(verdict.get("reasons") or []), None)  # the first: a law's fault
    row.update({k: cert.get(k) for k in ("d_max_s", "d_star_s", "held")})
    row["command_age_p99_us"] = (t.get("command_age_zenoh") or {}).get("p99_us")
    keys = ("samples_without_command", "samples_judged", "deadline_misses", "ticks")
    row.update({k: t.get(k) for k in keys})
    return {**row, "error": s.get("error")}


def _ratio(rows: list[dict[str, Any]], num: str, den: str) -> float | None:
    n = sum(r.get(num) or 0 for r in rows)
    d = sum(r.get(den) or 0 for r in rows)
    return n / d if d else None


def fleet_summary(out: Path, codes: dict[str, int | None], facts: dict[str, Any]) -> dict[str, Any]:
    rows = [_robot(out / robot, code) for robot, code in codes.items()]
    p99 = [r["command_age_p99_us"] for r in rows if r.get("command_age_p99_us") is not None]
    fleet = {
        "robots": len(rows),
        "passed": sum(r.get("verdict") == "PASS" for r in rows),
        "certificates_held": sum(bool(r.get("held")) for r in rows),
        "command_age_p99_us_max": max(p99, default=None),
        "command_age_p99_us_median": sorted(p99)[len(p99) // 2] if p99 else None,
        "samples_without_command_rate": _ratio(rows, "samples_without_command", "samples_judged"),
        "deadline_miss_rate": _ratio(rows, "deadline_misses", "ticks"),
    }
    return {**facts, "fleet": fleet, "per_robot": rows}


def _ms(x: float | None) -> str:
    return "-" if x is None else f"{x * 1e3:.2f}"


def markdown(summary: dict[str, Any]) -> str:
    f = summary["fleet"]
    lines = [
        f"# Fleet of {f['robots']} robots",
        "",
        f"PASS {f['passed']} of {f['robots']}; certificates held {f['certificates_held']}.",
        f"Command age p99 (max over robots) {f['command_age_p99_us_max']} us; samples without "
        f"a command {f['samples_without_command_rate']}; deadline miss rate "
        f"{f['deadline_miss_rate']}.",
        "",
        "| robot | verdict | D (ms) | D* (ms) | held | command age p99 (us) |",
        "|---|---|---|---|---|---|",
    ]
    for r in summary["per_robot"]:
        lines.append(
            f"| {r['robot']} | {r.get('verdict')} | {_ms(r.get('d_max_s'))} | "
            f"{_ms(r.get('d_star_s'))} | {r.get('held')} | {r.get('command_age_p99_us')} |"
        )
    why = [r for r in summary["per_robot"] if r.get("verdict") != "PASS" and r.get("reason")]
    if why:
        lines += ["", "Why (each robot's first reason):", ""]
        lines += [f"- {r['robot']}: {r['reason']}" for r in why]
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
