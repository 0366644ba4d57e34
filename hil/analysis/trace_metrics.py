"""Sampling-effect metrics: what the sampled, delayed loop did to the sliding-mode law.

Pure functions of arrays (a trace's columns) and numbers; no files, no clocks. The paper's
guarantees (Proposition 1, (13)-(18)) are continuous-time: the law (10) switches the torque on the
sign of the sliding variables v~ = v - alpha_v and w~ = w - alpha_w, and under sampling those
variables no longer stay at zero but chatter in a *quasi-sliding band* whose width grows with the
sampling period and delay. The figures here measure that band, the switching rate of tau1 and
tau2, the constraints (2) against their limits and against the sampled-data bound, the tracking
error (4) and the deviation from the ideal (finely sampled) trajectory.

Definitions (also in docs/reports.md):

- reaching time: the first sample at which the sliding variable crosses zero (changes sign or is
  exactly zero) or enters the boundary layer |s| <= threshold (eps1/eps2 of (19), 0 for (10));
  the reaching phase of sliding-mode control ends at the first hit of the manifold s = 0.
- band: over the samples after the reaching time, ``band_p99`` = p99 of |s| and ``band_max`` =
  max |s|; also ``band_spread`` = max(s) - min(s).
- switching rate: sign changes of a torque per second (zero samples skipped).
- saturation share: the fraction of samples at which |tau| >= 0.999 varpi (the sign law's
  torque sits at its limit; the boundary layer (19) lowers it).
- percentile: exact, one of the measured values: numpy's ``method="inverted_cdf"`` (the
  smallest value with at least q % of the samples at or below it), the definition of
  :mod:`hil.analysis.measure.stats` and of every timing figure in summary.json, so no percentile can
  exceed the maximum and the same samples give the same figure on every path.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from typing import NamedTuple

import numpy as np

from hil.folder.records import Metrics
from hil.limits import ConstraintFigure
from protocol.angles import wrap_angle

PERCENTILES: tuple[float, ...] = (50.0, 90.0, 99.0, 99.9)


def percentile(values: Iterable[float] | np.ndarray, q: float) -> float:
    """The q-th percentile (0 <= q <= 100), exact (module docstring; q = 0: the minimum)."""
    data = np.asarray(values, dtype=float).ravel()
    if data.size == 0:
        raise ValueError("percentile of an empty sample")
    if not 0.0 <= q <= 100.0:
        raise ValueError(f"percentile {q} outside [0, 100]")
    return float(np.percentile(data, q, method="inverted_cdf"))


def percentiles(
    values: Iterable[float] | np.ndarray, qs: Sequence[float] = PERCENTILES
) -> dict[str, float]:
    """p50, p90, p99, p999 and max (keys as in summary.json's timing object, without _us)."""
    data = np.asarray(values, dtype=float).ravel()
    return {**{_pkey(q): percentile(data, q) for q in qs}, "max": float(np.max(data))}


def _pkey(q: float) -> str:
    return "p" + (f"{q:g}".replace(".", ""))


def position_error(x: np.ndarray, y: np.ndarray, xd: np.ndarray, yd: np.ndarray) -> np.ndarray:
    """Euclidean distance to the virtual robot (3): sqrt(xe^2 + ye^2) of (4)."""
    return np.hypot(np.asarray(x) - np.asarray(xd), np.asarray(y) - np.asarray(yd))


def heading_error(theta: np.ndarray, thetad: np.ndarray) -> np.ndarray:
    """theta_e = theta - theta_d of (4), wrapped to (-pi, pi]."""
    return wrap_angle(np.asarray(theta) - np.asarray(thetad))


class Band(NamedTuple):
    """The quasi-sliding band of one sliding variable (v~ or w~ of (10))."""

    reaching_time: float | None  # s from the trace's start; None: never reached the manifold
    band_p99: float | None
    band_max: float | None
    band_spread: float | None
    samples_after: int


def quasi_sliding_band(t: np.ndarray, s: np.ndarray, threshold: float = 0.0) -> Band:
    """Reaching time and band of s after it (p99 |s|, max |s|, max(s) - min(s))."""
    t, s = np.asarray(t, dtype=float), np.asarray(s, dtype=float)
    # The reaching time: the first sample on or across the manifold (module docstring).
    crossed = np.zeros(s.size, dtype=bool)
    crossed[1:] = np.sign(s[1:]) * np.sign(s[:-1]) < 0
    hit = np.flatnonzero((np.abs(s) <= threshold) | crossed)
    if hit.size == 0:
        return Band(None, None, None, None, 0)
    k = int(hit[0])
    after = s[k:]
    mag = np.abs(after)
    return Band(
        reaching_time=float(t[k] - t[0]),
        band_p99=percentile(mag, 99.0),
        band_max=float(mag.max()),
        band_spread=float(after.max() - after.min()),
        samples_after=int(after.size),
    )


def switching_rate(t: np.ndarray, tau: np.ndarray) -> float:
    """Sign changes of tau per second over the trace (zero samples skipped)."""
    t = np.asarray(t, dtype=float)
    signs = np.sign(np.asarray(tau, dtype=float))
    signs = signs[signs != 0.0]
    duration = float(t[-1] - t[0]) if t.size > 1 else 0.0
    if duration <= 0.0 or signs.size < 2:
        return 0.0
    return float(np.count_nonzero(signs[1:] != signs[:-1]) / duration)


SATURATION_FRACTION = 0.999


def saturation_share(tau: np.ndarray, varpi: float, fraction: float = SATURATION_FRACTION) -> float:
    """The fraction of (known) samples at which |tau| >= fraction * varpi: how much of the time
    the torque sits at its limit of (2). Missing (NaN) samples are left out."""
    mag = np.abs(np.asarray(tau, dtype=float))
    known = mag[~np.isnan(mag)]
    if known.size == 0 or varpi <= 0:
        return 0.0
    return float(np.count_nonzero(known >= fraction * varpi) / known.size)


def deviation_from_ideal(
    t: np.ndarray,
    x: np.ndarray,
    y: np.ndarray,
    t_ideal: np.ndarray,
    x_ideal: np.ndarray,
    y_ideal: np.ndarray,
) -> np.ndarray:
    """Distance at each sample time between the trace and the ideal trajectory (the same
    scenario simulated at a fine period, standing in for continuous time), the ideal one
    linearly interpolated onto the trace's times."""
    return position_error(x, y, np.interp(t, t_ideal, x_ideal), np.interp(t, t_ideal, y_ideal))


def _peak(values: np.ndarray) -> float:
    """max |x|, ignoring missing (NaN) samples: a run's trace has gaps where no command was in
    force; an all-missing column has no peak (0)."""
    mag = np.abs(np.asarray(values, dtype=float))
    known = mag[~np.isnan(mag)]  # an infinite velocity is a broken limit, not a gap
    return float(known.max()) if known.size else 0.0


def sampling_effects(
    trace: Mapping[str, np.ndarray],
    *,
    phi1: float,
    phi2: float,
    varpi1: float,
    varpi2: float,
    v_bound: float | None = None,
    w_bound: float | None = None,
    eps1: float = 0.0,
    eps2: float = 0.0,
    ideal: Mapping[str, np.ndarray] | None = None,
    sliding: Mapping[str, tuple[np.ndarray, np.ndarray]] | None = None,
) -> Metrics:
    """Every sampling-effect figure of one trace (trace.csv's columns as arrays: t, x, y, theta,
    v, omega, xd, yd, thetad, tau1, tau2). The bands use its v_tilde / w_tilde columns, else
    ``sliding`` (name -> (t, values), e.g. a run's recorded telemetry), else are None."""
    t = np.asarray(trace["t"], dtype=float)
    pos = position_error(trace["x"], trace["y"], trace["xd"], trace["yd"])
    head = heading_error(trace["theta"], trace["thetad"])
    # RMS over the last 10 % of the run (as summary.json's rms_position_error).
    tail = pos[t >= t[-1] - 0.1 * (t[-1] - t[0])]
    rms = float(np.sqrt(np.mean(tail**2))) if tail.size else math.nan
    out: Metrics = {
        "duration": float(t[-1] - t[0]) if t.size else 0.0,
        "samples": int(t.size),
        "tracking": {
            "final_position_error": float(pos[-1]),
            "final_heading_error": float(head[-1]),
            "max_position_error": float(pos.max()),
            "rms_position_error_last10": rms,
        },
    }
    bands: dict[str, dict[str, float] | None] = {}
    for name, eps in (("v_tilde", eps1), ("w_tilde", eps2)):
        t_s, col = t, trace.get(name)
        if col is None and sliding and name in sliding and len(sliding[name][0]) > 1:
            t_s, col = sliding[name]
        bands[name] = None if col is None else quasi_sliding_band(t_s, col, eps)._asdict()
    out["bands"] = bands
    torques = {"tau1": varpi1, "tau2": varpi2}
    out["switching_rate"] = {k: switching_rate(t, trace[k]) for k in torques}
    out["saturation_share"] = {k: saturation_share(trace[k], w) for k, w in torques.items()}
    limits = {"v": (phi1, v_bound), "omega": (phi2, w_bound),
              "tau1": (varpi1, None), "tau2": (varpi2, None)}  # fmt: skip
    out["constraints"] = {
        k: ConstraintFigure(k, _peak(trace[k]), lim, bound).as_dict()
        for k, (lim, bound) in limits.items()
    }
    out["deviation_from_ideal"] = None
    if ideal is not None:
        dev = deviation_from_ideal(t, trace["x"], trace["y"], ideal["t"], ideal["x"], ideal["y"])
        out["deviation_from_ideal"] = {
            "max": float(dev.max()),
            "rms": float(np.sqrt(np.mean(dev**2))),
            "final": float(dev[-1]),
        }
    return out
