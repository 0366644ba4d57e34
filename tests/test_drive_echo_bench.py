"""Known answers for bench/bench_drive_echo.py's two figures, and its raw peer's independence.

The benchmark quotes the virtual drives beside a raw python-can peer (bench/raw_can_peer.py).
Here the peer itself is the device under measurement, with known injections: it answers one id
at once and another 2 ms later, and sends a cyclic frame every 10 ms with every 5th frame 3 ms
late. The benchmark's own measuring functions, on a real zenoh_can bus, must find those amounts
(request to reply: the measurer's CLOCK_MONOTONIC around send and receive; period jitter: the
bus's receive stamps, |t[i+1] - t[i] - T|). The timing bounds are causal or the injection's:
each is written beside its assertion.
"""

from __future__ import annotations

import ast
import json
import statistics
import subprocess
import sys
from pathlib import Path

import pytest

from bench import bench_drive_echo as bench
from bench import raw_can_peer
from tests.procs import free_tcp_port, spawned

ROOT = Path(__file__).resolve().parents[1]
PROMPT, DELAYED, CYCLIC = 0x230, 0x231, 0x232  # node 17's ids, of no drive
DELAY_MS, PERIOD_MS, LATE_EVERY, LATE_MS = 2.0, 10.0, 5, 3.0


def test_the_raw_peer_imports_python_can_and_the_standard_library_only():
    tree = ast.parse((ROOT / "bench" / "raw_can_peer.py").read_text())
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names |= {a.name.split(".")[0] for a in node.names}
        elif isinstance(node, ast.ImportFrom):
            names.add((node.module or "").split(".")[0])
    assert names - sys.stdlib_module_names == {"can"}, names


def test_period_jitter_is_each_periods_distance_from_the_configured_one():
    t = [0.5 + 0.01 * i for i in range(100)]
    t[40] += 0.003  # one frame 3 ms late: its period 13 ms, the next one 7 ms
    jitter = bench.period_jitter_us(t, 0.01)
    assert len(jitter) == 99
    assert [round(j) for j in jitter[39:41]] == [3000, 3000]
    assert max(jitter[:39] + jitter[41:]) < 1e-3  # float rounding of the stamps only
    s = bench.summarize(jitter)
    assert s["count"] == 99 and s["max_us"] == pytest.approx(3000)
    assert s["p50_us"] < 1e-3 and s["p99_us"] == pytest.approx(3000)  # 2 of 99 > 1 %
    assert bench.summarize([]) == {"count": 0}


# The measurer, in a process of its own at the benchmark's SCHED_FIFO (this test's process
# stays as it is): the benchmark's functions, their raw results as JSON on stdout.
MEASURER = """
import json, sys
from bench import bench_drive_echo as bench, raw_can_peer
endpoint, prompt, delayed, cyclic = sys.argv[1], *map(int, sys.argv[2:5])
bus = bench.open_measurer_bus(bench.BusConfig("zenoh_can", "ka0", endpoint))
try:
    print(raw_can_peer.READY, flush=True)
    sys.stdin.readline()  # the peer is up
    raw_can_peer.apply_scheduling("fifo")
    bench.wait_for(bus, {cyclic}, [], timeout=60.0)
    rtt = bench.round_trips(bus, [prompt, delayed], 150)
    stamps = bench.collect_stamps(bus, {cyclic}, 2.0)[cyclic]
    print(json.dumps({"rtt": {str(k): v for k, v in rtt.items()}, "stamps": stamps}), flush=True)
finally:
    bus.shutdown()
"""


@pytest.fixture(scope="module")
def measured() -> dict:
    """The raw peer with its injections, measured by the benchmark's functions."""
    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
    cfg = bench.BusConfig("zenoh_can", "ka0", endpoint)
    ids = [str(i) for i in (PROMPT, DELAYED, CYCLIC)]
    with spawned() as spawn:
        # the measurer first: it owns the endpoint, as in the benchmark
        measurer = spawn.python(["-c", MEASURER, endpoint, *ids], text=True, cwd=ROOT,
                                stdin=subprocess.PIPE, stderr=None)  # fmt: skip
        assert measurer.stdout.readline().strip() == raw_can_peer.READY
        argv = bench.peer_argv(
            cfg,
            [str(PROMPT), f"{DELAYED}:{DELAY_MS}"],
            [f"{CYCLIC}:{PERIOD_MS}"],
            *("--late-every", str(LATE_EVERY), "--late-ms", str(LATE_MS)),
            *("--scheduling", "fifo"),  # its sleeps end on time (the injections' basis)
        )
        peer = spawn.start(argv, text=True, stderr=None)
        assert peer.stdout.readline().strip() == raw_can_peer.READY
        out, _ = measurer.communicate("go\n", timeout=120)
    assert measurer.returncode == 0
    return json.loads(out.splitlines()[-1])


def test_a_peer_that_answers_2ms_later_reads_2ms_later(measured: dict):
    got = {int(k): v for k, v in measured["rtt"].items()}
    prompt, delayed = got[PROMPT]["rtt_us"], got[DELAYED]["rtt_us"]
    assert got[PROMPT]["lost"] == got[DELAYED]["lost"] == 0
    assert len(prompt) == len(delayed) == 150
    # Causal: the peer sleeps at least 2 ms between the request's arrival and its answer, and
    # both happen inside the measurer's two stamps.
    assert min(delayed) >= DELAY_MS * 1000
    # The difference of the medians is the injected 2 ms and the peer's oversleep (SCHED_FIFO:
    # tens of us): within 0.5 ms of it on both sides.
    extra = statistics.median(delayed) - statistics.median(prompt)
    assert abs(extra - DELAY_MS * 1000) <= 500, (extra, statistics.median(prompt))


def test_a_frame_sent_3ms_late_every_5th_period_reads_as_that_jitter(measured: dict):
    jitter = bench.period_jitter_us(measured["stamps"], PERIOD_MS / 1000)
    assert 150 <= len(jitter) <= 210  # 2 s of a 10 ms period
    # Each late frame makes two periods 3 ms off (13 ms, then 7 ms back on the grid): 2 of
    # every 5 samples. A split at 1.5 ms, half the injection, tells them from the others.
    hit = [j for j in jitter if j > LATE_MS * 500]
    assert abs(len(hit) - 2 * len(jitter) / LATE_EVERY) <= 4, (len(hit), len(jitter))
    assert abs(statistics.median(hit) - LATE_MS * 1000) <= 500
    s = bench.summarize(jitter)
    assert s["p50_us"] < LATE_MS * 500  # 3 samples of 5 on time: the median is one of them
    assert abs(s["p99_us"] - LATE_MS * 1000) <= 500
