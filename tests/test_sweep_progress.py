"""The sweep's progress names the grid points running now: every group of
one Ts says its Ts, its delays and how many loops run at once, and which group of how many it
is (the label stayed "Ts=0.001 s" for the whole grid); --worst-disturbance names each point."""

from __future__ import annotations

from hil.bundled import bundled_dir
from hil.scenario import load_scenario
from hil.sweep.grid import make_grid
from hil.sweep.runner import run_sweep
from hil.sweep.worst import run_worst_sweep


def _labels(run, grid) -> list[str]:
    sc = load_scenario(bundled_dir() / "paper_tracking.toml")
    seen: list[str] = []

    def progress(ts: float, done: int, n: int, label: str = "") -> None:
        if not seen or seen[-1] != label:
            seen.append(label)

    run(sc, grid, 0.2, progress)
    return seen


def test_each_group_of_the_grid_is_named_as_it_runs() -> None:
    grid = make_grid(ts=(0.002, 0.005), delay=(0.0, 0.01, 0.02))
    assert _labels(run_sweep, grid) == [
        "Ts = 0.005 s, delay 0–0.02 s (group 1 of 2, 3 loops at once)",
        "Ts = 0.002 s, delay 0–0.02 s (group 2 of 2, 3 loops at once)",
    ]


def test_a_single_ts_grid_still_says_which_points_run() -> None:
    grid = make_grid(ts=(0.005,), delay=(0.0, 0.01), jitter=(0.0, 0.001), seeds=2)
    assert _labels(run_sweep, grid) == [
        "Ts = 0.005 s, delay 0–0.01 s, jitter 0–0.001 s, 2 seeds (group 1 of 1, 8 loops at once)"
    ]


def test_the_worst_disturbance_sweep_names_each_point() -> None:
    grid = make_grid(ts=(0.01,), delay=(0.0, 0.01))
    assert _labels(run_worst_sweep, grid) == [
        "Ts = 0.01 s, delay 0 s (point 1 of 2)",
        "Ts = 0.01 s, delay 0.01 s (point 2 of 2)",
    ]
