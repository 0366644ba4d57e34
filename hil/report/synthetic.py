"""Synthetic run and simulation folders in the contract's format, for tests and benchmarks.

The signals imitate a sampled sign law (10) tracking the paper's circle: the pose converges
exponentially onto the reference, v~ and w~ chatter in a band of width ~ varpi (Ts + delay),
the torques switch between +-varpi. They are not a simulation of the law; they exercise the
report's code paths with known figures (``overshoot`` pushes v beyond phi1).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from hil.report.figures import write_columns


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
) -> Path:
    """Write trace.csv, summary.json, scenario.resolved.toml (and for ``run`` a timing object,
    message counts and per-sample latency/lateness columns) into ``out``."""
    rng = np.random.default_rng(seed)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    ts = 1.0 / rate
    n = round(duration * rate) + 1
    t = np.arange(n) * ts
    vd, wd = 0.5, 0.2
    thetad = wd * t
    xd, yd = (vd / wd) * np.sin(thetad), (vd / wd) * (1.0 - np.cos(thetad))
    decay = np.exp(-t / 2.0)
    x, y, theta = xd - 1.0 * decay, yd + 0.5 * decay, thetad + 0.3 * decay
    band = 3.3 * (ts + delay)
    k = np.arange(n)
    v_tilde = np.where(t < 0.4, 0.5 * (0.4 - t), band * ((k % 2) * 2.0 - 1.0) / 2.0)
    w_tilde = np.where(t < 0.2, 1.5 * (0.2 - t), 51.0 * (ts + delay) * ((k % 3 == 0) - 0.5))
    v = vd + 0.2 * decay + v_tilde + (overshoot * np.exp(-((t - duration / 2) ** 2) * 50))
    omega = wd + 0.5 * decay * np.cos(3 * t) + w_tilde
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
    summary: dict = {
        "schema_version": 1,
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
    if run:
        zenoh = delay * 1e6 + rng.gamma(4.0, 50.0, n)
        can = delay * 1e6 + rng.gamma(6.0, 60.0, n)
        lateness = rng.gamma(3.0, 40.0, n)
        cols["zenoh_latency_us"] = zenoh
        cols["can_latency_us"] = can
        cols["lateness_us"] = lateness
        from hil.timing import summarize

        summary["timing"] = {
            "wake_lateness": summarize((lateness * 1000).astype(np.int64)),
            "zenoh_sample_to_apply": summarize((zenoh * 1000).astype(np.int64)),
            "can_sample_to_apply": summarize((can * 1000).astype(np.int64)),
        }
        summary["messages"] = {"sent": n, "received": n, "lost": 0, "duplicated": 0, "reordered": 0}
        summary["deadline_misses"] = 0
        summary["cycles"] = n
    write_columns(out / "trace.csv", cols)
    (out / "summary.json").write_text(json.dumps(summary, indent=2))
    (out / "scenario.resolved.toml").write_text(
        f"""[limits]
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
eps1 = 0.1
eps2 = 0.1

[timing]
ts = {ts}
delay = {delay}
jitter = 0.0
jitter_kind = "uniform"
seed = {seed}

[run]
duration = {duration}
"""
    )
    return out
