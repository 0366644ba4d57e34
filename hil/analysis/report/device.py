"""The report's section "The device at the bus": the device's figures as summary.json holds them
(:class:`hil.folder.device.DeviceFigures`, measured by :mod:`hil.analysis.measure.device` from
the plant's hop log alone), for an outside device and for the bench's own controller alike.

:func:`add_device` hooks it into a report's data (the section's place and its figures);
:func:`device_section` writes it into a section of :mod:`hil.analysis.report.content` (any
object with ``p``, ``items`` and ``table``, so that this module needs nothing of the page's)."""

from __future__ import annotations

from typing import Any

from hil.folder.device import DeviceFigures
from hil.folder.records import Percentiles

SECTION = "device"
TITLE = "The device at the bus"
LISTED = 10  # gaps listed in the page (the longest; summary.json lists more)
# The certificate's source for an outside device on CAN (hil.analysis.report.build), which the
# headline quotes (hil.analysis.report.content).
NO_D_ON_CAN = "an outside device's CAN frames name no State, so D is not measured"


def has_news(device: DeviceFigures) -> bool:
    """Whether the section has something to say: always for an outside device; for the bench's
    own controller (whose hops, compute and wake-ups the other sections show) only when it left
    a gap of its own, asked beyond (2), named a State never sent or was refused on the bus."""
    own_gap = any(g.owner == "device" for g in device.gaps)
    return (
        device.outside
        or own_gap
        or bool(device.beyond_limits)
        or device.unnamed > 0
        or device.bus.any_trouble
    )


def add_device(data: Any, device: DeviceFigures | None) -> None:
    """Put the device's figures into a report's data (report.json) and its section after the
    certificate's where it has news (:func:`has_news`); nothing without them (a simulation)."""
    if device is None:
        return
    data[SECTION] = device.as_dict()
    if not has_news(device):
        return
    sections = data["sections"]
    at = sections.index("certificate") + 1 if "certificate" in sections else len(sections)
    sections.insert(at, SECTION)


def _ms(p: Percentiles | None, key: str) -> str:
    value = (p or {}).get(key)
    return f"{value / 1e3:.3f}" if isinstance(value, int | float) else "–"


def _ms_s(value: float | None) -> str:
    return f"{value * 1e3:.3f}" if value is not None else "–"


_P_FROM = {
    "control period": "the run's control period",
    "device median": "the median of the device's own command intervals: its rate is its own",
}


def device_section(s: Any, data: Any) -> None:
    """The section (module docstring); docs/reports.md, "The device at the bus"."""
    raw = data.get(SECTION)
    if not isinstance(raw, dict):
        s.p("No device figures: the folder holds no plant hop log.")
        return
    d = DeviceFigures.from_dict(raw)
    who = "an outside device" if d.outside else "the bench's own controller, seen as a device"
    share = d.samples_in_gaps / d.samples_judged if d.samples_judged else 0.0
    s.p(
        f"What {who} did on the {d.path} path, from the plant's hop log alone (its clock; the "
        f"device's stamps are never read), against P = {d.nominal_period_s * 1e3:.3f} ms "
        f"({_P_FROM.get(d.nominal_period_from, d.nominal_period_from)}). "
        f"Samples inside its gaps (inter-arrivals ≥ 2 P): {d.samples_in_gaps} of "
        f"{d.samples_judged} ({share:.3%}), {d.samples_in_bench_gaps} more in gaps the bench's "
        'own stalls made (docs/realtime.md, "Figures of a device at the bus").'
    )
    _streams(s, d)
    _timing(s, d)
    _limits_and_bus(s, d)


def _streams(s: Any, d: DeviceFigures) -> None:
    """Per stream its period, jitter and gaps; the longest gaps, folded."""
    s.table(
        ["stream", "commands (count)", "period mean [ms]", "|interval − P| p50 / p99 / max [ms]",
         "gaps (count)", "longest gap [ms]"],
        [
            [st.name, st.commands, _ms_s(st.period_mean_s),
             f"{_ms(st.jitter, 'p50_us')} / {_ms(st.jitter, 'p99_us')} / "
             f"{_ms(st.jitter, 'max_us')}",
             st.gap_count, _ms_s(st.gap_longest_s)]
            for st in d.streams
        ],
    )  # fmt: skip
    gaps = sorted(d.gaps, key=lambda g: -g.length_s)[:LISTED]
    if gaps:
        s.table(
            ["at t [s]", "interval [ms]", "length: interval − P [ms]", "whose"],
            [[f"{g.start_s:.3f}", _ms_s(g.interval_s), _ms_s(g.length_s), g.owner]
             for g in gaps],
            fold=f"the {len(gaps)} longest gaps (the bench's: its stalls cover half or more)",
        )  # fmt: skip


def _timing(s: Any, d: DeviceFigures) -> None:
    """Response time and command age at landing, each with its two stamps."""
    start = (
        "State sent → first command naming it"
        if d.path == "zenoh"
        else "encoder frame → next torque frame of its node"
    )
    age = "lower bound: apply − newest estimate sent" if d.age_is_bound else "apply − named State"
    s.table(
        ["figure", "stamps (the plant's)", "count", "p50 [ms]", "p99 [ms]", "max [ms]"],
        [
            ["response time", start, d.response.get("count", 0), _ms(d.response, "p50_us"),
             _ms(d.response, "p99_us"), _ms(d.response, "max_us")],
            ["command age at landing", age, d.age.get("count", 0), _ms(d.age, "p50_us"),
             _ms(d.age, "p99_us"), _ms(d.age, "max_us")],
        ],
    )  # fmt: skip


def _limits_and_bus(s: Any, d: DeviceFigures) -> None:
    """Torques asked beyond (2), what else was counted; what the device did on the bus."""
    beyond = "; ".join(
        f"{b.signal} {b.count} times beyond {b.limit:.4g} (worst {b.worst_words()})"
        for b in d.beyond_limits
    )
    named = f" It named {d.unnamed} States the bench never sent (no age)." if d.unnamed else ""
    unanswered = f" {d.responses_unanswered} never answered." if d.responses_unanswered else ""
    s.p(
        (f"Asked beyond the limits of (2), before the bench clamped: {beyond}."
         if beyond else "Every torque it asked was within the limits of (2).")
        + named + unanswered
    )  # fmt: skip
    b = d.bus
    s.table(
        ["on the bus", "count"],
        [
            [name, "–" if value is None else value]
            for name, value in (
                ("state requests (Set_Axis_State)", b.state_requests),
                ("Clear_Errors", b.clear_errors),
                ("drives armed (closed loop)", b.armed),
                ("watchdog trips", b.watchdog_trips),
                ("malformed frames or messages", b.malformed),
                ("unknown frames (command, node, id)", b.unknown),
                ("refused (decoded, not accepted)", b.refused),
                ("command timeouts of the plant (zero torque)", b.command_timeouts),
                *((f"rejected: {k}", n) for k, n in b.rejections.items()),
            )
        ],
        fold="what the device did on the bus (counted, never fatal)",
    )
