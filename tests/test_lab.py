"""The lab (hil.bench.lab): hosts as network namespaces through a bridge, each with its own
CLOCK_MONOTONIC offset and router; impaired links; everything it made removed, also after the
command that built it was interrupted or killed, and nothing it did not make."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from hil.bench.lab.state import ROOT as LAB_ROOT
from tests.lab_helpers import ROOT, hil, lab, lab_argv, lab_name, lab_skip_reason
from tests.procs import wait_until

pytestmark = pytest.mark.skipif(lab_skip_reason() is not None, reason=lab_skip_reason() or "")

PUBSUB = r"""
import sys, time, zenoh
from protocol.zenoh_config import ZenohSettings, session_config
s = zenoh.open(session_config(ZenohSettings(mode="client", connect=("tcp/127.0.0.1:7447",))))
got = []
if sys.argv[1] == "sub":
    import threading
    sub = s.declare_subscriber("lab/test", lambda smp: got.append(1))
    print("subscribed", flush=True)
    # A line on stdin (or its end): the publisher has exited, every put is on its way through
    # the routers. The wait for the last ones is bounded from then, not from this start: the
    # publisher's start and its match across the lossy link take as long as the host makes them.
    done = threading.Event()
    threading.Thread(target=lambda: (sys.stdin.readline(), done.set()), daemon=True).start()
    while len(got) < int(sys.argv[2]) and not done.wait(0.02):
        pass
    deadline = time.monotonic() + 20
    while len(got) < int(sys.argv[2]) and time.monotonic() < deadline:
        time.sleep(0.02)
    print("received", len(got), flush=True)
else:
    pub = s.declare_publisher("lab/test")
    # The subscriber on the other host reaches this router through the lab's (lossy) link:
    # put only once Zenoh says the publisher has a match (bounded wait on that condition).
    deadline = time.monotonic() + 30
    while not pub.matching_status.matching and time.monotonic() < deadline:
        time.sleep(0.02)
    for i in range(int(sys.argv[2])):
        pub.put(b"x")
        time.sleep(0.005)
s.close()
"""


def _netns() -> set[str]:
    return set(
        subprocess.run(["ip", "netns", "list"], capture_output=True, text=True).stdout.split()
    )


def _lab_mounts(name: str) -> list[str]:
    folder = str(LAB_ROOT / name)
    return [ln for ln in Path("/proc/self/mountinfo").read_text().splitlines() if folder in ln]


def _alive(pid: int) -> bool:
    return Path(f"/proc/{pid}").exists() and "Z" not in Path(f"/proc/{pid}/stat").read_text()


def _pubsub(name: str, sub_host: str, pub_host: str, n: int) -> int:
    """Puts from ``pub_host`` that a subscriber on ``sub_host`` received (each through its
    own host's router)."""
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    sub = subprocess.Popen(
        lab_argv(name, sub_host, sys.executable, "-c", PUBSUB, "sub", str(n)),
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
        env=env,
    )
    try:
        assert sub.stdout.readline().strip() == "subscribed"
        pub = subprocess.run(
            lab_argv(name, pub_host, sys.executable, "-c", PUBSUB, "pub", str(n)),
            env=env,
            timeout=60,
        )
        assert pub.returncode == 0
        out, _ = sub.communicate("published\n", timeout=30)  # the subscriber's last wait
    finally:
        if sub.poll() is None:
            sub.kill()
            sub.wait()
    return int(out.split()[-1])


def _monotonic_on(name: str, host: str) -> tuple[int, int, int]:
    """(this host's clock before, the lab host's clock, this host's clock after)."""
    code = "import time; print(time.monotonic_ns())"
    before = time.monotonic_ns()
    out = subprocess.run(
        lab_argv(name, host, sys.executable, "-c", code), capture_output=True, text=True
    )
    after = time.monotonic_ns()
    return before, int(out.stdout), after


def test_lab_hosts_have_their_clocks_and_routers_and_leave_nothing():
    name = lab_name("a")
    before_netns = _netns()
    with lab(name, "--hosts", "2", "--offset", "h1=3.2", "--offset", "h2=-1.7"):
        state = json.loads((LAB_ROOT / name / "state.json").read_text())
        routers = [m["pid"] for m in state["made"] if m["kind"] == "proc"]
        assert len(routers) == 2 and all(_alive(p) for p in routers)
        assert {f"hillab-{name}-h1", f"hillab-{name}-h2", f"hillab-{name}-sw"} <= _netns()
        for host, offset_ns in (("h1", 3_200_000_000), ("h2", -1_700_000_000)):
            before, theirs, after = _monotonic_on(name, host)
            # Their clock was read between our two readings: exact bounds, no tolerance.
            assert before <= theirs - offset_ns <= after
        # Nothing of the lab is in this namespace: its addresses live only inside it.
        assert (
            "10.231.0."
            not in subprocess.run(["ip", "-o", "addr"], capture_output=True, text=True).stdout
        )
        assert _pubsub(name, "h1", "h2", 40) == 40
    assert _netns() == before_netns
    assert not _lab_mounts(name)
    assert not (LAB_ROOT / name).exists()
    assert not any(_alive(p) for p in routers)


def test_lab_link_loss_is_dropped_and_counted_by_the_kernel():
    name = lab_name("b")
    with lab(name, "--hosts", "2", "--loss", "h2=0.3", "--rate-bps", "h2=2000000"):
        # TCP resends what the kernel drops: every put still arrives, the drops are counted.
        assert _pubsub(name, "h2", "h1", 40) == 40
        status = json.loads(hil("lab", "status", "--name", name).stdout)[0]
        h2 = next(h for h in status["hosts"] if h["name"] == "h2")
        assert h2["counters"]["dropped"] > 0
        assert h2["counters"]["received"] > h2["counters"]["dropped"]
        qdisc = subprocess.run(
            ["tc", "-n", f"hillab-{name}-h2", "qdisc", "show", "dev", "eth0"],
            capture_output=True,
            text=True,
        ).stdout
        assert "tbf" in qdisc and "rate 2Mbit" in qdisc


def _start_up(spawn, name: str, hosts: int):
    return spawn.python(["-m", "hil", "lab", "up", "--name", name, "--hosts", str(hosts)], cwd=ROOT)


def _routers_recorded(name: str) -> list[int]:
    try:
        state = json.loads((LAB_ROOT / name / "state.json").read_text())
    except (OSError, ValueError):
        return []
    return [m["pid"] for m in state["made"] if m["kind"] == "proc" and m["pid"] > 0]


def test_a_lab_left_by_a_killed_up_is_removed_by_down(spawn):
    name = lab_name("c")
    before_netns = _netns()
    proc = _start_up(spawn, name, 4)
    try:
        # Killed while building: at least one router started, the lab not finished.
        assert wait_until(lambda: len(_routers_recorded(name)) >= 1, 60)
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
        routers = _routers_recorded(name)
        status = json.loads(hil("lab", "status", "--name", name).stdout)
        assert status[0]["phase"] in ("leftover", "up")  # up only if it finished in between
        assert any(_alive(p) for p in routers)
    finally:
        down = hil("lab", "down", "--name", name)
    assert down.returncode == 0, down.stderr
    assert _netns() == before_netns
    assert not _lab_mounts(name)
    assert not any(_alive(p) for p in routers)


def test_ctrl_c_during_up_removes_what_was_made(spawn):
    name = lab_name("d")
    before_netns = _netns()
    proc = _start_up(spawn, name, 4)
    assert wait_until(lambda: len(_routers_recorded(name)) >= 1, 60)
    routers = _routers_recorded(name)
    os.kill(proc.pid, signal.SIGINT)
    assert proc.wait(timeout=60) in (0, 130)  # 0 only if it had finished first
    if proc.returncode == 0:
        hil("lab", "down", "--name", name)
        pytest.skip("the lab was built before the interrupt arrived")
    assert _netns() == before_netns
    assert not _lab_mounts(name)
    assert not (LAB_ROOT / name).exists()
    assert not any(_alive(p) for p in routers)


def test_the_lab_never_touches_what_it_did_not_make(spawn):
    name = lab_name("e")
    foreign = f"hillab-{name}-h2"
    subprocess.run(["ip", "netns", "add", foreign], check=True)
    try:
        # A namespace of the lab's name that it did not make: up refuses and leaves it.
        refused = hil("lab", "up", "--name", name, "--hosts", "2")
        assert refused.returncode == 2
        assert "not this lab's" in refused.stderr
        assert foreign in _netns()
        assert (
            not (LAB_ROOT / name).exists()
            or json.loads((LAB_ROOT / name / "state.json").read_text())["made"] == []
        )
    finally:
        subprocess.run(["ip", "netns", "del", foreign], check=True)
        hil("lab", "down", "--name", name)
    with lab(name, "--hosts", "1"):
        # A recorded PID now held by a process the lab did not start (same PID and start
        # time faked in the state, but no lab mark in its environment): down leaves it.
        other = spawn.start(["sleep", "60"])
        path = LAB_ROOT / name / "state.json"
        state = json.loads(path.read_text())
        start = int(Path(f"/proc/{other.pid}/stat").read_text().rsplit(")", 1)[1].split()[19])
        state["made"].insert(0, {"kind": "proc", "name": "x", "pid": other.pid, "start": start})
        path.write_text(json.dumps(state))
    assert other.poll() is None


def test_lab_needs_root_and_says_so():
    if subprocess.run(["setpriv", "--help"], capture_output=True).returncode != 0:
        pytest.skip("setpriv (util-linux) is not installed")
    nobody = ["setpriv", "--reuid=65534", "--regid=65534", "--clear-groups"]
    done = subprocess.run(
        [*nobody, sys.executable, "-m", "hil", "lab", "up", "--name", lab_name("f")],
        capture_output=True,
        text=True,
        cwd=ROOT,
    )
    assert done.returncode == 2, done.stderr
    assert "needs root" in done.stderr
