"""A lab host's Zenoh router: ``python -m hil.bench.lab.router --listen EP ... [--connect EP ...]``
(docs/lab.md, "What up makes"): on the host's loopback and its lab address, connected to the
routers of the hosts made before it (a full mesh), never bound outside the lab's namespaces.
"""

from __future__ import annotations

import argparse
import signal
import threading

import zenoh

from protocol.zenoh_config import ZenohSettings, session_config


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m hil.bench.lab.router")
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
    raise SystemExit(main())
