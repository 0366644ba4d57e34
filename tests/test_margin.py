"""hil margin: the timing margin k* of a scenario (any law by import path) or of a run folder
(its measured landings replayed), margin.json, and the report's lines about it."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from hil.analysis.margin import record
from hil.analysis.margin.record import MarginProbe, MarginRecord
from hil.analysis.margin.timing import from_run, run_scenario, scaled
from hil.cli import main
from tests.run_helpers import PASSES, expected_exit, fails
from tests.scenario_text import NEAR, circle
from tests.synthetic_folder import write_synthetic_folder

DISTURBANCE = {"s1": 0.3, "s2": 3.0}
USER_LAW = circle(
    NEAR,
    controller={"law": "tests.margin_user_law:SaturatedTracker", "gain": 20.0},
    timing={"ts": 0.01, "delay": 0.02, "jitter": 0.005},
    run={"duration": 6.0},
)
DISTURBED = circle(
    NEAR,
    controller={"law": "unified", "rho": 0.5},
    disturbance={"kind": "random", **DISTURBANCE, "period": 0.1},
    timing={"ts": 0.02, "delay": 0.02},
    run={"duration": 3.0},
)


def _margin(tmp_path: Path, text: str, name: str, *extra: str) -> tuple[int, MarginRecord]:
    path = tmp_path / f"{name}.toml"
    path.write_text(text)
    out = tmp_path / name
    code = main(["margin", str(path), "--out", str(out), *extra])
    rec = record.read(out)
    assert rec is not None
    return code, rec


def _consistent(rec: MarginRecord) -> None:
    """k* is the broken end of a bracket narrowed to 2%, and every age is k times the replay's."""
    at = {p.k: p for p in rec.probes}
    assert at[rec.k_star].broke and not at[rec.k_held].broke
    assert rec.k_held < rec.k_star <= rec.k_held * 1.0201
    for p in rec.probes:
        assert p.age_s == pytest.approx(p.k * rec.d_replay_s, rel=0.03, abs=0.002)


def test_margin_of_a_users_own_law(tmp_path):
    code, rec = _margin(tmp_path, USER_LAW, "user", "--seeds", "8")
    assert rec.law == "tests.margin_user_law:SaturatedTracker"
    assert rec.d_star_s is None and rec.conservatism is None  # no certificate for this law
    assert rec.k_star is not None and rec.k_star > 1.0 and code == 0
    assert rec.first_broken in ("|v|", "|omega|")
    assert rec.d_replay_s == pytest.approx(0.035, abs=0.002)  # ts + delay + jitter bound
    _consistent(rec)
    # A tracking-error bound the law cannot meet even at the measured timing: k* <= 1, exit 1.
    tight_opts = ("--seeds", "4", "--duration", "2", "--error-bound", "0.001")
    code, tight = _margin(tmp_path, USER_LAW, "tight", *tight_opts)
    assert code == 1 and tight.first_broken == "position error" and tight.k_star <= 1.0


def test_worst_disturbance_margin_is_no_larger_than_the_scenarios(tmp_path):
    _, own = _margin(tmp_path, DISTURBED, "own", "--seeds", "16")
    _, worst = _margin(tmp_path, DISTURBED, "worst", "--seeds", "16", "--worst-disturbance")
    assert worst.disturbance == "worst" and worst.disturbance_at_break
    assert worst.k_star <= own.k_star
    # The unified law: D*, the empirical break under the worst disturbance and their ratio.
    assert worst.d_star_s == pytest.approx(0.0449, abs=2e-4)
    assert worst.conservatism == pytest.approx(worst.age_at_break_s / worst.d_star_s)
    assert worst.conservatism > 1.0  # no break below D* (the certificate is sound)
    _consistent(worst)


def test_margin_of_a_run_folder_replays_its_measured_timing(tmp_path):
    folder = write_synthetic_folder(
        tmp_path / "run", run=True, duration=3.0, delay=0.01, stall=(1.5, 0.04)
    )
    scenario = run_scenario(folder)
    base = from_run(folder, scenario)
    assert base.path == "zenoh" and base.measured_d_s > 0.04  # the stall's lost commands
    _, schedule = scaled(scenario, base, 1.0, 4, 3.0)
    # The replay's longest age is the measured D, to the plant step and the sample grid.
    assert schedule.max_age() == pytest.approx(base.measured_d_s, abs=scenario.timing.ts)
    _, twice = scaled(scenario, base, 2.0, 4, 3.0)
    assert twice.max_age() == pytest.approx(2.0 * schedule.max_age(), rel=0.02)
    code = main(["margin", str(folder), "--seeds", "4", "--duration", "2"])
    rec = record.read(folder)
    assert rec is not None and rec.source == str(folder)
    assert code == (1 if rec.k_star is not None and rec.k_star <= 1.0 else 0)
    assert rec.d_measured_s == pytest.approx(base.measured_d_s)
    # The synthetic run's 40 ms stall (and its start) put D past D* by the system's own
    # timing, and its lost commands leave 1.3 % of the samples without one: FAIL.
    assert main(["report", str(folder)]) == expected_exit("FAIL", command="report")
    verdict = json.loads((folder / "report.json").read_text())["verdict"]
    assert fails("certificate_system", "samples_without_command").check(verdict) is None, verdict
    text = (folder / "report.md").read_text()
    assert "Timing margin" in text and "ratio" in text
    margin = json.loads((folder / "report.json").read_text())["margin"]  # k* in report.json
    assert margin["k_star"] == rec.k_star and margin["k_held"] == rec.k_held


def test_record_round_trip_and_unreadable_files(tmp_path):
    rec = MarginRecord(
        source="x",
        law="unified",
        disturbance="worst",
        seeds=2,
        duration_s=1.0,
        k_star=2.0,
        k_held=1.96,
        first_broken="|omega|",
        disturbance_at_break="d1 aligned; d2 outward",
        d_measured_s=0.02,
        d_replay_s=0.02,
        age_at_break_s=0.04,
        d_star_s=0.02,
        probes=(MarginProbe(2.0, 1.1, "|omega|", True, 0.04, "d1 aligned; d2 outward"),),
    )
    record.write(tmp_path, rec)
    assert record.read(tmp_path) == rec
    data = json.loads((tmp_path / "margin.json").read_text())
    assert data["conservatism"] == 2.0 and np.isfinite(data["k_star"])
    lines = record.summary_lines(record.read(tmp_path))
    assert "k* = 2" in lines[0] and "|omega| at k = 2" in lines[0] and "ratio 2.00" in lines[2]
    (tmp_path / "margin.json").write_text("{not json")
    assert record.read(tmp_path) is None and record.read(tmp_path / "absent") is None


def test_certify_prints_d_star_and_with_empirical_the_break_and_their_ratio(tmp_path, capsys):
    path = tmp_path / "d.toml"
    path.write_text(DISTURBED)
    assert main(["certify", str(path)]) == 0
    assert "D* = 44.89" in capsys.readouterr().out
    assert main(["certify", str(path), "--json", "--empirical"]) == 0
    out = json.loads(capsys.readouterr().out)
    emp = out["empirical"]
    assert out["d_star_s"] == pytest.approx(0.0449, abs=2e-4)
    # Sound: no break below D*; and the break is found, under a named disturbance.
    assert emp["age_at_break_s"] > out["d_star_s"]
    assert emp["ratio_to_d_star"] == pytest.approx(emp["age_at_break_s"] / out["d_star_s"])
    assert emp["first_broken"] in ("|v|", "|omega|") and "d1" in emp["disturbance"]


def test_a_law_on_floats_only_runs_one_robot_at_a_time_said_once_and_law_picks_it(tmp_path, capsys):
    """A law written for one robot on floats runs on the batch path one robot at a time (as
    hil sweep runs it), the user told once; --law runs it on a scenario that names another
    law (margin.json names the law that ran)."""
    pd = "tests.example_user_controller:SaturatedPD"
    text = USER_LAW.replace("tests.margin_user_law:SaturatedTracker", pd)
    args = ("--seeds", "2", "--duration", "2")
    code, named = _margin(tmp_path, text.replace("gain = 20.0", "gain = 5.0"), "pd", *args)
    err = capsys.readouterr().err
    assert err.count("one robot at a time") == 1, err
    assert code in (0, 1) and named.law == pd and named.probes  # it ran: no refusal
    other = tmp_path / "unified.toml"
    other.write_text(DISTURBED)
    out = tmp_path / "by-option"
    main(["margin", str(other), "--law", pd, "--out", str(out), *args])
    by_option = record.read(out)
    assert by_option is not None and by_option.law == pd and by_option.probes


def test_margin_of_a_simulation_folder_is_its_scenarios_and_lands_in_its_report(tmp_path):
    """A hil sim folder has no measured timing: hil margin replays its scenario's [timing]
    (the same k* as the scenario itself), writes margin.json into it, and its report shows k*.
    A folder of neither kind is refused (exit 2) and gets no margin.json."""
    path = tmp_path / "d.toml"
    path.write_text(DISTURBED)
    sim = tmp_path / "sim"
    assert main(["sim", str(path), "--out", str(sim)]) == 0  # its limits held at its timing
    code = main(["margin", str(sim), "--seeds", "4"])
    rec = record.read(sim)
    assert rec is not None and rec.source.startswith("scenario timing")
    _, own = _margin(tmp_path, DISTURBED, "own", "--seeds", "4")
    assert rec.k_star == own.k_star and rec.k_held == own.k_held and rec.k_star is not None
    assert code == (1 if rec.k_star <= 1.0 else 0)
    assert main(["report", str(sim)]) == expected_exit("PASS", command="report")
    judged = json.loads((sim / "report.json").read_text())
    assert PASSES.check(judged["verdict"]) is None, judged["verdict"]
    assert judged["margin"]["k_star"] == rec.k_star
    assert "Timing margin k* =" in (sim / "report.md").read_text()
    empty = tmp_path / "empty"
    empty.mkdir()
    assert main(["margin", str(empty)]) == 2 and record.read(empty) is None
