"""``hil sweep`` on the real batch simulator: grid, break point, outputs, replay, Ctrl-C."""

from __future__ import annotations

import html
import json
import signal
import subprocess
from pathlib import Path

import numpy as np
import pytest

from hil.analysis.replay import latencies_from_run
from hil.cli import main
from hil.errors import BadInputError
from hil.sweep.grid import DEFAULT_DELAY, DEFAULT_TS, break_points, make_grid
from tests.procs import wait_until
from tests.scenario_text import CIRCLE_TABLE1
from tests.synthetic_folder import write_synthetic_folder

# m1 near its bound phi1 - mu1 = 1.1 and z1(0) = -m1, so alpha_v starts near mu1 + m1: with a
# long delay the sampled sign law lets v run past phi1 = 1.6 (docs/design.md, section 2).
EDGE = """
[reference]
kind = "circle"
vd = 0.5
wd = 0.2

[initial]
x = 0.0
y = 0.0
theta = 0.0
z1 = -1.05

[controller]
law = "unified"
m1 = 1.05
m2 = 0.5
l1 = 0.5
l2 = 0.5
lam = 1.0
rho = 1.0

[run]
duration = 3.0

[sweep]
ts = [0.005, 0.05]
delay = [0.0, 0.1]
"""

PAPER = (
    CIRCLE_TABLE1
    + """

[run]
duration = 2.0
"""
)


def write(tmp_path: Path, name: str, text: str) -> Path:
    p = tmp_path / name
    p.write_text(text)
    return p


def test_default_grid_and_bad_values() -> None:
    g = make_grid()
    assert g.ts == DEFAULT_TS and g.delay == DEFAULT_DELAY and g.seeds == 1
    assert set(g.defaulted) == {"ts", "delay", "jitter", "seeds"}
    g2 = make_grid([0.01, 0.001, 0.01], [0.0], [0.0, 0.001], 3)
    assert g2.ts == (0.001, 0.01) and len(g2) == 2 * 1 * 2 * 3
    groups = g2.by_ts(base_seed=10)
    assert [ts for ts, _ in groups] == [0.01, 0.001]  # cheap coarse periods first
    assert {p.seed for p in groups[0][1]} == {10, 11, 12}
    for bad in ([0.0], [-1.0], [float("nan")]):
        with pytest.raises(ValueError):
            make_grid(bad)
    with pytest.raises(ValueError):
        make_grid(delay=[-0.1])


def test_break_point_is_the_smallest_violating_ts_and_delay() -> None:
    rows = [
        {"ts": ts, "delay": d, "jitter": 0.0, "seed": 0, "violation": ts + d >= 0.05}
        for ts in (0.001, 0.01, 0.05)
        for d in (0.0, 0.04, 0.1)
    ]
    bp = break_points(rows)
    assert bp["first"] == {"ts": 0.01, "delay": 0.04, "jitter": 0.0, "seed": 0}
    assert bp["ts_by_delay"] == {0.0: 0.05, 0.04: 0.01, 0.1: 0.001}
    assert bp["delay_by_ts"][0.001] == 0.1
    assert break_points([{**r, "violation": False} for r in rows])["first"] is None


def test_sweep_finds_the_break_point_of_a_design_near_its_limits(tmp_path: Path) -> None:
    out = tmp_path / "out"
    assert main(["sweep", str(write(tmp_path, "edge.toml", EDGE)), "--out", str(out)]) == 0
    doc = json.loads((out / "sweep.json").read_text())
    rows = doc["rows"]
    assert len(rows) == 4 and all(r["complete"] for r in rows)
    bp = doc["break_point"]
    assert bp["first"] is not None and bp["first"]["delay"] == 0.1
    # without delay the limits hold at both periods; with 100 ms they break
    by = {(r["ts"], r["delay"]): r for r in rows}
    assert not by[(0.005, 0.0)]["violation"] and by[(0.005, 0.1)]["violation"]
    assert by[(0.005, 0.1)]["overshoot_v"] > 1.0
    # the measured peaks never exceed the certified bound at their own timing
    assert all(r["within_bound"] for r in rows)
    assert "first break at Ts = 0.005 s with a delay of 0.1 s" in (out / "sweep.md").read_text()
    csv_rows = (out / "sweep.csv").read_text().splitlines()
    assert len(csv_rows) == 5
    assert doc["figures"]
    for f in doc["figures"]:
        assert (out / f["png"]).read_bytes().startswith(b"\x89PNG")
        assert (out / f["data"]).stat().st_size > 0
    again = ["--out", str(out), "--strict", "--force"]  # the same folder, replaced whole
    assert main(["sweep", str(tmp_path / "edge.toml"), *again]) == 1


def test_sweep_rows_equal_the_single_run_path(tmp_path: Path) -> None:
    from hil.scenario import load_scenario
    from hil.sim import RobotVariation, simulate
    from hil.sweep.runner import scenario_at

    path = write(tmp_path, "paper.toml", PAPER)
    out = tmp_path / "out"
    args = ["sweep", str(path), "--out", str(out), "--ts", "0.002", "--delay", "0,0.004"]
    assert main([*args, "--jitter", "0.001", "--seeds", "2"]) == 0
    doc = json.loads((out / "sweep.json").read_text())
    assert doc["break_point"]["first"] is None and len(doc["rows"]) == 4
    row = next(r for r in doc["rows"] if r["delay"] == 0.004 and r["seed"] == 1)
    sc = scenario_at(load_scenario(path), 0.002, 2.0)
    single = simulate(sc, RobotVariation(delay=0.004, jitter=0.001, jitter_seed=1)).summary
    assert row["max_abs_v"] == pytest.approx(single["max_abs_v"], rel=1e-9)
    assert row["final_position_error"] == pytest.approx(single["final_position_error"], rel=1e-6)
    assert row["band_v"] is not None and row["band_v"] > 0


def test_sweep_bad_input_exits_2(tmp_path: Path) -> None:
    path = write(tmp_path, "paper.toml", PAPER)
    assert main(["sweep", str(tmp_path / "none.toml"), "--out", str(tmp_path / "o")]) == 2
    assert main(["sweep", str(path), "--ts", "0,-1", "--out", str(tmp_path / "o")]) == 2
    assert main(["sweep", str(path), "--ts", "abc", "--out", str(tmp_path / "o")]) == 2


def test_replay_latencies_from_a_run_folder(tmp_path: Path) -> None:
    from hil.analysis.measure.folder import measure_folder

    run = write_synthetic_folder(tmp_path / "run", duration=0.5, run=True)
    lat = measure_folder(run).latency_us()  # the run's one result (hil.analysis.measure)
    got = latencies_from_run(run)
    assert np.array_equal(got, np.concatenate([lat["zenoh"], lat["can"]]) * 1e-6)
    assert np.array_equal(latencies_from_run(f"{run}::can"), lat["can"] * 1e-6)
    with pytest.raises(BadInputError):
        latencies_from_run(f"{run}::udp")
    with pytest.raises(BadInputError):
        latencies_from_run(tmp_path / "missing.mcap")
    with pytest.raises(BadInputError, match="no hop logs"):
        latencies_from_run(write_synthetic_folder(tmp_path / "sim", duration=0.5))
    # a sweep of a scenario that replays the run's latencies
    text = PAPER.replace(
        "[run]", f'[timing]\njitter_kind = "replay"\nreplay = "{run}::zenoh"\n\n[run]'
    )
    path = write(tmp_path, "replay.toml", text)
    out = tmp_path / "out"
    assert main(["sweep", str(path), "--out", str(out), "--ts", "0.002", "--delay", "0"]) == 0
    replayed = json.loads((out / "replay.json").read_text())["latencies"]
    assert np.array_equal(replayed, lat["zenoh"] * 1e-6)
    assert len(json.loads((out / "sweep.json").read_text())["rows"]) == 1


@pytest.mark.slow
def test_ctrl_c_keeps_the_groups_already_done(tmp_path: Path, spawn) -> None:
    path = write(tmp_path, "paper.toml", PAPER)
    out = tmp_path / "out"
    # Ts = 0.05 s runs first and fast; the Ts = 1 ms group then takes tens of seconds.
    args = ["--ts", "0.05,0.001", "--delay", "0,0.01", "--duration", "60"]
    proc = spawn.python(["-m", "hil", "sweep", str(path), "--out", str(out), *args])
    csv_path = out / "sweep.csv"
    assert wait_until(
        lambda: csv_path.exists() and len(csv_path.read_text().splitlines()) >= 3, timeout=120
    ), "the first group never finished"
    proc.send_signal(signal.SIGINT)
    try:
        proc.wait(timeout=120)
    except subprocess.TimeoutExpired:
        pytest.fail("sweep did not stop on SIGINT")
    err = proc.stderr.read().decode(errors="replace")
    said = proc.stdout.read().decode(errors="replace")
    assert proc.returncode == 130, err[-2000:]
    assert f"interrupted: partial results kept in {out}" in err
    doc = json.loads((out / "sweep.json").read_text())
    assert doc["interrupted"] is True and doc["groups_done"] == 1
    assert {r["ts"] for r in doc["rows"] if r["complete"]} == {0.05}
    assert all(not r["complete"] for r in doc["rows"] if r["ts"] == 0.001)
    md = (out / "sweep.md").read_text()
    assert md.count("INTERRUPTED") == 1
    # What it did not cover, said on every output; never "held everywhere" (c20de4f: "break
    # point: none, the limits held everywhere" after 2 of 4 loops). The Ts = 1 ms group was
    # cut short (its rows kept, complete: false) or not reached at all.
    cut = sum(1 for r in doc["rows"] if not r["complete"])
    assert doc["coverage"] == {"loops": 4, "covered": 2, "cut_short": cut, "not_run": 2 - cut}
    parts = ", ".join(
        f"{n} {w}" for n, w in ((cut, "cut short"), (2 - cut, "not run")) if n
    )  # fmt: skip
    missing = f"covered 2 of 4 loops; 2 not covered ({parts}): no claim about them"
    page = html.unescape((out / "sweep.html").read_text())
    for text in (said, md, page):
        assert missing in text.replace("\n", " ") or missing[0].upper() + missing[1:] in text
        assert "held everywhere" not in text and "held in all" not in text
    assert "among the loops run" in said, said
