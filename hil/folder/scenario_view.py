"""What a report needs from ``scenario.resolved.toml`` (limits, design, timing), read by
:func:`hil.scenario.parse_scenario`: a missing key takes the scenario's documented default, a bad
or unreadable one is a :class:`hil.errors.BadInputError` naming it, never a silent fallback."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace
from typing import Any

from controller_service.laws.base import DesignContext, Limits
from hil.errors import BadInputError
from hil.law.facts import Law
from hil.provenance import Toml
from hil.scenario import Scenario, build_reference, design_context, parse_scenario

BOUND_KEYS = ("mu1", "mu2", "k1", "k2")  # Assumption 2's bounds, in a resolved [reference]


@dataclass(frozen=True)
class ScenarioView:
    limits: Limits
    context: DesignContext
    law: str
    controller: Toml  # the [controller] table, resolved
    ts: float
    delay: float
    jitter: float
    jitter_kind: str
    duration: float | None
    v0: float = 0.0
    w0: float = 0.0

    @property
    def boundary_layer(self) -> bool:
        return Law(self.law).boundary_layer

    @property
    def eps1(self) -> float:
        return float(self.controller.get("eps1", 0.0)) if self.boundary_layer else 0.0

    @property
    def eps2(self) -> float:
        return float(self.controller.get("eps2", 0.0)) if self.boundary_layer else 0.0

    @property
    def worst_delay(self) -> float:
        """The scenario's worst sample-to-apply delay: delay plus the jitter's bound (uniform
        jitter is bounded by ``jitter``; normal jitter is taken at 4 standard deviations)."""
        return self.delay + (4.0 if self.jitter_kind == "normal" else 1.0) * self.jitter


def _without_none(table: Mapping[str, Any]) -> Toml:
    """The tables as scenario.resolved.toml holds them: a None (an unset optional key such as
    ``[realtime] rate``) is left out, as the TOML writer leaves it out."""
    return {
        k: _without_none(v) if isinstance(v, Mapping) else v
        for k, v in table.items()
        if v is not None
    }


def folder_scenario(scenario: Mapping[str, Any], base_dir: Path | None = None) -> Scenario:
    """A folder's ``scenario.resolved.toml`` (its tables) parsed: once per folder and process
    (:attr:`hil.folder.RunFolder.typed`); ``base_dir`` resolves a reference's file."""
    # The period every figure of a report scales with: a resolved scenario always states it,
    # so its absence is a broken folder, not the default's 1 ms.
    timing = scenario.get("timing")
    if not isinstance(timing, Mapping) or "ts" not in timing:
        raise BadInputError("[timing] ts: missing from the resolved scenario")
    return parse_scenario(_without_none(scenario), base_dir or Path("."))


def as_resolved(scenario: Scenario, tables: Mapping[str, Any]) -> Scenario:
    """The scenario a run holds in memory as its folder's ``scenario.resolved.toml`` (``tables``)
    states it: the controller's resolved table, the reference's bounds mu1..k2 and the plant's
    step, without parsing the file again (the rest of it was written from ``scenario``)."""
    plant = dataclasses.replace(scenario.plant, step=scenario.plant_step)
    return dataclasses.replace(
        scenario,
        controller=_without_none(tables.get("controller") or scenario.controller),
        reference=_without_none(tables.get("reference") or scenario.reference),
        plant=plant,
    )


def view(
    scenario: Mapping[str, Any], base_dir: Path | None = None, parsed: Scenario | None = None
) -> ScenarioView:
    """The view of a scenario's tables (``scenario.resolved.toml`` parsed, or a scenario dict);
    ``base_dir`` resolves a reference's file when its bounds mu1..k2 must be computed;
    ``parsed``: the tables already parsed (:func:`folder_scenario`), not parsed again."""
    sc = parsed if parsed is not None else folder_scenario(scenario, base_dir)
    return view_of(sc, "duration" in (scenario.get("run") or {}))


def view_of(sc: Scenario, duration_given: bool = True) -> ScenarioView:
    """The view of a parsed resolved scenario (``duration_given``: its file states the run's
    length)."""
    ref = sc.reference
    if all(k in ref for k in BOUND_KEYS):  # a resolved file has them all
        d = sc.disturbance
        bounds = {k: float(ref[k]) for k in BOUND_KEYS}
        context = DesignContext(limits=sc.limits, s1=d.s1, s2=d.s2, **bounds)
    else:
        context = design_context(sc, build_reference(sc))
    return ScenarioView(
        limits=sc.limits,
        context=context,
        law=str(sc.controller.get("law", "unified")),
        controller=dict(sc.controller),
        ts=sc.timing.ts,
        delay=sc.timing.delay,
        jitter=sc.timing.jitter,
        jitter_kind=sc.timing.jitter_kind,
        duration=sc.run.duration if duration_given else None,
        v0=sc.initial.v,
        w0=sc.initial.omega,
    )


@dataclass(frozen=True)
class BoundInputs:
    """What the sampled-data bound needs besides the measured D (from the resolved scenario)."""

    params: Any
    context: Any
    boundary_layer: bool
    v0: float = 0.0
    w0: float = 0.0


def bound_inputs(resolved: Toml) -> BoundInputs | None:
    """The certificate's inputs from a resolved scenario (None: the law has no certificate)."""
    return bound_inputs_of(view(resolved))


def bound_inputs_of(sv: ScenarioView) -> BoundInputs | None:
    """The certificate's inputs from a scenario's view (None: the law has no certificate)."""
    if not Law(sv.law).has_certificate:
        return None
    return BoundInputs(
        SimpleNamespace(**sv.controller), sv.context, sv.boundary_layer, sv.v0, sv.w0
    )
