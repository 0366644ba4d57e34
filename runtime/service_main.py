"""The command line both services share: ``python -m SERVICE SETTINGS.json``.

One settings file written by ``hil`` (``run_settings.json`` of a run folder, or
``hil controller|emulator SCENARIO --write-settings FILE``); ``--settings FILE`` is the same.
Several files (one per robot, ``hil fleet --per-process``): one process serves each robot
(runtime.group).
Exit codes: 0 done, 1 no start, 2 usage or a bad settings file.
"""

from __future__ import annotations

import sys
from collections.abc import Callable


def usage(module: str, hil_command: str) -> str:
    return (
        f"usage: python -m {module} SETTINGS.json [MORE.json ...]  (a resolved run, one per "
        f"robot, written by hil: "
        f"'hil {hil_command} SCENARIO --write-settings FILE', or a run folder's "
        f"run_settings.json; to run from a scenario use 'hil {hil_command} SCENARIO')"
    )


def service_main(
    module: str,
    hil_command: str,
    doc: str | None,
    load: Callable[[], Callable[..., int]],
    argv: list[str] | None = None,
) -> int:
    """Parse ``argv`` and run the service; ``load`` imports its ``main_from_settings`` (only
    once the arguments are known good: ``--help`` needs nothing else)."""
    from protocol.errors import BadInputError

    args = list(sys.argv[1:] if argv is None else argv)
    if args in (["--help"], ["-h"]):
        print(usage(module, hil_command))
        print(doc)
        return 0
    if len(args) == 2 and args[0] == "--settings":
        args = args[1:]
    if not args or any(a.startswith("-") or a.endswith(".toml") for a in args):
        print(usage(module, hil_command), file=sys.stderr)
        return 2
    try:
        return load()(*args)
    except BadInputError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
