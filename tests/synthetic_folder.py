"""Synthetic run and simulation folders in the contract's format, for tests and benchmarks.

The signals imitate a sampled sign law (10) tracking the paper's circle: the pose converges
exponentially onto the reference, v~ and w~ chatter in a band of width ~ varpi (Ts + delay),
the torques switch between +-varpi. They are not a simulation of the law; they exercise the
report's code paths with known figures (``overshoot`` pushes v beyond phi1).

A synthetic *run* folder is a run in every way the report can see: the two services' hop logs
(``controller.hoplog``, ``plant.hoplog``, :mod:`protocol.hoplog`) with a periodic controller,
the Zenoh path applied and the CAN path as a live shadow (slower than Zenoh, so that a figure
taken from the wrong path shows), and a summary.json whose ``timing``, ``messages`` and
``certificate`` come from :func:`hil.analysis.measure.folder.measure_folder`, as ``hil run`` writes
them. ``stall = (t_s, length_s)`` loses every Zenoh command sampled in that window on the wire (the
controller sent it, the plant never received it): a command-age stall with cause
``command_lost``.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from hil.analysis.report.figures import write_columns
from protocol.versions import RUN_SCHEMA_VERSION, SIM_SCHEMA_VERSION

EPOCH_NS = 1_000_000_000_000
US = 1000  # ns


def write_synthetic_folder(
    out: str | Path,
    *,
    duration: float = 5.0,
    rate: float = 1000.0,
    overshoot: float = 0.0,
    run: bool = False,
    delay: float = 0.0,
    law: str = "unified",
    seed: int = 1,
    start: float = 0.0,
    stall: tuple[float, float] | None = None,
) -> Path:
    """Write trace.csv, summary.json, scenario.resolved.toml (and for ``run`` the hop logs and
    the measured timing, messages and certificate) into ``out``. ``start``: the time of the
    trace's first sample (a run that starts late: its epoch lies ``start`` before it)."""
    rng = np.random.default_rng(seed)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    ts = 1.0 / rate
    n = round(duration * rate) + 1
    k = np.arange(n)
    t = start + k * ts
    vd, wd = 0.5, 0.2
    thetad = wd * t
    xd, yd = (vd / wd) * np.sin(thetad), (vd / wd) * (1.0 - np.cos(thetad))
    decay = np.exp(-(t - start) / 2.0)
    x, y, theta = xd - 1.0 * decay, yd + 0.5 * decay, thetad + 0.3 * decay
    band = 3.3 * (ts + delay)
    tt = t - start
    v_tilde = np.where(tt < 0.4, 0.5 * (0.4 - tt), band * ((k % 2) * 2.0 - 1.0) / 2.0)
    w_tilde = np.where(tt < 0.2, 1.5 * (0.2 - tt), 51.0 * (ts + delay) * ((k % 3 == 0) - 0.5))
    v = vd + 0.2 * decay + v_tilde + (overshoot * np.exp(-((tt - duration / 2) ** 2) * 50))
    omega = wd + 0.5 * decay * np.cos(3 * tt) + w_tilde
    tau1 = -3.3 * np.sign(v_tilde)
    tau2 = -51.0 * np.sign(w_tilde)
    cols: dict[str, np.ndarray] = {
        "t": t,
        "x": x,
        "y": y,
        "theta": theta,
        "v": v,
        "omega": omega,
        "xd": xd,
        "yd": yd,
        "thetad": thetad,
        "tau1": tau1,
        "tau2": tau2,
        "tau1_cmd": tau1,
        "tau2_cmd": tau2,
        "v_tilde": v_tilde,
        "w_tilde": w_tilde,
    }
    summary: dict[str, Any] = {
        "schema_version": SIM_SCHEMA_VERSION,
        "final_position_error": float(math.hypot(x[-1] - xd[-1], y[-1] - yd[-1])),
        "final_heading_error": float(theta[-1] - thetad[-1]),
        "rms_position_error": 0.0,
        "max_abs_v": float(np.abs(v).max()),
        "max_abs_omega": float(np.abs(omega).max()),
        "max_abs_tau1": 3.3,
        "max_abs_tau2": 51.0,
        "violations": {
            "v": int(np.count_nonzero(np.abs(v) > 1.6 * (1 + 1e-9))),
            "omega": int(np.count_nonzero(np.abs(omega) > 5.1 * (1 + 1e-9))),
            "tau1": 0,
            "tau2": 0,
        },
    }
    (out / "scenario.resolved.toml").write_text(
        _scenario_text(vd, wd, law, ts, delay, seed, duration)
    )
    if run:
        period = round(ts * 1e9)
        sample_ns = EPOCH_NS + k * period
        cols["sample_ns"] = sample_ns.astype(float)
        cols["state_seq"] = k.astype(float)
        _write_hop_logs(out, rng, cols, period, delay, stall)
        summary.update(_measured_summary(out, cols))
    write_columns(out / "trace.csv", cols)
    (out / "summary.json").write_text(json.dumps(summary, indent=2))
    return out


def _gamma_us(rng: np.random.Generator, shape: float, scale_us: float, n: int, cap_us: float):
    """Gamma-distributed durations in ns, capped (so that the synthetic loop keeps its order)."""
    return (np.minimum(rng.gamma(shape, scale_us, n), cap_us) * US).astype(np.int64)


def _write_hop_logs(
    out: Path,
    rng: np.random.Generator,
    cols: dict[str, np.ndarray],
    period: int,
    delay: float,
    stall: tuple[float, float] | None,
) -> None:
    """controller.hoplog and plant.hoplog of a periodic loop sampled at ``period``."""
    from protocol.hoplog import CONTROLLER_TABLES, PLANT_TABLES, HopLogWriter

    n = cols["t"].size
    k = np.arange(n)
    cap = period / US / 4.0  # every random hop below Ts/4: events keep their order
    sample = EPOCH_NS + k * period
    wake_p = sample + _gamma_us(rng, 3.0, 10.0, n, cap)
    send_p = wake_p + 40 * US
    recv_s = send_p + _gamma_us(rng, 4.0, 30.0, n, cap)
    deadline = sample + period // 2
    wake_c = deadline + _gamma_us(rng, 3.0, 20.0, n, cap)
    c_start = np.maximum(wake_c, recv_s) + 5 * US
    c_end = c_start + 30 * US
    z_send = c_end + 2 * US
    can_send = z_send + 20 * US
    z_recv = z_send + _gamma_us(rng, 4.0, 30.0, n, cap)
    apply = z_recv + round(delay * 1e9)
    # the CAN shadow: each wheel's frame lands later than the Zenoh command (its age is larger:
    # a report that took the worst of both paths would show it)
    shadow = 2 * (period // 10) + round(delay * 1e9)
    can_recv = {
        node: can_send + off * US + shadow + _gamma_us(rng, 6.0, 20.0, n, cap)
        for node, off in ((1, 0), (0, 5))
    }
    lost = np.zeros(n, bool)
    if stall is not None:
        t0, length = stall
        lost = (cols["t"] >= t0) & (cols["t"] < t0 + length)
    tau1, tau2 = cols["tau1"], cols["tau2"]
    epoch = EPOCH_NS - round(float(cols["t"][0]) * 1e9)  # a late start: the epoch came earlier

    plant = HopLogWriter(
        out / "plant.hoplog",
        "plant",
        PLANT_TABLES,
        {
            "robot_id": "robot0",
            "sensor_period_ns": period,
            "control_period_ns": period,
            "plant_step_ns": period // 10,
            "lockstep": False,
            "cmd_path": "zenoh",
            "delay_s": delay,
            "jitter_s": 0.0,
            "epoch_ns": epoch,
        },
        flush_interval=60.0,
    )
    ctrl = HopLogWriter(
        out / "controller.hoplog",
        "controller",
        CONTROLLER_TABLES,
        {
            "robot_id": "robot0",
            "period_ns": period,
            "trigger": "periodic",
            "lockstep": False,
            "cmd_path": "zenoh",
            "epoch_ns": epoch,
        },
        flush_interval=60.0,
    )
    arm = EPOCH_NS - 2 * period
    for node in (1, 0):  # the lifecycle's zero torque, before the first sample
        # zenoh_can names a frame by its modelled end of transmission; both sides log it.
        end = arm + node * US + 100 * US
        ctrl.append("can_tx", (node, arm + node * US, -1, 0.0, end))
        plant.append("cmd_rx", (1, 0, -1, 0, 0, end, arm + 200 * US + node * US, 0.0, 0.0, node, 0))
    for i in range(n):
        s = int(sample[i])
        plant.append(
            "samples",
            (
                i,
                s,
                int(wake_p[i]),
                int(send_p[i]),
                *(float(cols[c][i]) for c in ("x", "y", "theta", "v", "omega")),
                float(tau1[i]),
                float(tau2[i]),
                float(tau1[i]),
                float(tau2[i]),
                0,
            ),
        )
        ctrl.append("state_rx", (i, s, int(send_p[i]), int(recv_s[i]), 0))
        ctrl.append(
            "ticks",
            (
                i,
                int(deadline[i]),
                int(wake_c[i]),
                0,
                i,
                s,
                int(send_p[i]),
                int(recv_s[i]),
                int(c_start[i]),
                int(c_end[i]),
                int(z_send[i]),
                int(can_send[i]),
                i,
                float(tau1[i]),
                float(tau2[i]),
                0,
            ),
        )
        for node in (1, 0):
            sent = int(can_send[i]) + (5 * US if node == 0 else 0)
            q = float(np.float32(tau1[i] if node == 1 else tau2[i]))  # any torque, checked as sent
            ctrl.append("can_tx", (node, sent, i, q, sent + 100 * US))
            plant.append(
                "cmd_rx",
                (1, i + 1, -1, 0, 0, sent + 100 * US, int(can_recv[node][i]), q, 0.0, node, 0),
            )
        if lost[i]:
            continue
        plant.append(
            "cmd_rx",
            (
                0,
                i,
                i,
                s,
                int(c_start[i]),
                int(z_send[i]),
                int(z_recv[i]),
                float(tau1[i]),
                float(tau2[i]),
                -1,
                0,
            ),
        )
        plant.append(
            "apply",
            (0, i, -1, int(z_recv[i]), int(apply[i]), float(tau1[i]), float(tau2[i]), 0),
        )
    frames = 2 * n + 2
    ctrl.close(
        {
            "deadline_misses": 0,
            "rejections": {},
            "can": {
                "phase": "stopped",
                "fault": "",
                "frames_sent": frames,
                "arm_sends": 1,
                "rearms": 0,
                "send_errors": 0,
                "rejections": {},
            },
        }
    )
    plant.close(
        {
            "rejections": {},
            "can": {"frames_in": frames, "frames_out": 0, "rejections": {}},
        }
    )


def _measured_summary(out: Path, cols: dict[str, np.ndarray]) -> dict[str, Any]:
    """What ``hil run`` adds to a run's summary.json: hil.analysis.measure's timing, messages and
    certificate (JSON-clean), the applied path, CAN states and rejection counts."""
    from hil.analysis.measure.folder import measure_folder

    m = measure_folder(out)
    assert m is not None
    clean = json.loads(json.dumps(_plain({"t": m.timing, "m": m.messages, "c": m.certificate})))
    frames = 2 * cols["t"].size + 2
    return {
        "schema_version": RUN_SCHEMA_VERSION,
        "kind": "run",
        "cmd_path": "zenoh",
        "trigger": "periodic",
        "lockstep": False,
        "timing": clean["t"],
        "messages": clean["m"],
        "certificate": clean["c"],
        "device": json.loads(json.dumps(_plain(m.device.as_dict()))) if m.device else None,
        "logs_complete": {"controller": True, "plant": True},
        "rejections": {"controller": {}, "plant": {}, "drives": {}},
        "can": {
            "controller": {
                "phase": "stopped",
                "fault": "",
                "frames_sent": frames,
                "arm_sends": 1,
                "rearms": 0,
                "send_errors": 0,
                "rejections": {},
            },
            "plant": {"frames_in": frames, "frames_out": 0, "rejections": {}},
        },
    }


def _plain(obj: Any) -> Any:
    if isinstance(obj, dict):
        return {str(k): _plain(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_plain(v) for v in obj]
    if isinstance(obj, np.integer):
        return int(obj)
    if isinstance(obj, np.floating):
        return float(obj)
    if isinstance(obj, np.bool_):
        return bool(obj)
    return obj


def _scenario_text(
    vd: float, wd: float, law: str, ts: float, delay: float, seed: int, duration: float
) -> str:
    eps = "eps1 = 0.1\neps2 = 0.1\n" if law == "unified_boundary" else ""
    return f"""[limits]
phi1 = 1.6
phi2 = 5.1
varpi1 = 3.3
varpi2 = 51.0

[disturbance]
kind = "none"
s1 = 0.0
s2 = 0.0

[reference]
kind = "circle"
vd = {vd}
wd = {wd}
mu1 = 0.5
mu2 = 0.2
k1 = 1.0
k2 = 1.0

[initial]
x = -1.0
y = 0.5
theta = 0.3

[controller]
law = "{law}"
m1 = 0.5
m2 = 0.5
l1 = 0.5
l2 = 0.5
lam = 1.0
rho = 1.0
{eps}
[timing]
ts = {ts}
delay = {delay}
jitter = 0.0
jitter_kind = "uniform"
seed = {seed}

[run]
duration = {duration}

[robot]
mass = 10.0
yaw_inertia = 0.5
wheel_radius = 0.05
half_track = 0.2
gear_ratio = 10.0
"""
