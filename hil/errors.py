"""Errors that map to the contract's exit codes (see :func:`hil.cli.main`)."""

from __future__ import annotations

from protocol.errors import BadInputError, one_line

__all__ = ["BadInputError", "NegativeVerdictError", "one_line"]


class NegativeVerdictError(Exception):
    """The command worked and its verdict is not PASS: ``outcome`` is "FAIL" (the default) or
    "INCONCLUSIVE", and :func:`hil.cli.main` exits with that outcome's code
    (:data:`hil.verdict.EXIT_CODE`: 1 or 4)."""

    def __init__(self, message: str, outcome: str = "FAIL") -> None:
        super().__init__(message)
        self.outcome = outcome
