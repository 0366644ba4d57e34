"""The report's "Where it ran" section of a run across lab hosts (topology.json): the host of
each service, each host's injected offset, the estimated offset with its uncertainty (a figure
drawn from clock-controller.csv), the routers each hop figure crossed; none for a run on one
host; and the recording carries topology.json."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest

from hil.bench.lifecycle import attachment_files
from hil.bench.recorder import Recorder, RecordingWriter
from hil.cli import main
from hil.folder.recording import read_attachments
from runtime.clocksync import CLOCK_FILE, COLUMNS
from tests.synthetic_folder import write_synthetic_folder
from tests.test_report import RUN_SECTIONS, check_html, check_images

INJECTED = {"h1": 3.2, "h2": -1.7}  # the plant's host and the controller's
TOPOLOGY = {
    "lab": "demo",
    "processes": {"plant": "h1", "controller": "h2", "recorder": "h1"},
    "hosts": {
        h: {"address": f"10.231.0.{i}", "offset_s": o, "router": f"tcp/10.231.0.{i}:7447"}
        for i, (h, o) in enumerate(INJECTED.items(), start=1)
    },
    "session_endpoint": "tcp/127.0.0.1:7447",
    "router_hops": {"command": ["router@h2", "router@h1"], "state": ["router@h1", "router@h2"]},
    "clock": {
        "estimates": 3,
        "related": True,
        "converted": True,
        "offset_ns_median": 4_900_040_000.0,
        "offset_ns_range": [4_899_950_000.0, 4_900_040_000.0],
        "uncertainty_ns_median": 350_000.0,
        "uncertainty_ns_max": 660_000.0,
        "cross_host_figures": ["hop_state", "hop_cmd_zenoh", "loop_transport_compute"],
    },
}
# (t4 on the controller's clock, estimate, its uncertainty): the rows the figure must draw.
ESTIMATES = [(10**9, 4_900_040_000, 660_000), (2 * 10**9, 4_899_950_000, 350_000)]
ESTIMATES += [(3 * 10**9, 4_900_040_000, 300_000)]


def _lab_folder(root: Path) -> Path:
    folder = write_synthetic_folder(root / "run", run=True, delay=0.0005)
    (folder / "topology.json").write_text(json.dumps(TOPOLOGY))
    rows = [",".join(COLUMNS)]
    rows += [f"0,0,0,{t},{o},{2 * u},{o},{u}" for t, o, u in ESTIMATES]
    (folder / CLOCK_FILE).write_text("\n".join(rows) + "\n")
    return folder


def test_a_lab_runs_report_says_where_it_ran(tmp_path: Path) -> None:
    folder = _lab_folder(tmp_path)
    main(["report", str(folder), "--no-ideal"])
    data = json.loads((folder / "report.json").read_text())
    sections = data["sections"]
    assert set(sections) == RUN_SECTIONS | {"topology"}
    assert sections.index("topology") == sections.index("latency") - 1
    assert data["topology"]["injected_difference_s"] == pytest.approx(4.9)
    md = (folder / "report.md").read_text()
    section = md.split("## Where it ran")[1].split("\n## ")[0]
    # Each host with what it ran and its injected offset.
    assert "| h1 | plant, recorder | 10.231.0.1 | 3.2 |" in section
    assert "| h2 | controller | 10.231.0.2 | -1.7 |" in section
    # The estimate against the injected difference, with its uncertainty.
    assert "median 4.900040 s" in section and "at most 660.0 us" in section
    assert "off by +40.0 us" in section
    # Each hop figure with the routers it crossed; one host's figures cross none, uncorrected.
    rows = {line.split(" | ")[0].strip("| "): line for line in section.splitlines()}
    assert "router@h2 -> router@h1 | two, corrected" in rows["hop_cmd_zenoh"]
    assert rows["hop_cmd_zenoh"].endswith("| 660 |")
    assert "router@h1 -> router@h2 | two, corrected" in rows["hop_state"]
    assert "none (one host) | h2's alone" in rows["compute"]
    assert "h1's alone" in rows["command_age_zenoh"]  # D: the plant's clock only
    # The figure is the clock file's estimates, over the controller's time.
    with (folder / "report_clock_offset.csv").open() as f:
        cols = ("t_s", "offset_ns", "uncertainty_ns")
        drawn = [tuple(float(r[c]) for c in cols) for r in csv.DictReader(f)]
    assert drawn == [((t - 10**9) / 1e9, o, u) for t, o, u in ESTIMATES]
    c = check_html(folder / "report.html")
    assert "topology" in c.section_ids
    check_images(c)
    assert "Where it ran" in (folder / "report.html").read_text()


def test_a_run_on_one_host_has_no_such_section(tmp_path: Path) -> None:
    folder = write_synthetic_folder(tmp_path / "run", run=True, delay=0.0005)
    main(["report", str(folder), "--no-ideal"])
    data = json.loads((folder / "report.json").read_text())
    assert set(data["sections"]) == RUN_SECTIONS and "topology" not in data


def test_the_recording_carries_the_topology(tmp_path: Path) -> None:
    folder = _lab_folder(tmp_path)
    recorder = Recorder(RecordingWriter(folder / "recording.mcap", metadata={"robot_id": "r"}))
    recorder.close(attachment_files(folder))
    got = read_attachments(folder / "recording.mcap")
    assert json.loads(got["topology.json"]) == TOPOLOGY
    assert got[CLOCK_FILE] == (folder / CLOCK_FILE).read_bytes()
