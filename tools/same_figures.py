"""Do two versions of hil measure and draw the same run folders the same way?

A refactoring of the analysis must leave every figure as it was. This records three run
folders with the code of BASE (a Zenoh run, a CAN-applied run, and a run whose ``hil run`` was
killed with SIGKILL and is then recovered), keeps only what the services and the recorder
wrote (hop logs, recording, settings, scenario), and has each version rebuild the rest from
them exactly as a user would (``hil recover DIR``, then ``hil report DIR``), each in the same
path so that a path written into a file is no difference. Then it compares file by file,
summary.json key by key, and every command's ``--help``.

    python -m tools.same_figures 3b3ab2f              # BASE against this working tree
    python -m tools.same_figures 3b3ab2f --against 9d476ff --keep /tmp/figs

Exit 0 when every figure file (summary.json, trace.csv, series.npz, the report's CSV and PNG
files, trajectory.png) and every ``--help`` is byte-identical, 1 otherwise. The killed run's
recording is rewritten by ``hil recover`` and is not a figure; report.md/html/json are listed
(their wording may change without a figure changing). Both versions run in this virtual
environment: a BASE whose dependencies differ must be compared from its own.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import tarfile
import tempfile
import time
from dataclasses import dataclass, field
from io import BytesIO
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
DURATION_S = 6.0
KILL_AFTER_S = 9.0  # into a 20 s run: past start-up, well before its end
FOLDERS = {
    "zenoh": ["--duration", str(DURATION_S)],
    "can": ["--duration", str(DURATION_S), "--cmd-path", "can"],
    "killed": ["--duration", "20"],
}
# What hil recover and hil report write: everything else in a folder is the run's own record.
DERIVED_PREFIXES = (
    "report",
    "summary.json",
    "trace.csv",
    "series.npz",
    "trajectory.png",
    "recovered.json",
)
NOT_FIGURES = ("report.md", "report.html", "report.json", "recovered.json")
HELP_COLUMNS = "100"
COMMAND_ROW = re.compile(r"^│ ([a-z][a-z0-9-]*) ", re.MULTILINE)  # a row of a Commands box


@dataclass
class Comparison:
    """What differs between the two analyses of one folder."""

    same: list[str] = field(default_factory=list)
    different: list[str] = field(default_factory=list)
    only_base: list[str] = field(default_factory=list)
    only_other: list[str] = field(default_factory=list)
    summary_changes: list[str] = field(default_factory=list)

    def figures_differ(self, folder: str) -> list[str]:
        return [
            n
            for n in self.different + self.only_base
            if n not in NOT_FIGURES and not (folder == "killed" and n == "recording.mcap")
        ]


def export(rev: str, into: Path) -> Path:
    """The tree of ``rev`` (git archive), or this working tree for ``rev`` == "."."""
    if rev == ".":
        return ROOT
    data = subprocess.run(
        ["git", "-C", str(ROOT), "archive", rev], check=True, capture_output=True
    ).stdout
    into.mkdir(parents=True)
    with tarfile.open(fileobj=BytesIO(data)) as tar:
        tar.extractall(into, filter="data")
    return into


def hil(root: Path, *args: str) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "PYTHONPATH": str(root), "COLUMNS": HELP_COLUMNS}
    return subprocess.run(
        [sys.executable, "-m", "hil", *args], cwd=root, env=env, text=True, capture_output=True
    )


def record(root: Path, name: str, out: Path) -> None:
    """One run folder recorded by the code at ``root``; "killed" dies of SIGKILL mid-run and
    its services (their PIDs in processes.json) are stopped if they outlive it."""
    argv = [sys.executable, "-m", "hil", "run", *FOLDERS[name], "--no-report", "--out", str(out)]
    env = {**os.environ, "PYTHONPATH": str(root)}
    print(f"recording {name} with {root} ...", flush=True)
    if name != "killed":
        done = subprocess.run(argv, cwd=root, env=env, capture_output=True, text=True)
        if done.returncode not in (0, 1, 4):  # a verdict's exit codes: the folder is whole
            raise SystemExit(f"hil run for {name} exited {done.returncode}:\n{done.stderr}")
        return
    proc = subprocess.Popen(
        argv, cwd=root, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
    )
    try:
        time.sleep(KILL_AFTER_S)
    finally:
        proc.kill()
        proc.wait()
        stop_services(out)


def stop_services(folder: Path, grace_s: float = 10.0) -> None:
    try:
        pids = [int(p) for p in json.loads((folder / "processes.json").read_text()).values()]
    except (OSError, ValueError):
        return
    deadline = time.monotonic() + grace_s
    for pid in pids:
        while time.monotonic() < deadline and alive(pid):
            time.sleep(0.1)
        if alive(pid):
            os.kill(pid, signal.SIGKILL)


def alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    return True


def raw_copy(src: Path, dst: Path) -> None:
    dst.mkdir(parents=True)
    for f in src.iterdir():
        if f.is_file() and not f.name.startswith(DERIVED_PREFIXES):
            shutil.copy2(f, dst / f.name)


def analyse(root: Path, raw: Path, work: Path, out: Path) -> None:
    """``hil recover`` then ``hil report`` by the code at ``root``, in ``work`` (one path for
    both versions), the result moved to ``out``."""
    shutil.rmtree(work, ignore_errors=True)
    shutil.copytree(raw, work)
    logs = [hil(root, "recover", str(work)), hil(root, "report", str(work))]
    shutil.move(work, out)
    (out.parent / f"{out.name}.log").write_text(
        "".join(
            f"$ hil {' '.join(p.args[3:])}\n{p.stdout}{p.stderr}exit {p.returncode}\n" for p in logs
        )
    )


def summary_changes(a: object, b: object, path: str = "") -> list[str]:
    if isinstance(a, dict) and isinstance(b, dict):
        out = []
        for k in sorted(set(a) | set(b)):
            if k not in a:
                out.append(f"+ {path}/{k}")
            elif k not in b:
                out.append(f"- {path}/{k}")
            else:
                out += summary_changes(a[k], b[k], f"{path}/{k}")
        return out
    return [] if a == b else [f"~ {path}: {json.dumps(a)[:80]} -> {json.dumps(b)[:80]}"]


def compare(a: Path, b: Path) -> Comparison:
    c = Comparison()
    names_a = {f.name for f in a.iterdir()}
    names_b = {f.name for f in b.iterdir()}
    c.only_base, c.only_other = sorted(names_a - names_b), sorted(names_b - names_a)
    for n in sorted(names_a & names_b):
        same = (a / n).read_bytes() == (b / n).read_bytes()
        (c.same if same else c.different).append(n)
    if "summary.json" in c.different:
        c.summary_changes = summary_changes(
            json.loads((a / "summary.json").read_text()),
            json.loads((b / "summary.json").read_text()),
        )
    return c


def helps(root: Path) -> dict[str, str]:
    """Every command's and subcommand's --help text, by command line."""
    out: dict[str, str] = {}

    def walk(words: list[str]) -> None:
        text = hil(root, *words, "--help").stdout
        out[" ".join(["hil", *words])] = text
        listing = text.split("Commands", 1)[1] if "Commands" in text else ""
        for sub in COMMAND_ROW.findall(listing):
            walk([*words, sub])

    walk([])
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument("base", help="the version before (a git revision); it records the folders")
    p.add_argument("--against", default=".", help="the version after (default: this tree)")
    p.add_argument("--keep", type=Path, default=None, help="keep the folders here")
    args = p.parse_args(argv)
    top = args.keep or Path(tempfile.mkdtemp(prefix="same-figures-"))
    if args.keep is not None and top.exists() and any(top.iterdir()):
        p.error(f"{top} holds files; give an empty or new folder")
    top.mkdir(parents=True, exist_ok=True)
    base = export(args.base, top / "tree-base")
    other = export(args.against, top / "tree-other")
    failed = False
    try:
        for name in FOLDERS:
            record(base, name, top / "recorded" / name)
            raw_copy(top / "recorded" / name, top / "raw" / name)
            for label, root in (("base", base), ("other", other)):
                analyse(root, top / "raw" / name, top / "work" / name, top / label / name)
            c = compare(top / "base" / name, top / "other" / name)
            differ = c.figures_differ(name)
            failed |= bool(differ)
            print(
                f"{name}: {len(c.same)} files byte-identical; figures different: "
                f"{', '.join(differ) or 'none'}"
            )
            for label, names in (
                ("differ (not figures)", [n for n in c.different if n not in differ]),
                ("only before", c.only_base),
                ("only after", c.only_other),
            ):
                if names:
                    print(f"  {label}: {', '.join(names)}")
            for line in c.summary_changes:
                print(f"  summary.json {line}")
        h_base, h_other = helps(base), helps(other)
        changed = sorted(k for k in h_base.keys() & h_other.keys() if h_base[k] != h_other[k])
        gone, new = sorted(h_base.keys() - h_other.keys()), sorted(h_other.keys() - h_base.keys())
        failed |= bool(changed or gone)
        print(
            f"--help: {len(h_base)} before, {len(h_other)} after; changed: "
            f"{', '.join(changed) or 'none'}; gone: {', '.join(gone) or 'none'}; "
            f"new: {', '.join(new) or 'none'}"
        )
    except KeyboardInterrupt:
        print(f"interrupted; what was done is in {top}", file=sys.stderr)
        return 130
    print(f"folders: {top}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
