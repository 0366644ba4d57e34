"""Figures of a device at the bus (hil.analysis.measure.device; docs/realtime.md, "Figures of a
device at the bus"), each a two-sided known answer: what was injected is found, and nothing is
found where nothing was injected.

The fast tests write plant hop logs with :class:`protocol.hoplog.HopLogWriter` from constructed
rows (no controller log: an outside device) and measure them with the one pipeline
(:func:`hil.analysis.measure.folder.measure_folder`). The real-process tests run ``hil run``
with a hosted law that stalls once (tests/stall_law.py), the plant seeing the bench's controller
as a device like any other, and ``hil report`` on a hosted run's folder stripped of the
controller's log."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from collections.abc import Iterable
from pathlib import Path

import numpy as np
import pytest

from hil.analysis.measure.folder import device_limits, measure_folder
from hil.analysis.report.device import add_device, has_news
from hil.folder import layout
from hil.folder.device import DeviceFigures, DeviceLimits
from hil.folder.jsonio import jsonable
from hil.verdict import EXIT_CODE, FAIL, INCONCLUSIVE, PASS, judge
from protocol.hoplog import (
    NO_NODE,
    NO_SEQ,
    PLANT_TABLES,
    ApplyOutcome,
    ApplyRow,
    CmdPath,
    CmdRxRow,
    EncTxRow,
    HopLogWriter,
    RxVerdict,
    SampleRow,
    read_hoplog,
)
from tests.external_helpers import odrive_can_device, run_external, zenoh_device
from tests.scenario_text import NEAR, TABLE1, circle
from tests.synthetic_folder import _scenario_text

EPOCH = 10**12  # any origin on the plant's clock
P = 5_000_000  # 200 Hz: the nominal control period of the constructed runs
MS = 1_000_000
# The resolved scenario the measurement reads (limits of (2) with the paper's values, [robot]'s
# defaults, a 200 Hz period, the unified law).
LIMITS_TOML = _scenario_text(0.5, 0.2, "unified", P / 1e9, 0.0, 1, 3.0)


def _write_plant(
    folder: Path,
    n_samples: int,
    commands: Iterable[tuple[int, int, float, float]] = (),
    frames: Iterable[tuple[int, int, float]] = (),
    estimates: Iterable[tuple[int, int, int]] = (),
    path: str = "zenoh",
    tables: dict | None = None,
    garbage_stamp: bool = True,
) -> Path:
    """A plant.hoplog of ``n_samples`` samples every P from EPOCH (State sent 100 µs after
    each), Zenoh ``commands`` (recv_ns, state_seq named, tau1, tau2), CAN torque ``frames``
    (node, recv_ns, torque) and encoder ``estimates`` (node, sample_ns, send_ns); each command
    lands 10 µs after it arrives. ``garbage_stamp``: the commands carry a wrong sample stamp of
    their own (the figures must not read it)."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / layout.SCENARIO_RESOLVED).write_text(LIMITS_TOML)
    meta = {
        "epoch_ns": EPOCH, "control_period_ns": P, "sensor_period_ns": P,
        "plant_step_ns": P // 10, "cmd_path": path, "lockstep": False,
    }  # fmt: skip
    log = HopLogWriter(folder / layout.PLANT_LOG, "plant", tables or PLANT_TABLES, meta)
    for k in range(n_samples):
        t = EPOCH + k * P
        log.append("samples", SampleRow(k, t, t + 50_000, t + 100_000, *([0.0] * 9), 0))
    for i, (recv, named, tau1, tau2, *again) in enumerate(commands):
        stamp = 12345 if garbage_stamp else EPOCH + named * P
        log.append("cmd_rx", CmdRxRow(CmdPath.ZENOH, i, named, stamp, 0, 0, recv, tau1, tau2,
                                      NO_NODE, RxVerdict.ACCEPTED))  # fmt: skip
        for t in again:  # the same command arriving again (a duplicate on the way)
            log.append("cmd_rx", CmdRxRow(CmdPath.ZENOH, i, named, stamp, 0, 0, t, tau1, tau2,
                                          NO_NODE, RxVerdict.DUPLICATE))  # fmt: skip
        log.append("apply", ApplyRow(CmdPath.ZENOH, i, NO_NODE, recv, recv + 10_000, tau1, tau2,
                                     ApplyOutcome.LANDED))  # fmt: skip
    counts: dict[int, int] = {}
    for node, recv, q in frames:
        i = counts[node] = counts.get(node, -1) + 1
        log.append("cmd_rx", CmdRxRow(CmdPath.CAN, i, NO_SEQ, 0, 0, 0, recv, q, 0.0, node,
                                      RxVerdict.ACCEPTED))  # fmt: skip
        log.append("apply", ApplyRow(CmdPath.CAN, i, node, recv, recv + 10_000, q, 0.0,
                                     ApplyOutcome.LANDED))  # fmt: skip
    for node, sample, send in estimates:
        if "enc_tx" in (tables or PLANT_TABLES):
            log.append("enc_tx", EncTxRow(node, sample, send))
    log.close({"timeouts": 0})
    return folder


def _device(folder: Path) -> DeviceFigures:
    m = measure_folder(folder)
    assert m is not None and m.device is not None
    return m.device


def _answering(n: int, delay_ns: int = 1 * MS, stall_at: int | None = None, stall_ns: int = 0):
    """A device answering each State ``delay_ns`` after its send, naming it; from sample
    ``stall_at`` on, every answer is ``stall_ns`` later until the device has caught up (it
    answers the newest State then: those sent meanwhile are skipped)."""
    out = []
    resume = None
    for k in range(n):
        recv = EPOCH + k * P + 100_000 + delay_ns
        if stall_at is not None and k == stall_at:
            resume = recv + stall_ns
            out.append((resume, k, 0.1, 0.0))
            continue
        if resume is not None and recv <= resume:
            continue
        out.append((recv, k, 0.1, 0.0))
    return out


# --- command period, jitter, gaps -------------------------------------------------------------


def test_a_40_ms_stall_reads_as_a_40_ms_gap(tmp_path):
    n = 600  # 3 s at 200 Hz
    stalled = _device(
        _write_plant(tmp_path / "s", n, _answering(n, stall_at=200, stall_ns=40 * MS))
    )
    (z,) = stalled.streams
    assert z.gap_count == 1
    (gap,) = z.gaps
    # The command due at t = 1 s came 40 ms late: the gap is that lateness (interval - P).
    assert abs(gap.length_s - 0.040) <= 0.002
    assert abs(gap.interval_s - 0.045) <= 0.002
    assert abs(gap.start_s - (199 * P + 1.1 * MS) / 1e9) <= 1e-6  # the command before it
    assert gap.owner == "device"  # the plant was on time throughout
    # The samples taken inside it after its first period: (40 ms - 0) / 5 ms, about 8.
    assert 7 <= stalled.samples_in_gaps <= 9
    clean = _device(_write_plant(tmp_path / "c", n, _answering(n)))
    assert clean.streams[0].gap_count == 0 and clean.samples_in_gaps == 0
    assert clean.streams[0].gap_longest_s is None


def test_a_200_hz_device_with_uniform_1_ms_jitter_reads_as_5_ms_and_that_jitter(tmp_path):
    rng = np.random.default_rng(37)
    n = 4000  # 20 s
    jitter = rng.uniform(-1 * MS, 1 * MS, n).astype(np.int64)
    cmds = [(EPOCH + k * P + 2 * MS + int(jitter[k]), k, 0.1, 0.0) for k in range(n)]
    dev = _device(_write_plant(tmp_path / "j", n + 2, cmds))
    (z,) = dev.streams
    assert abs(z.period_mean_s - 0.005) <= 0.00001
    assert abs(z.period["p50_us"] - 5000.0) <= 100.0
    # Each inter-arrival is the difference of two uniform draws in [-1, 1] ms: triangular on
    # [-2, 2] ms, so |dev| reaches near 2 ms and its median is 2 (1 - 1/sqrt 2) = 0.586 ms.
    assert 1800.0 <= z.jitter["max_us"] <= 2000.0
    assert abs(z.jitter["p50_us"] - 585.8) <= 40.0
    assert z.gap_count == 0
    steady = [(EPOCH + k * P + 2 * MS, k, 0.1, 0.0) for k in range(n)]
    (s,) = _device(_write_plant(tmp_path / "s", n + 2, steady)).streams
    assert s.jitter["max_us"] == 0.0 and s.period_mean_s == pytest.approx(0.005, abs=1e-12)


def test_a_command_that_arrives_twice_is_one_command_of_the_stream(tmp_path):
    n = 400
    cmds = [(*c, c[0] + 200_000) if c[1] % 10 == 0 else c for c in _answering(n)]
    (z,) = _device(_write_plant(tmp_path / "d", n, cmds)).streams
    assert z.commands == n - 1 and z.jitter["max_us"] == 0.0  # (the last lands after the window)


def test_can_streams_are_per_node(tmp_path):
    n = 400
    frames = [(node, EPOCH + k * P + 300_000, 0.1) for k in range(n) for node in (0, 1)]
    # node 1 stalls 40 ms once: its frame due at sample 100 comes 40 ms late, those due
    # meanwhile are not sent
    frames = [
        (nd, t + (40 * MS if nd == 1 and t == EPOCH + 100 * P + 300_000 else 0), q)
        for nd, t, q in frames
        if not (nd == 1 and EPOCH + 100 * P + 300_000 < t <= EPOCH + 100 * P + 300_000 + 40 * MS)
    ]
    dev = _device(_write_plant(tmp_path / "c", n, frames=sorted(frames, key=lambda f: f[1]),
                               path="can"))  # fmt: skip
    by = {s.name: s for s in dev.streams}
    assert by["node 0"].gap_count == 0
    assert by["node 1"].gap_count == 1
    assert abs(by["node 1"].gaps[0].length_s - 0.040) <= 0.002


# --- response time and age --------------------------------------------------------------------


def test_a_device_that_waits_3_ms_reads_3_ms_slower(tmp_path):
    n = 400
    base = _device(_write_plant(tmp_path / "b", n, _answering(n, delay_ns=1 * MS)))
    slow = _device(_write_plant(tmp_path / "s", n, _answering(n, delay_ns=4 * MS)))
    # Response: the State's send (100 µs after its sample) to the command naming it.
    assert base.response["p50_us"] == pytest.approx(1000.0, abs=1.0)
    assert slow.response["p50_us"] - base.response["p50_us"] == pytest.approx(3000.0, abs=500.0)
    # Age at landing: apply (arrival + 10 µs) - the plant's own sample time of the named State
    # (the commands' own stamp, 12345 ns, is never read).
    assert base.age["p50_us"] == pytest.approx(1110.0, abs=1.0)
    assert slow.age["max_us"] == pytest.approx(4110.0, abs=1.0)
    assert base.d_max_s == pytest.approx(1.11e-3, abs=1e-6) and not base.age_is_bound
    assert base.unnamed == 0 and base.responses_unanswered == 0


def test_a_name_that_matches_no_state_is_counted_and_gives_no_age(tmp_path):
    n = 100
    cmds = _answering(n)
    cmds[50] = (cmds[50][0], 10**6, 0.1, 0.0)  # names a State never sent
    dev = _device(_write_plant(tmp_path / "u", n, cmds))
    clean = _device(_write_plant(tmp_path / "c", n, _answering(n)))
    assert dev.unnamed == 1 and clean.unnamed == 0
    assert dev.age["count"] == clean.age["count"] - 1
    assert dev.responses_unanswered == clean.responses_unanswered + 1  # State 50, never named
    # The run's command age D (the certificate's) reads the plant's own sample times too: the
    # unnamed command renews nothing, so D spans two periods there, one elsewhere.
    d_max = measure_folder(tmp_path / "u").certificate["d_max_s"]
    assert d_max == pytest.approx((2 * P + 1_110_000) / 1e9, abs=1e-9)
    assert measure_folder(tmp_path / "c").certificate["d_max_s"] == pytest.approx(
        (P + 1_110_000) / 1e9, abs=1e-9
    )


def test_can_response_from_each_encoder_frame_and_the_age_bound(tmp_path):
    n = 400
    enc_period = 10 * MS

    def folder(name: str, wait_ns: int) -> DeviceFigures:
        est, frames = [], []
        for j in range(n * P // enc_period - 1):
            sample = EPOCH + j * enc_period + 200_000
            for node in (0, 1):
                est.append((node, sample, sample + 30_000))  # on the bus 30 µs later
                frames.append((node, sample + 30_000 + 500_000 + wait_ns, 0.1))
        frames.sort(key=lambda f: f[1])
        return _device(_write_plant(tmp_path / name, n, frames=frames, estimates=est, path="can"))

    base, slow = folder("b", 0), folder("s", 3 * MS)
    assert base.response["p50_us"] == pytest.approx(530.0, abs=1.0)
    assert slow.response["p50_us"] - base.response["p50_us"] == pytest.approx(3000.0, abs=500.0)
    assert base.response["count"] > 0 and base.responses_unanswered <= 2
    # The bound: apply - the newest estimate's sample on the bus before the frame arrived.
    assert base.age_is_bound
    assert base.age["max_us"] == pytest.approx(540.0, abs=1.0)
    assert slow.age["max_us"] == pytest.approx(3540.0, abs=1.0)


def test_the_age_bound_counts_from_the_window_start(tmp_path):
    """Estimates the drives sent while the bench waited for the device (the plant not yet
    stepping) are as old as the wait: a first torque frame answering one 1 s old reads from
    the window's start, as the hosted age does (seen: 1.04 s in the C device's run)."""
    est = [(0, EPOCH - 1_000 * MS, EPOCH - 999 * MS)]  # before the window, 1 s old
    est += [(0, EPOCH + 10 * MS, EPOCH + 10 * MS + 30_000)]
    frames = [(0, EPOCH + 2 * MS, 0.1), (0, EPOCH + 11 * MS, 0.1)]
    dev = _device(_write_plant(tmp_path / "w", 50, frames=frames, estimates=est, path="can"))
    assert dev.age["count"] == 2
    # first: apply (2 ms + 10 µs) - the window's start; second: apply - its estimate's sample
    assert dev.age["max_us"] == pytest.approx(2010.0, abs=0.01)
    assert dev.age["p50_us"] == pytest.approx(1010.0, abs=0.01)


def _can_answering(n: int, stall: tuple[int, int] | None = None, silent: tuple[int, int] = (0, 0)):
    """A CAN device answering each 10 ms encoder estimate of both nodes 500 µs after it was on
    the bus, beside a plant sampling every P (5 ms): ``stall`` = (node, ns) once at 1 s (that
    node answers none of the estimates of the ns from then); ``silent`` = (from, to) ns after
    EPOCH: no estimate (the bench's drives silent), so no answer either."""
    est, frames = [], []
    for j in range(n * P // (10 * MS) - 1):
        sample = EPOCH + j * 10 * MS + 200_000
        if silent[0] <= sample - EPOCH < silent[1]:
            continue
        for node in (0, 1):
            est.append((node, sample, sample + 30_000))
            if stall and node == stall[0] and 0 <= sample - EPOCH - 1000 * MS < stall[1]:
                continue
            frames.append((node, sample + 30_000 + 500_000, 0.1))
    frames.sort(key=lambda f: f[1])
    return frames, est


def test_an_outside_device_is_judged_at_its_own_rate_not_the_plants(tmp_path):
    """A CAN device at the drives' 100 Hz beside a 200 Hz plant: P is its own median interval
    (10 ms), no gap and no sample in one (at the plant's 5 ms it was a 'stall' every other
    sample: a working device FAILed by construction); a 40 ms stall of one node reads 40 ms."""
    frames, est = _can_answering(400)
    dev = _device(_write_plant(tmp_path / "a", 400, frames=frames, estimates=est, path="can"))
    assert dev.nominal_period_from == "device median"
    assert dev.nominal_period_s == pytest.approx(0.010, abs=1e-9)
    assert dev.gap_count == 0 and dev.samples_in_gaps == 0, dev.gaps
    frames, est = _can_answering(400, stall=(0, 40 * MS))
    dev = _device(_write_plant(tmp_path / "s", 400, frames=frames, estimates=est, path="can"))
    (gap,) = dev.gaps
    assert gap.owner == "device" and gap.length_s == pytest.approx(0.040, abs=1e-9)
    assert dev.samples_in_gaps == 8  # (50 ms - P) past its due time, every 5 ms


def test_a_device_gap_where_the_drives_fell_silent_is_the_benchs(tmp_path):
    """The drives send no estimate for 100 ms: a device that answers each sends nothing either;
    its gap is the bench's (INCONCLUSIVE at most), never the device's stall."""
    frames, est = _can_answering(400, silent=(1000 * MS, 1100 * MS))
    dev = _device(_write_plant(tmp_path / "q", 400, frames=frames, estimates=est, path="can"))
    assert {g.owner for g in dev.gaps} == {"bench"} and len(dev.gaps) == 2  # both nodes
    assert dev.samples_in_gaps == 0 and dev.samples_in_bench_gaps > 0


def test_a_log_without_the_encoder_table_still_reads(tmp_path):
    old = {k: v for k, v in PLANT_TABLES.items() if k != "enc_tx"}
    frames = [(node, EPOCH + k * P + 300_000, 0.1) for k in range(100) for node in (0, 1)]
    dev = _device(_write_plant(tmp_path / "o", 100, frames=frames, path="can", tables=old))
    assert dev.response["count"] == 0 and dev.age["count"] == 0 and dev.d_max_s is None
    assert {s.name for s in dev.streams} == {"node 0", "node 1"}


# --- limits -----------------------------------------------------------------------------------


def test_torques_asked_beyond_the_limits_are_counted_with_the_worst(tmp_path):
    n = 100
    cmds = _answering(n)
    cmds[10] = (cmds[10][0], 10, 5.0, 0.0)  # |tau1| 5 > varpi1 = 3.3
    cmds[20] = (cmds[20][0], 20, -7.5, 0.0)
    cmds[30] = (cmds[30][0], 30, 3.3, -51.0)  # at the limits: legal
    cmds[40] = (cmds[40][0], 40, float("nan"), 0.0)  # never within a limit
    dev = _device(_write_plant(tmp_path / "l", n, cmds))
    (b,) = dev.beyond_limits
    assert (b.signal, b.limit, b.count, b.worst, b.non_finite) == ("tau1", 3.3, 3, -7.5, 1)
    # through summary.json (NaN is no JSON: None) and back, said in words
    back = DeviceFigures.from_dict(json.loads(json.dumps(jsonable(dev.as_dict()))))
    assert back.beyond_limits[0].worst_words() == "-7.5 (and 1 non-finite)"
    at_limits = [c if i != 10 else (c[0], 10, 3.3, 51.0) for i, c in enumerate(_answering(n))]
    ok = _device(_write_plant(tmp_path / "k", n, at_limits))
    assert ok.beyond_limits == []


def test_can_torques_beyond_the_motor_limit(tmp_path):
    # [robot]'s defaults: varpi1 = 3.3, varpi2 = 51 ask at most 0.40 N·m of one motor
    frames = [(node, EPOCH + k * P + 300_000, 0.3) for k in range(100) for node in (0, 1)]
    frames[41] = (1, frames[41][1], 2.0)
    dev = _device(_write_plant(tmp_path / "c", 100, frames=frames, path="can"))
    (b,) = dev.beyond_limits
    assert b.signal == "q node 1" and b.count == 1 and b.worst == 2.0
    assert 0.39 < b.limit < 0.41


# --- the verdict reads them -------------------------------------------------------------------


def _verdict(dev: DeviceFigures, timing: dict | None = None):
    return judge({}, {}, None, timing or {}, {}, None, device=dev)


def test_the_verdict_reads_the_device_figures(tmp_path):
    n = 600
    clean = _device(_write_plant(tmp_path / "c", n, _answering(n)))
    assert _verdict(clean).outcome == PASS
    # CAN, outside: no samples_without_command in timing, the device's gaps are judged.
    stalled = _device(_write_plant(tmp_path / "s", n, _answering(n, stall_at=200,
                                                                 stall_ns=200 * MS)))  # fmt: skip
    v = _verdict(stalled)
    assert v.outcome == FAIL and v.fail_reasons[0].startswith("the device stalled: ")
    # ... unless the hosted figure judges it already (the same thing, said once)
    assert _verdict(stalled, {"samples_without_command": 0}).outcome == PASS
    bench = DeviceFigures.from_dict(
        {**stalled.as_dict(), "samples_in_gaps": 0,
         "samples_in_bench_gaps": stalled.samples_in_gaps}
    )  # fmt: skip
    assert _verdict(bench).outcome == INCONCLUSIVE
    asked = [(c[0], c[1], 9.0 if i == 5 else c[2], 0.0) for i, c in enumerate(_answering(n))]
    beyond = _device(_write_plant(tmp_path / "b", n, asked))
    v = _verdict(beyond)
    assert v.outcome == FAIL and "beyond the limits of (2): |tau1| up to 9" in v.fail_reasons[0]


def test_the_record_round_trips_through_json(tmp_path):
    dev = _device(
        _write_plant(tmp_path / "r", 300, _answering(300, stall_at=100, stall_ns=40 * MS))
    )
    back = DeviceFigures.from_dict(json.loads(json.dumps(dev.as_dict())))
    assert back == dev


def test_device_limits_of_a_scenario():
    """The limits a device is judged against: varpi1, varpi2 as given; on CAN the largest motor
    torque they ask of one wheel of [robot] (the defaults: about 0.40 N·m), plus the float32
    hair the drives allow; none without [limits]."""
    lim = device_limits({"varpi1": 3.3, "varpi2": 51.0}, {})
    assert lim == DeviceLimits(3.3, 51.0, pytest.approx(0.4012e0, rel=2e-3))
    heavier = device_limits({"varpi1": 3.3, "varpi2": 51.0}, {"mass": 20.0})
    assert heavier.motor_nm > lim.motor_nm
    assert device_limits({}, {}) is None


# --- real processes ---------------------------------------------------------------------------

# The unified law of Table 1 whose update at t = 1 s spins 40 ms once (tests/stall_law.py).
STALL_LAW = circle(
    NEAR, controller={**TABLE1, "law": "tests.stall_law:SpinOnceUnified", "spin_ms": 40.0,
                      "spin_at_s": 1.0},
)  # fmt: skip


def _hil_run(tmp_path: Path, name: str, *args: str) -> tuple[Path, dict]:
    scen = tmp_path / "stall.toml"
    scen.write_text(STALL_LAW)
    out = tmp_path / name
    p = subprocess.run(
        [sys.executable, "-m", "hil", "run", str(scen), "--duration", "2.5", "--rate", "200",
         "--out", str(out), "--quiet", *args],
        capture_output=True, text=True, timeout=400,
    )  # fmt: skip
    summary = json.loads((out / layout.SUMMARY).read_text())
    assert p.returncode == EXIT_CODE[summary["verdict"]["outcome"]], p.stderr
    return out, summary


def _stall_found(
    pairs: np.ndarray, t0_ns: int, gaps: list[dict], epoch_ns: int, period: int = P
) -> dict:
    """The device's stall near t0 + 1 s, as the device's OWN log of its sends shows it (same
    host clock; the figures never read it), found in the bench's figure. ``pairs``: per
    command, (the device's send, the plant's receive), in order. The longest send interval
    there, less P, is how late the device was (at least the 40 ms injected; more when the host
    held it longer); the plant's gap after that command is exactly that plus what the path
    added to it (its hop less the one before): on a quiet path, microseconds, and the gap reads
    40 ms +- 2 ms; on a loaded host the path's share is named, never hidden."""
    pairs = pairs[np.argsort(pairs[:, 0], kind="stable")]
    iv = np.diff(pairs[:, 0])
    near = (pairs[:-1, 0] >= t0_ns + 900 * MS) & (pairs[:-1, 0] <= t0_ns + 1200 * MS)
    k = int(np.argmax(np.where(near, iv, -1)))
    own_late = (int(iv[k]) - period) / 1e6
    # The stall injected: at least 40 ms (a spin or a sleep), less what the send before it was
    # itself late (its own interval past P; beside two CPU hogs own_late alone read 37.9 ms)
    before = max(0, int(iv[k - 1]) - period) / 1e6 if k > 0 else 0.0
    assert own_late + before >= 40.0 - 0.5, (own_late, before)
    at = (int(pairs[k, 1]) - epoch_ns) / 1e9
    gap = min(gaps, key=lambda g: abs(g["start_s"] - at))
    assert abs(gap["start_s"] - at) < 1e-6 and gap["owner"] == "device", (gap, at)
    hops = pairs[:, 1] - pairs[:, 0]
    path_ms = int(hops[k + 1] - hops[k]) / 1e6
    assert abs(gap["length_s"] * 1e3 - (own_late + path_ms)) <= 0.001, (gap, own_late, path_ms)
    if abs(path_ms) <= 0.5:
        assert abs(gap["length_s"] * 1e3 - own_late) <= 2.0, (gap, own_late)
    return gap


def _hosted_pairs(run: Path, node: int | None = None) -> tuple[np.ndarray, int]:
    """Per command of the hosted controller, its own send stamp (its hop log) and the plant's
    receive (Zenoh: by the command's number; CAN on zenoh_can: by the bus's name for the
    frame, which both sides log); and the run's epoch."""
    c, pl = read_hoplog(run / layout.CONTROLLER_LOG), read_hoplog(run / layout.PLANT_LOG)
    if node is None:
        recv = {r["seq"]: r["recv_ns"] for r in pl.table("cmd_rx") if r["path"] == CmdPath.ZENOH}
        sends = [(r["zenoh_send_ns"], r["cmd_seq"]) for r in c.table("ticks") if r["cmd_seq"] >= 0]
        pairs = [(t, recv[key]) for t, key in sends if t > 0 and key in recv]
    else:  # the two sides compute the bus's name apart: the same frame within a microsecond
        rx = sorted((r["send_ns"], r["recv_ns"]) for r in pl.table("cmd_rx")
                    if r["path"] == CmdPath.CAN and r["node"] == node)  # fmt: skip
        names = np.array([n for n, _ in rx], np.int64)
        pairs = []
        for r in c.table("can_tx"):
            if r["node"] != node or r["cmd_seq"] < 0 or r["send_ns"] <= 0 or not names.size:
                continue
            i = int(np.clip(np.searchsorted(names, r["bus_end_ns"]), 1, names.size - 1))
            j = min((i - 1, i), key=lambda m: abs(int(names[m]) - r["bus_end_ns"]))
            if abs(int(names[j]) - r["bus_end_ns"]) < 1_000:
                pairs.append((r["send_ns"], rx[j][1]))
    return np.array(pairs, np.int64), int(c.meta["epoch_ns"])


def test_a_hosted_law_that_stalls_40_ms_reads_as_a_40_ms_gap(tmp_path):
    out, summary = _hil_run(tmp_path, "z")
    # The law spins 40 ms in its update at t = 1 s: its next command came 40 ms late.
    pairs, epoch = _hosted_pairs(out)
    (z,) = summary["device"]["streams"]
    gap = _stall_found(pairs, epoch, z["gaps"], epoch)
    dev = summary["device"]
    assert dev["outside"] is False and dev["path"] == "zenoh"
    assert dev["response"]["count"] > 300 and dev["age"]["count"] > 300
    _stripped_folder_reports(tmp_path, out, gap)


def _stripped_folder_reports(tmp_path: Path, hosted: Path, gap: dict) -> None:
    """The hosted run's folder without controller.hoplog and the clock file (what an outside
    device's run holds), its derived files removed: ``hil report`` measures it again from the
    plant's log, gives the device's figures (the same gap) and a verdict, and exits with its
    code."""
    folder = tmp_path / "stripped"
    shutil.copytree(hosted, folder)
    for name in (layout.CONTROLLER_LOG, layout.CLOCK, layout.SUMMARY, layout.TRACE,
                 layout.SERIES, layout.REPORT_HTML, layout.REPORT_MD):  # fmt: skip
        (folder / name).unlink(missing_ok=True)
    p = subprocess.run(
        [sys.executable, "-m", "hil", "report", str(folder), "--no-ideal"],
        capture_output=True, text=True, timeout=400,
    )  # fmt: skip
    summary = json.loads((folder / layout.SUMMARY).read_text())
    outcome = summary["verdict"]["outcome"]
    assert p.returncode == EXIT_CODE[outcome], p.stderr  # hil/errors.py's table
    dev = summary["device"]
    assert dev["outside"] is True
    # the same gap, from the plant's log alone; its length against the outside device's own P
    # (the median of its intervals at the plant: the hosted run's 5 ms within 2 %; on a loaded
    # host the arrivals' jitter moves the median, 22 us once in CI)
    (same,) = [g for g in dev["streams"][0]["gaps"] if g["start_s"] == gap["start_s"]]
    assert same["interval_s"] == gap["interval_s"] and same["owner"] == gap["owner"]
    assert dev["nominal_period_from"] == "device median"
    assert same["length_s"] == pytest.approx(gap["interval_s"] - dev["nominal_period_s"], abs=1e-9)
    assert dev["nominal_period_s"] == pytest.approx(P / 1e9, rel=0.02)
    # what needs the controller's log is absent, never 0
    timing = summary["timing"]
    for key in ("compute", "hop_state", "hop_cmd_zenoh", "deadline_misses", "wakeup_lateness"):
        assert key not in timing, key
    assert summary["messages"] == {}
    report = (folder / layout.REPORT_MD).read_text()
    assert "The device at the bus" in report


@pytest.mark.parametrize("interface", ["zenoh_can"])
def test_the_same_stall_on_the_can_path_reads_per_wheel(tmp_path, interface):
    out, summary = _hil_run(tmp_path, "c", "--cmd-path", "can", "--can-interface", interface)
    dev = summary["device"]
    assert dev["path"] == "can"
    for node in (0, 1):
        pairs, epoch = _hosted_pairs(out, node)
        (st,) = [x for x in dev["streams"] if x["name"] == f"node {node}"]
        _stall_found(pairs, epoch, st["gaps"], epoch)
    # encoder estimates were logged and answered
    assert dev["response"]["count"] > 100 and dev["age_is_bound"] is True


# --- outside devices (hil run --controller external; tests/devices/, no code of the bench's) --


def _external(
    spawn, tmp_path: Path, name: str, device: list[str], *run_args: str, rate: float = 200.0
) -> dict:
    """An outside device's run whose rate, the nominal P, is the device's: 200 Hz (P = 5 ms)
    on Zenoh, the plant's States at that rate too; 100 Hz on CAN, the drives' encoder
    estimates' rate, which a device answering each one keeps."""
    scen = tmp_path / f"{name}.toml"
    scen.write_text(circle(NEAR, controller=TABLE1, realtime={"rate": rate, "sensor_rate": rate}))
    out = tmp_path / name
    args = (*run_args, str(scen))
    code, _, err = run_external(spawn, out, device, duration=2.0, run_args=args)
    summary = json.loads((out / layout.SUMMARY).read_text())
    assert code == EXIT_CODE[summary["verdict"]["outcome"]], err
    assert summary["device"]["outside"] is True
    assert not (out / layout.CONTROLLER_LOG).exists()
    return summary["device"]


def test_an_outside_zenoh_device_stall_jitter_and_wait_read_as_injected(tmp_path, spawn):
    # The devices run SCHED_FIFO (--fifo), as a real-time device would: their own timing then
    # does not move with the host's load (tests/test_campaign.py found the same).
    own_log = tmp_path / "stall-sends.txt"
    stalled = _external(
        spawn, tmp_path, "stall",
        zenoh_device("--fifo", "--stall-at", "1", "--stall-ms", "40", "--log", str(own_log)),
    )  # fmt: skip
    (z,) = stalled["streams"]
    # It answers each State; once, 1 s after its first, it sleeps 40 ms before answering.
    plant = read_hoplog(tmp_path / "stall" / layout.PLANT_LOG)
    recv = {r["seq"]: r["recv_ns"] for r in plant.table("cmd_rx")}
    own = np.loadtxt(own_log, dtype=np.int64, ndmin=2)
    pairs = np.array([(t, recv[q]) for q, t in own if q in recv], np.int64)
    # against the figures' P: an outside device's own median interval (about 5 ms here)
    nominal = round(stalled["nominal_period_s"] * 1e9)
    _stall_found(pairs, int(own[0, 1]), z["gaps"], int(plant.meta["epoch_ns"]), nominal)
    log = tmp_path / "sends.txt"
    jittered = _external(
        spawn,
        tmp_path,
        "jitter",
        zenoh_device("--fifo", "--hz", "200", "--jitter-ms", "1", "--log", str(log)),
    )
    (j,) = jittered["streams"]
    # The device moves each send by a uniform draw in [-1, 1] ms: |interval - P| has a median of
    # 2 (1 - 1/sqrt 2) = 0.586 ms (the constructed logs above find exactly that). Its own log of
    # its sends (same host clock; the bench never reads it) shows it did, and the path to the
    # plant adds its own jitter (each command's hop less the one before): the figure is the
    # device's jitter when the path's is small, and never less than the device's otherwise.
    own_log = np.loadtxt(log, dtype=np.int64, ndmin=2)
    plant = read_hoplog(tmp_path / "jitter" / layout.PLANT_LOG)
    recv = {r["seq"]: r["recv_ns"] for r in plant.table("cmd_rx")}
    sn = plant.columns("samples")["sample_ns"]
    mine = np.array([(t, recv[q]) for q, t in own_log if q in recv and sn[0] <= recv[q] <= sn[-1]])
    own = np.median(np.abs(np.diff(mine[:, 0]) - P)) / 1e3  # µs
    path = np.median(np.abs(np.diff(mine[:, 1] - mine[:, 0]))) / 1e3
    assert abs(own - 585.8) <= 150.0, own  # the device drew its jitter (SCHED_FIFO: on time)
    assert abs(np.median(np.diff(mine[:, 0])) / 1e3 - 5000.0) <= 200.0  # at 200 Hz
    if path <= 50.0:  # then the plant sees the device's 200 Hz and its jitter
        assert abs(j["period"]["p50_us"] - 5000.0) <= 200.0, (j["period"], path)
        assert abs(j["jitter"]["p50_us"] - own) <= 200.0, (j["jitter"], own, path)
    assert j["jitter"]["p50_us"] >= own - 200.0, (j["jitter"], own, path)
    slow = _external(spawn, tmp_path, "wait", zenoh_device("--fifo", "--wait-ms", "3"))
    raised = slow["response"]["p50_us"] - stalled["response"]["p50_us"]
    assert abs(raised - 3000.0) <= 500.0, (slow["response"], stalled["response"])
    # The age is the State's path to the device plus its response: it rises by what the response
    # rose, give or take how the two runs' State paths differed (574 us more under two hogs).
    aged = slow["age"]["p50_us"] - stalled["age"]["p50_us"]
    assert aged >= 2500.0 and abs(aged - raised) <= 1000.0, (aged, raised)
    assert stalled["unnamed"] == 0 and stalled["beyond_limits"] == []


def test_an_outside_can_device_that_waits_3_ms_reads_3_ms_slower(tmp_path, spawn):
    # SCHED_FIFO as the Zenoh devices above: the device's own timing moves less with the load
    can = ("--cmd-path", "can")
    base = _external(spawn, tmp_path, "base", odrive_can_device("--fifo"), *can, rate=100.0)
    slow = _external(
        spawn, tmp_path, "wait", odrive_can_device("--fifo", "--wait-ms", "3"), *can, rate=100.0
    )
    assert base["path"] == "can" and {s["name"] for s in base["streams"]} == {"node 0", "node 1"}
    # It answers 3 ms after the estimate reached its bus (the frame's own stamp, so that the
    # other wheel's frame, come at the same time, does not wait twice): the wait covers what
    # the base device spent between its bus and its handler, so the response is at least
    # 3 ms and at most the base's + 3 ms (here: 3.84-5.01 ms against 1.61-2.60 ms), give or
    # take 1 ms for the two runs' load (a fresh clone: 5.17 ms against 1.44 ms).
    wait_p50, base_p50 = slow["response"]["p50_us"], base["response"]["p50_us"]
    assert 3000.0 <= wait_p50 <= base_p50 + 3000.0 + 1000.0, (slow["response"], base["response"])
    # what the device did on the bus: it armed both drives (state requests, closed loop)
    assert base["bus"]["state_requests"] >= 2 and base["bus"]["armed"] >= 2
    assert base["age_is_bound"] is True and base["age"]["count"] > 0
    for st in base["streams"]:  # it answers each 100 Hz estimate: the period, no stall
        assert abs(st["period_mean_s"] - 0.010) <= 0.0005, st


def test_the_report_section_speaks_when_the_device_has_news(tmp_path):
    """The section is always there for an outside device; for the bench's own controller (its
    hops and wake-ups are in the other sections) only with a gap of its own, a torque beyond
    (2), a State named that was never sent or a refusal on the bus."""
    n = 400
    clean = _device(_write_plant(tmp_path / "c", n, _answering(n)))
    stalled = _device(
        _write_plant(tmp_path / "s", n, _answering(n, stall_at=100, stall_ns=40 * MS))
    )
    assert clean.outside and has_news(clean)
    hosted = DeviceFigures.from_dict({**clean.as_dict(), "outside": False})
    assert not has_news(hosted)
    assert has_news(DeviceFigures.from_dict({**stalled.as_dict(), "outside": False}))
    data = {"sections": ["headline", "certificate", "trajectory"]}
    add_device(data, hosted)
    assert "device" in data and data["sections"] == ["headline", "certificate", "trajectory"]
    add_device(data, stalled)
    assert data["sections"] == ["headline", "certificate", "device", "trajectory"]


def test_a_device_that_sent_nothing_or_never_armed_the_drives_fails(tmp_path):
    """Garbage that merely looked like a device (cangen) must not PASS: an outside device that
    sent no command, or on CAN never armed a drive, FAILs; the same figures with a command
    stream and armed drives do not."""
    n = 300
    clean = _device(_write_plant(tmp_path / "c", n, _answering(n)))
    outside = {**clean.as_dict(), "outside": True}
    assert _verdict(DeviceFigures.from_dict(outside)).outcome == PASS
    silent = DeviceFigures.from_dict(
        {**outside, "streams": [{**s, "commands": 0} for s in outside["streams"]]}
    )
    v = _verdict(silent)
    assert v.outcome == FAIL and "sent no command" in v.fail_reasons[0]
    bus = {**outside["bus"], "armed": 0}
    never = DeviceFigures.from_dict({**outside, "path": "can", "bus": bus})
    v = _verdict(never)
    assert v.outcome == FAIL and "never armed the drives" in v.fail_reasons[0]
    armed = DeviceFigures.from_dict({**outside, "path": "can", "bus": {**bus, "armed": 2}})
    assert _verdict(armed).outcome == PASS
