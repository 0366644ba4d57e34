"""Long runs in bounded memory, in short: a 20 s run at 1 kHz with both paths live, whose
logs read in chunks (hil.analysis.measure, as ``hil run`` and ``hil report`` read them) give every
figure an independent in-memory reading gives; and the report of a 2 M-sample trace, which
stays within a memory bound and draws each figure from its bins' extremes (a regression to
per-sample plotting or per-sample Python objects breaks them). How long they take and how the
services' memory grows are benchmark figures, which a loaded host moves: bench/bench_long_run.py
(1, 2, 10 and 60 minutes: service memory growth, the report's time) and
bench/bench_report.py --two-million (the 2 M-sample report's time)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from tests.run_helpers import expected_exit

ROOT = Path(__file__).resolve().parents[1]
WARMUP_S = 5.0


def _json(obj: Any) -> str:
    """A canonical text of a figure tree (numpy scalars as Python numbers, NaN as NaN)."""

    def conv(o: Any) -> Any:
        if isinstance(o, np.integer):
            return int(o)
        if isinstance(o, np.floating):
            return float(o)
        if isinstance(o, np.bool_):
            return bool(o)
        raise TypeError(type(o))

    return json.dumps(obj, default=conv, sort_keys=True)


def _in_memory_logs(run_dir: Path) -> Any:
    """The run's hop logs read whole (protocol.hoplog.read_hoplog, every row a Python list)
    and turned into the columns hil.analysis.measure joins, without hil.analysis.measure.logs'
    chunked reader."""
    from hil.analysis.measure.logs import RunLogs
    from hil.folder.hoplogs import COLUMNS, LogHead
    from protocol.hoplog import CONTROLLER_TABLES, HOST_TABLES, PLANT_TABLES, read_hoplog

    logs = RunLogs(None, None)
    for role, tables in (
        ("controller", CONTROLLER_TABLES),
        ("plant", PLANT_TABLES),
        ("host", HOST_TABLES),
    ):
        log = read_hoplog(run_dir / f"{role}.hoplog")
        head = LogHead(
            meta=log.meta,
            counters=log.counters,
            final=log.final,
            complete=log.complete,
            truncated=log.truncated,
            restarts=log.restarts,
        )
        setattr(logs, role, head)
        for name in dict(tables):
            fields = log.fields.get(name, [])
            rows = log.rows.get(name, [])
            logs.tables[name] = {
                c: np.array([r[fields.index(c)] for r in rows], dtype=dtype)
                if c in fields and rows
                else np.zeros(0, dtype)
                for c, dtype in COLUMNS[name].items()
            }
    return logs


@pytest.mark.realtime
@pytest.mark.slow
def test_a_20s_run_keeps_service_memory_flat_and_its_chunked_analysis_is_exact(
    tmp_path: Path,
) -> None:
    sys.path.insert(0, str(ROOT / "bench"))
    from longrun import run_sampled

    from hil.analysis.measure import measure
    from hil.analysis.measure.folder import measure_folder, resolved_scenario
    from hil.folder.scenario_view import bound_inputs

    run_dir = tmp_path / "run"
    sampled = run_sampled(run_dir, 20.0, rate=1000.0)
    # The services' memory was sampled by PID the whole run (its growth is
    # bench/bench_long_run.py's figure): the sampler saw both of them live after the warm-up.
    for name in ("plant", "controller"):
        after = [kb for t, kb in sampled.rss[name] if t >= WARMUP_S]
        assert len(after) >= 10 and min(after) > 0, (name, sampled.rss[name])

    summary = json.loads((run_dir / "summary.json").read_text())
    chunked = measure_folder(run_dir)
    whole = measure(_in_memory_logs(run_dir), bound_inputs(resolved_scenario(run_dir)))
    assert chunked is not None
    for part in ("timing", "messages", "certificate"):
        assert _json(getattr(chunked, part)) == _json(getattr(whole, part)), part
        assert _json(getattr(chunked, part)) == _json(summary[part]), part
    timing = summary["timing"]
    assert timing["wakeup_lateness"]["count"] > 15_000  # 20 s at 1 kHz, every tick counted
    lat_c, lat_w = chunked.latency_us(), whole.latency_us()
    assert lat_c.keys() == lat_w.keys() and all(np.array_equal(lat_c[p], lat_w[p]) for p in lat_c)


def _wait4(argv: list[str]) -> tuple[int, int]:
    """Run argv; (exit code, peak RSS kB of the child)."""
    proc = subprocess.Popen(argv, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    _, status, usage = os.wait4(proc.pid, 0)
    proc.returncode = os.waitstatus_to_exitcode(status)
    return proc.returncode, int(usage.ru_maxrss)


@pytest.mark.slow
def test_the_report_of_two_million_samples_is_small(tmp_path: Path) -> None:
    """2 M samples (33 minutes at 1 kHz): about 0.6 GB here, bound 1 GB (memory, which a
    loaded host does not move; its time, ~10 s, is bench/bench_report.py --two-million's).
    Every figure's data holds its drawn samples (the extremes of each time bin), not 2 M
    rows, and keeps the true peak."""
    from hil.folder import read_trace
    from tests.synthetic_folder import write_synthetic_folder

    folder = write_synthetic_folder(tmp_path / "long", duration=2000.0, rate=1000.0)
    code, peak_kb = _wait4([sys.executable, "-m", "hil", "report", str(folder), "--no-ideal"])
    # The synthetic folder's timing is clean: PASS, and the report's exit code that of PASS.
    assert code == expected_exit("PASS", command="report")
    assert peak_kb < 1024 * 1024, peak_kb
    report = json.loads((folder / "report.json").read_text())
    assert report["metrics"]["samples"] == 2_000_001
    for f in report["figures"]:
        rows = len((folder / f["data"]).read_text().splitlines()) - 1
        assert rows <= 25_000, (f["data"], rows)
    v = np.genfromtxt(folder / "report_v.csv", delimiter=",", names=True)
    trace = read_trace(folder / "trace.csv")
    assert np.max(np.abs(v["v"])) == np.max(np.abs(trace["v"]))
    assert "drawn" in (folder / "report.md").read_text()
