"""The sampled-data constraint certificate of the unified law (proof: docs/sampled_data_bound.md).

Pure arithmetic. With D = ts + delay the largest age of the command in force (the longest gap
between the sample times of successive applied commands plus the largest sample-to-apply
latency, stale commands dropped), the push thresholds b1 = eps1 s1 / varpi1, b2 = eps2 s2 /
varpi2 (zero for the sign law (10)) and the initial velocities v0, w0:

    V = max(|v0|, mu1 + m1 + b1) + (varpi1 + s1) D
    W = max(|w0|, mu2 + lam mu1 + m2 + rho c2s + b2) + (varpi2 + s2) D,
    c2s = (mu1 + V) + 1 + mu1^2 + mu2^2   (c0..c2 of Proposition 1 with phi1 replaced by V),

and (2) is guaranteed when V <= phi1 and W <= phi2 (|tau| <= varpi holds by clamping).
:func:`certify` also reports Assumption 2, (9), (11) and (12) (needed for Theorem 1),
:func:`propose` finds the nearest design that restores (2) at the given timing, and
:func:`critical_age` finds D*, the largest D at which V <= phi1 and W <= phi2 still hold (a run
compares its measured D with it; docs section 9).

Rule of :func:`propose` (stated so users can predict it):
1. l1, l2 above their bound in (9) become 0.99 of the bound.
2. m1 becomes min(m1, phi1 - mu1 - b1 - (varpi1 + s1) D), the largest m1 <= the request with
   V <= phi1.
3. With the budget R = phi2 - mu2 - b2 - (varpi2 + s2) D, m2 + lam mu1 + rho c2s <= R is
   restored by reducing m2 alone when that keeps at least half of the requested m2; otherwise
   m2, lam and rho are scaled by one common factor q (the point with the smallest largest
   relative change).
4. If (11) or (12) still fails, lam, then rho, become 0.99 of their bound and step 3 repeats.
The result is certified again; when nothing can restore (2) (for example (varpi1 + s1) D alone
exceeds phi1 - mu1 - b1) the proposal has ``params = None`` and a reason.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from controller_service.design import design_constants, lam_bound, rho_bound
from controller_service.laws.base import DesignContext

STRICT_SHRINK = 0.99  # strict conditions (9), (11), (12): a proposal lands just inside them


class CertificateError(ValueError):
    """The certificate cannot be computed from this input (e.g. a negative period)."""


@dataclass(frozen=True)
class Condition:
    """One checked inequality ``value < bound`` (strict) or ``value <= bound``, or with
    ``above`` ``value > bound`` (a gain that must be positive: shown as given, not negated).

    ``kind``: "assumption" (Assumption 1/2), "design" ((9), (11), (12), positivity), "sampled"
    (the bounds of docs/sampled_data_bound.md) or "info" (reported, not part of ``held``).
    """

    name: str
    value: float
    bound: float
    strict: bool
    kind: str
    held: bool
    above: bool = False

    @property
    def margin(self) -> float:
        """How far the value is inside its bound (negative: outside)."""
        return self.value - self.bound if self.above else self.bound - self.value

    def to_dict(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "value": _json_float(self.value),
            "bound": _json_float(self.bound),
            "strict": self.strict,
            "relation": ">" if self.above else ("<" if self.strict else "<="),
            "kind": self.kind,
            "held": self.held,
            "margin": _json_float(self.margin),
        }


def _json_float(x: float) -> float | str:
    return x if math.isfinite(x) else ("inf" if x > 0 else ("-inf" if x < 0 else "nan"))


def _cond(name: str, value: float, bound: float, kind: str, strict: bool = True) -> Condition:
    # "value < bound" is False for NaN, so a NaN never passes.
    ok = (value < bound) if strict else (value <= bound)
    return Condition(name, float(value), float(bound), strict, kind, bool(ok))


def _cond_above(name: str, value: float, bound: float, kind: str) -> Condition:
    """``value > bound`` (strict); NaN never passes."""
    return Condition(name, float(value), float(bound), True, kind, bool(value > bound), True)


@dataclass(frozen=True)
class Certificate:
    """Whether (2) is guaranteed for the sampled, delayed loop, and why.

    ``constraints_guaranteed``: V <= phi1 and W <= phi2 (with s < varpi); ``held``: that and the
    paper's conditions (Assumption 2, (9), (11), (12)).
    """

    ts: float
    delay: float
    age: float
    boundary_layer: bool
    v_bound: float
    w_bound: float
    phi1: float
    phi2: float
    c2s: float
    conditions: tuple[Condition, ...]
    constraints_guaranteed: bool
    held: bool
    notes: tuple[str, ...] = ()
    outage_tolerance_s: float | None = None
    margins: dict[str, float] = field(default_factory=dict)

    def condition(self, name_prefix: str) -> Condition:
        """The first condition whose name starts with ``name_prefix``."""
        for cond in self.conditions:
            if cond.name.startswith(name_prefix):
                return cond
        raise KeyError(name_prefix)

    def failed(self) -> tuple[Condition, ...]:
        return tuple(c for c in self.conditions if not c.held and c.kind != "info")

    def to_dict(self) -> dict[str, Any]:
        return {
            "ts": self.ts,
            "delay": self.delay,
            "age": self.age,
            "boundary_layer": self.boundary_layer,
            "v_bound": _json_float(self.v_bound),
            "w_bound": _json_float(self.w_bound),
            "phi1": self.phi1,
            "phi2": self.phi2,
            "c2s": _json_float(self.c2s),
            "constraints_guaranteed": self.constraints_guaranteed,
            "held": self.held,
            "margins": {k: _json_float(v) for k, v in self.margins.items()},
            "outage_tolerance_s": None
            if self.outage_tolerance_s is None
            else _json_float(self.outage_tolerance_s),
            "conditions": [c.to_dict() for c in self.conditions],
            "notes": list(self.notes),
        }


def _finite_nonneg(name: str, x: float) -> float:
    try:
        value = float(x)
    except (TypeError, ValueError) as exc:
        raise CertificateError(f"{name} must be a number, got {x!r}") from exc
    if not math.isfinite(value) or value < 0.0:
        raise CertificateError(f"{name} must be finite and >= 0, got {x!r}")
    return value


def _gains(params: Any, boundary_layer: bool) -> dict[str, float]:
    names = ["m1", "m2", "l1", "l2", "lam", "rho"] + (["eps1", "eps2"] if boundary_layer else [])
    out: dict[str, float] = {}
    for name in names:
        raw = getattr(params, name, None)
        if raw is None:
            raise CertificateError(f"parameter {name} is missing")
        try:
            value = float(raw)
        except (TypeError, ValueError) as exc:
            raise CertificateError(f"parameter {name} must be a number, got {raw!r}") from exc
        if not math.isfinite(value):
            raise CertificateError(f"parameter {name} must be finite, got {raw!r}")
        out[name] = value
    return out


def push_thresholds(context: DesignContext, gains: dict[str, float], boundary_layer: bool):
    """b1, b2: the level of v~ (w~) above which the torque beats the worst disturbance
    (docs section 1): 0 for the sign law (10), eps s / varpi for the boundary layer (19)."""
    if not boundary_layer:
        return 0.0, 0.0
    lim = context.limits
    return gains["eps1"] * context.s1 / lim.varpi1, gains["eps2"] * context.s2 / lim.varpi2


def velocity_bound(
    context: DesignContext, m1: float, age: float, b1: float = 0.0, v0: float = 0.0
) -> float:
    """V = max(|v0|, mu1 + m1 + b1) + (varpi1 + s1) D (docs, Theorem of section 2)."""
    return max(abs(v0), context.mu1 + m1 + b1) + (context.limits.varpi1 + context.s1) * age


def sampled_c2(context: DesignContext, v_bound: float) -> float:
    """c2 of Proposition 1 with c0 = mu1 + V (the law evaluates xi' from the sampled v)."""
    return design_constants(context, v_bound=v_bound)["c2"]


def omega_bound(
    context: DesignContext,
    *,
    m2: float,
    lam: float,
    rho: float,
    v_bound: float,
    age: float,
    b2: float = 0.0,
    w0: float = 0.0,
) -> float:
    """W = max(|w0|, mu2 + lam mu1 + m2 + rho c2s + b2) + (varpi2 + s2) D (docs section 3)."""
    c2s = sampled_c2(context, v_bound)
    alpha_w_max = context.mu2 + lam * context.mu1 + m2 + rho * c2s
    return max(abs(w0), alpha_w_max + b2) + (context.limits.varpi2 + context.s2) * age


def _outage_gap(
    limit: float, base: float, rate_hold: float, rate_drift: float, delay: float, watchdog: float
) -> float:
    """Largest sample gap G with base + rate_hold (min(G, Tw) + delay) + rate_drift max(0, G - Tw)
    <= limit (docs section 6); negative when not even G = 0 fits."""
    hold_full = base + rate_hold * (watchdog + delay)
    if hold_full <= limit:
        if rate_drift == 0.0:
            return math.inf
        return watchdog + (limit - hold_full) / rate_drift
    return (limit - base) / rate_hold - delay


def _paper_conditions(
    context: DesignContext, g: dict[str, float], boundary_layer: bool
) -> list[Condition]:
    """Assumption 2, positivity of the gains, (9), (11) and (12) (the conditions of Theorem 1)."""
    lim = context.limits
    mu1, mu2, k1, k2, s1, s2 = (
        context.mu1,
        context.mu2,
        context.k1,
        context.k2,
        context.s1,
        context.s2,
    )
    conds: list[Condition] = [
        _cond("Assumption 2 mu1 < phi1", mu1, lim.phi1, "assumption"),
        _cond("Assumption 2 mu2 < phi2", mu2, lim.phi2, "assumption"),
        _cond("Assumption 2 k1 < varpi1 - s1", k1, lim.varpi1 - s1, "assumption"),
        _cond("Assumption 2 k2 < varpi2 - s2", k2, lim.varpi2 - s2, "assumption"),
    ]
    for name in ("m1", "m2", "l1", "l2", "lam", "rho") + (
        ("eps1", "eps2") if boundary_layer else ()
    ):
        conds.append(_cond_above(f"{name} > 0", g[name], 0.0, "design"))
    conds += [
        _cond("(9) m1 < phi1 - mu1", g["m1"], lim.phi1 - mu1, "design"),
        _cond("(9) m2 < phi2 - mu2", g["m2"], lim.phi2 - mu2, "design"),
        _cond("(9) l1 < varpi1 - k1 - s1", g["l1"], lim.varpi1 - k1 - s1, "design"),
        _cond("(9) l2 < varpi2 - k2 - s2", g["l2"], lim.varpi2 - k2 - s2, "design"),
        _cond(
            "(11) lam < lam bound", g["lam"], lam_bound(context, m2=g["m2"], l2=g["l2"]), "design"
        ),
        _cond(
            "(12) rho < rho bound",
            g["rho"],
            rho_bound(context, m1=g["m1"], m2=g["m2"], l1=g["l1"], l2=g["l2"], lam=g["lam"]),
            "design",
        ),
    ]
    return conds


def _sampled_bounds(
    context: DesignContext,
    g: dict[str, float],
    *,
    age: float,
    b: tuple[float, float],
    v0: float,
    w0: float,
) -> tuple[float, float, float]:
    """V, c2s and W of the module docstring at command age ``age``."""
    v_bound = velocity_bound(context, g["m1"], age, b[0], v0)
    c2s = sampled_c2(context, v_bound)
    w_bound = omega_bound(
        context, m2=g["m2"], lam=g["lam"], rho=g["rho"], v_bound=v_bound, age=age, b2=b[1], w0=w0
    )
    return v_bound, c2s, w_bound


def _sampled_conditions(
    context: DesignContext, g: dict[str, float], v_bound: float, w_bound: float
) -> list[Condition]:
    """V <= phi1, W <= phi2, and the reaching condition at the sampled bounds (info only)."""
    lim = context.limits
    # The reaching conditions of (12)/(14) with the sampled bounds in place of phi1, phi2:
    # they govern the quasi-sliding behaviour (Theorem 1), not the constraints.
    reach = design_constants(context, v_bound=max(lim.phi1, v_bound))
    dav = context.k1 + g["rho"] * context.mu1 * reach["c2"] + g["l1"]
    return [
        _cond("sampled |v| bound <= phi1", v_bound, lim.phi1, "sampled", strict=False),
        _cond("sampled |w| bound <= phi2", w_bound, lim.phi2, "sampled", strict=False),
        _cond(
            "reaching |alpha_v'| < varpi1 - s1 at sampled bounds",
            dav,
            lim.varpi1 - context.s1,
            "info",
        ),
    ]


def _bound_notes(
    context: DesignContext,
    g: dict[str, float],
    *,
    ts: float,
    age: float,
    boundary_layer: bool,
    b: tuple[float, float],
    bounds: tuple[float, float],
    v0: float,
    w0: float,
) -> list[str]:
    """The certificate's explanatory notes on the age, the push thresholds and the bounds."""
    b1, b2 = b
    v_bound, c2s = bounds
    notes = [
        f"age D = ts + delay = {age:.6g} s: the longest time a command is in force after its "
        "sample (stale commands dropped; lost commands widen ts)",
        "|tau1| <= varpi1, |tau2| <= varpi2 hold by construction (sign/saturation, clamped)",
        "the shipped law clamps |z1| <= m1, |z2| <= m2 and integrates eta exactly, so the alpha "
        "bounds hold at every sample for any period (docs section 5)",
    ]
    if boundary_layer:
        notes.append(
            f"boundary layer (19): push thresholds b1 = eps1 s1/varpi1 = {b1:.4g}, "
            f"b2 = eps2 s2/varpi2 = {b2:.4g} added to the alpha bounds"
        )
    if v_bound > context.limits.phi1:
        notes.append(
            f"V = {v_bound:.6g} > phi1: the paper's c0 = mu1 + phi1 undercounts |g|; "
            f"c0 = mu1 + V used (c2s = {c2s:.6g})"
        )
    if l_dt := [n for n, m in (("l1", "m1"), ("l2", "m2")) if g[n] * ts > 2.0 * g[m]]:
        notes.append(
            f"{', '.join(l_dt)} ts > 2 m: a plain Euler update of (8) would leave |z| <= m; the "
            "shipped law's clamp keeps it"
        )
    mu1, mu2 = context.mu1, context.mu2
    if abs(v0) > mu1 + g["m1"] or abs(w0) > mu2 + g["lam"] * mu1 + g["m2"] + g["rho"] * c2s:
        notes.append("an initial velocity above the alpha bound enters V or W through max()")
    notes.append(
        "not covered: watchdog outages longer than ts (v drifts by s1 per second under zero "
        "torque), sensor noise, actuator lag (docs section 6)"
    )
    return notes


def _outage_tolerance(
    context: DesignContext,
    g: dict[str, float],
    *,
    ts: float,
    delay: float,
    watchdog_timeout: float,
    b: tuple[float, float],
    v0: float,
    w0: float,
) -> tuple[float, str]:
    """The largest sample gap (2) survives with a watchdog zeroing the torque (docs section 6),
    and the note that says so."""
    lim = context.limits
    mu1, mu2, s1, s2 = context.mu1, context.mu2, context.s1, context.s2
    b1, b2 = b
    tw = _finite_nonneg("watchdog_timeout", watchdog_timeout)
    c2_out = sampled_c2(context, lim.phi1)
    gv = _outage_gap(lim.phi1, max(abs(v0), mu1 + g["m1"] + b1), lim.varpi1 + s1, s1, delay, tw)
    base_w = max(abs(w0), mu2 + g["lam"] * mu1 + g["m2"] + g["rho"] * c2_out + b2)
    gw = _outage_gap(lim.phi2, base_w, lim.varpi2 + s2, s2, delay, tw)
    outage = min(gv, gw)
    if outage < ts:
        return outage, (
            f"with a watchdog zeroing torque {tw:.4g} s after the last command, no outage is "
            "tolerated: (2) is not guaranteed even without one"
        )
    return outage, (
        f"with a watchdog zeroing torque {tw:.4g} s after the last command, (2) survives "
        f"sample gaps up to {outage:.4g} s"
    )


def _finite_initial_velocities(v0: float, w0: float) -> tuple[float, float]:
    v0 = float(v0)
    w0 = float(w0)
    if not (math.isfinite(v0) and math.isfinite(w0)):
        raise CertificateError("initial velocities must be finite")
    return v0, w0


def certify(
    params: Any,
    context: DesignContext,
    ts: float,
    delay: float,
    boundary_layer: bool,
    *,
    v0: float = 0.0,
    w0: float = 0.0,
    watchdog_timeout: float | None = None,
) -> Certificate:
    """The certificate of docs/sampled_data_bound.md for the unified law at period ``ts`` (the
    longest gap between sample times of successive applied commands) and worst sample-to-apply
    latency ``delay``. ``boundary_layer`` selects (19) (needs params.eps1, eps2) over (10).

    Raises :class:`CertificateError` on malformed input (negative or non-finite timing, missing
    or non-finite gains); a broken design is reported in the certificate, never raised.
    """
    ts = _finite_nonneg("ts", ts)
    delay = _finite_nonneg("delay", delay)
    v0, w0 = _finite_initial_velocities(v0, w0)
    g = _gains(params, boundary_layer)
    lim = context.limits
    age = ts + delay
    conds = _paper_conditions(context, g, boundary_layer)
    b1, b2 = push_thresholds(context, g, boundary_layer)
    v_bound, c2s, w_bound = _sampled_bounds(context, g, age=age, b=(b1, b2), v0=v0, w0=w0)
    conds += _sampled_conditions(context, g, v_bound, w_bound)
    sampled_ok = all(c.held for c in conds if c.kind == "sampled")
    held = all(c.held for c in conds if c.kind != "info")
    notes = _bound_notes(
        context,
        g,
        ts=ts,
        age=age,
        boundary_layer=boundary_layer,
        b=(b1, b2),
        bounds=(v_bound, c2s),
        v0=v0,
        w0=w0,
    )
    outage = None
    if watchdog_timeout is not None:
        outage, note = _outage_tolerance(
            context,
            g,
            ts=ts,
            delay=delay,
            watchdog_timeout=watchdog_timeout,
            b=(b1, b2),
            v0=v0,
            w0=w0,
        )
        notes.append(note)
    margins = {
        "v": lim.phi1 - v_bound,
        "w": lim.phi2 - w_bound,
        "v_relative": (lim.phi1 - v_bound) / lim.phi1,
        "w_relative": (lim.phi2 - w_bound) / lim.phi2,
    }
    speed_room = context.s1 < lim.varpi1 and context.s2 < lim.varpi2
    return Certificate(
        ts=ts,
        delay=delay,
        age=age,
        boundary_layer=bool(boundary_layer),
        v_bound=v_bound,
        w_bound=w_bound,
        phi1=lim.phi1,
        phi2=lim.phi2,
        c2s=c2s,
        conditions=tuple(conds),
        constraints_guaranteed=bool(sampled_ok and speed_room),
        held=bool(held and speed_room),
        notes=tuple(notes),
        outage_tolerance_s=outage,
        margins=margins,
    )


CRITICAL_AGE_TOL_S = 1e-9  # bisection tolerance of critical_age on the omega side (1 ns)


def critical_age(
    params: Any,
    context: DesignContext,
    boundary_layer: bool,
    *,
    v0: float = 0.0,
    w0: float = 0.0,
    tol: float = CRITICAL_AGE_TOL_S,
) -> float:
    """D*: the largest command age D >= 0 at which the sampled-data bound still implies (2),
    i.e. V(D) <= phi1 and W(D) <= phi2 (docs/sampled_data_bound.md, section 9).

    D is the command age of docs/design.md, "the longest time any command stays in force after
    its sample" (max over j of a_(j+1) - t_j, a the landing times; assumption A2 of the docs);
    :func:`certify` at ``ts = D, delay = 0`` evaluates the bound at exactly that age, with the
    same formulas used here: the push thresholds b1, b2 of ``boundary_layer``, max(|v0|, ...)
    and max(|w0|, ...), and c2s = :func:`sampled_c2` at V(D). The v part is solved in closed
    form,
    D_v = (phi1 - max(|v0|, mu1 + m1 + b1)) / (varpi1 + s1) (stepped down by ulps until
    V(D_v) <= phi1 in floating point); the w part, nondecreasing in D (rho >= 0), is bisected
    on [0, D_v] to ``tol`` (1 ns), keeping the end at which W <= phi2. So certify at the
    returned age has both "sampled" conditions held, and at any age ``tol`` larger at least
    one broken.

    Returns 0.0 when even D = 0 breaks (2) (the bound at D = 0 already exceeds phi1 or phi2,
    e.g. mu1 + m1 + b1 > phi1 or |v0| > phi1), and also when s1 >= varpi1 or s2 >= varpi2
    (the proof needs s < varpi: no age is certified). Never infinite: varpi1 + s1 > 0 and
    varpi2 + s2 > 0 make the bounds grow without limit. Only (2) is concerned; the paper's
    design conditions (9), (11), (12) are :func:`certify`'s ``held``, not part of D*.

    Raises :class:`CertificateError` on malformed input (missing or non-finite gains,
    non-finite v0/w0, non-positive varpi + s or tol).
    """
    v0, w0 = _finite_initial_velocities(v0, w0)
    tol = float(tol)
    if not (math.isfinite(tol) and tol > 0.0):
        raise CertificateError(f"tol must be finite and > 0, got {tol!r}")
    g = _gains(params, boundary_layer)
    lim = context.limits
    rate1 = lim.varpi1 + context.s1
    rate2 = lim.varpi2 + context.s2
    if not (math.isfinite(rate1) and rate1 > 0.0 and math.isfinite(rate2) and rate2 > 0.0):
        raise CertificateError("varpi1 + s1 and varpi2 + s2 must be finite and > 0")
    if not (context.s1 < lim.varpi1 and context.s2 < lim.varpi2):
        return 0.0
    b1, b2 = push_thresholds(context, g, boundary_layer)
    d_v = _velocity_age(context, g["m1"], b1, v0)
    if d_v is None:
        return 0.0

    def w_at(age: float) -> float:
        v_bound = velocity_bound(context, g["m1"], age, b1, v0)
        return omega_bound(
            context,
            m2=g["m2"],
            lam=g["lam"],
            rho=g["rho"],
            v_bound=v_bound,
            age=age,
            b2=b2,
            w0=w0,
        )

    return _bisect_omega_age(w_at, lim.phi2, d_v, tol)


def _velocity_age(context: DesignContext, m1: float, b1: float, v0: float) -> float | None:
    """The largest D with V(D) <= phi1 as :func:`velocity_bound` computes it; None if even
    D = 0 fails. Closed form, then stepped down past rounding."""
    phi1 = context.limits.phi1
    d_v = (phi1 - max(abs(v0), context.mu1 + m1 + b1)) / (context.limits.varpi1 + context.s1)
    if not d_v >= 0.0:  # also NaN
        return None
    while d_v > 0.0 and velocity_bound(context, m1, d_v, b1, v0) > phi1:
        d_v = math.nextafter(d_v, 0.0)
    if velocity_bound(context, m1, d_v, b1, v0) > phi1:
        return None
    return d_v


def _bisect_omega_age(w_at: Callable[[float], float], phi2: float, d_v: float, tol: float) -> float:
    """The largest D in [0, d_v] with W(D) <= phi2 to ``tol`` (W nondecreasing in D), 0.0 when
    even D = 0 fails."""
    if w_at(d_v) <= phi2:
        return d_v
    if not w_at(0.0) <= phi2:
        return 0.0
    lo, hi = 0.0, d_v  # W(lo) <= phi2 < W(hi)
    while hi - lo > tol:
        mid = 0.5 * (lo + hi)
        if mid <= lo or mid >= hi:
            break
        if w_at(mid) <= phi2:
            lo = mid
        else:
            hi = mid
    return lo


@dataclass(frozen=True)
class Proposal:
    """The nearest admissible parameters (``params``; None when impossible) and why."""

    params: Any | None
    reason: str
    changes: dict[str, tuple[float, float]]
    certificate: Certificate | None


def _replace(params: Any, **changes: float) -> Any:
    if dataclasses.is_dataclass(params) and not isinstance(params, type):
        return dataclasses.replace(params, **changes)
    if hasattr(params, "_replace"):
        return params._replace(**changes)
    data = dict(vars(params))
    data.update(changes)
    return type(params)(**data)


def _fit_w_budget(g: dict[str, float], budget: float, c2s: float, mu1: float) -> None:
    """Step 3 of the module rule: m2 + lam mu1 + rho c2s <= budget, in place."""
    load = g["lam"] * mu1 + g["rho"] * c2s
    if g["m2"] + load <= budget:
        return
    if budget - load >= 0.5 * g["m2"]:
        g["m2"] = budget - load
        return
    q = budget / (g["m2"] + load)
    for name in ("m2", "lam", "rho"):
        g[name] *= q


def _fit_m1(
    context: DesignContext, g: dict[str, float], age: float, b1: float, v0: float
) -> str | None:
    """Step 2 of the module rule, in place; the reason when no m1 can do."""
    lim = context.limits
    mu1 = context.mu1
    rise1 = (lim.varpi1 + context.s1) * age
    m1_max = lim.phi1 - mu1 - b1 - rise1
    if abs(v0) + rise1 > lim.phi1:
        return (
            f"|v0| + (varpi1 + s1)(ts + delay) = {abs(v0) + rise1:.4g} "
            f"exceeds phi1 = {lim.phi1:.4g} whatever the gains"
        )
    if m1_max <= 0.0:
        return (
            f"(varpi1 + s1)(ts + delay) = {rise1:.4g} alone exceeds the margin "
            f"phi1 - mu1 - b1 = {lim.phi1 - mu1 - b1:.4g}: shorten the period or the delay"
        )
    g["m1"] = min(g["m1"], m1_max, STRICT_SHRINK * (lim.phi1 - mu1))
    return None


def _omega_budget(
    context: DesignContext, age: float, b2: float, w0: float
) -> tuple[float | None, str]:
    """R of step 3 of the module rule, or None and the reason when it leaves nothing."""
    lim = context.limits
    rise2 = (lim.varpi2 + context.s2) * age
    budget = lim.phi2 - context.mu2 - b2 - rise2
    if abs(w0) + rise2 > lim.phi2:
        return None, (
            f"|w0| + (varpi2 + s2)(ts + delay) = {abs(w0) + rise2:.4g} "
            f"exceeds phi2 = {lim.phi2:.4g} whatever the gains"
        )
    if budget <= 0.0:
        return None, (
            f"(varpi2 + s2)(ts + delay) = {rise2:.4g} alone exceeds the margin "
            f"phi2 - mu2 - b2 = {lim.phi2 - context.mu2 - b2:.4g}: shorten the period or the delay"
        )
    return budget, ""


def _fit_omega_side(
    context: DesignContext, g: dict[str, float], budget: float, c2s: float
) -> str | None:
    """Steps 3 and 4 of the module rule, in place; the reason when (11) or (12) leaves nothing."""
    lim = context.limits
    mu1 = context.mu1
    for _ in range(8):
        _fit_w_budget(g, budget, c2s, mu1)
        g["m2"] = min(g["m2"], STRICT_SHRINK * (lim.phi2 - context.mu2))
        lam_max = lam_bound(context, m2=g["m2"], l2=g["l2"])
        if not g["lam"] < lam_max:
            if not lam_max > 0.0:
                return f"(11) leaves no positive lam (bound {lam_max:.4g})"
            g["lam"] = STRICT_SHRINK * lam_max
        rho_max = rho_bound(context, m1=g["m1"], m2=g["m2"], l1=g["l1"], l2=g["l2"], lam=g["lam"])
        if not g["rho"] < rho_max:
            if not rho_max > 0.0:
                return f"(12) leaves no positive rho (bound {rho_max:.4g})"
            g["rho"] = STRICT_SHRINK * rho_max
        if g["m2"] + g["lam"] * mu1 + g["rho"] * c2s <= budget:
            break
    return None


def _unfixable(first: Certificate, g: dict[str, float]) -> str | None:
    """Why no change of gains can help (a broken Assumption 2, a non-positive gain), if so."""
    bad_assumption = [c for c in first.conditions if c.kind == "assumption" and not c.held]
    if bad_assumption:
        return (
            f"{bad_assumption[0].name} fails: no gains can fix the limits, "
            "references or disturbance bounds"
        )
    for name in ("m1", "m2", "l1", "l2", "lam", "rho"):
        if g[name] <= 0.0:
            return f"{name} must be positive"
    return None


def propose(
    params: Any,
    context: DesignContext,
    ts: float,
    delay: float,
    boundary_layer: bool = False,
    *,
    v0: float = 0.0,
    w0: float = 0.0,
) -> Proposal:
    """The nearest parameters (rule in the module docstring) with which :func:`certify` holds
    at ``ts`` and ``delay``. Returns the request itself when it already holds."""
    first = certify(params, context, ts, delay, boundary_layer, v0=v0, w0=w0)
    if first.held:
        return Proposal(params, "the requested design already holds", {}, first)
    lim = context.limits
    g = _gains(params, boundary_layer)
    if (reason := _unfixable(first, g)) is not None:
        return Proposal(None, reason, {}, None)
    age = ts + delay
    b1, b2 = push_thresholds(context, g, boundary_layer)
    for name, bound in (
        ("l1", lim.varpi1 - context.k1 - context.s1),
        ("l2", lim.varpi2 - context.k2 - context.s2),
    ):
        if g[name] >= bound:
            g[name] = STRICT_SHRINK * bound
    if (reason := _fit_m1(context, g, age, b1, v0)) is not None:
        return Proposal(None, reason, {}, None)
    c2s = sampled_c2(context, velocity_bound(context, g["m1"], age, b1, v0))
    budget, reason = _omega_budget(context, age, b2, w0)
    if budget is None:
        return Proposal(None, reason, {}, None)
    if (reason := _fit_omega_side(context, g, budget, c2s)) is not None:
        return Proposal(None, reason, {}, None)
    changed = {
        name: (float(getattr(params, name)), g[name])
        for name in ("m1", "m2", "l1", "l2", "lam", "rho")
        if g[name] != float(getattr(params, name))
    }
    candidate = _replace(params, **{name: new for name, (_, new) in changed.items()})
    cert = certify(candidate, context, ts, delay, boundary_layer, v0=v0, w0=w0)
    if not cert.held:
        failed = ", ".join(c.name for c in cert.failed())
        return Proposal(None, f"no admissible design found by the rule ({failed})", changed, cert)
    return Proposal(
        candidate, "nearest design by the rule of controller_service.certificate", changed, cert
    )
