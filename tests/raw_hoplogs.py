"""The calibration tests' own reader of a run: the two services' hop logs parsed with the
services' format (protocol.hoplog) and every figure of docs/realtime.md ("Timing figures")
evaluated here from its written definition, with numpy alone.

Nothing here imports hil.analysis.measure: a calibration test compares summary.json
(hil.analysis.measure's one result) with what this module finds in the raw stamps, and the injected
quantity with what the raw stamps show where it was injected. Only what the calibration runs need is
covered: the Zenoh path, and CAN frames on a bus that names them (zenoh_can: each arrival carries
the name its send logged as ``bus_end_ns``, so the matching is a join, not an inference).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np

from protocol.hoplog import (
    TICK_NO_SEND,
    ApplyOutcome,
    CmdPath,
    HopLog,
    RxVerdict,
    read_hoplog,
)

LANDED = (int(ApplyOutcome.LANDED), int(ApplyOutcome.BURST))  # outcomes that put a command in force
QUANTILES = (("p50_us", 50.0), ("p90_us", 90.0), ("p99_us", 99.0))
NAME_TOLERANCE_NS = 2_000  # zenoh_can's frame name crosses the bus as float seconds
FLOAT_COLUMNS = {"tau1", "tau2", "cmd1", "cmd2", "value", "x", "y", "theta", "v", "omega"}


def columns(log: HopLog, table: str) -> dict[str, np.ndarray]:
    """A table of a hop log as numpy columns (int64 for stamps and numbers)."""
    cols = log.columns(table)
    return {
        k: np.asarray(v, dtype=float if k in FLOAT_COLUMNS else np.int64) for k, v in cols.items()
    }


def stats(values_ns: Any) -> dict[str, Any]:
    """count, exact percentiles (a measured value each: numpy's inverted_cdf), max and mean,
    in µs: the summary.json shape, computed here."""
    v = np.asarray(values_ns, dtype=np.int64)
    if v.size == 0:
        return {"count": 0}
    out: dict[str, Any] = {"count": int(v.size)}
    for name, q in QUANTILES:
        out[name] = int(np.percentile(v, q, method="inverted_cdf")) / 1000.0
    out["max_us"] = int(v.max()) / 1000.0
    out["mean_us"] = float(v.mean()) / 1000.0
    return out


def assert_same(name: str, figure: dict[str, Any], values_ns: Any) -> None:
    """summary.json's ``figure`` is the raw values' summary: count, percentiles and max
    exactly (each is one measured value), the mean to float rounding."""
    want = stats(values_ns)
    for key in ("count", *(k for k, _ in QUANTILES), "max_us"):
        if key in want:
            assert figure[key] == want[key], (name, key, figure[key], want[key])
    if want["count"]:
        assert abs(figure["mean_us"] - want["mean_us"]) <= 1e-6 * max(1.0, abs(want["mean_us"])), (
            name,
            figure["mean_us"],
            want["mean_us"],
        )


@dataclass(frozen=True)
class Landings:
    """Changes of the command in force, in time order: when, the sample it was computed from,
    its command number."""

    land: np.ndarray
    sample: np.ndarray
    cmd: np.ndarray


class RawRun:
    """A run folder read from its hop logs and run_settings.json."""

    def __init__(self, folder: Path) -> None:
        self.folder = Path(folder)
        self.ctrl = read_hoplog(self.folder / "controller.hoplog")
        self.plant = read_hoplog(self.folder / "plant.hoplog")
        settings = json.loads((self.folder / "run_settings.json").read_text())
        self.ts = round(float(settings["ts"]) * 1e9)
        self.sensor_ts = round(float(settings.get("sensor_ts") or settings["ts"]) * 1e9)
        self.h = round(float(settings["plant_step"]) * 1e9)
        self.delay = round(float(settings["delay"]) * 1e9)
        self.jitter = round(float(settings["jitter"]) * 1e9)
        self.cmd_path = str(settings["cmd_path"])
        self.epoch = int(self.ctrl.meta["epoch_ns"])
        self.ticks = columns(self.ctrl, "ticks")
        self.state_rx = columns(self.ctrl, "state_rx")
        self.can_tx = columns(self.ctrl, "can_tx")
        self.samples = columns(self.plant, "samples")
        self.cmd_rx = columns(self.plant, "cmd_rx")
        self.apply = columns(self.plant, "apply")
        sn = self.samples["sample_ns"]
        self.w0, self.w1 = int(sn[0]), int(sn[-1])  # the window: first to last plant sample

    @staticmethod
    def epoch_of(folder: Path) -> int:
        """The run's epoch from the controller's hop log (KeyError before the start)."""
        return int(read_hoplog(Path(folder) / "controller.hoplog").meta["epoch_ns"])

    def t(self, ns: Any) -> Any:
        """Seconds after the epoch."""
        return (np.asarray(ns) - self.epoch) / 1e9

    def in_window(self, ns: np.ndarray) -> np.ndarray:
        return (ns >= self.w0) & (ns <= self.w1)

    # --- wake-ups ---------------------------------------------------------------------------
    @cached_property
    def win_ticks(self) -> np.ndarray:
        """Periodic ticks whose slot is due in the window."""
        return self.in_window(self.ticks["deadline_ns"])

    def wakeup_lateness(self) -> np.ndarray:
        t, w = self.ticks, self.win_ticks
        return t["wake_ns"][w] - t["deadline_ns"][w]

    def period_jitter(self) -> np.ndarray:
        t, w = self.ticks, self.win_ticks
        return np.abs(np.diff(t["wake_ns"][w]) - np.diff(t["k"][w]) * self.ts)

    def plant_wakeup_lateness(self) -> np.ndarray:
        return self.samples["wake_ns"] - self.samples["sample_ns"]

    def plant_sample_to_send(self) -> np.ndarray:
        return self.samples["send_ns"] - self.samples["sample_ns"]

    def plant_skipped(self) -> np.ndarray:
        """Per sample, the sensor slots skipped after it (0 for the last)."""
        gaps = np.diff(self.samples["sample_ns"]) // self.sensor_ts - 1
        return np.append(np.clip(gaps, 0, None), 0)

    # --- the controller's side of a command ----------------------------------------------------
    @cached_property
    def fresh(self) -> np.ndarray:
        """Ticks that computed from a fresh State sampled in the window."""
        t = self.ticks
        ok = (t["state_seq"] >= 0) & ((t["flags"] & TICK_NO_SEND) == 0) & (t["state_recv_ns"] > 0)
        return ok & self.in_window(t["state_sample_ns"])

    def compute(self) -> np.ndarray:
        t, f = self.ticks, self.fresh
        return t["compute_end_ns"][f] - t["compute_start_ns"][f]

    def hop_state(self) -> np.ndarray:
        t, f = self.ticks, self.fresh
        return t["state_recv_ns"][f] - t["state_send_ns"][f]

    def wait_for_tick(self) -> np.ndarray:
        t, f = self.ticks, self.fresh
        return t["compute_start_ns"][f] - t["state_recv_ns"][f]

    def tick_of_cmd(self, cmd: np.ndarray) -> np.ndarray:
        """The tick row of each command number (-1: none)."""
        seq = self.ticks["cmd_seq"]
        rows = np.nonzero(seq >= 0)[0]
        where = dict(zip(seq[rows].tolist(), rows.tolist(), strict=True))
        return np.array([where.get(int(c), -1) for c in np.asarray(cmd).tolist()], np.int64)

    # --- Zenoh commands ---------------------------------------------------------------------
    @cached_property
    def zenoh_arrivals(self) -> dict[str, np.ndarray]:
        """Each Zenoh command's first arrival at the plant with its tick row, for commands sent
        (a send stamp) from a sample in the window."""
        rx = self.cmd_rx
        z = rx["path"] == int(CmdPath.ZENOH)
        seq, first = np.unique(rx["seq"][z], return_index=True)
        recv = rx["recv_ns"][z][first]
        row = self.tick_of_cmd(seq)
        t = self.ticks
        ok = row >= 0
        ok[ok] = (t["zenoh_send_ns"][row[ok]] > 0) & self.in_window(t["state_sample_ns"][row[ok]])
        return {"seq": seq[ok], "recv": recv[ok], "row": row[ok]}

    def hop_cmd_zenoh(self) -> np.ndarray:
        a = self.zenoh_arrivals
        return a["recv"] - self.ticks["zenoh_send_ns"][a["row"]]

    def loop_transport_compute(self) -> np.ndarray:
        a, t = self.zenoh_arrivals, self.ticks
        r = a["row"]
        hop_state = t["state_recv_ns"][r] - t["state_send_ns"][r]
        compute = t["compute_end_ns"][r] - t["compute_start_ns"][r]
        return (hop_state + compute + self.hop_cmd_zenoh())[self.fresh[r]]

    def state_send_to_cmd_recv(self) -> np.ndarray:
        a = self.zenoh_arrivals
        s = self.samples
        send = dict(zip(s["seq"].tolist(), s["send_ns"].tolist(), strict=True))
        state = self.ticks["state_seq"][a["row"]].tolist()
        has = np.array([q in send for q in state], bool)
        sent = np.array([send.get(q, 0) for q in state], np.int64)
        return (a["recv"] - sent)[has]

    # --- CAN frames (named by the bus) ------------------------------------------------------
    @cached_property
    def can_frames(self) -> dict[str, np.ndarray]:
        """Every CAN arrival joined to the send of its name (the same node's send whose
        ``bus_end_ns`` is nearest the arrival's, within NAME_TOLERANCE_NS: the name crosses the
        bus as a float of seconds): node, frame index, receive, send, the command it carries
        (-1 a lifecycle zero, -2 no send of that name) and whether it repeats a name already
        received."""
        rx, tx = self.cmd_rx, self.can_tx
        c = (rx["path"] == int(CmdPath.CAN)) & (rx["verdict"] != int(RxVerdict.LOST_BY_FAULT))
        node, name, recv, index = rx["node"][c], rx["send_ns"][c], rx["recv_ns"][c], rx["seq"][c]
        send = np.zeros(node.size, np.int64)
        cmd = np.full(node.size, -2, np.int64)
        which = np.full(node.size, -1, np.int64)
        on_bus = tx["send_ns"] > 0
        for n in np.unique(node).tolist():
            mine = np.nonzero(on_bus & (tx["node"] == n))[0]
            mine = mine[np.argsort(tx["bus_end_ns"][mine], kind="stable")]
            names = tx["bus_end_ns"][mine]
            rows = np.nonzero(node == n)[0]
            if names.size == 0:
                continue
            pos = np.clip(np.searchsorted(names, name[rows]), 1, names.size - 1)
            pos -= np.abs(names[pos - 1] - name[rows]) <= np.abs(names[pos] - name[rows])
            pos = np.clip(pos, 0, names.size - 1)
            ok = np.abs(names[pos] - name[rows]) <= NAME_TOLERANCE_NS
            hit = mine[pos[ok]]
            send[rows[ok]], cmd[rows[ok]], which[rows[ok]] = (
                tx["send_ns"][hit],
                tx["cmd_seq"][hit],
                hit,
            )
        dup = np.zeros(node.size, bool)
        seen: set[int] = set()
        for i, w in enumerate(which.tolist()):
            dup[i] = w >= 0 and w in seen
            seen.add(w)
        return {
            "node": node,
            "index": index,
            "recv": recv,
            "send": send,
            "cmd": cmd,
            "duplicated": dup,
        }

    def hop_cmd_can(self) -> np.ndarray:
        c = self.can_frames
        ok = (c["cmd"] >= 0) & (c["send"] > 0) & self.in_window(c["send"]) & ~c["duplicated"]
        return c["recv"][ok] - c["send"][ok]

    # --- landings and what follows from them ---------------------------------------------------
    @cached_property
    def _named_sample(self) -> dict[int, int]:
        """Command number -> the plant's sample time of the State its first Zenoh arrival
        names (for a command the controller's log lost: killed before its last chunk)."""
        rx, s = self.cmd_rx, self.samples
        sample = dict(zip(s["seq"].tolist(), s["sample_ns"].tolist(), strict=True))
        out: dict[int, int] = {}
        z = rx["path"] == int(CmdPath.ZENOH)
        for q, named in zip(rx["seq"][z].tolist(), rx["state_seq"][z].tolist(), strict=True):
            if q not in out and named in sample:
                out[q] = sample[named]
        return out

    def _sample_of(self, cmd: np.ndarray) -> np.ndarray:
        """The sample each command was computed from: its tick's (the controller's log), else
        the sample of the State it named (docs/realtime.md, sample_to_apply), else 0."""
        row = self.tick_of_cmd(cmd)
        out = np.zeros(row.size, np.int64)
        out[row >= 0] = self.ticks["state_sample_ns"][row[row >= 0]]
        named = self._named_sample
        for i in np.nonzero(row < 0)[0].tolist():
            out[i] = named.get(int(cmd[i]), 0)
        return out

    def _in_force(self, node: np.ndarray, land: np.ndarray, cmd: np.ndarray) -> Landings:
        """Each change of the command in force: the newest landed wins; on CAN a command is in
        force once every wheel's frame of it (or a newer one) landed."""
        keep = cmd >= 0
        keep[keep] = self._sample_of(cmd[keep]) > 0  # a watchdog's zero: no sample, no command
        node, land, cmd = node[keep], land[keep], cmd[keep]
        order = np.argsort(land, kind="stable")
        node, land, cmd = node[order], land[order], cmd[order]
        newest = {int(n): -1 for n in np.unique(node).tolist()}
        out_land, out_cmd, current = [], [], -1
        for n, a, q in zip(node.tolist(), land.tolist(), cmd.tolist(), strict=True):
            newest[n] = max(newest[n], q)
            eff = min(newest.values())
            if eff >= 0 and eff != current:
                out_land.append(a)
                out_cmd.append(eff)
                current = eff
        cmd_arr = np.array(out_cmd, np.int64)
        return Landings(np.array(out_land, np.int64), self._sample_of(cmd_arr), cmd_arr)

    def landings(self, path: str) -> Landings:
        """The applied path's landings (plant ``apply`` rows), or for a shadow path its
        arrivals (what would have been applied)."""
        applied = path == self.cmd_path
        if path == "zenoh":
            if applied:
                ap = self.apply
                m = np.isin(ap["outcome"], LANDED) & (ap["path"] == int(CmdPath.ZENOH))
                return self._in_force(
                    np.zeros(int(m.sum()), np.int64), ap["apply_ns"][m], ap["seq"][m]
                )
            rx = self.cmd_rx
            m = rx["path"] == int(CmdPath.ZENOH)
            return self._in_force(np.zeros(int(m.sum()), np.int64), rx["recv_ns"][m], rx["seq"][m])
        c = self.can_frames
        if not applied:
            return self._in_force(c["node"], c["recv"], c["cmd"])
        ap = self.apply
        m = np.isin(ap["outcome"], LANDED) & (ap["path"] == int(CmdPath.CAN))
        # The frame landed is the drive's index-th received: the command of that arrival.
        by_index = {
            (int(n), int(i)): int(q)
            for n, i, q in zip(c["node"], c["index"], c["cmd"], strict=True)
        }
        cmd = np.array(
            [
                by_index.get((int(n), int(i)), -2)
                for n, i in zip(ap["node"][m], ap["seq"][m], strict=True)
            ],
            np.int64,
        )
        return self._in_force(ap["node"][m], ap["apply_ns"][m], cmd)

    def sample_to_apply(self, path: str) -> np.ndarray:
        lg = self.landings(path)
        w = self.in_window(lg.sample)
        return lg.land[w] - lg.sample[w]

    def command_age(self, path: str) -> tuple[np.ndarray, int]:
        """The age at every plant step of the window (g = w0 + i h, g < w1): g - the sample of
        the command in force (w0 before the first landing), and the largest age of all, the
        peak before each next landing (the plant also steps to each landing: D)."""
        lg = self.landings(path)
        keep = lg.land <= self.w1
        land, samp = lg.land[keep], lg.sample[keep]
        if land.size == 0 or land[0] > self.w0:
            land, samp = np.r_[self.w0, land], np.r_[self.w0, samp]
        grid = np.arange(self.w0, self.w1, self.h, dtype=np.int64)
        ages = grid - samp[np.searchsorted(land, grid, side="right") - 1]
        peaks = np.r_[land[1:], self.w1] - samp
        return ages, int(peaks.max())

    @property
    def settle(self) -> int:
        """2 Ts + delay + jitter: samples this close to the end are not judged."""
        return 2 * self.ts + self.delay + self.jitter

    def judged(self) -> np.ndarray:
        return self.samples["sample_ns"] <= self.w1 - self.settle

    def samples_without_command(self) -> np.ndarray:
        """The judged samples (their times) from which no landed command was computed."""
        landed = np.unique(self.landings(self.cmd_path).sample)
        s = self.samples["sample_ns"]
        return s[self.judged() & ~np.isin(s, landed)]

    def late_commands(self) -> np.ndarray:
        """Sample times of the landed commands that took more than Ts, judged ones."""
        lg = self.landings(self.cmd_path)
        w = self.in_window(lg.sample) & (lg.sample <= self.w1 - self.settle)
        return lg.sample[w & (lg.land - lg.sample > self.ts)]

    def sample_gap(self) -> np.ndarray:
        landed = np.unique(self.landings(self.cmd_path).sample)
        return np.diff(landed[self.in_window(landed)])


FIGURES = {
    "wakeup_lateness": lambda r: r.wakeup_lateness(),
    "period_jitter": lambda r: r.period_jitter(),
    "plant_wakeup_lateness": lambda r: r.plant_wakeup_lateness(),
    "plant_sample_to_send": lambda r: r.plant_sample_to_send(),
    "compute": lambda r: r.compute(),
    "hop_state": lambda r: r.hop_state(),
    "wait_for_tick": lambda r: r.wait_for_tick(),
    "hop_cmd_zenoh": lambda r: r.hop_cmd_zenoh(),
    "hop_cmd_can": lambda r: r.hop_cmd_can(),
    "loop_transport_compute": lambda r: r.loop_transport_compute(),
    "state_send_to_cmd_recv": lambda r: r.state_send_to_cmd_recv(),
    "sample_to_apply_zenoh": lambda r: r.sample_to_apply("zenoh"),
    "sample_to_apply_can": lambda r: r.sample_to_apply("can"),
    "sample_gap": lambda r: r.sample_gap(),
}


def check_summary_against_raw(summary: dict[str, Any], raw: RawRun) -> None:
    """Every timing figure and count of ``summary`` equals the raw logs' own evaluation."""
    t = summary["timing"]
    for name, values in FIGURES.items():
        got = values(raw)
        if name not in t and got.size == 0:
            continue  # a path not live
        assert_same(name, t[name], got)
    for path in ("zenoh", "can"):
        if path != raw.cmd_path and not raw.landings(path).land.size:
            assert f"command_age_{path}" not in t  # a path not live: no figure
            continue
        ages, peak = raw.command_age(path)
        age = t[f"command_age_{path}"]
        want = stats(ages)
        assert (age["count"], age["p50_us"], age["p99_us"]) == (
            want["count"],
            want["p50_us"],
            want["p99_us"],
        ), (path, age, want)
        assert age["max_us"] == peak / 1000.0, (path, age, peak)
    assert abs(summary["certificate"]["d_max_s"] * 1e9 - raw.command_age(raw.cmd_path)[1]) <= 1
    late = raw.wakeup_lateness()
    skipped = raw.ticks["skipped"][raw.win_ticks]
    misses = int((late >= raw.ts).sum() + skipped.sum())
    assert (t["late_ticks"], t["skipped_slots"]) == ((late >= raw.ts).sum(), skipped.sum())
    assert (t["deadline_misses"], t["slots"]) == (misses, late.size + skipped.sum())
    assert t["deadline_miss_rate"] == misses / t["slots"]
    plate, pskip = raw.plant_wakeup_lateness(), raw.plant_skipped()
    pmiss = int((plate >= raw.sensor_ts).sum() + pskip.sum())
    assert (t["plant_deadline_misses"], t["plant_skipped_slots"]) == (pmiss, pskip.sum())
    assert t["plant_slots"] == plate.size + pskip.sum()
    assert t["plant_deadline_miss_rate"] == pmiss / t["plant_slots"]
    judged = int(raw.judged().sum())
    assert t["samples_judged"] == judged
    assert t["samples_without_command"] == raw.samples_without_command().size
    assert t["samples_without_command_rate"] == raw.samples_without_command().size / judged
    assert t["late_commands"] == raw.late_commands().size
    assert t["late_commands_rate"] == raw.late_commands().size / judged
    lg = raw.landings(raw.cmd_path)
    assert t["startup_hold_s"] == (int(lg.land[0]) - raw.w0) / 1e9
