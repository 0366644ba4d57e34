"""The two services' hop logs of one run, as numpy columns, with the joins every figure uses.

Sources: a run folder (``controller.hoplog``, ``plant.hoplog``, possibly truncated by a kill)
or the same two files carried as attachments of the run's recording (``*.mcap``), so a
recording alone reproduces every figure.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from protocol.hoplog import CONTROLLER_TABLES, PLANT_TABLES, HopLog, read_hoplog

CONTROLLER_FILE = "controller.hoplog"
PLANT_FILE = "plant.hoplog"

# Columns held as floats; every other column is an integer (ns stamps, indices, flags).
FLOAT_COLUMNS = {"tau1", "tau2", "x", "y", "theta", "v", "omega", "cmd1", "cmd2"}


def _columns(log: HopLog | None, table: str, names: tuple[str, ...]) -> dict[str, np.ndarray]:
    rows = log.rows.get(table, []) if log is not None else []
    fields = log.fields.get(table, list(names)) if log is not None else list(names)
    out: dict[str, np.ndarray] = {}
    for name in names:
        dtype = np.float64 if name in FLOAT_COLUMNS else np.int64
        if name in fields and rows:
            i = fields.index(name)
            out[name] = np.fromiter((r[i] for r in rows), dtype=dtype, count=len(rows))
        else:
            out[name] = np.zeros(len(rows) if name in fields else 0, dtype=dtype)
    return out


@dataclass
class RunLogs:
    controller: HopLog | None
    plant: HopLog | None
    tables: dict[str, dict[str, np.ndarray]] = field(default_factory=dict)

    @classmethod
    def of(cls, controller: HopLog | None, plant: HopLog | None) -> RunLogs:
        logs = cls(controller, plant)
        for name, cols in CONTROLLER_TABLES.items():
            logs.tables[name] = _columns(controller, name, cols)
        for name, cols in PLANT_TABLES.items():
            logs.tables[name] = _columns(plant, name, cols)
        return logs

    def __getitem__(self, table: str) -> dict[str, np.ndarray]:
        return self.tables[table]

    @property
    def cmeta(self) -> dict[str, Any]:
        return self.controller.meta if self.controller is not None else {}

    @property
    def pmeta(self) -> dict[str, Any]:
        return self.plant.meta if self.plant is not None else {}

    @property
    def cinfo(self) -> dict[str, Any]:
        return self.controller.info if self.controller is not None else {}

    @property
    def pinfo(self) -> dict[str, Any]:
        return self.plant.info if self.plant is not None else {}

    @property
    def epoch_ns(self) -> int:
        return int(self.pmeta.get("epoch_ns") or self.cmeta.get("epoch_ns") or 0)

    @property
    def complete(self) -> dict[str, bool]:
        return {
            "controller": bool(self.controller and self.controller.complete),
            "plant": bool(self.plant and self.plant.complete),
        }


def _read(path: Path) -> HopLog | None:
    try:
        return read_hoplog(path)
    except (OSError, ValueError):
        return None


def load_folder_logs(folder: str | Path) -> RunLogs | None:
    """The hop logs of a run folder (None when it has neither)."""
    folder = Path(folder)
    c, p = _read(folder / CONTROLLER_FILE), _read(folder / PLANT_FILE)
    if c is None and p is None:
        return None
    return RunLogs.of(c, p)


def load_recording_logs(path: str | Path) -> RunLogs | None:
    """The hop logs carried as attachments of a recording (None when it has none)."""
    import tempfile

    from hil.recording import read_attachments

    found = read_attachments(path, names=(CONTROLLER_FILE, PLANT_FILE))
    if not found:
        return None
    with tempfile.TemporaryDirectory(prefix="hil-hoplogs-") as tmp:
        logs = {}
        for name, data in found.items():
            p = Path(tmp) / name
            p.write_bytes(data)
            logs[name] = _read(p)
    return RunLogs.of(logs.get(CONTROLLER_FILE), logs.get(PLANT_FILE))
