"""sweep.csv, sweep.json, the figures (PNG + CSV) and sweep.md of ``hil sweep``."""

from __future__ import annotations

import csv
from collections.abc import Mapping, Sequence
from dataclasses import asdict
from pathlib import Path
from typing import Any, TypedDict

import numpy as np

from hil.analysis.report import figures as fg
from hil.folder.jsonio import jsonable, write_json
from hil.folder.records import LawFaultRecord
from hil.law.facts import Law
from hil.sweep.grid import (
    BreakPoints,
    CertifiedBreak,
    GridPoint,
    LawFaultPoint,
    SweepGrid,
    SweepRow,
    aggregate,
    break_points,
    break_sentence,
    coverage,
    coverage_sentence,
)
from hil.sweep.runner import LAW_FAULT_RECORD
from protocol.versions import SWEEP_SCHEMA_VERSION

# sweep.csv: the columns of hil.sweep.runner.point_row, in its order
CSV_COLUMNS = (
    "ts", "delay", "jitter", "seed", "age", "final_position_error", "rms_position_error",
    "max_abs_v", "max_abs_omega", "max_abs_tau1", "max_abs_tau2", "overshoot_v",
    "overshoot_omega", "band_v", "band_w", "violations", "violation", "v_bound", "w_bound",
    "certified", "within_bound", "commands_dropped", "complete", "nonfinite_steps", "law_fault",
)  # fmt: skip
# (metric, y label, how to aggregate over jitter and seeds, reference line)
FIGURES: tuple[tuple[str, str, str, float | None], ...] = (
    ("rms_position_error", "tracking error: RMS position error, last 10% [m]", "mean", None),
    ("band_v", "band of v~: p99 |v~| after reaching [m/s]", "max", None),
    ("band_w", "band of w~: p99 |w~| after reaching [rad/s]", "max", None),
    ("overshoot_v", "max |v| / φ1 (1: the limit)", "max", 1.0),
    ("overshoot_omega", "max |ω| / φ2 (1: the limit)", "max", 1.0),
)


def _series(
    rows: Sequence[SweepRow], metric: str, how: str, along: str, grid: SweepGrid
) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    agg = aggregate(rows, metric, how)
    if along == "ts":
        x, others, label = grid.ts, grid.delay, "delay"
    else:
        x, others, label = grid.delay, grid.ts, "Ts"
    series = {}
    for o in others:
        keyed = [(xv, o) if along == "ts" else (o, xv) for xv in x]
        ys = np.array([agg.get(k, np.nan) for k in keyed], dtype=float)
        if np.isfinite(ys).any():
            series[f"{label}={o:g} s"] = ys
    return np.asarray(x, dtype=float), series


def sweep_figures(rows: Sequence[SweepRow], grid: SweepGrid, bp: BreakPoints):
    figs = []
    first = bp.get("first")
    for metric, ylabel, how, hline in FIGURES:
        for along, xlabel in (("ts", "Ts [s]"), ("delay", "delay [s]")):
            x, series = _series(rows, metric, how, along, grid)
            if not series:
                continue
            mark = None if first is None else first[along]
            title = f"{ylabel} against {xlabel.split()[0]}"
            name = f"{metric}_vs_{along}"
            figs.append(
                fg.against_parameter(name, title, xlabel, ylabel, x, series, hline, mark or None)
            )
    return figs


def write_csv(path: Path, rows: Sequence[SweepRow]) -> None:
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(CSV_COLUMNS)
        for r in rows:
            w.writerow(["" if r.get(c) is None else r.get(c) for c in CSV_COLUMNS])


class SweepMeta(TypedDict, total=False):
    """What sweep.json says of the sweep beside its rows (hil.commands.sweep)."""

    scenario_file: str
    law: str
    limits: dict[str, float]  # phi1, phi2 of (2)
    duration: float  # s per loop
    interrupted: bool
    groups_done: int
    robot_steps: int
    elapsed_s: float
    robot_steps_per_s: float | None
    certificate: CertifiedBreak
    disturbance: str
    provenance: dict[str, str]
    executor: str  # with --workers or --scheduler (hil.sweep.cluster.ExecutorFacts)
    chunks: int
    chunk_size: int


class BreakPointsJson(TypedDict, total=False):
    """sweep.json's ``break_point``: :class:`BreakPoints` with its two maps as lists."""

    held_everywhere: bool | None
    violating_points: int
    law_faults: int
    first_law_fault: LawFaultPoint | None
    ts_by_delay: list[dict[str, float | None]]  # {"delay", "ts"}
    delay_by_ts: list[dict[str, float | None]]  # {"ts", "delay"}
    first: GridPoint | None


class SweepDocument(SweepMeta, total=False):
    """sweep.json (docs/reports.md, "hil sweep")."""

    schema_version: int
    grid: dict[str, list[float] | list[str] | int]  # hil.sweep.grid.SweepGrid's fields
    coverage: dict[str, int]
    break_point: BreakPointsJson
    law_fault: LawFaultRecord | None
    rows: list[SweepRow]
    figures: list[dict[str, str]]


def write_outputs(
    out: Path,
    rows: list[SweepRow],
    grid: SweepGrid,
    meta: SweepMeta,
) -> SweepDocument:
    out.mkdir(parents=True, exist_ok=True)
    # The first faulted point's whole record (traceback) once, not one per row.
    records = [r for r in rows if r.get(LAW_FAULT_RECORD) is not None]
    rows = [{k: v for k, v in r.items() if k != LAW_FAULT_RECORD} for r in rows]
    bp = break_points(rows) if rows else BreakPoints(held_everywhere=None, first=None)
    write_csv(out / "sweep.csv", rows)
    figs = sweep_figures(rows, grid, bp) if rows else []
    files = []
    for fig in figs:
        png, data = fig.write(out, "sweep_")
        files.append({"name": fig.name, "title": fig.title, "png": png.name, "data": data.name})
    by_delay = [{"delay": k, "ts": v} for k, v in bp.get("ts_by_delay", {}).items()]
    by_ts = [{"ts": k, "delay": v} for k, v in bp.get("delay_by_ts", {}).items()]
    doc: SweepDocument = {
        "schema_version": SWEEP_SCHEMA_VERSION,
        "grid": {k: list(v) if isinstance(v, tuple) else v for k, v in asdict(grid).items()},
        **meta,
        "coverage": coverage(rows, len(grid)),
        "break_point": jsonable({**bp, "ts_by_delay": by_delay, "delay_by_ts": by_ts}),
        "law_fault": _first_record(records, bp.get("first_law_fault")),
        "rows": rows,
        "figures": files,
    }
    write_json(out / "sweep.json", doc)
    (out / "sweep.md").write_text(_markdown(doc, bp, files))
    return doc


def _first_record(
    records: Sequence[SweepRow], first: Mapping[str, Any] | None
) -> LawFaultRecord | None:
    """The law fault record (controller_service.laws.guard.LawFault) of the first faulted
    point, None when the law never failed."""
    keys = ("ts", "delay", "jitter", "seed")
    for r in records:
        if first is not None and all(r[k] == first[k] for k in keys):
            return r[LAW_FAULT_RECORD]
    return records[0][LAW_FAULT_RECORD] if records else None


def certificate_sentence(rows: Sequence[SweepRow], law: Any) -> str:
    """What the certificate says over the loops run, from their ``certified`` column (the
    results table's "certificate holds"): the points where it does not guarantee (2), listed
    per delay (and jitter), never a "from" that the table may contradict (the certificate is
    not monotone in Ts at a fixed delay, nor in the delay at a fixed Ts)."""
    if not Law(str(law)).has_certificate:
        return "The certificate covers the unified laws only: not evaluated for this law."
    points: dict[tuple[float, float, float], Any] = {}
    for r in rows:
        points[(r["ts"], r["delay"], r["jitter"])] = r.get("certified")
    if not points:
        return "No loop ran: the certificate was not evaluated."
    jitters = len({j for _, _, j in points}) > 1
    what = "(Ts, delay, jitter)" if jitters else "(Ts, delay)"
    no = sorted(k for k, held in points.items() if held is False)
    unknown = sum(1 for held in points.values() if held is None)
    if not no and not unknown:
        return (
            f"The certificate (docs/sampled_data_bound.md) guarantees (2) at every {what} "
            f"point run ({len(points)})."
        )
    parts = []
    for key in sorted({(d, j if jitters else 0.0) for _, d, j in no}):
        where = f"delay = {key[0]:g} s" + (f", jitter = {key[1]:g} s" if jitters else "")
        mine = sorted(t for t, d, j in points if (d, j if jitters else 0.0) == key)
        bad = sorted(t for t, d, j in no if (d, j if jitters else 0.0) == key)
        ts = "every Ts run" if bad == mine else "Ts = " + ", ".join(f"{t:g}" for t in bad) + " s"
        parts.append(f"{where}: {ts}")
    text = (
        f"The certificate does not guarantee (2) at {len(no)} of the {len(points)} {what} "
        f"points run"
    )
    text += (": " + "; ".join(parts)) if parts else ""
    if unknown:
        text += f"; at {unknown} it could not be evaluated"
    return text + "; a limit may still hold there (the heat map shows where one broke)."


def _markdown(doc: SweepDocument, bp: BreakPoints, files: list[dict[str, str]]) -> str:
    g = doc["grid"]
    cov = doc["coverage"]
    lines = [
        "# Sweep",
        "",
        f"Scenario `{doc.get('scenario_file', '?')}`, law `{doc.get('law', '?')}`, "
        f"{doc.get('duration', '?')} s per loop, {len(doc['rows'])} loops"
        + (" (INTERRUPTED: partial results)" if doc.get("interrupted") else "")
        + ".",
        f"Grid: Ts {g['ts']}, delay {g['delay']}, jitter {g['jitter']}, seeds {g['seeds']}"
        + (f" (defaults used for: {', '.join(g['defaulted'])})" if g["defaulted"] else "")
        + ".",
        "",
    ]
    fault = bp.get("first_law_fault")
    if fault is not None:
        lines += [
            "## Law fault",
            "",
            f"The law failed at {bp['law_faults']} of {len(doc['rows'])} loops (a FAIL of the "
            f"law: those points never count as held); first at Ts = {fault['ts']:g} s, delay = "
            f"{fault['delay']:g} s: {fault['law_fault']}.",
            "",
        ]
    lines += ["## Break point", "", break_sentence(bp, cov, len(doc["rows"]))]
    if bp.get("first") is not None:
        lines += [
            "",
            "| delay [s] | smallest Ts that broke a limit [s] (none: held at every Ts run) |",
            "|---|---|",
        ]
        for d, ts in bp["ts_by_delay"].items():
            lines.append(f"| {d:g} | {'none' if ts is None else f'{ts:g}'} |")
    missing = coverage_sentence(cov)
    if missing and bp.get("first") is not None:  # without a break the sentence above says it
        lines += ["", missing[0].upper() + missing[1:] + "."]
    cert = certificate_sentence(doc["rows"], doc.get("law"))
    lines += ["", f"Certificate: {cert}", "", "## Figures", ""]
    for f in files:
        lines += [f"![{f['title']}]({f['png']}) (data: [{f['data']}]({f['data']}))", ""]
    return "\n".join(lines) + "\n"
