"""``jitter_kind = "replay"`` from a real run: the latencies measured in a run folder or its
recording, in seconds, for the simulator's replay (``hil.sim.landing.extra_delays``).

Accepted paths: a run folder or a ``.mcap`` recording; both are read through the run's one
result, :mod:`hil.measure` (a folder's hop logs by ``measure_folder``, a recording's attached
hop logs by ``measure_recording``), so a folder and its recording replay the same latencies:
``Measurement.latency_us()``, the sample-to-apply latency of every command (applied path: apply
- sample; shadow path: receive - sample). ``PATH::zenoh`` or ``PATH::can`` keeps one path
(default: every path, each in landing order, Zenoh first). Plain latency files stay with
``hil.sim.landing.jitter_samples_from``.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from hil.errors import BadInputError

US = 1e-6


def split_path(spec: str | Path) -> tuple[Path, str | None]:
    text = str(spec)
    if "::" in text:
        head, _, which = text.rpartition("::")
        return Path(head), which or None
    return Path(text), None


def is_run_source(spec: str | Path) -> bool:
    p, _ = split_path(spec)
    return p.is_dir() or p.suffix == ".mcap"


def measured_latencies_us(p: Path) -> dict[str, np.ndarray]:
    """Per path, the sample-to-apply latencies (µs) of a run folder or recording."""
    from hil.measure.folder import measure_folder, measure_recording

    if p.is_dir():
        m = measure_folder(p)
        where = "hop logs (controller.hoplog, plant.hoplog)"
    elif p.suffix == ".mcap" and p.is_file():
        m = measure_recording(p)
        where = "attached hop logs"
    else:
        raise BadInputError(f"[timing] replay: {p} is neither a run folder nor a .mcap recording")
    if m is None:
        raise BadInputError(f"[timing] replay: {p} has no {where}: not a run of hil run")
    return m.latency_us()


def latencies_from_run(spec: str | Path) -> np.ndarray:
    """Measured sample-to-apply latencies (seconds) of a run folder or recording."""
    p, which = split_path(spec)
    try:
        per_path = measured_latencies_us(p)
    except BadInputError as exc:
        text = str(exc)
        raise BadInputError(
            text if text.startswith("[timing] replay") else f"[timing] replay: {text}"
        ) from exc
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
    seconds = np.concatenate(values) * US
    seconds = seconds[np.isfinite(seconds) & (seconds >= 0)]
    if seconds.size == 0:
        raise BadInputError(f"[timing] replay: {p} holds no finite latency >= 0")
    return seconds


def write_latency_file(
    spec: str | Path | np.ndarray, out: Path, source: str | Path | None = None
) -> Path:
    """The run's latencies (``spec``: its folder or recording, or latencies already read from
    it, then ``source`` names it) as a JSON latency list the simulator's replay hook reads."""
    if isinstance(spec, np.ndarray):
        seconds, source = spec, source if source is not None else ""
    else:
        seconds, source = latencies_from_run(spec), spec
    out.write_text(json.dumps({"latencies": seconds.tolist(), "source": str(source)}))
    return out
