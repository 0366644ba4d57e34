"""A lab host's Zenoh router: ``python -m hil.lab.router --listen EP ... [--connect EP ...]``.

It listens on the host's loopback (where the host's services connect, as they would to the
router of their own computer) and on the host's lab address (where the other hosts' routers
connect); it connects to the routers of the hosts made before it, so the routers form a full
mesh. The lab's addresses exist only inside the lab's namespaces: nothing binds outside.
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading

import zenoh

from protocol.zenoh_config import ZenohSettings, session_config


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m hil.lab.router")
    parser.add_argument("--listen", action="append", default=[])
    parser.add_argument("--connect", action="append", default=[])
    args = parser.parse_args(argv)
    settings = ZenohSettings(
        mode="router",
        listen=tuple(args.listen),
        connect=tuple(args.connect),
        allow_non_loopback=True,  # the lab's own addresses, inside its namespaces
    )
    done = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: done.set())
    session = zenoh.open(session_config(settings))
    print("router up", flush=True)
    try:
        done.wait()
    finally:
        session.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
