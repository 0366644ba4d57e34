"""``hil run --lab NAME --plant-host H --controller-host H``: the run's processes on lab hosts
(docs/lab.md, "A run across hosts": the recorder on the plant's host, each service on its own,
every session a client of its own host's router). ``hil run`` executes itself again on the
plant's host with :data:`PLACED_ENV` set to its PID (``nsenter`` execs: the PID stays).
"""

from __future__ import annotations

import json
import os
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from hil.bench.lab.lab import LOCAL_ROUTER, host_command, host_env, host_of, require_root
from hil.bench.lab.state import load
from hil.errors import BadInputError
from hil.folder import layout
from hil.folder.clocks import read_track

PLACED_ENV = "HIL_LAB_PLACED"  # the PID of the ``hil run`` placed on the recorder's host


@dataclass(frozen=True)
class Placement:
    lab: str
    plant: str
    controller: str

    @property
    def recorder(self) -> str:
        return self.plant

    def host_of(self, process: str) -> str:
        return {"plant": self.plant, "controller": self.controller}.get(process, self.recorder)


def placement_of(opts: Any, impaired: bool = False) -> Placement | None:
    """The run's placement, or None without ``--lab``; a bad combination is a BadInputError
    (``impaired``: the scenario has an [impair] table)."""
    lab = getattr(opts, "lab", None)
    plant, controller = getattr(opts, "plant_host", None), getattr(opts, "controller_host", None)
    if lab is None:
        if plant or controller:
            raise BadInputError("--plant-host and --controller-host need --lab NAME")
        return None
    if opts.secure:
        raise BadInputError("--lab runs through the lab's own (open) routers: not with --secure")
    external = getattr(opts, "controller", "bench") == "external"
    if opts.cmd_path == "can" or (opts.can_live and not external):
        raise BadInputError(
            "--lab carries the Zenoh command path between hosts: add --no-can (a CAN bus "
            "does not cross the lab's routers)"
        )
    if impaired:
        raise BadInputError(
            "--lab impairs the lab's links (hil lab up --loss, --rate-bps):"
            " a scenario with [impair] cannot run there"
        )
    return Placement(lab, plant or "h1", controller or "h2")


def _state(p: Placement) -> Any:
    require_root("hil run --lab")
    state = load(p.lab)
    if state is None or state.phase != "up":
        raise BadInputError(f"--lab {p.lab}: the lab is not up (hil lab up --name {p.lab})")
    for host in (p.plant, p.controller):
        host_of(state, host)  # a host the lab does not have: BadInputError naming them
    return state


def enter(opts: Any, impaired: bool, started_as_hil_run: bool) -> Placement | None:
    """Before ``hil run`` prepares anything: None without ``--lab``; else, the first time,
    execute this same command again on the recorder's host (never returns). ``impaired``: the
    scenario has [impair]; ``started_as_hil_run``: this process can be executed again as is."""
    p = placement_of(opts, impaired)
    if p is None or os.environ.get(PLACED_ENV) == str(os.getpid()):  # placed already
        return p
    if not started_as_hil_run:
        raise BadInputError(
            "--lab: start it as `hil run` (or python -m hil run), which "
            "executes itself again on the plant's lab host"
        )
    state = _state(p)
    argv = host_command(state, p.recorder, [sys.executable, *sys.orig_argv[1:]])
    env = {**host_env(state), PLACED_ENV: str(os.getpid())}
    sys.stdout.flush()
    sys.stderr.flush()
    os.execvpe(argv[0], argv, env)
    return p  # not reached


def child_argv(p: Placement | None, process: str, argv: list[str]) -> list[str]:
    """``argv`` of a run's child, on its host (unchanged on the recorder's host)."""
    if p is None or p.host_of(process) == p.recorder:
        return argv
    return host_command(_state(p), p.host_of(process), argv)


# The figures that subtract a controller stamp from a plant stamp (hil.analysis.measure.figures).
CROSS_HOST = ("hop_state", "hop_cmd_zenoh", "loop_transport_compute")


def write_topology(p: Placement | None, run_dir: Path, device: bool = False) -> None:
    """``topology.json``: which host ran what, each host's injected offset, the routers a
    message crosses and the clocks; a warning when the controller's clock could not be related
    to the plant's across hosts (its cross-host figures then compare nothing). ``device``: the
    controller host runs an outside device: no clock of its is read, every figure is the
    plant's (hil.analysis.measure.device)."""
    if p is None:
        return
    state = load(p.lab)
    hosts = {}
    for name in dict.fromkeys((p.plant, p.controller)):
        h = host_of(state, name) if state else {}
        hosts[name] = {k: h.get(k) for k in ("address", "offset_s", "router", "impair")}
    same = p.plant == p.controller
    path = [f"router@{p.controller}"] + ([] if same else [f"router@{p.plant}"])
    facts = {
        "lab": p.lab,
        "processes": {
            "plant": p.plant,
            ("device" if device else "controller"): p.controller,
            "recorder": p.recorder,
        },
        "hosts": hosts,
        "session_endpoint": LOCAL_ROUTER,
        "router_hops": {"command": path, "state": path[::-1]},
        "clock_source": "the plant's host; the controller's estimate: clock-controller.csv",
    }
    track = read_track(run_dir)
    clock = facts["clock"] = track.facts()
    clock["cross_host_figures"] = [] if same or device else list(CROSS_HOST)
    if device:
        clock["source"] = "the plant's host only: an outside device's clock is never read"
    elif not same and track.at_ns.size == 0:
        clock["warning"] = "clocks not related: the cross-host figures are not valid"
        print(
            f"warning: the controller's clock was not related to the plant's: "
            f"{', '.join(CROSS_HOST)} mix two clocks and are not valid",
            file=sys.stderr,
        )
    # Drawn from the same estimates by the analysis (hil.analysis.report.clockplot), which the
    # bench does not import: named here when there are estimates to draw.
    clock["plot"] = layout.CLOCK_PLOT if track.at_ns.size else None
    (run_dir / layout.TOPOLOGY).write_text(json.dumps(facts, indent=2) + "\n")
