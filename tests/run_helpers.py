"""Helpers for the tests that start ``hil run`` (real processes, real Zenoh, real CAN bus)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import msgpack


def hil_run(out: Path, *args: str, timeout: float = 240, ok_codes: tuple[int, ...] = (0,)) -> dict:
    """``hil run ARGS`` into ``out``; its summary. ``ok_codes``: exit codes that are expected
    (1 = a limit of (2) broken, which a slow loop may legitimately do)."""
    proc = subprocess.run(
        [sys.executable, "-m", "hil", "run", *args, "--quiet", "--no-report", "--out", str(out)],
        capture_output=True,
        text=True,
        timeout=timeout,
    )
    if proc.returncode not in ok_codes:
        logs = {p.name: p.read_text()[-2000:] for p in out.glob("*.log")}
        raise AssertionError((proc.returncode, proc.stdout[-2000:], proc.stderr[-3000:], logs))
    return json.loads((out / "summary.json").read_text())


def load_log(path: Path) -> dict:
    return msgpack.unpackb(path.read_bytes(), raw=False, strict_map_key=False)


def children_of(pid: int) -> list[int]:
    """PIDs whose parent is ``pid`` (from /proc)."""
    out = []
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            with open(f"/proc/{entry}/stat") as f:
                stat = f.read()
        except OSError:
            continue
        ppid = int(stat.rsplit(")", 1)[1].split()[1])
        if ppid == pid:
            out.append(int(entry))
    return out


def cmdline(pid: int) -> str:
    try:
        with open(f"/proc/{pid}/cmdline", "rb") as f:
            return f.read().replace(b"\0", b" ").decode()
    except OSError:
        return ""


def alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False
