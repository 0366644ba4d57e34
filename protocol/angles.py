"""Angle wrapping, in one place for the plant, the simulator, the run results and the reports."""

from __future__ import annotations

import math
from typing import Any

import numpy as np


def wrap_angle(a: Any) -> Any:
    """An angle (a float or an array of them) wrapped to (-pi, pi], as theta_e of (4) is
    reported (the laws that need continuity use unwrapped angles)."""
    if isinstance(a, np.ndarray):
        w = np.mod(a + np.pi, 2.0 * np.pi) - np.pi
        return np.where(w == -np.pi, np.pi, w)
    w = math.fmod(a + math.pi, 2.0 * math.pi)
    if w < 0.0:
        w += 2.0 * math.pi
    w -= math.pi
    return math.pi if w == -math.pi else w
