"""``hil compare DIR_A DIR_B``: two folders side by side (Zenoh path against CAN path, two
rates, a run against its simulation): overlaid trajectories, velocities and torques, the
latency CDFs of both runs, and a table of summary, sampling-effect and timing figures with
their differences (B - A); first, the headline: the differences that matter, with units. A
run's timing figures, message counts and certificate are its measurement as the folder holds it
(:func:`hil.analysis.measure.folder.measured`), never figures of compare's own."""

from __future__ import annotations

import math
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np

from hil.analysis import trace_metrics
from hil.analysis.measure.figures import Measurement
from hil.analysis.measure.folder import measured
from hil.analysis.report import content as ct
from hil.analysis.report import figures as fg
from hil.folder import RunFolder as Folder
from hil.folder.jsonio import write_json
from hil.folder.scenario_view import view
from hil.units import ms_or
from hil.verdict import LIMIT_NAMES, short_reason
from protocol.versions import COMPARE_SCHEMA_VERSION

PREFIX = "compare_"
#: How many of the most-moved figures the headline lists.
MOST_MOVED = 8
#: How much of a verdict's first reason the headline quotes (the reports have all of it).
WHY_CHARS = 200
MOVED_NOTE = (
    "The figures whose value changed most from A to B, relative to A's value (the change "
    "itself where A is 0), largest first."
)


def figures_of(folder: Folder, m: Measurement | None = None) -> dict[str, float]:
    """The scalar figures compared: summary.json's numbers, the sampling effects and, for a
    run, its measurement's timing figures, message counts and certificate."""
    sv = view(folder.scenario)
    eff = trace_metrics.sampling_effects(
        folder.trace, **asdict(sv.limits), eps1=sv.eps1, eps2=sv.eps2
    )
    out: dict[str, float] = {"ts": sv.ts, "delay": sv.delay, "jitter": sv.jitter}
    for k, v in folder.summary.items():
        if _number(v) and k != "schema_version":  # the file's format, not a figure of the run
            out[f"summary.{k}"] = float(v)
        elif isinstance(v, dict) and k == "violations":
            out |= {f"violations.{n}": float(c) for n, c in v.items() if isinstance(c, int | float)}
    out.update({f"tracking.{k}": v for k, v in eff["tracking"].items()})
    out.update({f"max_over_limit.{k}": c["ratio"] for k, c in eff["constraints"].items()})
    for name, b in eff["bands"].items():
        if b is not None:
            out[f"band_p99.{name}"] = b["band_p99"] if b["band_p99"] is not None else math.nan
    for group in ("switching_rate", "saturation_share"):
        out.update({f"{group}.{k}": r for k, r in eff[group].items()})
    if m is not None:
        out.update(measured_figures(m))
    return out


def measured_figures(m: Measurement) -> dict[str, float]:
    """timing.*, messages.* and certificate.* of a run's measurement, as numbers."""
    out: dict[str, float] = {}
    quantiles, kept = ("p50_us", "p99_us", "max_us"), ("sent", "lost", "duplicated", "reordered")
    for name, f in m.timing.items():
        values = {f"{name}.{q}": f.get(q) for q in quantiles} if isinstance(f, dict) else {name: f}
        out.update({f"timing.{k}": float(v) for k, v in values.items() if _number(v)})
    for stream, counts in m.messages.items():
        out |= {f"messages.{stream}.{k}": float(counts[k]) for k in kept if _number(counts.get(k))}
    cert = m.certificate or {}
    keys = ("d_max_s", "d_star_s", "margin_s", "v_bound", "omega_bound")
    out.update({f"certificate.{k}": float(cert[k]) for k in keys if _number(cert.get(k))})
    if isinstance(cert.get("held"), bool):
        out["certificate.held"] = float(cert["held"])
    if "stalls" in cert:
        out["certificate.stalls"] = float(len(cert["stalls"]))
    return out


def _number(x: Any) -> bool:
    return isinstance(x, int | float) and not isinstance(x, bool)


def compare_rows(a: dict[str, float], b: dict[str, float]) -> list[list[Any]]:
    both = set(a) & set(b)
    return [
        [k, a.get(k), b.get(k), b[k] - a[k] if k in both else None] for k in sorted(set(a) | set(b))
    ]


def _outcome(folder: Folder) -> str:
    v = folder.summary.get("verdict")
    if isinstance(v, dict) and v.get("outcome"):
        return str(v["outcome"])
    held = folder.summary.get("limits_held")
    return "limits held" if held else ("limits broken" if held is False else "n/a")


def _age(folder: Folder) -> str:
    c = folder.summary.get("certificate")
    if not isinstance(c, dict):
        return "D n/a"
    return f"D = {ms_or(c.get('d_max_s'), 'n/a')} of D* = {ms_or(c.get('d_star_s'), 'n/a')}"


def _why(folder: Folder) -> str | None:
    """The first reason of a verdict that is not PASS, up to its details."""
    v = folder.summary.get("verdict")
    if not isinstance(v, dict) or v.get("outcome") in (None, "PASS") or not v.get("reasons"):
        return None
    return short_reason(str(v["reasons"][0]), WHY_CHARS)


def most_moved(rows: list[list[Any]], n: int = MOST_MOVED) -> list[list[Any]]:
    """The rows whose value changed most relative to A (absolute change where A is 0)."""
    scored = []
    for key, a, b, diff in rows:
        if diff is None or not math.isfinite(diff) or diff == 0 or key in ("ts", "delay"):
            continue
        base = abs(a) if a else 1.0
        scored.append((abs(diff) / base, [key, a, b, diff, ct.unit_of(key), ct.label_of(key)]))
    scored.sort(key=lambda s: -s[0])
    once: dict[tuple[Any, ...], list[Any]] = {}
    for _, row in scored:  # one figure under two keys (summary and tracking) is listed once
        once.setdefault((row[5], row[1], row[2]), row)
    return list(once.values())[:n]


def compare_headline(
    fa: Folder, fb: Folder, a: dict[str, float], b: dict[str, float], rows: list[list[Any]]
) -> dict[str, Any]:
    """What compare says first, with units: both folders' verdicts, D against D* and limits of
    (2), then the figures that moved most. Every number is one the two folders already hold."""
    lines = [f"Verdict: A {_outcome(fa)}, B {_outcome(fb)}."]
    lines += [f"Why {n}: {why.rstrip('.')}." for n, f in (("A", fa), ("B", fb)) if (why := _why(f))]
    lines.append(
        f"Command age: A {_age(fa)}; B {_age(fb)} (D: the longest a command stayed in force "
        "after the sample it was computed from; D*: the longest the paper's bound allows "
        "while still guaranteeing the limits (2))."
    )
    limits = []
    for name, sym in ct.SYMBOL.items():
        ra, rb = a.get(f"max_over_limit.{name}"), b.get(f"max_over_limit.{name}")
        if ra is not None and rb is not None:
            limits.append(f"max |{sym}|/{ct.LIMITS[name]} {ra:.3f} → {rb:.3f}")
    if limits:
        lines.append(
            "Limits of (2), the bounds φ1, φ2 on the velocities and ϖ1, ϖ2 on the inputs the "
            f"law must keep, as peak / limit from A to B (1 = at the limit): {'; '.join(limits)}."
        )
    return {"lines": lines, "most_moved": most_moved(rows)}


def build_compare(fa: Folder, fb: Folder, out: Path, label_a: str = "A", label_b: str = "B"):
    """Write compare.html (self-contained), compare.md, compare.json and the figures with
    their data into ``out``; returns the comparison dict."""
    out.mkdir(parents=True, exist_ok=True)
    la, lb = f"{label_a}: {fa.name}", f"{label_b}: {fb.name}"
    sva = view(fa.scenario)
    ta, tb = fa.trace, fb.trace
    paths = [(la, ta["x"], ta["y"]), (lb, tb["x"], tb["y"]), ("reference", ta["xd"], ta["yd"])]
    figs = [fg.trajectory(paths, "Trajectories overlaid")]
    for key, title in ct.TITLES.items():
        # Different rates have different sample times: put B on A's time axis for the data file.
        tb_on_a = np.interp(ta["t"], tb["t"], tb[key])
        # Switching torques as their envelope and duty per bin (a solid block otherwise).
        draw = fg.switching_band if key.startswith("tau") else fg.signal_with_limits
        series = [(la, ta[key]), (lb + " (on A's times)", tb_on_a)]
        limit = getattr(sva.limits, LIMIT_NAMES[key])
        figs.append(draw(key, title, ct.SIGNALS[key], ta["t"], series, limit))
    pa, pb = (trace_metrics.position_error(t["x"], t["y"], t["xd"], t["yd"]) for t in (ta, tb))
    series = [(la, pa), (lb + " (on A's times)", np.interp(ta["t"], tb["t"], pb))]
    figs.append(fg.signal_with_limits("position_error", "Position error", "m", ta["t"], series))
    ma, mb = measured(fa), measured(fb)
    latency = {}
    for label, m in ((label_a, ma), (label_b, mb)):
        for path, values in (m.latency_us() if m is not None else {}).items():
            latency[f"{label} {path}"] = values
    if latency:
        title = "Sample-to-apply latency per run and path"
        figs.append(fg.histogram_and_cdf("latency", title, latency))
    a_fig, b_fig = figures_of(fa, ma), figures_of(fb, mb)
    rows = compare_rows(a_fig, b_fig)
    head = compare_headline(fa, fb, a_fig, b_fig, rows)
    files = []
    for f in figs:
        png, csv_path = f.write(out, PREFIX)
        files.append({"name": f.name, "title": f.title, "png": png.name, "data": csv_path.name})
    data = {
        "schema_version": COMPARE_SCHEMA_VERSION,
        "a": str(fa.path),
        "b": str(fb.path),
        "headline": head,
        "rows": [{"figure": r[0], "a": r[1], "b": r[2], "b_minus_a": r[3]} for r in rows],
        "figures": files,
    }
    write_json(out / "compare.json", data)
    _write_pages(out, data, (la, lb), rows, figs)
    return data


def _write_pages(
    out: Path, data: dict[str, Any], labels: tuple[str, str], rows: list[list[Any]], figs: list
) -> None:
    """compare.md and compare.html: the headline first, then every figure and the overlays."""
    la, lb = labels
    head, files = data["headline"], data["figures"]
    fa, fb = data["a"], data["b"]
    header = ["figure", "key (compare.json)", la, lb, "B − A", "unit"]
    every = [[ct.label_of(k), k, a, b, d, ct.unit_of(k)] for k, a, b, d in rows]
    moved_header = ["figure", la, lb, "B − A", "unit"]
    moved = [[r[5], *r[1:5]] for r in head["most_moved"]]
    md = [f"# Comparison: {fa} vs {fb}", "", *(f"- {t}" for t in head["lines"]), ""]
    md += ["## The figures that moved most", "", MOVED_NOTE, "", ct._md_table(moved_header, moved)]
    md += ["", "## Every figure", "", ct.SLIDING, "", ct._md_table(header, every), ""]
    md += ["## Overlays", "", ct.NORMALIZED, ""]
    for f in files:
        md += [f"![{f['title']}]({f['png']})", "", f"Data: [{f['data']}]({f['data']})", ""]
    (out / "compare.md").write_text("\n".join(md) + "\n")
    html = [
        "<!DOCTYPE html>",
        '<html lang="en"><head><meta charset="utf-8">',
        f"<title>{ct.esc('Comparison')}</title><style>{ct.CSS}</style></head><body>",
        f"<h1>Comparison: {ct.esc(fa)} vs {ct.esc(fb)}</h1>",
        '<section id="headline"><div class="verdict unsure"><ul>',
        *(f"<li>{ct.esc(t)}</li>" for t in head["lines"]),
        "</ul></div>",
        "<h2>The figures that moved most</h2>",
        f"<p>{ct.esc(MOVED_NOTE)}</p>",
        ct.table(moved_header, moved),
        "</section>",
        '<section id="figures_table"><h2>Every figure</h2>',
        f"<p>{ct.esc(ct.SLIDING)}</p>",
        f"<details><summary>{len(rows)} figures of A and B, each with its unit</summary>",
        ct.table(header, every),
        "</details></section>",
        '<section id="overlays"><h2>Overlays</h2>',
        f"<p>{ct.esc(ct.NORMALIZED)}</p>",
        '<div class="figs">',
        *(ct.figure(f, PREFIX) for f in figs),
        "</div></section></body></html>",
    ]
    (out / "compare.html").write_text("\n".join(html))
