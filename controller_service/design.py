"""Design constants and admissibility checks of the unified law (Li et al. 2024, Section 3).

Everything here is pure arithmetic on a :class:`DesignContext` (limits (2), disturbance bounds of
Assumption 1, reference bounds of Assumption 2) and the law's parameters.

- :func:`design_constants`: c0..c7 of Theorem 1. The paper writes ``varpi1`` alone in c5; the
  second derivative h = r'' contains xe v'/r with v' = tau1 + d1, so ``varpi1 + s1`` is used.
- :func:`check_unified`: Assumption 2, the positivity of the gains, (9), (11) and (12). The first
  violated condition raises :class:`DesignError` naming the condition, the value and the bound.
- :func:`lam_bound` / :func:`rho_bound`: the right-hand sides (the minima) of (11) and (12); a
  term divided by mu1 = 0 (pure stabilization) is +infinity.
- :func:`resolve_auto`: ``lam = "auto"`` / ``rho = "auto"`` take the bound times
  :data:`SAFETY_FACTOR` (0.9) because (11) and (12) are strict inequalities. Where the bound is
  +infinity (only (11) for lam, when mu1 = 0: lam then enters no condition) lam takes the finite
  default :data:`LAM_DEFAULT_UNBOUNDED` = 1.0 (Table 1) and a note says so. rho always has a
  finite bound because its first term, (phi2 - mu2 - m2 - lam mu1)/c2, is finite.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any, NamedTuple

from controller_service.laws.base import DesignContext

SAFETY_FACTOR = 0.9
LAM_DEFAULT_UNBOUNDED = 1.0

LAM_CONDITION = (
    "(11) lam < min{(phi2 - mu2 - m2)/mu1, (varpi2 - k2 - l2 - s2)/(k1 + mu1 (c0 + c3 + c4))}"
)
RHO_CONDITION = (
    "(12) rho < min{(phi2 - mu2 - m2 - lam mu1)/c2, (varpi1 - k1 - l1 - s1)/(mu1 c2),"
    " (varpi2 - k2 - l2 - s2 - lam (k1 + mu1 (c0 + c3 + c4)))/(lam mu1 c2 + c7)}"
)


class DesignError(ValueError):
    """A design condition of the paper is broken.

    ``condition`` names it as the paper writes it (e.g. ``"(9) m1 < phi1 - mu1"``), ``value`` is
    the left-hand side and ``bound`` the right-hand side that it failed to stay below.
    """

    def __init__(self, condition: str, value: float, bound: float) -> None:
        self.condition = condition
        self.value = float(value)
        self.bound = float(bound)
        super().__init__(
            f"design condition {condition} is violated: value {self.value:.6g} "
            f"is not below the bound {self.bound:.6g}"
        )


def design_constants(context: DesignContext, v_bound: float | None = None) -> dict[str, float]:
    """The constants c0..c7 of Theorem 1 (docs/design.md, section 1, with s1 in c5).

    ``v_bound`` replaces phi1 wherever phi1 stands for the bound on |v| (c0, c3, c5): under
    sampling |v| may exceed phi1, and the sampled-data certificate then needs the larger value.
    """
    lim = context.limits
    phi1 = lim.phi1 if v_bound is None else float(v_bound)
    phi2 = lim.phi2
    mu1, mu2, k1, k2, s1 = context.mu1, context.mu2, context.k1, context.k2, context.s1
    c0 = mu1 + phi1
    c1 = c0 + 1.0
    c2 = c1 + mu1**2 + mu2**2
    c3 = phi1 + mu1 + phi2
    c4 = mu2 + phi2
    c5 = (
        mu1**2
        + 2.0 * mu1 * phi1
        + phi1**2
        + phi1 * phi2
        + (lim.varpi1 + s1)
        + k1
        + mu1 * mu2
        + (mu1 + phi1) * c0
    )
    c6 = 1.0 + 2.0 * c0 + 2.0 * c0**2 + c5
    c7 = 2.0 * mu1 * k1 + 2.0 * mu2 * k2 + (mu1**2 + mu2**2) * (c1 + c2) + c6
    return {"c0": c0, "c1": c1, "c2": c2, "c3": c3, "c4": c4, "c5": c5, "c6": c6, "c7": c7}


def _ratio(num: float, den: float) -> float:
    """num/den where den = 0 (a term divided by mu1 = 0) is +infinity, as the paper reads it."""
    if den == 0.0:
        return math.inf
    return num / den


def lam_bound(context: DesignContext, *, m2: float, l2: float) -> float:
    """The right-hand side of (11): the supremum of admissible lam."""
    lim = context.limits
    c = design_constants(context)
    mu1 = context.mu1
    return min(
        _ratio(lim.phi2 - context.mu2 - m2, mu1),
        _ratio(
            lim.varpi2 - context.k2 - l2 - context.s2,
            context.k1 + mu1 * (c["c0"] + c["c3"] + c["c4"]),
        ),
    )


def rho_bound(
    context: DesignContext, *, m1: float, m2: float, l1: float, l2: float, lam: float
) -> float:
    """The right-hand side of (12): the supremum of admissible rho for the given lam."""
    lim = context.limits
    c = design_constants(context)
    mu1 = context.mu1
    k_term = context.k1 + mu1 * (c["c0"] + c["c3"] + c["c4"])
    return min(
        _ratio(lim.phi2 - context.mu2 - m2 - lam * mu1, c["c2"]),
        _ratio(lim.varpi1 - context.k1 - l1 - context.s1, mu1 * c["c2"]),
        _ratio(
            lim.varpi2 - context.k2 - l2 - context.s2 - lam * k_term,
            lam * mu1 * c["c2"] + c["c7"],
        ),
    )


def _below(condition: str, value: float, bound: float) -> None:
    # "not (value < bound)" also refuses NaN.
    if not (value < bound):
        raise DesignError(condition, value, bound)


def check_assumption2(context: DesignContext) -> None:
    """Assumption 2 (and Assumption 1's bounds being non-negative): raises :class:`DesignError`."""
    lim = context.limits
    for name in ("s1", "s2", "mu1", "mu2", "k1", "k2"):
        value = getattr(context, name)
        if not (value >= 0.0) or math.isinf(value):
            raise DesignError(f"{name} >= 0 (finite)", -abs(value), 0.0)
    _below("Assumption 2 mu1 < phi1", context.mu1, lim.phi1)
    _below("Assumption 2 mu2 < phi2", context.mu2, lim.phi2)
    _below("Assumption 2 k1 < varpi1 - s1", context.k1, lim.varpi1 - context.s1)
    _below("Assumption 2 k2 < varpi2 - s2", context.k2, lim.varpi2 - context.s2)


def check_design9(context: DesignContext, *, m1: float, m2: float, l1: float, l2: float) -> None:
    """Positivity of m1, m2, l1, l2 and condition (9)."""
    lim = context.limits
    for name, value in (("m1", m1), ("m2", m2), ("l1", l1), ("l2", l2)):
        _below(f"{name} > 0", -value, 0.0)
    _below("(9) m1 < phi1 - mu1", m1, lim.phi1 - context.mu1)
    _below("(9) m2 < phi2 - mu2", m2, lim.phi2 - context.mu2)
    _below("(9) l1 < varpi1 - k1 - s1", l1, lim.varpi1 - context.k1 - context.s1)
    _below("(9) l2 < varpi2 - k2 - s2", l2, lim.varpi2 - context.k2 - context.s2)


def check_unified(params: Any, context: DesignContext) -> None:
    """Every condition of Theorem 1 for ``params`` (a UnifiedParams or any object with m1, m2,
    l1, l2, lam, rho and optional eps1, eps2): Assumption 2, (9), (11), (12), positivity.

    Raises :class:`DesignError` at the first violation.
    """
    check_assumption2(context)
    m1, m2, l1, l2 = (float(getattr(params, k)) for k in ("m1", "m2", "l1", "l2"))
    lam, rho = float(params.lam), float(params.rho)
    check_design9(context, m1=m1, m2=m2, l1=l1, l2=l2)
    _below("lam > 0", -lam, 0.0)
    _below("rho > 0", -rho, 0.0)
    _below(LAM_CONDITION, lam, lam_bound(context, m2=m2, l2=l2))
    _below(RHO_CONDITION, rho, rho_bound(context, m1=m1, m2=m2, l1=l1, l2=l2, lam=lam))
    for name in ("eps1", "eps2"):
        eps = getattr(params, name, None)
        if eps is not None:
            _below(f"(19) {name} > 0", -float(eps), 0.0)
            _below(f"(19) {name} finite", float(eps), math.inf)


class AutoResolution(NamedTuple):
    """Parameters with ``"auto"`` lam/rho replaced by numbers, and notes saying how."""

    params: dict[str, Any]
    notes: tuple[str, ...]


def resolve_auto(
    params: Mapping[str, Any], context: DesignContext, safety: float = SAFETY_FACTOR
) -> AutoResolution:
    """Replace ``lam = "auto"`` and ``rho = "auto"`` in ``params`` (a dict with m1, m2, l1, l2,
    lam, rho) by ``safety`` times the bound of (11) / (12); lam is resolved first since (12)
    depends on it. An infinite lam bound (mu1 = 0) gives lam = LAM_DEFAULT_UNBOUNDED.

    Conditions (9) and Assumption 2 are checked first so a bound is never computed from an
    inadmissible design. The result is not checked against (11)/(12) here: see check_unified.
    """
    out = dict(params)
    notes: list[str] = []
    if out.get("lam") == "auto" or out.get("rho") == "auto":
        check_assumption2(context)
        check_design9(
            context,
            m1=float(out["m1"]),
            m2=float(out["m2"]),
            l1=float(out["l1"]),
            l2=float(out["l2"]),
        )
    if out.get("lam") == "auto":
        bound = lam_bound(context, m2=float(out["m2"]), l2=float(out["l2"]))
        if math.isinf(bound):
            out["lam"] = LAM_DEFAULT_UNBOUNDED
            notes.append(
                f"lam = auto: (11) gives no finite bound (mu1 = 0), so lam = "
                f"{LAM_DEFAULT_UNBOUNDED} (Table 1's value)"
            )
        else:
            if not (bound > 0.0):
                raise DesignError(LAM_CONDITION, 0.0, bound)
            out["lam"] = safety * bound
            notes.append(f"lam = auto: {safety} x bound of (11) {bound:.6g} = {out['lam']:.6g}")
    if out.get("rho") == "auto":
        bound = rho_bound(
            context,
            m1=float(out["m1"]),
            m2=float(out["m2"]),
            l1=float(out["l1"]),
            l2=float(out["l2"]),
            lam=float(out["lam"]),
        )
        if not (bound > 0.0):
            raise DesignError(RHO_CONDITION, 0.0, bound)
        out["rho"] = safety * bound
        notes.append(f"rho = auto: {safety} x bound of (12) {bound:.6g} = {out['rho']:.6g}")
    return AutoResolution(out, tuple(notes))
