"""Bad input, named: the one exception every layer raises for a user's mistake.

It lives at the bottom so that the services (a bad credentials file, a bad settings file) and
``hil`` (a bad scenario key, a bad option) raise the same class, which :func:`hil.cli.main`
maps to exit code 2 (README.md, "Commands")."""

from __future__ import annotations


def one_line(text: object) -> str:
    """``text`` on one line: line breaks (and the whitespace around them) become one space."""
    return " ".join(part.strip() for part in str(text).splitlines() if part.strip())


class BadInputError(Exception):
    """Bad usage or input (a malformed scenario, a design condition broken): exit code 2.

    The message is always one line (a wrapped message from a library or a user's controller
    may hold line breaks); it names the scenario key (``[table] key``) or the option
    (``--name``) at fault."""

    def __init__(self, message: object = "") -> None:
        super().__init__(one_line(message))
