"""v~ and w~ of (10) out of a run's recording (``*.mcap``, :mod:`hil.recording`): the
controller's telemetry messages, for the report's quasi-sliding bands when trace.csv has no
``v_tilde``/``w_tilde`` columns (a run's trace holds the plant's samples, not the law's
internals). Timing figures never come from here: they are hil.measure's.
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

import numpy as np


def sliding_from_recordings(paths: Iterable[Path]) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """v~ and w~ of (10) from the controller's telemetry messages: name -> (time_ns, values).
    Telemetry may be decimated; the band is then computed over the recorded samples."""
    from hil.recording import read_messages

    t: list[int] = []
    vt: list[float] = []
    wt: list[float] = []
    for path in paths:
        try:
            for m in read_messages(path):
                d = m.data if isinstance(m.data, dict) else {}
                if not m.topic.endswith("telemetry") or "v_tilde" not in d:
                    continue
                v, w = d.get("v_tilde"), d.get("w_tilde")
                if isinstance(v, int | float) and isinstance(w, int | float):
                    t.append(int(d.get("time_ns", m.log_time_ns)))
                    vt.append(float(v))
                    wt.append(float(w))
        except Exception:  # a truncated recording: keep what was read
            continue
    if not t:
        return {}
    order = np.argsort(np.asarray(t), kind="stable")
    tn = np.asarray(t, dtype=np.int64)[order]
    return {
        "v_tilde": (tn, np.asarray(vt)[order]),
        "w_tilde": (tn, np.asarray(wt)[order]),
    }
