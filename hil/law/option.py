"""``--law module:Class``: what the option does to a scenario (the option itself, the same on
``hil run``, ``sim``, ``sweep``, ``margin`` and ``fleet``, is :mod:`hil.commands.new_law`)."""

from __future__ import annotations

import dataclasses
from typing import Any

from controller_service.registry import check_table
from hil.errors import BadInputError
from hil.options import plain_string


def with_law(scenario: Any, law: str | None) -> Any:
    """``scenario`` with ``law`` as its [controller] law (None: unchanged). The table is
    checked, not built: the module is imported when the loop is built, from the scenario's
    folder or the working directory."""
    if law is None:
        return scenario
    plain_string("--law", law, empty=False)
    if law == scenario.controller.get("law", "unified"):
        return scenario
    table = {"law": law}
    try:
        check_table(table)
    except ValueError as exc:
        raise BadInputError(f"--law: {exc}") from exc
    return dataclasses.replace(scenario, controller=table)
