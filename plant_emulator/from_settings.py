"""The plant's parts from the resolved run settings alone (no scenario, no ``hil``).

``hil`` resolved the scenario into :class:`protocol.settings.RunSettings`: the initial state of
model (1), the RK4 step, the limits (2), the disturbance, the actuator lag, the sensor and when
commands land; the plant (and the virtual drives) are built from those, as the offline
simulator builds its own, so lockstep equals the simulation bit for bit.
"""

from __future__ import annotations

import math

import numpy as np

from plant_emulator.dynamics import NO_DRAG, Drag, PlantState
from plant_emulator.landing import extra_delays, landing_offsets
from plant_emulator.sensors import Sensor
from protocol.settings import RunSettings


def initial_state(s: RunSettings, at_rest: bool = False) -> PlantState:
    """The robot at t = 0 (``at_rest``: the pose only, v = omega = 0)."""
    i = s.initial
    v, omega = (0.0, 0.0) if at_rest else (i["v"], i["omega"])
    return PlantState(i["x"], i["y"], i["theta"], v, omega, 0.0, 0.0)


def drag_of(s: RunSettings) -> Drag:
    """The friction and top speed of [plant] (none when the settings have neither)."""
    c_v, c_omega = s.friction or (0.0, 0.0)
    v_max, omega_max = s.max_speed or (math.inf, math.inf)
    drag = Drag(float(c_v), float(c_omega), float(v_max), float(omega_max))
    return drag if drag.active else NO_DRAG


def sensor_of(s: RunSettings) -> Sensor:
    t = s.sensor
    if not t:
        return Sensor()
    return Sensor(tuple(t["noise_std"]), tuple(t["quantization"]), int(t["seed"]))  # type: ignore[arg-type]


def lockstep_offsets(s: RunSettings, n: int, h: float) -> list[int]:
    """Landing offsets (plant steps after each sample) drawn exactly as the simulator does."""
    replay = None if s.replay is None else np.asarray(s.replay, dtype=float)
    extra = extra_delays(s.jitter_kind, s.jitter, s.seed, n, replay)
    return [int(v) for v in landing_offsets(extra, s.delay, h).tolist()]
