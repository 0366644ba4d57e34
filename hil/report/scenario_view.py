"""What a report needs from ``scenario.resolved.toml``: limits, design, timing.

Read defensively (a resolved scenario has every key, but a hand-made folder may not): missing
keys fall back to the paper's Section 4 set-up, as CONTRACT.md's defaults do.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from controller_service.laws.base import DesignContext, Limits

UNIFIED_LAWS = ("unified", "unified_boundary")


def _num(table: Mapping[str, Any], key: str, default: float) -> float:
    value = table.get(key, default)
    try:
        out = float(value)
    except (TypeError, ValueError):
        return default
    return out if math.isfinite(out) else default


@dataclass(frozen=True)
class ScenarioView:
    limits: Limits
    context: DesignContext
    law: str
    controller: dict[str, Any]
    ts: float
    delay: float
    jitter: float
    jitter_kind: str
    duration: float | None
    v0: float = 0.0
    w0: float = 0.0

    @property
    def boundary_layer(self) -> bool:
        return self.law == "unified_boundary"

    @property
    def eps1(self) -> float:
        return _num(self.controller, "eps1", 0.0) if self.boundary_layer else 0.0

    @property
    def eps2(self) -> float:
        return _num(self.controller, "eps2", 0.0) if self.boundary_layer else 0.0

    @property
    def worst_delay(self) -> float:
        """The scenario's worst sample-to-apply delay: delay plus the jitter's bound (uniform
        jitter is bounded by ``jitter``; normal jitter is taken at 4 standard deviations)."""
        if self.jitter_kind == "normal":
            return self.delay + 4.0 * self.jitter
        return self.delay + self.jitter


def view(scenario: Mapping[str, Any]) -> ScenarioView:
    lim = scenario.get("limits", {}) or {}
    dist = scenario.get("disturbance", {}) or {}
    ref = scenario.get("reference", {}) or {}
    ctl = dict(scenario.get("controller", {}) or {})
    tim = scenario.get("timing", {}) or {}
    run = scenario.get("run", {}) or {}
    ini = scenario.get("initial", {}) or {}
    base = Limits()
    limits = Limits(
        phi1=_num(lim, "phi1", base.phi1),
        phi2=_num(lim, "phi2", base.phi2),
        varpi1=_num(lim, "varpi1", base.varpi1),
        varpi2=_num(lim, "varpi2", base.varpi2),
    )
    dc = DesignContext()
    context = DesignContext(
        limits=limits,
        s1=_num(dist, "s1", 0.0),
        s2=_num(dist, "s2", 0.0),
        mu1=_num(ref, "mu1", dc.mu1),
        mu2=_num(ref, "mu2", dc.mu2),
        k1=_num(ref, "k1", dc.k1),
        k2=_num(ref, "k2", dc.k2),
    )
    duration = run.get("duration")
    return ScenarioView(
        limits=limits,
        context=context,
        law=str(ctl.get("law", "unified")),
        controller=ctl,
        ts=_num(tim, "ts", 0.001),
        delay=_num(tim, "delay", 0.0),
        jitter=_num(tim, "jitter", 0.0),
        jitter_kind=str(tim.get("jitter_kind", "uniform")),
        duration=float(duration) if isinstance(duration, int | float) else None,
        v0=_num(ini, "v", 0.0),
        w0=_num(ini, "omega", 0.0),
    )
