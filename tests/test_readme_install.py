"""The README's first command, proved on a clean tree as a new user runs it.

The repository is cloned to a temporary folder (what is committed, nothing else), the README's
install command runs there exactly as written (a fresh virtual environment, the locked versions),
and the installed ``hil`` then runs from a folder outside the clone. A third-party module the
code imports without declaring it is absent from that environment, so this test fails on it.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from tests.run_helpers import LOADED_HOST, PASSES, check_verdict

ROOT = Path(__file__).resolve().parent.parent
MAIN_JOB = "hil run"


def readme_commands(text: str) -> list[str]:
    """The command lines of the README's first ``sh`` block, trailing comments removed."""
    m = re.search(r"```sh\n(.*?)```", text, re.DOTALL)
    assert m, "the README opens with no ```sh block"
    lines = [ln.split("  #", 1)[0].strip() for ln in m.group(1).splitlines()]
    return [ln for ln in lines if ln]


def install_part(command: str) -> str:
    """The README's first command without its final ``&& hil run``: the install, as written."""
    assert command.endswith("&& " + MAIN_JOB), (
        f"the first command should end with the main job: {command!r}"
    )
    return command[: -len("&& " + MAIN_JOB)].strip()


def clean_env(tmp: Path) -> dict[str, str]:
    """The environment of a new shell: no virtual environment of ours on PATH."""
    env = {k: v for k, v in os.environ.items() if k not in ("VIRTUAL_ENV", "PYTHONPATH")}
    ours = str(Path(sys.prefix) / "bin")
    env["PATH"] = os.pathsep.join(p for p in env["PATH"].split(os.pathsep) if p != ours)
    env["HOME"] = os.environ.get("HOME", str(tmp))
    return env


def test_readme_opens_with_the_two_commands():
    cmds = readme_commands((ROOT / "README.md").read_text(encoding="utf-8"))
    assert len(cmds) == 2, cmds
    install_part(cmds[0])
    assert "requirements.lock" in cmds[0], "the README's install must use the locked versions"
    assert cmds[1] == "bash .ci/run"


@pytest.mark.slow
@pytest.mark.timeout(1500)
def test_readme_first_command_works_in_a_clean_clone(tmp_path):
    if shutil.which("git") is None or not (ROOT / ".git").exists():
        pytest.fail("this test clones the repository: it needs git and a git checkout")
    clone = tmp_path / "clone"
    subprocess.run(["git", "clone", "-q", str(ROOT), str(clone)], check=True, timeout=120)
    env = clean_env(tmp_path)
    install = install_part(readme_commands((clone / "README.md").read_text(encoding="utf-8"))[0])
    res = subprocess.run(
        ["bash", "-c", install], cwd=clone, env=env, capture_output=True, text=True, timeout=1200
    )
    assert res.returncode == 0, (
        f"README install failed: {install}\n{res.stdout[-3000:]}\n{res.stderr[-3000:]}"
    )
    hil = clone / ".venv" / "bin" / "hil"
    assert hil.exists(), "the README's install should leave `hil` in .venv/bin"

    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    env["PATH"] = str(hil.parent) + os.pathsep + env["PATH"]
    run = subprocess.run(
        [str(hil), "run", "--duration", "2", "--quiet", "--out", str(elsewhere / "run")],
        cwd=elsewhere,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    # A crash leaves no summary. The README's first command runs the paper's circle at 1 kHz
    # (D* = 20 ms): PASS, or what a loaded host does to a loop of that period, explained by
    # the run's own logs, with that verdict's exit code.
    written = (elsewhere / "run" / "summary.json").is_file()
    assert written, (
        f"hil run failed ({run.returncode}):\n{run.stdout[-3000:]}\n{run.stderr[-3000:]}"
    )
    summary = json.loads((elsewhere / "run" / "summary.json").read_text())
    check_verdict(summary, (PASSES, *LOADED_HOST), run.returncode, elsewhere / "run",
                  context=run.stderr[-3000:])  # fmt: skip
    assert summary["duration"] > 1.5
    assert (elsewhere / "run" / "report.html").exists()

    sim = subprocess.run(
        [str(hil), "sim", "paper_tracking", "--out", str(elsewhere / "sim")],
        cwd=elsewhere,
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert sim.returncode == 0, (
        f"hil sim failed ({sim.returncode}):\n{sim.stdout[-3000:]}\n{sim.stderr[-3000:]}"
    )
    assert (elsewhere / "sim" / "trace.csv").stat().st_size > 0
    sim_summary = json.loads((elsewhere / "sim" / "summary.json").read_text())
    assert sim_summary["limits_held"] is True
