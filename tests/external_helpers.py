"""Runs of an outside device: ``hil run --controller external`` and a device process beside it,
both stopped by their PIDs."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from hil.folder import layout
from tests.procs import Lines, Spawner, free_tcp_port, stop_pid, wait_until

DEVICES = Path(__file__).parent / "devices"
EXAMPLES = Path(__file__).parent.parent / "examples"


def run_external(
    spawn: Spawner,
    out: Path,
    device: list[str],
    duration: float = 2.0,
    run_args: tuple[str, ...] = (),
    timeout: float = 240.0,
) -> tuple[int, str, str]:
    """``hil run --controller external`` into ``out``; once it waits for its device, ``device``
    (argv after the interpreter; ``{endpoint}`` and ``{can_endpoint}``, the run's Zenoh and
    zenoh_can endpoints, replaced) starts. The run's exit code, its stdout and stderr (the
    device is stopped by PID after the run)."""
    endpoints = {
        "{endpoint}": f"tcp/127.0.0.1:{free_tcp_port()}",
        "{can_endpoint}": f"tcp/127.0.0.1:{free_tcp_port()}",
    }
    argv = ["-m", "hil", "run", "--controller", "external", "--duration", str(duration)]
    argv += ["--out", str(out), "--zenoh-endpoint", endpoints["{endpoint}"]]
    argv += ["--can-endpoint", endpoints["{can_endpoint}"], "--quiet", *run_args]
    run = spawn.python(argv, text=True)
    err = Lines(run.stderr)
    out_lines = Lines(run.stdout)
    assert wait_until(lambda: err.seen("waiting up to") or run.poll() is not None, 120), err.text()
    dev = spawn.python([endpoints.get(a, a) for a in device], text=True)
    try:
        code = run.wait(timeout=timeout)
    finally:
        stop_pid(dev)
    return code, out_lines.text(5.0), err.text(5.0)


#: What shows a CAN device armed both drives (node 0 and 1) or sent a first input
#: (hil.bench.device.CanArrival): which comes first is a race of the device's own frames (a
#: client may send node 0 a torque before it arms node 1).
CAN_ARRIVALS = (
    "closed-loop control asked of nodes [0, 1]",
    "a SET_INPUT_TORQUE frame to node 0",
    "a SET_INPUT_TORQUE frame to node 1",
)


def can_device_arrived(err: str) -> bool:
    """The run's stderr says a CAN device connected, by one of its signs."""
    return "device connected after" in err and any(h in err for h in CAN_ARRIVALS)


#: A verdict's exit code (hil.verdict.EXIT_CODE), spelled here so the tests check the product.
EXIT_OF = {"PASS": 0, "FAIL": 1, "INCONCLUSIVE": 4}
#: What a working device may still be failed for on a loaded host: its own stalls (a Python
#: device starved of the CPU is the device's stall, judged as any device's: in its command
#: gaps on CAN, as samples without a command on Zenoh, where its commands name their States),
#: and the certificate where they pushed the command age past D* (the run's worst stall then
#: the device's silence, ``controller_late``: the bench does not see an outside device's ticks).
DEVICE_TIMING = ("the device stalled", "samples without a command")
DEVICE_CERTIFICATE = ("certificate not held", "by the system's own timing", "controller_late")


def _device_timing(reason: str) -> bool:
    head, why, cause = DEVICE_CERTIFICATE
    return reason.startswith(head) and why in reason and reason.endswith(cause)


def judged(out: Path, code: int, may_fail_for: tuple[str, ...] = DEVICE_TIMING) -> dict:
    """The run's verdict (summary.json): ``hil run`` exited with its code, and a FAIL is only
    for the reasons ``may_fail_for`` begins (never a limit, never the bench's fault)."""
    verdict = json.loads((out / layout.SUMMARY).read_text())["verdict"]
    assert code == EXIT_OF[verdict["outcome"]], (code, verdict)
    for reason in verdict["fail_reasons"]:
        timing = may_fail_for == DEVICE_TIMING and _device_timing(reason)
        assert timing or reason.startswith(may_fail_for), verdict["fail_reasons"]
    return verdict


def report_again(out: Path) -> int:
    """``hil report OUT --force`` on the run's folder: its exit code (the saved verdict's)."""
    rep = subprocess.run(
        [sys.executable, "-m", "hil", "report", str(out), "--force"],
        capture_output=True,
        text=True,
        timeout=300,
    )
    return rep.returncode


def device_json(out: Path) -> dict:
    return json.loads((out / layout.DEVICE).read_text())


def zenoh_device(*args: str) -> list[str]:
    return [str(DEVICES / "zenoh_device.py"), "{endpoint}", *args]


def example_controller() -> list[str]:
    return [str(EXAMPLES / "zenoh_controller.py"), "{endpoint}"]


def odrive_can_device(*args: str) -> list[str]:
    """The odrive-can client device on the run's zenoh_can bus (nodes 0 and 1)."""
    return [str(DEVICES / "odrive_can_device.py"), "--endpoint", "{can_endpoint}", *args]


def foreign_can_frames(*args: str) -> list[str]:
    """A device on the run's zenoh_can bus that never arms a drive (tests/devices)."""
    return [str(DEVICES / "foreign_can_frames.py"), "--endpoint", "{can_endpoint}", *args]
