"""Turn the services' hop logs into the run folder's trace.csv and summary.json: the analysis of
a run the bench recorded (:class:`hil.folder.records.Recorded`; ``hil run`` and ``hil recover``
call it after the bench, :mod:`hil.commands.run`, :mod:`hil.commands.recover`).

Every timing figure, message count and the certificate come from :mod:`hil.analysis.measure` (one
pipeline, definitions in docs/realtime.md); this module adds the trace (one row per plant
sample) and the run's outcome (errors, extremes, violations over every plant step).
"""

from __future__ import annotations

import csv
import math
import operator
import sys
from collections.abc import Mapping
from pathlib import Path
from typing import Any, cast

import numpy as np

from controller_service.laws.guard import LawFault
from hil import interrupts
from hil.analysis.measure.figures import Measurement
from hil.analysis.measure.folder import measure_and_save, resolved_scenario
from hil.analysis.measure.logs import TRACE_SOURCE_COLUMNS, RunLogs, load_folder_logs
from hil.analysis.measure.reactions import reactions
from hil.analysis.report.clockplot import write_clock_plot
from hil.analysis.report.figures import envelope_indices, plt
from hil.errors import BadInputError
from hil.folder import layout, write_summary
from hil.folder.device import DeviceFigures
from hil.folder.jsonio import read_json_object
from hil.folder.records import LawFaultRecord, Recorded, Summary, VerdictRecord
from hil.folder.scenario_view import as_resolved
from hil.folder.trace_csv import read_trace
from hil.limits import LIMIT_NAMES, PEAK_KEYS
from hil.trace import COMMAND_COLUMNS, TRACE_COLUMNS
from hil.verdict import LawEnd, RunFacts, constraints_from_peaks, judge
from protocol.angles import wrap_angle as wrap
from protocol.hoplog import TICK_NO_SEND
from protocol.versions import RUN_SCHEMA_VERSION as SCHEMA_VERSION


def _commanded_by_sample(logs: RunLogs, seqs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Torques the controller computed from each state seq of ``seqs`` (first tick; NaN: none)."""
    t = logs["ticks"]
    used = (t["state_seq"] >= 0) & ((t["flags"] & TICK_NO_SEND) == 0) & (t["state_sample_ns"] > 0)
    known, first = np.unique(t["state_seq"][used], return_index=True)
    tau1, tau2 = t["tau1"][used][first], t["tau2"][used][first]
    c1, c2 = np.full((2, seqs.size), np.nan)
    if known.size:
        at = np.minimum(np.searchsorted(known, seqs), known.size - 1)
        hit = known[at] == seqs
        c1[hit], c2[hit] = tau1[at[hit]], tau2[at[hit]]
    return c1, c2


TRACE_CHUNK_ROWS = 16_384


def write_trace(
    run_dir: Path, logs: RunLogs, reference: Any, ts: float, lockstep: bool
) -> tuple[np.ndarray, float]:
    """trace.csv: one row per plant sample; returns (position errors, last heading error).

    Column by column, a chunk of rows at a time (the text of one ``csv`` row per sample), so
    linear in the run's length; the reference sampled per row with its own ``sample`` (exactly
    the controller's values)."""
    s = logs["samples"]
    seq_all = s["seq"]
    c1_all, c2_all = _commanded_by_sample(logs, seq_all)
    n = seq_all.size
    pos_err = np.empty(n)
    head_err = 0.0
    with (run_dir / layout.TRACE).open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow([*TRACE_COLUMNS, *COMMAND_COLUMNS, "sample_ns", "state_seq"])
        for r0 in range(0, n, TRACE_CHUNK_ROWS):
            r1 = min(n, r0 + TRACE_CHUNK_ROWS)
            seq = seq_all[r0:r1]
            sample_ns = s["sample_ns"][r0:r1]
            t = seq * ts if lockstep else (sample_ns - logs.epoch_ns) / 1e9
            refs = [reference.sample(tk) for tk in t.tolist()]
            xd, yd, thd = ([getattr(r, k) for r in refs] for k in ("xd", "yd", "thetad"))
            x, y, th, v, om = (s[k][r0:r1].tolist() for k in ("x", "y", "theta", "v", "omega"))
            pos_err[r0:r1] = list(map(math.hypot, map(operator.sub, x, xd),
                                      map(operator.sub, y, yd)))  # fmt: skip
            head_err = wrap(th[-1] - thd[-1])
            floats = [t.tolist(), x, y, th, v, om, xd, yd, thd]
            floats += [col[r0:r1].tolist() for col in (s["tau1"], s["tau2"], c1_all, c2_all)]
            cells = [list(map(repr, map(float, col))) for col in floats]
            cells += [list(map(str, sample_ns.tolist())), list(map(str, seq.tolist()))]
            f.write("\r\n".join(map(",".join, zip(*cells, strict=True))))
            f.write("\r\n")
    return pos_err, head_err


def write_results(rec: Recorded) -> Summary:
    """trace.csv, summary.json and trajectory.png of a run the bench recorded (and clock.png of
    one across lab hosts); a second Ctrl-C while the folder is written is recorded, not raised
    (hil.interrupts)."""
    with interrupts.shielded():
        summary = analyze(rec)
        try:
            plot(rec.run_dir)
        except Exception as exc:
            print(f"warning: plots not written: {exc}", file=sys.stderr)
        write_clock_plot(rec.run_dir)
    return summary


def analyze(rec: Recorded) -> Summary:
    """Write trace.csv and summary.json from the two hop logs; returns the summary."""
    run_dir, scenario, settings = rec.run_dir, rec.scenario, rec.settings
    tables = resolved_scenario(run_dir) or {}
    logs = load_folder_logs(run_dir) or RunLogs.read(None, None)
    resolved = as_resolved(scenario, tables)  # the folder's scenario, not parsed again
    m = (measure_and_save(run_dir, logs, resolved) if logs.plant else None) or Measurement()
    drive_reactions = [r.as_dict() for r in reactions(logs.tables, logs.epoch_ns)]
    # The figures' columns go before the trace's are read: an hour's run holds one set at a
    # time (the two reads cost a second pass over the logs, ~10 s an hour).
    logs.tables.clear()
    lockstep = bool(settings.lockstep)
    traced = load_folder_logs(run_dir, TRACE_SOURCE_COLUMNS)
    traced = traced or RunLogs.read(None, None, TRACE_SOURCE_COLUMNS)
    pos_err, head_err = write_trace(run_dir, traced, rec.reference, settings.ts, lockstep)
    del traced
    n = len(pos_err)
    tail = pos_err[-max(1, n // 10) :].tolist() if n else []
    pinfo, cinfo = logs.pinfo, logs.cinfo
    ext = pinfo.get("extremes", {})
    summary: Summary = {
        "schema_version": SCHEMA_VERSION,
        "kind": "run",
        "final_position_error": float(pos_err[-1]) if n else None,
        "final_heading_error": head_err if n else None,
        "rms_position_error": math.sqrt(sum(e * e for e in tail) / len(tail)) if tail else None,
        "initial_position_error": float(pos_err[0]) if n else None,
        **{k: ext.get(k) for k in PEAK_KEYS.values()},
        "violations": ext.get("violations", {}),
        "nonfinite_steps": int(ext.get("nonfinite_steps") or 0),
        "nonfinite_first_t_s": ext.get("nonfinite_first_t_s"),
        "samples": n,
        "duration": (n * settings.ts) if lockstep else settings.duration,
        "lockstep": lockstep,
        "cmd_path": settings.cmd_path,
        "trigger": "on_state" if lockstep else settings.trigger,
        "rate_hz": rate_hz(tables, settings),
        "timing": m.timing,
        "messages": m.messages,
        "certificate": m.certificate,
        **({"device": m.device.as_dict()} if m.device is not None else {}),
        "host": m.host,
        "logs_complete": logs.complete,
        **({"logs_unreadable": logs.unreadable} if logs.unreadable else {}),
    }
    summary["rejections"] = {
        "controller": cinfo.get("rejections", {}),
        "plant": pinfo.get("rejections", {}),
        "drives": (pinfo.get("can") or {}).get("rejections", {}),
    }
    summary["watchdog"] = {
        "controller_stale_entries": cinfo.get("stale_entries", 0),
        "plant_command_timeouts": pinfo.get("timeouts", 0),
    }
    summary["can"] = {"controller": cinfo.get("can"), "plant": pinfo.get("can")}
    summary["faults"] = {
        "config": logs.pmeta.get("faults") or {},
        "injected": {"controller": cinfo.get("injected"), "plant": pinfo.get("injected")},
    }
    # How the device reacted to each drive's disarm (hil.analysis.measure.reactions)
    summary["drive_reactions"] = drive_reactions
    summary["scheduling"] = {
        "controller": cinfo.get("scheduling"),
        "plant": logs.pmeta.get("scheduling"),
    }
    summary.update(rec.extra)
    fault = law_fault_of(run_dir)
    if fault is not None:
        summary["law_fault"] = fault
    # What ran (the plant's window): a run cut short says so here and in its verdict; an
    # open-ended one (--until-stopped) lasted that long.
    summary["duration_run_s"] = m.timing.get("window_s")
    summary["duration_planned_s"] = summary["duration"]
    ended_early = summary.get("interrupted") or summary.get("until_stopped")
    if ended_early and summary["duration_run_s"] is not None:
        summary["duration"] = summary["duration_run_s"]
    summary["verdict"] = run_verdict(summary, scenario)
    # Whole or absent, never half: a kill while it is written leaves the folder to recover.
    write_summary(run_dir, summary)
    return summary


def rate_hz(resolved: Mapping[str, Any], settings: Any) -> float:
    """The control rate as the user asked for it (``--rate``, ``[realtime] rate`` or 1 / ts),
    for summary.json: the folder's ``[provenance] rate_hz`` as ``hil run`` wrote it, else 1 / ts."""
    value = resolved.get("provenance", {}).get("rate_hz")
    if isinstance(value, int | float) and not isinstance(value, bool) and value > 0:
        return float(value)
    return 1.0 / settings.ts


def run_verdict(summary: Summary, scenario: Any) -> VerdictRecord:
    """The run's verdict (hil.verdict.judge at the default thresholds) from its summary."""
    limits = {k: float(getattr(scenario.limits, k)) for k in LIMIT_NAMES.values()}
    device = summary.get("device")
    return judge(
        constraints_from_peaks(summary, limits),
        summary.get("violations") or {},
        summary.get("certificate"),
        summary.get("timing") or {},
        summary.get("messages") or {},
        RunFacts.of(summary),
        ended=LawEnd.of(summary),
        device=DeviceFigures.from_dict(device) if isinstance(device, dict) else None,
    ).as_dict()


def law_fault_of(run_dir: Path) -> LawFaultRecord | None:
    """The controller's law_fault.json (the record of its law's failure), None when there is
    none; a file that cannot be read is said in the record rather than lost."""
    path = run_dir / layout.LAW_FAULT
    if not path.is_file():
        return None
    try:
        return cast(LawFaultRecord, LawFault.from_dict(read_json_object(path)).to_dict())
    except BadInputError as exc:
        return {"law": "?", "where": "?", "kind": "unreadable", "detail": str(exc)}


def plot(run_dir: Path) -> None:
    """trajectory.png: path vs reference, position error and torques over time (long runs
    drawn from per-bin min/max envelopes, :func:`hil.analysis.report.figures.envelope_indices`)."""
    try:
        data = read_trace(run_dir / layout.TRACE)
    except BadInputError:
        return
    t = data["t"]
    err = np.hypot(data["x"] - data["xd"], data["y"] - data["yd"])
    path = envelope_indices(np.arange(t.size), [data["x"], data["y"]])
    ref = envelope_indices(np.arange(t.size), [data["xd"], data["yd"]])
    fig, ax = plt.subplots(1, 3, figsize=(15, 4.5))
    ax[0].plot(data["xd"][ref], data["yd"][ref], "--", label="reference")
    ax[0].plot(data["x"][path], data["y"][path], label="robot")
    ax[0].set_aspect("equal")
    ax[0].legend()
    ax[0].set_title("path (m)")
    i = envelope_indices(t, [err])
    ax[1].semilogy(t[i], np.maximum(err[i], 1e-12))
    ax[1].set_title("position error (m)")
    ax[1].set_xlabel("t (s)")
    i = envelope_indices(t, [data["tau1"], data["tau2"]])
    ax[2].plot(t[i], data["tau1"][i], label="tau1 applied")
    ax[2].plot(t[i], data["tau2"][i], label="tau2 applied", alpha=0.7)
    ax[2].legend()
    ax[2].set_xlabel("t (s)")
    fig.tight_layout()
    fig.savefig(run_dir / layout.TRAJECTORY_PNG, dpi=90)
    plt.close(fig)
