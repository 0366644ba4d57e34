"""Ctrl-C (SIGINT by PID) of ``hil sim`` and ``hil paper`` as real processes: exit 130 exactly,
and what was done is kept. (``hil sweep``: tests/test_sweep.py; ``hil run``:
tests/test_run_signals.py.) The exit code comes from hil.interrupts, not from the CLI library,
so the in-process tests below check :func:`hil.cli.main` against every way a library may hand
an interrupt back."""

from __future__ import annotations

import csv
import json
import signal
import subprocess
from pathlib import Path

import pytest

import hil.cli
from hil import interrupts
from hil.cli import main
from tests.procs import Lines, wait_until
from tests.run_helpers import alive, children_of


def _stop(proc: subprocess.Popen, err: Lines) -> int:
    proc.send_signal(signal.SIGINT)
    try:
        return proc.wait(timeout=60)
    except subprocess.TimeoutExpired:
        pytest.fail("did not stop on SIGINT:\n" + err.text()[-3000:])


def test_ctrl_c_of_hil_sim_writes_what_was_computed(spawn, tmp_path: Path) -> None:
    out = tmp_path / "sim"
    # 600 s of the paper's tracking task take tens of seconds: SIGINT lands mid-loop.
    args = ["-m", "hil", "sim", "paper_tracking", "--duration", "600", "--out", str(out)]
    proc = spawn.python(args, cwd=tmp_path, text=True)
    err, _out = Lines(proc.stderr), Lines(proc.stdout)
    # The start line, then progress lines when stderr is not a terminal (hil.ticker).
    started = "hil sim: paper_tracking.toml"
    assert wait_until(lambda: err.seen(started) and err.seen("hil sim: sample"), 60), err.text()
    code = _stop(proc, err)
    assert code == 130, err.text(5)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["interrupted"] is True
    assert 0 < summary["duration"] < 600
    # what it did not cover, said (a cut-short command says so)
    said = f"interrupted: at t = {summary['duration']:.3f} s of 600 s; wrote what was computed"
    assert said in err.text(5) and "(no claim about the rest)" in err.text(5), err.text(5)
    with (out / "trace.csv").open() as f:
        rows = list(csv.reader(f))
    assert rows[0][:2] == ["t", "x"] and len(rows) - 1 == summary["samples"] > 0
    assert (out / "scenario.resolved.toml").is_file()


@pytest.mark.parametrize("jobs", [1, 2])
def test_ctrl_c_of_hil_paper_keeps_the_figures_written(spawn, tmp_path: Path, jobs: int) -> None:
    out = tmp_path / "paper"
    # Full durations (about a minute): the tracking figures come after a few seconds, the
    # stabilization run (300 s) is still going when SIGINT lands.
    args = ["-m", "hil", "paper", "--jobs", str(jobs), "--out", str(out)]
    proc = spawn.python(args, cwd=tmp_path, text=True)
    err, _out = Lines(proc.stderr), Lines(proc.stdout)
    first = out / "fig02_tracking_xy.png"
    assert wait_until(first.exists, 240), err.text()
    workers = children_of(proc.pid)
    assert len(workers) == (jobs if jobs > 1 else 0), workers
    code = _stop(proc, err)
    assert code == 130, err.text(5)
    assert "interrupted: kept " in err.text(5)
    table = json.loads((out / "table.json").read_text())
    missing = table["runs_not_done"]
    assert missing and "tracking" not in missing  # stabilization was still going
    assert f"runs not done: {', '.join(missing)} (no claim about them" in err.text(5)
    # The first group of figures is whole (PNG and its CSV), the last was never drawn.
    assert first.stat().st_size > 0 and first.with_suffix(".csv").is_file()
    assert (out / "fig06_tracking_tau2.png").is_file()
    assert not (out / "fig20_compare_omega.png").exists()
    table = json.loads((out / "table.json").read_text())
    assert table["interrupted"] is True and table["checks"] == []
    assert "tracking" in [r["run"] for r in table["runs"]]
    assert "INTERRUPTED" in (out / "table.md").read_text()
    assert (out / "runs" / "tracking" / "summary.json").is_file()
    # The pool's workers were stopped with it, not left running.
    assert wait_until(lambda: not any(alive(w) for w in workers), 10)


# hil.cli.main against the ways a CLI library may hand back a KeyboardInterrupt.


def _interrupted_then(then):  # type: ignore[no-untyped-def]
    """A fake app: the project's handler fires inside the command, then ``then()``."""

    def app(args=None, standalone_mode=True):  # type: ignore[no-untyped-def]
        try:
            interrupts.handler(signal.SIGINT, None)
        except KeyboardInterrupt as exc:
            return then(exc)
        raise AssertionError("the handler did not raise")

    return app


class _LibraryAbortError(RuntimeError):
    """Like click's Abort: no exit_code."""


class _LibraryExitError(RuntimeError):
    exit_code = 0  # a library exit carrying success


def _raise(exc: BaseException):  # type: ignore[no-untyped-def]
    raise exc


@pytest.mark.parametrize(
    "then",
    [
        lambda exc: None,  # the command caught it and returned normally (partial results kept)
        lambda exc: 0,  # the library returned an exit code of its own
        lambda exc: _raise(SystemExit(0)),
        lambda exc: _raise(SystemExit(1)),
        lambda exc: _raise(_LibraryAbortError()),
        lambda exc: _raise(_LibraryExitError()),
        lambda exc: _raise(exc),  # the KeyboardInterrupt itself
    ],
    ids=["returned", "code-0", "SystemExit-0", "SystemExit-1", "abort", "exit-0", "raised"],
)
def test_main_exits_130_whatever_the_library_did_with_the_interrupt(
    monkeypatch, capsys, then
) -> None:
    monkeypatch.setattr(hil.cli, "app", _interrupted_then(then))
    assert main(["anything"]) == 130
    err = capsys.readouterr().err
    assert err.strip().splitlines() == ["interrupted: stopped by SIGINT"]
    assert not interrupts.happened()  # cleared for the next call


def test_main_prints_what_the_command_kept(monkeypatch, capsys) -> None:
    def then(exc: BaseException) -> None:
        interrupts.note("partial results kept in DIR")

    monkeypatch.setattr(hil.cli, "app", _interrupted_then(then))
    assert main(["anything"]) == 130
    assert capsys.readouterr().err.strip() == "interrupted: partial results kept in DIR"


def test_main_keeps_usage_and_project_codes_without_an_interrupt(monkeypatch) -> None:
    from hil.errors import BadInputError, NegativeVerdictError

    class UsageError(Exception):
        exit_code = 2

        def show(self) -> None:
            pass

    assert main(["--help"]) == 0
    assert main(["sim", "--no-such-option"]) == 2
    for exc, code in (
        (UsageError(), 2),
        (BadInputError("x"), 2),
        (NegativeVerdictError("x"), 1),  # FAIL, the default
        (NegativeVerdictError("x", "FAIL"), 1),
        (NegativeVerdictError("x", "INCONCLUSIVE"), 4),
        (RuntimeError("a bug"), 3),
    ):
        monkeypatch.setattr(
            hil.cli, "app", lambda args=None, standalone_mode=True, e=exc: _raise(e)
        )
        assert main(["anything"]) == code


def test_a_shielded_interrupt_is_recorded_not_raised() -> None:
    with interrupts.installed():
        with interrupts.shielded():
            interrupts.handler(signal.SIGINT, None)  # nothing raised
        assert interrupts.happened()
        with pytest.raises(KeyboardInterrupt):
            interrupts.handler(signal.SIGINT, None)
    assert not interrupts.happened()
