"""Several robots' services in one process (a fleet on a 2-core machine): one thread per robot,
each with its own service object, keys, hop log, state and deadlines; the process' Zenoh
session, its scheduling set-up (policy, CPU, locked memory, frozen GC) and its signal handlers
are shared. Each thread runs what the process would run for that robot alone.
"""

from __future__ import annotations

import sys
import threading
import traceback
from collections.abc import Callable, Sequence

from protocol.errors import BadInputError
from protocol.settings import RunSettings
from runtime.zsession import check_credentials

JOIN_POLL_S = 0.2  # the main thread wakes this often: signal handlers run on it only


def run_threads(names: Sequence[str], bodies: Sequence[Callable[[], int]]) -> int:
    """Run each body in its own thread (named after its robot) until all end; the process'
    exit code is the largest of theirs (an exception counts as 1 and is printed)."""
    codes: dict[str, int] = {}

    def wrap(name: str, body: Callable[[], int]) -> None:
        try:
            codes[name] = int(body())
        except Exception:
            print(f"{name}: {traceback.format_exc()}", file=sys.stderr, flush=True)
            codes[name] = 1

    threads = [
        threading.Thread(target=wrap, args=(n, b), name=n, daemon=True)
        for n, b in zip(names, bodies, strict=True)
    ]
    for t in threads:
        t.start()
    for t in threads:
        while t.is_alive():
            t.join(JOIN_POLL_S)
    return max(codes.values(), default=0)


def check_group(settings: Sequence[RunSettings]) -> None:
    """The robots of one process share its session and its scheduling: their settings must
    agree on those, and name different robots (a BadInputError names the first that does
    not)."""
    first = settings[0]
    seen: set[str] = set()
    for s in settings:
        if s.robot_id in seen:
            raise BadInputError(f"robot {s.robot_id} twice in one process")
        seen.add(s.robot_id)
        for name in ("zenoh_endpoint", "zenoh_mode", "scheduling", "lockstep"):
            if getattr(s, name) != getattr(first, name):
                raise BadInputError(
                    f"robot {s.robot_id}: {name} {getattr(s, name)!r} differs from robot "
                    f"{first.robot_id}'s {getattr(first, name)!r} (one process, one {name})"
                )


def load_group(paths: Sequence[str]) -> list[RunSettings]:
    """One process's robots: each settings file loaded and validated, the group checked
    (:func:`check_group`) and the session's credentials too, before anything is written."""
    settings = [RunSettings.load(p) for p in paths]
    for s in settings:
        s.validate()
    check_group(settings)
    check_credentials(settings[0].zenoh_endpoint, settings[0].zenoh_mode)
    return settings
