"""The unified tracking-and-stabilization sliding-mode law of Li et al. 2024, eqs. (4)-(10), (19).

One source serves one robot on plain floats (real-time path) and N robots on numpy arrays of
shape (N,) (batch path) through :mod:`runtime.mathns`. When the N robots share t, dt
and the reference sample (the simulator's batches), a variant of the array path evaluates the
same formulas with fewer array operations (``_update_array_shared_ref``; equal to rounding).

Law (docs/design.md, section 1, signs restored):

- errors (4): xe = cos th (x-xd) + sin th (y-yd), ye = -sin th (x-xd) + cos th (y-yd),
  theta_e = th - thd. theta_e is NOT wrapped: the law uses half angles (period 4 pi), so
  wrapping would make it jump; give th and thd unwrapped (continuous).
- time-varying signal: r = sqrt(1 + xe^2 + ye^2), f = rho tanh(r - 1) sin t (t is the law
  clock passed to ``update``), xi = eta f, g = r' = (xe (v - vd cos theta_e) + ye vd sin
  theta_e)/r, f' = rho sin t (1 - tanh^2(r - 1)) g + rho cos t tanh(r - 1),
  xi' = -(vd^2 + wd^2) xi + eta f'.
- virtual controls (7): alpha_v = vd cos xi - z1,
  alpha_w = xi' + wd - (lam vd / r)(xe sin((theta_e + xi)/2) + ye cos((theta_e + xi)/2)) - z2.
- torques (10): tau1 = -varpi1 sign(v - alpha_v), tau2 = -varpi2 sign(w - alpha_w);
  boundary layer (19): the sign is replaced by clip(v_tilde / eps1, -1, 1) (same for tau2),
  i.e. sign outside |v_tilde| < eps1 and linear inside.

Memory-advance rule (``update`` returns the memory at t + dt from the samples at t):

- eta' = -(vd^2 + wd^2) eta is integrated exactly for vd, wd held over dt:
  eta(t + dt) = eta(t) exp(-(vd^2 + wd^2) dt);
- the adaptive laws (8), z1' = (l1/2)(xe/r - z1/m1), z2' = (l2/2)(sin((theta_e - xi)/2) -
  z2/m2), by one explicit Euler step with the sampled right-hand sides, then clamped to
  |z1| <= m1, |z2| <= m2, which (8) guarantees in continuous time (|xe/r| < 1,
  |sin| <= 1) and which the Euler step keeps anyway whenever dt l/(2m) <= 1.

Bad input: a non-finite state, reference sample, memory or clock gives zero torque, telemetry
``nonfinite = 1`` and the memory unchanged (element-wise on the batch path). Torques never
exceed varpi1, varpi2 in magnitude.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np

from controller_service.design import check_unified
from controller_service.laws.base import (
    ControlOutput,
    DesignContext,
    ReferenceSample,
    RobotState,
)
from protocol.paper import TABLE1
from runtime.mathns import ARRAY_MATH, FLOAT_MATH, inline_float_helpers

# tuple.__new__ skips a NamedTuple's Python-level __new__ (a measurable part of one update).
_new = tuple.__new__
_float = float
_ndarray = np.ndarray

TELEMETRY_KEYS = (
    "xe",
    "ye",
    "theta_e",
    "xi",
    "v_tilde",
    "w_tilde",
    "z1",
    "z2",
    "eta",
    "alpha_v",
    "alpha_w",
    "nonfinite",
)


@dataclass(frozen=True)
class UnifiedParams:
    """Gains of the unified law: (8)'s m1, m2, l1, l2, (7)'s lam, the signal's rho, and the
    boundary-layer widths eps1, eps2 of (19) (None = the pure sign law (10)). Table 1 defaults."""

    m1: float = TABLE1["m1"]
    m2: float = TABLE1["m2"]
    l1: float = TABLE1["l1"]
    l2: float = TABLE1["l2"]
    lam: float = TABLE1["lam"]
    rho: float = TABLE1["rho"]
    eps1: float | None = None
    eps2: float | None = None


class UnifiedMemory(NamedTuple):
    """The law's internal states: eta of the time-varying signal and the adaptive z1, z2 (8)."""

    eta: Any
    z1: Any
    z2: Any


class UnifiedSignals(NamedTuple):
    """Every intermediate signal of (4)-(7) at one instant (for telemetry and tests)."""

    xe: Any
    ye: Any
    theta_e: Any
    r: Any
    f: Any
    xi: Any
    dxi: Any
    alpha_v: Any
    alpha_w: Any


def make_step(ns: Any) -> Any:
    """The law's one definition, bound to a math namespace: ``step(t, dt, state, ref, memory,
    p)`` (state (x, y, theta, v, omega), the reference sample's first five fields used, memory
    (eta, z1, z2)) with ``p`` = :meth:`UnifiedController.constants`.

    Returns (tau1, tau2, eta, z1, z2 at t + dt, xe, ye, theta_e, r, f, xi, xi', alpha_v,
    alpha_w, v_tilde, w_tilde). Errors (4), the signal xi and its derivative, (7), torques
    (10) or (19) (``p``'s 1/eps1 > 0) and the memory rule of the module doc.

    Why a closure: the functions of ``ns`` become closure variables, so the float path pays no
    namespace lookup per call, the array path runs the same source on numpy, and numba compiles
    the same source (:mod:`hil.sim.compiled`) with ``ns`` its scalar functions.
    """
    sin, cos, tanh, sqrt, exp, sign, clip = (
        ns.sin,
        ns.cos,
        ns.tanh,
        ns.sqrt,
        ns.exp,
        ns.sign,
        ns.clip,
    )

    def step(t, dt, state, ref, memory, p):  # type: ignore[no-untyped-def]
        x, y, th, v, w = state
        xd, yd, thd, vd, wd = ref[:5]
        eta, z1, z2 = memory
        lam, rho, m1, m2, half_l1, half_l2, varpi1, varpi2, inv_eps1, inv_eps2 = p
        dx = x - xd
        dy = y - yd
        c = cos(th)
        s = sin(th)
        xe = c * dx + s * dy
        ye = c * dy - s * dx
        the = th - thd
        r = sqrt(1.0 + xe * xe + ye * ye)
        tanh_r = tanh(r - 1.0)
        sin_t = sin(t)
        f = rho * tanh_r * sin_t
        xi = eta * f
        q = vd * vd + wd * wd
        g = (xe * (v - vd * cos(the)) + ye * vd * sin(the)) / r
        df = rho * (sin_t * (1.0 - tanh_r * tanh_r) * g + cos(t) * tanh_r)
        dxi = eta * df - q * xi
        half = 0.5 * (the + xi)
        alpha_v = vd * cos(xi) - z1
        alpha_w = dxi + wd - (lam * vd / r) * (xe * sin(half) + ye * cos(half)) - z2
        v_tilde = v - alpha_v
        w_tilde = w - alpha_w
        if inv_eps1 > 0.0:  # (19)
            tau1 = -varpi1 * clip(v_tilde * inv_eps1, -1.0, 1.0)
            tau2 = -varpi2 * clip(w_tilde * inv_eps2, -1.0, 1.0)
        else:  # (10)
            tau1 = -varpi1 * sign(v_tilde)
            tau2 = -varpi2 * sign(w_tilde)
        eta_next = eta * exp(-q * dt)
        z1_next = clip(z1 + dt * half_l1 * (xe / r - z1 / m1), -m1, m1)
        z2_next = clip(z2 + dt * half_l2 * (sin(0.5 * (the - xi)) - z2 / m2), -m2, m2)
        return (
            tau1,
            tau2,
            eta_next,
            z1_next,
            z2_next,
            xe,
            ye,
            the,
            r,
            f,
            xi,
            dxi,
            alpha_v,
            alpha_w,
            v_tilde,
            w_tilde,
        )

    return step


FLOAT_STEP = inline_float_helpers(make_step, FLOAT_MATH)
ARRAY_STEP = make_step(ARRAY_MATH)


def unified_signals(
    ns: Any,
    t: Any,
    state: RobotState,
    ref: ReferenceSample,
    memory: UnifiedMemory,
    lam: float,
    rho: float,
) -> UnifiedSignals:
    """Errors (4), the time-varying signal xi and its derivative, and alpha_v, alpha_w (7)
    (the law's step without its torques and memory advance; ``ns`` is FLOAT_MATH or
    ARRAY_MATH). ``state.v`` enters only through g = r' (the measured v)."""
    step = ARRAY_STEP if ns.is_array else FLOAT_STEP
    p = (lam, rho, 1.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    out = step(t, 0.0, tuple(state[:5]), ref, tuple(memory[:3]), p)
    return UnifiedSignals(*out[5:14])


def lyapunov_v(sig: UnifiedSignals, memory: UnifiedMemory, params: UnifiedParams, ns: Any) -> Any:
    """V of the proof of Theorem 1: (r - 1) + (4/lam)(1 - cos((theta_e - xi)/2))
    + z1^2/l1 + 2 z2^2/(l2 lam)."""
    lam = params.lam
    return (
        (sig.r - 1.0)
        + (4.0 / lam) * (1.0 - ns.cos(0.5 * (sig.theta_e - sig.xi)))
        + memory.z1 * memory.z1 / params.l1
        + 2.0 * memory.z2 * memory.z2 / (params.l2 * lam)
    )


def _shared_scalar(value: Any, n: int) -> float | None:
    """``value`` as one finite float when it is a scalar or an (n,) array of one value."""
    if isinstance(value, np.ndarray):
        if value.ndim == 0:
            value = value[()]
        elif value.shape != (n,) or not (value == value[0]).all():
            return None
        else:
            value = value[0]
    if not isinstance(value, (float, int, np.floating, np.integer)):
        return None
    value = float(value)
    return value if math.isfinite(value) else None


def _own_arrays(values: tuple[Any, ...]) -> tuple[np.ndarray, ...] | None:
    """``values`` when all are float64 arrays of one shape (N,) with N >= 1, else None."""
    n = None
    for value in values:
        if not isinstance(value, np.ndarray) or value.dtype != np.float64 or value.ndim != 1:
            return None
        if n is None:
            n = value.shape[0]
        if value.shape[0] != n or n == 0:
            return None
    return values


def _errors_shared_ref(
    x: np.ndarray, y: np.ndarray, th: np.ndarray, xd: float, yd: float, thd: float
) -> tuple[np.ndarray, ...]:
    """Errors (4) for robots sharing one reference sample, with the half-angle rotations of
    :meth:`UnifiedController._update_array_shared_ref`: xe, ye, theta_e, and sin, cos of
    theta_e / 2 (from those of theta / 2 and thetad / 2 by the angle-difference formulas)."""
    c_half_d = math.cos(0.5 * thd)
    s_half_d = math.sin(0.5 * thd)
    half_th = 0.5 * th
    s_h = np.sin(half_th)
    c_h = np.cos(half_th)
    c = c_h * c_h - s_h * s_h
    s = 2.0 * s_h * c_h
    dx = x - xd
    dy = y - yd
    xe = c * dx + s * dy
    ye = c * dy - s * dx
    the = th - thd
    s_a = s_h * c_half_d - c_h * s_half_d  # sin(theta_e / 2)
    c_a = c_h * c_half_d + s_h * s_half_d  # cos(theta_e / 2)
    return xe, ye, the, s_a, c_a


def _xi_shared_ref(
    t_s: float,
    xe: np.ndarray,
    ye: np.ndarray,
    v: np.ndarray,
    eta: np.ndarray,
    s_a: np.ndarray,
    c_a: np.ndarray,
    vd: float,
    q: float,
    rho: float,
) -> tuple[np.ndarray, ...]:
    """The time-varying signal xi = eta f and its derivative for robots sharing one
    reference sample: r, xi, xi', and sin, cos of xi / 2."""
    sin_t = math.sin(t_s)
    cos_t = math.cos(t_s)
    cos_the = c_a * c_a - s_a * s_a
    sin_the = 2.0 * s_a * c_a
    r = np.sqrt(1.0 + xe * xe + ye * ye)
    tanh_r = np.tanh(r - 1.0)
    f = rho * tanh_r * sin_t
    xi = eta * f
    g = (xe * (v - vd * cos_the) + ye * vd * sin_the) / r
    df = rho * (sin_t * (1.0 - tanh_r * tanh_r) * g + cos_t * tanh_r)
    dxi = eta * df - q * xi
    half_xi = 0.5 * xi
    s_b = np.sin(half_xi)
    c_b = np.cos(half_xi)
    return r, xi, dxi, s_b, c_b


def _step_total(
    t: Any, dt: Any, xe: Any, ye: Any, vt: Any, wt: Any, eta_n: Any, z1_n: Any, z2_n: Any
) -> Any:
    """The sum every path checks, in one order: not finite means a non-finite input or an
    overflow (huge finite inputs), rejected either way, so that the float and the array paths
    reject the same robots (the float path writes it inline: one call less per update)."""
    return t + dt + xe + ye + vt + wt + eta_n + z1_n + z2_n


class UnifiedController:
    """The unified law (10) (``name = "unified"``) or its boundary-layer variant (19)
    (``name = "unified_boundary"``, when eps1 and eps2 are given).

    The design is checked when the controller is built (Assumption 2, (9), (11), (12)); a
    violation raises :class:`controller_service.design.DesignError`.
    """

    def __init__(self, params: UnifiedParams, context: DesignContext) -> None:
        if (params.eps1 is None) != (params.eps2 is None):
            raise ValueError("unified_boundary needs both eps1 and eps2 (or neither)")
        check_unified(params, context)
        self.params = params
        self.context = context
        self.name = "unified" if params.eps1 is None else "unified_boundary"
        lim = context.limits
        self._varpi1 = float(lim.varpi1)
        self._varpi2 = float(lim.varpi2)
        self._lam = float(params.lam)
        self._rho = float(params.rho)
        self._m1 = float(params.m1)
        self._m2 = float(params.m2)
        self._half_l1 = 0.5 * float(params.l1)
        self._half_l2 = 0.5 * float(params.l2)
        self._boundary = params.eps1 is not None
        self._inv_eps1 = 1.0 / params.eps1 if params.eps1 is not None else 0.0
        self._inv_eps2 = 1.0 / params.eps2 if params.eps2 is not None else 0.0
        self._p = self.constants()

    def constants(self) -> tuple[float, ...]:
        """The design constants of :func:`make_step`'s ``p``: lam, rho, m1, m2, l1 / 2, l2 / 2,
        varpi1, varpi2, 1/eps1, 1/eps2 (0 for the sign law (10))."""
        return (
            self._lam,
            self._rho,
            self._m1,
            self._m2,
            self._half_l1,
            self._half_l2,
            self._varpi1,
            self._varpi2,
            self._inv_eps1,
            self._inv_eps2,
        )

    def initial_memory(self, n: int | None = None, z1: float = 0.0, z2: float = 0.0) -> Any:
        """eta(0) = 1 and the given z1(0), z2(0), clamped to |z1| <= m1, |z2| <= m2 as (8)
        requires."""
        z1 = min(max(float(z1), -self._m1), self._m1)
        z2 = min(max(float(z2), -self._m2), self._m2)
        if n is None:
            return UnifiedMemory(1.0, z1, z2)
        return UnifiedMemory(np.ones(n), np.full(n, z1), np.full(n, z2))

    def signals(
        self, t: Any, state: RobotState, ref: ReferenceSample, memory: UnifiedMemory
    ) -> UnifiedSignals:
        arrays = isinstance(state.x, np.ndarray) or isinstance(memory.eta, np.ndarray)
        step = ARRAY_STEP if arrays else FLOAT_STEP
        out = step(t, 0.0, tuple(state[:5]), ref, tuple(memory[:3]), self._p)
        return UnifiedSignals(*out[5:14])

    def update(
        self, t: float, dt: float, state: RobotState, ref: ReferenceSample, memory: UnifiedMemory
    ) -> tuple[ControlOutput, UnifiedMemory]:
        """Torques (10) or (19) at law time t and the memory advanced to t + dt (module doc)."""
        eta, z1, z2 = memory
        # Float memory means one robot on floats (the real-time path: one identity test); any
        # other memory is sorted here, and arrays met in the float step send the call back.
        if eta.__class__ is not _float and self._any_array(state, ref, memory):
            return self._update_arrays(t, dt, state, ref, memory)
        try:
            (tau1, tau2, eta_n, z1_n, z2_n, xe, ye, the, _, _, xi, _, av, aw, vt, wt) = FLOAT_STEP(
                t, dt, state, ref, memory, self._p
            )
        except TypeError:
            if not self._any_array(state, ref, memory):
                raise
            return self._update_arrays(t, dt, state, ref, memory)
        except (ValueError, OverflowError, ZeroDivisionError):
            # Finite but huge input overflows math functions (sin(inf), exp(1e308)).
            return self._reject_float(memory)
        # Every input reaches one of these (dt directly, the state and the reference through the
        # errors and the sliding variables, t through xi, the memory through its advance). A sum
        # that is not finite means a non-finite input or an overflow: rejected either way.
        total = t + dt + xe + ye + vt + wt + eta_n + z1_n + z2_n  # _step_total, inline
        if total - total != 0.0:
            return self._reject_float(memory)
        telemetry = {
            "xe": xe,
            "ye": ye,
            "theta_e": the,
            "xi": xi,
            "v_tilde": vt,
            "w_tilde": wt,
            "z1": z1,
            "z2": z2,
            "eta": eta,
            "alpha_v": av,
            "alpha_w": aw,
            "nonfinite": 0.0,
        }
        memory_next = _new(UnifiedMemory, (eta_n, z1_n, z2_n))
        return _new(ControlOutput, (tau1, tau2, telemetry)), memory_next

    @staticmethod
    def _any_array(state: RobotState, ref: ReferenceSample, memory: UnifiedMemory) -> bool:
        return (
            isinstance(state[0], _ndarray)
            or isinstance(memory[0], _ndarray)
            or isinstance(ref[0], _ndarray)
        )

    def _update_arrays(
        self, t: Any, dt: Any, state: RobotState, ref: ReferenceSample, memory: UnifiedMemory
    ) -> tuple[ControlOutput, UnifiedMemory]:
        """The array path: the batch simulator's shared-reference form when it applies, else
        the finite fast form, else the masked general form."""
        fast = self._update_array_shared_ref(t, dt, state, ref, memory)
        if fast is not None:
            return fast
        fast = self._update_array_finite(t, dt, state, ref, memory)
        if fast is not None:
            return fast
        return self._update_array(t, dt, state, ref, memory)

    def _torques(self, ns: Any, v_tilde: Any, w_tilde: Any) -> tuple[Any, Any]:
        """Torques (10), or (19) with the boundary layer, from the sliding variables."""
        if self._boundary:
            return (
                -self._varpi1 * ns.clip(v_tilde * self._inv_eps1, -1.0, 1.0),
                -self._varpi2 * ns.clip(w_tilde * self._inv_eps2, -1.0, 1.0),
            )
        return -self._varpi1 * ns.sign(v_tilde), -self._varpi2 * ns.sign(w_tilde)

    def _next_z(
        self, ns: Any, dt: Any, z1: Any, z2: Any, xe_over_r: Any, sin_diff: Any
    ) -> tuple[Any, Any]:
        """z1, z2 of (8) advanced by one Euler step over dt, clamped to [-m, m] (module doc);
        ``sin_diff`` is sin((theta_e - xi) / 2)."""
        m1, m2 = self._m1, self._m2
        return (
            ns.clip(z1 + dt * self._half_l1 * (xe_over_r - z1 / m1), -m1, m1),
            ns.clip(z2 + dt * self._half_l2 * (sin_diff - z2 / m2), -m2, m2),
        )

    def _reject_float(self, memory: UnifiedMemory) -> tuple[ControlOutput, UnifiedMemory]:
        telemetry = dict.fromkeys(TELEMETRY_KEYS, 0.0)
        telemetry["nonfinite"] = 1.0
        return ControlOutput(0.0, 0.0, telemetry), memory

    def _update_array(
        self, t: Any, dt: Any, state: RobotState, ref: ReferenceSample, memory: UnifiedMemory
    ) -> tuple[ControlOutput, UnifiedMemory]:
        fields = (
            *(np.asarray(value, dtype=float) for value in state),
            *(np.asarray(value, dtype=float) for value in ref[:5]),
            *(np.asarray(value, dtype=float) for value in memory),
            np.asarray(t, dtype=float),
            np.asarray(dt, dtype=float),
        )
        shape = np.broadcast_shapes(*(f.shape for f in fields))
        fields = tuple(np.broadcast_to(f, shape) for f in fields)
        ok = np.ones(shape, dtype=bool)
        for f in fields:
            ok &= np.isfinite(f)
        # Zeros stand in for bad elements so the arithmetic stays quiet; those outputs are masked.
        clean = [np.where(ok, f, 0.0) for f in fields]
        st = RobotState(*clean[0:5])
        rf = ReferenceSample(*clean[5:10])
        mem = UnifiedMemory(*clean[10:13])
        t_arr, dt_arr = clean[13], clean[14]
        with np.errstate(all="ignore"):
            out = ARRAY_STEP(t_arr, dt_arr, st, rf, mem, self._p)
            tau1, tau2, eta_next, z1_next, z2_next = out[:5]
            sig = UnifiedSignals(*out[5:14])
            v_tilde, w_tilde = out[14], out[15]
            for value in (tau1, tau2, eta_next, z1_next, z2_next, v_tilde, w_tilde):
                ok &= np.isfinite(value)
            # ... and the float path's rule: finite values whose sum overflows are rejected too
            ok &= np.isfinite(
                _step_total(t_arr, dt_arr, sig.xe, sig.ye, v_tilde, w_tilde, eta_next, z1_next,
                            z2_next)
            )  # fmt: skip
        zero = np.zeros(shape)
        telemetry = {
            "xe": np.where(ok, sig.xe, zero),
            "ye": np.where(ok, sig.ye, zero),
            "theta_e": np.where(ok, sig.theta_e, zero),
            "xi": np.where(ok, sig.xi, zero),
            "v_tilde": np.where(ok, v_tilde, zero),
            "w_tilde": np.where(ok, w_tilde, zero),
            "z1": np.where(ok, mem.z1, zero),
            "z2": np.where(ok, mem.z2, zero),
            "eta": np.where(ok, mem.eta, zero),
            "alpha_v": np.where(ok, sig.alpha_v, zero),
            "alpha_w": np.where(ok, sig.alpha_w, zero),
            "nonfinite": np.where(ok, 0.0, 1.0),
        }
        old = fields[10:13]
        new_memory = UnifiedMemory(
            np.where(ok, eta_next, old[0]),
            np.where(ok, z1_next, old[1]),
            np.where(ok, z2_next, old[2]),
        )
        out = ControlOutput(np.where(ok, tau1, zero), np.where(ok, tau2, zero), telemetry)
        return out, new_memory

    def _update_array_finite(
        self, t: Any, dt: Any, state: RobotState, ref: ReferenceSample, memory: UnifiedMemory
    ) -> tuple[ControlOutput, UnifiedMemory] | None:
        """:meth:`_update_array` when state and memory are float64 arrays of one shape (N,)
        and every input and output is finite (t, dt and the reference: numbers or (N,) arrays,
        e.g. robots that started at different times), or None when that does not hold.

        The same formulas on the same values (where :meth:`_update_array` masks nothing), so
        the same results to rounding (scalars stay scalars here), without the per-field
        broadcasting and masking that cost more than the law itself at a few hundred robots.
        Any non-finite input or output sends the call to :meth:`_update_array`."""
        arrays = _own_arrays((*state, *memory))
        if arrays is None:
            return None
        n = arrays[0].shape[0]
        for value in (t, dt, *ref[:5]):
            if isinstance(value, np.ndarray):
                if value.dtype != np.float64 or value.shape not in ((n,), ()):
                    return None
            elif not isinstance(value, (float, int)) or isinstance(value, bool):
                return None
        with np.errstate(all="ignore"):
            total = sum((*arrays, t, dt, *ref[:5]), 0.0)
            if not np.isfinite(total).all():
                return None
            st = RobotState(*arrays[0:5])
            mem = UnifiedMemory(*arrays[5:8])
            out = ARRAY_STEP(t, dt, st, ref, mem, self._p)
            tau1, tau2, eta_next, z1_next, z2_next = out[:5]
            sig = UnifiedSignals(*out[5:14])
            v_tilde, w_tilde = out[14], out[15]
            total = _step_total(t, dt, sig.xe, sig.ye, v_tilde, w_tilde, eta_next, z1_next, z2_next)
            if not np.isfinite(total).all():
                return None

        def own(value: Any) -> np.ndarray:  # an array of its own, shape (N,)
            if isinstance(value, np.ndarray) and value.shape == (n,):
                return value
            return np.full(n, value, dtype=float)

        telemetry = {
            "xe": own(sig.xe),
            "ye": own(sig.ye),
            "theta_e": own(sig.theta_e),
            "xi": own(sig.xi),
            "v_tilde": v_tilde,
            "w_tilde": w_tilde,
            "z1": mem.z1.copy(),
            "z2": mem.z2.copy(),
            "eta": mem.eta.copy(),
            "alpha_v": own(sig.alpha_v),
            "alpha_w": own(sig.alpha_w),
            "nonfinite": np.zeros(n),
        }
        new_memory = UnifiedMemory(own(eta_next), own(z1_next), own(z2_next))
        return ControlOutput(tau1, tau2, telemetry), new_memory

    def _update_array_shared_ref(
        self, t: Any, dt: Any, state: RobotState, ref: ReferenceSample, memory: UnifiedMemory
    ) -> tuple[ControlOutput, UnifiedMemory] | None:
        """:meth:`_update_array` for the batch simulator's case, or None when it does not apply.

        Applies when state and memory are float64 arrays of one shape (N,), all finite, and t,
        dt and the reference sample are one value for all robots (the simulator's robots share
        the reference). Then every function of t, dt and the reference is a scalar evaluated
        once, and the angles share rotations: with H = theta / 2, A = theta_e / 2 = H - thetad
        / 2 and B = xi / 2, the four sines and cosines of H and B give cos/sin theta of (4),
        cos/sin theta_e of g, cos xi and sin/cos((theta_e + xi) / 2) of (7) and sin((theta_e -
        xi) / 2) of (8) by angle-sum formulas (4 numpy trigonometric calls instead of 12; one
        costs as much as ~20 array additions). The results equal :meth:`_update_array` to a few
        rounding errors. Any non-finite output sends the call to :meth:`_update_array`, which
        masks element-wise.
        """
        arrays = _own_arrays((*state, *memory))
        if arrays is None:
            return None
        x, y, th, v, w, eta, z1, z2 = arrays
        n = x.shape[0]
        shared: list[float] = []
        for value in (t, dt, *ref[:5]):
            scalar = _shared_scalar(value, n)
            if scalar is None:
                return None
            shared.append(scalar)
        t_s, dt_s, xd, yd, thd, vd, wd = shared
        lam, rho = self._lam, self._rho
        with np.errstate(all="ignore"):
            if not np.isfinite(x + y + th + v + w + eta + z1 + z2).all():
                return None
            q = vd * vd + wd * wd
            xe, ye, the, s_a, c_a = _errors_shared_ref(x, y, th, xd, yd, thd)
            r, xi, dxi, s_b, c_b = _xi_shared_ref(t_s, xe, ye, v, eta, s_a, c_a, vd, q, rho)
            sin_half = s_a * c_b + c_a * s_b  # sin((theta_e + xi) / 2)
            cos_half = c_a * c_b - s_a * s_b
            # Virtual controls (7).
            alpha_v = vd * (c_b * c_b - s_b * s_b) - z1
            alpha_w = dxi + wd - (lam * vd / r) * (xe * sin_half + ye * cos_half) - z2
            v_tilde = v - alpha_v
            w_tilde = w - alpha_w
            tau1, tau2 = self._torques(ARRAY_MATH, v_tilde, w_tilde)
            eta_next = eta * math.exp(-q * dt_s)
            sin_diff = s_a * c_b - c_a * s_b  # sin((theta_e - xi) / 2)
            z1_next, z2_next = self._next_z(ARRAY_MATH, dt_s, z1, z2, xe / r, sin_diff)
            total = _step_total(t_s, dt_s, xe, ye, v_tilde, w_tilde, eta_next, z1_next, z2_next)
            if not np.isfinite(total).all():
                return None
        telemetry = {
            "xe": xe,
            "ye": ye,
            "theta_e": the,
            "xi": xi,
            "v_tilde": v_tilde,
            "w_tilde": w_tilde,
            "z1": z1.copy(),
            "z2": z2.copy(),
            "eta": eta.copy(),
            "alpha_v": alpha_v,
            "alpha_w": alpha_w,
            "nonfinite": np.zeros(n),
        }
        out = ControlOutput(tau1, tau2, telemetry)
        return out, UnifiedMemory(eta_next, z1_next, z2_next)

    def resolved_table(self) -> dict[str, Any]:
        """Every parameter actually used, as a scenario's [controller] table."""
        p = self.params
        table: dict[str, Any] = {
            "law": self.name,
            "m1": p.m1,
            "m2": p.m2,
            "l1": p.l1,
            "l2": p.l2,
            "lam": p.lam,
            "rho": p.rho,
        }
        if p.eps1 is not None:
            table["eps1"] = p.eps1
            table["eps2"] = p.eps2
        return table
