"""The controller's law built from the resolved run settings alone (no scenario, no ``hil``).

``hil`` resolved the scenario into :class:`protocol.settings.RunSettings`: the ``[controller]``
table as given, the virtual robot (3), the design context (limits (2), s1, s2 of Assumption 1,
mu1..k2 of Assumption 2) and z1(0), z2(0) of (8). The law is built from them by the same
constructors ``hil.scenario.build_loop`` and the offline simulator use
(:func:`controller_service.registry.build_controller`,
:func:`controller_service.references.build_reference`, :func:`initial_memory`), so lockstep
equals the simulation bit for bit.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from controller_service.laws.base import DesignContext
from controller_service.laws.guard import LawFaultError, build_fault
from controller_service.references import build_reference
from controller_service.registry import build_controller
from protocol.settings import RunSettings


def initial_memory(controller: Any, n: int | None, z1: Any = 0.0, z2: Any = 0.0) -> Any:
    """The law's memory at t = 0 for one robot (``n is None``) or ``n``, with z1(0), z2(0) of
    (8) (every law takes them: ``Controller.initial_memory``; one without adaptive states
    ignores them). The simulator calls the same, so lockstep equals it bit for bit."""
    return controller.initial_memory(n, z1=z1, z2=z2)


def design_context(s: RunSettings) -> DesignContext:
    """The design context the law was checked against when ``hil`` resolved the scenario."""
    return DesignContext(limits=s.limits_value, **s.design)


def build_law(s: RunSettings) -> tuple[Any, Any, Any, str]:
    """(the law, the reference (3), its memory at t = 0, the law's name) for the run ``s``; a
    law whose module or constructor raises here raises :class:`LawFaultError` (``"build"``):
    a fault of the law, not of the bench."""
    reference = build_reference(s.reference, Path(s.base_dir))
    named = str(s.controller.get("law", "unified"))
    try:
        controller = build_controller(dict(s.controller), design_context(s), s.law_path)
        memory = initial_memory(controller, None, s.initial["z1"], s.initial["z2"])
    except Exception as exc:  # the user's module and constructor may raise anything
        cause: BaseException = exc
        while cause.__cause__ is not None:  # what the law raised, not the registry's wrapper
            cause = cause.__cause__
        module = named.partition(":")[0].rpartition(".")[2]
        raise LawFaultError(build_fault(module, named, cause)) from exc
    law = str(s.controller.get("law", getattr(controller, "name", "unified")))
    return controller, reference, memory, law
