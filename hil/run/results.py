"""Turn the services' hop logs into the run folder's trace.csv, summary.json and plots.

Time stamps (``time.monotonic_ns()``, one host) per control sample k:

- plant: sample (the model time of State k, on the epoch's grid), send;
- controller: wake-up and its deadline (periodic), state receive, compute start and end, send
  on Zenoh, send on CAN (both wheel frames);
- plant: receive and apply of each path (the applied one lands after the injected delay; the
  shadow is only received). CAN frames stay pure CANSimple, so the drives' arrivals are matched
  to the controller's CAN send log in per-node order.

Figures (microseconds, percentiles p50/p90/p99/p999/max through :mod:`hil.timing`):
``wakeup_lateness`` (wake - deadline), ``period_jitter`` (|wake_k - wake_{k-1} - Ts|),
``compute`` (compute end - start), ``sample_to_apply_<path>`` (apply or, for a shadow,
receive - sample), ``hop_state`` (controller receive - plant send), ``hop_cmd_<path>`` (plant
receive - controller send), ``wait_for_tick`` (compute start - state receive: what the periodic
trigger adds), ``loop_transport_compute`` (over Zenoh: state hop + compute + command hop, the
periodic trigger's wait excluded), ``state_send_to_cmd_recv`` (the same end to end, wait
included), ``sample_gap`` (the longest gap between the sample
times of successive applied commands, the Ts of the sampled-data bound).
"""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path
from typing import Any

import msgpack

from hil.timing import diffs, summarize
from hil.trace import COMMAND_COLUMNS, TRACE_COLUMNS

SCHEMA_VERSION = 1


def load_log(path: Path) -> dict[str, Any] | None:
    try:
        return msgpack.unpackb(path.read_bytes(), raw=False, strict_map_key=False)
    except (OSError, ValueError, msgpack.UnpackException):
        return None


def _rows(log: dict[str, Any] | None, rows_key: str, fields_key: str) -> list[dict[str, Any]]:
    if not log:
        return []
    names = log[fields_key]
    return [dict(zip(names, r, strict=False)) for r in log[rows_key]]


def wrap(a: float) -> float:
    """An angle in (-pi, pi]."""
    w = math.remainder(a, 2.0 * math.pi)
    return math.pi if w == -math.pi else w


def sampled_data_bound(
    context: Any, params: dict[str, Any], ts_gap: float, delta: float
) -> dict[str, float]:
    """The sampled-data bound of docs/sampled_data_bound.md at the run's measured worst sample
    gap and delay, from :mod:`controller_service.certificate` (one formula for the certificate,
    the run and the report): |v| <= V = mu1 + m1 + b1 + (varpi1 + s1)(Ts + delta) and
    |w| <= mu2 + lam mu1 + m2 + rho c2(V) + b2 + (varpi2 + s2)(Ts + delta), with b1, b2 the
    boundary layer's eps s / varpi terms (0 for the sign law)."""
    from controller_service.certificate import omega_bound, velocity_bound

    lim = context.limits
    m1, m2 = float(params.get("m1", 0.5)), float(params.get("m2", 0.5))
    lam, rho = float(params.get("lam", 1.0)), float(params.get("rho", 1.0))
    eps1, eps2 = float(params.get("eps1", 0.0)), float(params.get("eps2", 0.0))
    span = ts_gap + delta
    b1, b2 = eps1 * context.s1 / lim.varpi1, eps2 * context.s2 / lim.varpi2
    v_bound = velocity_bound(context, m1, span, b1)
    w_bound = omega_bound(context, m2=m2, lam=lam, rho=rho, v_bound=v_bound, age=span, b2=b2)
    return {"v": v_bound, "omega": w_bound, "ts_gap": ts_gap, "delta": delta}


def analyze(
    run_dir: Path,
    scenario: Any,
    settings: Any,
    reference: Any,
    context: Any,
    controller_params: dict[str, Any],
    extra: dict[str, Any],
) -> dict[str, Any]:
    """Write trace.csv and summary.json from the two logs; returns the summary."""
    clog = load_log(run_dir / "controller_log.msgpack")
    plog = load_log(run_dir / "plant_log.msgpack")
    crow = _rows(clog, "rows", "fields")
    states = _rows(plog, "states", "state_fields")
    cmds = _rows(plog, "commands", "cmd_fields")
    epoch = int((plog or clog or {}).get("epoch_ns", 0) or 0)
    lockstep = bool(settings.lockstep)
    ts = settings.ts

    by_state_seq: dict[int, dict[str, Any]] = {}
    for r in crow:
        if not (r["flags"] & 0x101):
            by_state_seq.setdefault(r["state_seq"], r)

    # --- trace.csv: one row per control sample (the states the plant published) ---
    trace_path = run_dir / "trace.csv"
    cols = [
        *TRACE_COLUMNS,
        *COMMAND_COLUMNS,
        "sample_ns",
        "state_seq",
    ]
    pos_err: list[float] = []
    head_err = 0.0
    with trace_path.open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(cols)
        for s in states:
            t = s["seq"] * ts if lockstep else (s["sample_ns"] - epoch) / 1e9
            ref = reference.sample(t)
            c = by_state_seq.get(s["seq"])
            t1c = c["tau1"] if c else float("nan")
            t2c = c["tau2"] if c else float("nan")
            w.writerow(
                [
                    repr(float(v))
                    for v in (
                        t,
                        s["x"],
                        s["y"],
                        s["theta"],
                        s["v"],
                        s["omega"],
                        ref.xd,
                        ref.yd,
                        ref.thetad,
                        s["tau1"],
                        s["tau2"],
                        t1c,
                        t2c,
                    )
                ]
                + [s["sample_ns"], s["seq"]]
            )
            pos_err.append(math.hypot(s["x"] - ref.xd, s["y"] - ref.yd))
            head_err = wrap(s["theta"] - ref.thetad)

    n = len(pos_err)
    tail = pos_err[-max(1, n // 10) :] if n else []
    ext = (plog or {}).get("extremes", {})
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
        "duration": (n * ts) if lockstep else settings.duration,
        "lockstep": lockstep,
        "cmd_path": settings.cmd_path,
        "trigger": "on_state" if lockstep else settings.trigger,
        "rate_hz": settings.rate_hz,
    }

    # --- timing ---
    timing: dict[str, Any] = {}
    tick_rows = (
        [r for r in crow if r["k"] >= 0] if (clog or {}).get("trigger") == "periodic" else []
    )
    if tick_rows:
        timing["wakeup_lateness"] = summarize(r["wake_ns"] - r["deadline_ns"] for r in tick_rows)
        period = int(clog["period_ns"])
        timing["period_jitter"] = summarize(
            abs(d - period) for d in diffs(r["wake_ns"] for r in tick_rows)
        )
    fresh = [r for r in crow if not (r["flags"] & 0x101) and r["state_recv_ns"] > 0]
    timing["compute"] = summarize(r["compute_end_ns"] - r["compute_start_ns"] for r in fresh)
    timing["hop_state"] = summarize(r["state_recv_ns"] - r["state_send_ns"] for r in fresh)
    timing["wait_for_tick"] = summarize(r["compute_start_ns"] - r["state_recv_ns"] for r in fresh)
    timing["plant_sample_to_send"] = summarize(s["send_ns"] - s["sample_ns"] for s in states)

    zen = [c for c in cmds if c["path"] == 0 and c["state_sample_ns"] > 0]
    zen_applied = [c for c in zen if c["applied"]]
    z_lat = [(c["apply_ns"] if c["applied"] else c["recv_ns"]) - c["state_sample_ns"] for c in zen]
    timing["sample_to_apply_zenoh"] = summarize(z_lat)
    timing["hop_cmd_zenoh"] = summarize(c["recv_ns"] - c["send_ns"] for c in zen)
    state_send = {s["seq"]: s["send_ns"] for s in states}
    timing["state_send_to_cmd_recv"] = summarize(
        c["recv_ns"] - state_send[c["state_seq"]] for c in zen if c["state_seq"] in state_send
    )
    # The loop's own work, without the periodic trigger's wait for its tick: both hops and
    # the law, joined on the command's sequence number.
    row_of_cmd = {r["cmd_seq"]: r for r in fresh if r["zenoh_send_ns"] > 0}
    timing["loop_transport_compute"] = summarize(
        (r["state_recv_ns"] - r["state_send_ns"])
        + (r["compute_end_ns"] - r["compute_start_ns"])
        + (c["recv_ns"] - c["send_ns"])
        for c in zen
        if (r := row_of_cmd.get(c["seq"])) is not None
    )

    # CAN: match arrivals per node, in order, to the controller's CAN sends.
    can_sends = [r for r in crow if r["can_send_ns"] > 0]
    last_state_ns = states[-1]["send_ns"] if states else 0
    can_arr = [c for c in cmds if c["path"] == 1]
    can_lat: list[int] = []
    can_hop: list[int] = []
    # Per node, the i-th Set_Input_Torque to arrive is the i-th the controller sent; the
    # lifecycle's zero torques (row -1) are skipped.
    tlog = ((clog or {}).get("can") or {}).get("torque_log") or []
    per_node: dict[int, list[tuple[int, int]]] = {}
    for node, send_ns, row in tlog:
        per_node.setdefault(node, []).append((send_ns, row))
    matched = []
    for c in can_arr:
        sends = per_node.get(c["node"], [])
        if c["seq"] < len(sends) and 0 <= sends[c["seq"]][1] < len(crow):
            matched.append((c, crow[sends[c["seq"]][1]], sends[c["seq"]][0]))
    for c, src, send_ns in matched:
        t_end = c["apply_ns"] if c["applied"] else c["recv_ns"]
        if src["state_sample_ns"] > 0:
            can_lat.append(t_end - src["state_sample_ns"])
        can_hop.append(c["recv_ns"] - send_ns)
    timing["sample_to_apply_can"] = summarize(can_lat)
    timing["hop_cmd_can"] = summarize(can_hop)

    # The sampled-data bound's Ts: the longest gap between sample times of applied commands.
    applied_samples: list[int] = []
    if settings.cmd_path == "zenoh":
        applied_samples = [c["state_sample_ns"] for c in zen_applied]
        delta_ns = max((c["apply_ns"] - c["state_sample_ns"] for c in zen_applied), default=0)
    else:
        seen = set()
        delta_ns = 0
        for c, src, _ in matched:
            if c["applied"] and src["state_sample_ns"] > 0:
                if src["state_sample_ns"] not in seen:
                    seen.add(src["state_sample_ns"])
                    applied_samples.append(src["state_sample_ns"])
                delta_ns = max(delta_ns, c["apply_ns"] - src["state_sample_ns"])
    gaps = diffs(sorted(applied_samples))
    if lockstep:
        gap_s = ts
        delta_s = settings.delay
    else:
        gap_s = max(gaps, default=int(ts * 1e9)) / 1e9
        delta_s = delta_ns / 1e9
    timing["sample_gap"] = summarize(gaps)
    misses = int((clog or {}).get("deadline_misses", 0))
    cycles = len(tick_rows)
    timing["deadline_misses"] = misses
    timing["deadline_miss_rate"] = misses / cycles if cycles else 0.0
    timing["plant_deadline_misses"] = int((plog or {}).get("deadline_misses", 0))
    timing["units"] = "us"
    summary["timing"] = timing

    # Message counts per stream.
    sc = (clog or {}).get("state_counts", {})
    cc = (plog or {}).get("cmd_counts", {})
    messages = {
        "state": {
            "sent": len(states),
            "received": sc.get("received", 0),
            "lost": max(0, len(states) - sc.get("accepted", 0) - sc.get("reordered", 0))
            if states
            else sc.get("lost", 0),
            "duplicated": sc.get("duplicated", 0),
            "reordered": sc.get("reordered", 0),
        },
        "torque_zenoh": {
            "sent": int((clog or {}).get("commands_sent", 0)),
            "received": len([c for c in cmds if c["path"] == 0])
            if settings.cmd_path != "zenoh" or lockstep
            else cc.get("received", 0),
            "lost": cc.get("lost", 0),
            "duplicated": cc.get("duplicated", 0),
            "reordered": cc.get("reordered", 0),
        },
    }
    ccan = (clog or {}).get("can") or {}
    pcan = (plog or {}).get("can") or {}
    if ccan or pcan:
        # Frames sent after the plant's last sample cannot have been received: not lost.
        sent_torque = 2 * len([r for r in can_sends if r["can_send_ns"] <= last_state_ns])
        got = len(can_arr)
        messages["torque_can"] = {
            "sent": sent_torque,
            "received": got,
            "lost": max(0, sent_torque - got),
            "duplicated": 0,
            "reordered": 0,
            "frames_sent_controller": ccan.get("frames_sent", 0),
            "frames_received_plant": pcan.get("frames_in", 0),
            "drive_phase": ccan.get("phase"),
            "drive_fault": ccan.get("fault"),
        }
    summary["messages"] = messages
    summary["rejections"] = {
        "controller": (clog or {}).get("rejections", {}),
        "plant": (plog or {}).get("rejections", {}),
        "drives": pcan.get("rejections", {}),
    }
    summary["watchdog"] = {
        "controller_stale_entries": (clog or {}).get("stale_entries", 0),
        "plant_command_timeouts": (plog or {}).get("timeouts", 0),
    }
    summary["scheduling"] = {
        "controller": (clog or {}).get("scheduling"),
        "plant": (plog or {}).get("scheduling"),
    }
    if context is not None:
        summary["sampled_data_bound"] = sampled_data_bound(
            context, controller_params, gap_s, delta_s
        )
    summary.update(extra)
    (run_dir / "summary.json").write_text(json.dumps(summary, indent=2, default=str))
    return summary


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
