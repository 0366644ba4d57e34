"""Model (1) of Li et al. 2024 with an optional first-order actuator, integrated by RK4.

Plant (1): x' = v cos theta, y' = v sin theta, theta' = omega, v' = tau1 + d1, omega' = tau2 + d2.
The *applied* torques (tau1, tau2 in :class:`PlantState`) follow the command held over a step:
with lag time constant ``T = 0`` they equal it; with ``T > 0`` they obey tau' = (cmd - tau)/T,
which is solved exactly over the step (tau(s) = cmd + (tau0 - cmd) exp(-s/T)) so that any T is
stable at any step h; RK4 then sees the exact applied torque at its stage times.

One RK4 of this model, on Python floats for one robot and on numpy arrays for N (tests check
both against an independent textbook RK4); :mod:`plant_emulator.sampled` is its only caller,
where the sampled-data step holds the command and lands delayed commands between calls:
- :func:`rk4_float`: the one-robot fast path, the classical stage formulas inlined on floats
  with the per-step extremes and violation counts (~1.5 M steps per 150 s run).
- :func:`rk4_array`: the same stage formulas on arrays of N robots, where cos/sin at the stage
  angles come from one exact cos/sin per call rotated by Taylor polynomials of the small stage
  increments (exact to rounding while h*|omega| <= 0.02, else exact trigonometry at every
  stage), because one numpy sin on 10,000 values costs as much as ~30 additions. Under a held
  torque with no lag and a constant disturbance (the common case) the stages are summed in
  complex form (:func:`_advance_array_held`), the same RK4 arithmetic regrouped.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np

from plant_emulator.disturbances import Disturbance, disturbance_at
from protocol.robot import Limits, RobotState

VIOLATION_RTOL = 1e-9  # a step counts as a violation beyond limit * (1 + VIOLATION_RTOL)
_TAYLOR_MAX_ANGLE = 0.02
_TAYLOR_CUT = 2.0**-70
NO_DISTURBANCE = Disturbance()


class PlantState(NamedTuple):
    """State of model (1) extended by the two applied torques (the actuator's state)."""

    x: Any
    y: Any
    theta: Any
    v: Any
    omega: Any
    tau1: Any = 0.0
    tau2: Any = 0.0

    def robot_state(self) -> RobotState:
        return RobotState(self.x, self.y, self.theta, self.v, self.omega)


class Drag(NamedTuple):
    """What model (1) leaves out, for a robot that should slow down by itself: viscous
    friction (v' = tau1 + d1 - c_v v, omega' = tau2 + d2 - c_omega omega, in 1/s) and a top
    speed (|v| <= v_max, |omega| <= omega_max, held at every plant step, as a motor at its
    no-load speed). Off by default and in the paper's scenarios."""

    c_v: float = 0.0
    c_omega: float = 0.0
    v_max: float = math.inf
    omega_max: float = math.inf

    @property
    def active(self) -> bool:
        return bool(self.c_v or self.c_omega) or math.isfinite(self.v_max + self.omega_max)


NO_DRAG = Drag()


def _decays(h: float, lag: float) -> tuple[float, float]:
    if lag <= 0.0:
        return 0.0, 0.0
    return math.exp(-0.5 * h / lag), math.exp(-h / lag)


@dataclass
class Extremes:
    """Largest |v|, |omega|, |tau1|, |tau2| (applied) over plant steps, and the number of steps
    beyond each limit of (2) by more than ``VIOLATION_RTOL`` relative. Floats for one robot,
    arrays of shape (N,) for a batch.

    A plant step whose end state or applied torque is not finite (NaN, inf) is counted in
    ``nonfinite_steps``; ``nonfinite_first_t`` is the end time of the first such step (NaN:
    none). Its peaks are then NaN or inf, never the last finite value: a comparison with NaN
    is false, so no limit counts it as a violation, and the count is what says (2) cannot
    hold (hil.verdict). Once a state is not finite it stays so (every update of model (1)
    adds to the state), so the steps of a call that ends non-finite are a tail of the call."""

    max_abs_v: Any = 0.0
    max_abs_omega: Any = 0.0
    max_abs_tau1: Any = 0.0
    max_abs_tau2: Any = 0.0
    violations_v: Any = 0
    violations_omega: Any = 0
    violations_tau1: Any = 0
    violations_tau2: Any = 0
    steps: int = 0
    nonfinite_steps: Any = 0
    nonfinite_first_t: Any = math.nan
    _n: int | None = field(default=None, repr=False)

    @classmethod
    def zeros(cls, n: int | None = None) -> Extremes:
        if n is None:
            return cls()
        z = np.zeros(n)
        zi = np.zeros(n, dtype=np.int64)
        return cls(
            *(z.copy() for _ in range(4)),
            *(zi.copy() for _ in range(4)),
            steps=0,
            nonfinite_steps=zi.copy(),
            nonfinite_first_t=np.full(n, math.nan),
            _n=n,
        )

    def nonfinite_first_t_s(self) -> Any:
        """``nonfinite_first_t`` as summaries give it: None (one robot) where no step was
        non-finite; arrays keep NaN there."""
        if isinstance(self.nonfinite_first_t, np.ndarray):
            return self.nonfinite_first_t
        return None if math.isnan(self.nonfinite_first_t) else float(self.nonfinite_first_t)


def _finite(values: Any) -> bool:
    return all(map(math.isfinite, values))


def _poisoned(peak: float, value: float) -> float:
    """A float peak that keeps a non-finite ``value`` (max() would drop a NaN)."""
    return abs(value) if not math.isfinite(value) and math.isfinite(peak) else peak


def _first_nonfinite_step(
    s: PlantState, cmd: tuple[Any, Any], t0: Any, h: float, n: int, rest: tuple[Any, ...],
    step0: int | None,
) -> int:  # fmt: skip
    """The index (0 .. n-1) of the first of ``n`` float steps from the finite ``s`` whose end
    is not finite, replayed one step at a time (the same arithmetic as the n steps);
    ``rest``: (disturbance, lag, seed, limits, drag)."""
    disturbance, lag, seed, limits, drag = rest
    scratch = Extremes()
    for i in range(n - 1):  # n == 1, or none of the first n - 1: the last one
        start = t0 + i * h if step0 is None else t0
        at = None if step0 is None else step0 + i
        s = rk4_float(s, *cmd, start, h, 1, disturbance, lag, seed, limits, scratch, at, drag)
        if not _finite(s):
            return i
    return n - 1


def _count_nonfinite_float(
    ext: Extremes, start: PlantState, end: PlantState, cmd: tuple[Any, Any], t0: Any, h: float,
    n: int, rest: tuple[Any, ...], step0: int | None,
) -> None:  # fmt: skip
    """After ``n`` float steps from ``start`` ended in ``end``: count the non-finite ones
    (Extremes' docstring) and keep the non-finite values in the peaks."""
    if _finite(end) or n <= 0:
        return
    lag = rest[1]
    head = start[:5] if lag <= 0.0 else start  # without lag the held command is the torque
    first = 0 if not _finite(head) else _first_nonfinite_step(start, cmd, t0, h, n, rest, step0)
    ext.nonfinite_steps += n - first
    if math.isnan(ext.nonfinite_first_t):
        ext.nonfinite_first_t = (t0 + (first + 1) * h) if step0 is None else (step0 + first + 1) * h
    ext.max_abs_v = _poisoned(ext.max_abs_v, end.v)
    ext.max_abs_omega = _poisoned(ext.max_abs_omega, end.omega)
    ext.max_abs_tau1 = _poisoned(ext.max_abs_tau1, end.tau1)
    ext.max_abs_tau2 = _poisoned(ext.max_abs_tau2, end.tau2)


def _count_nonfinite_array(
    ext: Extremes, start: PlantState, end: PlantState, cmd: tuple[Any, Any], t0: Any, h: float,
    n: int, rest: tuple[Any, ...], step0: int | None,
) -> None:  # fmt: skip
    """:func:`_count_nonfinite_float` for arrays of N robots: a cheap test of the sums first
    (a NaN or inf anywhere makes one); then robot by robot, each replayed on floats (the
    peaks on arrays keep a NaN already: numpy's maximum propagates it)."""
    if n <= 0:
        return
    # theta, tau1 and tau2 reach x, y, v or omega in the same step: these four tell.
    total = float(np.sum(end.x)) + float(np.sum(end.y))
    total += float(np.sum(end.v)) + float(np.sum(end.omega))
    if math.isfinite(total):
        return
    shape = np.shape(end.x)
    bad = np.zeros(shape, dtype=bool)
    for q in end:
        bad |= ~np.isfinite(np.broadcast_to(q, shape))
    disturbance, lag, seed, limits, drag = rest
    # Robots whose state was not finite at the start (every step counts: the common case once
    # a robot went bad), on arrays; the others replayed on floats, once in their life.
    head_bad = np.zeros(shape, dtype=bool)
    for q in start[:5] if lag <= 0.0 else start:
        head_bad |= ~np.isfinite(np.broadcast_to(q, shape))
    first = np.zeros(shape, dtype=np.int64)

    def one(values: Any, i: int) -> float:
        return float(np.broadcast_to(values, shape)[i]) if np.ndim(values) else float(values)

    for i in np.flatnonzero(bad & ~head_bad).tolist():
        s_i = PlantState(*(one(q, i) for q in start))
        c_i = (one(cmd[0], i), one(cmd[1], i))
        seed_i = int(np.ravel(seed)[i]) if np.ndim(seed) else seed
        rest_i = (disturbance, lag, seed_i, limits, drag)
        first[i] = _first_nonfinite_step(s_i, c_i, one(t0, i), h, n, rest_i, step0)
    ext.nonfinite_steps += np.where(bad, n - first, 0)
    if step0 is None:
        end_t = np.broadcast_to(np.asarray(t0, dtype=float), shape) + (first + 1) * h
    else:
        end_t = (step0 + first + 1) * h
    new = bad & np.isnan(ext.nonfinite_first_t)
    ext.nonfinite_first_t[new] = np.broadcast_to(end_t, shape)[new]


def _thresholds(limits: Limits) -> tuple[float, float, float, float]:
    """The limits of (2) on |v|, |omega|, |tau1|, |tau2| as violation thresholds."""
    r = 1.0 + VIOLATION_RTOL
    return limits.phi1 * r, limits.phi2 * r, limits.varpi1 * r, limits.varpi2 * r


def rk4_float(
    s: PlantState,
    cmd1: float,
    cmd2: float,
    t0: float,
    h: float,
    n: int,
    disturbance: Disturbance,
    lag: float,
    seed: int | None,
    limits: Limits,
    ext: Extremes,
    step0: int | None = None,
    drag: Drag = NO_DRAG,
) -> PlantState:
    """``n`` classical RK4 steps of model (1) from ``t0`` with the command held, on floats,
    updating ``ext`` every step (the one-robot fast path of :func:`rk4_array`).

    ``step0``: the index of the first step on the run's plant grid; when given, step i starts at
    ``(step0 + i) * h``, so times (and the random disturbance's hold index) do not depend on
    where an integration segment began. ``drag``: friction and top speed (:class:`Drag`; with
    them the steps are :func:`rk4_drag`'s).
    """
    if drag.active:
        return rk4_drag(s, cmd1, cmd2, t0, h, n, disturbance, lag, seed, limits, ext, step0, drag)
    x, y, th, v, w, a1, a2 = s
    hh = 0.5 * h
    h6 = h / 6.0
    cos, sin = math.cos, math.sin
    eh, ee = _decays(h, lag)
    const_d = disturbance.is_constant
    d10, d20 = disturbance_at(disturbance, t0, seed)
    d1h, d2h, d1e, d2e = d10, d20, d10, d20
    lv, lw, lt1, lt2 = _thresholds(limits)
    mv, mw, mt1, mt2 = ext.max_abs_v, ext.max_abs_omega, ext.max_abs_tau1, ext.max_abs_tau2
    nv, nw = ext.violations_v, ext.violations_omega
    nt1, nt2 = ext.violations_tau1, ext.violations_tau2
    if lag <= 0.0:
        a1, a2 = cmd1, cmd2
    a1h = a1e = cmd1
    a2h = a2e = cmd2
    for i in range(n):
        if lag > 0.0:
            a1h, a2h = cmd1 + (a1 - cmd1) * eh, cmd2 + (a2 - cmd2) * eh
            a1e, a2e = cmd1 + (a1 - cmd1) * ee, cmd2 + (a2 - cmd2) * ee
        if not const_d:
            t = t0 + i * h if step0 is None else (step0 + i) * h
            d10, d20 = disturbance_at(disturbance, t, seed)
            d1h, d2h = disturbance_at(disturbance, t + hh, seed)
            d1e, d2e = disturbance_at(disturbance, t + h, seed)
        u10, u20 = a1 + d10, a2 + d20
        u1h, u2h = a1h + d1h, a2h + d2h
        th2, v2, w2 = th + hh * w, v + hh * u10, w + hh * u20
        th3, v3, w3 = th + hh * w2, v + hh * u1h, w + hh * u2h
        th4, v4, w4 = th + h * w3, v + h * u1h, w + h * u2h
        x = x + h6 * (v * cos(th) + 2.0 * v2 * cos(th2) + 2.0 * v3 * cos(th3) + v4 * cos(th4))
        y = y + h6 * (v * sin(th) + 2.0 * v2 * sin(th2) + 2.0 * v3 * sin(th3) + v4 * sin(th4))
        th = th + h6 * (w + 2.0 * w2 + 2.0 * w3 + w4)
        v = v + h6 * (u10 + 4.0 * u1h + (a1e + d1e))
        w = w + h6 * (u20 + 4.0 * u2h + (a2e + d2e))
        a1, a2 = a1e, a2e
        av = v if v >= 0.0 else -v
        aw = w if w >= 0.0 else -w
        at1 = a1 if a1 >= 0.0 else -a1
        at2 = a2 if a2 >= 0.0 else -a2
        mv, mw = (av if av > mv else mv), (aw if aw > mw else mw)
        mt1, mt2 = (at1 if at1 > mt1 else mt1), (at2 if at2 > mt2 else mt2)
        nv, nw = nv + (av > lv), nw + (aw > lw)
        nt1, nt2 = nt1 + (at1 > lt1), nt2 + (at2 > lt2)
    ext.max_abs_v, ext.max_abs_omega, ext.max_abs_tau1, ext.max_abs_tau2 = mv, mw, mt1, mt2
    ext.violations_v, ext.violations_omega = nv, nw
    ext.violations_tau1, ext.violations_tau2 = nt1, nt2
    ext.steps += n
    end = PlantState(x, y, th, v, w, a1, a2)
    q = x + y + v + w  # theta and the torques reach these four in the same step
    if q - q != 0.0:  # NaN or inf somewhere (or a sum that overflowed: checked exactly)
        rest = (disturbance, lag, seed, limits, NO_DRAG)
        _count_nonfinite_float(ext, s, end, (cmd1, cmd2), t0, h, n, rest, step0)
    return end


def rk4_drag(
    s: PlantState,
    cmd1: Any,
    cmd2: Any,
    t0: Any,
    h: float,
    n: int,
    disturbance: Disturbance,
    lag: float,
    seed: Any,
    limits: Limits,
    ext: Extremes,
    step0: int | None,
    drag: Drag,
) -> PlantState:
    """:func:`rk4_float`'s steps (floats) or :func:`rk4_array`'s (arrays) with the friction
    and the top speed of ``drag``: the textbook stages, one at a time (no fast path: the
    losses are off unless a scenario asks for them)."""
    x, y, th, v, w, a1, a2 = s
    arrays = isinstance(x, np.ndarray)
    cos, sin = (np.cos, np.sin) if arrays else (math.cos, math.sin)
    cv, cw = drag.c_v, drag.c_omega
    hh, h6 = 0.5 * h, h / 6.0
    eh, ee = _decays(h, lag)
    if lag <= 0.0:
        a1, a2 = cmd1, cmd2
    a1h = a1e = cmd1
    a2h = a2e = cmd2
    for i in range(n):
        if lag > 0.0:
            a1h, a2h = cmd1 + (a1 - cmd1) * eh, cmd2 + (a2 - cmd2) * eh
            a1e, a2e = cmd1 + (a1 - cmd1) * ee, cmd2 + (a2 - cmd2) * ee
        t = t0 + i * h if step0 is None else (step0 + i) * h
        d10, d20 = disturbance_at(disturbance, t, seed)
        d1h, d2h = disturbance_at(disturbance, t + hh, seed)
        d1e, d2e = disturbance_at(disturbance, t + h, seed)
        # stage k: (x', y', theta', v', omega') at the stage's state, torque and disturbance
        k1 = (v * cos(th), v * sin(th), w, a1 + d10 - cv * v, a2 + d20 - cw * w)
        th2, v2, w2 = th + hh * k1[2], v + hh * k1[3], w + hh * k1[4]
        k2 = (v2 * cos(th2), v2 * sin(th2), w2, a1h + d1h - cv * v2, a2h + d2h - cw * w2)
        th3, v3, w3 = th + hh * k2[2], v + hh * k2[3], w + hh * k2[4]
        k3 = (v3 * cos(th3), v3 * sin(th3), w3, a1h + d1h - cv * v3, a2h + d2h - cw * w3)
        th4, v4, w4 = th + h * k3[2], v + h * k3[3], w + h * k3[4]
        k4 = (v4 * cos(th4), v4 * sin(th4), w4, a1e + d1e - cv * v4, a2e + d2e - cw * w4)
        x, y, th, v, w = (
            q + h6 * (p1 + 2.0 * p2 + 2.0 * p3 + p4)
            for q, p1, p2, p3, p4 in zip((x, y, th, v, w), k1, k2, k3, k4, strict=True)
        )
        if arrays:
            v, w = np.clip(v, -drag.v_max, drag.v_max), np.clip(w, -drag.omega_max, drag.omega_max)
        else:  # comparisons, not min/max: a NaN stays NaN (min(v_max, nan) is v_max)
            vm, wm = drag.v_max, drag.omega_max
            v = vm if v > vm else (-vm if v < -vm else v)
            w = wm if w > wm else (-wm if w < -wm else w)
        a1, a2 = a1e, a2e
        _track_step(ext, v, w, a1, a2, limits)
    ext.steps += n
    end = PlantState(x, y, th, v, w, a1, a2)
    rest = (disturbance, lag, seed, limits, drag)
    count = _count_nonfinite_array if arrays else _count_nonfinite_float
    count(ext, s, end, (cmd1, cmd2), t0, h, n, rest, step0)
    return end


def _track_step(ext: Extremes, v: Any, w: Any, a1: Any, a2: Any, limits: Limits) -> None:
    """One plant step's extremes and violations (floats or arrays)."""
    lv, lw, lt1, lt2 = _thresholds(limits)
    if isinstance(v, np.ndarray):
        _track_array(ext, v, w, lv, lw)
        _track_torque(ext, np.broadcast_to(a1, v.shape), np.broadcast_to(a2, v.shape), lt1, lt2, 1)
        return
    av, aw, at1, at2 = abs(v), abs(w), abs(a1), abs(a2)
    ext.max_abs_v, ext.max_abs_omega = max(ext.max_abs_v, av), max(ext.max_abs_omega, aw)
    ext.max_abs_tau1, ext.max_abs_tau2 = max(ext.max_abs_tau1, at1), max(ext.max_abs_tau2, at2)
    ext.violations_v += av > lv
    ext.violations_omega += aw > lw
    ext.violations_tau1 += at1 > lt1
    ext.violations_tau2 += at2 > lt2


def _rot(c: np.ndarray, s: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """cos and sin of (angle + d) from c = cos(angle), s = sin(angle), |d| <= 0.02.

    Taylor polynomials to d**7: truncation below 1e-18, i.e. exact to rounding.
    """
    u = d * d
    cd = 1.0 - u * (0.5 - u * (1.0 / 24.0 - u * (1.0 / 720.0)))
    sd = d * (1.0 - u * (1.0 / 6.0 - u * (1.0 / 120.0 - u * (1.0 / 5040.0))))
    return c * cd - s * sd, s * cd + c * sd


def _track_array(ext: Extremes, v: np.ndarray, w: np.ndarray, lv: float, lw: float) -> None:
    av = np.abs(v)
    aw = np.abs(w)
    np.maximum(ext.max_abs_v, av, out=ext.max_abs_v)
    np.maximum(ext.max_abs_omega, aw, out=ext.max_abs_omega)
    ext.violations_v += av > lv
    ext.violations_omega += aw > lw


def _track_torque(ext: Extremes, a1: Any, a2: Any, lt1: float, lt2: float, count: int) -> None:
    at1 = np.abs(a1)
    at2 = np.abs(a2)
    np.maximum(ext.max_abs_tau1, at1, out=ext.max_abs_tau1)
    np.maximum(ext.max_abs_tau2, at2, out=ext.max_abs_tau2)
    ext.violations_tau1 += (at1 > lt1) * count
    ext.violations_tau2 += (at2 > lt2) * count


def rk4_array(
    s: PlantState,
    cmd1: np.ndarray,
    cmd2: np.ndarray,
    t0: Any,
    h: float,
    n: int,
    disturbance: Disturbance,
    lag: float,
    seed: Any,
    limits: Limits,
    ext: Extremes,
    step0: int | None = None,
    drag: Drag = NO_DRAG,
) -> PlantState:
    """``n`` classical RK4 steps of model (1) on arrays of N robots, updating ``ext`` every step
    (times, ``step0`` and ``drag`` as in :func:`rk4_float`; ``t0`` may be one start time per
    robot).

    The stage formulas are :func:`rk4_float`'s; cos/sin at the stage angles are rotated from
    one exact evaluation per call while the stage increments stay small (module docstring),
    else evaluated exactly at every stage; a held torque without lag under a constant
    disturbance is summed in closed form (:func:`_advance_array_held`).
    """
    if drag.active:
        return rk4_drag(s, cmd1, cmd2, t0, h, n, disturbance, lag, seed, limits, ext, step0, drag)
    end = _rk4_array(s, cmd1, cmd2, t0, h, n, disturbance, lag, seed, limits, ext, step0)
    rest = (disturbance, lag, seed, limits, NO_DRAG)
    _count_nonfinite_array(ext, s, end, (cmd1, cmd2), t0, h, n, rest, step0)
    return end


def _rk4_array(
    s: PlantState,
    cmd1: np.ndarray,
    cmd2: np.ndarray,
    t0: Any,
    h: float,
    n: int,
    disturbance: Disturbance,
    lag: float,
    seed: Any,
    limits: Limits,
    ext: Extremes,
    step0: int | None,
) -> PlantState:
    """:func:`rk4_array` without drag and before the non-finite steps are counted."""
    d2bound = max(abs(disturbance.value2), abs(disturbance.amplitude2), disturbance.s2)
    if disturbance.kind == "none":
        d2bound = 0.0
    wmax = float(np.max(np.abs(s.omega))) if n else 0.0
    u2max = float(np.max(np.abs(cmd2))) + max(float(np.max(np.abs(s.tau2))), 0.0) + d2bound
    # Written as "not beyond" so that a NaN state keeps the rotated path, as it always has.
    taylor = not h * (wmax + n * h * u2max) > _TAYLOR_MAX_ANGLE
    if taylor and lag <= 0.0 and disturbance.is_constant:
        d1, d2 = disturbance_at(disturbance, t0, seed)
        return _advance_array_held(s, cmd1, cmd2, d1, d2, h, n, limits, ext)
    return _rk4_array_steps(
        s, cmd1, cmd2, t0, h, n, disturbance, lag, seed, limits, ext, step0, taylor
    )


def _trig(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return np.cos(a), np.sin(a)


def _rk4_array_steps(
    s: PlantState,
    cmd1: np.ndarray,
    cmd2: np.ndarray,
    t0: Any,
    h: float,
    n: int,
    disturbance: Disturbance,
    lag: float,
    seed: Any,
    limits: Limits,
    ext: Extremes,
    step0: int | None,
    taylor: bool,
) -> PlantState:
    """The stage-by-stage loop of :func:`rk4_array`: the stage cos/sin are rotated from the
    step's (``taylor``) or evaluated exactly (large stage angles)."""
    x, y, th, v, w, a1, a2 = s
    lv, lw, lt1, lt2 = _thresholds(limits)
    hh = 0.5 * h
    h6 = h / 6.0
    eh, ee = _decays(h, lag)
    const_d = disturbance.is_constant
    const_u2 = const_d and lag <= 0.0
    d10, d20 = disturbance_at(disturbance, t0, seed)
    d1h, d2h, d1e, d2e = d10, d20, d10, d20
    c, sn = _trig(th)
    if lag <= 0.0:
        a1, a2 = cmd1, cmd2
        _track_torque(ext, a1, a2, lt1, lt2, n)
    a1h = a1e = cmd1
    a2h = a2e = cmd2
    for i in range(n):
        if lag > 0.0:
            a1h, a2h = cmd1 + (a1 - cmd1) * eh, cmd2 + (a2 - cmd2) * eh
            a1e, a2e = cmd1 + (a1 - cmd1) * ee, cmd2 + (a2 - cmd2) * ee
        if not const_d:
            t = t0 + i * h if step0 is None else (step0 + i) * h
            d10, d20 = disturbance_at(disturbance, t, seed)
            d1h, d2h = disturbance_at(disturbance, t + hh, seed)
            d1e, d2e = disturbance_at(disturbance, t + h, seed)
        u10, u20 = a1 + d10, a2 + d20
        u1h, u2h = a1h + d1h, a2h + d2h
        dth2, v2, w2 = hh * w, v + hh * u10, w + hh * u20
        dth3, v3, w3 = hh * w2, v + hh * u1h, w + hh * u2h
        dth4, v4, w4 = h * w3, v + h * u1h, w + h * u2h
        if taylor:
            (c2, s2), (c3, s3), (c4, s4) = _rot(c, sn, dth2), _rot(c, sn, dth3), _rot(c, sn, dth4)
        else:
            (c2, s2), (c3, s3), (c4, s4) = _trig(th + dth2), _trig(th + dth3), _trig(th + dth4)
        x = x + h6 * (v * c + 2.0 * v2 * c2 + 2.0 * v3 * c3 + v4 * c4)
        y = y + h6 * (v * sn + 2.0 * v2 * s2 + 2.0 * v3 * s3 + v4 * s4)
        dth = h6 * (w + 2.0 * w2 + 2.0 * w3 + w4)
        th = th + dth
        if not taylor:
            c, sn = _trig(th)
        elif const_u2:
            # theta is exactly quadratic in time here, so the fourth stage angle is the next
            # step's angle and its rotation is reused.
            c, sn = c4, s4
        else:
            c, sn = _rot(c, sn, dth)
        v = v + h6 * (u10 + 4.0 * u1h + (a1e + d1e))
        w = w + h6 * (u20 + 4.0 * u2h + (a2e + d2e))
        if lag > 0.0:
            a1, a2 = a1e, a2e
            _track_torque(ext, a1, a2, lt1, lt2, 1)
        _track_array(ext, v, w, lv, lw)
    ext.steps += n
    return PlantState(x, y, th, v, w, a1, a2)


def _rot_small(d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """cos d and sin d for |d| <= 0.02: :func:`_rot` from angle 0 without its rotation.

    The polynomials stop at the first power of d**2 whose term is below 2**-70 (relative) for
    every element: the held segment's small angles (h omega / 2 ~ 1e-4, h^2 u2 / 4 ~ 1e-7) need
    only two or three terms, and each term costs two array operations.
    """
    u = d * d
    big = float(np.max(u)) if np.size(u) else 0.0
    if big * big * big >= 720.0 * _TAYLOR_CUT:
        cd = 1.0 - u * (0.5 - u * (1.0 / 24.0 - u * (1.0 / 720.0)))
        sd = d * (1.0 - u * (1.0 / 6.0 - u * (1.0 / 120.0 - u * (1.0 / 5040.0))))
    elif big * big >= 24.0 * _TAYLOR_CUT:
        cd = 1.0 - u * (0.5 - u * (1.0 / 24.0))
        sd = d * (1.0 - u * (1.0 / 6.0 - u * (1.0 / 120.0)))
    else:
        cd = 1.0 - u * 0.5
        sd = d * (1.0 - u * (1.0 / 6.0))
    return cd, sd


def _track_linear(
    ext_max: np.ndarray,
    ext_count: np.ndarray,
    lim: float,
    start: np.ndarray,
    rate: np.ndarray,
    first: np.ndarray,
    last: np.ndarray,
    n: int,
) -> None:
    """Extremes over the n step ends of q_i = q_{i-1} + rate, q_0 = start (v or omega under a
    held torque); ``first`` and ``last`` are q_1 and q_n.

    The sequence is monotone in floating point too, so its largest magnitude is at an end.
    Steps beyond ``lim`` are counted by replaying the same additions, only for the robots whose
    ends exceed it (usually none).
    """
    peak = np.maximum(np.abs(first), np.abs(last))
    np.maximum(ext_max, peak, out=ext_max)
    over = np.flatnonzero(peak > lim)
    if over.size == 0:
        return
    q = np.broadcast_to(start, peak.shape)[over]
    dq = np.broadcast_to(rate, peak.shape)[over]
    count = np.zeros(over.size, dtype=ext_count.dtype)
    for _ in range(n):
        q = q + dq
        count += np.abs(q) > lim
    ext_count[over] += count


def _unit(c: np.ndarray, s: np.ndarray) -> np.ndarray:
    """The complex array c + i s."""
    z = np.empty(np.shape(c), dtype=np.complex128)
    z.real = c
    z.imag = s
    return z


def _advance_array_held(
    s: PlantState,
    cmd1: np.ndarray,
    cmd2: np.ndarray,
    d1: Any,
    d2: Any,
    h: float,
    n: int,
    limits: Limits,
    ext: Extremes,
) -> PlantState:
    """:func:`rk4_array` when v' = u1 and omega' = u2 are constant over the segment
    (no lag, constant disturbance): the same RK4 stages of model (1), summed in closed form.

    With u constant, RK4's stages of step i give v2 = v3 = v_i + h u1 / 2, v4 = v_i + h u1
    (= v_{i+1}), omega2 = omega3, and stage angles theta_i + d2_i, theta_i + d2_i + e and
    theta_i + 2 (d2_i + e) = theta_{i+1}, with d2_i = h omega_i / 2 and e = h^2 u2 / 4. In
    complex form (x + i y, unit phasors Z_i = exp(i theta_i), R2_i = exp(i d2_i),
    E = exp(i e)) the stage phasors are P2 = Z_i R2_i, P3 = P2 E and P4 = P2 R2_{i+1} = Z_{i+1},
    with R2_{i+1} = R2_i E^2, and step i adds (h/6) (v_i Z_i + 2 v2 (P2 + P3) + v4 P4)
    = (h/6) (v_i T_i + h u1 (K P2 / 2 + P4)), T_i = Z_i + K P2 + P4, K = 2 (1 + E).
    With v_i = v_0 + i h u1 the n steps add (h/6) (v_0 S + h u1 ((n + 1/2) S - Q
    + (Z_n - Z_0) / 2)), S = sum of T_i, Q = sum over i of the partial sums T_0 + ... + T_i.
    theta, omega and v take the stage-by-stage form's additions; the extremes of v and omega
    over the step ends are at the first or the last step (both are linear in the step index).

    Why: at N = 10,000 a numpy operation costs about the same on complex as on real arrays, and
    this form takes 8 complex operations a step where the real stage-by-stage form takes ~45.
    The phasors start from one exact cos/sin of theta a call; E and R2_0 are Taylor polynomials
    of the small angles (|h omega|, h^2 |u2| <= 0.02, checked by the caller).
    """
    lv = limits.phi1 * (1.0 + VIOLATION_RTOL)
    lw = limits.phi2 * (1.0 + VIOLATION_RTOL)
    lt1 = limits.varpi1 * (1.0 + VIOLATION_RTOL)
    lt2 = limits.varpi2 * (1.0 + VIOLATION_RTOL)
    _track_torque(ext, cmd1, cmd2, lt1, lt2, n)
    x, y, th, v, w, _, _ = s
    if n <= 0:
        return PlantState(x, y, th, v, w, cmd1, cmd2)
    hh = 0.5 * h
    h6 = h / 6.0
    u1 = cmd1 + d1
    u2 = cmd2 + d2
    hu1 = h * u1
    hu2 = h * u2
    hhu2 = hh * u2
    e_pos = _unit(*_rot_small(hh * hhu2))  # E = exp(i e)
    e_sq = e_pos * e_pos  # R2_{i+1} / R2_i
    k = 2.0 * (1.0 + e_pos)
    r2 = _unit(*_rot_small(hh * w))  # R2_0
    z = _unit(np.cos(th), np.sin(th))  # Z_0
    v_first = v + hu1
    z, s_sum, q_sum, (th_end, w_end, v_end) = held_steps(
        z, r2, e_sq, k, (th, w, v), (hu2, hu1, hhu2), h, n
    )
    s_sum = held_displacement(s_sum, q_sum, z, v, hu1, h6, n)
    x = x + s_sum.real
    y = y + s_sum.imag
    _track_linear(ext.max_abs_v, ext.violations_v, lv, v, hu1, v_first, v_end, n)
    _track_linear(ext.max_abs_omega, ext.violations_omega, lw, w, hu2, w + hu2, w_end, n)
    ext.steps += n
    return PlantState(x, y, th_end, v_end, w_end, cmd1, cmd2)


def held_steps(
    z: Any,
    r2: Any,
    e_sq: Any,
    k: Any,
    start: tuple[Any, Any, Any],
    rates: tuple[Any, Any, Any],
    h: float,
    n: int,
) -> tuple[Any, Any, Any, tuple[Any, Any, Any]]:
    """The n steps of :func:`_advance_array_held`: Z_n, S, Q + Z_0 / 2 and (theta, omega, v)
    at the end. ``start``: (theta_0, omega_0, v_0); ``rates``: (h u2, h u1, h u2 / 2); n >= 1.

    Written with plain operators so that one source runs on numpy arrays of N robots (here) and
    on one robot's complex and float scalars compiled by numba (:mod:`hil.sim.compiled`).
    theta, omega and v take the additions of the stage-by-stage form (theta_{i+1} = theta_i +
    (omega_i + h u2 / 2) h, omega_{i+1} = omega_i + h u2, v_{i+1} = v_i + h u1): a closed form
    is as exact in real arithmetic but drifts from the single-run path by ~1e-12 in theta over
    20 s, where these additions stay within ~1e-15 of it.
    """
    hu2, hu1, hhu2 = rates
    # Own copies, then augmented assignments: in place on arrays (fewer temporaries), plain
    # rebinding on scalars; the caller's arrays are never written.
    th, w, v = start[0] + 0.0, start[1] + 0.0, start[2] + 0.0
    r2 = r2 + 0.0
    q_sum = 0.5 * z  # Q plus Z_0 / 2, which the end result subtracts
    s_sum = 0.0 * z  # 0 + T_0 = T_0 in the first step
    for _ in range(n):
        p2 = z * r2
        r2 *= e_sq
        t = p2 * k
        t += z
        z = p2  # P2's buffer becomes P4 = P2 R2 = Z_{i+1} (P2 is not needed after this)
        z *= r2
        t += z  # T_i
        s_sum += t
        q_sum += s_sum
        th += (w + hhu2) * h
        w += hu2
        v += hu1
    return z, s_sum, q_sum, (th, w, v)


def held_displacement(s_sum: Any, q_sum: Any, z: Any, v: Any, hu1: Any, h6: float, n: int) -> Any:
    """(h/6) (v_0 S + h u1 b) with b = (n + 1/2) S - Q + (Z_n - Z_0) / 2: the n steps' x + i y
    displacement (``q_sum`` holds Q + Z_0 / 2). Arrays or scalars, as :func:`held_steps`."""
    b = (s_sum * (n + 0.5) - q_sum + z * 0.5) * hu1
    return (s_sum * v + b) * h6


def track_initial(ext: Extremes, s: PlantState, limits: Limits) -> None:
    """Count the initial state as a plant step's end point (the paper assumes it admissible;
    a NaN there stays in the peaks)."""
    if isinstance(s.v, np.ndarray):
        ext.max_abs_v = np.maximum(ext.max_abs_v, np.abs(s.v))
        ext.max_abs_omega = np.maximum(ext.max_abs_omega, np.abs(s.omega))
    else:
        ext.max_abs_v = _poisoned(max(ext.max_abs_v, abs(s.v)), s.v)
        ext.max_abs_omega = _poisoned(max(ext.max_abs_omega, abs(s.omega)), s.omega)
    del limits
