"""``hil controller``: the controller service alone (what ``hil run`` starts as a child).

With ``--settings run_settings.json`` it runs exactly as under ``hil run``; with a scenario it
builds those settings itself, joins the Zenoh endpoint given and waits for the run's start
message (``Status(role="run", state="start")``) unless ``--epoch-ns`` gives t = 0. Both
services must reach each other: start a router (deploy/zenoh-router.json5) on ``--endpoint``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from hil.errors import BadInputError


def register(app: typer.Typer) -> None:
    @app.command("controller")
    def controller(
        scenario: Annotated[Path | None, typer.Argument(help="Scenario TOML.")] = None,
        settings: Annotated[
            Path | None, typer.Option(help="run_settings.json from hil run.")
        ] = None,
        endpoint: Annotated[
            str, typer.Option(help="Zenoh endpoint to join.")
        ] = "tcp/127.0.0.1:7447",
        duration: Annotated[float | None, typer.Option(help="Run length in s.")] = None,
        rate: Annotated[float | None, typer.Option(help="Control rate in Hz.")] = None,
        cmd_path: Annotated[str, typer.Option(help="zenoh or can.")] = "zenoh",
        lockstep: Annotated[bool, typer.Option()] = False,
        can_endpoint: Annotated[
            str, typer.Option(help="zenoh_can endpoint (the CAN bus over Zenoh).")
        ] = "tcp/127.0.0.1:7449",
        epoch_ns: Annotated[
            int,
            typer.Option(help="t = 0 as time.monotonic_ns(); 0 waits for the run's start message."),
        ] = 0,
        out: Annotated[Path, typer.Option(help="Where the hop log goes.")] = Path("."),
    ) -> None:
        """Run the controller service."""
        from controller_service.service import main_from_settings

        if settings is None:
            if scenario is None:
                raise BadInputError("give a scenario file or --settings")
            from hil.run.orchestrate import RunOptions, prepare

            out.mkdir(parents=True, exist_ok=True)
            _, s, run_dir, _ = prepare(
                RunOptions(
                    scenario=scenario,
                    duration=duration,
                    rate=rate,
                    cmd_path=cmd_path,
                    lockstep=lockstep,
                    out=out,
                )
            )
            s.zenoh_endpoint = endpoint
            s.can_endpoint = can_endpoint
            s.epoch_ns = epoch_ns
            settings = run_dir / "controller_settings.json"
            s.save(settings)
        code = main_from_settings(str(settings))
        if code:
            raise typer.Exit(code)
