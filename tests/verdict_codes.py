"""The exit code a command owes its folder's verdict (hil.verdict.EXIT_CODE: PASS 0, FAIL 1,
INCONCLUSIVE 4), for tests that run a real command whose verdict the machine decides: the code
must be the verdict's, whatever the verdict."""

from __future__ import annotations

import json
from pathlib import Path

from hil.verdict import EXIT_CODE, run_outcome


def run_code(run_dir: Path) -> int:
    """``hil run``'s code for its run folder (its summary's verdict; a run error is a FAIL)."""
    return EXIT_CODE[run_outcome(json.loads((run_dir / "summary.json").read_text()))]


def report_code(folder: Path) -> int:
    """``hil report``'s code for the report it wrote into ``folder``."""
    return EXIT_CODE[json.loads((folder / "report.json").read_text())["verdict"]["outcome"]]


def fleet_code(out: Path) -> int:
    """``hil fleet``'s code for the fleet report it wrote into ``out``."""
    return EXIT_CODE[json.loads((out / "fleet.json").read_text())["fleet"]["verdict"]]
