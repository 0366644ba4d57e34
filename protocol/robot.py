"""The robot's state and its constraints, the types both services and the simulator share.

Model (1) of Li et al. 2024 is the plant's; the constraints (2) bound it and the law. They sit
at the bottom so the plant does not import the controller's package to know a state.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, NamedTuple

from protocol.paper import PAPER_LIMITS

Number = Any  # a float on the real-time path, a numpy array of shape (N,) on the batch path


class RobotState(NamedTuple):
    """Measured state of the robot, model (1): pose and body velocities (SI units)."""

    x: Number
    y: Number
    theta: Number
    v: Number
    omega: Number


@dataclass(frozen=True)
class Limits:
    """The constraints (2): |v| <= phi1, |omega| <= phi2, |tau1| <= varpi1, |tau2| <= varpi2."""

    phi1: float = PAPER_LIMITS["phi1"]
    phi2: float = PAPER_LIMITS["phi2"]
    varpi1: float = PAPER_LIMITS["varpi1"]
    varpi2: float = PAPER_LIMITS["varpi2"]
