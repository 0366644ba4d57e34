"""sweep.html: the answer first (where the limits (2) break), a heat map of the break over
Ts x delay, the results table with units, then the figures of sweep.md.

Built from the document :func:`hil.sweep.outputs.write_outputs` returns (the content of
sweep.json), so the page shows exactly the figures the files hold. Self-contained HTML: no
script, no external style, the PNG figures linked by name from the same folder.
"""

from __future__ import annotations

import html
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from hil.sweep.grid import aggregate, break_sentence, coverage, coverage_sentence
from hil.sweep.outputs import certificate_sentence

# Heat-map colours of the worst overshoot max(|v|/phi1, |omega|/phi2): well inside, near, broken.
NEAR = 0.9  # from 90 % of a limit a cell is "near"
COLOURS = {"inside": "#d8f0d8", "near": "#fbe8a6", "broke": "#f4b4b4", "none": "#eeeeee"}
TABLE_ROWS_MAX = 2000  # more rows than this: the page shows the first ones, sweep.csv has all

# (key of a row, header with its unit, format)
COLUMNS: tuple[tuple[str, str, str], ...] = (
    ("ts", "Ts [s]", "g"),
    ("delay", "delay [s]", "g"),
    ("jitter", "jitter [s]", "g"),
    ("seed", "seed", "d"),
    ("age", "age Ts + delay + jitter [s]", "g"),
    ("rms_position_error", "RMS position error, last 10 % [m]", ".4g"),
    ("max_abs_v", "max |v| [m/s]", ".4g"),
    ("max_abs_omega", "max |ω| [rad/s]", ".4g"),
    ("overshoot_v", "max |v| / φ1 (1: the limit)", ".3f"),
    ("overshoot_omega", "max |ω| / φ2 (1: the limit)", ".3f"),
    ("violations", "plant steps beyond a limit [count]", "d"),
    ("certified", "certificate holds (age ≤ D*)", ""),
    ("law_fault", "law fault (the law failed here)", ""),
)

STYLE = """
body { font-family: system-ui, sans-serif; margin: 24px auto; max-width: 1200px; color: #222; }
h1 { font-size: 1.5em; } h2 { font-size: 1.2em; margin-top: 1.6em; }
.answer { font-size: 1.15em; padding: 12px 16px; border-radius: 6px; }
.held { background: #d8f0d8; } .broke { background: #f4b4b4; } .partial { background: #fbe8a6; }
table { border-collapse: collapse; font-size: 0.9em; }
th, td { border: 1px solid #bbb; padding: 4px 8px; text-align: right; }
th { background: #f2f2f2; }
.heat td { min-width: 84px; text-align: center; }
.legend span { display: inline-block; padding: 2px 10px; margin-right: 8px;
  border: 1px solid #bbb; }
img { max-width: 100%; border: 1px solid #ddd; margin: 8px 0; }
.note { color: #555; font-size: 0.9em; }
.figs { display: grid; grid-template-columns: 1fr 1fr; gap: 8px 20px; }
figure { margin: 0; } figcaption { color: #555; font-size: 0.9em; }
"""


def _e(value: Any) -> str:
    return html.escape(str(value))


def _fmt(value: Any, spec: str) -> str:
    if value is None or value == "":
        return "–"
    if isinstance(value, bool):
        return "yes" if value else "NO"
    if isinstance(value, float) and not math.isfinite(value):
        return str(value)
    return format(value, spec) if spec else str(value)


def _answer(doc: Mapping[str, Any]) -> str:
    bp = doc.get("break_point") or {}
    rows = doc.get("rows") or []
    n = len(rows)
    grid = doc.get("grid") or {}
    loops = len(grid.get("ts") or []) * len(grid.get("delay") or [])
    loops *= len(grid.get("jitter") or []) * int(grid.get("seeds") or 1)
    cov = doc.get("coverage") or coverage(rows, max(loops, n))
    if not n:
        return '<p class="answer broke">No loop finished: nothing to show.</p>'
    fault = bp.get("first_law_fault")
    text = break_sentence(bp, cov, n)
    missing = coverage_sentence(cov)
    if missing and bp.get("first") is not None:
        text += f" Interrupted: {missing}."
    if fault is not None:
        text = (
            f"FAIL: the law failed at {bp.get('law_faults', '?')} of {n} loops (those points "
            f"never count as held); first at Ts = {fault['ts']:g} s, delay = "
            f"{fault['delay']:g} s: {fault['law_fault']}. " + text
        )
    kind = "broke" if bp.get("first") is not None or fault else ("partial" if missing else "held")
    return f'<p class="answer {kind}">{_e(text)}</p>'


def _terms(doc: Mapping[str, Any]) -> str:
    """The paper's symbols the page uses, each in a plain sentence (with the scenario's own
    limits where the document has them)."""
    lim = doc.get("limits") or {}
    phi1 = f" = {lim['phi1']:g} m/s" if "phi1" in lim else ""
    phi2 = f" = {lim['phi2']:g} rad/s" if "phi2" in lim else ""
    return (
        f"What the words mean: (2) are the limits the law must keep, |v| ≤ φ1{phi1} and "
        f"|ω| ≤ φ2{phi2} on the velocities and |τ1| ≤ ϖ1, |τ2| ≤ ϖ2 on the inputs (which the "
        "law clips itself). Ts is the control period, the delay is added to every command and "
        "the jitter moves each wake-up of the controller: together they bound how old the "
        "state behind a command can be (its age, Ts + delay + jitter). A loop is one closed-"
        "loop simulation at one grid point and seed. v~ and w~ are the sliding variables of "
        "(10): how far v and ω are from the velocities the law steers them to; their band is "
        "how far from zero sampling keeps them. The certificate is the paper's sampled-data "
        "bound (docs/sampled_data_bound.md): while no command is older than D*, (2) holds."
    )


def _certificate_line(doc: Mapping[str, Any]) -> str:
    return certificate_sentence(doc.get("rows") or [], doc.get("law"))


def heat_cells(rows: Sequence[Mapping[str, Any]]) -> dict[tuple[float, float], tuple[float, bool]]:
    """(Ts, delay) -> (worst overshoot over jitter and seeds, whether any loop broke a limit);
    the cells where the law failed are :func:`fault_cells`'."""
    over_v = aggregate(rows, "overshoot_v", "max")
    over_w = aggregate(rows, "overshoot_omega", "max")
    broke = aggregate(rows, "violations", "max")
    gone = aggregate(rows, "nonfinite_steps", "max")  # a non-finite state: (2) broke
    return {
        key: (
            max(over_v.get(key, -math.inf), over_w.get(key, -math.inf)),
            broke.get(key, 0) > 0 or gone.get(key, 0) > 0,
        )
        for key in set(over_v) | set(over_w)
    }


def fault_cells(rows: Sequence[Mapping[str, Any]]) -> set[tuple[float, float]]:
    """The (Ts, delay) cells where the law failed at some jitter or seed."""
    return {(r["ts"], r["delay"]) for r in rows if r.get("law_fault")}


def _heat_map(doc: Mapping[str, Any]) -> str:
    grid = doc.get("grid") or {}
    ts_values = sorted(grid.get("ts") or [])
    delays = sorted(grid.get("delay") or [])
    cells = heat_cells(doc.get("rows") or [])
    faulted = fault_cells(doc.get("rows") or [])
    cut = {(r["ts"], r["delay"]) for r in doc.get("rows") or [] if not r.get("complete", True)}
    head = "".join(f"<th>Ts = {ts:g} s</th>" for ts in ts_values)
    body = []
    for d in delays:
        tds = []
        for ts in ts_values:
            cell = cells.get((ts, d))
            if (ts, d) in faulted:
                tds.append(f'<td style="background:{COLOURS["broke"]}">law fault ✗</td>')
                continue
            if cell is None:
                tds.append(f'<td style="background:{COLOURS["none"]}">not run</td>')
                continue
            worst, broke = cell
            kind = "broke" if broke else ("near" if worst >= NEAR else "inside")
            mark = " ✗" if broke else ""
            # A loop the interrupt stopped: what it broke counts, what it held says nothing.
            mark += " (cut short)" if (ts, d) in cut and not broke else ""
            tds.append(f'<td style="background:{COLOURS[kind]}">{worst:.2f}{mark}</td>')
        body.append(f"<tr><th>delay = {d:g} s</th>{''.join(tds)}</tr>")
    legend = (
        '<p class="legend">'
        f'<span style="background:{COLOURS["inside"]}">below {NEAR:.0%} of the limit</span>'
        f'<span style="background:{COLOURS["near"]}">{NEAR:.0%} of the limit or more</span>'
        f'<span style="background:{COLOURS["broke"]}">✗ a limit broke (or the law failed)</span>'
        f'<span style="background:{COLOURS["none"]}">not run</span></p>'
    )
    return (
        "<p>Each cell: the worst of max |v| / φ1 and max |ω| / φ2 over the jitters and "
        "seeds of that (Ts, delay), a share of the limit: 1.00 is the limit.</p>"
        f'<table class="heat"><tr><th>worst max / limit</th>{head}</tr>{"".join(body)}</table>'
        f"{legend}"
    )


def _results_table(rows: Sequence[Mapping[str, Any]]) -> str:
    head = "".join(f"<th>{_e(title)}</th>" for _, title, _ in COLUMNS)
    lines = []
    order = sorted(rows, key=lambda r: (r["ts"], r["delay"], r["jitter"], r["seed"]))
    for r in order[:TABLE_ROWS_MAX]:
        bad = r.get("violations") or r.get("law_fault") or r.get("nonfinite_steps")
        style = ' style="background:#f4b4b4"' if bad else ""
        tds = "".join(f"<td>{_e(_fmt(r.get(k), spec))}</td>" for k, _, spec in COLUMNS)
        lines.append(f"<tr{style}>{tds}</tr>")
    note = ""
    if len(rows) > TABLE_ROWS_MAX:
        note = (
            f'<p class="note">The first {TABLE_ROWS_MAX} of {len(rows)} loops; '
            'all of them are in <a href="sweep.csv">sweep.csv</a>.</p>'
        )
    return f"<table><tr>{head}</tr>{''.join(lines)}</table>{note}"


def _figures(doc: Mapping[str, Any]) -> str:
    out = [
        f'<figure><img src="{_e(f["png"])}" alt="{_e(f["title"])}"><figcaption>'
        f'{_e(f["title"])} (data: <a href="{_e(f["data"])}">{_e(f["data"])}</a>)'
        "</figcaption></figure>"
        for f in doc.get("figures") or []
    ]
    if not out:
        return "<p>No figures (no loop finished).</p>"
    return '<div class="figs">' + "".join(out) + "</div>"


def sweep_html(doc: Mapping[str, Any]) -> str:
    """The page for one sweep document (sweep.json's content)."""
    grid = doc.get("grid") or {}
    rows = doc.get("rows") or []
    facts = (
        f"Scenario {doc.get('scenario_file', '?')}, law {doc.get('law', '?')}, "
        f"{doc.get('duration', '?')} s per loop, {len(rows)} loops: Ts {grid.get('ts')} s, "
        f"delay {grid.get('delay')} s, jitter {grid.get('jitter')} s, "
        f"{grid.get('seeds')} seed(s) per point."
    )
    parts = [
        "<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>",
        f"<title>hil sweep: {_e(doc.get('scenario_file', ''))}</title>",
        f"<style>{STYLE}</style></head><body>",
        "<h1>Sweep of the sampling period Ts and the delay</h1>",
        _answer(doc),
        f"<p>{_e(_certificate_line(doc))}</p>",
        f"<p>{_e(_terms(doc))}</p>",
        f'<p class="note">{_e(facts)} Files: <a href="sweep.csv">sweep.csv</a>, '
        '<a href="sweep.json">sweep.json</a>, <a href="sweep.md">sweep.md</a>.</p>',
        "<h2>Where the limits break: Ts x delay</h2>",
        _heat_map(doc),
        "<h2>Results, one row per loop</h2>",
        _results_table(rows),
        "<h2>Figures</h2>",
        _figures(doc),
        "</body></html>",
    ]
    return "\n".join(parts) + "\n"


def write_sweep_page(out: Path, doc: Mapping[str, Any]) -> Path:
    """Write sweep.html into ``out``; its path."""
    path = out / "sweep.html"
    path.write_text(sweep_html(doc))
    return path
