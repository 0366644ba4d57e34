"""The ideal trajectory of a folder: the simulator at a fine period (Ts/10, no delay, no
jitter) standing in for continuous time, from the trace's first state and time. Absent
simulator: None (the report says so).
"""

from __future__ import annotations

import numpy as np

from hil.report.folder import Folder


def ideal_from_simulator(folder: Folder) -> dict[str, np.ndarray] | None:
    try:
        from hil.report.ideal_sim import simulate_ideal
    except ImportError:
        return None
    return simulate_ideal(folder.scenario, folder.path, folder.trace)
