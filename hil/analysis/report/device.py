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


def add_device(data: Any, device: DeviceFigures | None) -> None:
    """Put the device's figures and its section (after the certificate's) into a report's
    data; nothing without them (a simulation)."""
    if device is None:
        return
    data[SECTION] = device.as_dict()
    sections = data["sections"]
    at = sections.index("certificate") + 1 if "certificate" in sections else len(sections)
    sections.insert(at, SECTION)


def _ms(p: Percentiles | None, key: str) -> str:
    value = (p or {}).get(key)
    return f"{value / 1e3:.3f}" if isinstance(value, int | float) else "–"


def _ms_s(value: float | None) -> str:
    return f"{value * 1e3:.3f}" if value is not None else "–"


def device_section(s: Any, data: Any) -> None:
    """The section (module docstring); docs/reports.md, "The device at the bus"."""
    raw = data.get(SECTION)
    if not isinstance(raw, dict):
        s.p("No device figures: the folder holds no plant hop log.")
        return
    d = DeviceFigures.from_dict(raw)
    who = (
        "an outside device (no controller log: every figure is the plant's)"
        if d.outside
        else "the bench's own controller, seen from the plant like any device"
    )
    s.p(
        f"What the device did, measured at the bench's edge: {who}. Every stamp is the plant's "
        "(its hop log alone, one clock); the device's clock and its messages' stamps are never "
        f"read. Path: {d.path}; nominal period P = {d.nominal_period_s * 1e3:.3f} ms "
        '(docs/realtime.md, "Figures of a device at the bus").'
    )
    _streams(s, d)
    _timing(s, d)
    _limits_and_bus(s, d)


def _streams(s: Any, d: DeviceFigures) -> None:
    """Per stream its period, jitter and gaps; the longest gaps; the samples inside them."""
    s.table(
        ["stream", "commands (count)", "period mean [ms]", "period p50 / p99 [ms]",
         "jitter |interval − P| p50 / p99 / max [ms]", "gaps ≥ 2 P (count)", "longest gap [ms]",
         "first command [s]"],
        [
            [st.name, st.commands, _ms_s(st.period_mean_s),
             f"{_ms(st.period, 'p50_us')} / {_ms(st.period, 'p99_us')}",
             f"{_ms(st.jitter, 'p50_us')} / {_ms(st.jitter, 'p99_us')} / "
             f"{_ms(st.jitter, 'max_us')}",
             st.gap_count, _ms_s(st.gap_longest_s),
             f"{st.first_command_s:.3f}" if st.first_command_s is not None else "–"]
            for st in d.streams
        ],
    )  # fmt: skip
    gaps = sorted(d.gaps, key=lambda g: -g.length_s)[:LISTED]
    if gaps:
        s.p(
            "The device's gaps, longest first: an inter-arrival of at least 2 P; its length is "
            "how much later than due the next command came (interval − P). A gap the bench's "
            "own stalls (the plant late or silent, the recorder's host) cover at least half of "
            "is the bench's."
        )
        s.table(
            ["at t [s]", "interval [ms]", "length [ms]", "whose"],
            [[f"{g.start_s:.3f}", _ms_s(g.interval_s), _ms_s(g.length_s), g.owner]
             for g in gaps],
        )  # fmt: skip
    share = d.samples_in_gaps / d.samples_judged if d.samples_judged else 0.0
    s.p(
        f"Samples inside the device's own gaps: {d.samples_in_gaps} of {d.samples_judged} "
        f"({share:.3%}); inside gaps the bench made: {d.samples_in_bench_gaps}."
    )


def _timing(s: Any, d: DeviceFigures) -> None:
    """Response time and command age at landing."""
    start = (
        "the plant's send of each State to the first command naming it"
        if d.path == "zenoh"
        else "each encoder-estimate frame's entry into the path to the next torque frame of "
        "its node after it was on the bus"
    )
    age = (
        "a lower bound (apply − the sample time of the newest encoder estimate on the bus "
        "before the torque frame arrived: the device may have used an older one)"
        if d.age_is_bound
        else "exact (apply − the plant's own sample time of the State the command names)"
    )
    s.table(
        ["figure", "count", "p50 [ms]", "p99 [ms]", "max [ms]"],
        [
            ["response time", d.response.get("count", 0), _ms(d.response, "p50_us"),
             _ms(d.response, "p99_us"), _ms(d.response, "max_us")],
            ["command age at landing", d.age.get("count", 0), _ms(d.age, "p50_us"),
             _ms(d.age, "p99_us"), _ms(d.age, "max_us")],
        ],
    )  # fmt: skip
    s.items(
        [
            f"Response time: from {start}; {d.responses_unanswered} never answered.",
            f"Command age at landing: {age}.",
            f"States named that the bench never sent: {d.unnamed} (counted, no age)."
            if d.path == "zenoh"
            else "A torque frame names no State: the certificate's D is not measured for an "
            "outside device on CAN.",
        ]
    )


def _limits_and_bus(s: Any, d: DeviceFigures) -> None:
    """Torques asked beyond (2); what the device did on the bus."""
    if d.beyond_limits:
        s.p("Commands the device asked beyond the limits of (2) (before the bench clamped them):")
        s.table(
            ["signal", "limit", "commands beyond (count)", "worst asked [the limit's unit]"],
            [[b.signal, f"{b.limit:.4g}", b.count, b.worst_words()] for b in d.beyond_limits],
        )
    else:
        s.p("Every torque the device asked was within the limits of (2).")
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
            )
        ],
    )
    if b.rejections:
        s.items([f"{k}: {n}" for k, n in b.rejections.items()])
