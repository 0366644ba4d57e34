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

from hil.measure import age as agemod
from hil.measure.logs import RunLogs
from hil.measure.stats import summarize_ns
from protocol.hoplog import (
    APPLY_BURST,
    APPLY_LANDED,
    APPLY_REFUSED,
    RX_LOST_BY_FAULT,
    SAMPLE_DROPPED,
    SAMPLE_DUPLICATED,
    TICK_DROPPED,
    TICK_DUPLICATED,
    TICK_NO_SEND,
    TICK_REORDERED,
)

PATHS = ("zenoh", "can")
LANDINGS = (APPLY_LANDED, APPLY_BURST)  # apply outcomes that put a command in force
STALL_LIMIT = 20  # stalls listed in the certificate, worst first


@dataclass(frozen=True)
class BoundInputs:
    """What the sampled-data bound needs besides the measured D (from the resolved scenario)."""

    params: Any
    context: Any
    boundary_layer: bool
    v0: float = 0.0
    w0: float = 0.0


@dataclass
class Measurement:
    """The one result: the contract's ``timing``, ``messages`` and ``certificate`` objects, and
    the per-sample series that plots and latency replay read."""

    timing: dict[str, Any] = field(default_factory=dict)
    messages: dict[str, Any] = field(default_factory=dict)
    certificate: dict[str, Any] | None = None
    series: dict[str, Any] = field(default_factory=dict)
    window_ns: tuple[int, int] = (0, 0)

    def latency_us(self) -> dict[str, np.ndarray]:
        """Sample-to-apply latency per path in µs (applied: apply - sample, shadow: receive -
        sample), one value per command: what histograms and replay use."""
        return {
            p: np.asarray(self.series[f"sample_to_apply_{p}"], dtype=float) / 1000.0
            for p in PATHS
            if len(self.series.get(f"sample_to_apply_{p}", ()))
        }


def _in(x: np.ndarray, lo: int, hi: int) -> np.ndarray:
    return (x >= lo) & (x <= hi)


def _first_per_key(keys: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(distinct keys, the value of each key's first occurrence)."""
    uniq, first = np.unique(keys, return_index=True)
    return uniq, values[first]


def _lookup(keys: np.ndarray, values: np.ndarray, query: np.ndarray, missing: int = -1):
    """values[keys == q] for each q (keys distinct), ``missing`` where absent; vectorised."""
    order = np.argsort(keys, kind="stable")
    ks = keys[order]
    pos = np.clip(np.searchsorted(ks, query), 0, max(0, ks.size - 1))
    found = (ks.size > 0) & (ks[pos] == query) if ks.size else np.zeros(query.size, bool)
    out = np.full(query.size, missing, dtype=values.dtype if values.size else np.int64)
    if ks.size:
        out[found] = values[order][pos[found]]
    return out, found


def _nearest(keys: np.ndarray, query: np.ndarray, tolerance_ns: int) -> np.ndarray:
    """For each query, the index of the key nearest to it within the tolerance (-1: none)."""
    if keys.size == 0:
        return np.full(query.size, -1, np.int64)
    order = np.argsort(keys, kind="stable")
    ks = keys[order]
    pos = np.clip(np.searchsorted(ks, query), 1, max(1, ks.size - 1))
    left = np.clip(pos - 1, 0, ks.size - 1)
    right = np.clip(pos, 0, ks.size - 1)
    pick = np.where(np.abs(ks[left] - query) <= np.abs(ks[right] - query), left, right)
    ok = np.abs(ks[pick] - query) <= tolerance_ns
    return np.where(ok, order[pick], -1)


def _stream_counts(sent_ids: np.ndarray, rx_ids: np.ndarray) -> dict[str, int]:
    """sent, received (distinct ids that were sent), lost, duplicated, reordered: one definition
    for every stream. Reordered: an arrival older than one that arrived before it."""
    sent = np.unique(sent_ids)
    mine = np.isin(rx_ids, sent)
    rx = rx_ids[mine]
    distinct = np.unique(rx)
    reordered = 0
    if rx.size > 1:
        run_max = np.maximum.accumulate(rx)
        first = np.zeros(rx.size, bool)
        _, idx = np.unique(rx, return_index=True)
        first[idx] = True
        reordered = int(((rx[1:] < run_max[:-1]) & first[1:]).sum())
    return {
        "sent": int(sent.size),
        "received": int(distinct.size),
        "lost": int(sent.size - distinct.size),
        "duplicated": int(rx.size - distinct.size),
        "reordered": reordered,
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
        self.settle = 2 * self.ts + int(
            1e9 * (float(pm.get("delay_s") or 0.0) + float(pm.get("jitter_s") or 0.0))
        )
        self.samples = logs["samples"]
        self.ticks = logs["ticks"]
        sn = self.samples["sample_ns"]
        self.w0 = int(sn[0]) if sn.size else 0
        self.w1 = int(sn[-1]) if sn.size else 0
        # cmd_seq -> its tick row, and the sample it was computed from (the controller's own
        # record, not what the message claims).
        t = self.ticks
        self.cmd_rows = np.nonzero(t["cmd_seq"] >= 0)[0]
        self.cmd_keys = t["cmd_seq"][self.cmd_rows]
        self._can = self._match_can()

    # --- CAN: arrivals matched to sends in per-node order -------------------------------------
    def _match_can(self) -> dict[str, np.ndarray]:
        """Every CAN torque frame that reached a drive's receiver, matched to the send it came
        from. CANSimple frames carry no sequence number. Where the bus names each frame (the
        zenoh_can bus: its modelled end of transmission, which sender and receiver both log),
        frames are matched by that name exactly, so a frame lost on the way shifts nothing.
        Elsewhere (socketcan) the i-th frame a drive received is the i-th put on the bus for it
        (both logs keep bus order). Either way the torque each frame carries is checked against
        its send's: ``value_mismatches`` counts disagreements (a shifted match is never silent).
        ``lost``: the receiver lost the frame on purpose ([faults] frame loss)."""
        rx, tx = self.logs["cmd_rx"], self.logs["can_tx"]
        is_can = rx["path"] == 1
        node, idx, recv = rx["node"][is_can], rx["seq"][is_can], rx["recv_ns"][is_can]
        named, value = rx["send_ns"][is_can], rx["tau1"][is_can]
        lost = rx["verdict"][is_can] == RX_LOST_BY_FAULT
        send = np.zeros(node.size, np.int64)
        cmd = np.full(node.size, -2, np.int64)  # -2: no matching send
        # node -> (frame index among those its drive received, cmd_seq): arrays, not a dict:
        # an hour at 1 kHz is 3.6 M frames a node.
        self._frame_match: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        self.value_mismatches = 0
        on_bus = tx["send_ns"] > 0
        for n in np.unique(node).tolist():
            mine = on_bus & (tx["node"] == n)
            tsend, tcmd, tend = tx["send_ns"][mine], tx["cmd_seq"][mine], tx["bus_end_ns"][mine]
            tval = tx["value"][mine]
            rows = np.nonzero(node == n)[0]
            if rows.size and (named[rows] > 0).all() and (tend > 0).all():
                at = _nearest(tend, named[rows], tolerance_ns=2_000)
            else:
                at = np.where(idx[rows] < tsend.size, idx[rows], -1)
            ok = at >= 0
            send[rows[ok]] = tsend[at[ok]]
            cmd[rows[ok]] = tcmd[at[ok]]
            same = np.float32(value[rows[ok]]) == np.float32(tval[at[ok]])
            self.value_mismatches += int((~same).sum())
            self._frame_match[n] = (idx[rows], cmd[rows])
        return {"node": node, "index": idx, "recv": recv, "send": send, "cmd": cmd, "lost": lost}

    def can_frame_of(self, node: np.ndarray, index: np.ndarray) -> np.ndarray:
        """cmd_seq (-1 lifecycle, -2 unmatched) of received CAN frames given as (node, the
        frame's index among those its drive received)."""
        out = np.full(node.size, -2, np.int64)
        for n, (idx, cmd) in self._frame_match.items():
            mine = np.nonzero(node == n)[0]
            if idx.size == 0 or mine.size == 0:
                continue
            # The last frame with that index wins (a restarted plant counts from 0 again).
            order = np.argsort(idx, kind="stable")
            ks = idx[order]
            pos = np.searchsorted(ks, index[mine], side="right") - 1
            found = (pos >= 0) & (ks[np.maximum(pos, 0)] == index[mine])
            out[mine[found]] = cmd[order[pos[found]]]
        return out

    # --- landings: (time, sample) of each command put in force, per path -----------------------
    def landings(self, path: str, applied: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(land_ns, sample_ns, cmd_seq) per command put in force, newest wins; for a shadow
        path the arrival stands for the landing (what would have been applied)."""
        if applied and path == "zenoh":
            ap = self.logs["apply"]
            m = np.isin(ap["outcome"], LANDINGS) & (ap["path"] == 0)
            cmd, land = ap["seq"][m], ap["apply_ns"][m]
        elif applied:
            a = self.can_applies
            m = np.isin(a["outcome"], LANDINGS)
            return self._can_commands(a["node"][m], a["land"][m], a["cmd"][m])
        elif path == "zenoh":
            rx = self.logs["cmd_rx"]
            m = rx["path"] == 0
            cmd, land = rx["seq"][m], rx["recv_ns"][m]
        else:
            c = self._can
            got = ~c["lost"]
            return self._can_commands(c["node"][got], c["recv"][got], c["cmd"][got])
        return self._newest_wins(land, cmd)

    @cached_property
    def can_applies(self) -> dict[str, np.ndarray]:
        """The plant's CAN apply rows (every outcome) with the command each frame carried."""
        ap = self.logs["apply"]
        m = ap["path"] == 1
        node = ap["node"][m]
        return {
            "node": node,
            "land": ap["apply_ns"][m],
            "cmd": self.can_frame_of(node, ap["seq"][m]),
            "outcome": ap["outcome"][m],
        }

    def tick_of(self, cmd: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(tick row, found) of each command sequence number."""
        return _lookup(self.cmd_keys, self.cmd_rows, np.asarray(cmd, np.int64))

    def _sample_of(self, cmd: np.ndarray) -> np.ndarray:
        rows, found = self.tick_of(cmd)
        out = np.zeros(rows.size, np.int64)
        out[found] = self.ticks["state_sample_ns"][rows[found]]
        if not found.all():
            # A command the controller sent but never logged (killed: its log's last chunk
            # lost) still carries its sample's time in the message the plant received.
            rx = self.logs["cmd_rx"]
            z = (rx["path"] == 0) & (rx["state_sample_ns"] > 0)
            seq, samp = _first_per_key(rx["seq"][z], rx["state_sample_ns"][z])
            got, has = _lookup(seq, samp, np.asarray(cmd, np.int64)[~found], missing=0)
            out[~found] = np.where(has, got, 0)
        return out

    def _newest_wins(self, land: np.ndarray, cmd: np.ndarray):
        order = np.argsort(land, kind="stable")
        land, cmd = land[order], cmd[order]
        samp = self._sample_of(cmd)
        keep = samp > 0
        land, cmd, samp = land[keep], cmd[keep], samp[keep]
        if cmd.size:
            newer = np.concatenate([[True], cmd[1:] > np.maximum.accumulate(cmd)[:-1]])
            land, cmd, samp = land[newer], cmd[newer], samp[newer]
        return land, samp, cmd

    def _can_commands(self, node: np.ndarray, land: np.ndarray, cmd: np.ndarray):
        """A CAN command is in force once both wheels' frames of it (or newer) have landed: the
        sample in force is the older of the two wheels' (a conservative age)."""
        keep = cmd >= 0  # lifecycle zeros (-1) and unmatched frames (-2) are not commands
        node, land, cmd = node[keep], land[keep], cmd[keep]
        nodes = np.unique(node)
        if nodes.size == 0:
            z = np.zeros(0, np.int64)
            return z, z, z
        order = np.argsort(land, kind="stable")
        node, land, cmd = node[order], land[order], cmd[order]
        eff = np.full(land.size, np.iinfo(np.int64).max)
        for n in nodes.tolist():
            mine = node == n
            last = np.where(mine, cmd, -1)
            last = np.maximum.accumulate(last)  # the newest command of node n landed so far
            eff = np.minimum(eff, last)
        valid = eff >= 0
        land, eff = land[valid], eff[valid]
        if eff.size == 0:
            z = np.zeros(0, np.int64)
            return z, z, z
        change = np.concatenate([[True], eff[1:] != eff[:-1]])
        land, eff = land[change], eff[change]
        return land, self._sample_of(eff), eff


def measure(logs: RunLogs, bound: BoundInputs | None = None) -> Measurement:
    """The run's figures (see the module docstring and docs/realtime.md)."""
    r = _Run(logs)
    out = Measurement(window_ns=(r.w0, r.w1))
    if r.samples["sample_ns"].size == 0:
        out.timing = {"units": "us", "note": "no plant samples: the plant never ran"}
        return out
    timing: dict[str, Any] = {"units": "us", "window_s": (r.w1 - r.w0) / 1e9}
    _wakeups(r, timing, out.series)
    _hops(r, timing)
    _paths(r, timing, out.series)
    out.messages = _messages(r)
    if bound is not None:
        out.certificate = _certificate(r, bound, out.series)
    out.timing = timing
    return out


def _wakeups(r: _Run, timing: dict[str, Any], series: dict[str, Any]) -> None:
    t = r.ticks
    win = _in(t["deadline_ns"], r.w0, r.w1) if t["deadline_ns"].size else np.zeros(0, bool)
    if r.trigger == "periodic" and not r.lockstep and win.any():
        late = t["wake_ns"][win] - t["deadline_ns"][win]
        timing["wakeup_lateness"] = summarize_ns(late)
        misses = int((late >= r.period).sum())
        timing["deadline_misses"] = misses
        timing["skipped_slots"] = int(t["skipped"][win].sum())
        timing["ticks"] = int(win.sum())
        timing["deadline_miss_rate"] = misses / int(win.sum())
        k, wake = t["k"][win], t["wake_ns"][win]
        timing["period_jitter"] = summarize_ns(np.abs(np.diff(wake) - np.diff(k) * r.period))
        series["wakeup_lateness"] = ((t["deadline_ns"][win] - r.epoch) / 1e9, late)
    else:
        timing["deadline_misses"] = 0
        timing["skipped_slots"] = 0
        timing["deadline_miss_rate"] = 0.0
    s = r.samples
    if not r.lockstep and s["wake_ns"].size:
        plate = s["wake_ns"] - s["sample_ns"]
        timing["plant_wakeup_lateness"] = summarize_ns(plate)
        timing["plant_deadline_misses"] = int((plate >= r.sensor_period).sum())
        gaps = np.diff(s["sample_ns"]) // max(1, r.sensor_period) - 1
        timing["plant_skipped_slots"] = int(np.clip(gaps, 0, None).sum())
        series["plant_wakeup_lateness"] = ((s["sample_ns"] - r.epoch) / 1e9, plate)
    timing["plant_sample_to_send"] = summarize_ns(s["send_ns"] - s["sample_ns"])


def _hops(r: _Run, timing: dict[str, Any]) -> None:
    t = r.ticks
    fresh = (t["state_seq"] >= 0) & ((t["flags"] & TICK_NO_SEND) == 0) & (t["state_recv_ns"] > 0)
    fresh &= _in(t["state_sample_ns"], r.w0, r.w1)
    timing["compute"] = summarize_ns(t["compute_end_ns"][fresh] - t["compute_start_ns"][fresh])
    timing["hop_state"] = summarize_ns(t["state_recv_ns"][fresh] - t["state_send_ns"][fresh])
    timing["wait_for_tick"] = summarize_ns(t["compute_start_ns"][fresh] - t["state_recv_ns"][fresh])
    rx = r.logs["cmd_rx"]
    z = rx["path"] == 0
    seq, recv = _first_per_key(rx["seq"][z], rx["recv_ns"][z])
    i, found = r.tick_of(seq)
    seq, recv, i = seq[found], recv[found], i[found]
    send = t["zenoh_send_ns"][i]
    ok = (send > 0) & _in(t["state_sample_ns"][i], r.w0, r.w1)
    seq, recv, i, send = seq[ok], recv[ok], i[ok], send[ok]
    hop = recv - send
    timing["hop_cmd_zenoh"] = summarize_ns(hop)
    f = fresh[i]
    loop = (t["state_recv_ns"][i] - t["state_send_ns"][i]) + (
        t["compute_end_ns"][i] - t["compute_start_ns"][i]
    )
    timing["loop_transport_compute"] = summarize_ns((loop + hop)[f])
    ss, has = _lookup(r.samples["seq"], r.samples["send_ns"], t["state_seq"][i])
    timing["state_send_to_cmd_recv"] = summarize_ns((recv - ss)[has])
    c = r._can
    ok = (c["cmd"] >= 0) & (c["send"] > 0) & _in(c["send"], r.w0, r.w1)
    timing["hop_cmd_can"] = summarize_ns(c["recv"][ok] - c["send"][ok])


def _paths(r: _Run, timing: dict[str, Any], series: dict[str, Any]) -> None:
    judged_until = r.w1 - r.settle
    s = r.samples
    judged = s["sample_ns"] <= judged_until
    n_judged = int(judged.sum())
    for path in PATHS:
        applied = path == r.applied
        land, samp, _cmd = r.landings(path, applied)
        if land.size == 0 and not applied:
            continue
        inwin = _in(samp, r.w0, r.w1)
        lat = land[inwin] - samp[inwin]
        timing[f"sample_to_apply_{path}"] = summarize_ns(lat)
        series[f"sample_to_apply_{path}"] = lat
        seg = agemod.segments(land, samp, r.w1)
        timing[f"command_age_{path}"] = agemod.age_summary(seg, r.w0, r.h)
        series[f"command_age_{path}"] = seg
        if not applied:
            continue
        timing["startup_hold_s"] = (int(land[0]) - r.w0) / 1e9 if land.size else None
        landed = np.unique(samp)
        without = judged & ~np.isin(s["sample_ns"], landed)
        timing["samples_without_command"] = int(without.sum())
        timing["samples_judged"] = n_judged
        timing["samples_without_command_rate"] = int(without.sum()) / n_judged if n_judged else 0.0
        late = (lat > r.ts) & (samp[inwin] <= judged_until)
        timing["late_commands"] = int(late.sum())
        timing["late_commands_rate"] = int(late.sum()) / n_judged if n_judged else 0.0
        timing["sample_gap"] = summarize_ns(np.diff(landed[_in(landed, r.w0, r.w1)]))
        series["applied_path"] = path


def _messages(r: _Run) -> dict[str, Any]:
    s, t = r.samples, r.ticks
    srx = r.logs["state_rx"]
    state = _stream_counts(s["seq"], srx["seq"])
    state["injected_drops"] = int(((s["flags"] & SAMPLE_DROPPED) != 0).sum())
    state["injected_duplicates"] = int(((s["flags"] & SAMPLE_DUPLICATED) != 0).sum())
    out: dict[str, Any] = {"state": state}
    zsent = (t["zenoh_send_ns"] > 0) & (t["cmd_seq"] >= 0)
    # Commands count while the plant still listens: sent up to 2 Ts + delay + jitter before
    # its last sample (later ones may land after it stopped: "sent_after_window", not lost).
    end = r.w1 - r.settle
    inwin = zsent & _in(t["zenoh_send_ns"], r.w0, end)
    rx = r.logs["cmd_rx"]
    z = _stream_counts(t["cmd_seq"][inwin], rx["seq"][rx["path"] == 0])
    z["injected_drops"] = int(((t["flags"][inwin] & TICK_DROPPED) != 0).sum())
    z["injected_duplicates"] = int(((t["flags"][inwin] & TICK_DUPLICATED) != 0).sum())
    z["injected_reorders"] = int(((t["flags"][inwin] & TICK_REORDERED) != 0).sum())
    z["sent_after_window"] = int((zsent & (t["zenoh_send_ns"] > end)).sum())
    out["torque_zenoh"] = z
    tx = r.logs["can_tx"]
    if tx["node"].size or (rx["path"] == 1).any():
        out["torque_can"] = _can_messages(r)
    return out


def _can_messages(r: _Run) -> dict[str, Any]:
    """Per command (both wheels' frames of one cycle) and per frame; lifecycle zeros apart."""
    t, tx, c = r.ticks, r.logs["can_tx"], r._can
    rows, found = r.tick_of(tx["cmd_seq"])
    when = np.zeros(tx["cmd_seq"].size, np.int64)
    when[found] = t["compute_start_ns"][rows[found]]
    end = r.w1 - r.settle  # as for Zenoh: frames sent while the drives still listen
    # A command is this window's if it was computed in it and its last frame was put on the bus
    # by the end (a frame never on the bus counts at its compute time): a host stalled between
    # compute and send must not make a frame sent after the plant stopped count as lost.
    is_cmd = tx["cmd_seq"] >= 0
    put = np.where(tx["send_ns"] > 0, tx["send_ns"], when)[is_cmd]
    ids, inv = np.unique(tx["cmd_seq"][is_cmd], return_inverse=True)
    last_put = np.full(ids.size, np.iinfo(np.int64).min)
    np.maximum.at(last_put, inv, put)
    first = np.full(ids.size, np.iinfo(np.int64).max)
    np.minimum.at(first, inv, when[is_cmd])
    in_window = (first >= r.w0) & (last_put <= end)
    sent_cmds = ids[in_window]
    mine = np.zeros(is_cmd.size, bool)  # this window's command frames
    mine[is_cmd] = in_window[inv]
    got = (c["cmd"] >= 0) & ~c["lost"]
    nodes = max(1, np.unique(tx["node"]).size)
    received = sent_cmds[np.isin(sent_cmds, _whole(c["cmd"][got], nodes))]
    frames_sent = int(mine.sum())
    frames_rx = int((got & np.isin(c["cmd"], sent_cmds)).sum())
    out = {
        "sent": int(sent_cmds.size),
        "received": int(received.size),
        "lost": int(sent_cmds.size - received.size),
        "duplicated": 0,
        "reordered": 0,
        "frames_sent": frames_sent,
        "frames_received": frames_rx,
        "frames_lost": frames_sent - frames_rx,
        "frames_not_on_bus": int((mine & (tx["send_ns"] <= 0)).sum()),
        "injected_frame_losses": int((c["lost"] & np.isin(c["cmd"], sent_cmds)).sum()),
        "lifecycle_frames_sent": int((tx["cmd_seq"] < 0).sum()),
        "unmatched_frames_received": int((c["cmd"] == -2).sum()),
        "value_mismatches": int(r.value_mismatches),
        "sent_after_window": int((last_put > end).sum()),
    }
    if r.applied == "can":
        out.update(_can_fates(r, received, nodes))
    return out


def _whole(cmd: np.ndarray, nodes: int) -> np.ndarray:
    """The commands among ``cmd`` (one entry a frame) that have a frame for every wheel."""
    ids, counts = np.unique(cmd, return_counts=True)
    return ids[counts >= nodes]


def _can_fates(r: _Run, received: np.ndarray, nodes: int) -> dict[str, int]:
    """What became of each received command on the applied CAN path: ``applied`` (both wheels'
    frames landed), ``refused_by_drive`` (a wheel's drive refused a frame of it: non-finite,
    disarmed), ``arrived_after_plant_stopped`` (its last frame came after the plant's last
    sample: a slow host delayed it past the window; never applied, not lost). A received
    command that is none of these was dropped by the plant unexplained: ``unaccounted``."""
    a, c = r.can_applies, r._can
    cmd, outcome = a["cmd"], a["outcome"]
    applied = np.isin(received, _whole(cmd[np.isin(outcome, LANDINGS)], nodes))
    refused = np.isin(received, cmd[outcome == APPLY_REFUSED]) & ~applied
    late_ids = c["cmd"][(c["cmd"] >= 0) & ~c["lost"] & (c["recv"] > r.w1)]
    late = np.isin(received, late_ids) & ~applied & ~refused
    return {
        "applied": int(applied.sum()),
        "refused_by_drive": int(refused.sum()),
        "arrived_after_plant_stopped": int(late.sum()),
        "unaccounted": int((~(applied | refused | late)).sum()),
    }


def _certificate(r: _Run, b: BoundInputs, series: dict[str, Any]) -> dict[str, Any]:
    from controller_service.certificate import certify, critical_age

    seg: agemod.AgeSegments = series.get(f"command_age_{r.applied}") or agemod.segments(
        np.zeros(0, np.int64), np.zeros(0, np.int64), r.w1
    )
    d_max_ns = agemod.max_age(seg)
    d_star = critical_age(b.params, b.context, b.boundary_layer, v0=b.v0, w0=b.w0)
    d_max = d_max_ns / 1e9 if d_max_ns is not None else None
    cert = None
    if d_max is not None:
        cert = certify(b.params, b.context, d_max, 0.0, b.boundary_layer, v0=b.v0, w0=b.w0)
    threshold_ns = int(max(3 * r.ts, 0.5 * d_star * 1e9))
    stalls = find_stalls(r, seg, threshold_ns)
    held = bool(cert is not None and cert.held and d_max is not None and d_max <= d_star)
    return {
        "path": r.applied,
        "d_max_s": d_max,
        "d_star_s": d_star,
        "margin_s": (d_star - d_max) if d_max is not None else None,
        "held": held,
        "v_bound": float(cert.v_bound) if cert is not None else None,
        "omega_bound": float(cert.w_bound) if cert is not None else None,
        "stall_threshold_s": threshold_ns / 1e9,
        "stalls": stalls,
    }


def find_stalls(r: _Run, seg: agemod.AgeSegments, threshold_ns: int) -> list[dict[str, Any]]:
    """Excursions of the applied path's command age above ``threshold_ns``, worst first, each
    with the cause found by joining the logs over [sample in force, next landing]."""
    found: list[dict[str, Any]] = []
    peaks = seg.peak
    over = np.nonzero(peaks > threshold_ns)[0]
    if len(seg) and int(seg.start[0]) - r.w0 > threshold_ns:
        # A late first landing: the hold before it and the age of that first (old) command
        # are one excursion, the start-up's.
        age = int(seg.start[0]) - r.w0
        if over.size and over[0] == 0:
            age = max(age, int(peaks[0]))
            over = over[1:]
        found.append({"t_s": 0.0, "age_s": age / 1e9, "cause": "startup"})
    # The worst first, and only as many as are listed: joining the logs for each costs time.
    over = over[np.argsort(-peaks[over], kind="stable")][:STALL_LIMIT]
    for j in over.tolist():
        s0, e = int(seg.sample[j]), int(seg.end[j])
        cause, evidence = _cause(r, s0, e)
        found.append(
            {
                "t_s": (s0 + threshold_ns - r.epoch) / 1e9,
                "age_s": int(peaks[j]) / 1e9,
                "cause": cause,
                "evidence": evidence,
            }
        )
    found.sort(key=lambda st: -st["age_s"])
    return found[:STALL_LIMIT]


def _longest_quiet(stamps: np.ndarray, lo: int, hi: int) -> int:
    """The longest stretch of [lo, hi] without a stamp."""
    inside = np.sort(stamps[_in(stamps, lo, hi)])
    edges = np.concatenate([[lo], inside, [hi]])
    return int(np.diff(edges).max())


def _cause(r: _Run, lo: int, hi: int) -> tuple[str, dict[str, Any]]:
    t, s = r.ticks, r.samples
    scores: dict[str, float] = {}
    ev: dict[str, Any] = {}
    if r.trigger == "periodic" and t["wake_ns"].size:
        m = _in(t["wake_ns"], lo, hi)
        if m.any():
            worst = int((t["wake_ns"][m] - t["deadline_ns"][m]).max())
            ev["controller_lateness_s"] = worst / 1e9
            if worst >= r.period:
                scores["controller_late"] = worst
        # No tick at all for longer than the period's slack: the controller was down (killed,
        # restarting): it did not wake, the latest of lates.
        quiet = _longest_quiet(t["wake_ns"], lo, hi)
        if quiet >= 2 * r.period:
            ev["controller_silent_s"] = quiet / 1e9
            scores["controller_late"] = max(scores.get("controller_late", 0), quiet)
    m = _in(s["wake_ns"], lo, hi) if not r.lockstep else np.zeros(0, bool)
    if m.any():
        worst = int((s["wake_ns"][m] - s["sample_ns"][m]).max())
        ev["plant_lateness_s"] = worst / 1e9
        if worst >= r.sensor_period:
            scores["plant_late"] = worst
    m = _in(s["sample_ns"], lo, hi)
    lost = m & ~np.isin(s["seq"], r.logs["state_rx"]["seq"])
    if lost.any():
        ev["states_lost"] = int(lost.sum())
        ev["states_dropped_by_faults"] = int(((s["flags"][lost] & SAMPLE_DROPPED) != 0).sum())
        scores["state_lost"] = int(lost.sum()) * r.sensor_period
    rx = r.logs["cmd_rx"]
    if r.applied == "zenoh":
        sent = (t["zenoh_send_ns"] > 0) & _in(t["zenoh_send_ns"], lo, hi)
        lost_c = sent & ~np.isin(t["cmd_seq"], rx["seq"][rx["path"] == 0])
        if lost_c.any():
            ev["commands_lost"] = int(lost_c.sum())
            dropped = (t["flags"][lost_c] & (TICK_DROPPED | TICK_REORDERED)) != 0
            ev["commands_dropped_by_faults"] = int(dropped.sum())
            scores["command_lost"] = int(lost_c.sum()) * r.period
    else:
        tx, c = r.logs["can_tx"], r._can
        rows, found = r.tick_of(tx["cmd_seq"])
        when = np.where(found, t["compute_start_ns"][np.where(found, rows, 0)], 0)
        cmds = np.unique(tx["cmd_seq"][(tx["cmd_seq"] >= 0) & _in(when, lo, hi)])
        got = c["cmd"][(c["cmd"] >= 0) & ~c["lost"]]
        lost_cmds = cmds[~np.isin(cmds, got)]
        if lost_cmds.size:
            ev["commands_lost"] = int(lost_cmds.size)
            off_bus = np.isin(tx["cmd_seq"], lost_cmds) & (tx["send_ns"] <= 0)
            ev["frames_not_on_bus"] = int(off_bus.sum())
            ev["frames_lost_by_faults"] = int((c["lost"] & np.isin(c["cmd"], lost_cmds)).sum())
            scores["command_lost"] = int(lost_cmds.size) * r.period
    ap = r.logs["apply"]
    burst = (ap["outcome"] == APPLY_BURST) & _in(ap["apply_ns"], lo, hi)
    if burst.any():
        late = int((ap["apply_ns"][burst] - ap["recv_ns"][burst]).max())
        ev["landings_delayed_by_faults"] = int(burst.sum())
        scores["command_delayed"] = late
    if not scores:
        return "unknown", ev
    return max(scores, key=lambda k: scores[k]), ev
