"""The timing ``hil margin`` replays, and the same timing with every age scaled by k
(docs/margin.md, "The timing replayed": the cyclic replay, the start-up hold left out).

The *base timing* is a sample period ``ts`` and, per sample, the latency from the sample to the
landing of its command (NaN: never landed). From a run folder: the applied path's landings in
force measured by :mod:`hil.analysis.measure` (``Measurement.series["command_age_<path>"]``: landing
a_j and sample s_j of every command that took over the plant, on the plant's clock), sample index
round((s_j - t0) / ts) and latency a_j - s_j. From a scenario: its [timing] delay plus the
jitter's draw per seed. *Scaled by k*, the loop samples every k ts and every latency is k times
the base one: every command age is k times the base.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hil.analysis.measure.folder import measured
from hil.errors import BadInputError
from hil.folder import layout, load_folder, read_scenario
from hil.scenario import Scenario, parse_scenario
from hil.sim.adversary.loop import LOST, Schedule
from plant_emulator.landing import extra_delays

NS = 1e-9


@dataclass(frozen=True)
class BaseTiming:
    """Per-sample latencies (s; NaN = lost) of G draws over K samples at period ``ts``."""

    ts: float
    latency: np.ndarray
    source: str
    measured_d_s: float | None = None  # the run's D (hil.analysis.measure), for a run
    path: str | None = None  # the applied path the latencies come from
    cyclic: bool = False  # a run's one draw, replayed from several starting samples

    def draws(self, n: int, k_samples: int) -> np.ndarray:
        """(n, k_samples) latencies: a scenario's draw per seed (cycled when longer), or a
        run's, cyclically from n starting samples spread over the run, the first one placing
        the run's longest age in the middle of the window."""
        g, k = self.latency.shape
        cols = np.arange(k_samples)
        if not self.cyclic:
            return self.latency[(np.arange(n) % g)[:, None], (cols % k)[None, :]]
        row = self.latency[0]
        landed = np.flatnonzero(~np.isnan(row))
        if landed.size == 0:
            return np.full((n, k_samples), np.nan)
        # The age at each landing's end: the gap to the next landing plus that one's latency.
        nxt = np.append(landed[1:], landed[0] + k)
        age_end = (nxt - landed) * self.ts + row[nxt % k]
        worst = int(landed[int(np.argmax(age_end))])
        first = (worst - k_samples // 2) % k
        starts = (first + np.arange(n) * max(1, k // n)) % k
        return row[(starts[:, None] + cols[None, :]) % k]


def from_scenario(scenario: Scenario, seeds: int) -> BaseTiming:
    """The scenario's [timing] (delay + jitter) for ``seeds`` jitter seeds."""
    t = scenario.timing
    if t.jitter_kind == "replay":
        raise BadInputError("hil margin takes a scenario's delay and jitter, not a replay file")
    k = max(1, round(scenario.run.duration / t.ts))
    rows = [t.delay + extra_delays(t.jitter_kind, t.jitter, t.seed + i, k) for i in range(seeds)]
    return BaseTiming(t.ts, np.array(rows), f"scenario timing (ts {t.ts:g} s, delay {t.delay:g} s)")


def run_scenario(folder: Path) -> Scenario:
    """The scenario a run folder ran (its scenario.resolved.toml)."""
    return parse_scenario(read_scenario(folder), folder, str(folder / layout.SCENARIO_RESOLVED))


def from_run(folder: Path, scenario: Scenario) -> BaseTiming:
    """The applied path's measured landings of a run folder (module doc), from its measurement
    (:func:`hil.analysis.measure.folder.measured`: the saved series, or the hop logs measured
    once)."""
    m = measured(load_folder(folder, lazy=True))
    if m is None:
        raise BadInputError(f"{folder} has no hop logs: not a run of hil run")
    path = m.series.get("applied_path")
    seg = m.series.get(f"command_age_{path}") if path else None
    if seg is None or len(seg) == 0:
        raise BadInputError(f"{folder}: no command landed on the applied path")
    ts = scenario.timing.ts
    sample, land = (np.asarray(x, dtype=np.int64) for x in (seg.sample, seg.start))
    # The segments cover the measured window: the first starts at its start (a start-up hold
    # is a segment whose sample is that start, zero torque), the last ends at its end.
    t0 = int(min(sample[0], land[0]))
    real = ~((land == t0) & (sample == t0))
    index = np.rint((sample[real] - t0) * NS / ts).astype(np.int64)
    span = round((int(seg.end[-1]) - t0) * NS / ts)
    k = max(int(index.max()) + 1 if index.size else 1, span)
    latency = np.full(k, np.nan)
    ok = (index >= 0) & (index < k)
    latency[index[ok]] = (land[real][ok] - sample[real][ok]) * NS
    # Replayed cyclically, the run's start-up hold and its unlanded tail would join into one
    # gap the run never had: the cycle runs from the first landed sample to the last.
    landed = np.flatnonzero(~np.isnan(latency))
    if landed.size:
        latency = latency[landed[0] : landed[-1] + 1]
    cert = m.certificate or {}
    d = cert.get("d_max_s") if hasattr(cert, "get") else None
    return BaseTiming(ts, latency[None, :], str(folder), d, str(path), cyclic=True)


def scaled(
    scenario: Scenario, base: BaseTiming, k: float, n: int, duration: float
) -> tuple[Scenario, Schedule]:
    """The scenario at period k ts and ``duration`` s, and the schedule of ``n`` loops with
    every latency scaled by k (module doc)."""
    ts = k * base.ts
    if not (math.isfinite(ts) and ts > 0.0):
        raise BadInputError(f"scale k = {k!r} gives no sample period")
    timing = dataclasses.replace(scenario.timing, ts=ts, delay=0.0, jitter=0.0)
    run = dataclasses.replace(scenario.run, duration=duration)
    sc = dataclasses.replace(scenario, timing=timing, run=run)
    lat = base.draws(n, max(1, round(duration / ts)))
    h = sc.plant_step
    land = np.where(np.isnan(lat), LOST, np.rint(k * np.nan_to_num(lat) / h)).astype(np.int64)
    return sc, Schedule(ts, h, land, np.arange(n, dtype=np.intp))
