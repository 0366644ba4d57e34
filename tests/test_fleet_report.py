"""The fleet report's aggregates and exit rule (docs/fleet.md, "The fleet report"), from
synthetic per-robot summaries: each fleet figure is its per-robot figure pooled by the one
rule of hil.folder.rates, so a one-robot fleet has its robot's figures exactly."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from hil.analysis.fleet_report import fleet_outcome, fleet_summary
from hil.folder.rates import RATES, pooled, ratio
from hil.verdict import EXIT_CODE


def _robot(out: Path, name: str, verdict: str | None = "PASS", **timing) -> None:
    """A robot's folder with a summary.json holding ``timing`` (and the rates of its counts,
    as hil.analysis.measure writes them)."""
    folder = out / name
    folder.mkdir(parents=True)
    if verdict is None:
        return  # its run wrote no summary
    t = dict(timing)
    for rate, (count, over) in RATES.items():
        if count in t:
            t[rate] = ratio(t[count], t[over])
    cert = {"path": "zenoh", "d_max_s": 0.004, "d_star_s": 0.02, "held": True}
    summary = {
        "cmd_path": "zenoh",
        "timing": t,
        "verdict": {"outcome": verdict},
        "certificate": cert,
    }
    (folder / "summary.json").write_text(json.dumps(summary))


MISSED_15 = dict(deadline_misses=15, ticks=485, slots=500, samples_without_command=3,
             samples_judged=498, late_commands=7, plant_deadline_misses=2,
             plant_slots=500)  # fmt: skip


def test_a_one_robot_fleet_has_its_robots_rates_exactly(tmp_path):
    """A robot with 15 missed slots, 485 ticks, 500 slots: its rate is 15/500 = 0.03, and
    so is its fleet's (the report divided by ticks: 15/485 = 0.0309)."""
    _robot(tmp_path, "robot1", **MISSED_15, command_age_zenoh={"p99_us": 3100.0})
    summary = json.loads((tmp_path / "robot1" / "summary.json").read_text())
    f = fleet_summary(tmp_path, {"robot1": 0}, {})["fleet"]
    assert f["deadline_miss_rate"] == 0.03
    for rate in RATES:
        assert f[rate] == summary["timing"][rate], rate
    assert f["command_age_p99_us_max"] == f["command_age_p99_us_median"] == 3100.0


def test_fleet_rates_pool_the_robots_counts_over_their_denominators(tmp_path):
    robots = {
        "robot1": dict(MISSED_15, command_age_zenoh={"p99_us": 3100.0}),
        "robot2": dict(deadline_misses=0, ticks=500, slots=500, samples_without_command=0,
                       samples_judged=498, late_commands=1, plant_deadline_misses=0,
                       plant_slots=500, command_age_zenoh={"p99_us": 2900.0}),
        # on_state: no deadlines (absent, never 0): it adds nothing to the deadline figures
        "robot3": dict(samples_without_command=5, samples_judged=250, late_commands=0,
                       plant_deadline_misses=1, plant_slots=250,
                       command_age_zenoh={"p99_us": 5000.0}),
    }  # fmt: skip
    for name, timing in robots.items():
        _robot(tmp_path, name, **timing)
    f = fleet_summary(tmp_path, dict.fromkeys(robots, 0), {})["fleet"]
    assert f["deadline_miss_rate"] == 15 / 1000
    assert f["samples_without_command_rate"] == 8 / (498 + 498 + 250)
    assert f["late_commands_rate"] == 8 / (498 + 498 + 250)
    assert f["plant_deadline_miss_rate"] == 3 / 1250
    # The median robot's p99 is one of the robots' (an exact percentile, as every one of the
    # bench): of 2900, 3100, 5000 the middle one; of two, the lower.
    assert (f["command_age_p99_us_max"], f["command_age_p99_us_median"]) == (5000.0, 3100.0)
    rows = [dict(r) for r in robots.values()]
    for rate in RATES:
        assert f[rate] == pooled(rows, rate), rate
    assert pooled([rows[0], rows[1]], "deadline_miss_rate") == 15 / 1000
    assert pooled([{"slots": 0, "deadline_misses": 0}], "deadline_miss_rate") is None
    assert pooled([{}], "deadline_miss_rate") is None


def test_the_median_p99_of_an_even_fleet_is_the_lower_middle_robot(tmp_path):
    for i, p99 in enumerate((4000.0, 1000.0, 3000.0, 2000.0), start=1):
        _robot(tmp_path, f"robot{i}", command_age_zenoh={"p99_us": p99})
    f = fleet_summary(tmp_path, {f"robot{i}": 0 for i in range(1, 5)}, {})["fleet"]
    assert (
        f["command_age_p99_us_median"]
        == 2000.0
        == np.percentile([1000.0, 2000.0, 3000.0, 4000.0], 50, method="inverted_cdf")
    )


@pytest.mark.parametrize(
    ("verdicts", "outcome", "exits_1"),
    [
        (("PASS", "PASS"), "PASS", False),
        (("PASS", "INCONCLUSIVE"), "INCONCLUSIVE", False),
        (("INCONCLUSIVE", "FAIL"), "FAIL", True),
        (("FAIL", "PASS"), "FAIL", True),
        (("PASS", None), "FAIL", True),  # robot2 wrote no summary: no verdict
    ],
)
def test_the_fleet_outcome_and_exit_rule(tmp_path, verdicts, outcome, exits_1):
    for i, v in enumerate(verdicts, start=1):
        _robot(tmp_path, f"robot{i}", v, command_age_zenoh={"p99_us": 1.0})
    summary = fleet_summary(tmp_path, {f"robot{i}": 0 for i in range(1, 3)}, {})
    fleet = summary["fleet"]
    assert (fleet["verdict"], fleet["verdict_robots"]) == fleet_outcome(summary["per_robot"])
    assert fleet["verdict"] == outcome
    assert (EXIT_CODE[outcome] == 1) == exits_1
    if outcome != "PASS":  # the robots that made the verdict, named
        bad = [f"robot{i}" for i, v in enumerate(verdicts, start=1) if v in (outcome, None)]
        assert fleet["verdict_robots"] == bad
