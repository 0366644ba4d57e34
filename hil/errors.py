"""Errors that map to the contract's exit codes (see :func:`hil.cli.main`)."""

from __future__ import annotations


class BadInputError(Exception):
    """Bad usage or input (a malformed scenario, a design condition broken): exit code 2."""


class NegativeVerdictError(Exception):
    """The command worked and its verdict is negative (a limit broken): exit code 1."""
