"""A broken law is a FAIL of the law: in sim, sweep, margin, run and fleet alike.

Three user laws, written by each test into its own folder (a working law from ``hil new-law``
and three subclasses of it): ``nan_law`` returns tau1 = NaN from t = 1 s, ``raise_law`` raises
ZeroDivisionError from t = 1 s (on floats), ``tuple_law`` returns a tuple instead of a
ControlOutput from its first call. Every command must end with exit 1 and one sentence naming
the law, the time, the input and the exception (docs/own-controller.md, "When your law
fails"); never PASS, never INCONCLUSIVE, never "a fault of hil" (exit 3). A state that became
non-finite is never "limits held" either (plant_emulator.dynamics.Extremes).
"""

from __future__ import annotations

import json
import math
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from controller_service.laws.base import ControlOutput, ReferenceSample, RobotState
from controller_service.laws.guard import LawFault, LawFaultError, checked_update
from hil.bench.lifecycle import GONE_GRACE_S
from hil.law.template import write_law
from hil.scenario import loads_scenario
from hil.sim import RobotVariation, simulate, simulate_batch
from hil.verdict import BENCH_ADVICE, FAIL, LawEnd, judge, law_ended
from plant_emulator.disturbances import Disturbance
from plant_emulator.dynamics import Extremes, PlantState, rk4_array, rk4_float
from protocol.robot import Limits
from tests.procs import wait_until
from tests.scenario_text import CIRCLE, NEAR, toml_text

HIL = str(Path(sys.executable).with_name("hil"))

NAN_LAW = """from base_law import BaseLaw, ControlOutput
class NanLaw(BaseLaw):
    name = "nan_law"
    def update(self, t, dt, state, ref, memory):
        out, mem = super().update(t, dt, state, ref, memory)
        if t > 1.0:
            return ControlOutput(float("nan") * out.tau1, out.tau2, out.telemetry), mem
        return out, mem
"""
RAISE_LAW = """from base_law import BaseLaw
class RaiseLaw(BaseLaw):
    name = "raise_law"
    def update(self, t, dt, state, ref, memory):
        if (t > 1.0) if isinstance(t, float) else False:
            raise ZeroDivisionError("my bug")
        return super().update(t, dt, state, ref, memory)
"""
TUPLE_LAW = """from base_law import BaseLaw
class TupleLaw(BaseLaw):
    name = "tuple_law"
    def update(self, t, dt, state, ref, memory):
        out, mem = super().update(t, dt, state, ref, memory)
        return (out.tau1, out.tau2), mem
"""
# Built by hil (its checks) but not in the controller process: a file only hil's folder has.
BUILD_LAW = """import sys
from base_law import BaseLaw
class BuildLaw(BaseLaw):
    name = "build_law"
    def __init__(self, *args, **kwargs):
        if "controller_service" in sys.argv[0]:
            raise FileNotFoundError("calibration.json")
        super().__init__(*args, **kwargs)
"""
# module -> (source, class, kind, what the sentence says it did, law time of the first fault)
LAWS = {
    "nan_law": (NAN_LAW, "NanLaw", "non_finite", "returned a non-finite torque tau1 = nan", 1.0),
    "raise_law": (RAISE_LAW, "RaiseLaw", "exception", "raised ZeroDivisionError('my bug')", 1.0),
    "tuple_law": (
        TUPLE_LAW,
        "TupleLaw",
        "wrong_type",
        "returned (tuple, ...) instead of (ControlOutput, memory)",
        0.0,
    ),
}
STATE_WORDS = r"for the state x = \S+, y = \S+, theta = \S+, v = \S+, omega = \S+"


def _laws(folder: Path) -> Path:
    """The working law of ``hil new-law`` and the three broken ones, in ``folder``."""
    write_law("base_law", folder)
    for module, (source, *_) in LAWS.items():
        (folder / f"{module}.py").write_text(source)
    return folder


def _scenario(folder: Path, module: str, duration: float) -> Path:
    """The paper's circle run by ``module``'s law (its module beside the scenario)."""
    law = f"{module}:{LAWS[module][1]}"
    text = toml_text(
        reference=CIRCLE,
        initial=NEAR,
        controller={"law": law},
        timing={"ts": 0.002},
        run={"duration": duration},
    )
    path = folder / f"{module}.toml"
    path.write_text(text)
    return path


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env.pop("PYTHONPATH", None)  # the laws are found as a user's are: beside, or in the cwd
    return env


def _hil(*args: str, cwd: Path, timeout: float = 180) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [HIL, *args], cwd=cwd, env=_env(), capture_output=True, text=True, timeout=timeout
    )


def _check_sentence(text: str, module: str, details: str) -> float:
    """The sentence names the law, its class, what it did, the time and the state; returns
    the time it names."""
    _, cls, _, did, _ = LAWS[module]
    head = f"the law {module} ({module}:{cls}) {did} at t = "
    assert head in text, text
    rest = text[text.index(head) + len(head) :]
    m = re.match(r"(\S+) s " + STATE_WORDS + r" \((traceback|details) in " + details + r"\)", rest)
    assert m is not None, rest
    return float(m.group(1))


def _check_time(t: float, module: str, ts: float) -> None:
    """The first sample past the law's fault time (t > 1.0 for two of them, t = 0 for one)."""
    start = LAWS[module][4]
    assert start <= t <= start + ts + 1e-9, (module, t)


def _check_record(record: dict, module: str) -> None:
    _, cls, kind, _, _ = LAWS[module]
    assert (record["law"], record["where"], record["kind"]) == (module, f"{module}:{cls}", kind)
    assert set(record["state"]) == {"x", "y", "theta", "v", "omega"}
    assert all(isinstance(v, float) for v in record["state"].values())
    if kind == "exception":  # the traceback reaches into the user's file
        assert (
            f"{module}.py" in record["traceback"]
            and "ZeroDivisionError: my bug" in (record["traceback"])
        )
    else:
        assert record["traceback"] == ""


# --- the guard, on one call ------------------------------------------------------------------


class _Returns:
    name = "returns"

    def __init__(self, result):  # type: ignore[no-untyped-def]
        self.result = result

    def update(self, t, dt, state, ref, memory):  # type: ignore[no-untyped-def]
        if isinstance(self.result, Exception):
            raise self.result
        return self.result


STATE = RobotState(0.5, -0.25, 0.125, 1.0, 0.0625)
REF = ReferenceSample(0.0, 0.0, 0.0, 0.5, 0.2)


@pytest.mark.parametrize(
    ("result", "kind", "detail"),
    [
        ((ControlOutput(math.nan, 0.0, {}), 0), "non_finite", "tau1 = nan"),
        ((ControlOutput(0.0, -math.inf, {}), 0), "non_finite", "tau2 = -inf"),
        (KeyError("gain"), "exception", "KeyError('gain')"),
        (((0.0, 0.0), 0), "wrong_type", "(tuple, ...)"),
        (ControlOutput(0.0, 0.0, {}), "wrong_type", "a ControlOutput of 3"),
        ((ControlOutput("1", 0.0, {}), 0), "wrong_type", "a torque tau1 of type str"),
        ((ControlOutput(0.0, 0.0, [1.0]), 0), "wrong_type", "telemetry is a list"),
    ],
)
def test_the_guard_names_the_law_the_time_the_input_and_what_went_wrong(result, kind, detail):
    with pytest.raises(LawFaultError) as err:
        checked_update(_Returns(result), 2.5, 0.01, STATE, REF, 0)
    f = err.value.fault
    assert (f.law, f.where, f.kind, f.t_s) == (
        "returns",
        "tests.test_law_faults:_Returns",
        kind,
        2.5,
    )
    assert detail in f.detail
    assert f.state == {"x": 0.5, "y": -0.25, "theta": 0.125, "v": 1.0, "omega": 0.0625}
    assert f.reference["vd"] == 0.5
    words = f.sentence()
    assert words.startswith("the law returns (tests.test_law_faults:_Returns) ")
    assert (
        "at t = 2.5 s for the state x = 0.5, y = -0.25, theta = 0.125, v = 1, omega = 0.0625 ("
        in words
    )
    assert LawFault.from_dict(json.loads(json.dumps(f.to_dict()))) == f


def test_the_guard_names_the_first_robot_of_a_batch_whose_torque_is_not_finite():
    out = ControlOutput(np.array([1.0, 2.0, np.nan, np.nan]), np.zeros(4), {})
    state = RobotState(*(np.arange(4.0) + k for k in range(5)))
    with pytest.raises(LawFaultError) as err:
        checked_update(_Returns((out, 0)), np.full(4, 0.5), 0.01, state, REF, 0)
    f = err.value.fault
    assert (f.robot, f.detail, f.t_s, f.state["x"], f.state["omega"]) == (
        2,
        "tau1 = nan",
        0.5,
        2.0,
        6.0,
    )


# --- a non-finite state is never "limits held" -----------------------------------------------


def _steps(s, cmd1, t0, h, n, ext, step0=None):  # type: ignore[no-untyped-def]
    return rk4_float(s, cmd1, 0.0, t0, h, n, Disturbance(), 0.0, None, Limits(), ext, step0)


def test_extremes_count_the_non_finite_steps_of_one_robot_and_keep_the_nan():
    """A NaN torque: every step from the first is non-finite; the peaks are NaN, not the last
    finite value; no violation is counted for NaN (the count is what says so)."""
    ext = Extremes()
    s = _steps(PlantState(0, 0, 0, 0.5, 0.1), 1.0, 0.0, 0.001, 10, ext, 0)
    assert ext.nonfinite_steps == 0 and math.isnan(ext.nonfinite_first_t)
    assert ext.max_abs_v > 0.5
    s = _steps(s, math.nan, 0.01, 0.001, 10, ext, 10)
    assert ext.nonfinite_steps == 10
    assert ext.nonfinite_first_t == pytest.approx(0.011)  # the end of step 10 (the 11th)
    assert math.isnan(ext.max_abs_v) and math.isnan(ext.max_abs_tau1)
    assert ext.violations_v == 0 and ext.violations_tau1 == 0
    _steps(s, 0.0, 0.02, 0.001, 5, ext, 20)  # a finite torque cannot bring it back
    assert ext.nonfinite_steps == 15 and ext.nonfinite_first_t == pytest.approx(0.011)
    assert ext.nonfinite_first_t_s() == pytest.approx(0.011)


def test_extremes_find_the_first_step_that_overflows_inside_a_call():
    """A finite but huge torque overflows the state at a step inside one call: the count
    starts at that step, as counting step by step finds it."""
    ext, by_step = Extremes(), Extremes()
    _steps(PlantState(0, 0, 0, 0, 0), 2.5e307, 0.0, 1.0, 20, ext)
    s, first = PlantState(0, 0, 0, 0, 0), None
    for k in range(20):
        s = _steps(s, 2.5e307, float(k), 1.0, 1, by_step)
        if first is None and not all(map(math.isfinite, s)):
            first = k
    assert first is not None and 0 < first < 19  # inside the call, not at its ends
    assert ext.nonfinite_steps == by_step.nonfinite_steps == 20 - first
    assert ext.nonfinite_first_t == by_step.nonfinite_first_t == first + 1.0


@pytest.mark.filterwarnings("ignore:invalid value encountered:RuntimeWarning")  # NaN, on purpose
def test_extremes_on_arrays_count_only_the_robots_that_went_non_finite():
    ext = Extremes.zeros(3)
    z = np.zeros(3)
    start = PlantState(z, z, z, np.array([0.5, 0.5, np.inf]), z, z, z)  # robot 2 starts bad
    cmd1 = np.array([1.0, np.nan, 1.0])  # robot 1: a NaN torque
    rk4_array(start, cmd1, z, 0.0, 0.001, 8, Disturbance(), 0.0, None, Limits(), ext, 0)
    assert ext.nonfinite_steps.tolist() == [0, 8, 8]
    assert np.isnan(ext.nonfinite_first_t[0])
    assert ext.nonfinite_first_t[1:] == pytest.approx(0.001)
    assert math.isfinite(ext.max_abs_v[0]) and not np.isfinite(ext.max_abs_v[1:]).any()


class _Huge:
    """A finite torque that overflows the plant: no fault of the guard, a non-finite state."""

    name = "huge"

    def initial_memory(self, n=None, z1=0.0, z2=0.0):  # type: ignore[no-untyped-def]
        return 0

    def update(self, t, dt, state, ref, memory):  # type: ignore[no-untyped-def]
        return ControlOutput(1.7e308 if t >= 0.05 else 0.0, 0.0, {}), memory


def _circle(ts: float, duration: float):  # type: ignore[no-untyped-def]
    text = toml_text(reference=CIRCLE, initial=NEAR, timing={"ts": ts}, run={"duration": duration})
    return loads_scenario(text, Path("."))


def test_a_simulation_whose_state_became_non_finite_is_never_limits_held():
    sc = _circle(0.01, 0.2)
    s = simulate(sc, loop=(_Huge(), *_loop_rest(sc))).summary
    # the torque lands at t = 0.05 s; its first plant step (h = Ts / 10) ends at 0.051 s
    assert s["nonfinite_steps"] == 150 and s["nonfinite_first_t_s"] == pytest.approx(0.051)
    assert s["limits_held"] is False and "law_fault" not in s
    assert not math.isfinite(s["max_abs_v"])
    assert law_ended(s) == (
        "the robot's state became non-finite at t = 0.051 s (150 plant steps): the limits of "
        "(2) cannot hold"
    )


def _loop_rest(sc):  # type: ignore[no-untyped-def]
    from hil.scenario import build_loop

    _, reference, context = build_loop(sc)
    return reference, context


# --- the verdict -------------------------------------------------------------------------------


def test_the_verdict_fails_first_on_a_law_fault_a_dead_controller_or_a_non_finite_state():
    fault = LawFault("nan_law", "nan_law:NanLaw", "non_finite", 1.001, {"x": 0.5}, {}, "tau1 = nan")
    bench = {"t_s": 1.2, "age_s": 0.5, "cause": "host_stalled", "owner": "bench"}
    cert = {"d_max_s": 0.5, "d_star_s": 0.02, "d_system_s": 0.01, "held": False, "stalls": [bench]}
    cases = {
        "law": ({"law_fault": fault.to_dict()}, fault.sentence()),
        "killed": (
            {"controller_exit": {"code": None, "signal": "SIGKILL", "t_s": 2.5}},
            "the controller process was killed by signal SIGKILL at t = 2.500 s; its output: "
            "controller.log",
        ),
        "exited": (
            {"controller_exit": {"code": 1, "signal": None, "t_s": 0.25}},
            "the controller process exited with code 1 at t = 0.250 s; its output: controller.log",
        ),
        "nan": (
            {"nonfinite_steps": 7, "nonfinite_first_t_s": 0.5},
            "the robot's state became non-finite at t = 0.5 s (7 plant steps): the limits of (2) "
            "cannot hold",
        ),
    }
    for name, (summary, first) in cases.items():
        v = judge({}, {}, cert, {}, {}, None, ended=LawEnd.of(summary))
        assert v.outcome == FAIL and v.fail_reasons[0] == first, name
        if name != "nan":  # the controller ended: the bench's stall is no reason of the verdict
            assert not v.inconclusive_reasons and BENCH_ADVICE not in v.advice, name
            note = "not judged, the controller had ended: the bench stalled"
            assert any(n.startswith(note) for n in v.notes), (name, v.notes)
    # The same evidence without the end: the bench's stall makes it INCONCLUSIVE, as before.
    assert judge({}, {}, cert, {}, {}, None).outcome == "INCONCLUSIVE"


# --- the batch path: one robot's fault is that robot's -----------------------------------------


class _NanWhereFar:
    """tau1 = NaN for the robots that start beyond x = 0 (on arrays: robot by robot)."""

    name = "nan_where_far"

    def initial_memory(self, n=None, z1=0.0, z2=0.0):  # type: ignore[no-untyped-def]
        return 0.0 if n is None else np.zeros(n)

    def update(self, t, dt, state, ref, memory):  # type: ignore[no-untyped-def]
        far = np.asarray(state.x) > 0.0
        tau1 = np.where(far, np.nan, -np.asarray(state.v))
        tau2 = -np.asarray(state.omega)
        if np.ndim(state.x) == 0:
            return ControlOutput(float(tau1), float(tau2), {}), memory
        return ControlOutput(tau1, tau2, {}), memory


def test_a_non_finite_torque_on_the_batch_path_faults_that_robot_only():
    sc = _circle(0.01, 0.5)
    law = _NanWhereFar()
    robots = [RobotVariation(x=x) for x in (-1.0, 0.5, -0.5, 1.0)]
    result = simulate_batch(sc, robots, loop=(law, *_loop_rest(sc)), record=[0, 1])
    faulted = ["law_fault" in s for s in result.summaries]
    assert faulted == [False, True, False, True]
    for i in (1, 3):
        f = result.summaries[i]["law_fault"]
        assert (f["kind"], f["robot"], f["t_s"], f["state"]["x"]) == (
            "non_finite",
            i,
            0.0,
            robots[i].x,
        )
        assert result.summaries[i]["limits_held"] is False
    for i in (0, 2):  # the others ran to the end, their limits held, their torques finite
        assert result.summaries[i]["limits_held"] is True
        assert result.summaries[i]["samples"] == 50
    # the faulted robot's torque is held at zero, never NaN: its state stays finite
    assert np.isfinite(result.traces[1]).all() and (result.traces[1][:, 9:11] == 0.0).all()


# --- the commands, as a user runs them -----------------------------------------------------------


@pytest.mark.parametrize("module", list(LAWS))
def test_hil_sim_and_hil_report_fail_with_the_laws_sentence(tmp_path: Path, module: str) -> None:
    folder = _laws(tmp_path)
    cls = LAWS[module][1]
    sim = _hil(
        "sim",
        "paper_tracking",
        "--law",
        f"{module}:{cls}",
        "--duration",
        "2",
        "--out",
        "s",
        cwd=folder,
    )
    assert sim.returncode == 1, sim.stderr[-3000:]
    assert "internal error" not in sim.stderr and "Traceback" not in sim.stderr
    assert "verdict: FAIL: the law " in sim.stderr
    t = _check_sentence(sim.stderr, module, "law_fault.json")
    _check_time(t, module, 0.001)
    out = folder / "s"
    record = json.loads((out / "law_fault.json").read_text())
    _check_record(record, module)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["law_fault"] == record and summary["limits_held"] is False
    rows = (out / "trace.csv").read_text().splitlines()[1:]
    # the trace ends with the sample before the fault (the faulting one is left out)
    assert len(rows) == round(t / 0.001)
    report = _hil("report", "s", cwd=folder)
    assert report.returncode == 1, report.stderr[-3000:]
    _check_sentence(report.stderr, module, "law_fault.json")
    if len(rows) >= 2:
        verdict = json.loads((out / "report.json").read_text())["verdict"]
        assert (
            verdict["outcome"] == "FAIL"
            and verdict["reasons"][0] == LawFault.from_dict(record).sentence()
        )


@pytest.mark.parametrize("module", list(LAWS))
def test_hil_sweep_marks_the_points_where_the_law_failed_and_exits_1(
    tmp_path: Path, module: str
) -> None:
    folder = _laws(tmp_path)
    cls = LAWS[module][1]
    sweep = _hil(
        "sweep", "paper_tracking", "--law", f"{module}:{cls}", "--duration", "1.5",
        "--ts", "0.01,0.02", "--delay", "0,0.01", "--out", "w", cwd=folder,
    )  # fmt: skip
    assert sweep.returncode == 1, sweep.stderr[-3000:]
    assert "held everywhere" not in sweep.stdout and "internal error" not in sweep.stderr
    assert "law fault at 4 of 4 points" in sweep.stdout
    t = _check_sentence(sweep.stdout, module, "sweep.json")
    _check_time(t, module, 0.01)
    doc = json.loads((folder / "w" / "sweep.json").read_text())
    bp = doc["break_point"]
    assert bp["held_everywhere"] is False and bp["law_faults"] == 4
    assert all(
        r["law_fault"] and r["law_fault"].startswith(f"the law {module} ") for r in doc["rows"]
    )
    _check_record(doc["law_fault"], module)
    csv_rows = (folder / "w" / "sweep.csv").read_text().splitlines()
    assert "law_fault" in csv_rows[0].split(",") and all(
        f"the law {module}" in r for r in csv_rows[1:]
    )
    page = (folder / "w" / "sweep.html").read_text()
    assert '<p class="answer broke">FAIL: the law failed at 4 of 4 loops' in page
    assert "law fault ✗" in page and "held in all" not in page


@pytest.mark.parametrize("module", list(LAWS))
def test_hil_margin_fails_with_the_laws_sentence(tmp_path: Path, module: str) -> None:
    folder = _laws(tmp_path)
    scenario = _scenario(folder, module, 2.0)
    margin = _hil(
        "margin", str(scenario), "--seeds", "2", "--duration", "1.5", "--out", "m", cwd=folder
    )
    assert margin.returncode == 1, margin.stderr[-3000:]
    t = _check_sentence(margin.stderr, module, "margin.json")
    _check_time(t, module, 0.002)
    record = json.loads((folder / "m" / "margin.json").read_text())
    assert record["k_star"] is None
    _check_record(record["law_fault"], module)


def _run(spawn, folder: Path, *args: str) -> tuple[int, str, str]:  # type: ignore[no-untyped-def]
    proc = spawn.start([HIL, "run", *args], cwd=folder, env=_env(), text=True)
    out, err = proc.communicate(timeout=240)
    return proc.returncode, out, err


PLANNED_S = 30.0  # a run the faults end after ~1 s: waiting it out would take 30 s


@pytest.mark.parametrize("module", list(LAWS))
def test_hil_run_ends_at_the_laws_fault_and_fails_with_its_sentence(
    spawn, tmp_path: Path, module: str
) -> None:
    folder = _laws(tmp_path)
    cls = LAWS[module][1]
    args = ("paper_tracking", "--law", f"{module}:{cls}", "--duration", str(PLANNED_S))
    code, out, err = _run(spawn, folder, *args, "--no-can", "--no-report", "--quiet", "--out", "r")
    assert code == 1, err[-3000:]
    line = next(x for x in (out + err).splitlines() if x.startswith("result: "))
    assert line.startswith("result: FAIL: the law ")
    t = _check_sentence(line, module, "law_fault.json")
    run = folder / "r"
    record = json.loads((run / "law_fault.json").read_text())
    _check_record(record, module)
    assert record["t_s"] == pytest.approx(t, abs=5e-4)
    # The run's law clock is the plant's sample time: the fault comes at the first sample the
    # controller computes past the law's threshold (within a few periods of it on a busy host).
    assert LAWS[module][4] <= record["t_s"] <= LAWS[module][4] + 0.5
    s = json.loads((run / "summary.json").read_text())
    v = s["verdict"]
    assert v["outcome"] == "FAIL" and v["reasons"][0] == LawFault.from_dict(record).sentence()
    assert not v["inconclusive_reasons"] and not v["advice"]
    assert s["law_fault"] == record and s["exit_codes"]["controller"] == 5
    assert s["controller_exit"]["code"] == 5 and s["controller_exit"]["law_fault"] is True
    # Causal bound: hil run stops the run when the controller process exits (it polls every
    # 50 ms); waiting out the planned duration would make the plant's window ~30 s. Half of
    # it leaves a loaded host 14 s for the controller's exit and the plant's stop.
    assert s["duration_run_s"] < PLANNED_S / 2
    assert s["duration_planned_s"] == PLANNED_S
    assert "law fault: the law" in (run / "controller.log").read_text()


def test_hil_run_whose_law_cannot_be_built_in_the_controller_fails_naming_the_law(
    spawn, tmp_path: Path
) -> None:
    """A law that hil built but the controller process cannot (its constructor raises there):
    the law's FAIL with what it raised, at once, never the bench's "did not start"."""
    folder = _laws(tmp_path)
    (folder / "build_law.py").write_text(BUILD_LAW)
    args = ("paper_tracking", "--law", "build_law:BuildLaw", "--duration", str(PLANNED_S))
    code, out, err = _run(spawn, folder, *args, "--no-can", "--no-report", "--quiet", "--out", "b")
    assert code == 1, err[-3000:]
    said = (
        "the law build_law (build_law:BuildLaw) could not be built in the controller process: "
        "it raised FileNotFoundError('calibration.json') (traceback in law_fault.json)"
    )
    assert f"result: FAIL: {said}" in out + err
    s = json.loads((folder / "b" / "summary.json").read_text())
    assert s["verdict"]["reasons"] == [said] and not s["verdict"]["inconclusive_reasons"]
    assert s["law_fault"]["kind"] == "build" and "FileNotFoundError" in s["law_fault"]["traceback"]
    assert s["controller_exit"]["law_fault"] is True and s["bench_error"] is None


def test_hil_run_the_bench_did_not_start_is_its_inconclusive(spawn, tmp_path: Path) -> None:
    """Services that do not say ready in time (HIL_READY_TIMEOUT shorter than any start-up:
    the known answer of a host too slow to start them) are the bench's INCONCLUSIVE (exit 4)
    naming which services and their logs: never the system's FAIL."""
    env = {**_env(), "HIL_READY_TIMEOUT": "0.2"}
    args = [HIL, "run", "paper_tracking", "--duration", "5", "--no-can", "--no-report", "--quiet"]
    proc = spawn.start([*args, "--out", "n"], cwd=tmp_path, env=env, text=True)
    out, err = proc.communicate(timeout=240)
    assert proc.returncode == 4, err[-3000:]
    s = json.loads((tmp_path / "n" / "summary.json").read_text())
    why = s["bench_error"]
    assert re.fullmatch(
        r"the bench did not start the run: the plant and the controller did not say ready "
        r"within 0\.2\d* s \(still starting: a host too slow or too busy; output: plant\.log, "
        r"controller\.log\)",
        why,
    ), why
    v = s["verdict"]
    assert (v["outcome"], v["reasons"], v["fail_reasons"]) == ("INCONCLUSIVE", [why], [])
    assert s["error"] is None and f"result: INCONCLUSIVE: {why}" in out + err
    # Each service waits for its start a minute longer than hil run waits for both to be ready
    # (a plant ready long before a slow controller must not give up first).
    settings = json.loads((tmp_path / "n" / "run_settings.json").read_text())
    assert settings["start_timeout"] == pytest.approx(0.2 + 60.0)


def test_hil_run_whose_controller_is_killed_fails_naming_the_signal(spawn, tmp_path: Path) -> None:
    """A controller that dies without a law fault is the system's FAIL, never INCONCLUSIVE,
    never a stall of the bench; the run ends GONE_GRACE_S after it died (no restart came)."""
    args = ["run", "paper_tracking", "--duration", str(PLANNED_S), "--no-can", "--no-report"]
    proc = spawn.start([HIL, *args, "--quiet", "--out", "k"], cwd=tmp_path, env=_env(), text=True)
    log = tmp_path / "k" / "controller.log"
    started = wait_until(lambda: log.is_file() and "running epoch_ns" in log.read_text(), 120)
    assert started, proc.stderr
    # The epoch is announced 0.3 s ahead: a second on, the kill lands inside the run (any later
    # moment would do as well).
    time.sleep(1.0)
    pid = json.loads((tmp_path / "k" / "processes.json").read_text())["controller"]
    os.kill(pid, signal.SIGKILL)
    out, err = proc.communicate(timeout=240)
    assert proc.returncode == 1, err[-3000:]
    s = json.loads((tmp_path / "k" / "summary.json").read_text())
    v = s["verdict"]
    assert v["outcome"] == "FAIL", v
    first = v["reasons"][0]
    assert re.fullmatch(
        r"the controller process was killed by signal SIGKILL at t = \d+\.\d{3} s; its output: "
        r"controller\.log",
        first,
    ), first
    assert not v["inconclusive_reasons"] and not v["advice"]
    assert s["controller_exit"]["signal"] == "SIGKILL" and "law_fault" not in s
    # Causal: the plant runs on GONE_GRACE_S (3 s) after the death is seen, then the run stops;
    # the planned 30 s would be waited out otherwise (15 s: 11 s of slack for a loaded host).
    # Both on the run's clock (from its epoch): the plant's last sample is taken after the grace
    # (less a plant stall of up to 0.5 s on a loaded host, when it meets the stop asleep).
    rows = (tmp_path / "k" / "trace.csv").read_text().splitlines()
    last_t, dead_t = float(rows[-1].split(",")[0]), s["controller_exit"]["t_s"]
    assert dead_t + GONE_GRACE_S - 0.5 <= last_t < PLANNED_S / 2, (dead_t, last_t)
    assert s["duration_run_s"] < PLANNED_S / 2
    assert "result: FAIL: the controller process was killed by signal SIGKILL" in out + err


def test_hil_fleet_fails_the_robot_whose_law_failed(tmp_path: Path) -> None:
    folder = _laws(tmp_path)
    scenario = _scenario(folder, "nan_law", PLANNED_S)
    fleet = _hil(
        "fleet", str(scenario), "--robots", "2", "--per-process", "2", "--out", "f", cwd=folder,
        timeout=300,
    )  # fmt: skip
    assert fleet.returncode == 1, fleet.stderr[-3000:]
    assert "robot1: the law nan_law (nan_law:NanLaw) returned a non-finite torque" in fleet.stderr
    doc = json.loads((folder / "f" / "fleet.json").read_text())
    assert doc["fleet"]["passed"] == 0
    for row in doc["per_robot"]:
        assert row["verdict"] == "FAIL" and row["exit_code"] == 1
        _check_sentence(row["reason"], "nan_law", "law_fault.json")
        _check_record(
            json.loads((folder / "f" / row["robot"] / "law_fault.json").read_text()), "nan_law"
        )
    assert "Why (each robot's first reason):" in (folder / "f" / "fleet.md").read_text()
