"""``hil recover DIR``: a run folder made whole after ``hil run`` died (SIGKILL, power loss).

What a killed ``hil run`` leaves: the services' hop logs (streamed, and usually complete: the
children get SIGTERM from the kernel when their parent dies and exit cleanly), the resolved
scenario and settings, and a recording cut inside a chunk. Recovery rewrites the recording as a
complete, indexed MCAP (every whole chunk, plus the hop logs and the resolved scenario as
attachments) and rebuilds trace.csv and summary.json from the hop logs with the same code a
finished run uses (:func:`hil.run.results.analyze`, :mod:`hil.measure`).
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

from hil.errors import BadInputError

RECORDING = "recording.mcap"


def needs_recovery(run_dir: Path) -> list[str]:
    """What is missing or broken in a run folder (empty: nothing to do)."""
    from hil.recording import is_complete

    missing = [n for n in ("trace.csv", "summary.json") if not (run_dir / n).is_file()]
    rec = run_dir / RECORDING
    if rec.is_file() and not is_complete(rec):
        missing.append(RECORDING)
    return missing


def is_run_folder(run_dir: Path) -> bool:
    return (run_dir / "run_settings.json").is_file() and (
        (run_dir / "plant.hoplog").is_file() or (run_dir / "controller.hoplog").is_file()
    )


def recover(run_dir: str | Path) -> dict[str, Any]:
    """Make a killed run's folder whole; returns what was done. BadInputError when the folder
    is not a run folder (no settings, no hop logs) or holds no sample to rebuild from."""
    from hil.recording import rewrite_complete
    from hil.run.orchestrate import attachments_of
    from hil.run.results import analyze, plot
    from hil.scenario import build_loop, loads_scenario
    from protocol.settings import RunSettings

    run_dir = Path(run_dir)
    if not is_run_folder(run_dir):
        raise BadInputError(f"{run_dir}: not a hil run folder (no run_settings.json or hop logs)")
    todo = needs_recovery(run_dir)
    done: dict[str, Any] = {"folder": str(run_dir), "repaired": todo}
    if not todo:
        return done
    rec = run_dir / RECORDING
    if RECORDING in todo:
        tmp = run_dir / (RECORDING + ".recovering")
        counts = rewrite_complete(rec, tmp, attachments_of(run_dir))
        os.replace(tmp, rec)
        done["recording"] = counts
    if "summary.json" in todo or "trace.csv" in todo:
        settings = RunSettings.load(run_dir / "run_settings.json")
        resolved = run_dir / "scenario.resolved.toml"
        try:
            scenario = loads_scenario(resolved.read_text(), run_dir)
        except (OSError, ValueError) as exc:
            raise BadInputError(f"{resolved}: cannot rebuild the run ({exc})") from exc
        _, reference, context = build_loop(scenario)
        extra = {
            "interrupted": True,
            "error": None,
            "recovered": True,
            "recording": RECORDING,
            "note": "hil run did not finish; rebuilt by hil recover from the services' hop logs",
        }
        summary = analyze(run_dir, scenario, settings, reference, context, {}, extra)
        if not summary.get("samples"):
            raise BadInputError(f"{run_dir}: the run was killed before its first sample")
        try:
            plot(run_dir)
        except Exception as exc:  # plots are a convenience; the figures are in summary.json
            done["plot_error"] = str(exc)
        done["samples"] = summary["samples"]
    (run_dir / "recovered.json").write_text(json.dumps(done, indent=2))
    return done
