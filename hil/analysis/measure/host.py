"""What the bench's host was doing over a stretch of the run (``host.hoplog``, hil.bench.host_load).

Over [lo, hi], from the host samples bracketing it (every 0.1 s): ``busy_pct`` (all CPUs, of
their capacity), ``steal_pct`` (time a hypervisor gave to another guest), ``runnable_max``
(runnable tasks), and each bench process's CPU use in % of one CPU (``plant``, ``controller``,
``recorder``: ``hil run`` itself), and how long the plant's and the controller's main threads
waited runnable for a CPU (``*_wait_s``, /proc/PID/schedstat). None when the run has no host
log (``hil run`` older than it, or a simulation)."""

from __future__ import annotations

from typing import Any

import numpy as np

from hil.folder import layout
from hil.folder.records import HostLoad

PROCESSES = ("plant", "controller", "recorder")
INTERVAL_S = layout.HOST_INTERVAL_S  # hil run samples the host this often (hil.bench.host_load)
# The sampler, a thread of hil run, logged nothing for this long: the recorder was stopped or
# starved (a stall's evidence says so: its host figures then span the silence).
RECORDER_SILENT_NS = int(2.5 * INTERVAL_S * 1e9)


def host_figures(
    h: dict[str, np.ndarray], meta: dict[str, Any], lo: int, hi: int
) -> HostLoad | None:
    """The host over [lo, hi] from the two samples around it: the last whose counters were all
    read by ``lo`` and the first that began reading them at or after ``hi`` (a sampler preempted
    between its stamp and its reads on a loaded host would otherwise put a stall's run-queue
    wait on the wrong side of the stretch). ``from_s`` spans the two samples' midpoints."""
    t = h.get("time_ns")
    if t is None or t.size < 2:
        return None
    done = h.get("read_ns")
    if done is None or done.size != t.size:  # a log written before the second stamp
        done = t
    a = max(0, int(np.searchsorted(done, lo, side="right")) - 1)  # read by lo
    b = min(t.size - 1, int(np.searchsorted(t, hi, side="left")))  # reading from hi on
    if b <= a:
        b = min(t.size - 1, a + 1)
        a = b - 1
    d_total = int(h["cpu_total"][b] - h["cpu_total"][a])
    seconds = (int(t[b]) + int(done[b]) - int(t[a]) - int(done[a])) / 2e9
    if d_total <= 0 or seconds <= 0:
        return None
    tick = float(meta.get("clock_ticks_per_s") or 100)
    out: HostLoad = {
        "from_s": seconds,
        "busy_pct": 100.0 * (1.0 - int(h["cpu_idle"][b] - h["cpu_idle"][a]) / d_total),
        "steal_pct": 100.0 * int(h["cpu_steal"][b] - h["cpu_steal"][a]) / d_total,
        "runnable_max": int(h["runnable"][a : b + 1].max()),
        "cpus": int(meta.get("cpus") or 1),
    }
    for name in PROCESSES:
        c = h[f"{name}_cpu"]
        if c[a] >= 0 and c[b] >= 0:
            out[f"{name}_cpu_pct"] = 100.0 * int(c[b] - c[a]) / tick / seconds
    for name in ("plant", "controller"):
        w = h.get(f"{name}_wait_ns")
        if w is not None and w.size > b and w[a] >= 0 and w[b] >= 0:
            out[f"{name}_wait_s"] = int(w[b] - w[a]) / 1e9  # runnable, waiting for a CPU
    return out
