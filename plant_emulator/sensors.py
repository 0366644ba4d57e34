"""What the controller measures of model (1): the true state plus seeded noise, then quantized.

Noise on state ``i`` at sample ``k`` is ``std[i] * N(seed, i, k)``, a pure function of
(seed, state index, sample index) (see :func:`plant_emulator.disturbances.hash_normal`), so a
replayed or batched run sees exactly the same measurements. Quantization rounds each state to
a multiple of its step (an encoder's resolution; 0 = exact). Works on floats and on numpy
arrays (per-robot seeds allowed).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from plant_emulator.disturbances import hash_normal
from protocol.robot import RobotState

STATE_NAMES = ("x", "y", "theta", "v", "omega")
# Channels 0..9 of the hash are taken by the two uniforms of each normal; offset them from the
# disturbance's channels so a shared seed never correlates the two.
_CHANNEL_BASE = 16


@dataclass(frozen=True)
class Sensor:
    """Noise standard deviations and quantization steps per state (x, y, theta, v, omega)."""

    noise_std: tuple[float, float, float, float, float] = (0.0, 0.0, 0.0, 0.0, 0.0)
    quantization: tuple[float, float, float, float, float] = (0.0, 0.0, 0.0, 0.0, 0.0)
    seed: int = 0

    @property
    def is_ideal(self) -> bool:
        return not any(self.noise_std) and not any(self.quantization)


def _quantize(value: Any, step: float) -> Any:
    if step <= 0.0:
        return value
    if isinstance(value, np.ndarray):
        with np.errstate(over="ignore", invalid="ignore"):
            q = np.round(value / step) * step
        return np.where(np.isfinite(q), q, value)
    q = value / step
    if not math.isfinite(q):  # a step far below the value's own resolution: nothing to round
        return value
    return round(q) * step


def measure(sensor: Sensor, state: RobotState, k: int, seed: Any = None) -> RobotState:
    """The measured state at control sample ``k`` (``seed`` overrides ``sensor.seed``)."""
    if sensor.is_ideal:
        return state
    sd = sensor.seed if seed is None else seed
    out = []
    for i, value in enumerate(state):
        std = sensor.noise_std[i]
        if std > 0.0:
            value = value + std * hash_normal(sd, _CHANNEL_BASE + i, k)
        out.append(_quantize(value, sensor.quantization[i]))
    return RobotState(*out)
