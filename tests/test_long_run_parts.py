"""The parts that make long runs linear and bounded, each against the plain way it
replaces: the chunked trace reader, the chunked CSV writers, min/max envelopes, the recording's
telemetry reader and streamed attachments, references and disturbances on arrays of times, the
batch path with per-robot start times, and the windowed ideal trajectory."""

from __future__ import annotations

import csv
import json
import math
import os
from pathlib import Path

import numpy as np
import pytest

from hil.errors import BadInputError

# --------------------------------------------------------------------------- trace reading


def test_the_chunked_trace_reader_equals_loadtxt(tmp_path: Path, monkeypatch) -> None:
    from hil.folder import trace_csv as fmod

    rng = np.random.default_rng(3)
    data = rng.normal(size=(101, 11)) * 10.0 ** rng.integers(-12, 12, size=(101, 11))
    data[5, 9] = np.nan
    data[7, 10] = np.inf
    data[:, 0] = np.arange(101) * 0.01
    path = tmp_path / "trace.csv"
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["t", "x", "y", "theta", "v", "omega", "xd", "yd", "thetad", "tau1", "tau2"])
        for row in data:
            w.writerow([repr(float(v)) for v in row])
    monkeypatch.setattr(fmod, "CHUNK_ROWS", 7)  # many chunks, the last one short
    trace = fmod.read_trace(path)
    expected = np.loadtxt(path, delimiter=",", skiprows=1)
    names = ["t", "x", "y", "theta", "v", "omega", "xd", "yd", "thetad", "tau1", "tau2"]
    assert list(trace) == names
    for i, col in enumerate(trace.values()):
        assert np.array_equal(col, expected[:, i], equal_nan=True)
        assert col.flags.c_contiguous

    bad = tmp_path / "bad.csv"
    bad.write_text(path.read_text() + "0.5,oops" + ",1" * 9 + "\n")
    with pytest.raises(BadInputError, match="non-numeric"):
        fmod.read_trace(bad)
    short = tmp_path / "short.csv"
    lines = path.read_text().splitlines()
    short.write_text("\n".join(lines[:2]) + "\n")
    with pytest.raises(BadInputError, match="fewer than two"):
        fmod.read_trace(short)


def test_a_lazy_trace_reads_the_rarely_read_columns_only_when_asked(
    tmp_path: Path, monkeypatch
) -> None:
    """A lazily loaded folder's trace (hil.folder.trace_csv.TraceColumns) answers keys from the
    header, reads every column but the rarely read ones in one pass on first use, and those in
    a pass of their own only when one is asked for; each equal to the whole read."""
    from hil.folder import trace_csv as fmod
    from hil.trace import TRACE_COLUMNS

    names = [*TRACE_COLUMNS, "tau1_cmd", "tau2_cmd", "state_seq"]
    rng = np.random.default_rng(4)
    data = rng.normal(size=(50, len(names)))
    data[:, 0] = np.arange(50) * 0.01
    path = tmp_path / "trace.csv"
    path.write_text(
        ",".join(names) + "\n" + "".join(",".join(repr(float(v)) for v in r) + "\n" for r in data)
    )
    passes: list[list[str] | None] = []
    whole = fmod.read_trace(path)

    def counted(p, columns=None):
        passes.append(None if columns is None else list(columns))
        return whole_read(p, columns)

    whole_read = fmod.read_trace
    monkeypatch.setattr(fmod, "read_trace", counted)
    lazy = fmod.TraceColumns(path)
    assert list(lazy) == names and "tau1_cmd" in lazy and "v_tilde" not in lazy and not passes
    assert np.array_equal(lazy["x"], whole["x"])
    assert passes == [list(TRACE_COLUMNS)]
    assert np.array_equal(lazy["tau1"], whole["tau1"]) and len(passes) == 1  # already read
    assert np.array_equal(lazy["state_seq"], whole["state_seq"])
    assert passes[1] == ["tau1_cmd", "tau2_cmd", "state_seq"]
    assert all(np.array_equal(lazy[n], whole[n]) for n in names) and len(passes) == 2
    with pytest.raises(KeyError):
        lazy["v_tilde"]


def test_figure_data_and_run_traces_are_written_as_one_csv_row_per_sample(tmp_path: Path) -> None:
    """The chunked writers give the same bytes as ``csv.writer`` with ``repr`` per cell."""
    from hil.analysis.report import figures as fg

    cols = {
        "t": np.arange(150_001) * 1e-3,
        "a, b [m]": np.random.default_rng(0).normal(size=150_001),
        "short": np.array([1.5, np.nan, -0.0, 1e300]),
        "count": np.arange(70_000),
    }
    fg.write_columns(tmp_path / "fast.csv", cols)
    with open(tmp_path / "slow.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(list(cols))
        for i in range(150_001):
            w.writerow([repr(float(a[i])) if i < a.size else "" for a in cols.values()])
    assert (tmp_path / "fast.csv").read_bytes() == (tmp_path / "slow.csv").read_bytes()


def test_the_run_trace_is_the_row_by_row_trace(tmp_path: Path) -> None:
    """hil run's trace.csv, written column by column a chunk at a time, is byte for byte the
    one the row-by-row writer wrote (here against a copy of that writer)."""
    from controller_service.references import Circle
    from hil.analysis import analyze as results
    from hil.analysis.measure.logs import ALL_COLUMNS, load_folder_logs
    from hil.trace import COMMAND_COLUMNS, TRACE_COLUMNS
    from protocol.hoplog import TICK_NO_SEND
    from tests.synthetic_folder import write_synthetic_folder

    folder = write_synthetic_folder(tmp_path / "run", run=True, duration=2.0)
    logs = load_folder_logs(folder, ALL_COLUMNS)
    reference = Circle(0.5, 0.2)

    def row_by_row(out: Path, lockstep: bool) -> tuple[list[float], float]:
        t_ = logs["ticks"]
        used = (
            (t_["state_seq"] >= 0)
            & ((t_["flags"] & TICK_NO_SEND) == 0)
            & (t_["state_sample_ns"] > 0)
        )
        cmd: dict[int, tuple[float, float]] = {}
        for seq, a, b in zip(
            t_["state_seq"][used].tolist(),
            t_["tau1"][used].tolist(),
            t_["tau2"][used].tolist(),
            strict=True,
        ):
            cmd.setdefault(seq, (a, b))
        s = logs["samples"]
        pos, head = [], 0.0
        with (out / "trace.csv").open("w", newline="") as f:
            w = csv.writer(f)
            w.writerow([*TRACE_COLUMNS, *COMMAND_COLUMNS, "sample_ns", "state_seq"])
            for i in range(s["seq"].size):
                seq = int(s["seq"][i])
                sample_ns = int(s["sample_ns"][i])
                t = seq * 0.001 if lockstep else (sample_ns - logs.epoch_ns) / 1e9
                ref = reference.sample(t)
                c1, c2 = cmd.get(seq, (float("nan"), float("nan")))
                x, y, th = float(s["x"][i]), float(s["y"][i]), float(s["theta"][i])
                row = (t, x, y, th, s["v"][i], s["omega"][i], ref.xd, ref.yd, ref.thetad)
                row += (s["tau1"][i], s["tau2"][i], c1, c2)
                w.writerow([repr(float(v)) for v in row] + [sample_ns, seq])
                pos.append(math.hypot(x - ref.xd, y - ref.yd))
                head = results.wrap(th - ref.thetad)
        return pos, head

    for lockstep in (False, True):
        a, b = tmp_path / f"a{lockstep}", tmp_path / f"b{lockstep}"
        a.mkdir()
        b.mkdir()
        pos, head = results.write_trace(a, logs, reference, 0.001, lockstep)
        pos_ref, head_ref = row_by_row(b, lockstep)
        assert (a / "trace.csv").read_bytes() == (b / "trace.csv").read_bytes()
        assert pos.tolist() == pos_ref and head == head_ref


# --------------------------------------------------------------------------- envelopes


def test_envelopes_keep_every_bins_extremes_and_gaps() -> None:
    from hil.analysis.report.figures import MAX_DRAWN_POINTS, cdf_indices, envelope_indices

    n = 1_000_003
    t = np.arange(n) * 1e-3
    rng = np.random.default_rng(1)
    y = np.sin(t) + 0.01 * rng.normal(size=n)
    y[123_457] = 5.0  # single-sample spikes
    y[777_777] = -4.0
    y[500_000:500_010] = np.nan  # a gap
    z = np.cos(3 * t)
    bins = 1000
    idx = envelope_indices(t, [y, z], bins=bins)
    assert idx[0] == 0 and idx[-1] == n - 1 and np.all(np.diff(idx) > 0)
    assert {123_457, 777_777} <= set(idx.tolist())
    assert np.isnan(y[idx]).any()  # the gap stays a gap in the drawn line
    edges = np.searchsorted(t, np.linspace(t[0], t[-1], bins + 1)[1:-1], side="left")
    for series in (y, z):
        lo = np.fmin.reduceat(series, np.concatenate([[0], edges]))
        hi = np.fmax.reduceat(series, np.concatenate([[0], edges]))
        b = np.searchsorted(edges, idx, side="right")  # the bin of each drawn sample
        drawn_lo = np.full(bins, np.inf)
        drawn_hi = np.full(bins, -np.inf)
        np.fmin.at(drawn_lo, b, series[idx])
        np.fmax.at(drawn_hi, b, series[idx])
        assert np.array_equal(drawn_lo, lo) and np.array_equal(drawn_hi, hi)
    assert envelope_indices(t, [y, z]).size <= MAX_DRAWN_POINTS
    assert np.array_equal(envelope_indices(t[:500], [y[:500]]), np.arange(500))

    c = cdf_indices(3_600_000)
    assert c[0] == 0 and c[-1] == 3_599_999 and c.size <= 5_000
    assert set(range(3_599_000, 3_600_000)) <= set(c.tolist())  # the tail whole


def test_a_long_series_figure_draws_its_envelope_and_says_so() -> None:
    from hil.analysis.report import figures as fg

    n = 400_000
    t = np.arange(n) * 1e-3
    v = 0.5 + 0.01 * np.sin(t)
    v[300_001] = 1.7  # beyond a limit of 1.6 for one sample
    f = fg.signal_with_limits("v", "v", "m/s", t, [("v", v)], 1.6)
    assert f.columns["v"].size < 20_000 and f.columns["v"].max() == 1.7
    assert "drawn samples" in f.caption and "trace.csv" in f.caption
    short = fg.signal_with_limits("v", "v", "m/s", t[:150_000], [("v", v[:150_000])], 1.6)
    assert short.columns["v"].size == 150_000 and "every sample" in short.caption


# --------------------------------------------------------------------------- recordings


def _recording(path: Path, streamed: bool, blob: Path, n: int = 3000) -> None:
    from hil.bench.recorder import RecordingWriter

    w = RecordingWriter(path, metadata={"robot_id": "r"}, flush_interval=0.0)
    for i in range(n):
        w.write("hil/r/state", 1_000 + 2 * i, {"seq": i, "x": 0.1 * i})
        tel = {"time_ns": 5_000 + i, "v_tilde": 0.5 - i * 1e-3, "w_tilde": -i * 1e-4}
        if i % 7:
            tel.update(z1=1e-3 * i, z2=-1e-3 * i, eta=math.exp(-i / 100))
        w.write("hil/r/telemetry", 1_001 + 2 * i, tel)
    if streamed:
        w.add_attachment_file("plant.hoplog", blob, time_ns=42)
    else:
        w._writer.add_attachment(42, 42, "plant.hoplog", "application/msgpack", blob.read_bytes())
    w.write("hil/r/state", 10**7, {"seq": -1})
    w.close()


def test_streamed_attachments_are_the_same_recording(tmp_path: Path) -> None:
    from hil.folder.recording import read_attachments

    blob = tmp_path / "blob"
    blob.write_bytes(os.urandom(3 * 2**20 + 17))
    _recording(tmp_path / "a.mcap", False, blob)
    _recording(tmp_path / "b.mcap", True, blob)
    assert (tmp_path / "a.mcap").read_bytes() == (tmp_path / "b.mcap").read_bytes()
    assert read_attachments(tmp_path / "b.mcap")["plant.hoplog"] == blob.read_bytes()


def test_telemetry_read_by_message_index_equals_the_mcap_reader(tmp_path: Path) -> None:
    from hil.analysis.report.telemetry import recorded_telemetry, sliding_from_recordings
    from hil.folder.recording import read_messages, read_topic_payloads

    blob = tmp_path / "blob"
    blob.write_bytes(b"x")
    rec = tmp_path / "r.mcap"
    _recording(rec, True, blob)
    fast = [(lt, json.loads(p)) for _, lt, p in read_topic_payloads(rec, ["hil/r/telemetry"])]
    slow = [(m.log_time_ns, m.data) for m in read_messages(rec, topics=["hil/r/telemetry"])]
    assert sorted(fast, key=lambda r: r[0]) == slow and len(slow) == 3000
    tel = recorded_telemetry([rec])
    assert tel["v_tilde"][0].size == 3000 and tel["z1"][0].size == 3000 - 429
    i = np.arange(3000)
    assert np.array_equal(tel["v_tilde"][0], 5_000 + i)
    assert np.array_equal(tel["w_tilde"][1], -i * 1e-4)
    assert set(sliding_from_recordings([rec])) == {"v_tilde", "w_tilde"}


def test_telemetry_messages_that_do_not_carry_a_group_are_skipped_in_place(tmp_path) -> None:
    """A message without time_ns is placed at its log time, one whose values are not all
    numbers (a bool, a string, null) is skipped for that
    group only; a payload that is not JSON is None in its place, so the others keep their own
    log times (the batch is then decoded one by one, NaN by the standard library)."""
    from hil.analysis.report.telemetry import _decode, recorded_telemetry
    from hil.bench.recorder import RecordingWriter

    assert _decode([b'{"a": 1}', b"not json", b'{"a": NaN}', b"[1]"])[:2] == [{"a": 1}, None]
    assert math.isnan(_decode([b'{"a": NaN}'])[0]["a"])
    rec = tmp_path / "r.mcap"
    w = RecordingWriter(rec, metadata={"robot_id": "r"}, flush_interval=0.0)
    rows = [
        {"time_ns": 10, "v_tilde": 1.0, "w_tilde": 2, "z1": 0.0, "z2": 0.0, "eta": 1.0},
        {"v_tilde": 3.0, "w_tilde": 4.0},  # no time_ns: its log time, 1002
        {"time_ns": 30, "v_tilde": True, "w_tilde": 1.0, "z1": 1.0, "z2": 2.0, "eta": 0.5},
        {"time_ns": 40, "v_tilde": "5", "w_tilde": 1.0},
        {"time_ns": 50, "v_tilde": float("nan"), "w_tilde": 6.0, "z1": None},
        {"time_ns": 60, "v_tilde": 7.0, "w_tilde": 8.0},
    ]
    for i, row in enumerate(rows):
        w.write("hil/r/telemetry", 1_000 + i, row)
    w.close()
    tel = recorded_telemetry([rec])
    tn, v = tel["v_tilde"]  # the writer writes NaN as null: that row is not a number
    assert tn.tolist() == [10, 60, 1001] and v.tolist() == [1.0, 7.0, 3.0]
    assert tel["w_tilde"][1].tolist() == [2.0, 8.0, 4.0]
    assert tel["z1"][0].tolist() == [10, 30] and tel["eta"][1].tolist() == [1.0, 0.5]


# --------------------------------------------------------------------------- arrays of times


def test_references_and_disturbances_on_arrays_of_times(tmp_path: Path) -> None:
    from controller_service.references import (
        Circle,
        CircleThenStop,
        CsvReference,
        Lemniscate,
        Point,
        sample_array,
    )
    from plant_emulator.disturbances import Disturbance, disturbance_at

    (tmp_path / "r.csv").write_text(
        "t,xd,yd,thetad,vd,wd\n0,0,0,0,0.1,0\n1,0.1,0,0,0.2,0.1\n3,0.4,0.1,0.2,0.1,0\n"
    )
    refs = [
        Circle(),
        Circle(wd=0.0),
        Point(1.0, 2.0, 3.0),
        CircleThenStop(stop_time=2.0),
        CircleThenStop(vd=0.0, wd=0.0, stop_time=1.0),
        Lemniscate(),
        CsvReference(tmp_path / "r.csv"),
    ]
    t = np.concatenate([np.linspace(-1.0, 12.0, 1301), [0.0, 1.0, 2.0, 3.0]])
    for ref in refs:
        got = sample_array(ref, t)
        for i in range(7):
            want = np.array([ref.sample(float(x))[i] for x in t])
            assert np.allclose(got[i], want, rtol=0, atol=1e-15), (type(ref).__name__, i)
    for d in (
        Disturbance("sine", amplitude1=0.1, amplitude2=0.2, freq=0.7, phase=0.3),
        Disturbance("random", s1=0.1, s2=0.2, period=0.1, seed=5),
    ):
        a1, a2 = disturbance_at(d, t[t >= 0])
        want = [disturbance_at(d, float(x)) for x in t[t >= 0]]
        assert np.array_equal(a1, [w[0] for w in want]) and np.array_equal(a2, [w[1] for w in want])


# Only the keys each kind reads (the loader refuses the others).
DISTURBANCE = {
    "none": "",
    "sine": "s1 = 0.1\ns2 = 0.2\namplitude1 = 0.05\namplitude2 = 0.1\nfreq = 0.5\n",
    "random": "s1 = 0.1\ns2 = 0.2\nperiod = 0.05\n",
}

SCENARIO = """
[reference]
kind = "circle"
vd = 0.5
wd = 0.2

[initial]
x = -0.3
y = 0.2
theta = 0.1

[disturbance]
kind = "{kind}"
{disturbance}
[timing]
ts = {ts}

[plant]
step = {step}

[run]
duration = {duration}
"""


@pytest.mark.parametrize("kind", ["none", "sine", "random"])
def test_batch_robots_with_their_own_start_times_are_single_runs(tmp_path: Path, kind: str) -> None:
    from hil.scenario import loads_scenario
    from hil.sim import simulate, simulate_batch
    from hil.sim.core import RobotVariation

    sc = loads_scenario(
        SCENARIO.format(
            kind=kind, disturbance=DISTURBANCE[kind], ts=0.001, step=0.0005, duration=0.5
        ),
        tmp_path,
    )
    t0 = [0.0, 3.3, 17.123]
    var = [RobotVariation(x=-0.3 + 0.1 * i, theta=0.1 * i, v=0.05 * i) for i in range(3)]
    seen: dict[int, np.ndarray] = {}
    b = simulate_batch(
        sc, var, record=[0, 1, 2], t0=np.array(t0), on_sample=lambda k, s: seen.__setitem__(k, s.x)
    )
    assert sorted(seen) == list(range(501))
    for i in range(3):
        single = simulate(sc, var[i], t0=t0[i])
        assert np.allclose(b.traces[i], single.trace, rtol=0, atol=1e-12)
        xs = np.array([seen[k][i] for k in range(500)])
        assert np.allclose(xs, single.column("x"), rtol=0, atol=1e-12)
    plain = simulate_batch(sc, var, record=[0])
    zero = simulate_batch(sc, var, record=[0], t0=0.0, on_sample=lambda k, s: None)
    assert np.array_equal(plain.traces[0], zero.traces[0])


# --------------------------------------------------------------------------- windowed ideal


def _ideal_run_folder(tmp_path: Path, duration: float, kind: str = "sine") -> Path:
    """A simulation folder whose loop already is its own ideal: simulated at Ts/10 with no
    delay, its resolved scenario saying Ts (so the report's ideal is at that same period)."""
    from hil.scenario import loads_scenario
    from hil.sim import simulate, write_run_folder

    sc = loads_scenario(
        SCENARIO.format(
            kind=kind, disturbance=DISTURBANCE[kind], ts=0.001, step=0.001, duration=duration
        ),
        tmp_path,
    )
    result = simulate(sc)
    result.resolved["timing"]["ts"] = 0.01
    return write_run_folder(result, tmp_path / "ideal_run")


def test_the_windowed_ideal_of_an_ideal_loop_is_the_loop(tmp_path: Path, monkeypatch) -> None:
    """Restarted at each window from the robot's state and the law's memory (the trace's own
    columns here), the ideal retraces an ideal loop on both routes; with the law's initial
    memory at each restart it does not."""
    from hil.analysis.report import ideal_sim
    from hil.analysis.report.ideal import ideal_from_simulator, memory_source
    from hil.folder import load_folder

    folder = load_folder(_ideal_run_folder(tmp_path, 12.0))
    tr = folder.trace
    single_route = ideal_sim.simulate_ideal(
        folder.scenario, folder.path, tr, memory_source(folder), window=2.5
    )
    monkeypatch.setattr(ideal_sim, "BATCH_MIN_WINDOWS", 1)
    batch_route = ideal_sim.simulate_ideal(
        folder.scenario, folder.path, tr, memory_source(folder), window=2.5
    )
    forgetful = ideal_sim.simulate_ideal(folder.scenario, folder.path, tr, None, window=2.5)
    assert batch_route["window_start_t"].size == 5
    for k in ("x", "y", "theta"):
        assert np.allclose(single_route[k], tr[k], rtol=0, atol=1e-9)
        assert np.allclose(batch_route[k], tr[k], rtol=0, atol=1e-9)
    assert np.max(np.hypot(forgetful["x"] - tr["x"], forgetful["y"] - tr["y"])) > 1e-6
    assert np.array_equal(batch_route["t"], tr["t"])
    # 12 s is beyond one default window: the report's own provider takes the windowed route
    assert "window_start_t" in ideal_from_simulator(folder)


def test_the_windowed_ideal_spread_over_processes_equals_it_in_one(tmp_path: Path, monkeypatch):
    """An hour's ideal spreads its windows over the CPUs: the windows split into runs of
    consecutive windows, the second run simulated in a spawned process, the rows joined back
    in order: the same numbers as all windows in this process."""
    from hil.analysis.report import ideal_sim
    from hil.analysis.report.ideal import memory_source
    from hil.folder import load_folder

    folder = load_folder(_ideal_run_folder(tmp_path, 12.0))
    tr, source = folder.trace, memory_source(folder)
    monkeypatch.setattr(ideal_sim, "BATCH_MIN_WINDOWS", 1)
    monkeypatch.setattr(ideal_sim, "_groups", lambda windows: 1)
    together = ideal_sim.simulate_ideal(folder.scenario, folder.path, tr, source, window=2.5)
    monkeypatch.setattr(ideal_sim, "_groups", lambda windows: 2)
    spread = ideal_sim.simulate_ideal(folder.scenario, folder.path, tr, source, window=2.5)
    for k in ("t", "x", "y", "theta", "window_start_t"):
        assert np.array_equal(spread[k], together[k]), k
    # ... and it is the loop itself (an ideal loop is its own ideal): no row was misplaced
    assert np.allclose(spread["x"], tr["x"], rtol=0, atol=1e-9)


def test_the_windowed_ideal_on_the_compiled_kernel_equals_the_numpy_one(
    tmp_path: Path, monkeypatch
):
    """The bundled law on the common plant (here with no disturbance): all windows go, as one
    part, to one worker process (the kernel uses every CPU itself), and that part's batch on
    the compiled kernel gives the numpy batch path's ideal to 1e-12."""
    from hil.analysis.report import ideal_sim
    from hil.analysis.report.ideal import memory_source
    from hil.folder import load_folder
    from hil.sim import compiled

    folder = load_folder(_ideal_run_folder(tmp_path, 12.0, kind="none"))
    tr = folder.trace
    monkeypatch.setattr(ideal_sim, "BATCH_MIN_WINDOWS", 1)
    monkeypatch.setattr(compiled, "MIN_WORK", 0)
    routes: list[tuple[int, bool]] = []
    real_spread = ideal_sim._spread

    def spread(parts, loop, here=True):
        routes.append((len(parts), here))
        parts_seen.extend(parts)
        return real_spread(parts, loop, here)

    parts_seen: list = []
    monkeypatch.setattr(ideal_sim, "_spread", spread)
    whole = ideal_sim.simulate_ideal(folder.scenario, folder.path, tr, memory_source(folder), 2.5)
    assert routes == [(1, False)]  # one part, in a worker
    for k in ("x", "y", "theta"):
        assert np.allclose(whole[k], tr[k], rtol=0, atol=1e-9), k  # the loop is its own ideal
    kernel_runs: list[int] = []
    real_run = compiled.run
    monkeypatch.setattr(compiled, "run", lambda *a: kernel_runs.append(1) or real_run(*a))
    fast = ideal_sim._batch(parts_seen[0])  # what the worker runs, here
    monkeypatch.setenv("HIL_NO_COMPILED", "1")
    reference = ideal_sim._batch(parts_seen[0])
    assert kernel_runs == [1]
    for k in ("x", "y", "theta"):
        assert np.allclose(fast[k], reference[k], rtol=0, atol=1e-12), k
        assert np.allclose(fast[k], tr[k], rtol=0, atol=1e-9), k


@pytest.mark.parametrize("bad_row", [(1, 2), tuple(range(9))])
def test_a_hop_log_row_of_the_wrong_width_is_refused_by_name(tmp_path: Path, bad_row) -> None:
    from hil.analysis.measure.logs import FIGURE_COLUMNS, RunLogs
    from hil.folder.hoplogs import read_columns
    from protocol.hoplog import PLANT_TABLES, HopLogError, HopLogWriter

    path = tmp_path / "plant.hoplog"
    w = HopLogWriter(path, "plant", PLANT_TABLES, {"epoch_ns": 1})
    width = len(PLANT_TABLES["apply"])
    w.append("apply", tuple(range(width)))
    w.append("apply", bad_row)
    w.close()
    wanted = {"apply": FIGURE_COLUMNS["apply"]}
    with pytest.raises(HopLogError, match="a row of table apply has not 8 fields"):
        read_columns(path, wanted)
    logs = RunLogs.read(None, path)  # an unreadable log reads as absent, never half-used
    assert logs.plant is None and logs["apply"]["seq"].size == 0
