"""The sweep grid of ``hil sweep`` and the break point, as pure functions.

Grid: every combination of [sweep] ts x delay x jitter x seed (seeds = N gives seeds
0..N-1 added to the scenario's timing seed). Points are grouped by Ts because one batch of the
simulator shares its period; delay, jitter and seed vary inside a batch.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, TypedDict

from hil.folder.records import LawFaultRecord
from hil.verdict import FAIL, PASS

# Defaults when the scenario has no [sweep] table: Ts from 0.5 ms to 50 ms around the paper's
# 1 ms; delays from none to 50 ms (the probe of docs/design.md, section 2, broke phi1 at
# Ts = 50 ms, 100 ms delay only with m1 near its bound); no extra jitter; one seed.
DEFAULT_TS: tuple[float, ...] = (0.0005, 0.001, 0.002, 0.005, 0.01, 0.02, 0.05)
DEFAULT_DELAY: tuple[float, ...] = (0.0, 0.002, 0.01, 0.05)
DEFAULT_JITTER: tuple[float, ...] = (0.0,)
DEFAULT_SEEDS = 1


class SweepRow(TypedDict, total=False):
    """One point of a sweep as sweep.csv writes it (hil.sweep.runner.point_row, in this order;
    ``law_fault_record``: the first law fault's whole record, taken out before it is written)."""

    ts: float
    delay: float
    jitter: float
    seed: int
    age: float
    final_position_error: float
    rms_position_error: float
    max_abs_v: float
    max_abs_omega: float
    max_abs_tau1: float
    max_abs_tau2: float
    overshoot_v: float
    overshoot_omega: float
    band_v: float | None
    band_w: float | None
    violations: int
    violation: bool
    nonfinite_steps: int
    law_fault: str | None
    v_bound: float | None
    w_bound: float | None
    certified: bool | None
    within_bound: bool | None
    commands_dropped: int
    complete: bool
    law_fault_record: LawFaultRecord


@dataclass(frozen=True)
class SweepPoint:
    ts: float
    delay: float
    jitter: float
    seed: int


@dataclass(frozen=True)
class SweepGrid:
    ts: tuple[float, ...]
    delay: tuple[float, ...]
    jitter: tuple[float, ...]
    seeds: int
    defaulted: tuple[str, ...] = ()

    def by_ts(self, base_seed: int = 0) -> list[tuple[float, list[SweepPoint]]]:
        """Groups of one Ts each, the longest Ts first: coarse periods are cheap (few samples),
        so an interrupted sweep has already covered the whole range of Ts it could."""
        axes = list(itertools.product(self.delay, self.jitter, range(self.seeds)))
        return [
            (ts, [SweepPoint(ts, d, j, base_seed + s) for d, j, s in axes])
            for ts in sorted(self.ts, reverse=True)
        ]

    def __len__(self) -> int:
        return len(self.ts) * len(self.delay) * len(self.jitter) * self.seeds


def _span(values: Iterable[float]) -> str:
    got = sorted(set(values))
    return f"{got[0]:g} s" if len(got) == 1 else f"{got[0]:g}–{got[-1]:g} s"


def points_label(points: Sequence[SweepPoint], index: int, count: int, what: str = "group") -> str:
    """The grid point(s) running now, for the progress line: their Ts, delays, jitters and
    seeds, and which ``what`` (a group of one Ts, or one point) of ``count`` they are."""
    parts = [f"Ts = {_span(p.ts for p in points)}", f"delay {_span(p.delay for p in points)}"]
    if any(p.jitter for p in points):
        parts.append(f"jitter {_span(p.jitter for p in points)}")
    seeds = len({p.seed for p in points})
    if seeds > 1:
        parts.append(f"{seeds} seeds")
    at_once = f", {len(points)} loops at once" if len(points) > 1 else ""
    return f"{', '.join(parts)} ({what} {index} of {count}{at_once})"


def _values(name: str, raw: Iterable[Any], positive: bool) -> tuple[float, ...]:
    out = []
    for v in raw:
        if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
            raise ValueError(f"[sweep] {name}: {v!r} is not a finite number")
        if v < 0 or (positive and v == 0):
            raise ValueError(f"[sweep] {name}: {v!r} must be {'> 0' if positive else '>= 0'}")
        out.append(float(v))
    return tuple(sorted(set(out)))


def make_grid(
    ts: Sequence[float] = (),
    delay: Sequence[float] = (),
    jitter: Sequence[float] = (),
    seeds: int = 0,
) -> SweepGrid:
    """The grid with defaults for empty axes (listed in ``defaulted``); ValueError on a bad
    value (negative, zero period, not a number)."""
    if isinstance(seeds, bool) or not isinstance(seeds, int) or seeds < 0:
        raise ValueError(f"[sweep] seeds: {seeds!r} must be a whole number >= 1")
    given = {"ts": ts, "delay": delay, "jitter": jitter, "seeds": seeds}
    return SweepGrid(
        _values("ts", ts or DEFAULT_TS, True),
        _values("delay", delay or DEFAULT_DELAY, False),
        _values("jitter", jitter or DEFAULT_JITTER, False),
        int(seeds or DEFAULT_SEEDS),
        tuple(name for name, value in given.items() if not value),
    )


class GridPoint(TypedDict):
    """One loop of the grid: its period, delay, jitter and seed."""

    ts: float
    delay: float
    jitter: float
    seed: int


class LawFaultPoint(GridPoint):
    law_fault: str  # the sentence of hil.verdict.LawEnd


class BreakPoints(TypedDict, total=False):
    """Where the limits stop holding (:func:`break_points`; sweep.json ``break_point``)."""

    held_everywhere: bool | None  # None: no loop ran
    violating_points: int
    law_faults: int
    first_law_fault: LawFaultPoint | None
    ts_by_delay: dict[float, float | None]
    delay_by_ts: dict[float, float | None]
    first: GridPoint | None


class CertifiedBreak(TypedDict):
    """The certificate's own prediction over the grid (hil.sweep.runner.certified_break)."""

    first_uncertified: dict[str, float] | None  # ts, delay, jitter, age = ts + worst delay


def _point(r: Mapping[str, Any]) -> GridPoint:
    return GridPoint(ts=r["ts"], delay=r["delay"], jitter=r["jitter"], seed=r["seed"])


def break_points(rows: Sequence[Mapping[str, Any]]) -> BreakPoints:
    """Where the limits stop holding.

    - ``ts_by_delay``: for each delay, the smallest Ts at which any loop (any jitter, seed)
      broke a constraint of (2); None if none did.
    - ``delay_by_ts``: for each Ts, the smallest delay at which one did.
    - ``first``: the violating point with the smallest Ts + delay (the age of the command that
      the sampled-data bound grows with), or None when no limit broke.
    - ``law_faults``: the points where the law failed (raised, returned the wrong type or a
      non-finite torque), and ``first_law_fault`` the first of them with its sentence: a
      faulted point never counts as held, so ``held_everywhere`` is false when there is one.
    """
    ts_values = sorted({r["ts"] for r in rows})
    delay_values = sorted({r["delay"] for r in rows})
    bad = [r for r in rows if r.get("violation")]
    faulted = [r for r in rows if r.get("law_fault")]
    ts_by_delay = {
        d: min((r["ts"] for r in bad if r["delay"] == d), default=None) for d in delay_values
    }
    delay_by_ts = {
        ts: min((r["delay"] for r in bad if r["ts"] == ts), default=None) for ts in ts_values
    }
    first = min(bad, key=lambda r: (r["ts"] + r["delay"], r["ts"]), default=None)
    first_fault = min(faulted, key=lambda r: (r["ts"] + r["delay"], r["ts"]), default=None)
    fault_at = None
    if first_fault is not None:
        fault_at = LawFaultPoint(**_point(first_fault), law_fault=first_fault["law_fault"])
    return BreakPoints(
        held_everywhere=not bad and not faulted,
        violating_points=len(bad),
        law_faults=len(faulted),
        first_law_fault=fault_at,
        ts_by_delay=ts_by_delay,
        delay_by_ts=delay_by_ts,
        first=None if first is None else _point(first),
    )


def aggregate(
    rows: Sequence[Mapping[str, Any]], metric: str, how: str = "max"
) -> dict[tuple[float, float], float]:
    """metric over jitter and seeds for each (ts, delay): the worst case ("max") or "mean"
    (points where the law failed left out)."""
    groups: dict[tuple[float, float], list[float]] = {}
    for r in rows:
        if r.get("law_fault"):  # what ran until the law failed says nothing of held limits
            continue
        v = r.get(metric)
        if isinstance(v, int | float) and math.isfinite(v):
            groups.setdefault((r["ts"], r["delay"]), []).append(float(v))
    if how == "mean":
        return {k: sum(v) / len(v) for k, v in groups.items()}
    return {k: max(v) for k, v in groups.items()}


def coverage(rows: Sequence[Mapping[str, Any]], loops: int) -> dict[str, int]:
    """How much of a grid of ``loops`` loops the rows cover: ``covered`` (loops run to their
    end), ``cut_short`` (a loop the interrupt stopped: a limit it broke is a break, a limit it
    held says nothing of the rest) and ``not_run``."""
    covered = sum(1 for r in rows if r.get("complete", True))
    return {
        "loops": loops,
        "covered": covered,
        "cut_short": len(rows) - covered,
        "not_run": max(0, loops - len(rows)),
    }


def coverage_sentence(cov: Mapping[str, int]) -> str | None:
    """What a cut-short sweep did not cover, in one sentence (None when it covered all)."""
    missing = cov["loops"] - cov["covered"]
    if missing <= 0:
        return None
    parts = [f"{n} {what}" for n, what in ((cov["cut_short"], "cut short"),
                                           (cov["not_run"], "not run")) if n]  # fmt: skip
    return (
        f"covered {cov['covered']} of {cov['loops']} loops; {missing} not covered "
        f"({', '.join(parts)}): no claim about them"
    )


def break_sentence(bp: Mapping[str, Any], cov: Mapping[str, int], rows: int) -> str:
    """The sweep's answer in one sentence, from its break point and what it covered: never
    "held everywhere" for a grid it did not cover."""
    first = bp.get("first")
    if first is None:
        if cov["covered"] < cov["loops"]:
            return f"No limit of (2) broke in the loops run: {coverage_sentence(cov)}."
        if bp.get("law_faults"):  # where the law failed nothing ran to the end
            return "No limit of (2) broke where the law ran to the end."
        return f"The limits (2) held in all {cov['loops']} loops of the grid."
    among = " among the loops run" if cov["covered"] < cov["loops"] else ""
    return (
        f"The limits (2) first break{among} at Ts = {first['ts']:g} s with a delay of "
        f"{first['delay']:g} s (jitter {first['jitter']:g} s, seed {first['seed']}): "
        f"{bp.get('violating_points', '?')} of {rows} loops broke a limit."
    )


def sweep_outcome(rows: Sequence[Mapping[str, Any]], strict: bool) -> tuple[str, str]:
    """The sweep's verdict and its reason: the break point is the sweep's answer, not a
    failure (PASS, exit 0); FAIL when the law faulted in a loop (``law_fault``: a law that
    raised or returned a non-finite torque is the user's failure wherever it happens), or,
    ``strict``, when any loop broke a limit (the grid was to hold everywhere)."""
    faulted = [r for r in rows if r.get("law_fault")]
    if faulted:
        return FAIL, f"the law faulted in {len(faulted)} of {len(rows)} loops"
    broke = [r for r in rows if r.get("violation")]
    if strict and broke:
        return FAIL, f"a limit of (2) broke in {len(broke)} of {len(rows)} loops (--strict)"
    return PASS, ""
