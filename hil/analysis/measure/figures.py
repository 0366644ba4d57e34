"""Every timing figure, message count and the certificate of a run, from its hop logs alone.

This is the one implementation: ``summary.json``, the report, ``hil compare`` and latency
replay (run folder or ``.mcap``) all read :func:`measure`'s result. The definitions (which
clock, which two stamps) are in docs/realtime.md, "Timing figures"; in short, every stamp is
``time.monotonic_ns()`` on one host, and every figure counts only the window in which both
services ran: from the plant's first sample to its last.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property
from typing import Any

import numpy as np

from controller_service.certificate import certify, critical_age
from hil.analysis.measure import age as agemod
from hil.analysis.measure.can_match import UNMATCHED, match_node
from hil.analysis.measure.device import (
    DeviceFigures,
    DeviceLimits,
    command_arrivals,
    device_figures,
)
from hil.analysis.measure.host import RECORDER_SILENT_NS, host_figures
from hil.analysis.measure.logs import RunLogs
from hil.analysis.measure.stalls import Stamped, Stretches, find_stalls, host_windows
from hil.analysis.measure.stats import lookup as _lookup
from hil.analysis.measure.stats import summarize_ns
from hil.analysis.measure.stats import within as _in
from hil.folder.rates import ratio
from hil.folder.records import (
    Certificate,
    HostLoad,
    Messages,
    Percentiles,
    StreamCounts,
    Summary,
    TickPhase,
    Timing,
)
from hil.folder.scenario_view import BoundInputs
from hil.verdict import control_slot
from protocol.can.codec import MAX_NODE_ID
from protocol.hoplog import (
    SAMPLE_DROPPED,
    SAMPLE_DUPLICATED,
    TICK_DROPPED,
    TICK_DUPLICATED,
    TICK_NO_SEND,
    TICK_REORDERED,
    ApplyOutcome,
    CmdPath,
    RxVerdict,
)
from protocol.settings import CMD_PATHS

PATHS = CMD_PATHS
_NODES = MAX_NODE_ID + 1  # the node part of a frame key (_frame_keys)
LANDINGS = (ApplyOutcome.LANDED, ApplyOutcome.BURST)  # apply outcomes that put a command in force
# A torque frame dropped by the drives' own socket was sent at most this long before the read
# that found the drop's window open (its flight on the bus to the socket: microseconds).
BUS_FLIGHT_NS = 2_000_000
# A service that logs nothing for this many of its periods was not running (stopped, or its host
# not running it): a loop on time logs every period, and its stamps' jitter alone can stretch
# one gap a little past a period.
SILENT_PERIODS = 2


#: The measurement's per-sample series (numpy arrays) and the applied path's name.
Series = dict[str, "np.ndarray | str"]


@dataclass
class Measurement:
    """The one result: the contract's ``timing``, ``messages`` and ``certificate`` objects, and
    the per-sample series that plots and latency replay read."""

    timing: Timing = field(default_factory=lambda: Timing())
    messages: Messages = field(default_factory=dict)
    certificate: Certificate | None = None
    series: Series = field(default_factory=dict)
    window_ns: tuple[int, int] = (0, 0)
    # the bench's host over the window (hil.analysis.measure.host)
    host: HostLoad | None = None
    epoch_ns: int | None = None  # the run's time origin (trace.csv's t = 0)
    # the device at the bus, from the plant's log alone (hil.analysis.measure.device)
    device: DeviceFigures | None = None

    def arrays(self) -> dict[str, np.ndarray]:
        """The series as flat named arrays (what the folder saves as series.npz): an age
        series as NAME.start/.end/.sample, a time series as NAME.t/.v."""
        out: dict[str, np.ndarray] = {"epoch_ns": np.asarray(self.epoch_ns or 0, np.int64)}
        for key, value in self.series.items():
            if isinstance(value, agemod.AgeSegments):
                for part in ("start", "end", "sample"):
                    out[f"{key}.{part}"] = np.asarray(getattr(value, part))
            elif isinstance(value, tuple):
                out[f"{key}.t"], out[f"{key}.v"] = (np.asarray(v) for v in value)
            else:
                out[key] = np.asarray(value)
        return out

    @classmethod
    def from_saved(cls, summary: Summary, arrays: dict[str, np.ndarray]) -> Measurement:
        """The measurement as a folder holds it: summary.json's objects and the saved series
        (:meth:`arrays`), nothing recomputed."""
        series: Series = {}
        for key, value in arrays.items():
            name, _, part = key.partition(".")
            if part == "start":
                series[name] = agemod.AgeSegments(
                    value, arrays[f"{name}.end"], arrays[f"{name}.sample"]
                )
            elif part == "t":
                series[name] = (value, arrays[f"{name}.v"])
            elif not part and key != "epoch_ns":
                series[key] = str(value) if value.dtype.kind == "U" else value
        timing = summary.get("timing")
        device = summary.get("device")
        return cls(
            timing=timing if isinstance(timing, dict) else {},
            messages=summary.get("messages") or {},
            certificate=summary.get("certificate"),
            series=series,
            host=summary.get("host"),
            epoch_ns=int(arrays["epoch_ns"]) if "epoch_ns" in arrays else None,
            device=DeviceFigures.from_dict(device) if isinstance(device, dict) else None,
        )

    def latency_us(self) -> dict[str, np.ndarray]:
        """Sample-to-apply latency per path in µs (applied: apply - sample, shadow: receive -
        sample), one value per command: what histograms and replay use."""
        return {
            p: np.asarray(self.series[f"sample_to_apply_{p}"], dtype=float) / 1000.0
            for p in PATHS
            if len(self.series.get(f"sample_to_apply_{p}", ()))
        }


def _first_per_key(keys: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(distinct keys, the value of each key's first occurrence)."""
    uniq, first = np.unique(keys, return_index=True)
    return uniq, values[first]


def _in_flight(sent_ids: np.ndarray, rx_ids: np.ndarray, known_lost: np.ndarray) -> np.ndarray:
    """Of ``sent_ids`` (ids in the order sent), those sent after the newest that arrived and
    never received, less ``known_lost`` (the [faults] drops): in flight when the receiver
    stopped. Zenoh delivers one publisher's messages in order over its reliable link (TCP), so
    a message older than one that arrived and missing is lost, but one of these may only have
    been held up (a retransmission at the run's end) when the run stopped its receiver: the
    logs cannot call it lost, and its wait is in the command age. None arrived: none."""
    sent = np.unique(sent_ids)
    rx = rx_ids[np.isin(rx_ids, sent)]
    if rx.size == 0:
        return sent[:0]
    late = sent[sent > rx.max()]
    return late[~np.isin(late, known_lost)]


def _stream_counts(
    sent_ids: np.ndarray, rx_ids: np.ndarray, known_lost: np.ndarray | None = None
) -> dict[str, int]:
    """sent, received (distinct ids that were sent), lost, duplicated, reordered and
    in_flight_at_stop (:func:`_in_flight`): one definition for every stream; received + lost +
    in_flight_at_stop = sent. Reordered: a sent id's first arrival older than any arrival
    before it, of whatever id (one sent just after the window overtook it all the same)."""
    sent = np.unique(sent_ids)
    ours = np.isin(rx_ids, sent)
    ids, first_of = np.unique(rx_ids, return_index=True)
    distinct = ids[np.isin(ids, sent)]
    first = np.zeros(rx_ids.size, bool)
    first[first_of] = True
    overtaken = np.zeros(rx_ids.size, bool)
    overtaken[1:] = rx_ids[1:] < np.maximum.accumulate(rx_ids)[:-1]
    flying = _in_flight(sent_ids, rx_ids, known_lost if known_lost is not None else sent[:0])
    return {
        "sent": int(sent.size),
        "received": int(distinct.size),
        "lost": int(sent.size - distinct.size - flying.size),
        "duplicated": int(ours.sum() - distinct.size),
        "reordered": int((overtaken & first & ours).sum()),
        "in_flight_at_stop": int(flying.size),
    }


class _Run:
    """The joins every figure needs, computed once."""

    def __init__(self, logs: RunLogs) -> None:
        self.logs = logs
        cm, pm = logs.cmeta, logs.pmeta
        self.epoch = logs.epoch_ns
        self.period = int(cm.get("period_ns") or pm.get("control_period_ns") or 0)
        self.ts = int(pm.get("control_period_ns") or self.period)
        self.sensor_period = int(pm.get("sensor_period_ns") or self.period)
        self.h = int(pm.get("plant_step_ns") or max(1, self.ts // 10))
        self.applied = str(pm.get("cmd_path") or cm.get("cmd_path") or "zenoh")
        self.lockstep = bool(pm.get("lockstep") or cm.get("lockstep"))
        self.trigger = str(cm.get("trigger") or "periodic")
        # An outside device: no log of its own; the bench sees only what reached the plant.
        self.outside = logs.controller is None
        self.settle = 2 * self.ts + int(
            1e9 * (float(pm.get("delay_s") or 0.0) + float(pm.get("jitter_s") or 0.0))
        )
        self.samples, self.ticks = logs["samples"], logs["ticks"]
        sn = self.samples["sample_ns"]
        self.w0, self.w1 = (int(sn[0]), int(sn[-1])) if sn.size else (0, 0)
        # cmd_seq -> its tick row (the controller's own record, not what the message claims),
        # sorted by cmd_seq once: every join by command (tick_of) is then a search, not a sort.
        seq = self.ticks["cmd_seq"]
        rows = np.nonzero(seq >= 0)[0]
        self.cmd_rows = rows[np.argsort(seq[rows], kind="stable")]
        self.cmd_keys = seq[self.cmd_rows]
        self._can = self._match_can()
        self.series_without: np.ndarray | None = None  # sample times left without a command
        # Per sample (or slot) left without a command: the plant's lateness made it so
        self.without_plant_late: np.ndarray | None = None

    def _match_can(self) -> dict[str, np.ndarray]:
        """Every CAN torque frame a drive received, matched to its send
        (hil.analysis.measure.can_match),
        with the earliest match beside it (``cmd_early``: the command age's upper bound),
        duplicates, the ``ambiguous`` ones and the ``lost`` ones ([faults] frame loss);
        ``value_mismatches`` counts frames whose torque differs from their send's."""
        rx, tx = self.logs["cmd_rx"], self.logs["can_tx"]
        is_can = rx["path"] == CmdPath.CAN
        node, idx, recv = rx["node"][is_can], rx["seq"][is_can], rx["recv_ns"][is_can]
        named, value = rx["send_ns"][is_can], rx["tau1"][is_can]
        n_rx = node.size
        out = {
            "node": node, "index": idx, "recv": recv, "send": np.zeros(n_rx, np.int64),
            "cmd": np.full(n_rx, UNMATCHED, np.int64),
            "cmd_early": np.full(n_rx, UNMATCHED, np.int64),
            "lost": rx["verdict"][is_can] == RxVerdict.LOST_BY_FAULT,
            "duplicated": np.zeros(n_rx, bool), "ambiguous": np.zeros(n_rx, bool),
        }  # fmt: skip
        self._frame_match: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
        self.value_mismatches = 0
        self.can_reordered: dict[int, int] = {}
        self.can_realigned = 0
        on_bus = tx["send_ns"] > 0
        for n in np.unique(np.concatenate([node, tx["node"][on_bus]])).tolist():
            mine = on_bus & (tx["node"] == n)
            tsend, tcmd, tval = tx["send_ns"][mine], tx["cmd_seq"][mine], tx["value"][mine]
            rows = np.nonzero(node == n)[0]
            nm = match_node(
                tsend, tval, tx["bus_end_ns"][mine], recv[rows], value[rows], named[rows]
            )
            ok, oke = nm.chosen >= 0, nm.earliest >= 0
            out["send"][rows[ok]] = tsend[nm.chosen[ok]]
            out["cmd"][rows[ok]] = tcmd[nm.chosen[ok]]
            out["cmd_early"][rows[oke]] = tcmd[nm.earliest[oke]]
            out["duplicated"][rows] = nm.duplicated
            out["ambiguous"][rows] = nm.ambiguous
            same = np.float32(value[rows[ok]]) == np.float32(tval[nm.chosen[ok]])
            self.value_mismatches += int((~same).sum())
            self.can_reordered[int(n)] = nm.reordered
            self.can_realigned += nm.realigned
            self._frame_match[int(n)] = (idx[rows], out["cmd"][rows], out["cmd_early"][rows])
        return out

    def can_frame_of(self, node: np.ndarray, index: np.ndarray, early: bool = False) -> np.ndarray:
        """cmd_seq (-1 lifecycle, -2 unmatched) of received CAN frames given as (node, the
        frame's index among those its drive received); ``early``: the earliest match."""
        out = np.full(node.size, UNMATCHED, np.int64)
        for n, (idx, cmd, cmd_early) in self._frame_match.items():
            mine = np.nonzero(node == n)[0]
            if idx.size == 0 or mine.size == 0:
                continue
            # The last frame with that index wins (a restarted plant counts from 0 again).
            order = np.argsort(idx, kind="stable")
            ks = idx[order]
            pos = np.searchsorted(ks, index[mine], side="right") - 1
            found = (pos >= 0) & (ks[np.maximum(pos, 0)] == index[mine])
            out[mine[found]] = (cmd_early if early else cmd)[order[pos[found]]]
        return out

    def landings(
        self, path: str, applied: bool, early: bool = False
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(land_ns, sample_ns, cmd_seq) per command put in force, newest wins; for a shadow
        path the arrival stands for the landing (what would have been applied). ``early``: CAN
        frames matched to the earliest sends the logs allow (the age's upper bound)."""
        if path == "can":
            c, at = (self.can_applies, "land") if applied else (self._can, "recv")
            m = np.isin(c["outcome"], LANDINGS) if applied else ~c["lost"]
            cmd = c["cmd_early" if early else "cmd"]
            return self._in_force(c["node"][m], c[at][m], cmd[m])
        if applied:
            ap = self.logs["apply"]
            m = np.isin(ap["outcome"], LANDINGS) & (ap["path"] == CmdPath.ZENOH)
            cmd, land = ap["seq"][m], ap["apply_ns"][m]
        else:
            rx = self.logs["cmd_rx"]
            m = rx["path"] == CmdPath.ZENOH
            cmd, land = rx["seq"][m], rx["recv_ns"][m]
        return self._in_force(np.zeros(cmd.size, np.int64), land, cmd)  # one 'wheel'

    @cached_property
    def can_applies(self) -> dict[str, np.ndarray]:
        """The plant's CAN apply rows (every outcome) with the command each frame carried."""
        ap = self.logs["apply"]
        m = ap["path"] == CmdPath.CAN
        node = ap["node"][m]
        return {
            "node": node,
            "land": ap["apply_ns"][m],
            "cmd": self.can_frame_of(node, ap["seq"][m]),
            "cmd_early": self.can_frame_of(node, ap["seq"][m], early=True),
            "outcome": ap["outcome"][m],
        }

    def host_over(self, lo: int, hi: int) -> HostLoad | None:
        """The bench's host over [lo, hi] (hil.analysis.measure.host), None without a host log."""
        meta = self.logs.host.meta if self.logs.host is not None else {}
        return host_figures(self.logs["host"], meta, lo, hi) if "host" in self.logs.tables else None

    # What a stall's cause joins (hil.analysis.measure.stalls), sorted by time once.
    @cached_property
    def wake_sorted(self) -> Stamped:
        t = self.ticks
        return Stamped.by_time(t["wake_ns"], late=t["wake_ns"] - t["deadline_ns"])

    @cached_property
    def state_received(self) -> np.ndarray:
        """Per plant sample: its State reached the controller. An outside device's receipts are
        not seen: none is called lost (its silences are its stalls, :meth:`controller_stalls`)."""
        if self.outside:
            return np.ones(self.samples["seq"].size, bool)
        return np.isin(self.samples["seq"], self.logs["state_rx"]["seq"])

    @cached_property
    def state_injected_drop(self) -> np.ndarray:
        return (self.samples["flags"] & SAMPLE_DROPPED) != 0

    @cached_property
    def state_hops_sorted(self) -> Stamped:
        """State hops (controller receive - plant send) by sample time, of every State that
        arrived: a State the wire held up (a TCP retransmission) is often superseded before a
        tick uses it, and only its arrival row shows the hold."""
        rx = self.logs["state_rx"]
        ok = (rx["recv_ns"] > 0) & (rx["send_ns"] > 0)
        return Stamped.by_time(
            rx["sample_ns"][ok], hop=(rx["recv_ns"] - rx["send_ns"])[ok], start=rx["send_ns"][ok]
        )

    @cached_property
    def commands_sorted(self) -> Stamped:
        """The applied path's commands by when they were computed: arrived or not, dropped by
        a [faults] injection, and their hop (-1: never arrived)."""
        t = self.ticks
        if self.applied == "zenoh":
            rx = self.logs["cmd_rx"]
            z = rx["path"] == CmdPath.ZENOH
            seq, recv = _first_per_key(rx["seq"][z], rx["recv_ns"][z])
            sent = (t["zenoh_send_ns"] > 0) & (t["cmd_seq"] >= 0)
            stamps, cmd = t["zenoh_send_ns"][sent], t["cmd_seq"][sent]
            injected = (t["flags"][sent] & (TICK_DROPPED | TICK_REORDERED)) != 0
            off_bus = np.zeros(cmd.size, bool)
            by_bench = np.zeros(cmd.size, bool)  # Zenoh's own drops are not countable
        else:
            c = self._can
            got = (c["cmd"] >= 0) & ~c["lost"]
            seq, recv = _first_per_key(c["cmd"][got], c["recv"][got])
            tx = self.logs["can_tx"]
            mine = tx["cmd_seq"] >= 0
            cmd, first = np.unique(tx["cmd_seq"][mine], return_index=True)
            put = tx["send_ns"][mine][first]
            rows, found = self.tick_of(cmd)
            stamps = np.where(found, self.ticks["compute_start_ns"][np.where(found, rows, 0)], put)
            lost_by_fault = np.unique(c["cmd"][c["lost"] & (c["cmd"] >= 0)])
            injected = np.isin(cmd, lost_by_fault)
            off_bus = put <= 0
            by_bench = np.isin(cmd, self.commands_dropped_by_bench)
        arr, found = _lookup(seq, recv, cmd)
        hop = np.where(found, arr - stamps, -1)
        return Stamped.by_time(
            stamps, arrived=found, injected=injected, hop=hop, off_bus=off_bus, by_bench=by_bench
        )

    @cached_property
    def can_frames_lost(self) -> np.ndarray:
        """Per can_tx row: a torque frame put on the bus that no drive received (by the
        matching, hil.analysis.measure.can_match; a [faults] loss counts as not received)."""
        tx, c = self.logs["can_tx"], self._can
        got = (c["cmd"] >= 0) & ~c["lost"]
        received = np.unique(_frame_keys(c["cmd"][got], c["node"][got]))
        sent = (tx["cmd_seq"] >= 0) & (tx["send_ns"] > 0)
        return sent & ~np.isin(_frame_keys(tx["cmd_seq"], tx["node"]), received)

    @cached_property
    def frames_dropped_by_bench(self) -> np.ndarray:
        """Per can_tx row: a torque frame put on the bus, never received, and dropped by the
        drives' own receiving socket (its queue full: the plant's ``socket_drops`` log). Each
        drop the socket counted explains at most one frame sent in its window (less the bus's
        flight, :data:`BUS_FLIGHT_NS`), oldest first. Frames carry no number: a frame lost among
        its node's frames of the same bytes sent back to back (a held zero torque while the plant
        was stopped) is, for the logs, any one of them (hil.analysis.measure.can_match puts such
        losses last), so a drop explains it if its window holds any frame of that run."""
        tx = self.logs["can_tx"]
        out = np.zeros(tx["node"].size, bool)
        d = self.logs["socket_drops"]
        if d["dropped"].size == 0:
            return out
        rows = np.nonzero(self.can_frames_lost)[0]
        rows = rows[np.argsort(tx["send_ns"][rows], kind="stable")]
        first, last = _same_bytes_runs(tx)
        first, last = first[rows], last[rows]
        for since, seen, n in zip(d["since_ns"].tolist(), d["seen_ns"].tolist(),
                                  d["dropped"].tolist(), strict=True):  # fmt: skip
            inside = (first <= seen) & (last >= since - BUS_FLIGHT_NS) & ~out[rows]
            out[rows[np.nonzero(inside)[0][: int(n)]]] = True
        return out

    @cached_property
    def commands_dropped_by_bench(self) -> np.ndarray:
        """Commands with a frame lost, every lost frame of them dropped by the drives' own
        socket (:attr:`frames_dropped_by_bench`)."""
        tx = self.logs["can_tx"]
        by = self.frames_dropped_by_bench
        if not by.any():
            return np.zeros(0, np.int64)
        cand = np.unique(tx["cmd_seq"][by])
        other = np.unique(tx["cmd_seq"][self.can_frames_lost & ~by])  # a frame lost elsewhere too
        return cand[~np.isin(cand, other)]

    @cached_property
    def burst_sorted(self) -> Stamped:
        """Landings a [faults] burst delayed, by landing time, with the delay."""
        ap = self.logs["apply"]
        b = ap["outcome"] == ApplyOutcome.BURST
        return Stamped.by_time(ap["apply_ns"][b], hop=(ap["apply_ns"] - ap["recv_ns"])[b])

    @cached_property
    def sample_slots(self) -> np.ndarray | None:
        """Per plant sample, the control slot meant to answer it, when the controller answers
        one sample per control period (periodic, its period longer than the plant's sample
        period); None when it is meant to answer every sample (the rates equal, a slower
        sensor, on_state, lockstep). A sample's slot is the first whose deadline is at or
        after the sample (:func:`control_slot`): that slot's tick takes the newest State in
        hand, one of the samples taken since the previous deadline. The deadlines are the
        controller's own (its ticks', a learnt phase's shift included; the slots it skipped
        on their grid); with no tick, the nominal grid half a period after the epoch."""
        if self.trigger != "periodic" or self.lockstep or self.sensor_period >= self.period:
            return None
        sn = self.samples["sample_ns"]
        grid = self._deadline_grid
        if grid is None:
            return control_slot(sn, self.epoch + self.period // 2, self.period)
        # Samples before the first tick belong to it, those after the last to one more slot.
        return np.searchsorted(grid, sn, side="left")

    @cached_property
    def _deadline_grid(self) -> np.ndarray | None:
        """The controller's deadlines, one per slot from its first tick to its last (its
        ticks', a learnt phase's shift included; the slots it skipped on their grid); None
        with no tick."""
        t = self.ticks
        mine = t["k"] >= 0
        k, deadline = t["k"][mine], t["deadline_ns"][mine]
        if k.size == 0:
            return None
        k, first = np.unique(k, return_index=True)
        deadline = deadline[first]
        every = np.arange(int(k[0]), int(k[-1]) + 1)
        pos = np.searchsorted(k, every, side="right") - 1
        return deadline[pos] + (every - k[pos]) * self.period

    @cached_property
    def state_timing_at_tick(self) -> tuple[np.ndarray, np.ndarray] | None:
        """Per plant sample, against the tick of the slot meant to answer it (the first due at
        or after the sample): (its State was in hand when that tick woke; its State came after,
        yet would have been in hand had the plant woken on time: its arrival less the plant's
        wake-up lateness). None without deadlines (on_state, lockstep). A State never
        received, or a slot with no tick (skipped, after the last), is neither."""
        if self.trigger != "periodic" or self.lockstep:
            return None
        s, t = self.samples, self.ticks
        grid = self._deadline_grid
        n = s["sample_ns"].size
        if grid is None:
            return np.zeros(n, bool), np.zeros(n, bool)
        mine = t["k"] >= 0
        k, first = np.unique(t["k"][mine], return_index=True)
        wake_of_slot = np.full(grid.size, -1, np.int64)  # -1: no tick woke for the slot
        wake_of_slot[k - k[0]] = t["wake_ns"][mine][first]
        slot = np.searchsorted(grid, s["sample_ns"], side="left")
        wake = np.where(slot < grid.size, wake_of_slot[np.minimum(slot, grid.size - 1)], -1)
        rx = self.logs["state_rx"]
        seq, recv = _first_per_key(rx["seq"], rx["recv_ns"])
        recv, got = _lookup(seq, recv, s["seq"], ordered=True)
        ticked = got & (wake >= 0)
        in_hand = ticked & (recv <= wake)
        plant_late = np.maximum(s["wake_ns"] - s["sample_ns"], 0)
        missed_by_plant = ticked & (recv > wake) & (recv - plant_late <= wake)
        return in_hand, missed_by_plant

    @cached_property
    def controller_stalls(self) -> Stretches:
        """Where the controller stalled (hil.analysis.measure.stalls): ticks a period or more late
        (deadline to wake-up), and silences of two periods or more of every stamp its
        threads logged, each until it drained the States queued for it meanwhile
        (:meth:`Stretches.drained`); periodic trigger only (on_state and lockstep wait for States
        by design). An outside device's ticks and receipts are not seen: its stalls are its
        commands' silences of two periods or more at the plant (the device or its transport,
        both the system's), less the plant's own stalls (it read nothing then)."""
        if self.outside and not self.lockstep and self.period > 0:
            rx = self.logs["cmd_rx"]
            arrived = rx["recv_ns"][command_arrivals(rx, self.applied)]
            quiet = Stretches.silences(self._in_run(arrived), SILENT_PERIODS * self.period)
            return quiet.minus(self.plant_stalls)  # the plant read nothing then: its own stall
        if self.trigger != "periodic" or self.lockstep or self.period <= 0:
            return Stretches.none()
        t = self.ticks
        late = (t["wake_ns"] - t["deadline_ns"]) >= self.period
        stamps = np.concatenate(
            [t["wake_ns"], t["compute_start_ns"], t["compute_end_ns"], t["zenoh_send_ns"],
             self.logs["state_rx"]["recv_ns"], self.logs["can_tx"]["send_ns"]]
        )  # fmt: skip
        quiet = Stretches.silences(self._in_run(stamps), SILENT_PERIODS * self.period)
        stalls = quiet.union(Stretches.of(t["deadline_ns"][late], t["wake_ns"][late]))
        s = self.state_hops_sorted  # the States it receives: drained after each stall
        recv = s.hop_start + s.hop
        order = np.argsort(recv, kind="stable")
        return stalls.drained(recv[order], s.hop[order], self.period)

    @cached_property
    def plant_stalls(self) -> Stretches:
        """Where the plant stalled: samples a sensor period or more late (due to wake-up), and
        silences of two sensor periods or more of every stamp it logged, each until it drained
        the commands queued for it meanwhile; not in lockstep."""
        if self.lockstep or self.sensor_period <= 0:
            return Stretches.none()
        s = self.samples
        late = (s["wake_ns"] - s["sample_ns"]) >= self.sensor_period
        stamps = np.concatenate([s["wake_ns"], s["send_ns"], self.logs["cmd_rx"]["recv_ns"]])
        quiet = Stretches.silences(self._in_run(stamps), SILENT_PERIODS * self.sensor_period)
        stalls = quiet.union(Stretches.of(s["sample_ns"][late], s["wake_ns"][late]))
        c = self.commands_sorted  # the commands it receives: drained after each stall
        ok = c.arrived & (c.hop >= 0)
        recv = (c.stamps + c.hop)[ok]
        order = np.argsort(recv, kind="stable")
        return stalls.drained(recv[order], c.hop[ok][order], self.period)

    def _in_run(self, stamps: np.ndarray) -> np.ndarray:
        """A service's stamps from the run's start (the plant's first sample) on, that start
        among them: what it did before (arming the drives) is no stall, and a service silent
        from the start was not running."""
        return np.concatenate([[self.w0], stamps[stamps >= self.w0]])

    @cached_property
    def bench_drop_stamps(self) -> Stamped:
        """The drives' socket drops: when each was seen, and how many frames (as ``hop``)."""
        d = self.logs["socket_drops"]
        return Stamped.by_time(d["seen_ns"], hop=d["dropped"].astype(np.int64))

    @cached_property
    def bench_drops(self) -> Stretches:
        """The stretches the commands the bench's own socket dropped left without a landing:
        from the delivered command before each to the one after (by compute time)."""
        c = self.commands_sorted
        if not c.by_bench.any():
            return Stretches.none()
        ok = np.nonzero(c.arrived)[0]
        i = np.nonzero(c.by_bench & ~c.arrived)[0]
        pos = np.searchsorted(ok, i)
        before = np.where(pos > 0, c.stamps[ok[np.maximum(pos - 1, 0)]], c.stamps[i])
        after = np.where(pos < ok.size, c.stamps[ok[np.minimum(pos, ok.size - 1)]], c.stamps[i])
        return Stretches.of(before, after)

    @cached_property
    def host_gaps(self) -> Stretches:
        """Where the recorder's host sampler (a thread of ``hil run``) logged nothing for
        :data:`RECORDER_SILENT_NS` or more: the recorder stopped or starved."""
        host = self.logs.tables.get("host") or {}
        return Stretches.silences(host.get("time_ns", np.zeros(0, np.int64)), RECORDER_SILENT_NS)

    def tick_of(self, cmd: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(tick row, found) of each command sequence number."""
        return _lookup(self.cmd_keys, self.cmd_rows, np.asarray(cmd, np.int64), ordered=True)

    def _sample_of(self, cmd: np.ndarray) -> np.ndarray:
        rows, found = self.tick_of(cmd)
        out = np.zeros(rows.size, np.int64)
        out[found] = self.ticks["state_sample_ns"][rows[found]]
        if not found.all():
            # A command the controller never logged (killed: its log's last chunk lost; an
            # outside device: no log at all) names its State: that State's sample time is the
            # plant's own (its samples table), never the message's stamp. A name that matches
            # no State sent gives no sample (hil.analysis.measure.device counts it).
            rx = self.logs["cmd_rx"]
            z = rx["path"] == CmdPath.ZENOH
            seq, named = _first_per_key(rx["seq"][z], rx["state_seq"][z])
            name, has = _lookup(seq, named, np.asarray(cmd, np.int64)[~found], missing=-1)
            s = self.samples
            samp, known = _lookup(s["seq"], s["sample_ns"], name, missing=0)
            out[~found] = np.where(has & known, samp, 0)
        return out

    def _in_force(self, node: np.ndarray, land: np.ndarray, cmd: np.ndarray):
        """(land_ns, sample_ns, cmd_seq) of each change of the command in force, newest wins.
        On CAN a command is in force once every wheel's frame of it (or newer) has landed: the
        sample in force is the oldest of the wheels' (a conservative age)."""
        # Lifecycle zeros (-1) and unmatched frames (-2) are not commands; nor is a watchdog's
        # zero torque, computed from no sample: it does not renew the age (as on Zenoh).
        keep = cmd >= 0
        keep[keep] = self._sample_of(cmd[keep]) > 0
        node, land, cmd = node[keep], land[keep], cmd[keep]
        order = np.argsort(land, kind="stable")
        node, land, cmd = node[order], land[order], cmd[order]
        eff = np.full(land.size, np.iinfo(np.int64).max)
        for n in np.unique(node).tolist():
            # the newest command of node n landed so far
            eff = np.minimum(eff, np.maximum.accumulate(np.where(node == n, cmd, -1)))
        land, eff = land[eff >= 0], eff[eff >= 0]
        change = np.diff(eff, prepend=-1) != 0
        land, eff = land[change], eff[change]
        return land, self._sample_of(eff), eff


def measure(
    logs: RunLogs, bound: BoundInputs | None = None, limits: DeviceLimits | None = None
) -> Measurement:
    """The run's figures (see the module docstring and docs/realtime.md). Without the
    controller's log (an outside device) every figure that needs it is absent, never 0: the
    controller's hops and wake-ups, the message counts (what it sent is not known), and on CAN
    the applied path's age and the certificate (a frame names no State); the device's figures
    (``device``, from the plant's log alone) are there for every run."""
    r = _Run(logs)
    out = Measurement(window_ns=(r.w0, r.w1), epoch_ns=logs.epoch_ns)
    if r.samples["sample_ns"].size == 0:
        out.timing = {"units": "us", "note": "no plant samples: the plant never ran"}
        return out
    out.timing = timing = {"units": "us", "window_s": (r.w1 - r.w0) / 1e9}
    hosted = logs.controller is not None
    _wakeups(r, timing, out.series)
    if hosted:
        _hops(r, timing)
    _paths(r, timing, out.series)
    out.messages = _messages(r) if hosted else {}
    out.host = r.host_over(r.w0, r.w1)
    if hosted or r.applied != "can":
        out.certificate = _certificate(r, bound, out.series, timing)
    out.device = device_figures(
        logs.tables, logs.pmeta, logs.pinfo, limits, r.plant_stalls.union(r.host_gaps),
        outside=not hosted,
    )  # fmt: skip
    return out


# summary.json's names of _missed_slots' six figures (None: not reported).
_TICK_SLOTS = ("deadline_misses", "late_ticks", "skipped_slots", "ticks", "slots",
               "deadline_miss_rate")  # fmt: skip
_PLANT_SLOTS = ("plant_deadline_misses", "plant_late_samples", "plant_skipped_slots", None,
                "plant_slots", "plant_deadline_miss_rate")  # fmt: skip


def _missed_slots(
    keys: tuple[str | None, ...], late: np.ndarray, skipped: np.ndarray, period: int
) -> Timing:
    """Missed slots: every slot whose deadline passed without its wake-up within one period
    (the late wake-ups) plus the slots never run (skipped), over every slot of the window."""
    late_n = int((late >= period).sum())
    skipped_n = int(skipped.sum())
    slots = int(late.size) + skipped_n
    rate = ratio(late_n + skipped_n, slots)  # hil.folder.rates: the fleet pools the same
    figures = (late_n + skipped_n, late_n, skipped_n, int(late.size), slots, rate)
    return {k: v for k, v in zip(keys, figures, strict=True) if k is not None}


def _tick_phase(r: _Run) -> TickPhase:
    """Where the periodic ticks fell after the sample: the rule, and for "auto" the phase
    learnt and what it was learnt from (controller_service.tick_phase), in µs."""
    cm = r.logs.cmeta
    out: TickPhase = {"rule": str(cm.get("tick_phase") or "half"), "phase_us": r.period / 2e3}
    if cm.get("tick_phase_phase_ns") is not None:
        us = {"phase_ns": "phase_us", "arrival_q_ns": "arrival_p99_us", "path_q_ns": "path_p99_us"}
        out.update({v: int(cm[f"tick_phase_{k}"]) / 1e3 for k, v in us.items()})
        out["window_open"] = bool(cm["tick_phase_window_open"])
        out["clocks_related"] = bool(cm["tick_phase_clocks_related"])
        out["from_tick"] = int(cm["tick_phase_from_k"])
    return out


def _wakeups(r: _Run, timing: Timing, series: Series) -> None:
    """Wake-up figures where the trigger mode measures them; absent (never 0) elsewhere."""
    t = r.ticks
    win = _in(t["deadline_ns"], r.w0, r.w1)
    if r.trigger == "periodic" and not r.lockstep and win.any():
        late = t["wake_ns"][win] - t["deadline_ns"][win]
        timing["wakeup_lateness"] = summarize_ns(late)
        timing.update(_missed_slots(_TICK_SLOTS, late, t["skipped"][win], r.period))
        k, wake = t["k"][win], t["wake_ns"][win]
        expected = np.diff(k) * r.period
        at = r.logs.cmeta.get("tick_phase_from_k")
        if at is not None:
            # The learnt phase's one shift (controller_service.tick_phase) is not jitter: the
            # gap that crosses the slot it took effect at expects it.
            shift = int(r.logs.cmeta.get("tick_phase_shift_ns") or 0)
            expected = expected + shift * ((k[1:] >= int(at)) & (k[:-1] < int(at)))
        timing["period_jitter"] = summarize_ns(np.abs(np.diff(wake) - expected))
        timing["tick_phase"] = _tick_phase(r)
        series["wakeup_lateness"] = ((t["deadline_ns"][win] - r.epoch) / 1e9, late)
    s = r.samples
    if not r.lockstep and s["wake_ns"].size:
        plate = s["wake_ns"] - s["sample_ns"]
        timing["plant_wakeup_lateness"] = summarize_ns(plate)
        gaps = np.diff(s["sample_ns"]) // max(1, r.sensor_period) - 1
        timing.update(_missed_slots(_PLANT_SLOTS, plate, np.clip(gaps, 0, None), r.sensor_period))
        series["plant_wakeup_lateness"] = ((s["sample_ns"] - r.epoch) / 1e9, plate)
    timing["plant_sample_to_send"] = summarize_ns(s["send_ns"] - s["sample_ns"])


def _relatable(summary: Percentiles, ambiguous: int) -> Percentiles:
    """Mark a CAN figure fed by frames the logs could match to more than one send."""
    if ambiguous:
        summary["not_relatable"] = int(ambiguous)
    return summary


def _hops(r: _Run, timing: Timing) -> None:
    t = r.ticks
    fresh = (t["state_seq"] >= 0) & ((t["flags"] & TICK_NO_SEND) == 0) & (t["state_recv_ns"] > 0)
    fresh &= _in(t["state_sample_ns"], r.w0, r.w1)
    timing["compute"] = summarize_ns(t["compute_end_ns"][fresh] - t["compute_start_ns"][fresh])
    timing["hop_state"] = summarize_ns(t["state_recv_ns"][fresh] - t["state_send_ns"][fresh])
    timing["wait_for_tick"] = summarize_ns(t["compute_start_ns"][fresh] - t["state_recv_ns"][fresh])
    rx = r.logs["cmd_rx"]
    z = rx["path"] == CmdPath.ZENOH
    seq, recv = _first_per_key(rx["seq"][z], rx["recv_ns"][z])
    i, found = r.tick_of(seq)
    recv, i = recv[found], i[found]
    ok = (t["zenoh_send_ns"][i] > 0) & _in(t["state_sample_ns"][i], r.w0, r.w1)
    recv, i = recv[ok], i[ok]
    hop = recv - t["zenoh_send_ns"][i]
    timing["hop_cmd_zenoh"] = summarize_ns(hop)
    loop = t["state_recv_ns"] - t["state_send_ns"] + t["compute_end_ns"] - t["compute_start_ns"]
    timing["loop_transport_compute"] = summarize_ns((loop[i] + hop)[fresh[i]])
    ss, has = _lookup(r.samples["seq"], r.samples["send_ns"], t["state_seq"][i])
    timing["state_send_to_cmd_recv"] = summarize_ns((recv - ss)[has])
    c = r._can
    ok = (c["cmd"] >= 0) & (c["send"] > 0) & _in(c["send"], r.w0, r.w1) & ~c["duplicated"]
    timing["hop_cmd_can"] = _relatable(
        summarize_ns(c["recv"][ok] - c["send"][ok]), int(c["ambiguous"][ok].sum())
    )


def _paths(r: _Run, timing: Timing, series: Series) -> None:
    judged_until = r.w1 - r.settle
    s = r.samples
    judged = s["sample_ns"] <= judged_until
    n_judged = int(judged.sum())
    can_ambiguous = int((r._can["ambiguous"] & _in(r._can["recv"], r.w0, r.w1)).sum())
    for path in PATHS:
        applied = path == r.applied
        if path == "can" and r.logs.controller is None:
            continue  # no send log to match the frames to: their samples are not known
        land, samp, _cmd = r.landings(path, applied)
        if land.size == 0 and not applied:
            continue
        amb = can_ambiguous if path == "can" else 0
        inwin = _in(samp, r.w0, r.w1)
        lat = land[inwin] - samp[inwin]
        timing[f"sample_to_apply_{path}"] = _relatable(summarize_ns(lat), amb)
        series[f"sample_to_apply_{path}"] = lat
        # The age counts from t = 0: before the first landing the plant holds zero torque.
        seg = agemod.segments(land, samp, r.w1, start_ns=r.w0)
        timing[f"command_age_{path}"] = _relatable(agemod.age_summary(seg, r.w0, r.h), amb)
        series[f"command_age_{path}"] = seg
        if amb:
            land_e, samp_e, _ = r.landings(path, applied, early=True)
            upper = agemod.segments(land_e, samp_e, r.w1, start_ns=r.w0)
            series[f"command_age_{path}_upper"] = upper
        if not applied:
            continue
        timing["startup_hold_s"] = (int(land[0]) - r.w0) / 1e9 if land.size else None
        landed = np.unique(samp)
        answered = np.isin(s["sample_ns"], landed)
        slots = r.sample_slots
        # Whose lateness left a sample without a command: its State came after the tick meant
        # to answer it only because the plant (the bench's emulator: a physical robot's sensor
        # is never late) woke late.
        at_tick = r.state_timing_at_tick
        if slots is None:  # the controller was meant to answer every sample
            without = judged & ~answered
            r.series_without = s["sample_ns"][without]
            if at_tick is not None:
                r.without_plant_late = at_tick[1][without]
        else:  # one sample per control period: a slot with none of its samples answered
            _, slot = np.unique(slots, return_inverse=True)
            n_slots = int(slot.max()) + 1
            got = np.zeros(n_slots, bool)
            np.logical_or.at(got, slot, answered)
            whole = np.ones(n_slots, bool)  # every sample of the slot judged
            np.logical_and.at(whole, slot, judged)
            last = np.zeros(n_slots, np.int64)  # the slot's newest sample, the one a tick takes
            np.maximum.at(last, slot, s["sample_ns"])
            without = whole & ~got
            n_judged = int(whole.sum())
            r.series_without = last[without]
            if at_tick is not None:  # none of the slot's States in hand, one for the plant
                in_hand = np.zeros(n_slots, bool)
                np.logical_or.at(in_hand, slot, at_tick[0])
                missed = np.zeros(n_slots, bool)
                np.logical_or.at(missed, slot, at_tick[1])
                r.without_plant_late = (missed & ~in_hand)[without]
        timing["samples_without_command"] = int(without.sum())
        timing["samples_judged"] = n_judged
        timing["samples_without_command_rate"] = ratio(int(without.sum()), n_judged)
        late = (lat > r.ts) & (samp[inwin] <= judged_until)
        timing["late_commands"] = int(late.sum())
        timing["late_commands_rate"] = ratio(int(late.sum()), n_judged)
        timing["sample_gap"] = summarize_ns(np.diff(landed[_in(landed, r.w0, r.w1)]))
        series["applied_path"] = path


def _messages(r: _Run) -> Messages:
    s, t = r.samples, r.ticks
    state_rx = r.logs["state_rx"]["seq"]
    state = _stream_counts(s["seq"], state_rx, s["seq"][r.state_injected_drop])
    state["injected_drops"] = int(((s["flags"] & SAMPLE_DROPPED) != 0).sum())
    state["injected_duplicates"] = int(((s["flags"] & SAMPLE_DUPLICATED) != 0).sum())
    # States lost that no [faults] drop explains: on the wire, or in Zenoh's own queues (a DROP
    # publisher whose queue stayed full; not countable apart), with when (docs/reports.md).
    flying = np.isin(s["seq"], _in_flight(s["seq"], state_rx, s["seq"][r.state_injected_drop]))
    unexplained = ~r.state_received & ~r.state_injected_drop & ~flying
    state["lost_not_injected"] = int(unexplained.sum())
    when = s["sample_ns"][unexplained]
    state["lost_not_injected_t_s"] = (
        [(int(when[0]) - r.epoch) / 1e9, (int(when[-1]) - r.epoch) / 1e9] if when.size else None
    )
    out: Messages = {"state": state}
    zsent = (t["zenoh_send_ns"] > 0) & (t["cmd_seq"] >= 0)
    # Commands count while the plant still listens: sent up to 2 Ts + delay + jitter before
    # its last sample (later ones may land after it stopped: "sent_after_window", not lost).
    end = r.w1 - r.settle
    inwin = zsent & _in(t["zenoh_send_ns"], r.w0, end)
    rx = r.logs["cmd_rx"]
    dropped = inwin & ((t["flags"] & TICK_DROPPED) != 0)
    z = _stream_counts(
        t["cmd_seq"][inwin], rx["seq"][rx["path"] == CmdPath.ZENOH], t["cmd_seq"][dropped]
    )
    z["injected_drops"] = int(((t["flags"][inwin] & TICK_DROPPED) != 0).sum())
    z["injected_duplicates"] = int(((t["flags"][inwin] & TICK_DUPLICATED) != 0).sum())
    z["injected_reorders"] = int(((t["flags"][inwin] & TICK_REORDERED) != 0).sum())
    z["sent_after_window"] = int((zsent & (t["zenoh_send_ns"] > end)).sum())
    out["torque_zenoh"] = z
    if r.logs["can_tx"]["node"].size or (rx["path"] == CmdPath.CAN).any():
        out["torque_can"] = _can_messages(r)
    return out


def _can_window(r: _Run) -> tuple[np.ndarray, np.ndarray, int]:
    """(this window's commands, per can_tx row: a frame of one of them, the commands sent after
    the window). A command is this window's if it was computed in it and its last frame was put
    on the bus by the end (a frame never on the bus counts at its compute time): a host stalled
    between compute and send must not make a frame sent after the plant stopped count as lost."""
    t, tx = r.ticks, r.logs["can_tx"]
    rows, found = r.tick_of(tx["cmd_seq"])
    when = np.zeros(tx["cmd_seq"].size, np.int64)
    when[found] = t["compute_start_ns"][rows[found]]
    end = r.w1 - r.settle  # as for Zenoh: frames sent while the drives still listen
    is_cmd = tx["cmd_seq"] >= 0
    put = np.where(tx["send_ns"] > 0, tx["send_ns"], when)[is_cmd]
    ids, inv = np.unique(tx["cmd_seq"][is_cmd], return_inverse=True)
    last_put = np.full(ids.size, np.iinfo(np.int64).min)
    np.maximum.at(last_put, inv, put)
    first = np.full(ids.size, np.iinfo(np.int64).max)
    np.minimum.at(first, inv, when[is_cmd])
    in_window = (first >= r.w0) & (last_put <= end)
    mine = np.zeros(is_cmd.size, bool)
    mine[is_cmd] = in_window[inv]
    return ids[in_window], mine, int((last_put > end).sum())


def _can_messages(r: _Run) -> StreamCounts:
    """Per command (every wheel's frame of one cycle) and per frame, with a per-wheel split;
    lifecycle zeros apart."""
    tx, c = r.logs["can_tx"], r._can
    sent_cmds, mine, sent_after_window = _can_window(r)
    got = (c["cmd"] >= 0) & ~c["lost"] & ~c["duplicated"]
    wheels = np.unique(tx["node"])
    n_wheels = max(1, wheels.size)
    received = sent_cmds[np.isin(sent_cmds, _whole(c["cmd"][got], c["node"][got], n_wheels))]
    ours = np.isin(c["cmd"], sent_cmds)
    per_node: dict[str, dict[str, int]] = {}
    for n in wheels.tolist():
        on_n = c["node"] == n
        sent_n = int((mine & (tx["node"] == n)).sum())
        sel = got & ours & on_n  # distinct frames: by the command and wheel they carry
        rx_n = int(np.unique(_frame_keys(c["cmd"][sel], c["node"][sel])).size)
        per_node[str(n)] = {
            "frames_sent": sent_n,
            "frames_received": rx_n,
            "frames_lost": sent_n - rx_n,
            # An unnamed bus's copy matches no send: counted by when it arrived.
            "duplicated": int((c["duplicated"] & on_n & _in(c["recv"], r.w0, r.w1)).sum()),
            "reordered": int(r.can_reordered.get(int(n), 0)),
        }
    frames_sent = int(mine.sum())
    frames_rx = sum(v["frames_received"] for v in per_node.values())
    out = {
        "sent": int(sent_cmds.size),
        "received": int(received.size),
        "lost": int(sent_cmds.size - received.size),
        "duplicated": sum(v["duplicated"] for v in per_node.values()),
        "reordered": sum(v["reordered"] for v in per_node.values()),
        "frames_sent": frames_sent,
        "frames_received": frames_rx,
        "frames_lost": frames_sent - frames_rx,
        "frames_not_on_bus": int((mine & (tx["send_ns"] <= 0)).sum()),
        **_bench_losses(r, mine, sent_cmds, frames_sent - frames_rx),
        "frames_ambiguous": int((c["ambiguous"] & ours).sum()),
        "frames_realigned": r.can_realigned,
        "injected_frame_losses": int((c["lost"] & ours).sum()),
        "lifecycle_frames_sent": int((tx["cmd_seq"] < 0).sum()),
        "unmatched_frames_received": int(((c["cmd"] == UNMATCHED) & ~c["duplicated"]).sum()),
        "value_mismatches": int(r.value_mismatches),
        "sent_after_window": sent_after_window,
        "per_node": per_node,
    }
    if r.applied == "can":
        out.update(_can_fates(r, received, n_wheels))
    return out


def _bench_losses(
    r: _Run, mine: np.ndarray, sent_cmds: np.ndarray, frames_lost: int
) -> StreamCounts:
    """Whose the window's lost frames were: the drives' own receiving socket's (the bench's, its
    queue full: ``frames_lost_by_bench``, of the ``frames_dropped_by_bench_socket`` it counted,
    any frame; None where the bus has no socket to count on), a [faults] injection's, never put
    on the bus (bus-off), or the wire's (``frames_lost_on_wire``: the rest)."""
    d = r.logs["socket_drops"]
    window = _in(d["seen_ns"], r.w0, r.w1 + r.settle)
    counted = (
        d["dropped"].size > 0 or (r.logs.pinfo.get("can") or {}).get("socket_drops") is not None
    )
    by_frame = r.frames_dropped_by_bench & mine
    c, tx = r._can, r.logs["can_tx"]
    injected = int((c["lost"] & np.isin(c["cmd"], sent_cmds)).sum())
    off_bus = int((mine & (tx["send_ns"] <= 0)).sum())
    return {
        "frames_dropped_by_bench_socket": int(d["dropped"][window].sum()) if counted else None,
        "frames_lost_by_bench": int(by_frame.sum()),
        "lost_by_bench": int(np.isin(sent_cmds, r.commands_dropped_by_bench).sum()),
        "frames_lost_on_wire": max(0, frames_lost - int(by_frame.sum()) - injected - off_bus),
    }


def _same_bytes_runs(tx: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Per can_tx row, the send times of the first and the last frame of its run: the frames of
    its node on the bus, in bus order, back to back with the same float32 bytes (one frame, or
    none put on the bus: its own send time)."""
    send = tx["send_ns"]
    first, last = send.copy(), send.copy()
    on_bus = np.nonzero(send > 0)[0]
    order = on_bus[np.lexsort((send[on_bus], tx["node"][on_bus]))]
    if order.size == 0:
        return first, last
    node = tx["node"][order]
    raw = np.asarray(tx["value"][order], np.float32).view(np.int32)
    new = np.ones(order.size, bool)
    new[1:] = (node[1:] != node[:-1]) | (raw[1:] != raw[:-1])
    run = np.cumsum(new) - 1
    starts = np.nonzero(new)[0]
    ends = np.append(starts[1:], order.size) - 1
    first[order] = send[order][starts][run]
    last[order] = send[order][ends][run]
    return first, last


def _frame_keys(cmd: np.ndarray, node: np.ndarray) -> np.ndarray:
    """One int64 per (command, wheel) pair, ordered as the pairs are (command, then wheel):
    a 1-D key sorts in place, where ``np.unique(axis=1)`` over the stacked pairs copies them
    twice (about 240 MB over an hour's 7 M frames). CANSimple node ids are 6 bits."""
    return cmd.astype(np.int64) * _NODES + node.astype(np.int64)


def _whole(cmd: np.ndarray, node: np.ndarray, wheels: int) -> np.ndarray:
    """The commands among ``cmd`` (one entry a frame, ``node`` its wheel) with a frame from
    every wheel: a duplicate of one wheel's frame never stands in for the other's."""
    ids, counts = np.unique(np.unique(_frame_keys(cmd, node)) // _NODES, return_counts=True)
    return ids[counts >= wheels]


def _can_fates(r: _Run, received: np.ndarray, wheels: int) -> dict[str, int]:
    """What became of each received command on the applied CAN path: ``applied`` (every wheel's
    frame landed), ``refused_by_drive`` (a wheel's drive refused a frame of it: non-finite,
    disarmed), ``arrived_after_plant_stopped`` (its last frame came after the plant's last
    sample: a slow host delayed it past the window; never applied, not lost). A received
    command that is none of these was dropped by the plant unexplained: ``unaccounted``."""
    a, c = r.can_applies, r._can
    cmd, outcome = a["cmd"], a["outcome"]
    landed = np.isin(outcome, LANDINGS)
    applied = np.isin(received, _whole(cmd[landed], a["node"][landed], wheels))
    refused = np.isin(received, cmd[outcome == ApplyOutcome.REFUSED]) & ~applied
    late_ids = c["cmd"][(c["cmd"] >= 0) & ~c["lost"] & (c["recv"] > r.w1)]
    late = np.isin(received, late_ids) & ~applied & ~refused
    return {
        "applied": int(applied.sum()),
        "refused_by_drive": int(refused.sum()),
        "arrived_after_plant_stopped": int(late.sum()),
        "unaccounted": int((~(applied | refused | late)).sum()),
    }


def _in_windows(stamps: np.ndarray, windows: list[tuple[int, int]]) -> np.ndarray:
    inside = np.zeros(stamps.size, bool)
    for lo, hi in windows:
        inside |= _in(stamps, lo, hi)
    return inside


def _bench_shares(r: _Run, windows: list[tuple[int, int]], timing: Timing) -> None:
    """How much of the missed slots and of the samples without a command fell inside the
    bench's stalls, and how many samples without a command outside them the plant's own
    lateness left so (their State came after the tick meant to answer them, and would have
    been in hand had the plant woken on time): the verdict lays neither on the system."""
    inside = None
    if r.series_without is not None:
        inside = _in_windows(r.series_without, windows)
        if r.without_plant_late is not None:
            late = int((r.without_plant_late & ~inside).sum())
            timing["samples_without_command_plant_late"] = late
    if not windows:
        return
    t = r.ticks
    if "deadline_misses" in timing:
        win = _in(t["deadline_ns"], r.w0, r.w1) & _in_windows(t["deadline_ns"], windows)
        late = (t["wake_ns"] - t["deadline_ns"])[win] >= r.period
        timing["deadline_misses_in_bench_stalls"] = int(late.sum() + t["skipped"][win].sum())
    if inside is not None:
        timing["samples_without_command_in_bench_stalls"] = int(inside.sum())


def _certificate(r: _Run, b: BoundInputs | None, series: Series, timing: Timing) -> Certificate:
    """The sampled-data certificate at the measured D (for a law with the bound; for any other
    law D, D* None), with every stall counted and owned. ``held`` is True only if the bound
    holds for every matching of CAN frames the logs allow (at the upper bound of D), False if
    it fails even at the lower one, else None (unknown)."""
    empty = agemod.segments(np.zeros(0, np.int64), np.zeros(0, np.int64), r.w1)
    seg: agemod.AgeSegments = series.get(f"command_age_{r.applied}") or empty
    upper: agemod.AgeSegments = series.get(f"command_age_{r.applied}_upper") or seg
    d_max_ns, d_upper_ns = agemod.max_age(seg), agemod.max_age(upper)
    d_max = d_max_ns / 1e9 if d_max_ns is not None else None
    d_star = d_star_ns = cert = held = None
    if b is not None:
        d_star = critical_age(b.params, b.context, b.boundary_layer, v0=b.v0, w0=b.w0)
        d_star_ns = int(d_star * 1e9)

        def held_at(d: float | None) -> tuple[bool, Any]:
            if d is None:
                return False, None
            c = certify(b.params, b.context, d, 0.0, b.boundary_layer, v0=b.v0, w0=b.w0)
            return bool(c.held and d <= d_star), c

        low_ok, cert = held_at(d_max)
        high_ok = held_at(d_upper_ns / 1e9)[0] if d_upper_ns != d_max_ns else low_ok
        held = True if high_ok else (False if not low_ok else None)
    threshold_ns = int(max(3 * r.ts, 0.5 * d_star * 1e9 if d_star is not None else 0))
    stalls = find_stalls(r, seg, threshold_ns, d_star_ns)
    _bench_shares(r, [*stalls.bench_windows, *host_windows(r)], timing)
    out: Certificate = {
        "path": r.applied,
        "d_max_s": d_max,
        "d_star_s": d_star,
        "margin_s": (d_star - d_max) if d_max is not None and d_star is not None else None,
        "held": held,
        "v_bound": float(cert.v_bound) if cert is not None else None,
        "omega_bound": float(cert.w_bound) if cert is not None else None,
        "stall_threshold_s": threshold_ns / 1e9,
        "stall_count": stalls.count,
        "stalled_time_s": stalls.stalled_time_ns / 1e9,
        "stalls_by_owner": stalls.by_owner,
        "d_system_s": stalls.d_system_ns / 1e9 if stalls.d_system_ns is not None else None,
        "stalls": stalls.listed,
    }
    if d_upper_ns != d_max_ns and d_upper_ns is not None:
        out["d_max_upper_s"] = d_upper_ns / 1e9  # the largest D the CAN logs allow
    # The design conditions of the bound that fail at the measured D (certify at Ts = D).
    out["failed_conditions"] = [c.name for c in cert.failed()] if cert is not None else []
    return out
