"""The recorder's CPU cost per message, by kind: what ``hil run`` pays to record a run.

    python bench/bench_recorder.py [--messages 20000] [--repeats 5]

Times ``Recorder._write_one`` (decode the payload, convert it to JSON, append it to the MCAP
writer) on one message of each kind the recorder sees at 1 kHz with both paths live (about
2,700 a second): a State and a TorqueCommand as msgpack from Zenoh, and two CAN frames as
python-can Messages. Prints the median over the repeats, in microseconds a message, on
``time.perf_counter``. The recorder thread must keep up with the run, or its queue grows (and a
kill of ``hil run`` then loses what was queued: docs/reliability.md).
"""

from __future__ import annotations

import argparse
import json
import statistics
import tempfile
import time
from pathlib import Path

import _here  # noqa: F401  (this checkout first on sys.path)

from hil.bench.recorder import Recorder, RecordingWriter
from protocol.can.codec import Heartbeat, SetInputTorque
from protocol.can.codec import encode as can_encode
from protocol.can.drive_link import to_message
from protocol.messages import State, TorqueCommand, encode


def _cases() -> dict[str, tuple[str, object]]:
    state = State("robot0", 1, 123_456_789, 123_456_999, 0.1, 0.2, 0.3, 0.4, 0.5)
    torque = TorqueCommand("robot0", 1, 1, 123, 124, 125, 0.5, -0.5, "unified", 0)
    return {
        "state": ("hil/robot0/state", encode(state)),
        "torque": ("hil/robot0/torque", encode(torque)),
        "can_set_input_torque": ("can/bench", to_message(can_encode(SetInputTorque(1, 0.25)))),
        "can_heartbeat": ("can/bench", to_message(can_encode(Heartbeat(1, 0, 8)))),
    }


def _time_one(path: Path, topic: str, payload: object, n: int) -> float:
    """Seconds a message for ``n`` messages through one recorder (its thread stopped: the
    calls are made here, one after another, as the thread makes them)."""
    writer = RecordingWriter(path)
    recorder = Recorder(writer)
    recorder._stop.set()
    recorder._thread.join()
    t0 = time.perf_counter()
    for i in range(n):
        recorder._write_one(topic, i, payload)
    elapsed = time.perf_counter() - t0
    writer.close()
    return elapsed / n


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--messages", type=int, default=20_000, help="messages a repeat")
    ap.add_argument("--repeats", type=int, default=5, help="repeats (the median is printed)")
    a = ap.parse_args(argv)
    result: dict[str, float] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for name, (topic, payload) in _cases().items():
            runs = [
                _time_one(Path(tmp) / f"{name}{r}.mcap", topic, payload, a.messages)
                for r in range(a.repeats)
            ]
            result[name] = round(statistics.median(runs) * 1e6, 2)
            print(f"{name:22} {result[name]:7.2f} us/message")
    print(json.dumps({"us_per_message": result}, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
