"""Helpers for the tests that build a lab (hil.bench.lab): why they cannot run here, the ``hil``
command, a lab built and always taken down."""

from __future__ import annotations

import contextlib
import os
import shutil
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
_reason: list[str | None] = []


def _probe() -> str | None:
    if os.geteuid() != 0:
        return "the lab makes network and time namespaces: needs root"
    for tool in ("ip", "nsenter", "nft", "tc", "mount"):
        if shutil.which(tool) is None:
            return f"the lab needs {tool}: not installed"
    name = f"hillab-probe{os.getpid()}"
    made = subprocess.run(["ip", "netns", "add", name], capture_output=True, text=True)
    if made.returncode != 0:
        return f"cannot make a network namespace here: {made.stderr.strip()}"
    subprocess.run(["ip", "netns", "del", name], capture_output=True)
    if not Path("/proc/self/timens_offsets").exists():
        return "this kernel has no time namespaces (CONFIG_TIME_NS)"
    return None


def lab_skip_reason() -> str | None:
    """Why a lab cannot be built in this process, or None (probed once)."""
    if not _reason:
        _reason.append(_probe())
    return _reason[0]


def lab_name(tag: str) -> str:
    """A lab name no other test process uses (1-12 of [a-z0-9])."""
    return f"t{os.getpid() % 100000}{tag}"[:12]


def hil(*args: str, timeout: float = 120.0, **kw) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "hil", *args],
        capture_output=True,
        text=True,
        timeout=timeout,
        cwd=ROOT,
        **kw,
    )


def lab_argv(name: str, host: str, *argv: str) -> list[str]:
    return [sys.executable, "-m", "hil", "lab", "exec", host, "--name", name, "--", *argv]


@contextlib.contextmanager
def lab(name: str, *up_args: str) -> Iterator[str]:
    """``hil lab up --name NAME UP_ARGS``, then ``hil lab down`` whatever happened."""
    try:
        done = hil("lab", "up", "--name", name, *up_args)
        assert done.returncode == 0, done.stderr
        yield name
    finally:
        down = hil("lab", "down", "--name", name)
        assert down.returncode == 0, down.stderr
