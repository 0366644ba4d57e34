"""The unified law with eta re-armed when the reference comes to rest (beyond the paper).

The paper's eta decays as exp(-integral of (vd^2 + wd^2)): after 70 s of its circle eta is about
1e-9, so xi = eta f is gone and a robot whose reference stops no longer removes a lateral error
(the time-varying term is what makes the nonholonomic robot stabilizable). This wrapper resets
eta to 1 at a sample where

- the reference is at rest (|vd| + |wd| <= ``REST_TOL``),
- eta has decayed below ``below`` (default 0.5), and
- at least ``dwell`` seconds of law time have passed since the last reset (or since t = 0),

then runs the paper's law (:class:`controller_service.laws.unified.UnifiedController`)
unchanged on the re-armed memory. While the reference rests eta' = 0, so one reset per stop; the
dwell bounds the resets to one per ``dwell`` even for a reference that stops and starts. eta
stays in [0, 1], which is all the constraint proofs use (docs/laws.md, "eta re-arm").

With ``tol`` (metres, key ``eta_rearm_tol``; default None: eta only) the re-arm also resets
the law's other memory, in two phases. At a sample where the reference is at rest and at least
``dwell`` seconds have passed since the last reset:

- **kick**, while the position error |p| = sqrt(xe^2 + ye^2) exceeds ``tol``:

      eta = 1,   z1 = 0,   z2 = -m2 sgn(xe ye)     (sgn(0) taken as +1)

- **align**, once |p| <= ``tol``, at a sample where the heading error is within
  ``ALIGN_BAND`` (|sin(theta_e / 2)| <= sin(ALIGN_BAND / 2)) and |z2| exceeds m2
  sin(ALIGN_BAND / 2), the most that (8) settles at for such a heading error (a larger z2 is a
  turn still stored in the filter):

      eta = 1,   z1 = 0,   z2 = 0

Why: at rest the paper's law drives v = -z1 and w = xi' - z2, with xi of the order of the
squared error (rho tanh(r - 1) ~ |p|^2 / 2), so a lateral error of 0.15 m is removed over many
minutes. A kick turns the robot towards pointing its axis at the stop point (the sign of xe
ye; it flips once the axis points there), and the law's own xe loop (z1) drives it along that
axis; kicks a dwell apart keep turning it until it does. Once the robot is within ``tol`` the
law's heading loop turns it back; with the sign law sampled at a few ms the heading at rest
moves at a fixed rate (about varpi2 Ts / 2) and z2 lags it by the filter's time constant
2 m2 / l2, so the turn back overshoots and the swings die out over tens of seconds. The align
reset clears that stored lag as the heading crosses its target: afterwards the heading is in
the sign law's own limit cycle. Every reset keeps the memory in the box 0 <= eta <= 1,
|z1| <= m1, |z2| <= m2 that the constraint proofs use (docs/laws.md, "eta re-arm").

Memory: the paper's (eta, z1, z2) and ``since``, the law time since the last reset (starts at
``dwell``: a reference at rest from t = 0 with eta(0) = 1 never triggers an eta-only re-arm).
Telemetry: the paper's keys and ``eta_rearmed`` (1 at the sample where the memory was reset).
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import numpy as np

from controller_service.laws.base import ControlOutput, ReferenceSample, RobotState
from controller_service.laws.unified import UnifiedController, UnifiedMemory
from runtime.mathns import ARRAY_MATH, FLOAT_MATH

REST_TOL = 1e-9  # |vd| + |wd| at or below this is a reference at rest
DWELL_DEFAULT = 5.0  # s between resets at least
BELOW_DEFAULT = 0.5  # reset only an eta that has decayed below this
# rad: the align reset waits for the heading error to be this small. Well below the 0.05 rad a
# stop is judged by, and wider than the heading moves in one sample at rest (|w| is within one
# torque step varpi2 Ts of |alpha_w| <= m2 + |xi'|: about 1 rad/s, 0.01 rad per sample at
# Ts = 10 ms), so the band is not stepped over.
ALIGN_BAND = 0.02
_ALIGN_SIN = math.sin(0.5 * ALIGN_BAND)


def _errors(ns: Any, state: RobotState, ref: ReferenceSample) -> tuple[Any, Any, Any]:
    """xe ye, |p| = sqrt(xe^2 + ye^2) of the errors (4) and sin(theta_e / 2); where they are not
    finite |p| = 0 and sin(theta_e / 2) = 1, so neither a kick nor an align is taken (math
    raises on cos(inf), numpy warns: both quietened, the law rejects that input)."""
    if ns.is_array:
        with np.errstate(all="ignore"):
            return _errors_any(ns, state, ref)
    try:
        return _errors_any(ns, state, ref)
    except (ValueError, OverflowError):
        return 0.0, 0.0, 1.0


def _errors_any(ns: Any, state: RobotState, ref: ReferenceSample) -> tuple[Any, Any, Any]:
    dx = state.x - ref.xd
    dy = state.y - ref.yd
    c = ns.cos(state.theta)
    s = ns.sin(state.theta)
    xe = c * dx + s * dy
    ye = c * dy - s * dx
    p = ns.sqrt(xe * xe + ye * ye)
    # The law's half angle (theta_e is not wrapped); xi is left out: within tol it is at most
    # rho (sqrt(1 + tol^2) - 1), under 1e-3 rad for tol <= 0.04 m, far inside ALIGN_BAND.
    half = ns.sin(0.5 * (state.theta - ref.thetad))
    ok = ns.isfinite(p) & ns.isfinite(half)
    return xe * ye, ns.where(ok, p, 0.0), ns.where(ok, half, 1.0)


class RearmMemory(NamedTuple):
    """The paper's eta, z1, z2 and the law time since eta was last reset."""

    eta: Any
    z1: Any
    z2: Any
    since: Any


class EtaRearmController:
    """:class:`UnifiedController` whose eta is reset to 1 when the reference comes to rest
    (module doc). Same name, parameters and design checks as the wrapped law."""

    def __init__(
        self,
        inner: UnifiedController,
        dwell: float = DWELL_DEFAULT,
        below: float = BELOW_DEFAULT,
        tol: float | None = None,
    ) -> None:
        dwell, below = float(dwell), float(below)
        if not (math.isfinite(dwell) and dwell > 0.0):
            raise ValueError(f"[controller] eta_rearm_dwell must be > 0 s, got {dwell!r}")
        if not (0.0 < below <= 1.0):
            raise ValueError(f"[controller] eta_rearm_below must be in (0, 1], got {below!r}")
        if tol is not None and not (math.isfinite(tol) and tol > 0.0):
            raise ValueError(f"[controller] eta_rearm_tol must be > 0 m, got {tol!r}")
        self.inner = inner
        self.dwell = dwell
        self.below = below
        self.tol = None if tol is None else float(tol)
        self.name = inner.name
        self.params = inner.params
        self.context = inner.context
        self._m2 = float(inner.params.m2)

    def initial_memory(self, n: int | None = None, z1: float = 0.0, z2: float = 0.0) -> Any:
        eta, z1_0, z2_0 = self.inner.initial_memory(n, z1=z1, z2=z2)
        since = self.dwell if n is None else np.full(n, self.dwell)
        return RearmMemory(eta, z1_0, z2_0, since)

    def update(
        self, t: Any, dt: Any, state: RobotState, ref: ReferenceSample, memory: RearmMemory
    ) -> tuple[ControlOutput, RearmMemory]:
        """Reset the memory if the rule of the module doc fires, then the paper's law."""
        arrays = False
        for value in (*memory, *state[:3], *ref[:5]):
            if value.__class__ is not float and isinstance(value, np.ndarray):
                arrays = True
                break
        eta, z1, z2, since, fired = self._rearm(
            ARRAY_MATH if arrays else FLOAT_MATH, state, ref, memory
        )
        out, nxt = self.inner.update(t, dt, state, ref, UnifiedMemory(eta, z1, z2))
        # Input the law rejects leaves the whole memory as it was, the reset included.
        nxt = RearmMemory(*nxt, since + dt)
        bad = out.telemetry["nonfinite"] > 0.0
        if arrays or bad:
            ns = ARRAY_MATH if arrays else FLOAT_MATH
            nxt = RearmMemory(*(ns.where(bad, o, n) for o, n in zip(memory, nxt, strict=True)))
            fired = ns.where(bad, 0.0, fired)
        out.telemetry["eta_rearmed"] = fired
        return out, nxt

    def _rearm(self, ns: Any, state: RobotState, ref: ReferenceSample, memory: RearmMemory) -> Any:
        """The memory after the rule (one source for floats and arrays): eta, z1, z2, since and
        1.0 where it fired (else 0.0)."""
        eta, z1, z2, since = memory
        rest = ns.abs(ref.vd) + ns.abs(ref.wd) <= REST_TOL
        ready = rest & (since >= self.dwell)
        fire = ready & (eta < self.below)
        if self.tol is not None:
            cross, p, half = _errors(ns, state, ref)
            kick = ready & (p > self.tol)
            align = (
                ready
                & (p <= self.tol)
                & (ns.abs(half) <= _ALIGN_SIN)
                & (ns.abs(z2) > self._m2 * _ALIGN_SIN)
            )
            turn = ns.where(cross > 0.0, -1.0, ns.where(cross < 0.0, 1.0, -1.0))
            z1 = ns.where(kick | align, 0.0, z1)
            z2 = ns.where(kick, turn * self._m2, ns.where(align, 0.0, z2))
            fire = fire | kick | align
        eta = ns.where(fire, 1.0, eta)
        since = ns.where(fire, 0.0, since)
        return eta, z1, z2, since, ns.where(fire, 1.0, 0.0)

    def signals(self, t: Any, state: RobotState, ref: ReferenceSample, memory: Any) -> Any:
        return self.inner.signals(t, state, ref, UnifiedMemory(*memory[:3]))

    def resolved_table(self) -> dict[str, Any]:
        """The wrapped law's table and the re-arm keys."""
        return {
            **self.inner.resolved_table(),
            "eta_rearm": True,
            "eta_rearm_dwell": self.dwell,
            "eta_rearm_below": self.below,
            **({} if self.tol is None else {"eta_rearm_tol": self.tol}),
        }
