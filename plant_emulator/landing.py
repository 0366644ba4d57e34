"""When sampled commands land at the plant: constant delay plus seeded jitter (or a replay).

Sample k is taken at t_k = k Ts; its command lands at t_k + delay + extra_k, rounded to the plant
step h. extra_k is drawn once per run from ``numpy.random.default_rng(seed)``:
``uniform``: U[0, jitter]; ``normal``: |N(0, jitter)| (a half-normal of scale ``jitter``);
``replay``: given latencies, cycled in order (``jitter`` is ignored, ``delay`` adds).
The draw depends only on (kind, jitter, seed, number of samples), so the offline simulator
(:mod:`hil.sim`) and the plant in lockstep see the same landing times.
"""

from __future__ import annotations

import numpy as np

from protocol.errors import BadInputError


def extra_delays(
    kind: str, jitter: float, seed: int, n: int, replay: np.ndarray | None = None
) -> np.ndarray:
    """The extra delay of each of ``n`` samples (seconds)."""
    if kind == "replay":
        if replay is None or replay.size == 0:
            raise BadInputError("[timing] replay: no latencies")
        return np.resize(replay, n).astype(float)
    if jitter <= 0.0:
        return np.zeros(n)
    rng = np.random.default_rng(seed)
    if kind == "uniform":
        return rng.uniform(0.0, jitter, n)
    if kind == "normal":
        return np.abs(rng.normal(0.0, jitter, n))
    raise BadInputError(f"[timing] jitter_kind {kind!r} unknown")


def landing_offsets(delays: np.ndarray, delay: float, h: float) -> np.ndarray:
    """Plant steps from a sample to its command's landing: round((delay + extra) / h)."""
    steps = np.rint((delay + delays) / h)
    return steps.astype(np.int64)
