"""Runs of an outside device: ``hil run --controller external`` and a device process beside it,
both stopped by their PIDs."""

from __future__ import annotations

import json
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
    (argv after the interpreter; ``{endpoint}`` replaced) starts. The run's exit code, its
    stdout and stderr (the device is stopped by PID after the run)."""
    port = free_tcp_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    run = spawn.python(
        [
            "-m",
            "hil",
            "run",
            "--controller",
            "external",
            "--duration",
            str(duration),
            "--out",
            str(out),
            "--zenoh-endpoint",
            endpoint,
            "--quiet",
            *run_args,
        ],
        text=True,
    )
    err = Lines(run.stderr)
    out_lines = Lines(run.stdout)
    assert wait_until(lambda: err.seen("waiting up to") or run.poll() is not None, 120), err.text()
    argv = [a.replace("{endpoint}", endpoint) for a in device]
    dev = spawn.python(argv, text=True)
    try:
        code = run.wait(timeout=timeout)
    finally:
        stop_pid(dev)
    return code, out_lines.text(5.0), err.text(5.0)


def device_json(out: Path) -> dict:
    return json.loads((out / layout.DEVICE).read_text())


def zenoh_device(*args: str) -> list[str]:
    return [str(DEVICES / "zenoh_device.py"), "{endpoint}", *args]


def example_controller() -> list[str]:
    return [str(EXAMPLES / "zenoh_controller.py"), "{endpoint}"]
