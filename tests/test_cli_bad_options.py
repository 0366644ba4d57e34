"""Bad input at every edge: every command's options.

Each command runs as a real subprocess (``python -m hil ...``, as many at once as there are
CPUs, each in its own folder) with one bad value: negative,
zero where a positive number goes, NaN, infinity, out of range, text where a number goes, an
unknown choice, an --out that is a file. Every case must exit 2 with exactly one stderr line
naming the option, never a traceback, and leave no folder behind: the checks run before any
work (no run folder, no service process, no simulation).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
S = "paper_tracking"  # a bundled scenario: the bad value is the option, not the file

# (command line, the option the message must name); OUT is a fresh folder that must stay
# absent, FILE a regular file, SETTINGS a settings file (see the test).
CASES: list[tuple[list[str], str]] = [
    # hil sim
    (["sim", S, "--duration", "nan", "--out", "OUT"], "--duration"),
    (["sim", S, "--duration", "inf", "--out", "OUT"], "--duration"),
    (["sim", S, "--duration", "-1", "--out", "OUT"], "--duration"),
    (["sim", S, "--duration", "0", "--out", "OUT"], "--duration"),
    (["sim", S, "--duration", "1e9", "--out", "OUT"], "--duration"),
    (["sim", S, "--duration", "ten", "--out", "OUT"], "--duration"),
    (["sim", S, "--ts", "nan", "--out", "OUT"], "--ts"),
    (["sim", S, "--ts", "0", "--out", "OUT"], "--ts"),
    (["sim", S, "--ts", "-0.001", "--out", "OUT"], "--ts"),
    (["sim", S, "--ts", "100", "--out", "OUT"], "--ts"),
    (["sim", S, "--ts", "1e-9", "--out", "OUT"], "--ts"),
    (["sim", S, "--duration", "1e6", "--ts", "1e-5", "--out", "OUT"], "--duration"),
    (["sim", S, "--out", "FILE"], "--out"),
    (["sim", S, "--nope", "1"], "--nope"),
    (["sim", S, "--out", "UNWRITABLE"], "--out"),
    (["sim", S, "--law", "not a law", "--out", "OUT"], "--law"),
    (["sim", S, "--law", "no_such_law_module:Law", "--out", "OUT"], "no_such_law_module"),
    # hil run (each fails before its folder and its processes)
    (["run", "--rate", "nan", "--out", "OUT"], "--rate"),
    (["run", "--rate", "0", "--out", "OUT"], "--rate"),
    (["run", "--rate", "-5", "--out", "OUT"], "--rate"),
    (["run", "--rate", "1e6", "--out", "OUT"], "--rate"),
    (["run", "--rate", "fast", "--out", "OUT"], "--rate"),
    (["run", "--duration", "inf", "--out", "OUT"], "--duration"),
    (["run", "--duration", "0", "--out", "OUT"], "--duration"),
    (["run", "--cmd-path", "udp", "--out", "OUT"], "--cmd-path"),
    (["run", "--lockstep", "--cmd-path", "can", "--out", "OUT"], "--lockstep"),
    (["run", "--trigger", "sometimes", "--out", "OUT"], "--trigger"),
    (["run", "--can-interface", "nope", "--out", "OUT"], "--can-interface"),
    (["run", "--can-interface", "", "--out", "OUT"], "--can-interface"),
    (["run", "--can-channel", "", "--out", "OUT"], "--can-channel"),
    (["run", "--spin-us", "-1", "--out", "OUT"], "--spin-us"),
    (["run", "--spin-us", "nan", "--out", "OUT"], "--spin-us"),
    (["run", "--out", "FILE"], "--out"),
    (["run", "--out", "UNWRITABLE"], "--out"),
    (["run", "--law", "nonsense", "--out", "OUT"], "--law"),
    # hil controller / hil emulator run alone
    (["controller", S, "--endpoint", "localhost", "--out", "OUT"], "--endpoint"),
    (["emulator", S, "--can-endpoint", "", "--out", "OUT"], "--can-endpoint"),
    (["controller", S, "--epoch-ns", "-1", "--out", "OUT"], "--epoch-ns"),
    (["emulator", S, "--rate", "0", "--out", "OUT"], "--rate"),
    (["controller", S, "--duration", "nan", "--out", "OUT"], "--duration"),
    (["emulator", S, "--cmd-path", "serial", "--out", "OUT"], "--cmd-path"),
    (["controller", "--settings", "MISSING"], "--settings"),
    (["emulator", "--settings", "SETTINGS"], "--settings"),
    (["controller", "--out", "OUT"], "--settings"),
    (["emulator", S, "--out", "FILE"], "--out"),
    (["controller", S, "--write-settings", "UNWRITABLE"], "--write-settings"),
    (["emulator", S, "--write-settings", "DIR"], "--write-settings"),
    # hil drives, hil fleet (no --duration: drives that started would never end)
    (["drives", "--no-record", "--out", "UNWRITABLE"], "--out"),
    (["drives", "--record", "UNWRITABLE"], "--record"),
    (["drives", "--no-record", "--out", "FILE"], "--out"),
    (["drives", "--record", "FILE"], "--record"),
    (["fleet", S, "--robots", "1", "--out", "UNWRITABLE"], "--out"),
    (["fleet", S, "--robots", "1", "--out", "FILE"], "--out"),
    (["fleet", S, "--robots", "1", "--plant-host", "h1", "--out", "OUT"], "--plant-host"),
    # hil sweep
    (["sweep", S, "--ts", "0", "--out", "OUT"], "--ts"),
    (["sweep", S, "--ts", "0.001,nan", "--out", "OUT"], "--ts"),
    (["sweep", S, "--ts", "a,b", "--out", "OUT"], "--ts"),
    (["sweep", S, "--delay", "-1", "--out", "OUT"], "--delay"),
    (["sweep", S, "--jitter", "inf", "--out", "OUT"], "--jitter"),
    (["sweep", S, "--seeds", "0", "--out", "OUT"], "--seeds"),
    (["sweep", S, "--seeds", "100000", "--out", "OUT"], "--seeds"),
    (["sweep", S, "--seeds", "1.5", "--out", "OUT"], "--seeds"),
    (["sweep", S, "--duration", "inf", "--out", "OUT"], "--duration"),
    (["sweep", S, "--duration", "0", "--out", "OUT"], "--duration"),
    (["sweep", S, "--duration", "1000", "--ts", "1e-6", "--out", "OUT"], "--duration"),
    (["sweep", S, "--out", "FILE"], "--out"),
    (["sweep", S, "--out", "UNWRITABLE"], "--out"),
    (["sweep", S, "--law", "a:b:c", "--out", "OUT"], "--law"),
    # hil certify
    (["certify", S, "--ts", "nan"], "--ts"),
    (["certify", S, "--ts", "0"], "--ts"),
    (["certify", S, "--ts", "inf"], "--ts"),
    (["certify", S, "--delay", "-1"], "--delay"),
    (["certify", S, "--delay", "nan"], "--delay"),
    (["certify", S, "--delay", "soon"], "--delay"),
    # hil margin
    (["margin", S, "--seeds", "0", "--out", "OUT"], "--seeds"),
    (["margin", S, "--error-bound", "-1", "--out", "OUT"], "--error-bound"),
    (["margin", S, "--error-bound", "nan", "--out", "OUT"], "--error-bound"),
    (["margin", S, "--duration", "0", "--out", "OUT"], "--duration"),
    (["margin", S, "--k-max", "0.5", "--out", "OUT"], "--k-max"),
    (["margin", S, "--out", "FILE"], "--out"),
    (["margin", "no_such_scenario", "--out", "OUT"], "no_such_scenario"),
    # hil can-load
    (["can-load", "--rate", "nan", "--bitrate", "1e6"], "--rate"),
    (["can-load", "--rate", "0", "--bitrate", "1e6"], "--rate"),
    (["can-load", "--rate", "inf", "--bitrate", "1e6"], "--rate"),
    (["can-load", "--rate", "1000", "--bitrate", "-5"], "--bitrate"),
    (["can-load", "--rate", "1000", "--bitrate", "nan"], "--bitrate"),
    (["can-load", "--rate", "1000", "--bitrate", "1e6", "--drives", "0"], "--drives"),
    (["can-load", "--rate", "1000", "--bitrate", "1e6", "--drives", "65"], "--drives"),
    (["can-load", "--rate", "1000", "--bitrate", "1e6", "--heartbeat-rate", "-1"], "--heartbeat"),
    (["can-load", "--rate", "1000", "--bitrate", "1e6", "--encoder-rate", "nan"], "--encoder"),
    (["can-load", "--rate", "1000", "--bitrate", "1e6", "--out", "FILE"], "--out"),
    (["can-load", "--bitrate", "1e6"], "--rate"),
    (["can-dbc", "--out", "UNWRITABLE"], "--out"),
    (["can-dbc", "--out", "FILE"], "--out"),
    # hil report / compare / paper / scenarios
    (["report", "OUT", "--max-deadline-miss-ratio", "nan"], "--max-deadline-miss-ratio"),
    (["report", "OUT", "--max-lost-ratio", "2"], "--max-lost-ratio"),
    (["report", "OUT", "--max-lost-ratio", "-0.1"], "--max-lost-ratio"),
    (["report", "OUT", "--out", "FILE"], "--out"),
    (["report", "SIMDIR", "--out", "UNWRITABLE"], "--out"),
    (["compare", "OUT", "OUT", "--out", "FILE"], "--out"),
    (["compare", "SIMDIR", "SIMDIR", "--out", "UNWRITABLE"], "--out"),
    (["paper", "--out", "UNWRITABLE"], "--out"),
    (["new-law", "my-law"], "NAME"),
    (["paper", "--jobs", "0", "--out", "OUT"], "--jobs"),
    (["paper", "--jobs", "two", "--out", "OUT"], "--jobs"),
    (["paper", "--out", "FILE"], "--out"),
    (["scenarios", "--path", "no_such_scenario"], "no_such_scenario"),
    (["version", "--verbose"], "--verbose"),
    (["--nope"], "--nope"),
]


def _id(case: tuple[list[str], str]) -> str:
    args, _ = case
    return " ".join(a for a in args if a not in (S,))


@dataclass(frozen=True)
class Case:
    """One case's folders (each its own) and what its ``hil`` process did."""

    out: Path
    file: Path
    proc: subprocess.CompletedProcess[str]


def _run_case(folder: Path, sim_folder: Path, args: list[str]) -> Case:
    folder.mkdir(parents=True)
    out = folder / "out"
    file = folder / "file.txt"
    file.write_text("not a folder\n")
    settings = folder / "run_settings.json"
    settings.write_text(json.dumps({"scenario_path": S, "rate_hz": -1.0}))
    names = {
        "OUT": out,
        "FILE": file,
        "SETTINGS": settings,
        "MISSING": folder / "missing.json",
        # /proc takes no new folder, whoever runs the test (root's permission bits say yes)
        "UNWRITABLE": Path("/proc/hil-no-such-folder/out"),
        "SIMDIR": sim_folder,
        "DIR": folder,
    }
    argv = [str(names.get(a, a)) for a in args]
    proc = subprocess.run(
        [sys.executable, "-m", "hil", *argv],
        cwd=folder,
        capture_output=True,
        text=True,
        timeout=120,
        env=_env(),
    )
    return Case(out, file, proc)


@pytest.fixture(scope="module")
def cases(
    request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory, sim_folder: Path
) -> dict[str, Case]:
    """Each selected case's own ``hil`` process, as many at a time as there are CPUs (each is a
    Python start-up and an option check: CPU-bound and independent of the others), in its own
    folder."""
    test = test_a_bad_option_exits_2_with_one_line_naming_it.__name__
    chosen = {i.callspec.id for i in request.session.items if i.originalname == test}
    root = tmp_path_factory.mktemp("bad-options")
    with ThreadPoolExecutor(max_workers=os.cpu_count() or 1) as pool:
        running = {
            _id(c): pool.submit(_run_case, root / f"case{i}", sim_folder, c[0])
            for i, c in enumerate(CASES)
            if _id(c) in chosen
        }
        return {name: job.result() for name, job in running.items()}


@pytest.mark.parametrize(("args", "option"), CASES, ids=[_id(c) for c in CASES])
def test_a_bad_option_exits_2_with_one_line_naming_it(
    cases: dict[str, Case], args: list[str], option: str
) -> None:
    case = cases[_id((args, option))]
    proc = case.proc
    lines = proc.stderr.splitlines()
    assert "Traceback" not in proc.stderr, proc.stderr
    assert proc.returncode == 2, (proc.returncode, proc.stderr)
    assert len(lines) == 1 and lines[0].startswith("error: "), proc.stderr
    assert option in lines[0], lines[0]
    folder = case.file.parent
    assert not case.out.exists() and not (folder / "runs").exists(), "a folder was written"
    assert case.file.read_text() == "not a folder\n"


@pytest.fixture(scope="module")
def sim_folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A finished simulation folder, for report and compare."""
    from hil.bundled import resolve_scenario
    from hil.scenario import load_scenario
    from hil.sim import simulate, write_run_folder

    sc = load_scenario(resolve_scenario(S)).with_overrides(duration=0.2, ts=0.01)
    return write_run_folder(simulate(sc), tmp_path_factory.mktemp("sim") / "sim")


@pytest.mark.parametrize(
    "args",
    [
        ["sim", S],
        ["sweep", S, "--ts", "0.01", "--duration", "0.1"],
        ["run"],
        ["paper", "--quick"],
        ["drives"],
    ],
    ids=["sim", "sweep", "run", "paper", "drives"],
)
def test_an_unwritable_default_folder_is_refused_before_any_work(args: list[str]) -> None:
    """Without --out, the default runs/ under the working directory is checked first."""
    proc = subprocess.run(
        [sys.executable, "-m", "hil", *args],
        cwd="/proc",  # no folder can be made here
        capture_output=True,
        text=True,
        timeout=60,
        env=_env(),
    )
    assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr
    where = "--record" if args[0] == "drives" else "--out"  # hil drives records into a folder
    assert proc.stderr.startswith(f"error: {where} not given, so its default runs: cannot write")


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(ROOT), env.get("PYTHONPATH")) if p)
    return env


# A command with a fault of its own, registered on the real app beside the real commands (not
# a patch inside one command, which would stop injecting if that command's imports moved).
FAULTY_COMMAND = """
import sys
from hil.cli import app, main


@app.command("faulty")
def faulty(folder: str) -> None:
    raise RuntimeError("injected fault")


sys.exit(main(["faulty", sys.argv[1]]))
"""


def test_a_fault_of_hil_itself_exits_3_never_as_a_verdict(tmp_path: Path) -> None:
    """Python's own code for an uncaught exception is 1, which is the negative verdict's: a
    script reading ``hil report``'s exit code would take a crash for FAIL. An exception a
    command did not expect exits 3, with its traceback and one line saying it is the tool's
    fault."""
    proc = subprocess.run(
        [sys.executable, "-c", FAULTY_COMMAND, str(tmp_path)],
        cwd=ROOT, capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert proc.returncode == 3, (proc.returncode, proc.stderr[-2000:])
    assert "Traceback" in proc.stderr and "RuntimeError: injected fault" in proc.stderr
    last = proc.stderr.strip().splitlines()[-1]
    assert last.startswith("internal error: RuntimeError: injected fault") and "exit code 3" in last
