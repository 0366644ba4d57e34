"""A simulation folder (docs/run-folder.md): scenario.resolved.toml, trace.csv, summary.json."""

from __future__ import annotations

import datetime as _dt
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from hil.provenance import dumps_toml
from hil.sim.core import SimResult


def new_run_dir(root: str | Path = "runs", prefix: str = "sim") -> Path:
    """A fresh folder under ``root`` named by the UTC time (suffixed if it exists)."""
    stamp = _dt.datetime.now(_dt.UTC).strftime("%Y%m%dT%H%M%SZ")
    base = Path(root) / f"{prefix}-{stamp}"
    out = base
    i = 1
    while out.exists():
        out = Path(f"{base}-{i}")
        i += 1
    return out


def _jsonable(value: Any) -> Any:
    if isinstance(value, dict):
        return {k: _jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, np.floating):
        value = float(value)
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def write_trace_csv(path: Path, columns: list[str], trace: np.ndarray) -> None:
    with path.open("w") as f:
        f.write(",".join(columns) + "\n")
        if len(trace):
            np.savetxt(f, trace, delimiter=",", fmt="%.10g")


def write_json(path: Path, data: Any) -> None:
    path.write_text(json.dumps(_jsonable(data), indent=2, sort_keys=False) + "\n")


def write_run_folder(result: SimResult, out_dir: str | Path) -> Path:
    """Write the folder and return its path (created if needed)."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    (out / "scenario.resolved.toml").write_text(dumps_toml(result.resolved))
    write_trace_csv(out / "trace.csv", result.columns, result.trace)
    write_json(out / "summary.json", result.summary)
    return out
