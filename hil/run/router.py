"""A Zenoh router on the run's endpoint: ``python -m hil.run.router ENDPOINT`` (what ``hil run``
starts in router mode; tests restart it with the same command)."""

from __future__ import annotations

import sys
import time


def main(argv: list[str] | None = None) -> int:
    import zenoh

    from hil.run.zsession import session_config

    args = sys.argv[1:] if argv is None else argv
    if len(args) != 1:
        print("usage: python -m hil.run.router ENDPOINT", file=sys.stderr)
        return 2
    session = zenoh.open(session_config(args[0], listen_endpoint=True, mode="router"))
    print("router up", flush=True)
    try:
        while True:
            time.sleep(3600)
    except KeyboardInterrupt:
        return 0
    finally:
        session.close()


if __name__ == "__main__":
    sys.exit(main())
