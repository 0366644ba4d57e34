"""The search for the disturbance that breaks (2) first, on the batch path
(:mod:`hil.sim.adversary.loop`; docs/margin.md, "The worst disturbance": its rounds and scores).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from hil.scenario import Scenario, build_loop
from hil.sim.adversary.loop import MODES, LoopPeaks, Schedule, run_loops
from plant_emulator.dynamics import VIOLATION_RTOL, PlantState

ELITE = 0.1
SMOOTH = 0.7  # weight of the refitted probabilities (the rest stays with the previous ones)
LIMIT_NAMES = ("|v|", "|omega|", "|tau1|", "|tau2|", "position error")


@dataclass
class WorstDisturbance:
    """The worst loop found: its score (> 1: a limit broke), which limit, its pattern (2, B)
    of mode indices into ``MODES``, and how many loops the search ran."""

    score: float
    limit: str
    pattern: np.ndarray
    loops: int
    rounds: list[float] = field(default_factory=list)  # best score after each round
    peaks: dict[str, float] = field(default_factory=dict)  # the worst loop's LoopPeaks
    bounds: tuple[float, float] = (1.0, 1.0)  # s1, s2 the search had

    @property
    def broke(self) -> bool:
        return self.score > 1.0 + VIOLATION_RTOL

    def describe(self) -> str:
        """The pattern in words: one mode per channel when constant, else the share of each."""
        if self.bounds == (0.0, 0.0):
            return "none (s1 = s2 = 0)"
        parts = []
        for name, row in zip(("d1", "d2"), self.pattern, strict=True):
            if (row == row[0]).all():
                parts.append(f"{name} {MODES[int(row[0])]}")
            else:
                shares = ", ".join(
                    f"{m} {np.mean(row == i):.0%}" for i, m in enumerate(MODES) if (row == i).any()
                )
                parts.append(f"{name} switching ({shares} of {row.size} blocks)")
        return "; ".join(parts)

    def as_dict(self) -> dict[str, Any]:
        return {
            "score": self.score,
            "broke": self.broke,
            "limit": self.limit,
            "pattern": self.describe(),
            "loops": self.loops,
            "best_by_round": list(self.rounds),
            "peaks": dict(self.peaks),
        }


def scores(peaks: LoopPeaks, limits: Any, error_bound: float | None) -> tuple[np.ndarray, ...]:
    """Per loop: the largest ratio to a limit and the index of that limit (``LIMIT_NAMES``).
    The torques count only when beyond their limit: the laws clamp them, so a torque at its
    limit (ratio 1 all along for the sign law) says nothing about how close (2) came."""
    tau = np.array([peaks.max_abs_tau1 / limits.varpi1, peaks.max_abs_tau2 / limits.varpi2])
    ratios = [
        peaks.max_abs_v / limits.phi1,
        peaks.max_abs_omega / limits.phi2,
        np.where(tau > 1.0 + VIOLATION_RTOL, tau, 0.0),  # two rows: |tau1|, |tau2|
        peaks.max_late_error / error_bound if error_bound else np.zeros_like(peaks.max_abs_v),
    ]
    stacked = np.vstack(ratios)
    return stacked.max(axis=0), stacked.argmax(axis=0)


def _first_patterns(n: int, blocks: int, rng: np.random.Generator) -> np.ndarray:
    """Round 0: the 16 constant patterns, then random ones (modes other than none)."""
    modes = rng.integers(1, len(MODES), (n, 2, blocks), dtype=np.int8)
    fixed = [(a, b) for a in range(len(MODES)) for b in range(len(MODES))]
    for i, (a, b) in enumerate(fixed[:n]):
        modes[i, 0, :], modes[i, 1, :] = a, b
    return modes


def _refit(probs: np.ndarray, elite: np.ndarray) -> np.ndarray:
    """Cross-entropy update of the (2, B, M) mode probabilities from elite patterns (E, 2, B)."""
    counts = np.stack([(elite == i).mean(axis=0) for i in range(len(MODES))], axis=-1)
    return SMOOTH * counts + (1.0 - SMOOTH) * probs


def _draw(probs: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    cum = np.cumsum(probs, axis=-1)
    u = rng.random((n, *probs.shape[:2], 1))
    return np.minimum((u > cum[None]).sum(axis=-1), len(MODES) - 1).astype(np.int8)


def worst_disturbance(
    scenario: Scenario,
    schedule: Schedule,
    initial: PlantState,
    *,
    rounds: int = 3,
    blocks: int = 16,
    seed: int = 0,
    error_bound: float | None = None,
    stop_on_break: bool = False,
    memory: Any = None,
    loop: tuple[Any, Any, Any] | None = None,
) -> WorstDisturbance:
    """Search the patterns over ``rounds`` batches of N loops (N = the schedule's loops, each
    from its ``initial`` state and the law's ``memory``, default its initial memory);
    ``stop_on_break``: stop at the first round that broke a limit (enough for a bisection)."""
    loop = loop or build_loop(scenario)
    n = len(schedule.group)
    rng = np.random.default_rng(seed)
    modes = _first_patterns(n, blocks, rng)
    probs = np.full((2, blocks, len(MODES)), 1.0 / len(MODES))
    kept_modes = np.zeros((0, 2, blocks), dtype=np.int8)
    kept_scores = np.zeros(0)
    dist = scenario.disturbance
    best = WorstDisturbance(-np.inf, "", modes[0], 0, bounds=(float(dist.s1), float(dist.s2)))
    if best.bounds == (0.0, 0.0):
        rounds = min(rounds, 1)  # no disturbance to search: every pattern is the same loop
    for _ in range(rounds):
        peaks = run_loops(scenario, schedule, modes, initial, memory, loop)
        score, which = scores(peaks, scenario.limits, error_bound)
        i = int(np.argmax(score))
        best.loops += n
        if score[i] > best.score:
            best.score, best.limit, best.pattern = float(score[i]), LIMIT_NAMES[which[i]], modes[i]
            best.peaks = {k: float(v[i]) for k, v in vars(peaks).items()}
        best.rounds.append(best.score)
        if stop_on_break and best.broke:
            break
        kept_modes = np.concatenate([kept_modes, modes])
        kept_scores = np.concatenate([kept_scores, score])
        top = np.argsort(kept_scores)[-max(1, int(ELITE * len(kept_scores))) :]
        probs = _refit(probs, kept_modes[top])
        modes = _draw(probs, n, rng)
    return best
