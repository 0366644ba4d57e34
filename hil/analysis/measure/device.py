"""Figures of a device at the bus: what the controller did, seen from the plant's side alone.

The device is whatever sends the commands: an outside process (``hil run --controller
external``, with no controller.hoplog) or the bench's own controller, which the plant sees as a
device like any other. Every figure here is computed from plant.hoplog alone, every stamp on the
plant's clock (``time.monotonic_ns()`` of the plant process); the device's clock and the stamps
its messages carry are never read. The ``state_seq`` a Zenoh command names is used only to look
the State up in the plant's own ``samples`` table; a name that matches no State sent is counted
(``unnamed``), never trusted. docs/realtime.md, "Figures of a device at the bus", holds each
definition; in short:

- **command period** (per stream: the Zenoh commands, or each CAN node's ``Set_Input_Torque``
  frames): the inter-arrivals of consecutive commands, ``cmd_rx.recv_ns[i] - recv_ns[i-1]``;
  **jitter**: each inter-arrival's deviation from the nominal period P, ``|interval - P|``: for
  the bench's own controller the run's control period (``control_period_ns`` of the plant's
  log); for an outside device, whose rate the bench does not know, the median of its own
  command intervals in the window (pooled over its streams), so a device at 100 Hz beside a
  500 Hz plant is judged at its 10 ms, never as a stall every sample;
- **gaps** (the device's stalls): inter-arrivals of at least 2 P; each with its start (the
  command before it, s since the epoch), its ``interval`` and its ``length`` = interval - P
  (how much later than due the next command came: a device that stalls S ms once reads S);
  a gap is the bench's (``owner = "bench"``) when the bench's own stalls (the plant late or
  silent, the recorder's host silent; for an outside device on CAN also the silences of its
  drive's encoder estimates, ``enc_tx.send_ns`` intervals of at least twice their median: a
  device answering each estimate can only be as regular as they are) cover at least half its
  length, else the device's; the
  samples taken inside a device's gap after its first period (``samples_in_gaps``) are what the
  verdict judges (hil.verdict) where the hosted figure ``samples_without_command`` is absent;
- **response time**: Zenoh, from the plant's send of a State (``samples.send_ns``, its entry
  into the path toward the device) to the first arrival of a command naming it; CAN, from an
  encoder-estimate frame's entry into the path (``enc_tx.sample_ns``) to the first torque frame
  of that node received after the frame was on the bus (``enc_tx.send_ns``);
- **age at landing**: Zenoh, exact: ``apply_ns`` minus the plant's own ``sample_ns`` of the State
  the landed command names; CAN, a lower bound: ``apply_ns`` minus the sample time of the newest
  encoder estimate (any node) sent before the torque frame was received (the device may have
  used an older one: the true age is at least this);
- **commands beyond the limits** (2): the torques the device asked (``cmd_rx``, before any
  clamping) beyond varpi1, varpi2 (Zenoh) or beyond the largest motor torque (2) ever asks of
  one wheel (CAN, per node), counted with the worst value; a non-finite torque counts as
  beyond. v and omega against phi1, phi2 are the plant's peaks (summary.json's
  ``max_abs_v``, ``max_abs_omega``), not measured again here;
- **on the bus**: what the virtual drives counted (state requests, Clear_Errors, watchdog
  trips, arming, malformed, unknown and refused frames) and the plant's command timeouts.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from hil.analysis.measure.stalls import Stretches
from hil.analysis.measure.stats import lookup, summarize_ns, within
from hil.folder.device import (
    Beyond,
    BusActivity,
    CommandStream,
    DeviceFigures,
    DeviceLimits,
    Gap,
)
from hil.limits import LIMIT_REL_TOL
from protocol.hoplog import (
    SAMPLE_DROPPED,
    SAMPLE_FEEDBACK_LOST,
    ApplyOutcome,
    CmdPath,
    RxVerdict,
)

GAP_PERIODS = 2  # an inter-arrival of at least this many nominal periods is a gap
BENCH_SHARE = 0.5  # a gap is the bench's when its stalls cover at least this share of it
LISTED_GAPS = 20  # gaps listed (the longest first); every one is counted
__all__ = ["DeviceFigures", "DeviceLimits", "device_figures"]
LANDINGS = (ApplyOutcome.LANDED, ApplyOutcome.BURST)
# What the drives refuse, by the reason they count (plant_emulator.odrive, protocol.can.codec):
# a frame that does not decode as its id says, and one for no command or node they know. Every
# other reason is a frame that decoded and was refused.
MALFORMED = frozenset(
    {"malformed", "wrong_dlc", "out_of_range", "non_finite", "bad_id", "unexpected_rtr"}
)
UNKNOWN = frozenset({"unknown_cmd", "unknown_node"})


def _stream(
    name: str,
    node: int | None,
    recv: np.ndarray,
    period: int,
    epoch: int,
    bench: Stretches,
) -> tuple[CommandStream, list[tuple[int, int, str]]]:
    """One stream's figures, and its gaps' silences [due, next arrival] with their owners."""
    recv = np.sort(recv)
    iv = np.diff(recv)
    gap = iv >= GAP_PERIODS * period
    starts, ivs = recv[:-1][gap], iv[gap]
    lengths = ivs - period
    owners = [
        "bench" if bench.covered(int(a), int(a + i)) >= BENCH_SHARE * int(n) else "device"
        for a, i, n in zip(starts.tolist(), ivs.tolist(), lengths.tolist(), strict=True)
    ]
    listed = np.argsort(-lengths, kind="stable")[:LISTED_GAPS]
    gaps = [
        Gap((int(starts[k]) - epoch) / 1e9, int(ivs[k]) / 1e9, int(lengths[k]) / 1e9, owners[k])
        for k in sorted(listed.tolist(), key=lambda k: int(starts[k]))
    ]
    silences = [
        (int(a) + period, int(a + i), o)
        for a, i, o in zip(starts.tolist(), ivs.tolist(), owners, strict=True)
    ]
    out = CommandStream(
        name=name,
        node=node,
        commands=int(recv.size),
        period=summarize_ns(iv),
        period_mean_s=float(iv.mean()) / 1e9 if iv.size else None,
        jitter=summarize_ns(np.abs(iv - period)),
        gap_count=int(gap.sum()),
        gap_longest_s=int(lengths.max()) / 1e9 if lengths.size else None,
        gaps=gaps,
        first_command_s=(int(recv[0]) - epoch) / 1e9 if recv.size else None,
    )
    return out, silences


def _first_arrival(keys: np.ndarray, recv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(distinct keys, the earliest arrival of each)."""
    if keys.size == 0:
        return keys.astype(np.int64), recv.astype(np.int64)
    order = np.lexsort((recv, keys))
    k, r = keys[order], recv[order]
    first = np.ones(k.size, bool)
    first[1:] = k[1:] != k[:-1]
    return k[first], r[first]


def _beyond(signal: str, values: np.ndarray, limit: float | None) -> Beyond | None:
    if limit is None or values.size == 0:
        return None
    v = np.asarray(values, float)
    over = ~np.isfinite(v) | (np.abs(v) > limit * (1.0 + LIMIT_REL_TOL))
    if not over.any():
        return None
    bad = v[over]
    finite = bad[np.isfinite(bad)]
    worst = float(finite[np.argmax(np.abs(finite))]) if finite.size else None
    return Beyond(signal, float(limit), int(over.sum()), worst, int(bad.size - finite.size))


def bus_activity(pinfo: Mapping[str, Any], path: str) -> BusActivity:
    """The drives' and the plant's counters of what the device did (module docstring)."""
    can = pinfo.get("can") if path == "can" else None
    can = can if isinstance(can, dict) else {}
    events = can.get("events") or {}
    rej: dict[str, int] = {}
    for src in (can.get("rejections") or {}, pinfo.get("rejections") or {}):
        for k, n in src.items():
            if isinstance(n, int):
                rej[k] = rej.get(k, 0) + n
    ignored = {k: n for k, n in (can.get("ignored") or {}).items() if isinstance(n, int)}

    def ev(name: str) -> int | None:
        return int(events.get(name, 0)) if can else None

    return BusActivity(
        state_requests=ev("state_requests"),
        clear_errors=ev("clear_errors"),
        watchdog_trips=ev("watchdog_expired"),
        armed=ev("armed"),
        malformed=sum(n for k, n in rej.items() if k in MALFORMED),
        unknown=sum(n for k, n in rej.items() if k in UNKNOWN) + sum(ignored.values()),
        refused=sum(n for k, n in rej.items() if k not in MALFORMED | UNKNOWN),
        command_timeouts=int(pinfo.get("timeouts") or 0),
        rejections=dict(sorted(rej.items())),
    )


def device_figures(
    tables: Mapping[str, Mapping[str, np.ndarray]],
    pmeta: Mapping[str, Any],
    pinfo: Mapping[str, Any],
    limits: DeviceLimits | None,
    bench: Stretches | None = None,
    outside: bool = False,
) -> DeviceFigures | None:
    """The device's figures from the plant's tables (``samples``, ``cmd_rx``, ``apply``,
    ``enc_tx``), meta and counters; ``bench``: the bench's own stalls (plant, recorder's host);
    None when the plant took no sample."""
    s, rx, ap = tables["samples"], tables["cmd_rx"], tables["apply"]
    enc = tables.get("enc_tx") or {}
    sn = s["sample_ns"]
    if sn.size == 0:
        return None
    w0, w1 = int(sn[0]), int(sn[-1])
    epoch = int(pmeta.get("epoch_ns") or w0)
    period = int(pmeta.get("control_period_ns") or 0) or int(pmeta.get("sensor_period_ns") or 1)
    path = str(pmeta.get("cmd_path") or "zenoh")
    bench = bench if bench is not None else Stretches.none()
    on_path = command_arrivals(rx, path)
    inwin = on_path & within(rx["recv_ns"], w0, w1)
    period_from = "control period"
    if outside:
        own = _median_interval(rx, inwin, path)
        period, period_from = (own, "device median") if own > 0 else (period, period_from)
        if path == "can":
            bench = bench.union(_feedback_silences(enc, w0, w1, GAP_PERIODS * period))

    streams, in_dev, in_bench = _streams(rx, inwin, path, sn, period, epoch, bench)
    sample_of_seq = (s["seq"], sn)
    unnamed = 0
    beyond: list[Beyond] = []
    if path == "can":
        response, unanswered = _can_response(enc, rx, on_path, w0, w1)
        age = _can_age_bound(enc, ap, w0, w1)
        for n in np.unique(rx["node"][inwin]).tolist():
            mot = limits.motor_nm if limits is not None else None
            b = _beyond(f"q node {n}", rx["tau1"][inwin & (rx["node"] == n)], mot)
            beyond += [b] if b is not None else []
    else:
        sent = (s["send_ns"] > 0) & within(s["send_ns"], w0, w1)
        sent &= (s["flags"] & (SAMPLE_DROPPED | SAMPLE_FEEDBACK_LOST)) == 0  # never on the wire
        named, first = _first_arrival(rx["state_seq"][on_path], rx["recv_ns"][on_path])
        send_of, found = lookup(s["seq"][sent], s["send_ns"][sent], named, missing=0)
        response = (first - send_of)[found]
        unanswered = int(sent.sum()) - int(found.sum())
        _, known = lookup(*sample_of_seq, rx["state_seq"][inwin], missing=0)
        unnamed = int((~known).sum())
        age = _zenoh_age(s, rx, ap, on_path, w0, w1)
        for sig, col, lim in (("tau1", "tau1", limits and limits.varpi1),
                              ("tau2", "tau2", limits and limits.varpi2)):  # fmt: skip
            b = _beyond(sig, rx[col][inwin], lim or None)
            beyond += [b] if b is not None else []

    return DeviceFigures(
        path=path,
        outside=outside,
        nominal_period_s=period / 1e9,
        streams=streams,
        response=summarize_ns(response),
        responses_unanswered=unanswered,
        age=summarize_ns(age),
        age_is_bound=path == "can",
        d_max_s=int(age.max()) / 1e9 if age.size else None,
        unnamed=unnamed,
        beyond_limits=beyond,
        bus=bus_activity(pinfo, path),
        samples_judged=int(sn.size),
        samples_in_gaps=in_dev,
        samples_in_bench_gaps=in_bench,
        nominal_period_from=period_from,
    )


def command_arrivals(rx: dict[str, np.ndarray], path: str) -> np.ndarray:
    """Per cmd_rx row: an arrival of the applied path's command stream. A Zenoh command that
    arrived twice was sent once: its second arrival is no command of the stream (a CAN frame
    carries no number to tell)."""
    on_path = rx["path"] == (CmdPath.CAN if path == "can" else CmdPath.ZENOH)
    return on_path & (rx["verdict"] != RxVerdict.DUPLICATE)


def _median_interval(rx, inwin: np.ndarray, path: str) -> int:
    """The median of a device's command intervals in the window, pooled over its streams
    (each CAN node's own), in ns; 0 with fewer than two commands in any stream."""
    keys = rx["node"][inwin] if path == "can" else np.zeros(int(inwin.sum()), np.int64)
    recv = rx["recv_ns"][inwin]
    ivs = [np.diff(np.sort(recv[keys == k])) for k in np.unique(keys).tolist()]
    pooled = np.concatenate(ivs) if ivs else np.zeros(0, np.int64)
    return int(np.median(pooled)) if pooled.size else 0


def _feedback_silences(enc, w0: int, w1: int, at_least: int) -> Stretches:
    """Where a drive's encoder estimates went silent for ``at_least`` ns or more (per node;
    the device's own gap length): the bench's silence toward a device that answers them."""
    if not enc or enc["node"].size == 0:
        return Stretches.none()
    out = Stretches.none()
    sent = enc["send_ns"]
    for n in np.unique(enc["node"]).tolist():
        mine = sent[(enc["node"] == n) & within(sent, w0, w1)]
        out = out.union(Stretches.silences(mine, at_least))
    return out


def _streams(
    rx, inwin: np.ndarray, path: str, sn: np.ndarray, period: int, epoch: int, bench: Stretches
) -> tuple[list[CommandStream], int, int]:
    """The command streams (Zenoh, or one per CAN node) and the samples (every one the plant
    took) inside the device's own gaps and inside the bench's, after each gap's first period."""
    streams: list[CommandStream] = []
    silences: list[tuple[int, int, str]] = []
    if path == "can":
        for n in np.unique(rx["node"][inwin]).tolist():
            st, sil = _stream(f"node {n}", int(n), rx["recv_ns"][inwin & (rx["node"] == n)],
                              period, epoch, bench)  # fmt: skip
            streams.append(st)
            silences += sil
    else:
        st, silences = _stream("zenoh", None, rx["recv_ns"][inwin], period, epoch, bench)
        streams.append(st)
    in_dev = np.zeros(sn.size, bool)
    in_bench = np.zeros(sn.size, bool)
    for lo, hi, owner in silences:
        m = (sn > lo) & (sn < hi)
        (in_bench if owner == "bench" else in_dev)[m] = True
    in_bench &= ~in_dev
    return streams, int(in_dev.sum()), int(in_bench.sum())


def _zenoh_age(s, rx, ap, on_path, w0: int, w1: int) -> np.ndarray:
    """apply_ns - the plant's own sample_ns of the State each landed command names."""
    landed = np.isin(ap["outcome"], LANDINGS) & (ap["path"] == CmdPath.ZENOH)
    landed &= within(ap["apply_ns"], w0, w1)
    # the command's name for its State, from its first arrival (never its own stamps)
    seq, first_row = np.unique(rx["seq"][on_path], return_index=True)
    names = rx["state_seq"][on_path][first_row]
    named, has = lookup(seq, names, ap["seq"][landed], missing=0)
    sample, known = lookup(s["seq"], s["sample_ns"], named, missing=0)
    ok = has & known
    return (ap["apply_ns"][landed] - sample)[ok]


def _can_response(enc, rx, on_path, w0: int, w1: int) -> tuple[np.ndarray, int]:
    """Per encoder estimate sent in the window: the first torque frame of its node received
    after it was on the bus, less its entry into the path; and how many had none."""
    if not enc or enc["node"].size == 0:
        return np.zeros(0, np.int64), 0
    out, unanswered = [], 0
    inwin = within(enc["sample_ns"], w0, w1)
    for n in np.unique(enc["node"][inwin]).tolist():
        mine = inwin & (enc["node"] == n)
        recv = np.sort(rx["recv_ns"][on_path & (rx["node"] == n)])
        sent, samp = enc["send_ns"][mine], enc["sample_ns"][mine]
        k = np.searchsorted(recv, sent, side="right")
        ok = k < recv.size
        unanswered += int((~ok).sum())
        out.append(recv[k[ok]] - samp[ok])
    return (np.concatenate(out) if out else np.zeros(0, np.int64)), unanswered


def _can_age_bound(enc, ap, w0: int, w1: int) -> np.ndarray:
    """Per landed torque frame: apply_ns - the sample time of the newest encoder estimate (any
    node) on the bus before the frame was received (a lower bound of its age), counted from the
    window's start at the earliest, as the hosted age is: before the run the plant does not
    step, and the estimates the drives sent while the bench waited for the device are as old
    as that wait (seen: 1.04 s at the first landing), which is the bench's start, not the
    device's age."""
    landed = np.isin(ap["outcome"], LANDINGS) & (ap["path"] == CmdPath.CAN)
    landed &= within(ap["apply_ns"], w0, w1)
    if not enc or enc["node"].size == 0 or not landed.any():
        return np.zeros(0, np.int64)
    order = np.argsort(enc["send_ns"], kind="stable")
    sent, samp = enc["send_ns"][order], enc["sample_ns"][order]
    newest = np.maximum.accumulate(samp)  # the newest content on the bus by then
    k = np.searchsorted(sent, ap["recv_ns"][landed], side="left") - 1
    ok = k >= 0
    return (ap["apply_ns"][landed][ok] - np.maximum(newest[k[ok]], w0)).astype(np.int64)
