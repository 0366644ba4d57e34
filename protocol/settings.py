"""What the two services need to know about one run, shared by ``hil run`` and the services.

``hil run`` resolves the scenario once, writes ``run_settings.json`` into the run folder and
passes its path to both children, so the controller and the plant agree on the epoch, the
rates, the paths and the endpoints. ``hil controller`` / ``hil emulator`` run standalone build
the same object from a scenario file and command-line options.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

CMD_PATHS = ("zenoh", "can")
TRIGGERS = ("periodic", "on_state")


@dataclass
class RunSettings:
    scenario_path: str
    robot_id: str = "robot0"
    epoch_ns: int = 0
    duration: float = 10.0
    rate_hz: float = 1000.0
    sensor_rate_hz: float = 1000.0
    trigger: str = "periodic"
    lockstep: bool = False
    state_timeout: float = 0.05
    command_timeout: float = 0.05
    scheduling: str = "fifo"
    cmd_path: str = "zenoh"
    can_live: bool = True
    can: dict[str, Any] = field(default_factory=dict)
    robot: dict[str, Any] = field(default_factory=dict)
    zenoh_mode: str = "peer"
    zenoh_endpoint: str = "tcp/127.0.0.1:7447"
    can_endpoint: str = "tcp/127.0.0.1:7449"
    delay: float = 0.0
    jitter: float = 0.0
    jitter_kind: str = "uniform"
    seed: int = 0
    # [faults] of the scenario (hil.scenario.FaultsConfig as a dict); empty = no injection.
    faults: dict[str, Any] = field(default_factory=dict)
    out_dir: str = "."
    cpu_controller: int | None = None
    cpu_plant: int | None = None
    spin_us: float = 0.0
    ts_s: float | None = None  # the scenario's own Ts when the rate was not overridden
    start_timeout: float = 60.0  # s a service waits for the run's start message

    @property
    def ts(self) -> float:
        # The scenario's Ts bit for bit when given: 1 / (1 / ts) may differ in the last bit,
        # and lockstep must see the simulator's sample times exactly.
        return self.ts_s if self.ts_s is not None else 1.0 / self.rate_hz

    def validate(self) -> None:
        if self.cmd_path not in CMD_PATHS:
            raise ValueError(f"cmd path must be one of {CMD_PATHS}, got {self.cmd_path!r}")
        if self.trigger not in TRIGGERS:
            raise ValueError(f"[realtime] trigger must be one of {TRIGGERS}")
        for name in ("rate_hz", "sensor_rate_hz", "state_timeout", "command_timeout"):
            v = getattr(self, name)
            if not (isinstance(v, int | float) and math.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be a positive number, got {v!r}")
        if not (math.isfinite(self.duration) and self.duration > 0):
            raise ValueError(f"duration must be positive, got {self.duration!r}")
        if self.rate_hz > 20_000:
            raise ValueError("[realtime] rate above 20 kHz is not supported")
        if self.scheduling not in ("fifo", "other"):
            raise ValueError("[realtime] scheduling must be 'fifo' or 'other'")
        if not isinstance(self.faults, dict):
            raise ValueError(f"faults must be a table, got {self.faults!r}")
        for key, v in self.faults.items():
            if isinstance(v, bool) or not isinstance(v, int | float) or not (v >= 0):
                raise ValueError(f"[faults] {key} must be a number >= 0, got {v!r}")

    def save(self, path: str | Path) -> None:
        Path(path).write_text(json.dumps(asdict(self), indent=2))

    @classmethod
    def load(cls, path: str | Path) -> RunSettings:
        data = json.loads(Path(path).read_text())
        known = {f.name for f in fields(cls)}
        return cls(**{k: v for k, v in data.items() if k in known})
