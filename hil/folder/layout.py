"""A run or simulation folder's file names, each spelled here once (docs/run-folder.md); the
names of the files the services write (their hop logs, the clock probe, the law's fault) are
the services' contract, :mod:`protocol.hoplog`, and re-exported here."""

from __future__ import annotations

from protocol.hoplog import CLOCK_FILE, CONTROLLER_HOPLOG, LAW_FAULT_FILE, PLANT_HOPLOG

#: The scenario as given, and as resolved (every default filled in): the run's one input.
SCENARIO = "scenario.toml"
SCENARIO_RESOLVED = "scenario.resolved.toml"
#: The services' settings, written by hil run before they start.
RUN_SETTINGS = "run_settings.json"
#: The hop logs the services stream while they run (protocol/hoplog.py), and the host's load.
CONTROLLER_LOG = CONTROLLER_HOPLOG
PLANT_LOG = PLANT_HOPLOG
HOST_LOG = "host.hoplog"
#: How often hil run samples its host into HOST_LOG (hil.bench.host_load writes a row this
#: often; hil.analysis.measure.host reads the rows knowing it).
HOST_INTERVAL_S = 0.1
#: The controller's clock probe: its offset estimates to the plant's clock (runtime.clocksync).
CLOCK = CLOCK_FILE
#: The controller process's console output (stdout and stderr: a traceback, a law fault).
CONTROLLER_OUTPUT = "controller.log"
#: The live view's console output (hil run --live; hil fleet --live: in the fleet's folder).
LIVE_LOG = "live.log"
#: A run across lab hosts: which host ran what (hil.bench.lab.placement), and the clock plot
#: the analysis draws from CLOCK (hil.analysis.report.clockplot).
TOPOLOGY = "topology.json"
CLOCK_PLOT = "clock.png"
#: [impair]: the nftables rules the run installed (hil.bench.impair).
IMPAIR_RULES = "impair.nft"
#: The recorder's MCAP file (every message, the hop logs and the scenario attached).
RECORDING = "recording.mcap"
#: An outside device's run (hil run --controller external, hil drives): how it connects.
DEVICE = "device.json"
#: The services' PIDs (hil run), and what hil recover repaired.
PROCESSES = "processes.json"
RECOVERED = "recovered.json"
#: One row per control sample.
TRACE = "trace.csv"
#: The run's result: the measurement's figures, the outcome and the verdict.
SUMMARY = "summary.json"
#: The measurement's per-sample series (latencies, lateness, command age) for plots and replay.
SERIES = "series.npz"
TRAJECTORY_PNG = "trajectory.png"
REPORT_JSON = "report.json"
REPORT_MD = "report.md"
REPORT_HTML = "report.html"
#: hil margin's result (hil.analysis.margin.record).
MARGIN = "margin.json"
#: The law's failure (controller_service.laws.guard.LawFault), when it failed: written by the
#: controller service in a run (its name is the services' contract, protocol.hoplog), by hil sim.
LAW_FAULT = LAW_FAULT_FILE

#: A fleet's folder (hil fleet): one run folder per robot, the fleet report, and per group of
#: robots (--per-process K) its spec and its robots' exit codes, named by the group's first robot.
FLEET_JSON = "fleet.json"
FLEET_MD = "fleet.md"
FLEET_PNG = "fleet.png"
FLEET_HTML = "fleet.html"


def group_spec(first: str) -> str:
    return f".group-{first}.spec.json"


def group_codes(first: str) -> str:
    return f".group-{first}.codes.json"


#: What every run or simulation folder holds once written.
REQUIRED = (TRACE, SUMMARY, SCENARIO_RESOLVED)
