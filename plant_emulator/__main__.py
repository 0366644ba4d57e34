"""``python -m plant_emulator SETTINGS.json``: the plant emulator from a resolved settings
file alone.

``hil`` writes that file (``run_settings.json`` in a run folder, or
``hil emulator SCENARIO --write-settings FILE``); this entry needs nothing but the service's own
packages below ``hil`` (docs/architecture.md). ``--settings FILE`` is the same. Several
files (one per robot, ``hil fleet --per-process``): one process serves each of those robots.
Exit codes: 0 done, 1 no start, 2 a bad settings file.
"""

from __future__ import annotations

import sys
from collections.abc import Callable

from runtime.service_main import service_main


def _load() -> Callable[[str], int]:
    # Imported late: --help and bad usage need no service code.
    from plant_emulator.service import main_from_settings

    return main_from_settings


def main(argv: list[str] | None = None) -> int:
    return service_main("plant_emulator", "emulator", __doc__, _load, argv)


if __name__ == "__main__":
    sys.exit(main())
