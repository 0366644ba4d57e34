"""Outside devices on a real SocketCAN vcan0 (the QEMU guest lane): ``hil run --controller
external --cmd-path can`` on socketcan/vcan0 and device programs beside it (any executable: a C
binary, can-utils), every process stopped by its PID."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import time
import tomllib
from dataclasses import dataclass
from pathlib import Path

import pytest

from hil.folder import layout
from protocol.hoplog import HopLog, read_hoplog
from tests.external_helpers import EXIT_OF
from tests.procs import Lines, Spawner, stop_pid, wait_until

ROOT = Path(__file__).resolve().parent.parent
C_CONTROLLER = ROOT / "examples" / "socketcan_controller.c"
CHANNEL = "vcan0"
#: The guest runs Python ~25x slower than its host (TCG): the plant, the drives and the
#: recorder at 50 Hz (the drives' encoder frames keep their 10 ms), as tests/test_rt_vcan.py.
GUEST_RATE_HZ = 50
#: hil run's start (its services import numpy, zenoh and python-can) took ~28 s in the guest.
START_TIMEOUT_S = 240.0


@dataclass
class DeviceRun:
    """What a run of outside devices left: the run's exit code and output, each device's exit
    code and output (a device still running when the run ended was stopped by its PID)."""

    code: int
    stdout: str
    stderr: str
    devices: list[tuple[int | None, str]]
    out: Path
    finite_end_ns: int  # CLOCK_MONOTONIC when the last finite device had exited

    def judged(self) -> dict:
        """The run's verdict, with its report written beside it (report.html, report.json)."""
        assert self.code in (0, 1, 4), self.stderr  # a verdict, never the bench's fault (3)
        for name in (*layout.REQUIRED, layout.REPORT_HTML, layout.REPORT_JSON):
            assert (self.out / name).is_file(), name
        verdict = self.summary()["verdict"]
        assert self.code == EXIT_OF[verdict["outcome"]], (self.code, verdict)
        report = json.loads((self.out / layout.REPORT_JSON).read_text())
        assert report["verdict"]["outcome"] == verdict["outcome"], report["verdict"]
        return verdict

    def summary(self) -> dict:
        return json.loads((self.out / layout.SUMMARY).read_text())

    def device_json(self) -> dict:
        return json.loads((self.out / layout.DEVICE).read_text())

    def plant(self) -> HopLog:
        return read_hoplog(self.out / layout.PLANT_LOG)

    def limits(self) -> dict[str, float]:
        """The run's [limits] (2) as it resolved them."""
        resolved = tomllib.loads((self.out / layout.SCENARIO_RESOLVED).read_text())
        return {k: float(v) for k, v in resolved["limits"].items()}


def require_vcan0() -> None:
    if not Path(f"/sys/class/net/{CHANNEL}").exists():
        pytest.fail(
            f"{CHANNEL} does not exist: these tests run where the kernel has vcan or inside the "
            "QEMU guest lane (tests/test_vcan_lane.py), or deselect them with -m 'not vcan'"
        )


def require_program(name: str, package: str) -> str:
    path = shutil.which(name)
    if path is None:
        pytest.skip(f"{name} is not installed (Debian package {package}; .ci/run installs it)")
    return path


def build_c_controller(dest: Path) -> Path:
    """examples/socketcan_controller.c built with the system's gcc, as its header says."""
    gcc = require_program("gcc", "gcc")
    binary = dest / "socketcan_controller"
    argv = [gcc, "-O2", "-static", "-Wall", "-Wextra", "-Werror", "-o", str(binary)]
    res = subprocess.run(
        [*argv, str(C_CONTROLLER)], capture_output=True, text=True, timeout=300, check=False
    )
    assert res.returncode == 0, f"gcc failed:\n{res.stdout}{res.stderr}"
    return binary


def run_devices(
    spawn: Spawner,
    out: Path,
    devices: list[list[str]],
    duration: float,
    wait_device: float = 60.0,
    finite: tuple[list[str], ...] = (),
    timeout: float = 600.0,
    finite_after_connect: bool = False,
) -> DeviceRun:
    """``hil run --controller external --cmd-path can`` on socketcan/vcan0 into ``out``, its
    report written by the run (as ``hil report`` writes it, from the folder: in the guest a
    second process to import the report's modules costs a minute, the run's own report a few
    seconds). Once it waits for its device, every argv of
    ``devices`` (run until stopped) and ``finite`` (each ends by itself and must do so while
    the run still runs, so that all it sent met the bench) starts; with
    ``finite_after_connect`` the finite ones once the run said the device connected (what they
    send then meets drives the device armed, whatever order the guest started them in)."""
    require_vcan0()
    argv = ["-m", "hil", "run", "--controller", "external", "--cmd-path", "can"]
    argv += ["--can-interface", "socketcan", "--can-channel", CHANNEL]
    argv += ["--rate", str(GUEST_RATE_HZ), "--duration", str(duration)]
    argv += ["--wait-device", str(wait_device), "--out", str(out), "--quiet"]
    t0 = time.monotonic()
    run = spawn.python(argv, text=True)
    err, std = Lines(run.stderr), Lines(run.stdout)
    started = wait_until(lambda: err.seen("waiting up to") or run.poll() is not None, 240)
    assert started and run.poll() is None, f"hil run did not wait for a device:\n{err.text()}"
    t_wait = time.monotonic()
    procs = [spawn.start(d, text=True) for d in devices]
    if finite_after_connect:
        connected = wait_until(
            lambda: err.seen("device connected after") or run.poll() is not None, 240
        )
        assert connected and run.poll() is None, f"the device did not connect:\n{err.text()}"
    procs += [spawn.start(d, text=True) for d in finite]
    outputs = [Lines(p.stdout) for p in procs]
    errors = [Lines(p.stderr) for p in procs]
    ended = procs[len(devices) :]
    assert wait_until(lambda: all(p.poll() is not None for p in ended), timeout), "devices hang"
    finite_end_ns = time.monotonic_ns()
    assert run.poll() is None, (
        "the run ended before every finite device had sent all of its frames: lengthen it\n"
        + err.text()
    )
    try:
        code = run.wait(timeout=timeout)
    finally:
        for p in procs:
            stop_pid(p)
    after = time.monotonic() - t_wait
    print(f"hil run: {t_wait - t0:.1f} s until it waited for a device, {after:.1f} s after")
    devs = [
        (p.returncode, o.text(5.0) + e.text(5.0))
        for p, o, e in zip(procs, outputs, errors, strict=True)
    ]
    return DeviceRun(code, std.text(5.0), err.text(5.0), devs, out, finite_end_ns)


def report(out: Path) -> subprocess.CompletedProcess:
    """``hil report FOLDER``: the folder of an outside device's run is read like any other."""
    t0 = time.monotonic()
    res = subprocess.run(
        [sys.executable, "-m", "hil", "report", str(out), "--force"],
        capture_output=True,
        text=True,
        timeout=600,
        check=False,
    )
    print(f"hil report: {time.monotonic() - t0:.1f} s")
    return res


def torques_within_limits(run: DeviceRun, need_samples: bool = True) -> None:
    """Every plant sample's applied tau1, tau2 within the run's varpi1, varpi2 (2), and the
    plant's own extremes agree: none counted beyond them, none non-finite."""
    lim = run.limits()
    plant = run.plant()
    samples = plant.table("samples")
    assert samples or not need_samples, "the plant logged no sample"
    worst1 = max((abs(r["tau1"]) for r in samples), default=0.0)
    worst2 = max((abs(r["tau2"]) for r in samples), default=0.0)
    assert worst1 <= lim["varpi1"] and worst2 <= lim["varpi2"], (worst1, worst2, lim)
    assert plant.final is not None, "the plant did not end cleanly (no hop-log footer)"
    ext = plant.final["extremes"]
    assert ext["violations"]["tau1"] == 0 and ext["violations"]["tau2"] == 0, ext
    assert ext["nonfinite_steps"] == 0, ext
