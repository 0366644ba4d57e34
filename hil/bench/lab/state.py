"""What a lab made, written down before it is made, so that anything a killed ``hil lab up``
left behind can be removed later, and nothing else (docs/lab.md, "Removal").

``/run/hillab/<name>/state.json`` (``/run`` is a tmpfs: a reboot removes it with the namespaces)
lists each object in the order it was made, each recorded *before* the command that makes it
runs (an object never made is skipped at removal). A network namespace is the lab's when its
name (``hillab-<name>-...``) is listed (``up`` refuses a name that exists unlisted); a time
namespace is a bind mount on a file in the lab's own folder; a process is the lab's only while
its PID has its recorded start time (a reused PID has another) and its environment carries the
lab's random token (``HIL_LAB=<name>:<token>``), which the lab gives every process it starts.
"""

from __future__ import annotations

import json
import os
import secrets
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import TypedDict

ROOT = Path(os.environ.get("HIL_LAB_ROOT", "/run/hillab"))
PREFIX = "hillab-"
MARK_ENV = "HIL_LAB"


def lab_dir(name: str) -> Path:
    return ROOT / name


def proc_start(pid: int) -> int | None:
    """The process' start time in clock ticks since boot (/proc/PID/stat field 22), or None
    when there is no such process."""
    try:
        text = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    # The command name (field 2) may hold spaces and parentheses: fields follow the last ")".
    return int(text.rsplit(")", 1)[1].split()[19])


class LabHost(TypedDict):
    """One host of a lab as its state file keeps it (hil.bench.lab.lab.up)."""

    name: str
    netns: str  # its network namespace
    timens: str  # the file that holds its time namespace
    address: str
    offset_s: float  # its clock's injected offset
    router: str  # its Zenoh router's endpoint
    impair: dict[str, float]  # its link's impairment (hil.bench.lab.net.Impair)


@dataclass
class Made:
    """One object of the lab: ``kind`` netns, timens or proc."""

    kind: str
    name: str  # the namespace's name, the time namespace's file, the process' role
    pid: int = 0
    start: int = 0


@dataclass
class LabState:
    name: str
    token: str = field(default_factory=lambda: secrets.token_hex(8))
    phase: str = "building"  # building -> up; removed at down
    owner_pid: int = field(default_factory=os.getpid)
    owner_start: int = 0
    hosts: list[LabHost] = field(default_factory=list)
    made: list[Made] = field(default_factory=list)

    @property
    def mark(self) -> str:
        return f"{self.name}:{self.token}"

    @property
    def path(self) -> Path:
        return lab_dir(self.name) / "state.json"

    def save(self) -> None:
        """Written whole or not at all (a kill mid-write leaves the previous file)."""
        self.path.parent.mkdir(mode=0o700, parents=True, exist_ok=True)
        tmp = self.path.with_suffix(".tmp")
        tmp.write_text(json.dumps(asdict(self), indent=1))
        os.replace(tmp, self.path)

    def intend(self, item: Made) -> Made:
        """Record ``item`` before it is made."""
        self.made.append(item)
        self.save()
        return item

    def owns_process(self, item: Made) -> bool:
        """The recorded process is still the one the lab started (see the module docstring)."""
        if item.pid <= 0 or proc_start(item.pid) != item.start:
            return False
        try:
            environ = Path(f"/proc/{item.pid}/environ").read_bytes().split(b"\0")
        except OSError:
            return False
        return f"{MARK_ENV}={self.mark}".encode() in environ

    def owner_alive(self) -> bool:
        return self.owner_start != 0 and proc_start(self.owner_pid) == self.owner_start


def load(name: str) -> LabState | None:
    """The lab's state, or None when there is none (or it cannot be read as one)."""
    try:
        data = json.loads((lab_dir(name) / "state.json").read_text())
        made = [Made(**m) for m in data.pop("made")]
        return LabState(**data, made=made)
    except (OSError, ValueError, TypeError, KeyError):
        return None


def names() -> list[str]:
    """The labs that have a folder under :data:`ROOT`."""
    return sorted(p.parent.name for p in ROOT.glob("*/state.json") if p.is_file())
