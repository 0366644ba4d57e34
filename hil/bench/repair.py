"""``hil recover DIR``'s repair: what a killed ``hil run`` left (SIGKILL, power loss;
docs/reliability.md, "Crash-safe runs"), made whole as far as the bench goes.

The recording, cut inside a chunk, is rewritten as a complete, indexed MCAP with the run's
attachments and the States it lacks (:func:`missing_states`); trace.csv and summary.json are
then rebuilt from the hop logs by the code a finished run uses (:func:`hil.analysis.analyze.
analyze`), which ``hil recover`` calls next (:mod:`hil.commands.recover`) on the run
:func:`repair` hands it.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from hil.bench.lifecycle import attachment_files
from hil.bench.recorder import rewrite_complete, to_jsonable
from hil.errors import BadInputError
from hil.folder import layout
from hil.folder.hoplogs import read_columns
from hil.folder.recording import RecordedMessage, is_complete, topic_values
from hil.folder.records import Recorded, Recovered, RunExtra
from hil.scenario import build_loop, loads_scenario
from plant_emulator.from_settings import sensor_of
from plant_emulator.sensors import measure
from protocol.hoplog import SAMPLE_DROPPED
from protocol.keys import state_key
from protocol.messages import State
from protocol.robot import RobotState
from protocol.settings import RunSettings


def needs_recovery(run_dir: Path) -> list[str]:
    """What is missing or broken in a run folder (empty: nothing to do)."""
    missing = [n for n in (layout.TRACE, layout.SUMMARY) if not (run_dir / n).is_file()]
    rec = run_dir / layout.RECORDING
    if rec.is_file() and not is_complete(rec):
        missing.append(layout.RECORDING)
    return missing


def is_run_folder(run_dir: Path) -> bool:
    return (run_dir / layout.RUN_SETTINGS).is_file() and (
        (run_dir / layout.PLANT_LOG).is_file() or (run_dir / layout.CONTROLLER_LOG).is_file()
    )


def missing_states(run_dir: Path, recording: Path) -> list[RecordedMessage]:
    """The States the plant sent (its hop log's samples less ``[faults]`` drops) that
    ``recording`` lacks, in send order: the recorder's own JSON of each (the measured state
    recomputed with the run's seeded sensor model, as the plant did) plus ``restored_from``,
    logged and published at its send time (when the recorder received it is not known)."""
    cols = ("seq", "sample_ns", "send_ns", "x", "y", "theta", "v", "omega", "flags")
    if not (run_dir / layout.PLANT_LOG).is_file():
        return []
    head, tables = read_columns(run_dir / layout.PLANT_LOG, {"samples": cols})
    s = tables["samples"]
    settings = RunSettings.load(run_dir / layout.RUN_SETTINGS)
    robot = str(head.meta.get("robot_id") or settings.robot_id)
    topic = state_key(robot)
    recorded = np.fromiter((v for v in topic_values(recording, topic, "seq") if v is not None),
                           dtype=np.int64)  # fmt: skip
    lost = ((s["flags"] & SAMPLE_DROPPED) == 0) & ~np.isin(s["seq"], recorded)
    sensor = sensor_of(settings)
    epoch = int(head.meta.get("epoch_ns") or 0)
    period = max(1, int(head.meta.get("sensor_period_ns") or 1))
    out = []
    for i in np.nonzero(lost)[0].tolist():
        sample, send = int(s["sample_ns"][i]), int(s["send_ns"][i])
        true = RobotState(*(float(s[c][i]) for c in ("x", "y", "theta", "v", "omega")))
        # The sensor's noise is a pure function of the sample's slot k on the epoch's grid.
        m = measure(sensor, true, (sample - epoch + period // 2) // period)
        msg = State(robot, int(s["seq"][i]), sample, send, float(m.x), float(m.y), float(m.theta),
                    float(m.v), float(m.omega))  # fmt: skip
        data = {**to_jsonable(msg), "type": "State", "restored_from": layout.PLANT_LOG}
        out.append(RecordedMessage(topic, send, send, 0, data))
    out.sort(key=lambda m: m.log_time_ns)
    return out


def repair(run_dir: str | Path) -> tuple[Recovered, Recorded | None]:
    """Repair a killed run's folder: what was done (empty ``repaired``: nothing to do) and,
    when trace.csv or summary.json is missing, the run as the analysis rebuilds them from (None
    otherwise). BadInputError when the folder is not a run folder (no settings, no hop logs)."""
    run_dir = Path(run_dir)
    if not is_run_folder(run_dir):
        raise BadInputError(f"{run_dir}: not a hil run folder (no run_settings.json or hop logs)")
    todo = needs_recovery(run_dir)
    done: Recovered = {"folder": str(run_dir), "repaired": todo}
    if not todo:
        return done, None
    rec = run_dir / layout.RECORDING
    if layout.RECORDING in todo:
        tmp = run_dir / (layout.RECORDING + ".recovering")
        try:
            lost = missing_states(run_dir, rec)
        except (OSError, ValueError) as exc:  # an unreadable plant log: recover the rest
            lost = []
            done["restore_error"] = str(exc)
        done["recording"] = rewrite_complete(rec, tmp, attachment_files(run_dir), lost)
        os.replace(tmp, rec)
    if layout.SUMMARY not in todo and layout.TRACE not in todo:
        return done, None
    settings = RunSettings.load(run_dir / layout.RUN_SETTINGS)
    resolved = run_dir / layout.SCENARIO_RESOLVED
    try:
        scenario = loads_scenario(resolved.read_text(), run_dir)
    except (OSError, ValueError) as exc:
        raise BadInputError(f"{resolved}: cannot rebuild the run ({exc})") from exc
    _, reference, context = build_loop(scenario)
    extra: RunExtra = {
        "interrupted": True,
        "error": None,
        "bench_error": None,
        "recovered": True,
        "recording": layout.RECORDING,
        "note": "hil run did not finish; rebuilt by hil recover from the services' hop logs",
    }
    return done, Recorded(run_dir, scenario, settings, reference, context, extra)
