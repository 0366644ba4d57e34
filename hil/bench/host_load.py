"""The bench's host while a run goes: CPU use, steal time and runnable tasks, every 0.1 s.

A stall of the emulated plant or of the controller can come from the bench's own host: other
processes, the recorder, a hypervisor that took the CPU away (steal time). ``hil run`` samples
the host (``host.hoplog``, table ``host`` of :data:`protocol.hoplog.HOST_TABLES`) so that each
stall and the verdict can show what the host was doing (hil.analysis.measure.host)."""

from __future__ import annotations

import os
import threading
import time
from pathlib import Path

from hil.folder import layout
from protocol.hoplog import HOST_TABLES, HopLogWriter, HostRow


def _cpu_line() -> tuple[int, int, int]:
    """(total, idle incl. iowait, steal) clock ticks of all CPUs since boot."""
    with open("/proc/stat") as f:
        fields = [int(x) for x in f.readline().split()[1:]]
    fields += [0] * (8 - len(fields))
    # user nice system idle iowait irq softirq steal (guest times are inside user already)
    return sum(fields[:8]), fields[3] + fields[4], fields[7]


def _process_cpu(pid: int | None, wait: bool = False) -> int:
    """utime + stime of a process (clock ticks), or with ``wait`` the ns its main thread has
    waited runnable for a CPU; -1 when it is gone or not known yet (None)."""
    try:
        with open(f"/proc/{pid}/{'schedstat' if wait else 'stat'}") as f:
            text = f.read()
        if wait:
            return int(text.split()[1])
        rest = text.rsplit(")", 1)[1].split()
        return int(rest[11]) + int(rest[12])
    except (OSError, IndexError, ValueError):
        return -1


class HostSampler:
    """A daemon thread that logs the host every :data:`hil.folder.layout.HOST_INTERVAL_S` until
    closed."""

    def __init__(self, run_dir: Path) -> None:
        meta = {"clock_ticks_per_s": os.sysconf("SC_CLK_TCK"), "cpus": os.cpu_count() or 1}
        self.log = HopLogWriter(run_dir / layout.HOST_LOG, "host", HOST_TABLES, meta)
        self.pids: dict[str, int | None] = {"plant": None, "controller": None}
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="host-sampler", daemon=True)
        self._thread.start()

    def sample(self) -> None:
        stamp = time.monotonic_ns()
        total, idle, steal = _cpu_line()
        row = HostRow(
            time_ns=stamp,
            cpu_total=total,
            cpu_idle=idle,
            cpu_steal=steal,
            runnable=int(Path("/proc/loadavg").read_text().split()[3].split("/")[0]),
            plant_cpu=_process_cpu(self.pids["plant"]),
            controller_cpu=_process_cpu(self.pids["controller"]),
            recorder_cpu=_process_cpu(os.getpid()),
            plant_wait_ns=_process_cpu(self.pids["plant"], wait=True),
            controller_wait_ns=_process_cpu(self.pids["controller"], wait=True),
            read_ns=time.monotonic_ns(),
        )
        self.log.append("host", row)

    def _run(self) -> None:
        while not self._stop.wait(layout.HOST_INTERVAL_S):
            try:
                self.sample()
            except OSError:  # no /proc (not Linux): nothing to log
                return

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)
        self.log.close()
