"""Errors that map to the contract's exit codes (see :func:`hil.cli.main`)."""

from __future__ import annotations

from protocol.errors import BadInputError, one_line

__all__ = ["BadInputError", "NegativeVerdictError", "one_line"]


class NegativeVerdictError(Exception):
    """The command worked and its verdict is negative (a limit broken): exit code 1."""
