"""The report's "Where it ran" section, for a run across lab hosts (``topology.json``; a run on
one host has none): which host ran each service, each host's injected clock offset, the
controller's estimated offset to the plant's clock and its uncertainty, and the routers each hop
figure crossed, so that a reader can tell a network delay (through routers, corrected by the
estimate within its uncertainty) from a scheduling delay (one host's clock, no correction).
:func:`add` puts it into the report; :func:`build`, registered in :mod:`hil.report.content`,
writes its text.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from hil.lab.clockplot import clock_png
from hil.lab.placement import TOPOLOGY_FILE
from hil.measure.clocks import read_track
from hil.report import content
from hil.report.figures import Figure

SECTION = "topology"
TITLE = "Where it ran: hosts, clocks and routers"
FIGURE = "clock_offset"

# Each figure: the streams it rides on (router_hops keys, None: no network) and the processes
# its message passes through (docs/realtime.md defines each figure).
HOP_FIGURES: tuple[tuple[str, str | None, tuple[str, ...]], ...] = (
    ("hop_state", "state", ("plant", "controller")),
    ("hop_cmd_zenoh", "command", ("controller", "plant")),
    ("loop_transport_compute", "state+command", ("plant", "controller", "plant")),
    ("command_age_zenoh", "state+command", ("plant", "controller", "plant")),
    ("wakeup_lateness", None, ("controller",)),
    ("compute", None, ("controller",)),
    ("plant_sample_to_send", None, ("plant",)),
)


def _routers(topo: dict[str, Any], stream: str | None) -> list[str]:
    hops = topo.get("router_hops") or {}
    out: list[str] = []
    for part in stream.split("+") if stream else ():
        out += [r for r in hops.get(part) or [] if r not in out]
    return out


def _hop_rows(topo: dict[str, Any], timing: dict[str, Any], unc_us: float | None) -> list[list]:
    """One row per timing figure: hosts, routers crossed, clocks and the correction's bound."""
    procs = topo["processes"]
    cross = set((topo.get("clock") or {}).get("cross_host_figures") or [])
    rows = []
    for name, stream, path in HOP_FIGURES:
        f = timing.get(name)
        if not isinstance(f, dict):
            continue
        two = name in cross
        hosts = " -> ".join(f"{p}@{procs.get(p)}" for p in path)
        routers = " -> ".join(_routers(topo, stream)) or "none (one host)"
        clocks = "two, corrected" if two else f"{procs.get(path[0])}'s alone"
        bound = unc_us if two else 0.0
        rows.append([name, hosts, routers, clocks, f.get("p50_us"), f.get("p99_us"), bound])
    return rows


def facts(folder: Path) -> dict[str, Any] | None:
    """The section's facts (report.json ``topology``), or None for a run on one host."""
    try:
        topo = json.loads((folder / TOPOLOGY_FILE).read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(topo, dict) or not isinstance(topo.get("processes"), dict):
        return None
    hosts = topo.get("hosts") or {}
    injected = [h.get("offset_s") for h in hosts.values()]
    procs = topo["processes"]
    plant, ctrl = ((hosts.get(procs.get(p)) or {}).get("offset_s") for p in ("plant", "controller"))
    numbers = isinstance(plant, int | float) and isinstance(ctrl, int | float)
    difference = float(plant) - float(ctrl) if numbers else None
    return {**topo, "injected_offsets_s": injected, "injected_difference_s": difference}


def add(folder: Path, data: dict[str, Any], figs: list[Figure]) -> None:
    """Put the section (and the clock figure, when the run has estimates) into the report of
    ``folder`` if it ran across lab hosts; leave the report unchanged otherwise."""
    f = facts(folder)
    if f is None:
        return
    data["topology"] = f
    sections = data["sections"]
    at = sections.index("latency") if "latency" in sections else len(sections)
    sections.insert(at, SECTION)
    track = read_track(folder)
    png = clock_png(track)
    if png is not None:
        columns = {
            "t_s": (track.at_ns - track.at_ns[0]) / 1e9,
            "offset_ns": track.offset_ns.astype(float),
            "uncertainty_ns": track.uncertainty_ns.astype(float),
        }
        caption = "Offset estimates of the controller's clock to the plant's, with uncertainty."
        figs.append(Figure(FIGURE, "Clock offset over the run", png, columns, caption))


def _clock_text(f: dict[str, Any]) -> str:
    clock = f.get("clock") or {}
    if not clock.get("related"):
        warning = clock.get("warning") or "the cross-host figures are not valid"
        return f"The controller's clock was never related to the plant's: {warning}."
    med = clock["offset_ns_median"] / 1e9
    lo, hi = (x / 1e9 for x in clock["offset_ns_range"])
    text = (
        f"Estimated offset (plant clock minus controller clock, {clock['estimates']} exchanges, "
        f"RFC 5905 minimum-delay filter): median {med:.6f} s, range {lo:.6f} to {hi:.6f} s; "
        f"uncertainty (half the round trip of the exchange used) median "
        f"{clock['uncertainty_ns_median'] / 1e3:.1f} us, at most "
        f"{clock['uncertainty_ns_max'] / 1e3:.1f} us."
    )
    diff = f.get("injected_difference_s")
    if diff is not None:
        err = (clock["offset_ns_median"] - diff * 1e9) / 1e3
        text += f" Injected difference {diff:+.6f} s: the estimate is off by {err:+.1f} us."
    return text


def build(s: content.Section, data: dict[str, Any]) -> None:
    f = data["topology"]
    procs, hosts = f["processes"], f.get("hosts") or {}
    s.p(
        f"Lab {f.get('lab')}: each session is a client of its own host's router "
        f"({f.get('session_endpoint')}), so messages between hosts cross the routers as "
        "between computers."
    )
    runs = {h: [p for p, on in procs.items() if on == h] for h in hosts}
    keys = ("address", "offset_s", "router", "impair")
    s.table(
        ["host", "runs", "address", "injected CLOCK_MONOTONIC offset (s)", "router", "impair"],
        [[h, ", ".join(runs[h]), *(v.get(k) for k in keys)] for h, v in hosts.items()],
    )
    s.p(_clock_text(f))
    s.figure(FIGURE)
    clock = f.get("clock") or {}
    unc = clock.get("uncertainty_ns_max")
    unc_us = None if unc is None else float(np.round(unc / 1e3, 3))
    timing = (data.get("timing") or {}).get("summary") or {}
    s.table(
        ["figure", "from -> to", "routers crossed", "clocks", "p50 (us)", "p99 (us)", "+- (us)"],
        _hop_rows(f, timing, unc_us),
    )
    s.p(
        "A network delay shows in the figures that cross routers (each corrected by the "
        "offset estimate, within its uncertainty); a scheduling delay shows in wakeup_lateness "
        "and compute, each one host's clock with no router and no correction. The command age "
        "D is measured on the plant's clock alone and needs no correction."
    )


content.SECTIONS[SECTION] = (TITLE, build)
