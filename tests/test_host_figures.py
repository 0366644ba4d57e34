"""Known answers for the host figures the stall table reads (hil.analysis.measure.host, written by
hil.bench.host_load's sampler): processes of known CPU share, measured by the real sampler.

- A duty-cycle hog (bench/duty_hog.py) busy 20 ms of CPU time in every 40 ms reads as 50 % of one
  CPU (``*_cpu_pct``) within 10 points. It runs SCHED_FIFO at priority 1, above every time-shared
  process (the two ``yes`` hogs beside it among them), so it gets its share on a loaded host; it
  never waits for a CPU then (``*_wait_s`` ~ 0).
- A process that never sleeps is, at every moment, either running or runnable and waiting: its
  CPU share plus its run-queue wait (``*_wait_s``, /proc/PID/schedstat) is the whole window,
  100 % within 10 points, however the CPU is shared (here with a ``yes`` pinned beside it).
- Two ``yes`` hogs and the spinner keep both CPUs busy: ``busy_pct`` >= 90, ``runnable_max``
  >= 3. (A hypervisor's steal cannot be injected from inside the guest: ``steal_pct`` has only
  its unit tests, tests/test_stall_table.py.)
"""

from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np
import pytest

from bench.duty_hog import duty_hog
from bench.kill_matrix import cpu_hog
from hil.analysis.measure.host import host_figures
from hil.analysis.measure.logs import RunLogs
from hil.bench.host_load import HostSampler

pytestmark = [pytest.mark.realtime]

TOLERANCE_PCT = 10.0  # points of one CPU


@pytest.fixture(scope="module")
def figures(tmp_path_factory) -> dict:
    out = tmp_path_factory.mktemp("host")
    if os.geteuid() != 0:
        pytest.skip("the duty hog runs SCHED_FIFO (root) to get its share on a loaded host")
    cpu = min(os.sched_getaffinity(0))
    with (
        cpu_hog(2),
        duty_hog(20, 40, fifo=1) as half,
        duty_hog(100, 100, cpu=cpu) as spinner,  # busy the whole period: never sleeps
        cpu_hog(1) as (beside,),
    ):
        os.sched_setaffinity(beside.pid, {cpu})  # a yes on the spinner's CPU: it must share
        sampler = HostSampler(out)
        sampler.pids = {"plant": half.pid, "controller": spinner.pid}
        t0 = time.monotonic_ns()
        time.sleep(2.5)
        t1 = time.monotonic_ns()
        sampler.close()
    logs = RunLogs.read(None, None, host=out / "host.hoplog")
    assert logs.host is not None
    # The window from 0.3 s in (the sampler learnt the PIDs) to the last sample.
    f = host_figures(logs["host"], logs.host.meta, t0 + 300_000_000, t1 - 100_000_000)
    assert f is not None
    print(f"\nhost figures beside two yes hogs: {f}")
    return f


def test_a_hog_busy_20_of_every_40_ms_reads_as_half_a_cpu(figures):
    assert figures["plant_cpu_pct"] == pytest.approx(50.0, abs=TOLERANCE_PCT), figures
    assert figures["plant_wait_s"] <= 0.05 * figures["from_s"], figures  # FIFO: never queued


def test_a_process_that_never_sleeps_runs_or_waits_the_whole_window(figures):
    share = figures["controller_cpu_pct"] + 100.0 * figures["controller_wait_s"] / figures["from_s"]
    assert share == pytest.approx(100.0, abs=TOLERANCE_PCT), figures
    # Sharing its CPU with a yes, it waited a good part of the time.
    assert figures["controller_wait_s"] >= 0.2 * figures["from_s"], figures


def test_hogs_on_every_cpu_read_as_a_busy_host(figures):
    assert figures["busy_pct"] >= 90.0, figures
    assert figures["runnable_max"] >= 3, figures
    assert figures["cpus"] == os.cpu_count()
    # The test process itself (the "recorder" here) mostly sleeps.
    assert figures["recorder_cpu_pct"] <= TOLERANCE_PCT, figures
    assert 0.0 <= figures["steal_pct"] <= 100.0


def _scripted_host(**columns: np.ndarray) -> dict[str, np.ndarray]:
    """Four host samples 100 ms apart (2 CPUs at 100 ticks/s), ``columns`` replacing theirs."""
    h = {
        "time_ns": np.array([0, 100, 200, 300], np.int64) * 1_000_000,
        "cpu_total": np.array([0, 20, 40, 60]),
        "cpu_idle": np.array([0, 10, 15, 20]),
        "cpu_steal": np.array([0, 0, 2, 4]),
        "runnable": np.array([1, 3, 5, 2]),
        "plant_cpu": np.array([0, 5, 10, 15]),
        "controller_cpu": np.array([0, 1, 2, 3]),
        "recorder_cpu": np.array([0, 0, 0, 0]),
        "plant_wait_ns": np.array([0, 0, 10_000_000, 20_000_000]),
        "controller_wait_ns": np.array([0, 1, 2, 3]) * 1_000_000,
    }
    return {**h, **columns}


def test_host_figures_over_a_stretch_use_the_samples_around_it(tmp_path: Path):
    """Every figure is a difference of the two samples bracketing the stretch: the known rows
    of a scripted host log give known figures."""
    h = _scripted_host()
    f = host_figures(h, {"clock_ticks_per_s": 100, "cpus": 2}, 150_000_000, 250_000_000)
    assert f is not None
    # Samples at 100 and 300 ms bracket [150, 250] ms: 40 ticks, 10 idle, 4 stolen.
    assert f["from_s"] == pytest.approx(0.2)
    assert f["busy_pct"] == pytest.approx(75.0) and f["steal_pct"] == pytest.approx(10.0)
    assert f["runnable_max"] == 5
    assert f["plant_cpu_pct"] == pytest.approx(50.0) and f["controller_cpu_pct"] == 10.0
    assert f["plant_wait_s"] == pytest.approx(0.02) and f["controller_wait_s"] == 0.002


def test_a_sample_whose_reads_ended_inside_the_stretch_does_not_open_it():
    """A sampler preempted between its stamp and its reads (a loaded host): the sample stamped
    at 100 ms read its counters at 160 ms, inside [150, 250] ms, after the controller's 50 ms
    run-queue wait there was counted. The stretch opens on the sample before it, whose reads
    were done by 150 ms, so the wait is found; it closes on the first sample that began reading
    at or after 250 ms. On the stamps alone the wait would read as none (the old reading)."""
    ms = 1_000_000
    h = _scripted_host(
        read_ns=np.array([1, 160, 201, 301], np.int64) * ms,
        cpu_idle=np.zeros(4, np.int64),
        cpu_steal=np.zeros(4, np.int64),
        plant_wait_ns=np.zeros(4, np.int64),
        controller_wait_ns=np.array([0, 50, 50, 50]) * ms,
    )
    meta = {"clock_ticks_per_s": 100, "cpus": 2}
    f = host_figures(h, meta, 150 * ms, 250 * ms)
    assert f is not None
    assert f["controller_wait_s"] == pytest.approx(0.050)
    assert f["from_s"] == pytest.approx(0.300)  # from the midpoint 0.5 ms to 300.5 ms
    assert f["runnable_max"] == 5
    old = host_figures({k: v for k, v in h.items() if k != "read_ns"}, meta, 150 * ms, 250 * ms)
    assert old is not None and old["controller_wait_s"] == 0.0
