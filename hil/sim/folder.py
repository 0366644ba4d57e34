"""A simulation's folder (docs/run-folder.md): scenario.resolved.toml, trace.csv, summary.json,
and law_fault.json when the law failed."""

from __future__ import annotations

from pathlib import Path

from hil.folder import layout, write_summary
from hil.folder.jsonio import write_json
from hil.folder.trace_csv import write_trace_csv
from hil.provenance import dumps_toml
from hil.sim.core import SimResult


def write_run_folder(result: SimResult, out_dir: str | Path) -> Path:
    """Write the folder and return its path (created if needed)."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    (out / layout.SCENARIO_RESOLVED).write_text(dumps_toml(result.resolved))
    write_trace_csv(out / layout.TRACE, result.columns, result.trace)
    fault = result.summary.get("law_fault")
    if fault is not None:  # the record (its traceback too), as a run's controller writes it
        write_json(out / layout.LAW_FAULT, fault)
    write_summary(out, result.summary)
    return out
