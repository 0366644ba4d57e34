"""Turn the services' hop logs into the run folder's trace.csv and summary.json.

Every timing figure, message count and the certificate come from :mod:`hil.measure` (one
pipeline, definitions in docs/realtime.md); this module adds the trace (one row per plant
sample) and the run's outcome (errors, extremes, violations over every plant step).
"""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from hil.measure.figures import Measurement
from hil.measure.folder import measure_logs, resolved_scenario
from hil.measure.logs import RunLogs, load_folder_logs
from hil.trace import COMMAND_COLUMNS, TRACE_COLUMNS
from protocol.hoplog import TICK_NO_SEND

SCHEMA_VERSION = 2


def wrap(a: float) -> float:
    """An angle in (-pi, pi]."""
    w = math.remainder(a, 2.0 * math.pi)
    return math.pi if w == -math.pi else w


def _commanded_by_sample(logs: RunLogs) -> dict[int, tuple[float, float]]:
    """State seq -> the torques the controller computed from it (its first such tick)."""
    t = logs["ticks"]
    used = (t["state_seq"] >= 0) & ((t["flags"] & TICK_NO_SEND) == 0) & (t["state_sample_ns"] > 0)
    out: dict[int, tuple[float, float]] = {}
    for seq, a, b in zip(
        t["state_seq"][used].tolist(),
        t["tau1"][used].tolist(),
        t["tau2"][used].tolist(),
        strict=True,
    ):
        out.setdefault(seq, (a, b))
    return out


def write_trace(run_dir: Path, logs: RunLogs, reference: Any, ts: float, lockstep: bool):
    """trace.csv: one row per plant sample; returns (position errors, last heading error)."""
    s = logs["samples"]
    epoch = logs.epoch_ns
    cmd = _commanded_by_sample(logs)
    pos_err: list[float] = []
    head_err = 0.0
    with (run_dir / "trace.csv").open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow([*TRACE_COLUMNS, *COMMAND_COLUMNS, "sample_ns", "state_seq"])
        for i in range(s["seq"].size):
            seq = int(s["seq"][i])
            sample_ns = int(s["sample_ns"][i])
            t = seq * ts if lockstep else (sample_ns - epoch) / 1e9
            ref = reference.sample(t)
            c1, c2 = cmd.get(seq, (float("nan"), float("nan")))
            x, y, th = float(s["x"][i]), float(s["y"][i]), float(s["theta"][i])
            row = (t, x, y, th, s["v"][i], s["omega"][i], ref.xd, ref.yd, ref.thetad)
            row += (s["tau1"][i], s["tau2"][i], c1, c2)
            w.writerow([repr(float(v)) for v in row] + [sample_ns, seq])
            pos_err.append(math.hypot(x - ref.xd, y - ref.yd))
            head_err = wrap(th - ref.thetad)
    return pos_err, head_err


def analyze(
    run_dir: Path,
    scenario: Any,
    settings: Any,
    reference: Any,
    context: Any,
    controller_params: dict[str, Any],
    extra: dict[str, Any],
) -> dict[str, Any]:
    """Write trace.csv and summary.json from the two hop logs; returns the summary."""
    logs = load_folder_logs(run_dir) or RunLogs.read(None, None)
    m = measure_logs(logs, resolved_scenario(run_dir)) if logs.plant else Measurement()
    lockstep = bool(settings.lockstep)
    pos_err, head_err = write_trace(run_dir, logs, reference, settings.ts, lockstep)
    n = len(pos_err)
    tail = pos_err[-max(1, n // 10) :] if n else []
    pinfo, cinfo = logs.pinfo, logs.cinfo
    ext = pinfo.get("extremes", {})
    summary: dict[str, Any] = {
        "schema_version": SCHEMA_VERSION,
        "kind": "run",
        "final_position_error": pos_err[-1] if n else None,
        "final_heading_error": head_err if n else None,
        "rms_position_error": math.sqrt(sum(e * e for e in tail) / len(tail)) if tail else None,
        "initial_position_error": pos_err[0] if n else None,
        "max_abs_v": ext.get("max_abs_v"),
        "max_abs_omega": ext.get("max_abs_omega"),
        "max_abs_tau1": ext.get("max_abs_tau1"),
        "max_abs_tau2": ext.get("max_abs_tau2"),
        "violations": ext.get("violations", {}),
        "samples": n,
        "duration": (n * settings.ts) if lockstep else settings.duration,
        "lockstep": lockstep,
        "cmd_path": settings.cmd_path,
        "trigger": "on_state" if lockstep else settings.trigger,
        "rate_hz": settings.rate_hz,
        "timing": m.timing,
        "messages": m.messages,
        "certificate": m.certificate,
        "logs_complete": logs.complete,
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
    summary["scheduling"] = {
        "controller": cinfo.get("scheduling"),
        "plant": logs.pmeta.get("scheduling"),
    }
    summary.update(extra)
    (run_dir / "summary.json").write_text(json.dumps(_jsonable(summary), indent=2))
    return summary


def _jsonable(obj: Any) -> Any:
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, np.integer):
        return int(obj)
    if isinstance(obj, np.floating):
        return float(obj)
    if isinstance(obj, float) and not math.isfinite(obj):
        return repr(obj)
    return obj


def plot(run_dir: Path) -> Path | None:
    """trajectory.png: path vs reference, position error and torques over time."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        import numpy as np
    except ImportError:
        return None
    data = np.genfromtxt(run_dir / "trace.csv", delimiter=",", names=True)
    if data.size < 2:
        return None
    fig, ax = plt.subplots(1, 3, figsize=(15, 4.5))
    ax[0].plot(data["xd"], data["yd"], "--", label="reference")
    ax[0].plot(data["x"], data["y"], label="robot")
    ax[0].set_aspect("equal")
    ax[0].legend()
    ax[0].set_title("path (m)")
    err = np.hypot(data["x"] - data["xd"], data["y"] - data["yd"])
    ax[1].semilogy(data["t"], np.maximum(err, 1e-12))
    ax[1].set_title("position error (m)")
    ax[1].set_xlabel("t (s)")
    ax[2].plot(data["t"], data["tau1"], label="tau1 applied")
    ax[2].plot(data["t"], data["tau2"], label="tau2 applied", alpha=0.7)
    ax[2].legend()
    ax[2].set_xlabel("t (s)")
    fig.tight_layout()
    out = run_dir / "trajectory.png"
    fig.savefig(out, dpi=90)
    plt.close(fig)
    return out
