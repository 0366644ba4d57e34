"""``python -m hil.commands.group SPEC.json``: one group of a fleet's robots (``hil fleet
--per-process K`` starts one such process per group): the bench records the K robots
(:func:`hil.bench.group.record`), then each robot's folder is analysed as ``hil run`` analyses
its own, and each robot's exit code is written where ``hil fleet`` reads it. Not a command of
``hil``: a process the fleet starts."""

from __future__ import annotations

import json
import sys
from pathlib import Path


def main(argv: list[str] | None = None) -> int:
    from hil.analysis.analyze import write_results
    from hil.analysis.replay import latencies_from_run
    from hil.bench.group import GroupSpec, record
    from hil.bench.lab import placement
    from hil.folder import layout
    from hil.verdict import FAIL, INCONCLUSIVE, INTERRUPTED, PASS, exit_code, run_outcome
    from runtime.signals import stop_on_signals

    args = sys.argv[1:] if argv is None else argv
    if len(args) != 1:
        print(
            "usage: python -m hil.commands.group SPEC.json (written by hil fleet)", file=sys.stderr
        )
        return 2
    spec = GroupSpec.read(Path(args[0]))
    # --lab: executes this same command again on the recorder's lab host (as hil run does).
    placed = placement.enter(spec.options(), False, True)
    with stop_on_signals() as stop:
        codes: dict[str, int] = {}
        for rec in record(spec, stop, placed, latencies_from_run):
            # Each robot's trace.csv, summary.json and plots, and the exit code hil run gives
            # that summary (hil.commands.run).
            codes[rec.settings.robot_id] = exit_code(run_outcome(write_results(rec)))
        # Where hil fleet reads each robot's exit code (as ``hil run`` would exit for it).
        (Path(spec.out) / layout.group_codes(spec.robots[0])).write_text(json.dumps(codes) + "\n")
    if stop:
        return INTERRUPTED
    # The group's worst robot: any FAIL, else any INCONCLUSIVE (hil fleet reads each robot's).
    for outcome in (FAIL, INCONCLUSIVE):
        if exit_code(outcome) in codes.values():
            return exit_code(outcome)
    return exit_code(PASS)


if __name__ == "__main__":
    sys.exit(main())
