"""The ``hil`` front door: one typer app, one module per command under ``hil/commands``.

Each module in :mod:`hil.commands` defines ``register(app: typer.Typer) -> None``; modules are
discovered, so adding a command never edits this file. Exit codes follow the contract:
0 success, 1 negative verdict (a limit broken, a certificate not held), 2 bad usage or input.
"""

from __future__ import annotations

import importlib
import pkgutil
import sys

import click
import typer

from hil.errors import BadInputError, NegativeVerdictError

app = typer.Typer(
    name="hil",
    help=(
        "Test bench for the unified tracking-and-stabilization sliding-mode controller of "
        "Li et al. 2024: run it against an emulated robot over Zenoh and CAN, simulate it "
        "offline, sweep sampling period, delay and jitter, and report what timing did to it."
    ),
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    rich_markup_mode="markdown",
)


@app.callback()
def _root() -> None:
    """Keeps ``hil`` a command group even while only one command is registered."""


def _register_commands() -> None:
    import hil.commands as commands

    for info in sorted(pkgutil.iter_modules(commands.__path__), key=lambda m: m.name):
        module = importlib.import_module(f"hil.commands.{info.name}")
        register = getattr(module, "register", None)
        if register is not None:
            register(app)


_register_commands()


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``hil`` script; maps project errors to the contract's exit codes."""
    try:
        returned = app(args=argv, standalone_mode=False)
    except click.exceptions.Abort:  # Ctrl-C inside a prompt or a progress bar
        typer.echo("interrupted", err=True)
        return 130
    except BadInputError as exc:
        typer.echo(f"error: {exc}", err=True)
        return 2
    except NegativeVerdictError as exc:
        typer.echo(f"verdict: {exc}", err=True)
        return 1
    except KeyboardInterrupt:
        typer.echo("interrupted", err=True)
        return 130
    except SystemExit as exc:  # typer/click exits (e.g. --help) pass through with their code
        return int(exc.code or 0)
    except Exception as exc:  # click usage errors carry exit_code 2
        code = getattr(exc, "exit_code", None)
        if code is not None:
            show = getattr(exc, "show", None)
            if callable(show):
                show()
            return int(code)
        raise
    # With standalone_mode off click returns typer.Exit codes instead of raising them.
    return returned if isinstance(returned, int) else 0


if __name__ == "__main__":
    sys.exit(main())
