"""The scenario ``hil run`` uses with no arguments: the bundled ``paper_tracking`` (the paper's
tracking circle, Section 4, Table 1; ``hil sim paper_tracking`` runs the same one) with the run
defaults below laid over it: a short run at 500 Hz with both command paths live over loopback
(no vcan, no root needed). One name is one scenario: only the run's length, rate and transports
differ from the bundled file, never its initial condition, gains or reference."""

from __future__ import annotations

import os
import tomllib

from hil.bundled import bundled_path
from hil.provenance import Toml, dumps_toml

DEFAULT_DURATION = 10.0

#: How long ``hil run`` waits for its services to say ready (seconds, this environment variable
#: overrides it): generous, since start-up is seconds natively but minutes in an emulated (TCG)
#: guest; a service that ends meanwhile is noticed at once.
READY_TIMEOUT_ENV = "HIL_READY_TIMEOUT"
READY_TIMEOUT_S = 300.0


def ready_timeout_s() -> float:
    """The wait for the services' readiness (:data:`READY_TIMEOUT_ENV`, else 300 s)."""
    return float(os.environ.get(READY_TIMEOUT_ENV, READY_TIMEOUT_S))


DEFAULT_SCENARIO = "paper_tracking"

# Laid over the bundled scenario, table by table (a key here replaces the scenario's).
RUN_DEFAULTS: Toml = {
    "run": {"duration": DEFAULT_DURATION},
    "realtime": {
        "rate": 500.0,
        "sensor_rate": 500.0,
        "trigger": "periodic",
        "state_timeout": 0.05,
        "command_timeout": 0.05,
        "scheduling": "fifo",
    },
    "can": {
        "interface": "zenoh_can",
        "channel": "hil0",
        "bitrate": 1000000,
        "node_left": 0,
        "node_right": 1,
    },
}


def default_scenario_text() -> str:
    """The bundled ``paper_tracking`` with :data:`RUN_DEFAULTS` laid over it, as TOML."""
    data = tomllib.loads(bundled_path(DEFAULT_SCENARIO).read_text())
    for table, keys in RUN_DEFAULTS.items():
        data[table] = {**data.get(table, {}), **keys}
    head = (
        f"# hil run's default: the bundled {DEFAULT_SCENARIO} (hil scenarios) with the run's\n"
        f"# defaults laid over it ({DEFAULT_DURATION:g} s at 500 Hz, both command paths live).\n"
    )
    return head + dumps_toml(data)


PAPER_TRACKING_TOML = default_scenario_text()
