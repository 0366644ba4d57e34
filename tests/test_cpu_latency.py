"""The services' CPU latency request ([realtime] idle, runtime.realtime.hold_cpu_latency).

An idle CPU of this kind of machine sleeps in a state that takes tens of microseconds to leave;
with ``idle = "poll"`` each service holds the kernel's PM QoS request at 0 us while it lives
(as cyclictest does), and the kernel drops it when the process ends. The kernel's current
target is what ``/dev/cpu_dma_latency`` reads back, so the test reads the effect itself.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from protocol.errors import BadInputError
from protocol.settings import RunSettings
from runtime.realtime import PM_QOS_CPU_LATENCY

ROOT = Path(__file__).resolve().parent.parent

HOLDER = """
import sys
from runtime.realtime import setup_scheduling
r = setup_scheduling("other", lock_memory=False, freeze_gc=False, idle=sys.argv[1])
print(r.idle, r.errors.get("idle", ""), flush=True)
sys.stdin.read()
"""


def _current_us() -> int:
    with open(PM_QOS_CPU_LATENCY, "rb") as f:
        return int.from_bytes(f.read(4), sys.byteorder, signed=True)


def _usable() -> bool:
    return os.access(PM_QOS_CPU_LATENCY, os.R_OK | os.W_OK)


@pytest.mark.skipif(not _usable(), reason="needs /dev/cpu_dma_latency, readable and writable")
def test_poll_holds_the_request_while_the_process_lives_and_os_leaves_it():
    if _current_us() == 0:
        pytest.skip("another process already holds the CPU latency at 0 us")
    before = _current_us()
    for idle, expect_while in (("os", before), ("poll", 0)):
        proc = subprocess.Popen(
            [sys.executable, "-c", HOLDER, idle],
            cwd=ROOT,
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
        )
        try:
            got = proc.stdout.readline().split()
            assert got == [idle], got  # what it reports is what it asked for, with no error
            assert _current_us() == expect_while
        finally:
            proc.kill()
            proc.wait()
        assert _current_us() == before  # the kernel dropped the request with the process


def test_a_refused_request_is_reported_not_raised(tmp_path):
    """Where the request cannot be made (here: the kernel refuses to write a directory, a real
    error without needing an unprivileged user) the service runs on, idle "os", and says why."""
    refusing = "import runtime.realtime as r; r.PM_QOS_CPU_LATENCY = sys.argv[2]\n"
    code = HOLDER.replace(
        "from runtime.realtime import setup_scheduling\n",
        refusing + "from runtime.realtime import setup_scheduling\n",
    )
    proc = subprocess.run(
        [sys.executable, "-c", code, "poll", str(tmp_path)],
        cwd=ROOT,
        input="",
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode == 0, proc.stderr
    idle, _, why = proc.stdout.strip().partition(" ")
    assert idle == "os"
    assert "Is a directory" in why


def test_an_unknown_idle_policy_is_a_clear_error():
    s = RunSettings(idle="deep")
    with pytest.raises(BadInputError, match=r"\[realtime\] idle must be one of \('poll', 'os'\)"):
        s.validate()


def test_every_service_process_shortens_the_gil_switch_interval():
    """A thread waking at its deadline waits up to the switch interval for the GIL: the set-up
    every service runs sets it (runtime.realtime.GIL_SWITCH_S), whatever the policy."""
    code = (
        "import sys\n"
        "from runtime.realtime import GIL_SWITCH_S, setup_scheduling\n"
        "before = sys.getswitchinterval()\n"
        "setup_scheduling('other', lock_memory=False, freeze_gc=False, idle='os')\n"
        "print(before, sys.getswitchinterval(), GIL_SWITCH_S)\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True
    ).stdout.split()
    before, after, wanted = (float(x) for x in out)
    assert before == pytest.approx(0.005)  # Python's default: what the set-up changes
    assert after == pytest.approx(wanted) and wanted <= 0.001


def test_memory_is_locked_and_collected_before_the_real_time_policy_is_taken():
    """Locking every page of a service (numpy and Zenoh loaded: tens of ms) and a full
    collection at SCHED_FIFO 80 on its pinned CPU stalled another bench run's service on that
    CPU for as long (seen: 45-50 ms, twice in a 6 s run); both now run before the policy is
    raised. The policy each step ran under is recorded by wrapping the two calls."""
    code = (
        "import gc, os, runtime.realtime as r\n"
        "seen = []\n"
        "class Libc:\n"
        "    def mlockall(self, flags):\n"
        "        seen.append(('mlockall', os.sched_getscheduler(0)))\n"
        "        return 0\n"
        "r._LIBC = Libc()\n"
        "collect = gc.collect\n"
        "gc.collect = lambda: seen.append(('collect', os.sched_getscheduler(0))) or collect()\n"
        "got = r.setup_scheduling('fifo', priority=10, idle='os')\n"
        "print(got.policy, *(f'{w}={p}' for w, p in seen))\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True
    ).stdout.split()
    if out[0] != "SCHED_FIFO":
        pytest.skip("SCHED_FIFO refused here (needs root or CAP_SYS_NICE)")
    assert out[1:] == [f"mlockall={os.SCHED_OTHER}", f"collect={os.SCHED_OTHER}"], out


def test_the_end_of_a_run_leaves_the_real_time_policy_for_every_thread():
    """restore_gc, which every service calls when its run ends, puts every thread back to
    SCHED_OTHER first: the teardown (Zenoh closed, the interpreter's exit: 20 ms and more)
    at FIFO 80 on the pinned CPU stalled another bench run's plant there by 46 ms."""
    code = (
        "import os, threading, runtime.realtime as r\n"
        "done = threading.Event()\n"
        "helper = threading.Thread(target=done.wait)\n"
        "helper.start()\n"
        "got = r.setup_scheduling('fifo', priority=10, lock_memory=False, idle='os')\n"
        "def policies():\n"
        "    tids = os.listdir('/proc/self/task')\n"
        "    return sorted({os.sched_getscheduler(int(t)) for t in tids})\n"
        "during = policies()\n"
        "r.restore_gc()\n"
        "print(got.policy, got.helper_threads, during, policies())\n"
        "done.set()\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True
    ).stdout
    if not out.startswith("SCHED_FIFO"):
        pytest.skip("SCHED_FIFO refused here (needs root or CAP_SYS_NICE)")
    assert out.split(" ", 2)[2].strip() == f"[{os.SCHED_FIFO}] [{os.SCHED_OTHER}]", out
