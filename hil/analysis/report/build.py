"""``hil report DIR``: :func:`build_report` turns a loaded run or simulation folder into a plain
dict (headline, metrics, certificate, verdict) and figures; :func:`write_report` writes
report.json, report.md (PNG + CSV figures beside it) and a self-contained report.html.

Where the numbers come from (docs/reports.md): a run's certificate, timing figures and message
counts are summary.json's, which ``hil run`` took from :mod:`hil.analysis.measure`; the plots draw
that pipeline's per-sample series (series.npz; :func:`hil.analysis.measure.folder.measured`).
summary.json is only ever read, and the report computes no figure of its own. A simulation folder
(no hop logs) is certified at its scenario's timing
(:func:`hil.sim.certificate.scenario_certificate`).
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from dataclasses import asdict, fields
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from hil.analysis import trace_metrics
from hil.analysis.margin import record as margin_record
from hil.analysis.measure.age import envelope
from hil.analysis.measure.figures import Measurement
from hil.analysis.measure.folder import measured
from hil.analysis.report import figures as fg
from hil.analysis.report.clockplot import clock_png
from hil.analysis.report.content import SIGNALS, TITLES, headline, render_html, render_markdown
from hil.analysis.report.device import NO_D_ON_CAN, add_device
from hil.analysis.report.ideal import IdealUnavailableError
from hil.analysis.report.ideal_sim import WINDOW_S
from hil.analysis.report.telemetry import SLIDING, folder_telemetry, forget_memory
from hil.folder import RunFolder as Folder
from hil.folder import layout
from hil.folder.clocks import read_track
from hil.folder.jsonio import write_json
from hil.folder.layout import REPORT_HTML, REPORT_JSON, REPORT_MD
from hil.folder.records import (
    Certificate,
    DrivesBlock,
    Metrics,
    ReportData,
    ScenarioBlock,
    Summary,
)
from hil.folder.scenario_view import ScenarioView, view
from hil.limits import ConstraintFigure
from hil.sim.certificate import no_certificate, scenario_certificate
from hil.verdict import (
    DEFAULT_THRESHOLDS,
    LIMIT_NAMES,
    PEAK_KEYS,
    LawEnd,
    RunFacts,
    Thresholds,
    Verdict,
    judge,
)
from protocol.can.wheel_mapping import RobotGeometry, motor_torque_limit, motor_torques
from protocol.settings import CMD_PATHS
from protocol.versions import REPORT_SCHEMA_VERSION

FIGURE_PREFIX = "report_"
SOURCE = "summary.json and series.npz (hil.measure, measured once when the run ended)"
#: Named columns (a trace, the ideal trajectory); the sliding variables: name -> (t s, values).
Columns = dict[str, np.ndarray]
Sliding = dict[str, tuple[np.ndarray, np.ndarray]]
IdealProvider = Callable[[Folder], Columns | None]
_GEOMETRY = [f.name for f in fields(RobotGeometry)]


class Report(NamedTuple):
    data: ReportData
    figures: list[fg.Figure]


def drives_block(folder: Folder, sv: ScenarioView) -> tuple[DrivesBlock, np.ndarray | None]:
    """The motor torques (N·m) the wheel mapping of [robot] makes of the applied tau1, tau2
    (protocol.can.wheel_mapping.motor_torques), the drives' states and the rejection counts."""
    robot = folder.scenario.get("robot") or {}
    out: DrivesBlock = {"geometry": None, "note": ""}
    q = None
    try:
        g = RobotGeometry(**{k: float(robot[k]) for k in _GEOMETRY if k in robot})
    except (TypeError, ValueError) as exc:
        out["note"] = f"no wheel mapping: [robot] is not a geometry ({exc})"
    else:
        tr = folder.trace
        qr, ql = motor_torques(g, tr["tau1"], tr["tau2"])
        q = np.vstack([qr, ql])
        out["geometry"] = asdict(g)
        out["motor_torque_limit_nm"] = motor_torque_limit(g, sv.limits.varpi1, sv.limits.varpi2)
        out["max_abs_q_right_nm"] = float(np.nanmax(np.abs(qr)))
        out["max_abs_q_left_nm"] = float(np.nanmax(np.abs(ql)))
    for key in ("can", "rejections"):
        got = folder.summary.get(key)
        out[key] = got if isinstance(got, dict) else None
    rej = out["rejections"]
    out["rejection_counts"] = None if rej is None else {k: _count(v) for k, v in rej.items()}
    return out, q


def can_ran(drives: DrivesBlock) -> bool:
    """True when the folder's run had CAN drives (summary.json's ``can`` holds a side's
    counters): a simulation or a ``--no-can`` run has none, and no page section for them."""
    can = drives.get("can")
    return isinstance(can, dict) and any(isinstance(v, dict) and v for v in can.values())


def _count(obj: Any) -> int:
    """The sum of every count in a (nested) rejection dict."""
    if isinstance(obj, dict):
        return sum(_count(v) for v in obj.values())
    return int(obj) if isinstance(obj, int | float) and not isinstance(obj, bool) else 0


def build_report(
    folder: Folder,
    *,
    ideal: IdealProvider | None = None,
    thresholds: Thresholds = DEFAULT_THRESHOLDS,
    verdict: Verdict | None = None,
) -> Report:
    """The report of one run or simulation folder: metrics, certificate, verdict, figures;
    ``verdict``: the one the analysis judged already (``hil run``'s summary.json), not judged
    again."""
    sv = view(folder.scenario, parsed=folder.typed_scenario())
    m = measured(folder)  # first: its peak (the hop logs' columns) before the trace's
    tr = folder.trace
    kind = "run" if m is not None else folder.kind
    cert = _folder_certificate(sv, m, kind, folder.summary)
    ideal_traj, ideal_note = None, "not requested"
    if ideal is not None:
        try:
            ideal_traj = ideal(folder)
            ideal_note = _ideal_note(ideal_traj, tr)
        except IdealUnavailableError as exc:
            ideal_note = str(exc)
        forget_memory(folder)
    sliding = _recorded_sliding(folder, tr, m)
    metrics = _metrics(folder, sv, cert, (ideal_traj, ideal_note), sliding)
    # hil.verdict.judge: the one implementation hil run also uses, with the report's thresholds
    timing, messages = (m.timing, m.messages or {}) if m is not None else (None, None)
    violations, facts = folder.summary.get("violations") or {}, RunFacts.of(folder.summary)
    ended = LawEnd.of(folder.summary)  # the law's fault, the controller's end, a NaN state
    saved = folder.summary.get("verdict")
    judged = isinstance(saved, dict) and bool(saved.get("outcome"))
    if verdict is None and thresholds == DEFAULT_THRESHOLDS and judged:
        verdict = Verdict.from_dict(saved)  # judged once, by the analysis (run, recover)
    if verdict is None:
        verdict = judge(
            metrics["constraints"], violations, cert, timing, messages, facts, thresholds, ended,
            m.device if m is not None else None,
        )  # fmt: skip
    margin = margin_record.read(folder.path)  # hil margin's record, None if it never ran
    drives, q = drives_block(folder, sv)
    figs, sections = _figures(folder, sv, cert, m, (ideal_traj, sliding), q, drives, metrics)
    data = {
        "schema_version": REPORT_SCHEMA_VERSION,
        "folder": str(folder.path),
        "kind": kind,
        "scenario": _scenario_block(sv),
        "sections": sections,
        "metrics": metrics,
        "certificate": cert,
        "drives": drives,
        "timing": {
            "summary": timing,
            "messages": messages,
            "source": SOURCE if m is not None else None,
            "applied_path": cert.get("path"),
            "series": "series.npz (hil.measure)" if m is not None else None,
            **{k: folder.summary.get(k) for k in ("faults", "scheduling", "impair")},
        },
        "verdict": verdict.as_dict(),
        "margin": None if margin is None else margin.to_dict(),
        "summary": {k: v for k, v in folder.summary.items() if not isinstance(v, dict | list)},
    }
    _add_topology(folder.path, data, figs)  # "Where it ran", for a run across lab hosts
    add_device(data, m.device if m is not None else None)  # "The device at the bus"
    data["headline"] = headline(data, folder.summary)
    return Report(data, figs)


def _add_topology(folder: Path, data: ReportData, figs: list[fg.Figure]) -> None:
    """The "Where it ran" section of a run across lab hosts (``topology.json``, with report.json's
    ``topology``) and the clock figure, when the run has estimates; nothing for one host."""
    try:
        topo = json.loads((folder / layout.TOPOLOGY).read_text())
    except (OSError, ValueError):
        return
    if not isinstance(topo, dict) or not isinstance(topo.get("processes"), dict):
        return
    hosts, procs = topo.get("hosts") or {}, topo["processes"]
    injected = [h.get("offset_s") for h in hosts.values()]
    plant, ctrl = ((hosts.get(procs.get(p)) or {}).get("offset_s") for p in ("plant", "controller"))
    numbers = isinstance(plant, int | float) and isinstance(ctrl, int | float)
    difference = float(plant) - float(ctrl) if numbers else None
    data["topology"] = {**topo, "injected_offsets_s": injected, "injected_difference_s": difference}
    sections = data["sections"]
    at = sections.index("latency") if "latency" in sections else len(sections)
    sections.insert(at, "topology")
    track = read_track(folder)
    if (png := clock_png(track)) is not None:
        columns = {
            "t_s": (track.at_ns - track.at_ns[0]) / 1e9,
            "offset_ns": track.offset_ns.astype(float),
            "uncertainty_ns": track.uncertainty_ns.astype(float),
        }
        caption = "Offset estimates of the controller's clock to the plant's, with uncertainty."
        figs.append(fg.Figure("clock_offset", "Clock offset over the run", png, columns, caption))


def _folder_certificate(
    sv: ScenarioView, m: Measurement | None, kind: str, summary: Summary
) -> Certificate:
    """A run's certificate (a copy of summary.json's: the report never edits it), with where it
    came from and the design conditions failing at its D; else the simulation's."""
    if m is not None and m.certificate is None and m.device is not None and m.device.outside:
        # An outside device on CAN: a frame names no State, D is not measured (a lower bound
        # of the age at landing is, in "The device at the bus").
        return dict(no_certificate(m.device.path, None, NO_D_ON_CAN))
    if m is not None and m.certificate is None:
        # No certificate in the run (not a unified law): D is still measured.
        path = str(m.series["applied_path"]) if m.series.get("applied_path") else None
        age = m.timing.get(f"command_age_{path}") if path else None
        d = age.get("max_us") / 1e6 if isinstance(age, dict) and age.get("max_us") else None
        note = f"none (law {sv.law} has no certificate); D from {SOURCE}"
        return dict(no_certificate(path, d, note))
    if m is not None:
        cert = json.loads(json.dumps(m.certificate))
        cert["source"] = SOURCE
        cert.setdefault("failed_conditions", [])
        return cert
    saved = summary.get("certificate")
    if isinstance(saved, dict):  # a simulation's, computed once by hil sim
        return {**saved, "source": saved.get("source") or "summary.json (hil sim)"}
    cert = scenario_certificate(sv)  # a folder written before simulations saved theirs
    if kind == "run":  # a run folder from before hil.analysis.measure: neither hop logs nor figures
        cert["source"] = "scenario (the run has no hop logs and no measured certificate)"
    return cert


def _recorded_sliding(folder: Folder, tr: Columns, m: Measurement | None) -> Sliding | None:
    """v~, w~ from the recorded telemetry (time in s from the run's epoch) when the trace
    lacks them, else None."""
    if {"v_tilde", "w_tilde"} <= set(tr) or not folder.recordings:
        return None
    tel = folder_telemetry(folder)
    if not all(k in tel for k in SLIDING):
        return None
    base = m.epoch_ns if m is not None and m.epoch_ns else int(tel["v_tilde"][0][0])
    return {k: ((tel[k][0] - base) / 1e9, tel[k][1]) for k in SLIDING}


def _metrics(
    folder: Folder,
    sv: ScenarioView,
    cert: Certificate,
    ideal: tuple[Columns | None, str],
    sliding: Sliding | None,
) -> Metrics:
    """The sampling-effect metrics of the trace (against the ideal simulation and its note),
    with summary.json's peaks folded in."""
    tr = folder.trace
    ideal_traj, ideal_note = ideal
    extra = {"v_bound": cert.get("v_bound"), "w_bound": cert.get("omega_bound")}
    extra |= {"eps1": sv.eps1, "eps2": sv.eps2, "ideal": ideal_traj, "sliding": sliding}
    metrics = trace_metrics.sampling_effects(tr, **asdict(sv.limits), **extra)
    metrics["deviation_from_ideal_note"] = ideal_note
    metrics["bands_source"] = (
        "trace.csv" if "v_tilde" in tr else ("recorded telemetry" if sliding else "unavailable")
    )
    # summary.json's peaks cover every plant step, the trace only control samples: take both.
    for key, skey in PEAK_KEYS.items():
        peak, c = folder.summary.get(skey), metrics["constraints"][key]
        if isinstance(peak, int | float) and math.isfinite(peak) and peak > c["peak"]:
            fig = ConstraintFigure(key, float(peak), c["limit"], c["bound"])
            metrics["constraints"][key] = fig.as_dict()
    return metrics


def _scenario_block(sv: ScenarioView) -> ScenarioBlock:
    out = {k: getattr(sv, k) for k in ("law", "ts", "delay", "jitter", "jitter_kind")}
    return {**out, "limits": asdict(sv.limits), "eps1": sv.eps1, "eps2": sv.eps2}


def _ideal_note(ideal_traj: Columns | None, tr: Columns) -> str:
    if ideal_traj is None:
        return "no simulator"
    starts = ideal_traj.get("window_start_t")
    if starts is None:
        return f"simulated at Ts/10 from the trace's first state at t = {tr['t'][0]:.6g} s"
    return (
        f"windowed: simulated at Ts/10 in {len(starts)} windows of {WINDOW_S:g} s, each "
        f"restarted from the robot's state (and the law's recorded memory, where the folder "
        f"has it) at its first sample, from t = {tr['t'][0]:.6g} s; the deviation is measured "
        f"within each window"
    )


def _figures(
    folder: Folder,
    sv: ScenarioView,
    cert: Certificate,
    m: Measurement | None,
    extra: tuple[Columns | None, Sliding | None],
    q: np.ndarray | None,
    drives: DrivesBlock,
    metrics: Metrics,
) -> tuple[list[fg.Figure], list[str]]:
    """Every figure, and the report's sections in order (see hil.analysis.report.content);
    ``extra``: the ideal trajectory and the recorded sliding variables, where there are."""
    tr = folder.trace
    ideal_traj, sliding = extra
    figs = _state_figures(tr, sv, cert, ideal_traj)
    for name in ("tau1", "tau2"):  # switching bands, with the metrics' rate and saturation
        rate, share = metrics["switching_rate"].get(name), metrics["saturation_share"].get(name)
        note = ""
        if rate is not None and share is not None:
            note = f"It switches {rate:.0f} times a second, at its limit {share:.1%} of the time."
        limit, series = getattr(sv.limits, LIMIT_NAMES[name]), [(name, tr[name])]
        figs.append(
            fg.switching_band(name, TITLES[name], SIGNALS[name], tr["t"], series, limit, note)
        )
    figs.append(_tracking_error_figure(tr, ideal_traj))
    panels = []
    for name, eps, unit in (("v_tilde", sv.eps1, "v~ [m/s]"), ("w_tilde", sv.eps2, "w~ [rad/s]")):
        t_y = (tr["t"], tr[name]) if name in tr else (sliding or {}).get(name)
        if t_y is not None:
            panels.append((name, unit, *t_y, eps))
    if panels:
        src = "trace" if "v_tilde" in tr else "recorded telemetry"
        figs.append(fg.stacked("bands", f"Sliding variables v~ and w~ of (10) ({src})", panels))
    can = can_ran(drives)  # no section, no figure for a path that did not run
    if q is not None and can:
        title = "Motor torques sent to the drives (wheel mapping of [robot])"
        series, limit = [("right", q[0]), ("left", q[1])], drives.get("motor_torque_limit_nm")
        figs.append(fg.switching_band("motor_torques", title, "q [N·m]", tr["t"], series, limit))
    sections = ["headline", "terms", "verdict", "certificate", "trajectory", "velocities"]
    sections += ["torques", *(["drives"] if can else []), "tracking_error", "bands"]
    if m is not None:
        figs += _run_figures(m, cert)
        sections += ["latency", "lateness", "messages", "timing_summary"]
    return figs, sections


def _state_figures(
    tr: Columns, sv: ScenarioView, cert: Certificate, ideal_traj: Columns | None
) -> list[fg.Figure]:
    """The trajectory and the velocities against (2) and their bounds."""
    traj = [("reference", tr["xd"], tr["yd"]), ("robot", tr["x"], tr["y"])]
    if ideal_traj is not None:
        again = ", restarted every window" if "window_start_t" in ideal_traj else ""
        traj.append((f"ideal (Ts/10, no delay{again})", ideal_traj["x"], ideal_traj["y"]))
    figs = [fg.trajectory(traj)]
    for key, bound in (("v", cert.get("v_bound")), ("omega", cert.get("omega_bound"))):
        limit, series = getattr(sv.limits, LIMIT_NAMES[key]), [(key, tr[key])]
        figs.append(
            fg.signal_with_limits(key, TITLES[key], SIGNALS[key], tr["t"], series, limit, bound)
        )
    return figs


def _tracking_error_figure(tr: Columns, ideal_traj: Columns | None) -> fg.Figure:
    """Position and heading errors (4), and the deviation from the ideal simulation."""
    t = tr["t"]
    pos = trace_metrics.position_error(tr["x"], tr["y"], tr["xd"], tr["yd"])
    head = trace_metrics.heading_error(tr["theta"], tr["thetad"])
    err_series = [("position error [m]", pos), ("heading error [rad]", head)]
    if ideal_traj is not None:
        dev = trace_metrics.deviation_from_ideal(
            t, tr["x"], tr["y"], ideal_traj["t"], ideal_traj["x"], ideal_traj["y"]
        )
        err_series.append(("deviation from ideal [m]", dev))
    return fg.signal_with_limits("tracking_error", "Tracking error (4)", "error", t, err_series)


def _run_figures(m: Measurement, cert: Certificate) -> list[fg.Figure]:
    """Latency histograms/CDFs, wake-up lateness and command age over time, all from the
    measurement's per-sample series."""
    figs = []
    applied = cert.get("path")
    if lat := m.latency_us():
        title = "Sample-to-apply latency per path"
        if applied:
            title += f" (applied: {applied}; the other path is a shadow)"
        figs.append(fg.histogram_and_cdf("latency", title, lat))
    late = {}
    for key, label in (
        ("wakeup_lateness", "controller wake-up lateness"),
        ("plant_wakeup_lateness", "plant wake-up lateness"),
    ):
        series = m.series.get(key)
        if series is not None and len(series[0]):
            # ns -> µs in one allocation (an hour at 1 kHz: 29 MB a series, not three times that)
            late[label] = (np.asarray(series[0], float), np.divide(series[1], 1e3, dtype=float))
    if late:
        figs.append(fg.over_time("lateness", "Wake-up lateness over time", "µs", late))
    env = {}
    for p in sorted(CMD_PATHS, key=lambda p: p != applied):  # the applied path first
        seg = m.series.get(f"command_age_{p}")
        if seg is not None and len(seg) and m.epoch_ns is not None:
            env[f"{p} ({'applied' if p == applied else 'shadow'})"] = envelope(seg, m.epoch_ns)
    if env:
        stalls = [(s["t_s"], s["age_s"]) for s in cert.get("stalls") or []]
        title = "Command age over time (age of the command in force at each plant step)"
        lines = (cert.get("d_star_s"), cert.get("stall_threshold_s"))
        figs.append(fg.age_envelope("command_age", title, env, *lines, stalls))
    return figs


def write_report(report: Report, out: Path) -> dict[str, Path]:
    """report.json, report.md with PNG/CSV figures beside it, report.html (self-contained)."""
    out.mkdir(parents=True, exist_ok=True)
    files: list[dict[str, str]] = []
    for f in report.figures:
        png, csv_path = f.write(out, FIGURE_PREFIX)
        entry = {"name": f.name, "title": f.title, "png": png.name, "data": csv_path.name}
        files.append(entry | ({"caption": f.caption} if f.caption else {}))
    data = {**report.data, "figures": files}
    paths = {"json": out / REPORT_JSON, "md": out / REPORT_MD, "html": out / REPORT_HTML}
    write_json(paths["json"], data)
    paths["md"].write_text(render_markdown(data, files))
    paths["html"].write_text(render_html(data, report.figures))
    return paths


def folder_verdict(folder: Folder, thresholds: Thresholds = DEFAULT_THRESHOLDS) -> Verdict:
    """The folder's verdict: summary.json's (``hil run`` judged it), else judged here as
    :func:`build_report` judges (a simulation, a folder the report alone judged), without the
    ideal trajectory or any figure."""
    saved = folder.summary.get("verdict")
    if isinstance(saved, dict) and saved.get("outcome"):
        return Verdict.from_dict(saved)
    sv = view(folder.scenario, parsed=folder.typed_scenario())
    m = measured(folder)
    kind = "run" if m is not None else folder.kind
    cert = _folder_certificate(sv, m, kind, folder.summary)
    metrics = _metrics(folder, sv, cert, (None, "not requested"), None)
    timing, messages = (m.timing, m.messages or {}) if m is not None else (None, None)
    verdict = judge(
        metrics["constraints"],
        folder.summary.get("violations") or {},
        cert,
        timing,
        messages,
        RunFacts.of(folder.summary),
        thresholds,
        LawEnd.of(folder.summary),
    )
    return verdict
