"""``python -m plant_emulator SETTINGS.json``: the plant emulator from a resolved settings
file alone.

``hil`` writes that file (``run_settings.json`` in a run folder, or
``hil emulator SCENARIO --write-settings FILE``); this entry needs nothing but the service's own
packages below ``hil`` (docs/architecture.md). ``--settings FILE`` is the same.
Exit codes: 0 done, 1 no start, 2 a bad settings file.
"""

from __future__ import annotations

import sys

USAGE = (
    "usage: python -m plant_emulator SETTINGS.json  (a resolved run, written by hil: "
    "'hil emulator SCENARIO --write-settings FILE', or a run folder's run_settings.json; "
    "to run from a scenario use 'hil emulator SCENARIO')"
)


def main(argv: list[str] | None = None) -> int:
    from protocol.errors import BadInputError

    args = list(sys.argv[1:] if argv is None else argv)
    if args in (["--help"], ["-h"]):
        print(USAGE)
        print(__doc__)
        return 0
    if len(args) == 2 and args[0] == "--settings":
        args = args[1:]
    if len(args) != 1 or args[0].startswith("-") or args[0].endswith(".toml"):
        print(USAGE, file=sys.stderr)
        return 2
    from plant_emulator.service import main_from_settings

    try:
        return main_from_settings(args[0])
    except BadInputError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
