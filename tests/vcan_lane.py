"""The vcan lane: every ``vcan``-marked test run on a real SocketCAN vcan0 in the QEMU guest.

``run_lane`` collects the vcan tests on the host (what the guest must pass) and runs them in the
guest. Its ~12 minutes are mostly the guest's CPU (Python ~25x slower under TCG), so a session
that collects ``test_lane_runs_every_vcan_test_in_guest`` starts the lane in a thread as soon as
collection ends (``start_beside``), its qemu at the lowest priority (nice 19): it takes the CPU
time the rest of the session leaves idle (one core of two while a pure test runs) and never
slows a host test by more than a nice-19 process does. The lane test, run last, waits for it. A
guest test that failed there, where the session may have starved the guest of CPU for seconds
(a guest's run then stalls: the kill matrix loads both cores on purpose), runs again in the
foreground, with the machine's CPUs as a lane alone always had them; that run is its result.
A test passed beside the session passed with less CPU than the foreground gives.
``HIL_VCAN_LANE_BESIDE=0`` runs the whole lane in the foreground, as it ran before; the
session's end stops a lane still running, by qemu's PID.
"""

from __future__ import annotations

import contextlib
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
from dataclasses import dataclass, field
from pathlib import Path

from tools.vcan_guest import runner
from tools.vcan_guest.image import prepare
from tools.vcan_guest.native import native_vcan_status

ROOT = Path(__file__).resolve().parent.parent
LANE_TEST = "test_lane_runs_every_vcan_test_in_guest"
#: test_can_two_process's vcan case, the C device and the pair over vcan0 at least.
LANE_MIN_TESTS = 3
# Boot ~8-20 s and ~25x slower Python under TCG on a shared 2-core machine: be generous.
LANE_TIMEOUT_S = 1200.0
#: Beside a whole session the guest gets what the session leaves idle: none of it while the
#: session loads both cores (the kill matrix under full CPU load, minutes of it).
BESIDE_TIMEOUT_S = 3600.0
BESIDE_NICE = 19
VCAN_MARK = re.compile(r"\bpytest\.mark\.vcan\b")
ANSI = re.compile(r"\x1b\[[0-9;?]*[A-Za-z]")


def lane_skip_reason() -> str | None:
    if os.environ.get("HIL_IN_VCAN_GUEST") == "1":
        return "already inside the vcan guest"
    usable, _ = native_vcan_status()
    if usable:
        return "vcan0 is native here: the vcan tests run directly in this session"
    if os.environ.get("HIL_SKIP_VCAN_LANE") == "1":
        return "HIL_SKIP_VCAN_LANE=1: the vcan guest lane was explicitly skipped"
    return None


def vcan_test_files(tests_dir: Path) -> list[str]:
    """Test files that mark anything ``vcan``: the guest collects only these, since importing
    every test module costs minutes under TCG."""
    return sorted(
        str(p.relative_to(tests_dir.parent))
        for p in tests_dir.glob("test_*.py")
        if VCAN_MARK.search(p.read_text(encoding="utf-8"))
    )


def parse_pytest_outcome(text: str) -> tuple[dict[str, int], set[str]]:
    """(counts from pytest's closing line, ids listed PASSED by ``-rA``)."""
    clean = ANSI.sub("", text)
    counts: dict[str, int] = {}
    closing = [ln for ln in clean.splitlines() if re.match(r"^=+ .* in [0-9.]+s", ln)]
    if closing:
        for n, word in re.findall(r"(\d+) (\w+)", closing[-1]):
            counts[{"error": "errors", "warning": "warnings"}.get(word, word)] = int(n)
    passed = set(re.findall(r"^PASSED (\S+)", clean, re.MULTILINE))
    return counts, passed


def collect_vcan_ids(files: list[str]) -> set[str]:
    argv = [sys.executable, "-m", "pytest", "--collect-only", "-q", "-m", "vcan"]
    res = subprocess.run(
        [*argv, "-p", "no:cacheprovider", *files],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert res.returncode == 0, f"host collection of vcan tests failed:\n{res.stdout}{res.stderr}"
    return {ln.strip() for ln in res.stdout.splitlines() if "::" in ln}


@dataclass
class Lane:
    """One run of the lane: what the host collected and what the guest said."""

    log: Path
    expected: set[str] = field(default_factory=set)
    result: runner.GuestResult | None = None
    #: raised by the run (GuestUnavailableError, GuestError, AssertionError), kept for the test
    error: BaseException | None = None
    qemu_pid: int | None = None
    stop: threading.Event = field(default_factory=threading.Event)

    def started(self, pid: int) -> None:
        self.qemu_pid = pid
        if self.stop.is_set():  # stopped while it booted: never leave it behind
            kill_group(pid)


def kill_group(pid: int) -> None:
    with contextlib.suppress(ProcessLookupError):
        os.killpg(pid, signal.SIGKILL)


def run_lane(lane: Lane, timeout: float, nice: int = 0, ids: list[str] | None = None) -> Lane:
    """Collect the vcan tests on the host and run them in the guest (only ``ids``, when given:
    tests to run again); errors land in ``lane``."""
    try:
        image = prepare()
        if lane.stop.is_set():
            raise runner.GuestError("the session ended before the lane started", lane.log, "")
        files = vcan_test_files(ROOT / "tests")
        lane.expected = set(ids) if ids is not None else collect_vcan_ids(files)
        argv = ["python", "-m", "pytest", "-m", "vcan", "-p", "no:cacheprovider", "-rA"]
        argv += ["--color=no", "--durations=5", *(sorted(ids) if ids is not None else files)]
        lane.result = runner.run_in_guest(
            argv,
            cwd=str(ROOT),
            timeout=timeout,
            log_path=lane.log,
            image=image,
            on_start=lane.started,
            nice=nice,
        )
    except Exception as exc:  # the lane test reports it, by its kind
        lane.error = exc
    return lane


@dataclass
class _Beside:
    lane: Lane
    thread: threading.Thread


_beside: _Beside | None = None


def start_beside(items: list, collect_only: bool) -> None:
    """Start the lane in a thread when this session will run the lane test (see the module)."""
    global _beside
    if collect_only or _beside is not None or os.environ.get("HIL_VCAN_LANE_BESIDE") == "0":
        return
    if not any(item.name == LANE_TEST for item in items) or lane_skip_reason() is not None:
        return
    log = Path(tempfile.mkdtemp(prefix="hil-vcan-lane-")) / "guest-console.log"
    lane = Lane(log=log)
    thread = threading.Thread(
        target=run_lane, args=(lane, BESIDE_TIMEOUT_S, BESIDE_NICE), daemon=True
    )
    thread.start()
    _beside = _Beside(lane, thread)


def take_beside(timeout: float) -> Lane | None:
    """The lane started beside this session, once it ended (None when none was started)."""
    if _beside is None:
        return None
    _beside.thread.join(timeout)
    if _beside.thread.is_alive():
        stop_beside()
        _beside.lane.error = TimeoutError(f"the lane beside the session outlived {timeout:.0f} s")
    return _beside.lane


def remove_beside_log(keep: bool) -> None:
    """The lane's console log removed with its folder once the session is over, unless
    ``keep`` (a failed session: its path is said)."""
    if _beside is None:
        return
    folder = _beside.lane.log.parent
    if keep:
        print(f"\nvcan lane beside the session: its guest console log is {_beside.lane.log}")
    else:
        shutil.rmtree(folder, ignore_errors=True)


def stop_beside() -> None:
    """Stop a lane still running (the session ended first: -x, Ctrl-C, a deselected wait)."""
    if _beside is None or not _beside.thread.is_alive():
        return
    _beside.lane.stop.set()
    if _beside.lane.qemu_pid is not None:
        kill_group(_beside.lane.qemu_pid)
    _beside.thread.join(30.0)
