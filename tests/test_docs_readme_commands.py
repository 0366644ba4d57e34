"""The README's command table is true to the commands: every option it names for a command
is one of that command's options (what its ``--help`` lists), and every command it names
exists. A row that promises ``hil certify --out`` or ``hil margin --law`` fails here until the
command has it."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import typer

from hil.cli import app

README = Path(__file__).resolve().parents[1] / "README.md"


def _table_invocations() -> list[str]:
    """Every `hil ...` of the first cell of each row of the Commands table."""
    text = README.read_text().split("## Commands", 1)[1].split("\n## ", 1)[0]
    found = []
    for line in text.splitlines():
        if not line.startswith("| `hil "):
            continue
        first = re.split(r"(?<!\\)\|", line)[1]
        found += [c for c in re.findall(r"`([^`]+)`", first) if c.startswith("hil ")]
    return found


def _command(words: list[str]) -> tuple[Any, list[str]]:
    """The (sub)command the words name, and the words after its name (typer ships its own
    copy of click, so a group is what has ``commands``)."""
    cmd = typer.main.get_command(app)
    rest = list(words)
    while hasattr(cmd, "commands") and rest and rest[0] in cmd.commands:
        cmd = cmd.commands[rest.pop(0)]
    return cmd, rest


def _options(cmd: Any) -> set[str]:
    return {o for p in cmd.params for o in (*p.opts, *p.secondary_opts) if o.startswith("--")}


def test_the_table_names_its_commands() -> None:
    calls = _table_invocations()
    assert len(calls) >= 15, calls  # the parser reads the table, not nothing
    for call in calls:
        cmd, _ = _command(call.split()[1:])
        assert not hasattr(cmd, "commands"), f"README: {call!r} names no command of hil"


def test_every_option_the_table_names_is_in_that_commands_help() -> None:
    missing = []
    for call in _table_invocations():
        cmd, rest = _command(call.split()[1:])
        named = {w.split("=")[0] for w in re.findall(r"--[a-z][a-z0-9-]*", " ".join(rest))}
        missing += [f"{call!r}: {o}" for o in sorted(named - _options(cmd))]
    assert not missing, missing


def test_certify_and_margin_take_what_every_command_takes() -> None:
    """The README: every command writes under --out; --law runs a law wherever one runs."""
    rows = {c.split()[1]: c for c in _table_invocations()}
    assert "--out" in rows["certify"] and "--law" in rows["margin"]
