"""``hil report DIR``: the sampling-effect report of one run or simulation folder.

Functional core, thin shell: :func:`analyse` turns a loaded folder into a plain dict (metrics,
certificate, verdict) and a list of figures; :func:`write_report` writes report.json,
report.md (figures as PNG + CSV beside it) and a self-contained report.html. summary.json is
only ever read.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from hil import analysis
from hil.report import figures as fg
from hil.report import timing_data
from hil.report.cert import certificate
from hil.report.folder import Folder
from hil.report.html import render_html
from hil.report.markdown import render_markdown
from hil.report.scenario_view import ScenarioView, view

SCHEMA_VERSION = 1
FIGURE_PREFIX = "report_"
IdealProvider = Callable[[Folder], dict[str, np.ndarray] | None]


@dataclass(frozen=True)
class Thresholds:
    """When timing trouble turns the verdict negative (limits and certificate always do)."""

    max_deadline_miss_ratio: float = 0.01
    max_lost_ratio: float = 0.01


@dataclass
class Report:
    data: dict[str, Any]
    figures: list[fg.Figure] = field(default_factory=list)

    @property
    def negative(self) -> bool:
        return not self.data["verdict"]["ok"]


def _timing_gap_delay(folder: Folder, sv: ScenarioView) -> tuple[float, float, str]:
    """The Ts and delta the certificate is evaluated at: a run's measured worst gap between
    applied samples and worst sample-to-apply latency; a simulation's scenario values."""
    if folder.kind == "run":
        gap, delay = timing_data.worst_gap_and_delay(folder, sv.ts)
        if gap is not None:
            return gap, (delay if delay is not None else sv.worst_delay), "measured"
    return sv.ts, sv.worst_delay, "scenario"


def _counts(summary: dict[str, Any]) -> dict[str, int | None]:
    """Message counts and deadline misses wherever the summary keeps them."""
    found: dict[str, int | None] = {
        "sent": None,
        "received": None,
        "lost": None,
        "deadline_misses": None,
        "cycles": None,
    }

    def visit(obj: Any, depth: int = 0) -> None:
        if not isinstance(obj, dict) or depth > 3:
            return
        for key, value in obj.items():
            if isinstance(value, dict):
                visit(value, depth + 1)
                continue
            if not isinstance(value, int | float) or isinstance(value, bool):
                continue
            k = key.lower()
            for name in found:
                if k == name or k.endswith("_" + name) or (name == "cycles" and k == "samples"):
                    found[name] = int((found[name] or 0) + value)

    visit({k: v for k, v in summary.items() if k != "timing"})
    timing = summary.get("timing")
    if isinstance(timing, dict) and isinstance(timing.get("deadline_misses"), int):
        found["deadline_misses"] = timing["deadline_misses"]
        rate = timing.get("deadline_miss_rate")
        if isinstance(rate, float) and rate > 0:
            found["cycles"] = round(timing["deadline_misses"] / rate)
    return found


def verdict_block(
    cons: dict[str, Any],
    summary: dict[str, Any],
    cert: dict[str, Any],
    counts: dict[str, int | None],
    thresholds: Thresholds,
) -> dict[str, Any]:
    """The verdict rules of docs/reports.md. Negative when (a) a constraint of (2) is broken
    (summary.json's violations, which count every plant step, or the trace's peaks), (b) the
    certificate is not held at the loop's timing or a measured |v| / |omega| exceeds its
    bound, (c) deadline misses or lost messages exceed their thresholds."""
    reasons: list[str] = []
    violations = summary.get("violations") or {}
    broken = sorted(
        {k for k, n in violations.items() if isinstance(n, int | float) and n > 0}
        | {k for k, c in cons.items() if not c["held"]}
    )
    if broken:
        reasons.append("limits broken: " + ", ".join(broken))
    cert_state = "not applicable"
    if cert["held"] is not None:
        beyond = [k for k in ("v", "omega") if cons[k]["within_bound"] is False]
        if beyond:
            cert_state = "broken"
            reasons.append("measured beyond the sampled-data bound: " + ", ".join(beyond))
        elif not cert["held"]:
            cert_state = "not held"
            reasons.append(
                f"certificate not held at Ts={cert['ts']:.6g} s, delay={cert['delay']:.6g} s"
            )
        else:
            cert_state = "held"
    misses, cycles = counts.get("deadline_misses"), counts.get("cycles")
    if misses:
        ratio = misses / cycles if cycles else 1.0
        if ratio > thresholds.max_deadline_miss_ratio:
            reasons.append(f"deadline misses {misses} ({ratio:.2%})")
    lost, sent = counts.get("lost"), counts.get("sent")
    if lost:
        ratio = lost / sent if sent else 1.0
        if ratio > thresholds.max_lost_ratio:
            reasons.append(f"lost messages {lost} ({ratio:.2%})")
    return {
        "ok": not reasons,
        "limits": "broken" if broken else "held",
        "limits_broken": broken,
        "certificate": cert_state,
        "deadline_misses": misses,
        "lost_messages": lost,
        "reasons": reasons,
        "thresholds": {
            "max_deadline_miss_ratio": thresholds.max_deadline_miss_ratio,
            "max_lost_ratio": thresholds.max_lost_ratio,
        },
    }


def analyse(
    folder: Folder,
    *,
    ideal: IdealProvider | None = None,
    thresholds: Thresholds = Thresholds(),
) -> Report:
    sv = view(folder.scenario)
    tr = folder.trace
    gap, delay, timing_source = _timing_gap_delay(folder, sv)
    cert = certificate(sv, gap, delay).as_dict()
    cert["timing_source"] = timing_source
    ideal_traj, ideal_note = None, "not requested"
    if ideal is not None:
        if tr["t"][0] > 2.0 * sv.ts:
            # A run's clock starts before its first sample (start-up): the reference has moved
            # on while the robot waited, so a simulation from t = 0 is not the same loop.
            ideal_note = f"not comparable: the trace starts at t = {tr['t'][0]:.3f} s"
        else:
            ideal_traj = ideal(folder)
            ideal_note = "simulated at Ts/10" if ideal_traj is not None else "no simulator"
    sliding = None
    if not {"v_tilde", "w_tilde"} <= set(tr) and folder.recordings:
        from hil.report.mcap_timing import sliding_from_recordings

        rec = sliding_from_recordings(folder.recordings)
        epoch = timing_data.epoch_ns(folder)
        if rec:
            base = epoch if epoch is not None else int(rec["v_tilde"][0][0])
            sliding = {k: ((tn - base) / 1e9, vals) for k, (tn, vals) in rec.items()}
    lim = sv.limits
    metrics = analysis.sampling_effects(
        tr,
        phi1=lim.phi1,
        phi2=lim.phi2,
        varpi1=lim.varpi1,
        varpi2=lim.varpi2,
        v_bound=cert["v_bound"],
        w_bound=cert["w_bound"],
        eps1=sv.eps1,
        eps2=sv.eps2,
        ideal=ideal_traj,
        sliding=sliding,
    )
    metrics["deviation_from_ideal_note"] = ideal_note
    metrics["bands_source"] = (
        "trace.csv" if "v_tilde" in tr else ("recorded telemetry" if sliding else "unavailable")
    )
    # summary.json's peaks cover every plant step, the trace only control samples: take both.
    for key, skey in (
        ("v", "max_abs_v"),
        ("omega", "max_abs_omega"),
        ("tau1", "max_abs_tau1"),
        ("tau2", "max_abs_tau2"),
    ):
        peak = folder.summary.get(skey)
        if isinstance(peak, int | float) and math.isfinite(peak):
            c = metrics["constraints"][key]
            if peak > c["peak"]:
                fig = analysis.ConstraintFigure(key, float(peak), c["limit"], c["bound"])
                metrics["constraints"][key] = fig.as_dict()
    counts = _counts(folder.summary)
    verdict = verdict_block(metrics["constraints"], folder.summary, cert, counts, thresholds)
    timing = timing_data.collect(folder)
    sections = ["trajectory", "velocities", "torques", "tracking_error", "bands"]
    figs = _trace_figures(tr, sv, cert, ideal_traj, sliding)
    if timing.latency:
        figs.append(
            fg.histogram_and_cdf("latency", "Sample-to-apply latency per path", timing.latency)
        )
        sections.append("latency")
    if timing.lateness:
        figs.append(
            fg.over_time("lateness", "Wake-up lateness and jitter over time", "µs", timing.lateness)
        )
        sections.append("lateness")
    if folder.summary.get("timing"):
        sections.append("timing_summary")
    sections.append("verdict")
    data = {
        "schema_version": SCHEMA_VERSION,
        "folder": str(folder.path),
        "kind": folder.kind,
        "scenario": {
            "law": sv.law,
            "ts": sv.ts,
            "delay": sv.delay,
            "jitter": sv.jitter,
            "jitter_kind": sv.jitter_kind,
            "limits": {
                "phi1": lim.phi1,
                "phi2": lim.phi2,
                "varpi1": lim.varpi1,
                "varpi2": lim.varpi2,
            },
        },
        "sections": sections,
        "metrics": metrics,
        "certificate": cert,
        "timing": {
            "summary": folder.summary.get("timing"),
            "latency_percentiles_us": {
                k: analysis.percentiles(v) for k, v in timing.latency.items() if len(v)
            },
            "lateness_percentiles_us": {
                k: analysis.percentiles(v[1]) for k, v in timing.lateness.items() if len(v[1])
            },
            "source": timing.source,
        },
        "counts": counts,
        "verdict": verdict,
        "summary": {k: v for k, v in folder.summary.items() if not isinstance(v, dict | list)},
    }
    return Report(data, figs)


def _trace_figures(
    tr: dict[str, np.ndarray],
    sv: ScenarioView,
    cert: dict[str, Any],
    ideal_traj: dict[str, np.ndarray] | None,
    sliding: dict[str, tuple[np.ndarray, np.ndarray]] | None = None,
) -> list[fg.Figure]:
    t = tr["t"]
    lim = sv.limits
    traj = [("robot", tr["x"], tr["y"]), ("reference", tr["xd"], tr["yd"])]
    if ideal_traj is not None:
        traj.append(("ideal (fine period)", ideal_traj["x"], ideal_traj["y"]))
    out = [
        fg.trajectory(traj),
        fg.signal_with_limits(
            "v", "Linear velocity v", "v [m/s]", t, [("v", tr["v"])], lim.phi1, cert["v_bound"]
        ),
        fg.signal_with_limits(
            "omega",
            "Angular velocity ω",
            "ω [rad/s]",
            t,
            [("omega", tr["omega"])],
            lim.phi2,
            cert["w_bound"],
        ),
        fg.signal_with_limits(
            "tau1", "Torque τ1", "τ1 [N·m]", t, [("tau1", tr["tau1"])], lim.varpi1
        ),
        fg.signal_with_limits(
            "tau2", "Torque τ2", "τ2 [N·m]", t, [("tau2", tr["tau2"])], lim.varpi2
        ),
    ]
    pos = analysis.position_error(tr["x"], tr["y"], tr["xd"], tr["yd"])
    head = analysis.heading_error(tr["theta"], tr["thetad"])
    err_series = [("position error [m]", pos), ("heading error [rad]", head)]
    if ideal_traj is not None:
        dev = analysis.deviation_from_ideal(
            t, tr["x"], tr["y"], ideal_traj["t"], ideal_traj["x"], ideal_traj["y"]
        )
        err_series.append(("deviation from ideal [m]", dev))
    out.append(
        fg.signal_with_limits("tracking_error", "Tracking error (4)", "error", t, err_series)
    )
    band_series = [(name, tr[name]) for name in ("v_tilde", "w_tilde") if name in tr]
    if not band_series and sliding:
        out.append(
            fg.over_time("bands", "Sliding variables v~, w~ (recorded telemetry)", "value", sliding)
        )
    if band_series:
        out.append(
            fg.signal_with_limits(
                "bands", "Sliding variables v~, w~ (quasi-sliding band)", "value", t, band_series
            )
        )
    return out


def write_report(report: Report, out: Path) -> dict[str, Path]:
    """report.json, report.md with PNG/CSV figures beside it, report.html (self-contained)."""
    out.mkdir(parents=True, exist_ok=True)
    files: list[dict[str, str]] = []
    for f in report.figures:
        png, csv_path = f.write(out, FIGURE_PREFIX)
        files.append({"name": f.name, "title": f.title, "png": png.name, "data": csv_path.name})
    data = dict(report.data)
    data["figures"] = files
    (out / "report.json").write_text(json.dumps(_jsonable(data), indent=2, allow_nan=False))
    (out / "report.md").write_text(render_markdown(data, files))
    (out / "report.html").write_text(render_html(data, report.figures))
    return {"json": out / "report.json", "md": out / "report.md", "html": out / "report.html"}


def _jsonable(obj: Any) -> Any:
    """Non-finite floats become strings so report.json stays strict JSON."""
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, float | np.floating):
        return float(obj) if math.isfinite(obj) else repr(float(obj))
    if isinstance(obj, np.integer):
        return int(obj)
    if isinstance(obj, np.bool_):
        return bool(obj)
    return obj
