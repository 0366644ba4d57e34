"""The two services' hop logs of one run, as numpy columns (the joins are in figures.py).

Each log read by :func:`hil.folder.hoplogs.read_columns` (chunk by chunk, only the columns the
figures and the trace use; small integers in small types), so an hour's run at 1 kHz fits in a
few hundred MB and is read in linear time. Sources: a run folder (``controller.hoplog``,
``plant.hoplog``, possibly truncated by a kill) or the same two files carried as attachments of
the run's recording (``*.mcap``), so a recording alone reproduces every figure.
"""

from __future__ import annotations

import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from hil.analysis.measure.clocks import to_plant_clock
from hil.folder import layout
from hil.folder.hoplogs import COLUMNS, LogHead, ServiceFacts, column, read_columns
from hil.folder.recording import read_attachments
from protocol.hoplog import (
    CONTROLLER_TABLES,
    HOST_TABLES,
    PLANT_TABLES,
)

# The robot's physical state and the commanded torques: read only for trace.csv
# (hil.analysis.analyze), never by the figures; an hour's worth is ~300 MB.
TRACE_ONLY: dict[str, tuple[str, ...]] = {
    "ticks": ("tau1", "tau2", "can_send_ns"),
    "samples": ("x", "y", "theta", "v", "omega", "tau1", "tau2", "cmd1", "cmd2"),
}
ALL_COLUMNS: dict[str, tuple[str, ...]] = {name: tuple(cols) for name, cols in COLUMNS.items()}
FIGURE_COLUMNS: dict[str, tuple[str, ...]] = {
    name: tuple(c for c in cols if c not in TRACE_ONLY.get(name, ()))
    for name, cols in COLUMNS.items()
}
TRACE_SOURCE_COLUMNS: dict[str, tuple[str, ...]] = {
    "ticks": ("state_seq", "state_sample_ns", "flags", "tau1", "tau2"),
    "samples": ("seq", "sample_ns", "x", "y", "theta", "v", "omega", "tau1", "tau2"),
}


@dataclass
class RunLogs:
    controller: LogHead | None
    plant: LogHead | None
    tables: dict[str, dict[str, np.ndarray]] = field(default_factory=dict)
    host: LogHead | None = None  # hil run's samples of the host, when it wrote them
    # role -> why its log, present, could not be read (the figures are then not measured)
    unreadable: dict[str, str] = field(default_factory=dict)

    @classmethod
    def read(
        cls,
        controller: Path | None,
        plant: Path | None,
        columns: dict[str, tuple[str, ...]] | None = None,
        host: Path | None = None,
    ) -> RunLogs:
        """Both logs (and the host's, if any); ``columns``: the tables and columns to read
        (default: what the figures need, :data:`FIGURE_COLUMNS`)."""
        columns = FIGURE_COLUMNS if columns is None else columns
        logs = cls(None, None)
        for path, tables, role in (
            (controller, CONTROLLER_TABLES, "controller"),
            (plant, PLANT_TABLES, "plant"),
            (host, HOST_TABLES, "host"),
        ):
            wanted = {name: columns[name] for name in dict(tables) if name in columns}
            for name, cs in wanted.items():  # empty columns where the log is absent or unreadable
                logs.tables[name] = {c: column(None, c, COLUMNS[name][c]) for c in cs}
            head = None
            if path is not None:
                try:
                    head, cols = read_columns(path, wanted)
                    logs.tables.update(cols)
                except (OSError, ValueError) as exc:
                    head = None
                    logs.unreadable[role] = str(exc)
            setattr(logs, role, head)
        to_plant_clock(logs.tables, controller.parent if controller is not None else None)
        return logs

    def __getitem__(self, table: str) -> dict[str, np.ndarray]:
        return self.tables[table]

    @property
    def cmeta(self) -> ServiceFacts:
        return self.controller.meta if self.controller is not None else {}

    @property
    def pmeta(self) -> ServiceFacts:
        return self.plant.meta if self.plant is not None else {}

    @property
    def cinfo(self) -> ServiceFacts:
        return self.controller.info if self.controller is not None else {}

    @property
    def pinfo(self) -> ServiceFacts:
        return self.plant.info if self.plant is not None else {}

    @property
    def epoch_ns(self) -> int:
        return int(self.pmeta.get("epoch_ns") or self.cmeta.get("epoch_ns") or 0)

    @property
    def complete(self) -> dict[str, bool]:
        heads = {"controller": self.controller, "plant": self.plant}
        return {role: bool(head and head.complete) for role, head in heads.items()}


def load_folder_logs(
    folder: str | Path, columns: dict[str, tuple[str, ...]] | None = None
) -> RunLogs | None:
    """The hop logs of a run folder (None when it has neither); ``columns`` as RunLogs.read."""
    names = (layout.CONTROLLER_LOG, layout.PLANT_LOG, layout.HOST_LOG)
    c, p, h = (Path(folder) / n if (Path(folder) / n).is_file() else None for n in names)
    if c is None and p is None:
        return None
    return RunLogs.read(c, p, columns, h)


def load_recording_logs(path: str | Path) -> RunLogs | None:
    """The hop logs carried as attachments of a recording (None when it has none)."""
    found = read_attachments(path, names=(layout.CONTROLLER_LOG, layout.PLANT_LOG, layout.HOST_LOG))
    if not found:
        return None
    with tempfile.TemporaryDirectory(prefix="hil-hoplogs-") as tmp:
        paths = {name: Path(tmp) / name for name in found}
        for name, data in found.items():
            paths[name].write_bytes(data)
        return RunLogs.read(
            paths.get(layout.CONTROLLER_LOG),
            paths.get(layout.PLANT_LOG),
            host=paths.get(layout.HOST_LOG),
        )
