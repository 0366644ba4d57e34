"""The ``hil`` front door: one typer app, its commands in the modules of ``hil/commands``.

A module of :mod:`hil.commands` adds its commands to ``hil.commands.app`` when imported;
modules are discovered, so adding a command never edits this file. Exit codes are the table of
:mod:`hil.errors` (docs/reports.md, "Verdict and exit code"): 0 PASS or success, 1 FAIL, 4
INCONCLUSIVE, 2 bad usage or input, 3 the tool itself failed (an unexpected exception: its
traceback is printed; a script must not read it as a verdict), 130 interrupted (Ctrl-C; what
was done is kept). The interrupt is recorded by the project's own SIGINT handler
(:mod:`hil.interrupts`), so the exit code does not depend on what the CLI library does with a
KeyboardInterrupt.
"""

from __future__ import annotations

import importlib
import pkgutil
import sys
import traceback

import typer

from hil import commands, interrupts, options
from hil.commands import app
from hil.errors import (
    BAD_INPUT,
    INTERNAL_ERROR,
    INTERRUPTED,
    BadInputError,
    NegativeVerdictError,
    exit_code,
    one_line,
)

# Every command of hil.commands, listed by ``hil --help`` in alphabetical order.
for _info in pkgutil.iter_modules(commands.__path__):
    importlib.import_module(f"hil.commands.{_info.name}")
app.registered_commands.sort(key=lambda command: command.name or "")


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``hil`` script; maps project errors to the contract's exit codes."""
    with interrupts.installed():
        try:
            code = _dispatch(argv)
        except BaseException:
            if not interrupts.happened():
                raise
            code = INTERRUPTED
        if interrupts.happened():
            typer.echo(interrupts.message(), err=True)
            return INTERRUPTED
        return code


def _dispatch(argv: list[str] | None) -> int:
    """The command's exit code. After an interrupt any outcome means 130 (see :func:`main`),
    so nothing is printed for it here."""
    argv = options.expand_live_flag(sys.argv[1:] if argv is None else argv)  # --live [PORT]
    try:
        returned = app(args=argv, standalone_mode=False)
    except KeyboardInterrupt:  # not through hil.interrupts' handler: the same meaning
        interrupts.record()
        return INTERRUPTED
    except BadInputError as exc:
        if not interrupts.happened():
            typer.echo(f"error: {exc}", err=True)
        return BAD_INPUT
    except NegativeVerdictError as exc:
        if not interrupts.happened():
            typer.echo(f"verdict: {exc.outcome}: {exc}", err=True)
        return exit_code(exc.outcome)
    except SystemExit as exc:  # exits of the CLI library (e.g. --help) keep their code
        if isinstance(exc.code, str):
            typer.echo(exc.code, err=True)
            return 1
        return int(exc.code or 0)
    except Exception as exc:  # usage errors of the CLI library carry exit_code 2
        if interrupts.happened():  # whatever the library wrapped the KeyboardInterrupt in
            return INTERRUPTED
        code = getattr(exc, "exit_code", None)
        line = _usage_line(exc)
        if code == BAD_INPUT and line is not None:  # a bad option or argument: one line naming it
            typer.echo(f"error: {line}", err=True)
            return BAD_INPUT
        if code is not None:
            show = getattr(exc, "show", None)
            if callable(show):
                show()
            return int(code)
        traceback.print_exc()
        typer.echo(
            f"internal error: {type(exc).__name__}: {one_line(exc)} (a fault of hil itself, not "
            f"a verdict on your system: exit code {INTERNAL_ERROR}; please report it with the "
            "traceback above)",
            err=True,
        )
        return INTERNAL_ERROR
    # With standalone_mode off the CLI library returns typer.Exit codes instead of raising them.
    return returned if isinstance(returned, int) else 0


def _usage_line(exc: Exception) -> str | None:
    """A usage error of the CLI library (click's or the copy typer ships: both have
    ``format_message`` and ``ctx``) as one line saying where the options are; None for
    anything else."""
    fmt = getattr(exc, "format_message", None)
    message = one_line(fmt()) if callable(fmt) else ""
    if not message:  # also "no arguments: show the help", which carries no message of its own
        return None
    path = getattr(getattr(exc, "ctx", None), "command_path", None)
    return message + (f" (see {path} --help)" if path else "")


if __name__ == "__main__":
    sys.exit(main())
