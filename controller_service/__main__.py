"""``python -m controller_service SETTINGS.json``: the controller service from a resolved
settings file alone.

``hil`` writes that file (``run_settings.json`` in a run folder, or
``hil controller SCENARIO --write-settings FILE``); this entry needs nothing but the service's own
packages below ``hil`` (docs/architecture.md). ``--settings FILE`` is the same. Several
files (one per robot, ``hil fleet --per-process``): one process serves each of those robots.
Exit codes: 0 done, 1 no start, 2 a bad settings file, 5 the law failed
(protocol.hoplog.LAW_FAULT_EXIT: law_fault.json written into the run folder, no command sent
after the failing sample).
"""

from __future__ import annotations

import sys
from collections.abc import Callable

from runtime.service_main import service_main


def _load() -> Callable[[str], int]:
    # Imported late: --help and bad usage need no service code.
    from controller_service.service import main_from_settings

    return main_from_settings


def main(argv: list[str] | None = None) -> int:
    return service_main("controller_service", "controller", __doc__, _load, argv)


if __name__ == "__main__":
    sys.exit(main())
