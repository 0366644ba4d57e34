"""A CAN echo peer for the vcan lane: ``python -m tools.vcan_guest.can_echo --channel vcan0``.

Answers every request frame with its reply (see ``reply_to``) until the stop frame arrives, then
prints ``ECHOED <n>`` and exits 0. Prints ``READY`` once its socket is bound, so a test can wait
on that line instead of sleeping.
"""

from __future__ import annotations

import argparse
import sys

import can

STOP_ID = 0x7FF
REPLY_FLIP_STD = 0x400
REPLY_FLIP_EXT = 0x1000000


def reply_to(msg: can.Message) -> can.Message:
    """The echo of a request: id with one high bit flipped, data reversed, same DLC and kind."""
    flip = REPLY_FLIP_EXT if msg.is_extended_id else REPLY_FLIP_STD
    return can.Message(
        arbitration_id=msg.arbitration_id ^ flip,
        is_extended_id=msg.is_extended_id,
        data=bytes(reversed(msg.data)),
    )


def is_request(msg: can.Message) -> bool:
    flip = REPLY_FLIP_EXT if msg.is_extended_id else REPLY_FLIP_STD
    return not msg.is_error_frame and not (msg.arbitration_id & flip)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("--channel", default="vcan0")
    parser.add_argument("--idle-timeout", type=float, default=60.0)
    args = parser.parse_args(argv)
    echoed = 0
    with can.Bus(interface="socketcan", channel=args.channel) as bus:
        print("READY", flush=True)
        while True:
            msg = bus.recv(timeout=args.idle_timeout)
            if msg is None:
                print(f"IDLE after {echoed}", flush=True)
                return 3
            if not msg.is_extended_id and msg.arbitration_id == STOP_ID:
                print(f"ECHOED {echoed}", flush=True)
                return 0
            if is_request(msg):
                bus.send(reply_to(msg))
                echoed += 1


if __name__ == "__main__":
    sys.exit(main())
