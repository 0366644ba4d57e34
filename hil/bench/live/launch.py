"""Starting the live view's process for ``hil run --live``, ``hil drives --live`` and
``hil fleet --live``. A bare ``--live`` takes :data:`hil.options.LIVE_DEFAULT_PORT` (Foxglove's
own; see :func:`hil.options.expand_live_flag`); ``--live-host`` binds elsewhere than loopback,
with a warning: the server has no login and no TLS, so anyone who reaches the port sees the run.
"""

from __future__ import annotations

import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from hil import options
from hil.bench.supervisor import Supervisor
from hil.errors import BadInputError
from hil.folder import layout

START_TIMEOUT_S = 30.0
LOOPBACK = ("127.0.0.1", "localhost", "::1")


def check(port: int | None, host: str) -> None:
    """The live options, each named in a BadInputError; a warning for a non-loopback host."""
    if port is None:
        return
    options.integer("--live", port, 0, 65535)
    options.plain_string("--live-host", host, empty=False)
    # Bound now, before any folder or process, if at all: the view's own bind would fail later
    # (the port in use, or the host not an address of this machine).
    try:
        family, _, _, _, addr = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)[0]
    except OSError as exc:
        raise BadInputError(f"--live-host {host}: {exc}") from exc
    with socket.socket(family, socket.SOCK_STREAM) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind(addr)
        except OSError as exc:
            raise BadInputError(f"--live {port} on {host}: {exc.strerror or exc}") from exc
    if host not in LOOPBACK:
        print(
            f"warning: --live-host {host}: the live view serves the run's data (pose, "
            "commands, CAN frames, timing) to anyone who can reach that address; it has no "
            "login and no TLS",
            file=sys.stderr,
        )


def argv_for(settings: Sequence[Path], port: int, host: str, resolved: Path | None,
             zenoh_mode: str, other_clocks: bool = False) -> list[str]:  # fmt: skip
    """The live process's arguments after the interpreter (``settings``: each robot's;
    ``other_clocks``: the services run on a lab's hosts, whose clocks are not the view's)."""
    argv = ["-m", "hil.bench.live", *map(str, settings), "--host", host, "--port", str(port)]
    argv += ["--zenoh-mode", zenoh_mode] + (["--other-clocks"] if other_clocks else [])
    argv += ["--resolved", str(resolved)] if resolved is not None else ["--no-reference"]
    return argv


def _start(sup: Supervisor, argv: list[str], log: Any, log_path: Path) -> None:
    """Start the live process under ``sup``, its output to ``log`` (at ``log_path``); announce
    on stderr the ``ws://`` address it prints once it listens. BadInputError if it exits first
    (a port in use) or stays silent :data:`START_TIMEOUT_S` s."""
    child = sup.start_python("live", argv, stdout=log, stderr=subprocess.STDOUT)
    deadline = time.monotonic() + START_TIMEOUT_S
    while time.monotonic() < deadline:
        text = log_path.read_text(errors="replace") if log_path.exists() else ""
        for line in text.splitlines():
            if line.startswith("live: ws://"):
                url = line.split(" ", 1)[1]
                print(
                    f"live view: {url} (Foxglove or Lichtblick: Open connection > Foxglove "
                    "WebSocket; layout docs/live-layout.json)",
                    file=sys.stderr,
                )
                return
        if not child.alive():
            tail = text.strip().splitlines()[-3:]
            raise BadInputError("the live view did not start: " + " / ".join(tail))
        time.sleep(0.05)
    raise BadInputError(f"the live view did not start within {START_TIMEOUT_S:g} s ({log_path})")


def start_for_run(
    sup: Any, run_dir: Path, port: int, host: str, logs: Any, other_clocks: bool = False
) -> None:
    """The live process of ``hil run`` (a supervised child, stopped with the others)."""
    argv = argv_for([run_dir / layout.RUN_SETTINGS], port, host,
                    run_dir / layout.SCENARIO_RESOLVED, "client", other_clocks)  # fmt: skip
    _start(sup, argv, logs.open("live"), run_dir / layout.LIVE_LOG)


class FleetLive:
    """The live process of ``hil fleet``: every robot of the fleet on one server, started as
    soon as each robot's run folder holds its settings (:meth:`poll`), stopped by PID."""

    def __init__(
        self, out: Path, robots: Sequence[str], port: int, host: str, lab: bool = False
    ) -> None:
        self.settings = [out / r / layout.RUN_SETTINGS for r in robots]
        self.lab = lab
        self.resolved = out / robots[0] / layout.SCENARIO_RESOLVED
        self.port, self.host = port, host
        self.log_path = out / layout.LIVE_LOG
        self._sup = Supervisor()
        self._log: Any = None

    def poll(self) -> None:
        """Start the view once every robot's settings exist (a no-op before and after)."""
        if self._log is not None or not all(p.is_file() for p in self.settings):
            return
        resolved = self.resolved if self.resolved.is_file() else None
        argv = argv_for(self.settings, self.port, self.host, resolved, "client", self.lab)
        self._log = self.log_path.open("wb")
        _start(self._sup, argv, self._log, self.log_path)

    def close(self) -> None:
        self._sup.stop_all(grace=5.0)
        if self._log is not None:
            self._log.close()


class DrivesLive(FleetLive):
    """``hil drives``' live process: a fleet of one, its settings in a temporary folder."""

    def __init__(self, settings: Any, port: int, host: str) -> None:
        self._dir = tempfile.TemporaryDirectory(prefix="hil-live-")
        super().__init__(Path(self._dir.name), ["drives"], port, host)
        self.settings[0].parent.mkdir()
        settings.save(self.settings[0])
        try:
            self.poll()
        except BaseException:
            self.close()
            raise

    def close(self) -> None:
        super().close()
        self._dir.cleanup()
