"""Known answers for hil.analysis.measure: hop logs written with known stamps, the figures found
again.

Each test injects what a figure measures (a stall, a delay, a loss, a duplicate, a CAN re-arm)
into a scripted loop (tests/synthetic_run.py) and checks the one pipeline reports exactly it.
The same injections with real processes are in tests/test_calibration.py.
"""

from __future__ import annotations

import numpy as np
import pytest

from hil.analysis.measure import load_folder_logs, measure
from hil.analysis.measure.age import age_summary, envelope, max_age, segments
from hil.analysis.measure.stats import summarize_ns
from protocol.hoplog import HopLogError, HopLogWriter, iter_records, read_hoplog
from tests.synthetic_run import MS, US, Loop, write


def _measure(tmp_path, loop: Loop, bound=None):
    write(tmp_path / "run", loop)
    logs = load_folder_logs(tmp_path / "run")
    assert logs is not None
    return measure(logs, bound)


def _paper_bound():
    from types import SimpleNamespace

    from controller_service.laws.base import DesignContext
    from hil.folder.scenario_view import BoundInputs

    params = SimpleNamespace(m1=0.5, m2=0.5, l1=0.5, l2=0.5, lam=1.0, rho=1.0)
    return BoundInputs(params, DesignContext(), False)


# --- exact statistics ---------------------------------------------------------------------------


def test_percentiles_are_measured_values_never_above_the_max():
    rng = np.random.default_rng(1)
    v = rng.integers(0, 10_000_000, 12345)
    s = summarize_ns(v)
    sv = np.sort(v)
    for name, q in (("p50_us", 50), ("p99_us", 99), ("p999_us", 99.9)):
        assert s[name] * 1000 in set(sv.tolist())
        assert s[name] == np.percentile(v, q, method="inverted_cdf") / 1000
        assert s[name] <= s["max_us"]
    assert s["max_us"] == v.max() / 1000 and s["count"] == v.size


def test_command_age_at_every_plant_step_equals_brute_force():
    rng = np.random.default_rng(7)
    h, g0 = 100 * US, 5 * MS
    sample = g0 + np.cumsum(rng.integers(500 * US, 3 * MS, 400))
    land = sample + rng.integers(100 * US, 2 * MS, 400)
    land = np.maximum.accumulate(land)
    end = int(land[-1] + 3 * MS)
    seg = segments(land, sample, end)
    grid = np.arange(-(-(int(land[0]) - g0) // h), -(-(end - g0) // h)) * h + g0
    idx = np.searchsorted(land, grid, side="right") - 1
    ages = grid - sample[idx]
    got = age_summary(seg, g0, h)
    want = summarize_ns(ages)
    for key in ("count", "p50_us", "p90_us", "p99_us", "p999_us"):
        assert got[key] == want[key], key
    assert got["mean_us"] == pytest.approx(want["mean_us"], rel=1e-9)
    # The max is D: the age just before each next landing, not only on the grid.
    assert got["max_us"] * 1000 == max_age(seg) == int((seg.end - seg.sample).max())
    _, lo, hi = envelope(seg, g0, bins=50)
    assert hi.max() * 1e9 == pytest.approx(max_age(seg)) and lo.min() >= 0


# --- the loop's figures ---------------------------------------------------------------------------


def test_a_clean_loop_has_one_period_of_age_and_nothing_lost(tmp_path):
    m = _measure(tmp_path, Loop(), _paper_bound())
    t = m.timing
    assert t["deadline_misses"] == 0 and t["skipped_slots"] == 0
    assert t["samples_without_command"] == 0 and t["late_commands"] == 0
    # sample -> wake 20 µs -> send +100 -> arrival +200 ... the tick is at P/2 + 15 µs:
    # compute starts 5 µs later, sends after 30 + 10 µs, the command lands 150 µs on.
    lat = 1 * MS + 15 * US + 5 * US + 30 * US + 10 * US + 150 * US
    assert t["sample_to_apply_zenoh"]["p50_us"] == t["sample_to_apply_zenoh"]["max_us"] == lat / 1e3
    assert m.certificate["d_max_s"] == pytest.approx((2 * MS + lat) / 1e9)
    assert m.certificate["path"] == "zenoh" and m.certificate["held"] is True
    assert m.certificate["stalls"] == []
    for stream in ("state", "torque_zenoh", "torque_can"):
        assert m.messages[stream]["lost"] == 0, stream
    assert t["startup_hold_s"] == pytest.approx(lat / 1e9)


def test_a_30ms_controller_stall_is_found_in_full(tmp_path):
    loop = Loop(controller_stall=(400 * MS, 30 * MS))
    m = _measure(tmp_path, loop, _paper_bound())
    t = m.timing
    # The stall starts 1 ms after a deadline (+P/2) and ends 30 ms later: the late tick wakes
    # 29 ms after its deadline (never re-based), 14 slots were never run.
    assert t["wakeup_lateness"]["max_us"] == 29_000
    assert t["late_ticks"] == 1 and t["skipped_slots"] == 14
    assert t["deadline_misses"] == 15  # a stall of N periods misses N slots
    assert t["slots"] == t["ticks"] + 14
    assert t["deadline_miss_rate"] == pytest.approx(15 / t["slots"])
    assert 30_000 <= t["command_age_zenoh"]["max_us"] <= 30_000 + 2 * 2_000 + 1_210
    worst = m.certificate["stalls"][0]
    assert worst["cause"] == "controller_late" and worst["owner"] == "system"
    assert m.certificate["stall_count"] == 1
    assert worst["age_s"] >= 0.030 and abs(worst["t_s"] - 0.4) < 0.01
    assert t["samples_without_command"] >= 14  # states that arrived during the stall


def test_a_30ms_plant_stall_is_blamed_on_the_plant(tmp_path):
    m = _measure(tmp_path, Loop(plant_stall=(600 * MS, 30 * MS)), _paper_bound())
    assert m.timing["plant_wakeup_lateness"]["max_us"] >= 29_000
    worst = m.certificate["stalls"][0]
    assert worst["cause"] == "plant_late" and worst["age_s"] >= 0.030
    assert abs(worst["t_s"] - 0.6) < 0.1


def test_a_constant_delay_shifts_age_and_latency_by_exactly_that(tmp_path):
    a = _measure(tmp_path / "a", Loop())
    b = _measure(tmp_path / "b", Loop(delay=5 * MS))
    for fig in ("sample_to_apply_zenoh", "command_age_zenoh"):
        assert b.timing[fig]["p50_us"] - a.timing[fig]["p50_us"] == pytest.approx(5000, abs=1)
    assert b.timing["late_commands"] == b.timing["samples_judged"]  # every one > one period


def test_injected_drops_equal_the_lost_counts_exactly(tmp_path):
    m = _measure(tmp_path, Loop(drop_state_every=7, drop_command_every=5))
    st, cmd = m.messages["state"], m.messages["torque_zenoh"]
    assert st["lost"] == st["injected_drops"] == 500 // 7
    assert cmd["lost"] == cmd["injected_drops"] > 0
    assert cmd["sent"] - cmd["received"] == cmd["injected_drops"]


def test_lost_states_duplicates_are_counted_apart(tmp_path):
    m = _measure(tmp_path, Loop(lose_states={10, 11, 12}, duplicate_commands={3, 4}))
    assert m.messages["state"]["lost"] == 3 and m.messages["state"]["injected_drops"] == 0
    assert m.messages["torque_zenoh"]["duplicated"] == 2
    assert m.messages["torque_zenoh"]["lost"] == 0


def test_many_lost_states_make_a_stall_with_that_cause(tmp_path):
    m = _measure(tmp_path, Loop(lose_states=set(range(100, 120))), _paper_bound())
    worst = m.certificate["stalls"][0]
    assert worst["cause"] == "state_lost" and worst["evidence"]["states_lost"] == 20


def test_can_rearm_mid_run_keeps_matching_and_counts_no_lifecycle_frame(tmp_path):
    a = _measure(tmp_path / "a", Loop(cmd_path="can"))
    b = _measure(tmp_path / "b", Loop(cmd_path="can", rearm_at=250))
    for m in (a, b):
        can = m.messages["torque_can"]
        assert can["value_mismatches"] == 0
        assert can["sent"] == can["received"] and can["lost"] == 0
        assert can["frames_sent"] == can["frames_received"] == 2 * can["sent"]
    assert b.messages["torque_can"]["lifecycle_frames_sent"] == 4
    assert b.timing["sample_to_apply_can"] == a.timing["sample_to_apply_can"]
    assert b.timing["hop_cmd_can"] == a.timing["hop_cmd_can"]


def test_can_frames_lost_on_the_wire_shift_no_match(tmp_path):
    """A frame lost between the buses (no sequence number in CANSimple) must not shift the
    matching of every later one: losses are counted, the rest match their own sends."""
    clean = _measure(tmp_path / "a", Loop(cmd_path="can"))
    m = _measure(tmp_path / "b", Loop(cmd_path="can", lose_can_frames={5, 77, 78, 300}))
    can = m.messages["torque_can"]
    assert can["lost"] == 4 and can["frames_lost"] == 8, can
    assert can["unmatched_frames_received"] == 0
    assert m.timing["hop_cmd_can"]["max_us"] == clean.timing["hop_cmd_can"]["max_us"] == 250.0
    assert "negative" not in m.timing["hop_cmd_can"]
    assert can["value_mismatches"] == 0


def test_without_frame_names_a_lost_frame_is_one_lost_frame_and_nothing_else(tmp_path):
    """On a bus that names no frame (socketcan, udp_multicast), arrivals are matched by bytes
    and order: frames lost on the wire are exactly those frames lost, every other arrival is
    matched to its own send (hops, ages and D as in the clean run), nothing is ambiguous when
    the payloads change from one command to the next."""
    clean = _measure(tmp_path / "a", Loop(cmd_path="can", named_frames=False), _paper_bound())
    lost = {5, 77, 78, 300}
    m = _measure(
        tmp_path / "b", Loop(cmd_path="can", named_frames=False, lose_can_frames=lost),
        _paper_bound(),
    )  # fmt: skip
    can = m.messages["torque_can"]
    assert can["lost"] == 4 and can["frames_lost"] == 8, can
    assert can["value_mismatches"] == 0 and can["unmatched_frames_received"] == 0
    assert can["frames_ambiguous"] == 0
    hop = m.timing["hop_cmd_can"]
    assert hop["p50_us"] == hop["max_us"] == 250.0 and "not_relatable" not in hop
    assert m.timing["hop_cmd_can"]["count"] == clean.timing["hop_cmd_can"]["count"] - 8
    assert m.certificate["held"] is True
    # Each lost command leaves its sample without a command and the one before it in force
    # a period longer: D grows by exactly one period (78 and 77 lost: two periods).
    d_clean = clean.certificate["d_max_s"]
    assert m.certificate["d_max_s"] == pytest.approx(d_clean + 2 * 0.002, abs=1e-9)
    assert m.timing["samples_without_command"] == clean.timing["samples_without_command"] + 4


def test_without_frame_names_identical_payloads_a_slow_bus_or_a_loss_shift_nothing(tmp_path):
    """A saturated law sends the same bytes every cycle. A bus slower than two periods, with
    nothing lost, must not read as frames lost at the start and short hops (the newest send of
    those bytes is then not the frame's own); a loss on a fast bus must not read as every later
    frame a period late. Both embeddings are tried; the one whose hops do not jump wins."""
    base = dict(cmd_path="can", named_frames=False, constant_can_values=True)
    slow_bus = Loop(**base, can_hop=5250 * US, can_reader_stops_after=6 * MS)
    slow = _measure(tmp_path / "slow", slow_bus, _paper_bound())
    can = slow.messages["torque_can"]
    assert can["lost"] == can["frames_lost"] == 0 and can["value_mismatches"] == 0, can
    assert slow.timing["hop_cmd_can"]["p50_us"] == 5250.0
    assert can["frames_realigned"] > 400 and can["frames_ambiguous"] == 0
    lossy = _measure(tmp_path / "loss", Loop(**base, lose_can_frames={100}), _paper_bound())
    can = lossy.messages["torque_can"]
    assert can["frames_lost"] == 2 and can["lost"] == 1 and can["frames_ambiguous"] == 0, can
    assert lossy.timing["hop_cmd_can"]["max_us"] == 250.0
    assert can["frames_realigned"] > 700  # the earliest embedding slid every later frame


def test_when_both_embeddings_fit_alike_the_match_is_ambiguous():
    """Identical payloads every 2 ms, three of five received, nothing else to go by: a constant
    4.5 ms delay with the last two lost, or 0.5 ms with the first two lost. The logs cannot
    decide: every arrival is ambiguous and the bound is the oldest sends."""
    from hil.analysis.measure.can_match import match_node

    sends = np.arange(5, dtype=np.int64) * 2 * MS
    value = np.full(5, 1.5, np.float32)
    recv = np.array([4.5, 6.5, 8.5]) * MS
    m = match_node(sends, value, np.zeros(5, np.int64), recv.astype(np.int64),
                   value[:3], np.zeros(3, np.int64))  # fmt: skip
    assert m.ambiguous.all() and m.chosen.tolist() == [2, 3, 4]
    assert m.earliest.tolist() == [0, 1, 2]


def test_can_duplicates_are_counted_per_frame_and_wheel_and_never_make_a_command_whole(tmp_path):
    for named in (True, False):
        m = _measure(
            tmp_path / str(named),
            Loop(cmd_path="can", named_frames=named, duplicate_can_frames={40, 41}),
        )  # fmt: skip
        can = m.messages["torque_can"]
        assert can["duplicated"] == 4, (named, can)
        assert can["per_node"]["0"]["duplicated"] == can["per_node"]["1"]["duplicated"] == 2
        assert can["lost"] == 0 and can["frames_lost"] == 0 and can["value_mismatches"] == 0
        assert can["unmatched_frames_received"] == 0
    # One wheel's frame lost and the other's duplicated: two frames of the command arrived,
    # but not one from every wheel, so the command is not whole (lost, never applied).
    m = _measure(
        tmp_path / "half",
        Loop(cmd_path="can", duplicate_can_frames={60}, lose_can_wheel_frames={(60, 0)}),
    )  # fmt: skip
    can = m.messages["torque_can"]
    assert can["lost"] == 1 and can["frames_lost"] == 1 and can["duplicated"] == 1, can
    assert can["per_node"]["0"]["frames_lost"] == 1 and can["per_node"]["1"]["duplicated"] == 1
    assert can["applied"] == can["received"] == can["sent"] - 1


def test_a_watchdog_zero_torque_renews_no_age_on_either_path(tmp_path):
    """The controller's watchdog sends zero torque computed from no sample: it is no landing
    of a sampled command, so the age runs on from the last real one (D grows by the commands
    it replaced), never counted from a sample time of 0."""
    for path in ("zenoh", "can"):
        clean = _measure(tmp_path / f"a{path}", Loop(cmd_path=path), _paper_bound())
        m = _measure(
            tmp_path / f"b{path}",
            Loop(cmd_path=path, watchdog_zero_cmds={200, 201, 202}),
            _paper_bound(),
        )  # fmt: skip
        d0, d = clean.certificate["d_max_s"], m.certificate["d_max_s"]
        assert d == pytest.approx(d0 + 3 * 0.002, abs=1e-9), (path, d0, d)


# --- the log itself -------------------------------------------------------------------------------


def test_a_truncated_hop_log_reads_up_to_its_last_whole_chunk(tmp_path):
    path = tmp_path / "x.hoplog"
    w = HopLogWriter(path, "t", {"a": ("i",)}, flush_interval=10.0)
    for i in range(100):
        w.append("a", (i,))
    w.flush()
    w.counters({"n": 100})
    for i in range(100, 200):
        w.append("a", (i,))
    w.close({"n": 200})
    whole = path.read_bytes()
    cut = tmp_path / "cut.hoplog"
    header_end = next(iter_records(path))[1]
    for n in (len(whole) - 1, len(whole) // 2, header_end + 5):
        cut.write_bytes(whole[:n])
        log = read_hoplog(cut)
        assert not log.complete and log.truncated
        assert [r[0] for r in log.rows["a"]] == list(range(len(log.rows["a"])))
    cut.write_bytes(whole[: header_end - 1])  # not even a header: a clear error, not a crash
    with pytest.raises(HopLogError, match="no hop-log header"):
        read_hoplog(cut)
    assert read_hoplog(path).complete and len(read_hoplog(path).rows["a"]) == 200


def test_a_late_start_is_one_startup_stall_and_the_age_counts_from_t0(tmp_path):
    """Zero torque from t = 0 until the first landing is age from t = 0 (the bound's A2): a
    200 ms start-up makes D 200 ms and the certificate not held, and names the start-up."""
    m = _measure(tmp_path, Loop(controller_stall=(0, 200 * MS)), _paper_bound())
    stalls = m.certificate["stalls"]
    hold = m.timing["startup_hold_s"]
    assert 0.200 <= hold <= 0.200 + 0.002 + 0.001
    assert m.certificate["d_max_s"] == pytest.approx(hold, abs=1e-9)  # D is the start-up
    assert m.certificate["held"] is False
    assert stalls[0]["cause"] == "startup" and stalls[0]["t_s"] == 0.0
    assert stalls[0]["age_s"] == pytest.approx(hold, abs=1e-9)
    assert [s["cause"] for s in stalls].count("startup") == 1
    # Every plant step of the window is aged, from t = 0: 0.998 s at the 0.2 ms step.
    assert m.timing["command_age_zenoh"]["count"] == 4990


def test_every_stall_is_counted_with_its_time_and_owner(tmp_path):
    """Two stalls: both counted, the time above the threshold summed exactly; a controller and
    a plant late together is the bench's host (owner bench), and D outside it is the rest."""
    loop = Loop(n=1500, controller_stall=(600 * MS, 30 * MS), plant_stall=(2000 * MS, 30 * MS))
    m = _measure(tmp_path, loop, _paper_bound())
    c = m.certificate
    assert c["stall_count"] == 2
    by = {s["cause"]: s for s in c["stalls"]}
    assert by["controller_late"]["owner"] == "system" and by["plant_late"]["owner"] == "bench"
    # Brute force: the age on a 10 µs grid, the time it spent above the threshold.
    seg = m.series["command_age_zenoh"]
    dt = 10 * US
    grid = np.arange(int(seg.start[0]), int(seg.end[-1]), dt)
    age = grid - seg.sample[np.searchsorted(seg.start, grid, side="right") - 1]
    above = int((age > c["stall_threshold_s"] * 1e9).sum()) * dt / 1e9
    assert c["stalled_time_s"] == pytest.approx(above, abs=2 * 2 * dt / 1e9)
    assert c["stalled_time_s"] > 2 * (0.030 - c["stall_threshold_s"])
    assert c["d_system_s"] == pytest.approx(by["controller_late"]["age_s"], abs=1e-9)
    both = Loop(n=1500, controller_stall=(600 * MS, 30 * MS), plant_stall=(600 * MS, 30 * MS))
    m = _measure(tmp_path / "both", both, _paper_bound())
    (stall,) = m.certificate["stalls"]
    assert stall["cause"] == "host_stalled" and stall["owner"] == "bench"
    assert m.certificate["d_system_s"] < 0.005  # the clean loop's D without it


def test_a_trigger_without_deadlines_has_no_miss_figures_not_zero(tmp_path):
    m = _measure(tmp_path, Loop(trigger="on_state"))
    for key in ("wakeup_lateness", "deadline_misses", "late_ticks", "skipped_slots", "slots",
                "deadline_miss_rate", "period_jitter", "ticks"):  # fmt: skip
        assert key not in m.timing, key
    assert m.timing["plant_deadline_misses"] == 0 and m.timing["plant_slots"] == 500


def test_plant_misses_count_the_slots_a_plant_stall_skipped(tmp_path):
    m = _measure(tmp_path, Loop(plant_stall=(600 * MS, 30 * MS)))
    t = m.timing
    # The sample due at 600 ms woke 30 ms late; the 15 slots after it were never taken.
    assert t["plant_late_samples"] == 1 and t["plant_skipped_slots"] == 15
    assert t["plant_deadline_misses"] == 16
    assert t["plant_deadline_miss_rate"] == pytest.approx(16 / t["plant_slots"])


def test_frames_the_drives_refuse_are_no_landing(tmp_path):
    """A torque frame the drive refuses (non-finite, disarmed) leaves the old torque in force:
    its command never landed, so its sample has no command and the age keeps growing."""
    a = _measure(tmp_path / "a", Loop(cmd_path="can"))
    b = _measure(tmp_path / "b", Loop(cmd_path="can", refuse_can_frames={100, 101, 102}))
    assert b.timing["samples_without_command"] == a.timing["samples_without_command"] + 3
    assert b.timing["command_age_can"]["max_us"] >= a.timing["command_age_can"]["max_us"] + 6000


def test_every_received_can_command_is_applied_refused_or_came_after_the_plant_stopped(tmp_path):
    """A slow host can delay a command sent inside the window past the plant's last sample: it
    is received but never applied, and is counted as such, not as a loss or a silent drop."""
    a = _measure(tmp_path / "a", Loop(cmd_path="can"))
    can = a.messages["torque_can"]
    assert can["applied"] == can["received"] == can["sent"] > 400
    assert can["refused_by_drive"] == can["arrived_after_plant_stopped"] == can["unaccounted"] == 0
    # The last command the window counts (sent 2 Ts before the last sample) and every later
    # one take 10 ms longer: the first lands no more.
    last = can["sent"] - 1
    b = _measure(tmp_path / "b", Loop(cmd_path="can", slow_can_from=(last, 10 * MS)))
    can = b.messages["torque_can"]
    assert can["received"] == can["sent"] and can["lost"] == 0
    assert can["arrived_after_plant_stopped"] == 1 and can["applied"] == can["sent"] - 1
    assert can["unaccounted"] == 0
    c = _measure(tmp_path / "c", Loop(cmd_path="can", refuse_can_frames={100, 101, 102}))
    can = c.messages["torque_can"]
    assert can["refused_by_drive"] == 3 and can["applied"] == can["received"] - 3
    assert can["unaccounted"] == 0
    d = _measure(tmp_path / "d", Loop(cmd_path="can", forget_can_frames={200}))
    assert d.messages["torque_can"]["unaccounted"] == 1


def test_a_can_command_put_on_the_bus_after_the_window_is_not_lost(tmp_path):
    """The window counts a CAN command by when its frames were put on the bus, as Zenoh's by
    its send: computed in time but sent (a stalled host) after the plant stopped listening, it
    is ``sent_after_window``, not a loss."""
    a = _measure(tmp_path / "a", Loop(cmd_path="can"))
    last = a.messages["torque_can"]["sent"] - 1
    b = _measure(tmp_path / "b", Loop(cmd_path="can", late_can_send_from=(last, 10 * MS)))
    ca, cb = a.messages["torque_can"], b.messages["torque_can"]
    assert cb["sent"] == ca["sent"] - 1 and cb["lost"] == 0 and cb["received"] == cb["sent"]
    assert cb["sent_after_window"] == ca["sent_after_window"] + 1


def test_a_command_overtaken_by_one_sent_after_the_window_is_reordered():
    """A [faults] reorder on the window's last command: it is published after the next one,
    which was sent after the window. Its arrival is still an overtaken one (the controller's
    injected_reorders counts it, by its own send time); duplicates and other ids change
    nothing (CI, a slow host: reordered 152 of 153 injected when only window ids counted)."""
    from hil.analysis.measure.figures import _stream_counts

    sent_in_window = np.array([10, 11, 12, 13])
    arrivals = np.array([10, 11, 12, 14, 13, 13, 15])  # 13 held, published after 14
    c = _stream_counts(sent_in_window, arrivals)
    assert (c["sent"], c["received"], c["lost"], c["duplicated"]) == (4, 4, 0, 1)
    assert c["reordered"] == 1
    # inside the window alike; a duplicate's second arrival is no reorder; in order: none
    assert _stream_counts(np.arange(10, 16), arrivals)["reordered"] == 1
    assert _stream_counts(np.arange(10, 14), np.array([10, 12, 11, 12, 13]))["reordered"] == 1
    assert _stream_counts(np.arange(10, 14), np.arange(10, 16))["reordered"] == 0
