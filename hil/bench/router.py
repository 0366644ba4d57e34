"""A Zenoh router on the run's endpoint (:data:`USAGE`): what ``hil run`` starts in router mode;
tests restart it with the same command.

With ``--secure`` (or whenever ``HIL_ZENOH_DICTIONARY`` names a user dictionary,
:mod:`runtime.credentials`) the router authenticates every session and applies the bench's
access control, default deny (:mod:`protocol.zenoh_acl`), for the robots named (default
``robot1``). Only such a router may listen off the host (``--allow-non-loopback``): an open
router on a network is what the access control is for.
"""

from __future__ import annotations

import sys
import time
from typing import Any

import zenoh

from protocol.zenoh_acl import router_config
from runtime.credentials import ENV_DICTIONARY, CredentialsError, dictionary_from_environment
from runtime.zsession import session_config

USAGE = (
    "usage: python -m hil.bench.router ENDPOINT [--secure] [--robots=R1,R2,...] "
    "[--allow-non-loopback]"
)
FLAGS = ("--secure", "--allow-non-loopback")
ROBOTS = "--robots="


def _config(endpoint: str, flags: set[str], robots: list[str]) -> tuple[Any, str]:
    """The router's Zenoh config and the line it prints once up; CredentialsError or
    ValueError (a robot id that cannot be a key chunk, a flag it may not take) says why not."""
    dictionary = dictionary_from_environment()
    if "--secure" in flags and dictionary is None:
        raise ValueError(f"--secure needs {ENV_DICTIONARY}=/path/to/users (0600)")
    if dictionary is None:
        if "--allow-non-loopback" in flags:
            raise ValueError("only a --secure router may listen off the host")
        conf = session_config(endpoint, listen_endpoint=True, mode="router", credentials=None)
        return conf, "router up"
    off_host, robots = "--allow-non-loopback" in flags, robots or ["robot1"]
    conf = router_config([endpoint], str(dictionary), allow_non_loopback=off_host, robots=robots)
    return conf, "router up (usrpwd authentication, access control default deny)"


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    robots = [r for a in args if a.startswith(ROBOTS) for r in a[len(ROBOTS) :].split(",")]
    args = [a for a in args if not a.startswith(ROBOTS)]
    flags = {a for a in args if a.startswith("--")}
    rest = [a for a in args if not a.startswith("--")]
    if len(rest) != 1 or not flags <= set(FLAGS):
        print(USAGE, file=sys.stderr)
        return 2
    try:
        conf, up = _config(rest[0], flags, robots)
    except (CredentialsError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    session = zenoh.open(conf)
    print(up, flush=True)
    try:
        while True:
            time.sleep(3600)
    except KeyboardInterrupt:
        return 0
    finally:
        session.close()


if __name__ == "__main__":
    sys.exit(main())
