"""hil.bench.supervisor: children die with their parent (PR_SET_PDEATHSIG) and stop by PID."""

from __future__ import annotations

import signal
import textwrap

from tests.procs import wait_until
from tests.run_helpers import alive

PARENT = textwrap.dedent(
    """
    import sys, time
    from hil.bench.supervisor import Supervisor
    sup = Supervisor()
    c = sup.start("sleeper", [sys.executable, "-c", "import time; time.sleep(600)"])
    print(c.pid, flush=True)
    time.sleep(600)
    """
)


def test_child_dies_when_parent_is_sigkilled(spawn):
    parent = spawn.python(["-c", PARENT], text=True)
    child_pid = int(parent.stdout.readline())
    assert alive(child_pid)
    parent.send_signal(signal.SIGKILL)
    parent.wait(timeout=10)
    assert wait_until(lambda: not alive(child_pid), 10)


def test_stop_escalates_and_reports_exit_code(tmp_path):
    import sys

    from hil.bench.supervisor import Supervisor

    sup = Supervisor()
    # A child that ignores SIGINT must still be stopped (SIGTERM follows after the grace).
    c = sup.start(
        "stubborn",
        [
            sys.executable,
            "-c",
            "import signal, time; signal.signal(signal.SIGINT, signal.SIG_IGN);"
            " print('up', flush=True); time.sleep(600)",
        ],
        stdout=(tmp_path / "out").open("w"),
    )
    assert wait_until(lambda: (tmp_path / "out").read_text().startswith("up"), 20)
    codes = sup.stop_all(grace=0.5)
    assert codes["stubborn"] == -signal.SIGTERM
    assert not c.alive()


def test_stop_on_signals_sets_a_flag_instead_of_raising():
    import os

    from runtime.signals import stop_on_signals

    with stop_on_signals() as stop:
        assert not stop
        os.kill(os.getpid(), signal.SIGTERM)
        assert wait_until(lambda: bool(stop), 5)
        assert stop.signal == signal.SIGTERM
