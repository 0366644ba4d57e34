"""``hil controller`` and ``hil emulator``: one service alone, as ``hil run`` starts it as a child.

With ``--settings run_settings.json`` it runs exactly as under ``hil run``; with a scenario it
resolves those settings itself (``--write-settings FILE`` only writes them, for deploy/) and
waits for the run's start message (``Status(role="run", state="start")``) unless ``--epoch-ns``
gives t = 0. Both services must reach each other: start a router (deploy/zenoh-router.json5)
on ``--endpoint``.
"""

from __future__ import annotations

import importlib
from pathlib import Path
from typing import Annotated

import typer

from hil import options
from hil.commands import app
from hil.errors import BadInputError

# ``hil NAME``: the module whose ``main_from_settings`` runs the service, and the service's name.
SERVICES = {
    "controller": ("controller_service.service", "controller service"),
    "emulator": ("plant_emulator.service", "plant emulator service"),
}


def service(
    ctx: typer.Context,
    scenario: Annotated[
        Path | None,
        typer.Argument(help="Scenario TOML or a bundled scenario's name (hil scenarios)."),
    ] = None,
    settings: Annotated[Path | None, typer.Option(help="run_settings.json from hil run.")] = None,
    endpoint: Annotated[str, typer.Option(help="Zenoh endpoint to join.")] = "tcp/127.0.0.1:7447",
    duration: Annotated[float | None, typer.Option(help="Run length in s.")] = None,
    rate: Annotated[float | None, typer.Option(help="Control rate in Hz.")] = None,
    cmd_path: Annotated[str, typer.Option(help="zenoh or can.")] = "zenoh",
    lockstep: Annotated[bool, typer.Option()] = False,
    can_endpoint: Annotated[
        str, typer.Option(help="zenoh_can endpoint (the CAN bus over Zenoh).")
    ] = "tcp/127.0.0.1:7449",
    epoch_ns: Annotated[
        int, typer.Option(help="t = 0 as time.monotonic_ns(); 0 waits for the run's start message.")
    ] = 0,
    out: Annotated[Path, typer.Option(help="Where the hop log goes.")] = Path("."),
    start_timeout: Annotated[
        float, typer.Option(help="Seconds to wait for the run's start message (then exit 1).")
    ] = 60.0,
    write_settings: Annotated[
        Path | None,
        typer.Option(
            help="Only write the resolved settings to this file and exit: `python -m "
            "controller_service FILE` or `python -m plant_emulator FILE` then runs the "
            "service without hil."
        ),
    ] = None,
) -> None:
    from protocol.settings import RunSettings

    options.locator("--endpoint", endpoint)
    options.locator("--can-endpoint", can_endpoint)
    options.integer("--epoch-ns", epoch_ns, 0, 2**63 - 1)
    if write_settings is not None:
        options.out_file("--write-settings", write_settings)
    if settings is not None:  # its values checked now: the service would fail after starting
        options.existing_file("--settings", settings)
        try:
            RunSettings.load(settings).validate()
        except BadInputError as exc:
            raise BadInputError(
                f"--settings {settings}: not a valid run_settings.json ({exc})"
            ) from exc
    name = ctx.info_name or ""
    main_from_settings = importlib.import_module(SERVICES[name][0]).main_from_settings
    if settings is None:
        if scenario is None:
            raise BadInputError("give a scenario file or --settings")
        from hil.analysis.replay import latencies_from_run
        from hil.bench.prepare import RunOptions, prepare

        # Resolved as hil run resolves it, with this service's own endpoints and epoch.
        run = {"duration": duration, "rate": rate, "cmd_path": cmd_path, "lockstep": lockstep}
        opts = RunOptions(scenario=scenario, out=out, run_latencies=latencies_from_run, **run)
        opts.fresh_out = False  # the two services may share one folder (default: here)
        _, s, run_dir, _ = prepare(opts)
        s.zenoh_endpoint = endpoint
        s.can_endpoint = can_endpoint
        s.epoch_ns = epoch_ns
        s.start_timeout = start_timeout
        settings = write_settings or run_dir / f"{name}_settings.json"
        settings.parent.mkdir(parents=True, exist_ok=True)  # checked writable before any work
        s.save(settings)
    elif write_settings is not None:
        raise BadInputError("--write-settings needs a scenario, not --settings")
    if write_settings is not None:
        print(f"settings written to {settings}")
        return
    code = main_from_settings(str(settings))
    if code:
        raise typer.Exit(code)


for _name, (_, _what) in SERVICES.items():
    _help = f"Run the {_what} alone (as hil run starts it; see docs/realtime.md)."
    app.command(_name, help=_help)(service)
