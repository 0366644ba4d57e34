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
from typing import Any, TypedDict

import numpy as np

from hil.analysis import trace_metrics
from hil.analysis.measure.figures import Measurement
from hil.analysis.measure.folder import measured
from hil.analysis.report import content as ct
from hil.analysis.report import figures as fg
from hil.analysis.report.build import folder_verdict
from hil.folder import RunFolder as Folder
from hil.folder.jsonio import write_json
from hil.folder.scenario_view import view
from hil.law.facts import Law
from hil.limits import SYMBOLS as LIMIT_SYMBOLS
from hil.units import ms_or
from hil.verdict import LIMIT_NAMES, PASS, Verdict, short_reason
from protocol.versions import COMPARE_SCHEMA_VERSION

PREFIX = "compare_"
#: How many of the most-moved figures the headline lists (the verdicts' reasons always are).
MOST_MOVED = 8
MOVED_NOTE = (
    "What moved, by what matters: first the figures the verdicts' reasons name (what decided "
    "them), then the figures that have a limit or a threshold, by how far they moved in units "
    "of it (max |v| / φ1, samples without a command against the verdict's threshold, D against "
    "D*), then the others by their relative change; a figure below its unit's noise level in "
    "both folders (a position error of 1e-12 m) is never listed."
)
#: Below this in both folders a figure is numerical noise, in its unit (hil.analysis.report
#: .content.unit_of): a micrometre, a microradian, a microsecond.
NOISE = {"m": 1e-6, "rad": 1e-6, "m/s": 1e-6, "rad/s": 1e-6, "s": 1e-6, "fraction": 1e-9}
NOISE |= {"m/s²": 1e-6, "rad/s²": 1e-6, "µs": 1e-3}
#: Settings of the scenario, not figures of what ran: never "moved".
SETTINGS = ("ts", "delay", "jitter", "summary.ts", "summary.plant_step", "summary.duration")
SETTINGS += ("summary.samples", "summary.plant_steps", "summary.nonfinite_first_t_s")
#: The verdict's rates (its record's ``timing``): their figure's key here, and their
#: threshold's name in the record (hil.verdict.Thresholds).
RATE_THRESHOLDS = {
    "deadline_misses": ("timing.deadline_miss_rate", "max_deadline_miss_ratio"),
    "samples_without_command": (
        "timing.samples_without_command_rate",
        "max_samples_without_command_ratio",
    ),
    "lost_messages": ("verdict.lost_messages_rate", "max_lost_ratio"),
}
RATE_WORDS = {
    "deadline_misses": "missed slots",
    "samples_without_command": "samples without a command",
}
RATE_WORDS["lost_messages"] = "lost messages"


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
    for key, judged in folder_verdict(folder).timing.items():
        rate = judged.get("rate") if isinstance(judged, dict) else None
        if key in RATE_THRESHOLDS and _number(rate):
            out.setdefault(RATE_THRESHOLDS[key][0], float(rate))  # as the verdict held it
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


def _outcome(v: Verdict) -> str:
    return v.outcome or "n/a"


def _age(folder: Folder) -> str:
    c = folder.summary.get("certificate")
    if not isinstance(c, dict):
        return "D n/a"
    return f"D = {ms_or(c.get('d_max_s'), 'n/a')} of D* = {ms_or(c.get('d_star_s'), 'n/a')}"


def _why(name: str, v: Verdict) -> str | None:
    """Every reason of a verdict that is not PASS, each whole up to its details (the reports
    have those): one line."""
    reasons = [short_reason(str(r)).rstrip(".") for r in v.reasons]
    if v.outcome == PASS or not reasons:
        return None
    if len(reasons) == 1:
        return f"Why {name}: {reasons[0]}."
    listed = "; ".join(f"({i}) {r}" for i, r in enumerate(reasons, 1))
    return f"Why {name}, {len(reasons)} reasons: {listed}."


def _scale(key: str, v: Verdict, a: dict[str, float]) -> tuple[float, str] | None:
    """What a figure is measured against, and that in words: its limit of (2), the verdict's
    threshold for a rate, D* for D; None for a figure without one."""
    group, _, last = key.partition(".")
    if group == "max_over_limit":
        return 1.0, f"{LIMIT_SYMBOLS[last]} (1 = at the limit)"
    th = v.thresholds
    for fig, th_key in RATE_THRESHOLDS.values():
        if key == fig and _number(th.get(th_key)):
            return float(th[th_key]), f"threshold {100 * th[th_key]:g} %"
    d_star = a.get("certificate.d_star_s")
    if key == "certificate.d_max_s" and d_star:
        return d_star, f"D* = {ms_or(d_star, 'n/a')}"
    return None


def _reason_keys(v: Verdict) -> dict[str, str]:
    """The figures a verdict's reasons name (the limits broken, the certificate, the rates over
    their thresholds), each with the reason in a few words."""
    if v.outcome == PASS:
        return {}
    out = {f"max_over_limit.{k}": f"limit {LIMIT_SYMBOLS[k]} broken" for k in v.limits_broken}
    if v.certificate in ("not held", "broken"):
        out["certificate.d_max_s"] = f"certificate {v.certificate}"
    th = v.thresholds
    for name, judged in v.timing.items():
        fig, th_key = RATE_THRESHOLDS.get(name, ("", ""))
        rate = judged.get("rate") if isinstance(judged, dict) else None
        if _number(rate) and _number(th.get(th_key)) and rate > th[th_key]:
            out[fig] = f"{RATE_WORDS.get(name, name)} over the threshold"
    return out


def most_moved(
    rows: list[list[Any]],
    verdicts: tuple[Verdict, Verdict] = (Verdict(), Verdict()),
    n: int = MOST_MOVED,
) -> list[list[Any]]:
    """The figures that moved, by what matters (:data:`MOVED_NOTE`): each row [key, A, B, B − A,
    unit, label, measured against, why listed]. The verdicts' reasons' figures come first
    (all of them), then up to ``n`` in all."""
    va, vb = verdicts
    named = {**_reason_keys(va), **_reason_keys(vb)}
    a_of = {r[0]: r[1] for r in rows if r[1] is not None}
    tiers: list[tuple[int, float, str, list[Any]]] = []
    for key, a, b, diff in rows:
        if key in SETTINGS or key.startswith("summary.max_abs_") or key == "certificate.margin_s":
            continue  # a setting, or a figure listed under its limit (peak / limit, D)
        if diff is None or not math.isfinite(diff) or a is None or b is None:
            continue
        unit = ct.unit_of(key)
        scale = _scale(key, vb, a_of)
        against = scale[1] if scale else ""
        row = [key, a, b, diff, unit, ct.label_of(key), against]
        if key in named:
            size = abs(diff) / scale[0] if scale else abs(diff)
            tiers.append((0, -size, key, [*row, f"the verdict: {named[key]}"]))
        elif diff == 0:
            continue
        elif scale is not None:
            tiers.append((1, -abs(diff) / scale[0], key, [*row, "moved in units of its limit"]))
        elif max(abs(a), abs(b)) >= NOISE.get(unit, 0.0):
            change = abs(diff) / max(abs(a), abs(b))
            tiers.append((2, -change, key, [*row, "relative change"]))
    tiers.sort(key=lambda t: t[:3])
    once: dict[tuple[Any, ...], list[Any]] = {}
    for tier, _, _, row in tiers:  # one figure under two keys (summary and tracking) once
        if tier == 0 or len(once) < n:
            once.setdefault((row[5], row[1], row[2]), row)
    return list(once.values())


class CompareHeadline(TypedDict):
    """What compare says first (compare.json's ``headline``)."""

    lines: list[str]
    most_moved: list[list[Any]]  # :func:`most_moved`'s rows


class CompareRow(TypedDict):
    """One figure of both folders (compare.json's ``rows``)."""

    figure: str
    a: float | None
    b: float | None
    b_minus_a: float | None


class CompareFigure(TypedDict):
    """One overlay written (compare.json's ``figures``): its PNG and its data."""

    name: str
    title: str
    png: str
    data: str


class CompareDocument(TypedDict):
    """compare.json."""

    schema_version: int
    a: str
    b: str
    headline: CompareHeadline
    rows: list[CompareRow]
    figures: list[CompareFigure]


def compare_headline(
    fa: Folder, fb: Folder, a: dict[str, float], b: dict[str, float], rows: list[list[Any]]
) -> CompareHeadline:
    """What compare says first, with units: both folders' verdicts and every reason of each,
    D against D* and limits of (2), then the figures that moved most. Every number is one the
    two folders already hold."""
    va, vb = folder_verdict(fa), folder_verdict(fb)
    lines = [f"Verdict: A {_outcome(va)}, B {_outcome(vb)}."]
    lines += [why for n, v in (("A", va), ("B", vb)) if (why := _why(n, v))]
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
    return {"lines": lines, "most_moved": most_moved(rows, (va, vb))}


def build_compare(
    fa: Folder, fb: Folder, out: Path, label_a: str = "A", label_b: str = "B"
) -> CompareDocument:
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
    files: list[CompareFigure] = []
    for f in figs:
        png, csv_path = f.write(out, PREFIX)
        files.append({"name": f.name, "title": f.title, "png": png.name, "data": csv_path.name})
    data: CompareDocument = {
        "schema_version": COMPARE_SCHEMA_VERSION,
        "a": str(fa.path),
        "b": str(fb.path),
        "headline": head,
        "rows": [{"figure": r[0], "a": r[1], "b": r[2], "b_minus_a": r[3]} for r in rows],
        "figures": files,
    }
    write_json(out / "compare.json", data)
    # v~, w~ are explained only where a law has them (hil.law.facts.Law)
    sliding = any(Law(view(f.scenario).law).sliding_variables for f in (fa, fb))
    _write_pages(out, data, (la, lb), rows, figs, ct.SLIDING if sliding else "")
    return data


#: The headline's table in a reader's units (compare.json keeps SI): shares in %, seconds in ms.
_READABLE = {"fraction": (100.0, "%"), "s": (1e3, "ms")}


def _readable(cells: list[Any]) -> list[Any]:
    """[A, B, B − A, unit] scaled to the reader's unit of :data:`_READABLE`."""
    a, b, diff, unit = cells
    scale, shown = _READABLE.get(unit, (1.0, unit))
    return [*(None if x is None else x * scale for x in (a, b, diff)), shown]


def _write_pages(
    out: Path,
    data: CompareDocument,
    labels: tuple[str, str],
    rows: list[list[Any]],
    figs: list,
    sliding: str,
) -> None:
    """compare.md and compare.html: the headline first, then every figure and the overlays."""
    la, lb = labels
    head, files = data["headline"], data["figures"]
    fa, fb = data["a"], data["b"]
    header = ["figure", "key (compare.json)", la, lb, "B − A", "unit"]
    every = [[ct.label_of(k), k, a, b, d, ct.unit_of(k)] for k, a, b, d in rows]
    moved_header = ["figure", la, lb, "B − A", "unit", "against", "listed for"]
    moved = [[r[5], *_readable(r[1:5]), r[6], r[7]] for r in head["most_moved"]]
    md = [f"# Comparison: {fa} vs {fb}", "", *(f"- {t}" for t in head["lines"]), ""]
    md += ["## The figures that moved most", "", MOVED_NOTE, "", ct._md_table(moved_header, moved)]
    md += ["", "## Every figure", "", *([sliding, ""] if sliding else [])]
    md += [ct._md_table(header, every), ""]
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
        *([f"<p>{ct.esc(sliding)}</p>"] if sliding else []),
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
