"""Errors that map to the contract's exit codes (see :func:`hil.cli.main`)."""

from __future__ import annotations

from protocol.errors import BadInputError, one_line

__all__ = ["BadInputError", "NegativeVerdictError", "one_line"]

PASS, FAIL, INCONCLUSIVE = "PASS", "FAIL", "INCONCLUSIVE"
#: The exit code of each outcome, for every command that has a verdict (docs/reports.md,
#: "Verdict and exit code"); here, beside the errors that carry them, so that the command line
#: starts without the verdict's imports.
EXIT_CODE = {PASS: 0, FAIL: 1, INCONCLUSIVE: 4}
#: The rest of the table: bad usage or input, a fault of hil itself (its traceback printed,
#: never a verdict; Python's own code for an uncaught exception would be 1, FAIL's), and an
#: interrupt (Ctrl-C or SIGTERM, after what ran was written).
BAD_INPUT, INTERNAL_ERROR, INTERRUPTED = 2, 3, 130


def exit_code(outcome: str) -> int:
    """The exit code of a verdict's outcome (:data:`EXIT_CODE`); KeyError for anything else."""
    return EXIT_CODE[outcome]


class NegativeVerdictError(Exception):
    """The command worked and its verdict is not PASS: ``outcome`` is "FAIL" (the default) or
    "INCONCLUSIVE", and :func:`hil.cli.main` exits with that outcome's code
    (:data:`EXIT_CODE`: 1 or 4)."""

    def __init__(self, message: str, outcome: str = "FAIL") -> None:
        super().__init__(message)
        self.outcome = outcome
