"""The ``--live [PORT]`` and ``--live-host`` options, one spelling for every command that
serves a live view (run, drives, fleet; docs/live.md)."""

from __future__ import annotations

from typing import Annotated, Any

import typer

LiveHostOpt = Annotated[
    str,
    typer.Option(
        help="Address the live view binds to. Anything but loopback exposes the run's data "
        "to whoever reaches it (no login, no TLS): a warning says so."
    ),
]


def live_opt(serves: str) -> Any:
    """``--live [PORT]``: ``serves`` says what is served, the rest is the same everywhere."""
    return Annotated[
        int | None,
        typer.Option(
            "--live",
            metavar="[PORT]",
            help=f"Serve {serves} live over the Foxglove WebSocket protocol on this port "
            "(bare --live: 8765; 0: any free port), from a process of its own (docs/live.md).",
        ),
    ]
