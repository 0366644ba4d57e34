"""``hil controller``: the controller service alone (:mod:`hil.commands.service_command`)."""

from __future__ import annotations

import typer

from hil.commands.service_command import register_service_command


def register(app: typer.Typer) -> None:
    register_service_command(app, "controller", "controller_service.service", "controller service")
