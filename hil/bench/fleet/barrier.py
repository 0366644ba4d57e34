"""A fleet's robots start together (docs/fleet.md): each ``hil run`` of a fleet, once its own
services are ready, marks itself ready in the fleet's folder and waits (bounded) until every
robot is, so that no run starts while the others still import their libraries on the same cores.
"""

from __future__ import annotations

import os
import time
from pathlib import Path
from typing import Any

ENV = "HIL_FLEET_BARRIER"  # DIR:N:ROBOT, set by hil fleet for each of its runs
TIMEOUT_S = 300.0


def env_for(folder: Path, robots: int, robot: str) -> dict[str, str]:
    return {ENV: f"{folder}:{robots}:{robot}"}


def release(folder: Path, robot: str) -> None:
    """Count a robot whose run ended before it was ready (hil fleet does it for a run that
    exited): the others are not held for it."""
    marks = folder / ".ready"
    marks.mkdir(exist_ok=True)
    (marks / robot).touch()


def wait(stop: Any) -> None:
    """Mark this run ready and wait for the fleet's other runs (no-op outside a fleet)."""
    value = os.environ.get(ENV)
    if not value:
        return
    folder, n, robot = value.rsplit(":", 2)
    release(Path(folder), robot)
    marks = Path(folder) / ".ready"
    deadline = time.monotonic() + TIMEOUT_S
    while not stop and time.monotonic() < deadline and len(list(marks.iterdir())) < int(n):
        time.sleep(0.02)
