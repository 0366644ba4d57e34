"""Baseline [7]: the backstepping tracker of Jiang & Nijmeijer 1997 (Automatica 33(7)).

The paper (Li et al. 2024, Section 4) uses it with c1 = 7, c2 = 0.1 to show a tracker that
ignores the velocity constraints (its Figure 16: |v| goes beyond phi1 = 1.6).

Form used. The original text could not be retrieved (searches found only citations), so the law
is the Lyapunov design of [7]'s global kinematic tracker with its two named gains, written in
this project's error coordinates (4) (robot minus reference, robot frame; [7] uses the
opposite sign, which flips the signs of xe, ye, theta_e but not the law):

    V = (xe^2 + ye^2)/2 + c2 theta_e^2/2,   theta_e wrapped to (-pi, pi]
    v_c = vd cos theta_e - c1 xe
    w_c = wd - (vd/c2) ye sin(theta_e)/theta_e - c1 theta_e
    V'  = -c1 xe^2 - c1 c2 theta_e^2   along (5) with v = v_c, w = w_c.

(c2 weighs theta_e in V, so 1/c2 = 10 is the lateral coupling gain; read the other way round,
c2 = 0.1 as the coupling gain, the lateral error decays too slowly to show [7]'s asymptotic
tracking within the paper's run.)

No saturation is designed in: with c1 = 7 an initial error of 1 m asks for |v| ~ 7 m/s.

Inner velocity loop (the paper's model (1) is driven by torques): [7] backsteps the kinematic
law into the dynamics; here the same role is played by the stated loop

    tau1 = clip(dv_c/dt - kv (v - v_c), -varpi1, varpi1)
    tau2 = clip(dw_c/dt - kw (w - w_c), -varpi2, varpi2)

with dv_c/dt, dw_c/dt the backward differences of the commands over the control period (0 at
the first sample) and kv = kw = 20 1/s by default (``inner_kv``, ``inner_kw``). The memory is
(v_c, w_c, primed) of the previous sample. A non-finite input gives zero torque, telemetry
``nonfinite = 1`` and the memory unchanged.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any, NamedTuple

import numpy as np

from controller_service.laws.base import (
    ControlOutput,
    DesignContext,
    ReferenceSample,
    RobotState,
)
from runtime.mathns import ARRAY_MATH, FLOAT_MATH

INNER_K_DEFAULT = 20.0
POSITIVE_MAX = 1e9  # the largest gain or time a baseline's table may give
BASELINE_TELEMETRY_KEYS = ("xe", "ye", "theta_e", "v_c", "w_c", "mode", "nonfinite")


class VelocityLoopMemory(NamedTuple):
    """The previous velocity commands, for the feed-forward difference; primed = 0 at start."""

    v_c: Any
    w_c: Any
    primed: Any


def tracking_errors(ns: Any, state: RobotState, ref: ReferenceSample) -> tuple[Any, Any, Any]:
    """Errors (4): xe, ye in the robot frame (robot minus reference) and theta_e wrapped to
    (-pi, pi] (the baselines use theta_e itself, not half angles)."""
    dx = state.x - ref.xd
    dy = state.y - ref.yd
    c = ns.cos(state.theta)
    s = ns.sin(state.theta)
    the = state.theta - ref.thetad
    the = ns.atan2(ns.sin(the), ns.cos(the))
    return c * dx + s * dy, c * dy - s * dx, the


def sinc(ns: Any, x: Any) -> Any:
    """sin(x)/x with sinc(0) = 1 (no division by zero on either path)."""
    small = ns.abs(x) < 1e-8
    safe = ns.where(small, 1.0, x)
    return ns.where(small, 1.0 - x * x / 6.0, ns.sin(safe) / safe)


# A kinematic law: (ns, t, state, ref) -> (v_c, w_c, mode, xe, ye, theta_e).
KinematicLaw = Callable[[Any, Any, RobotState, ReferenceSample], tuple[Any, ...]]


class VelocityLoopController:
    """A kinematic law (v_c, w_c) turned into torques by the stated inner velocity loop."""

    name = "velocity_loop"

    def __init__(self, context: DesignContext, inner_kv: float, inner_kw: float) -> None:
        for key, value in (("inner_kv", inner_kv), ("inner_kw", inner_kw)):
            if not (isinstance(value, int | float) and not isinstance(value, bool)):
                raise ValueError(f"{key} must be a number, got {value!r}")
            if not (0.0 < value < float("inf")):
                raise ValueError(f"{key} must be a finite number > 0, got {value!r}")
        self.context = context
        self.inner_kv = float(inner_kv)
        self.inner_kw = float(inner_kw)
        self._varpi1 = float(context.limits.varpi1)
        self._varpi2 = float(context.limits.varpi2)

    def kinematic(self, ns: Any, t: Any, state: RobotState, ref: ReferenceSample) -> tuple:
        raise NotImplementedError

    def initial_memory(
        self, n: int | None = None, z1: float = 0.0, z2: float = 0.0
    ) -> VelocityLoopMemory:
        """Previous commands 0, not primed; z1, z2 are ignored (no adaptive states of (8))."""
        if n is None:
            return VelocityLoopMemory(0.0, 0.0, 0.0)
        return VelocityLoopMemory(np.zeros(n), np.zeros(n), np.zeros(n))

    def update(
        self,
        t: float,
        dt: float,
        state: RobotState,
        ref: ReferenceSample,
        memory: VelocityLoopMemory,
    ) -> tuple[ControlOutput, VelocityLoopMemory]:
        """Torques from the kinematic commands at t; the memory holds them for t + dt."""
        arrays = (
            isinstance(state.x, np.ndarray)
            or isinstance(memory.v_c, np.ndarray)
            or isinstance(ref.xd, np.ndarray)
        )
        ns = ARRAY_MATH if arrays else FLOAT_MATH
        fields = (*state, *ref[:5], *memory, t, dt)
        if arrays:
            raw, ok, clean = _finite_arrays(fields)
        else:
            acc = 0.0
            for f in fields:
                acc += f - f
            if acc != 0.0:
                return self._reject_float(memory)
            clean = list(fields)
        try:
            with np.errstate(all="ignore"):
                loop = self._loop(ns, clean)
        except (ValueError, OverflowError, ZeroDivisionError):
            # Only the float path raises: finite but huge input overflows math functions.
            return self._reject_float(memory)
        if not arrays:
            return self._float_output(memory, *loop)
        return _array_output(raw[10:13], ok, *loop)

    def _loop(self, ns: Any, clean: list[Any]) -> tuple[Any, ...]:
        """The kinematic commands and the inner velocity loop's torques (module docstring)."""
        st = RobotState(*clean[0:5])
        rf = ReferenceSample(*clean[5:10])
        mem = VelocityLoopMemory(*clean[10:13])
        t_c, dt_c = clean[13], clean[14]
        v_c, w_c, mode, xe, ye, the = self.kinematic(ns, t_c, st, rf)
        inv_dt = 1.0 / ns.where(dt_c > 0.0, dt_c, 1.0)
        dv_ff = mem.primed * (v_c - mem.v_c) * inv_dt
        dw_ff = mem.primed * (w_c - mem.w_c) * inv_dt
        tau1 = ns.clip(dv_ff - self.inner_kv * (st.v - v_c), -self._varpi1, self._varpi1)
        tau2 = ns.clip(dw_ff - self.inner_kw * (st.omega - w_c), -self._varpi2, self._varpi2)
        return tau1, tau2, v_c, w_c, mode, xe, ye, the

    def _float_output(
        self, memory: VelocityLoopMemory, *loop: Any
    ) -> tuple[ControlOutput, VelocityLoopMemory]:
        tau1, tau2, v_c, w_c, mode, xe, ye, the = loop
        acc = (tau1 - tau1) + (tau2 - tau2) + (v_c - v_c) + (w_c - w_c)
        if acc != 0.0:
            return self._reject_float(memory)
        telemetry = {
            "xe": xe,
            "ye": ye,
            "theta_e": the,
            "v_c": v_c,
            "w_c": w_c,
            "mode": mode,
            "nonfinite": 0.0,
        }
        return ControlOutput(tau1, tau2, telemetry), VelocityLoopMemory(v_c, w_c, 1.0)

    def _reject_float(self, memory: VelocityLoopMemory) -> tuple[ControlOutput, Any]:
        telemetry = dict.fromkeys(BASELINE_TELEMETRY_KEYS, 0.0)
        telemetry["nonfinite"] = 1.0
        return ControlOutput(0.0, 0.0, telemetry), memory


def _finite_arrays(fields: tuple[Any, ...]) -> tuple[list[np.ndarray], np.ndarray, list[Any]]:
    """The inputs broadcast to one shape, the mask of lanes where all are finite, and the inputs
    with the other lanes zeroed (so they compute quietly and are discarded)."""
    raw = [np.asarray(f, dtype=float) for f in fields]
    shape = np.broadcast_shapes(*(f.shape for f in raw))
    raw = [np.broadcast_to(f, shape) for f in raw]
    ok = np.ones(shape, dtype=bool)
    for f in raw:
        ok &= np.isfinite(f)
    clean = [np.where(ok, f, 0.0) for f in raw]
    return raw, ok, clean


def _array_output(
    old: list[np.ndarray], ok: np.ndarray, *loop: Any
) -> tuple[ControlOutput, VelocityLoopMemory]:
    """Per lane: the loop's result where inputs and outputs are finite, else zero torque,
    ``nonfinite = 1`` and the old memory ``old``."""
    tau1, tau2, v_c, w_c, mode, xe, ye, the = loop
    for value in (tau1, tau2, v_c, w_c):
        ok &= np.isfinite(value)
    zero = np.zeros(ok.shape)

    def keep(value: Any) -> np.ndarray:
        return np.where(ok, value, zero)

    telemetry = {
        "xe": keep(xe),
        "ye": keep(ye),
        "theta_e": keep(the),
        "v_c": keep(v_c),
        "w_c": keep(w_c),
        "mode": keep(mode),
        "nonfinite": np.where(ok, 0.0, 1.0),
    }
    new_memory = VelocityLoopMemory(
        np.where(ok, v_c, old[0]), np.where(ok, w_c, old[1]), np.where(ok, 1.0, old[2])
    )
    return ControlOutput(keep(tau1), keep(tau2), telemetry), new_memory


def positive_number(law: str, key: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ValueError(f"[controller.{law}] {key} must be a number, got {value!r}")
    if not (0.0 < float(value) <= POSITIVE_MAX):
        raise ValueError(
            f"[controller.{law}] {key} must be a finite number > 0 (at most {POSITIVE_MAX:g}), "
            f"got {value!r}"
        )
    return float(value)


class Jiang1997Controller(VelocityLoopController):
    """[7]'s tracker (module docstring) behind the inner velocity loop; ``name = "jiang1997"``.

    Built as ``Jiang1997Controller(params, context)`` with params c1, c2 and optional inner_kv,
    inner_kw (the [controller.jiang1997] table).
    """

    name = "jiang1997"
    KEYS = ("c1", "c2", "inner_kv", "inner_kw")

    def __init__(self, params: Mapping[str, Any], context: DesignContext) -> None:
        unknown = sorted(set(params) - set(self.KEYS))
        if unknown:
            raise ValueError(f"[controller.jiang1997]: unknown key(s) {', '.join(unknown)}")
        self.c1 = positive_number("jiang1997", "c1", params.get("c1", 7.0))
        self.c2 = positive_number("jiang1997", "c2", params.get("c2", 0.1))
        super().__init__(
            context,
            positive_number("jiang1997", "inner_kv", params.get("inner_kv", INNER_K_DEFAULT)),
            positive_number("jiang1997", "inner_kw", params.get("inner_kw", INNER_K_DEFAULT)),
        )

    def kinematic(self, ns: Any, t: Any, state: RobotState, ref: ReferenceSample) -> tuple:
        xe, ye, the = tracking_errors(ns, state, ref)
        v_c = ref.vd * ns.cos(the) - self.c1 * xe
        w_c = ref.wd - ref.vd * ye * sinc(ns, the) / self.c2 - self.c1 * the
        return v_c, w_c, 0.0 * xe, xe, ye, the

    def resolved_table(self) -> dict[str, Any]:
        return {
            "law": self.name,
            "jiang1997": {
                "c1": self.c1,
                "c2": self.c2,
                "inner_kv": self.inner_kv,
                "inner_kw": self.inner_kw,
            },
        }
