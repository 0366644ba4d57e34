"""A user's own law: ``hil new-law``, the law found without PYTHONPATH, ``--law`` on run, sim
and sweep, and a law that takes only floats on the batch path (docs/own-controller.md)."""

from __future__ import annotations

import dataclasses
import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from controller_service.laws.base import DesignContext
from controller_service.registry import build_controller
from hil.bundled import resolve_scenario
from hil.commands.new_law import LAW_HELP
from hil.errors import BadInputError
from hil.law.batch import PerRobot, batch_note, for_batch
from hil.law.option import with_law
from hil.scenario import build_loop, load_scenario
from hil.sim import RobotVariation, simulate, simulate_batch
from tests.run_helpers import PASSES, check_verdict, clean_scenario

ROOT = Path(__file__).resolve().parents[1]

HIL = str(Path(sys.executable).with_name("hil"))  # the console script a user runs
SCALAR_LAW = "tests.example_user_controller:SaturatedPD"  # math on floats only


def _env() -> dict[str, str]:
    """The user's environment: no PYTHONPATH, so nothing but hil's own lookup finds a law."""
    env = dict(os.environ)
    env.pop("PYTHONPATH", None)
    return env


def _hil(*args: str, cwd: Path, timeout: float = 120) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [HIL, *args], cwd=cwd, env=_env(), capture_output=True, text=True, timeout=timeout
    )


def test_new_law_writes_a_law_whose_own_test_passes(tmp_path: Path) -> None:
    made = _hil("new-law", "my_first_law", "--dir", "laws", cwd=tmp_path)
    assert made.returncode == 0, made.stderr
    folder = tmp_path / "laws"
    assert (folder / "my_first_law.py").is_file() and (folder / "test_my_first_law.py").is_file()
    assert "--law my_first_law:MyFirstLaw" in made.stdout
    # The written test, as the user runs it: in a fresh process, from the law's folder.
    test = subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "test_my_first_law.py"],
        cwd=folder,
        env=_env(),
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert test.returncode == 0, test.stdout[-3000:] + test.stderr[-2000:]
    assert "4 passed" in test.stdout, test.stdout[-2000:]


@pytest.mark.parametrize(
    ("name", "words"),
    [("My-Law", "Python module name"), ("class", "Python module name"), ("numpy", "installed")],
)
def test_new_law_refuses_a_name_the_bench_could_not_import(
    tmp_path: Path, name: str, words: str
) -> None:
    proc = _hil("new-law", name, cwd=tmp_path)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr
    assert len(proc.stderr.splitlines()) == 1 and words in proc.stderr, proc.stderr
    assert list(tmp_path.iterdir()) == []


def test_new_law_does_not_overwrite_without_force(tmp_path: Path) -> None:
    assert _hil("new-law", "kept_law", cwd=tmp_path).returncode == 0
    (tmp_path / "kept_law.py").write_text("# mine\n")
    again = _hil("new-law", "kept_law", cwd=tmp_path)
    assert again.returncode == 2 and "--force" in again.stderr, again.stderr
    assert (tmp_path / "kept_law.py").read_text() == "# mine\n"
    assert _hil("new-law", "kept_law", "--force", cwd=tmp_path).returncode == 0
    assert "class KeptLaw" in (tmp_path / "kept_law.py").read_text()
    # python -m hil puts the working directory on the path: the user's own kept_law.py there
    # is not "an installed module of that name"
    again = subprocess.run(
        [sys.executable, "-m", "hil", "new-law", "kept_law", "--force"],
        cwd=tmp_path, env=_env(), capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert again.returncode == 0, again.stderr


def test_a_law_next_to_the_scenario_is_found_from_another_folder(tmp_path: Path) -> None:
    project, elsewhere = tmp_path / "project", tmp_path / "elsewhere"
    elsewhere.mkdir()
    assert _hil("new-law", "beside_law", "--dir", str(project), cwd=tmp_path).returncode == 0
    text = resolve_scenario("paper_tracking").read_text()
    text = text.replace('law = "unified"', 'law = "beside_law:BesideLaw"')
    for key in ("m1", "m2", "l1", "l2", "lam", "rho"):  # the unified law's gains
        text = "\n".join(line for line in text.splitlines() if not line.startswith(f"{key} ="))
    (project / "scenario.toml").write_text(text)
    out = elsewhere / "sim"
    proc = _hil("sim", str(project / "scenario.toml"), "--duration", "1", "--out", str(out),
                cwd=elsewhere)  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    summary = json.loads((out / "summary.json").read_text())
    assert summary["law"] == "beside_law"


@pytest.mark.realtime
def test_a_law_in_the_working_directory_runs_in_hil_run(tmp_path: Path) -> None:
    """hil run: the controller is another process; it finds the law through the run's
    settings (law_path), not through its own working directory or PYTHONPATH."""
    assert _hil("new-law", "cwd_law", cwd=tmp_path).returncode == 0
    out = tmp_path / "run"
    # A clean run (CLEAN_50HZ) with the template's law: it keeps the limits, PASS.
    scenario = str(clean_scenario(tmp_path))
    proc = _hil("run", scenario, "--law", "cwd_law:CwdLaw", "--duration", "1", "--no-report",
                "--quiet", "--out", str(out), cwd=tmp_path, timeout=180)  # fmt: skip
    assert (out / "summary.json").is_file(), proc.stderr[-3000:]
    check_verdict(json.loads((out / "summary.json").read_text()), PASSES, proc.returncode, out)
    settings = json.loads((out / "run_settings.json").read_text())
    assert settings["controller"] == {"law": "cwd_law:CwdLaw"}
    assert str(tmp_path.resolve()) in settings["law_path"]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["messages"]["torque_zenoh"]["received"] > 0, summary["messages"]
    assert "cwd_law" in (out / "scenario.resolved.toml").read_text()
    # The run is over: its report and a comparison need the law no more.
    _move_law_away(tmp_path, "cwd_law")
    _report_and_compare_without_the_law(tmp_path, out, "cwd_law:CwdLaw")


def _move_law_away(folder: Path, name: str) -> None:
    """The user's module leaves the folder (renamed, deleted, another machine): not even a
    compiled copy stays where the bench looks."""
    (folder / f"{name}.py").rename(folder / f"{name}.py.moved")
    shutil.rmtree(folder / "__pycache__", ignore_errors=True)


def _report_and_compare_without_the_law(cwd: Path, folder: Path, law: str) -> None:
    """hil report and hil compare of ``folder`` in full, from ``cwd`` where ``law`` was found
    when it ran and is not found now, even asked to run it again (--ideal): the ideal
    trajectory, the one fresh simulation, left out with why."""
    report = _hil("report", str(folder), "--ideal", cwd=cwd)
    assert "Traceback" not in report.stderr, report.stderr[-3000:]
    data = json.loads((folder / "report.json").read_text())
    # The verdict's exit, never 2: both folders here (a clean run, the template's simulation
    # of the paper's circle) are PASS.
    check_verdict(data, PASSES, report.returncode, folder, command="report")
    assert data["scenario"]["law"] == law
    note = data["metrics"]["deviation_from_ideal_note"]
    assert note.startswith("not computed") and "not found here" in note, note
    assert {"headline", "verdict", "trajectory", "tracking_error"} <= set(data["sections"])
    assert data["metrics"]["tracking"]["final_position_error"] >= 0.0
    html = (folder / "report.html").read_text()
    assert html.count("data:image/png;base64,") >= 5  # every figure drawn from the folder
    baseline = cwd / "baseline"
    sim = _hil("sim", "paper_tracking", "--duration", "1", "--out", str(baseline), cwd=cwd)
    assert sim.returncode == 0, sim.stderr[-3000:]
    compare = _hil("compare", str(folder), str(baseline), "--out", str(cwd / "cmp"), cwd=cwd)
    assert compare.returncode == 0 and "Traceback" not in compare.stderr, compare.stderr[-3000:]
    rows = {r["figure"]: r for r in json.loads((cwd / "cmp" / "compare.json").read_text())["rows"]}
    assert rows["summary.max_abs_v"]["a"] > 0.0 and rows["summary.max_abs_v"]["b"] > 0.0


def test_report_and_compare_of_a_users_law_need_no_module_after_the_run(tmp_path: Path) -> None:
    """The report never imports the user's module on its own; asked (--ideal), it finds it as
    the simulation did (no PYTHONPATH) and simulates the ideal trajectory with it; once the
    module is gone, report and compare still read the whole folder."""
    assert _hil("new-law", "moved_law", cwd=tmp_path).returncode == 0
    marker = tmp_path / "imported.txt"  # the module leaves a mark each time it is imported
    with (tmp_path / "moved_law.py").open("a") as module:
        module.write(f"\nopen({str(marker)!r}, 'a').write('imported\\n')\n")
    out = tmp_path / "runs" / "moved"
    sim = _hil("sim", "paper_tracking", "--law", "moved_law:MovedLaw", "--duration", "2",
               "--out", str(out), cwd=tmp_path)  # fmt: skip
    # The template's law keeps the paper's limits on its circle: a simulation that holds them.
    assert sim.returncode == 0 and marker.is_file(), sim.stderr[-3000:]
    marker.unlink()

    def note() -> str:
        return json.loads((out / "report.json").read_text())["metrics"]["deviation_from_ideal_note"]

    report = _hil("report", str(out), cwd=tmp_path)
    judged = json.loads((out / "report.json").read_text())
    check_verdict(judged, PASSES, report.returncode, out, command="report")
    assert not marker.exists(), "the report imported the user's module on its own"
    assert note().startswith("not computed") and "--ideal" in note(), note()
    report = _hil("report", str(out), "--ideal", cwd=tmp_path)
    judged = json.loads((out / "report.json").read_text())
    check_verdict(judged, PASSES, report.returncode, out, command="report")
    assert marker.is_file() and note().startswith("simulated at Ts/10"), note()
    _move_law_away(tmp_path, "moved_law")
    _report_and_compare_without_the_law(tmp_path, out, "moved_law:MovedLaw")


def test_a_missing_law_says_where_it_looked(tmp_path: Path) -> None:
    proc = _hil("sim", "paper_tracking", "--law", "not_here_law:X", "--out", "o", cwd=tmp_path)
    assert proc.returncode == 2 and len(proc.stderr.splitlines()) == 1, proc.stderr
    assert "cannot import 'not_here_law'" in proc.stderr
    assert str(tmp_path.resolve()) in proc.stderr  # the working directory was searched
    assert not (tmp_path / "o").exists()


def test_law_path_lookup_in_process(tmp_path: Path) -> None:
    (tmp_path / "path_law_mod.py").write_text(
        "from tests.example_user_controller import SaturatedPD as Law\n"
    )
    with pytest.raises(ValueError, match=r"cannot import 'path_law_mod'.*looked in"):
        build_controller({"law": "path_law_mod:Law"}, DesignContext(), law_path=())
    law = build_controller({"law": "path_law_mod:Law"}, DesignContext(), [str(tmp_path)])
    assert law.name == "saturated_pd"


def test_law_option_is_the_same_wherever_a_law_runs(tmp_path: Path) -> None:
    """--law on every command that runs a law (margin and fleet included), and a fleet's
    --law reaches each robot, one hil run each or K robots a process."""
    import typer.main

    from hil.bench.fleet.spawner import FleetOptions, group_argv, run_argv
    from hil.bench.group import GroupSpec
    from hil.bench.prepare import RunOptions
    from hil.cli import app

    group = typer.main.get_command(app)
    for name in ("run", "sim", "sweep", "margin", "fleet"):
        params = {p.name: p for p in group.commands[name].params}  # type: ignore[attr-defined]
        assert params["law"].opts == ["--law"] and params["law"].help == LAW_HELP, name
    opts = FleetOptions(RunOptions(Path("s.toml"), law="my_law:MyLaw"), 2, tmp_path)
    argv = run_argv(opts, "robot1")
    assert argv[argv.index("--law") + 1] == "my_law:MyLaw"
    spec = GroupSpec.read(Path(group_argv(opts, ["robot1", "robot2"])[-1]))
    assert spec.options("robot1").law == "my_law:MyLaw"


def test_law_option_replaces_the_table_unless_it_names_the_same_law() -> None:
    sc = load_scenario(resolve_scenario("paper_tracking"))
    assert with_law(sc, None) is sc and with_law(sc, "unified") is sc
    assert with_law(sc, "jiang1997").controller == {"law": "jiang1997"}
    with pytest.raises(BadInputError, match="--law"):
        with_law(sc, "not a law")


def _short(law: str, ts: float = 0.01, duration: float = 2.0):  # type: ignore[no-untyped-def]
    sc = with_law(load_scenario(resolve_scenario("paper_tracking")), law)
    return sc.with_overrides(duration=duration, ts=ts)


def test_a_float_only_law_runs_one_robot_at_a_time_on_the_batch_path() -> None:
    sc = _short(SCALAR_LAW)
    controller, reference, _ = build_loop(sc)
    assert isinstance(for_batch(controller, sc, reference), PerRobot)
    assert "one robot at a time" in (batch_note(controller, sc, reference) or "")
    variations = [RobotVariation(delay=d) for d in (0.0, 0.02)]
    batch = simulate_batch(sc, variations)
    for i, v in enumerate(variations):
        single = simulate(
            dataclasses.replace(sc, timing=dataclasses.replace(sc.timing, delay=v.delay))
        )
        for key in ("final_position_error", "max_abs_v", "max_abs_tau1"):
            assert np.isclose(batch.summaries[i][key], single.summary[key], rtol=1e-9), key


def test_an_array_law_is_not_wrapped() -> None:
    sc = _short("jiang1997")
    controller, reference, _ = build_loop(sc)
    assert for_batch(controller, sc, reference) is controller
    assert batch_note(controller, sc, reference) is None


class _FirstRobotOnly:
    """Takes arrays without an error but gives every robot the first one's torque."""

    name = "first_only"

    def initial_memory(self, n=None, z1=0.0, z2=0.0):  # type: ignore[no-untyped-def]
        return None

    def update(self, t, dt, state, ref, memory):  # type: ignore[no-untyped-def]
        from controller_service.laws.base import ControlOutput

        v = float(np.ravel(state.v)[0])
        return ControlOutput(-v, 0.0, {}), memory


class _Broken(_FirstRobotOnly):
    def update(self, t, dt, state, ref, memory):  # type: ignore[no-untyped-def]
        raise ZeroDivisionError("my bug")


def test_a_law_that_mixes_robots_up_or_fails_is_caught_before_the_loop() -> None:
    """A law that fails even on one robot is a fault of the law, not bad input: the
    batch path runs it robot by robot, so each robot meets its own fault with its own input."""
    sc = _short(SCALAR_LAW)
    _, reference, _ = build_loop(sc)
    wrapped = for_batch(_FirstRobotOnly(), sc, reference)
    assert isinstance(wrapped, PerRobot) and "other torques" in wrapped.reason
    broken = for_batch(_Broken(), sc, reference)
    assert isinstance(broken, PerRobot) and broken.probe_fault is not None
    assert broken.probe_fault.detail == "ZeroDivisionError('my bug')"


def test_hil_sweep_with_a_float_only_law_says_so_and_finishes(tmp_path: Path) -> None:
    (tmp_path / "float_law.py").write_text(
        (Path(__file__).parent / "example_user_controller.py").read_text()
    )
    proc = _hil("sweep", "paper_tracking", "--law", "float_law:SaturatedPD", "--duration", "1",
                "--ts", "0.01,0.02", "--delay", "0,0.01", "--out", "sw", cwd=tmp_path)  # fmt: skip
    assert proc.returncode == 0 and "Traceback" not in proc.stderr, proc.stderr[-3000:]
    assert "one robot at a time" in proc.stderr
    rows = (tmp_path / "sw" / "sweep.csv").read_text().splitlines()
    assert len(rows) == 1 + 4


def test_the_template_runs_on_arrays_as_it_is(tmp_path: Path) -> None:
    """hil new-law's law is written for the batch path: no robot-by-robot fallback."""
    from hil.law.template import write_law

    write_law("array_ready_law", tmp_path)
    sc = with_law(
        load_scenario(resolve_scenario("paper_tracking")), "array_ready_law:ArrayReadyLaw"
    )
    sc = dataclasses.replace(sc, base_dir=tmp_path).with_overrides(duration=1.0, ts=0.01)
    controller, reference, _ = build_loop(sc)
    assert for_batch(controller, sc, reference) is controller
    assert batch_note(controller, sc, reference) is None


def test_the_laws_test_runs_as_printed_right_after_the_readmes_install(tmp_path: Path) -> None:
    """The README's install has no pytest (requirements.lock holds none): the command that
    hil new-law prints and docs/own-controller.md gives first runs the law's test without it
    (here pytest is made unimportable, as in that install)."""
    assert not re.search(r"^pytest==", (ROOT / "requirements.lock").read_text(), re.M)
    doc = (ROOT / "docs" / "own-controller.md").read_text()
    first = next(ln for ln in doc.splitlines() if "test_my_law.py" in ln and ln.startswith("py"))
    assert first.split("#")[0].split() == ["python", "test_my_law.py"], first
    made = _hil("new-law", "law_no_pytest", cwd=tmp_path)
    assert made.returncode == 0, made.stderr
    line = next(ln for ln in made.stdout.splitlines() if ln.startswith("test it:"))
    argv = line.split(":", 1)[1].split("(")[0].split()
    assert argv == ["python", "test_law_no_pytest.py"], line
    shadow = tmp_path / "no-pytest"
    shadow.mkdir()
    (shadow / "pytest.py").write_text("raise ImportError('No module named pytest')\n")
    env = _env() | {"PYTHONPATH": str(shadow)}
    test = subprocess.run(
        [sys.executable, *argv[1:]],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert test.returncode == 0, test.stdout[-2000:] + test.stderr[-2000:]
    assert test.stdout.count("ok  test_") == 4, test.stdout
