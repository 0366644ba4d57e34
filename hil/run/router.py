"""A Zenoh router on the run's endpoint: ``python -m hil.run.router ENDPOINT [--secure]
[--robots=R1,R2,...] [--allow-non-loopback]`` (what ``hil run`` starts in router mode; tests
restart it with the same command).

With ``--secure`` (or whenever ``HIL_ZENOH_DICTIONARY`` names a user dictionary,
:mod:`runtime.credentials`) the router authenticates every session and applies the bench's
access control, default deny (:mod:`protocol.zenoh_acl`), for the robots named (default
``robot1``). Only such a router may listen off the host (``--allow-non-loopback``): an open
router on a network is what the access control is for.
"""

from __future__ import annotations

import sys
import time

import zenoh

from protocol.zenoh_acl import router_config
from runtime.credentials import ENV_DICTIONARY, CredentialsError, dictionary_from_environment
from runtime.zsession import session_config

USAGE = (
    "usage: python -m hil.run.router ENDPOINT [--secure] [--robots=R1,R2,...] "
    "[--allow-non-loopback]"
)
FLAGS = ("--secure", "--allow-non-loopback")
ROBOTS = "--robots="


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
        dictionary = dictionary_from_environment()
    except CredentialsError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if "--secure" in flags and dictionary is None:
        print(f"error: --secure needs {ENV_DICTIONARY}=/path/to/users (0600)", file=sys.stderr)
        return 2
    if dictionary is not None:
        try:
            conf = router_config(
                [rest[0]],
                str(dictionary),
                allow_non_loopback="--allow-non-loopback" in flags,
                robots=robots or ["robot1"],
            )
        except ValueError as exc:  # a robot id that cannot be a key chunk
            print(f"error: {exc}", file=sys.stderr)
            return 2
        up = "router up (usrpwd authentication, access control default deny)"
    elif "--allow-non-loopback" in flags:
        print("error: only a --secure router may listen off the host", file=sys.stderr)
        return 2
    else:
        conf = session_config(rest[0], listen_endpoint=True, mode="router", credentials=None)
        up = "router up"
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
