"""``--law module:Class``: the same option, help and meaning on ``hil run``, ``sim`` and
``sweep``."""

from __future__ import annotations

import dataclasses
from typing import Annotated, Any

import typer

from hil.errors import BadInputError
from hil.options import plain_string

LAW_HELP = (
    "Control law instead of the scenario's: unified, unified_boundary, jiang1997, jiang2001 or "
    "your own 'module:Class' (a module next to the scenario or in the working directory is "
    "found without PYTHONPATH; hil new-law writes one). The scenario's [controller] "
    "parameters are kept only when they name the same law; otherwise the law's defaults."
)
LawOpt = Annotated[str | None, typer.Option("--law", help=LAW_HELP)]


def with_law(scenario: Any, law: str | None) -> Any:
    """``scenario`` with ``law`` as its [controller] law (None: unchanged). The table is
    checked, not built: the module is imported when the loop is built, from the scenario's
    folder or the working directory."""
    if law is None:
        return scenario
    from controller_service.registry import check_table

    plain_string("--law", law, empty=False)
    if law == scenario.controller.get("law", "unified"):
        return scenario
    table = {"law": law}
    try:
        check_table(table)
    except ValueError as exc:
        raise BadInputError(f"--law: {exc}") from exc
    return dataclasses.replace(scenario, controller=table)
