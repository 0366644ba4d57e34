"""A run or simulation folder's file names, each spelled here once (docs/run-folder.md)."""

from __future__ import annotations

from protocol.hoplog import LAW_FAULT_FILE

#: The scenario as given, and as resolved (every default filled in): the run's one input.
SCENARIO = "scenario.toml"
SCENARIO_RESOLVED = "scenario.resolved.toml"
#: The services' settings, written by hil run before they start.
RUN_SETTINGS = "run_settings.json"
#: The hop logs the services stream while they run (protocol/hoplog.py), and the host's load.
CONTROLLER_LOG = "controller.hoplog"
PLANT_LOG = "plant.hoplog"
HOST_LOG = "host.hoplog"
#: The controller process's console output (stdout and stderr: a traceback, a law fault).
CONTROLLER_OUTPUT = "controller.log"
#: The recorder's MCAP file (every message, the hop logs and the scenario attached).
RECORDING = "recording.mcap"
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

#: What every run or simulation folder holds once written.
REQUIRED = (TRACE, SUMMARY, SCENARIO_RESOLVED)
