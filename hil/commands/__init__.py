"""``hil`` subcommands: each module adds its commands to :data:`app` (see :mod:`hil.cli`)."""

from typing import Annotated

import typer

#: ``--force`` of every command that writes a folder (hil.folder.claim): one spelling.
ForceOpt = Annotated[
    bool,
    typer.Option(
        "--force",
        help="Replace the output folder whole when it already holds files (a folder hil "
        "wrote); without it such a folder is refused, so no stale file stays beside new ones.",
    ),
]

app = typer.Typer(
    name="hil",
    help="Test bench for the unified tracking-and-stabilization sliding-mode controller of "
    "Li et al. 2024: run it against an emulated robot over Zenoh and CAN, simulate it "
    "offline, sweep sampling period, delay and jitter, and report what timing did to it.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    rich_markup_mode="markdown",
)
