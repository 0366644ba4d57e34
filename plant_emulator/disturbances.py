"""Matched disturbances d1, d2 of model (1), bounded as in Assumption 1 (|d1| <= s1, |d2| <= s2).

Every disturbance is a pure function of time (and, for ``random``, of a seed), so the offline
simulator, the batch path, lockstep and the real-time plant all see the same values. The random
kind is piecewise constant with hold ``period``: the value on hold ``j`` is a hash of
(seed, channel, j) (splitmix64), uniform in [-s, s]. ``disturbance_at`` works on a float time with
an int seed (real-time path) and with numpy arrays of per-robot seeds (batch path).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

KINDS = ("none", "constant", "sine", "random")

_MASK = 0xFFFFFFFFFFFFFFFF
_GOLDEN = 0x9E3779B97F4A7C15
_M1 = 0xBF58476D1CE4E5B9
_M2 = 0x94D049BB133111EB
_INV_2_53 = 1.0 / 9007199254740992.0


@dataclass(frozen=True)
class Disturbance:
    """One [disturbance] table of the scenario (see docs/scenario.md).

    ``s1``, ``s2`` are the bounds of Assumption 1 that the design uses; the signal itself is set
    by the kind's own keys (constant: value1, value2; sine: amplitude1, amplitude2, freq, phase;
    random: uniform in [-s1, s1] and [-s2, s2], held for ``period`` seconds, seeded by ``seed``).
    """

    kind: str = "none"
    s1: float = 0.0
    s2: float = 0.0
    value1: float = 0.0
    value2: float = 0.0
    amplitude1: float = 0.0
    amplitude2: float = 0.0
    freq: float = 0.0
    phase: float = 0.0
    period: float = 0.1
    seed: int = 0

    @property
    def is_zero(self) -> bool:
        return self.kind == "none" or (
            self.kind == "constant" and self.value1 == 0.0 and self.value2 == 0.0
        )

    @property
    def is_constant(self) -> bool:
        """True when d does not depend on time (lets integrators evaluate it once a step)."""
        return self.kind in ("none", "constant")


def splitmix64(x: int) -> int:
    """One splitmix64 output for a 64-bit integer input (Python ints, wrapped to 64 bits)."""
    z = (x + _GOLDEN) & _MASK
    z = ((z ^ (z >> 30)) * _M1) & _MASK
    z = ((z ^ (z >> 27)) * _M2) & _MASK
    return z ^ (z >> 31)


def splitmix64_array(x: np.ndarray) -> np.ndarray:
    """:func:`splitmix64` on a uint64 array (numpy wraps unsigned products modulo 2**64)."""
    z = x.astype(np.uint64) + np.uint64(_GOLDEN)
    z = (z ^ (z >> np.uint64(30))) * np.uint64(_M1)
    z = (z ^ (z >> np.uint64(27))) * np.uint64(_M2)
    return z ^ (z >> np.uint64(31))


def hash_unit(seed: Any, channel: int, index: Any) -> Any:
    """A value in [0, 1) that is a pure function of (seed, channel, index).

    Floats in, float out; any array in, array out. Equal inputs give bit-identical outputs on
    both paths (the hash is integer arithmetic, the scaling is one exact multiply).
    """
    if isinstance(seed, np.ndarray) or isinstance(index, np.ndarray):
        s = np.asarray(seed, dtype=np.int64).astype(np.uint64)
        i = np.asarray(index, dtype=np.int64).astype(np.uint64)
        z = splitmix64_array(splitmix64_array(splitmix64_array(s) + np.uint64(channel)) + i)
        return (z >> np.uint64(11)).astype(np.float64) * _INV_2_53
    z = splitmix64(
        (splitmix64((splitmix64(int(seed) & _MASK) + channel) & _MASK) + int(index)) & _MASK
    )
    return float(z >> 11) * _INV_2_53


def hash_normal(seed: Any, channel: int, index: Any) -> Any:
    """A standard normal value, a pure function of (seed, channel, index) (Box-Muller)."""
    u1 = hash_unit(seed, 2 * channel, index)
    u2 = hash_unit(seed, 2 * channel + 1, index)
    if isinstance(u1, np.ndarray):
        return np.sqrt(-2.0 * np.log1p(-u1)) * np.cos(2.0 * np.pi * u2)
    return math.sqrt(-2.0 * math.log1p(-u1)) * math.cos(2.0 * math.pi * u2)


def hold_index(dist: Disturbance, t: float) -> int:
    """Index of the hold interval of the random disturbance containing time ``t`` (t >= 0)."""
    j = math.floor(t / dist.period)
    return j if j > 0 else 0


def disturbance_at(dist: Disturbance, t: float, seed: Any = None) -> tuple[Any, Any]:
    """(d1, d2) at time ``t``.

    ``seed`` overrides ``dist.seed`` (an int, or a numpy array of per-robot seeds, in which case
    the random kind returns arrays). Non-random kinds return floats whatever the seed.
    """
    kind = dist.kind
    if kind == "none":
        return 0.0, 0.0
    if kind == "constant":
        return dist.value1, dist.value2
    if isinstance(t, np.ndarray):  # per-robot times (a batch whose loops start apart)
        return _disturbance_at_times(dist, t, seed)
    if kind == "sine":
        s = math.sin(2.0 * math.pi * dist.freq * t + dist.phase)
        return dist.amplitude1 * s, dist.amplitude2 * s
    if kind == "random":
        sd = dist.seed if seed is None else seed
        j = hold_index(dist, t)
        u1 = hash_unit(sd, 1, j)
        u2 = hash_unit(sd, 2, j)
        return dist.s1 * (2.0 * u1 - 1.0), dist.s2 * (2.0 * u2 - 1.0)
    raise ValueError(f"unknown disturbance kind {kind!r}; expected one of {KINDS}")


def _disturbance_at_times(dist: Disturbance, t: np.ndarray, seed: Any) -> tuple[Any, Any]:
    """:func:`disturbance_at` at an array of times (the same formulas on numpy)."""
    kind = dist.kind
    if kind == "sine":
        s = np.sin(2.0 * math.pi * dist.freq * t + dist.phase)
        return dist.amplitude1 * s, dist.amplitude2 * s
    if kind == "random":
        sd = np.broadcast_to(np.asarray(dist.seed if seed is None else seed, np.int64), t.shape)
        j = np.maximum(np.floor(t / dist.period), 0.0).astype(np.int64)
        u1 = hash_unit(sd, 1, j)
        u2 = hash_unit(sd, 2, j)
        return dist.s1 * (2.0 * u1 - 1.0), dist.s2 * (2.0 * u2 - 1.0)
    raise ValueError(f"unknown disturbance kind {kind!r}; expected one of {KINDS}")


def max_abs(dist: Disturbance) -> tuple[float, float]:
    """The largest |d1|, |d2| this disturbance can produce (compare with s1, s2)."""
    if dist.kind == "constant":
        return abs(dist.value1), abs(dist.value2)
    if dist.kind == "sine":
        return abs(dist.amplitude1), abs(dist.amplitude2)
    if dist.kind == "random":
        return dist.s1, dist.s2
    return 0.0, 0.0
