"""Replay latencies of a real run (a run folder or a ``.mcap`` recording), for ``[timing]
jitter_kind = "replay"`` naming one (:mod:`hil.folder.replay` reads the latency files).

The latencies are the run's measured sample-to-apply latencies, ``Measurement.latency_us()``
(applied path: apply - sample; shadow path: receive - sample), read from the folder's saved
measurement (:mod:`hil.analysis.measure.folder`) or, for a recording alone, measured from its
attached hop logs, so a folder and its recording replay the same latencies. ``PATH::zenoh`` or
``PATH::can`` keeps one path (default: every path, each in landing order, Zenoh first).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from hil.analysis.measure.folder import measure_folder, measure_recording, measured
from hil.errors import BadInputError
from hil.folder import load_folder, replay
from hil.folder.layout import SUMMARY
from hil.folder.replay import split_path
from hil.scenario import Scenario


def scenario_latencies(scenario: Scenario) -> np.ndarray | None:
    """``[timing] replay``'s latencies of ``scenario`` (a file's or a run's); None: its jitter
    is drawn, not replayed."""
    t = scenario.timing
    return jitter_samples_from(scenario.base_dir / t.replay) if t.jitter_kind == "replay" else None


def jitter_samples_from(path: str | Path) -> np.ndarray:
    """Latencies in seconds from a latency file (:func:`hil.folder.replay.jitter_samples_from`)
    or a real run (:func:`latencies_from_run`)."""
    return replay.jitter_samples_from(path, latencies_from_run)


def latencies_from_run(spec: str | Path) -> np.ndarray:
    """Measured sample-to-apply latencies (seconds) of a run folder (its saved measurement, else
    its hop logs measured) or recording."""
    p, which = split_path(spec)
    try:
        if p.is_dir():
            m = measured(load_folder(p, lazy=True)) if (p / SUMMARY).is_file() else None
            m = m if m is not None else measure_folder(p)
            where = "hop logs (controller.hoplog, plant.hoplog)"
        elif p.suffix == ".mcap" and p.is_file():
            m, where = measure_recording(p), "attached hop logs"
        else:
            raise BadInputError(f"{p} is neither a run folder nor a .mcap recording")
        if m is None:
            raise BadInputError(f"{p} has no {where}: not a run of hil run")
        per_path = m.latency_us()  # µs per path
    except BadInputError as exc:  # named once as the key it comes from
        text = str(exc).removeprefix("[timing] replay: ")
        raise BadInputError(f"[timing] replay: {text}") from exc
    except Exception as exc:  # a damaged folder or recording: whatever its reader raised
        raise BadInputError(
            f"[timing] replay: cannot read latencies from {p}: {type(exc).__name__}: {exc}"
        ) from exc
    if which is not None:
        if which not in per_path:
            raise BadInputError(
                f"[timing] replay: {p} has no latencies of path {which!r} "
                f"(has: {', '.join(sorted(per_path)) or 'none'})"
            )
        per_path = {which: per_path[which]}
    values = [v for v in per_path.values() if v.size]
    if not values:
        raise BadInputError(f"[timing] replay: no latency samples found in {p}")
    seconds = np.concatenate(values) * 1e-6  # µs to s
    seconds = seconds[np.isfinite(seconds) & (seconds >= 0)]
    if seconds.size == 0:
        raise BadInputError(f"[timing] replay: {p} holds no finite latency >= 0")
    return seconds
