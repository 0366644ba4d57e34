"""Two-sided known answers for every timing figure of docs/realtime.md ("Timing figures").

Each test writes a run's two hop logs from a script (tests/synthetic_run.py) in which every
stamp is known, injects one known quantity (a wake-up pattern, a longer hop, a slower law, a
stall, a loss) and checks the figure equals what was injected -- exactly, or within a stated
tolerance on both sides -- and that the figures it must not move stay where they were. A
floor alone (``>=``) would let a regression that doubles a figure pass. The same injections
into real processes are in tests/test_calibration.py; docs/realtime.md lists, per figure,
which test calibrates it (checked at the end of this file).

The scripted loop's stamps (tests/synthetic_run.py, period P = 2 ms, 500 samples):
plant sample d -> wakes d + 20 µs -> sends its State ``plant_send`` (100 µs) later -> the State
arrives ``hop_state`` (200 µs) later; the controller's tick for slot k is due at d + P/2 and wakes
15 µs late, starts computing 5 µs later, computes ``compute`` (30 µs), sends 10 µs later; the
Zenoh command arrives ``hop_cmd`` (150 µs) later and lands ``delay`` after that; each CAN frame
is put on the bus 5 µs after the Zenoh send and arrives 250 µs later.
"""

from __future__ import annotations

import re
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from hil.analysis.measure import load_folder_logs, measure
from hil.analysis.measure.figures import Measurement
from hil.folder.scenario_view import BoundInputs
from tests.calibrates import calibrates
from tests.synthetic_run import MS, US, Loop, write

ROOT = Path(__file__).resolve().parent.parent
P = 2 * MS
H = 200 * US  # the plant's step: the command age is sampled on its grid
# Fixed offsets of tests/synthetic_run.py (not knobs): see the module docstring.
PLANT_WAKE, TICK_WAKE, TO_COMPUTE, TO_SEND, TO_BUS, CAN_HOP = 20, 15, 5, 10, 5, 250  # µs
# The clean loop's figures in µs, from those stamps.
HOP_STATE, COMPUTE, HOP_CMD, PLANT_SEND = 200, 30, 150, 100
WAIT = P // 2 // US + TICK_WAKE + TO_COMPUTE - (PLANT_WAKE + PLANT_SEND + HOP_STATE)  # 700
S2A_ZENOH = P // 2 // US + TICK_WAKE + TO_COMPUTE + COMPUTE + TO_SEND + HOP_CMD  # 1210
S2A_CAN = S2A_ZENOH - HOP_CMD + TO_BUS + CAN_HOP  # 1315
TICKS = 499  # slots due in the window [first sample, last sample]: deadlines 1 ms .. 997 ms
JUDGED = 498  # samples up to 2 P before the last one


def _paper_bound() -> BoundInputs:
    from controller_service.laws.base import DesignContext

    params = SimpleNamespace(m1=0.5, m2=0.5, l1=0.5, l2=0.5, lam=1.0, rho=1.0)
    return BoundInputs(params, DesignContext(), False)


def _measure(tmp_path: Path, name: str, **knobs) -> Measurement:
    write(tmp_path / name, Loop(**knobs))
    logs = load_folder_logs(tmp_path / name)
    assert logs is not None
    return measure(logs, _paper_bound())


def _constant(summary: dict, value_us: float, count: int | None = None) -> None:
    """Every value of the figure is ``value_us``: p50, max and mean all equal it."""
    got = (summary["p50_us"], summary["max_us"], summary["mean_us"])
    assert got == (value_us, value_us, pytest.approx(value_us)), summary
    if count is not None:
        assert summary["count"] == count, summary


@pytest.fixture(scope="module")
def clean(tmp_path_factory) -> Measurement:
    return _measure(tmp_path_factory.mktemp("clean"), "run")


# --- the clean loop: every figure is the stamps' difference -------------------------------------


@calibrates(
    "wakeup_lateness",
    "period_jitter",
    "plant_wakeup_lateness",
    "plant_sample_to_send",
    "compute",
    "hop_state",
    "wait_for_tick",
    "hop_cmd_zenoh",
    "hop_cmd_can",
    "loop_transport_compute",
    "state_send_to_cmd_recv",
    "sample_to_apply_zenoh (applied)",
    "sample_to_apply_can (shadow)",
    "sample_gap",
    "startup_hold_s",
    "command_age_zenoh (applied)",
    "command_age_can (shadow)",
    "late_commands",
    "samples_without_command",
    injects="nothing: a clean scripted loop, every stamp known (tests/synthetic_run.py)",
    found="the difference of the figure's two scripted stamps, to the nanosecond (the test "
    "spells each value out)",
)
def test_the_clean_loop_gives_each_figure_its_scripted_value(clean):
    t = clean.timing
    _constant(t["wakeup_lateness"], TICK_WAKE, TICKS)
    _constant(t["period_jitter"], 0.0, TICKS - 1)
    _constant(t["plant_wakeup_lateness"], PLANT_WAKE, 500)
    _constant(t["plant_sample_to_send"], PLANT_WAKE + PLANT_SEND, 500)
    _constant(t["compute"], COMPUTE)
    _constant(t["hop_state"], HOP_STATE)
    _constant(t["wait_for_tick"], WAIT)
    _constant(t["hop_cmd_zenoh"], HOP_CMD)
    _constant(t["hop_cmd_can"], CAN_HOP)
    _constant(t["loop_transport_compute"], HOP_STATE + COMPUTE + HOP_CMD)
    _constant(t["state_send_to_cmd_recv"], S2A_ZENOH - PLANT_WAKE - PLANT_SEND)
    _constant(t["sample_to_apply_zenoh"], S2A_ZENOH)
    _constant(t["sample_to_apply_can"], S2A_CAN)  # the CAN shadow: arrival - sample
    _constant(t["sample_gap"], P / US, 498)  # 499 commands landed in the window
    assert t["late_commands"] == t["samples_without_command"] == 0
    assert t["samples_judged"] == JUDGED
    assert t["startup_hold_s"] == S2A_ZENOH * US / 1e9
    # The age saw-tooth: from S2A just after a landing to P + S2A just before the next; on the
    # plant's 200 µs grid the ages of one period are 1400, 1600, ..., 3200 µs: p50 = 2200 µs.
    assert t["command_age_zenoh"]["max_us"] == P / US + S2A_ZENOH
    assert t["command_age_zenoh"]["p50_us"] == 2200.0
    assert t["command_age_can"]["max_us"] == P / US + S2A_CAN  # the shadow's age
    assert clean.certificate["d_max_s"] == (P / US + S2A_ZENOH) / 1e6


# --- controller wake-ups ------------------------------------------------------------------------


@calibrates(
    "wakeup_lateness",
    "period_jitter",
    "wait_for_tick",
    injects="ticks 0, 100, 300 µs late in turn",
    found="lateness p50 115 µs, max 315 µs; jitter p50 200 µs, max 300 µs; wait p50 +100 "
    "µs, exactly",
)
def test_a_known_wake_pattern_gives_lateness_and_jitter_exactly(tmp_path):
    """Ticks wake 0, 100, 300 µs later in turn (k mod 3): lateness is 15 µs plus that; the
    jitter |wake_k - wake_(k-1) - P| is 100, 200, 300 µs in turn."""
    m = _measure(tmp_path, "run", tick_late=(0, 100 * US, 300 * US))
    t = m.timing
    extra = np.array([0, 100, 300])[np.arange(TICKS) % 3]
    lat = t["wakeup_lateness"]
    assert (lat["count"], lat["p50_us"], lat["max_us"]) == (TICKS, 115.0, 315.0)
    assert lat["mean_us"] == pytest.approx(TICK_WAKE + extra.mean(), abs=1e-9)
    jit = t["period_jitter"]
    assert (jit["count"], jit["p50_us"], jit["max_us"]) == (TICKS - 1, 200.0, 300.0)
    assert jit["mean_us"] == pytest.approx(np.abs(np.diff(extra)).mean(), abs=1e-9)
    # What a later tick changes, and what it must not.
    assert t["wait_for_tick"]["p50_us"] == WAIT + 100 and t["wait_for_tick"]["max_us"] == WAIT + 300
    assert t["sample_to_apply_zenoh"]["max_us"] == S2A_ZENOH + 300
    _constant(t["hop_state"], HOP_STATE)
    _constant(t["loop_transport_compute"], HOP_STATE + COMPUTE + HOP_CMD)
    _constant(t["plant_wakeup_lateness"], PLANT_WAKE)
    assert t["late_commands"] == 0 and t["deadline_misses"] == 0


@calibrates(
    "late_commands",
    "late_commands_rate",
    injects="every fifth tick 900 µs late",
    found="exactly those commands late: 99 of 498 judged samples",
)
def test_ticks_900us_late_make_exactly_those_commands_late(tmp_path):
    """Every fifth tick wakes 900 µs late: its command lands 2110 µs after its sample, more
    than one period; the others (1210 µs) are in time."""
    m = _measure(tmp_path, "run", tick_late=(0, 0, 0, 0, 900 * US))
    t = m.timing
    late = len(range(4, JUDGED, 5))  # ticks k = 4, 9, ... of the judged samples k < 498
    assert t["late_commands"] == late == 99
    assert t["late_commands_rate"] == late / JUDGED
    assert t["samples_without_command"] == 0
    assert t["wakeup_lateness"]["max_us"] == TICK_WAKE + 900
    assert t["sample_to_apply_zenoh"]["max_us"] == S2A_ZENOH + 900


@calibrates(
    "wakeup_lateness",
    "skipped_slots",
    "period_jitter",
    "samples_without_command",
    "sample_gap",
    "command_age_zenoh (applied)",
    injects="no tick from 400 ms to 430 ms",
    found="lateness max 29 ms, 14 skipped slots, jitter max 28.985 ms, 14 samples without"
    " a command, a 30 ms gap, D = 32.195 ms, exactly",
)
def test_a_30ms_controller_stall_gives_each_figure_exactly(tmp_path):
    """SIGSTOP-like: no tick from 400 ms to 430 ms. The tick due at 401 ms wakes at 430 ms
    (29 ms late, never re-based), 14 slots are skipped, and it computes from the newest state,
    the sample of 428 ms: samples 400 .. 426 ms (14) never get a command. The command in force
    since 399.21 ms (sample 398 ms) is replaced at 430.195 ms: D = 32.195 ms."""
    m = _measure(tmp_path, "run", controller_stall=(400 * MS, 30 * MS))
    t = m.timing
    assert t["wakeup_lateness"]["max_us"] == 29_000.0
    assert t["wakeup_lateness"]["p50_us"] == TICK_WAKE
    assert t["skipped_slots"] == 14
    # 430 ms - 399.015 ms against one period, then 431.015 - 430 ms against 15 periods.
    assert t["period_jitter"]["max_us"] == 28_985.0
    assert t["samples_without_command"] == 14
    assert t["late_commands"] == 1  # the first one after it: 430.195 - 428 = 2.195 ms
    assert t["sample_to_apply_zenoh"]["max_us"] == 2195.0
    assert t["sample_gap"]["max_us"] == 15 * P / US  # landed samples 398 ms, then 428 ms
    assert t["command_age_zenoh"]["max_us"] == 32_195.0
    cert = m.certificate
    assert cert["d_max_s"] == 0.032195
    worst = cert["stalls"][0]
    assert worst["cause"] == "controller_late" and worst["age_s"] == 0.032195
    # It crossed the threshold that long after the sample in force (398 ms).
    assert worst["t_s"] == pytest.approx(0.398 + cert["stall_threshold_s"], abs=1e-9)


@calibrates(
    "plant_wakeup_lateness",
    "plant_skipped_slots",
    "plant_sample_to_send",
    injects="no plant sample from 600 ms to 630 ms",
    found="lateness max 30.02 ms, 15 skipped sensor slots, sample_to_send max 30.12 ms, exactly",
)
def test_a_30ms_plant_stall_gives_each_plant_figure_exactly(tmp_path):
    """The plant's sample due at 600 ms wakes at 630.02 ms (30.02 ms late) and the next is at
    632 ms: 15 sensor slots skipped. Its State goes out 100 µs after the wake."""
    m = _measure(tmp_path, "run", plant_stall=(600 * MS, 30 * MS))
    t = m.timing
    assert t["plant_wakeup_lateness"]["max_us"] == 30_020.0
    assert t["plant_wakeup_lateness"]["p50_us"] == PLANT_WAKE
    assert t["plant_wakeup_lateness"]["count"] == 485  # 500 slots - 15 skipped
    assert t["plant_skipped_slots"] == 15
    assert t["plant_sample_to_send"]["max_us"] == 30_020.0 + PLANT_SEND
    # The controller was on time throughout.
    assert t["wakeup_lateness"]["max_us"] == TICK_WAKE
    # The command of the 598 ms sample stays in force from 599.21 ms until the stalled sample's
    # command lands at 631.21 ms: D = 33.21 ms.
    assert t["command_age_zenoh"]["max_us"] == 33_210.0
    worst = m.certificate["stalls"][0]
    assert worst["cause"] == "plant_late" and worst["age_s"] == 0.03321
    assert worst["t_s"] == pytest.approx(0.598 + m.certificate["stall_threshold_s"], abs=1e-9)


# --- the plant's samples ------------------------------------------------------------------------


@calibrates(
    "plant_wakeup_lateness",
    "plant_sample_to_send",
    "state_send_to_cmd_recv",
    "wait_for_tick",
    injects="samples 0, 0, 300 µs late in turn, each State sent 400 µs (not 100 µs) after its wake",
    found="lateness p50 20 µs, max 320 µs; sample_to_send 420 µs, 720 µs; the wait and "
    "state_send_to_cmd_recv 300 µs shorter, exactly",
)
def test_plant_wake_pattern_and_send_delay_are_found_exactly(tmp_path):
    """Samples wake 0, 0, 300 µs later in turn, and each State goes out 400 µs (not 100) after
    its wake: the plant's figures move by exactly that, the controller's do not."""
    m = _measure(tmp_path, "run", sample_late=(0, 0, 300 * US), plant_send=400 * US)
    t = m.timing
    lat = t["plant_wakeup_lateness"]
    assert (lat["p50_us"], lat["p90_us"], lat["max_us"]) == (20.0, 320.0, 320.0)
    s2s = t["plant_sample_to_send"]
    assert (s2s["p50_us"], s2s["max_us"]) == (PLANT_WAKE + 400, PLANT_WAKE + 400 + 300)
    assert t["plant_deadline_misses"] == t["plant_skipped_slots"] == 0
    _constant(t["hop_state"], HOP_STATE)  # the hop starts at the send
    # The tick does not move: the state waits 300 µs less for it, and 0 or 300 µs more late.
    assert t["wait_for_tick"]["max_us"] == WAIT - 300
    assert t["wait_for_tick"]["p50_us"] == WAIT - 300
    assert t["state_send_to_cmd_recv"]["max_us"] == S2A_ZENOH - PLANT_WAKE - 400
    _constant(t["sample_to_apply_zenoh"], S2A_ZENOH)


# --- the hops and the law -----------------------------------------------------------------------


@calibrates(
    "compute",
    "loop_transport_compute",
    "state_send_to_cmd_recv",
    injects="a law 200 µs slower",
    found="compute 230 µs; what contains it +200 µs, the hops unmoved, exactly",
)
def test_a_200us_slower_law_raises_compute_and_what_contains_it_by_200us(tmp_path, clean):
    m = _measure(tmp_path, "run", compute=(COMPUTE + 200) * US)
    t, c = m.timing, clean.timing
    _constant(t["compute"], COMPUTE + 200, c["compute"]["count"])
    for fig in ("loop_transport_compute", "state_send_to_cmd_recv", "sample_to_apply_zenoh"):
        assert t[fig]["p50_us"] - c[fig]["p50_us"] == 200.0, fig
        assert t[fig]["max_us"] - c[fig]["max_us"] == 200.0, fig
    for fig in ("hop_state", "wait_for_tick", "hop_cmd_zenoh", "hop_cmd_can"):
        assert t[fig] == c[fig], fig


@calibrates(
    "hop_state",
    "wait_for_tick",
    "loop_transport_compute",
    injects="every State 300 µs longer on the wire",
    found="hop_state 500 µs, the wait 300 µs shorter (the tick absorbs it), the loop +300"
    " µs, exactly",
)
def test_a_300us_longer_state_hop_is_found_and_absorbed_by_the_tick(tmp_path, clean):
    m = _measure(tmp_path, "run", hop_state=(HOP_STATE + 300) * US)
    t, c = m.timing, clean.timing
    _constant(t["hop_state"], HOP_STATE + 300, c["hop_state"]["count"])
    _constant(t["wait_for_tick"], WAIT - 300)
    _constant(t["loop_transport_compute"], HOP_STATE + 300 + COMPUTE + HOP_CMD)
    # The periodic tick still runs at its slot: the command is no later.
    for fig in ("state_send_to_cmd_recv", "sample_to_apply_zenoh", "hop_cmd_zenoh", "compute"):
        assert t[fig] == c[fig], fig


@calibrates(
    "hop_cmd_zenoh",
    "loop_transport_compute",
    "state_send_to_cmd_recv",
    "sample_to_apply_zenoh (applied)",
    injects="every Zenoh command 300 µs longer on the wire",
    found="hop_cmd_zenoh 450 µs, and +300 µs in what contains it, exactly",
)
def test_a_300us_longer_command_hop_on_zenoh_is_found_exactly(tmp_path, clean):
    m = _measure(tmp_path, "run", hop_cmd=(HOP_CMD + 300) * US)
    t, c = m.timing, clean.timing
    _constant(t["hop_cmd_zenoh"], HOP_CMD + 300, c["hop_cmd_zenoh"]["count"])
    _constant(t["loop_transport_compute"], HOP_STATE + COMPUTE + HOP_CMD + 300)
    _constant(t["state_send_to_cmd_recv"], S2A_ZENOH + 300 - PLANT_WAKE - PLANT_SEND)
    _constant(t["sample_to_apply_zenoh"], S2A_ZENOH + 300)
    assert t["command_age_zenoh"]["max_us"] == P / US + S2A_ZENOH + 300
    for fig in ("hop_state", "compute", "wait_for_tick", "hop_cmd_can"):
        assert t[fig] == c[fig], fig


@calibrates(
    "hop_cmd_can",
    "sample_to_apply_can (applied)",
    "command_age_can (applied)",
    injects="the applied CAN path, then every frame 300 µs slower; frames named by the "
    "bus and in bus order",
    found="hop_cmd_can 250 µs then 550 µs, sample_to_apply 1315 µs + the same, D a period"
    " past it, exactly",
)
@pytest.mark.parametrize("named", [True, False], ids=["named_frames", "bus_order"])
def test_can_latencies_are_found_exactly_and_a_slower_bus_by_exactly_its_delay(tmp_path, named):
    """The applied CAN path's absolute latencies (both matchings: frames named by the bus, and
    per-node bus order), then every frame 300 µs slower on the wire."""
    a = _measure(tmp_path, "a", cmd_path="can", named_frames=named)
    b = _measure(tmp_path, "b", cmd_path="can", named_frames=named, slow_can_from=(0, 300 * US))
    for m, extra in ((a, 0), (b, 300)):
        t = m.timing
        _constant(t["hop_cmd_can"], CAN_HOP + extra)
        _constant(t["sample_to_apply_can"], S2A_CAN + extra)
        assert t["command_age_can"]["max_us"] == P / US + S2A_CAN + extra
        assert m.certificate["d_max_s"] * 1e6 == pytest.approx(P / US + S2A_CAN + extra)
        _constant(t["hop_cmd_zenoh"], HOP_CMD)  # the Zenoh shadow does not move
        _constant(t["sample_to_apply_zenoh"], S2A_ZENOH)
        assert m.messages["torque_can"]["value_mismatches"] == 0
    assert a.timing["startup_hold_s"] == S2A_CAN * US / 1e9


@calibrates(
    "sample_to_apply_zenoh (applied)",
    "command_age_zenoh (applied)",
    "late_commands",
    "late_commands_rate",
    injects="[timing] delay = 5 ms",
    found="sample_to_apply +5 ms, the age's p50 2200 -> 7200 µs, every judged command "
    "late (495 of 495), the hops unmoved, exactly",
)
def test_a_5ms_delay_shifts_apply_and_age_by_exactly_5ms_and_no_hop(tmp_path, clean):
    m = _measure(tmp_path, "run", delay=5 * MS)
    t, c = m.timing, clean.timing
    _constant(t["sample_to_apply_zenoh"], S2A_ZENOH + 5000)
    assert t["command_age_zenoh"]["max_us"] == P / US + S2A_ZENOH + 5000
    # The grid's ages shift by 25 plant steps: p50 2200 -> 7200 µs.
    assert t["command_age_zenoh"]["p50_us"] == c["command_age_zenoh"]["p50_us"] + 5000 == 7200.0
    for fig in ("hop_cmd_zenoh", "state_send_to_cmd_recv", "loop_transport_compute"):
        assert t[fig] == c[fig], fig  # the delay is after the arrival
    # Judged: samples up to 2 P + delay before the last (k <= 494); every one landed late.
    assert t["samples_judged"] == 495
    assert t["late_commands"] == 495 and t["late_commands_rate"] == 1.0
    assert t["samples_without_command"] == 0


# --- what never landed -------------------------------------------------------------------------


@calibrates(
    "samples_without_command",
    "samples_without_command_rate",
    "sample_gap",
    injects="10 States lost in a row",
    found="10 samples without a command of 498 judged, a 22 ms gap, exactly",
)
def test_lost_states_are_exactly_the_samples_without_command_and_the_gap(tmp_path):
    m = _measure(tmp_path, "run", lose_states=set(range(100, 110)))
    t = m.timing
    assert t["samples_without_command"] == 10
    assert t["samples_without_command_rate"] == 10 / JUDGED
    assert t["sample_gap"]["max_us"] == 11 * P / US  # sample 99, then 110
    assert t["sample_gap"]["count"] == 498 - 10
    assert t["late_commands"] == 0
    # The command of sample 99 stays in force until sample 110's lands.
    assert t["command_age_zenoh"]["max_us"] == 11 * P / US + S2A_ZENOH


@calibrates(
    "samples_without_command",
    injects="every 7th State dropped ([faults])",
    found="71 samples without a command, gaps of 4 ms, lost = injected drops, exactly",
)
def test_dropped_states_every_7th_are_exactly_the_samples_without_command(tmp_path):
    m = _measure(tmp_path, "run", drop_state_every=7)
    dropped = len(range(6, JUDGED, 7))  # samples 6, 13, ... judged (k < 498)
    assert m.timing["samples_without_command"] == dropped == 71
    assert m.timing["sample_gap"]["max_us"] == 2 * P / US
    assert m.messages["state"]["lost"] == m.messages["state"]["injected_drops"] == 500 // 7


# The plant wakes late for every 50th sample (49, 99, ..., 449 judged: 9 of 498, 1.8 %). Its
# State then arrives at d + 20 µs + late + 100 µs + 200 µs; the tick meant for it woke at
# d + 1015 µs and the next takes sample k + 1: the sample is left without a command when
# late > 695 µs. Less the plant's lateness the State would have arrived at d + 320 µs.
PLANT_LATE_EVERY, PLANT_LATE_LEFT = 50, 9


def _plant_late_every_50th(late_ns: int) -> tuple[int, ...]:
    return (0,) * (PLANT_LATE_EVERY - 1) + (late_ns,)


def _judged(m: Measurement):
    from hil.verdict import judge

    return judge({}, {}, m.certificate, m.timing, m.messages)


def test_samples_the_plants_late_wakeups_left_without_a_command_are_the_benchs(tmp_path):
    """A plant woken 1 ms late (its State after the tick, in hand by 695 µs had the plant been
    on time) leaves its sample without a command: 9 of 498, all the plant's, none the
    system's; the verdict is the bench's (INCONCLUSIVE), never the system's FAIL."""
    m = _measure(tmp_path, "run", sample_late=_plant_late_every_50th(1 * MS))
    t = m.timing
    assert t["samples_without_command"] == PLANT_LATE_LEFT
    assert t["samples_without_command_plant_late"] == PLANT_LATE_LEFT
    v = _judged(m)
    assert v.outcome == "INCONCLUSIVE" and not v.fail_reasons, v
    assert "the plant's late wake-ups left 9 of them" in v.inconclusive_reasons[0]
    # Control: 0.6 ms late, its State still before the tick (d + 920 µs): nothing left.
    t = _measure(tmp_path, "early", sample_late=_plant_late_every_50th(600 * US)).timing
    assert (t["samples_without_command"], t["samples_without_command_plant_late"]) == (0, 0)


def test_samples_left_by_the_system_stay_the_systems_beside_a_late_plant(tmp_path):
    """The same 9 States lost on the wire instead (the system's): 9 without a command, none the
    plant's, a FAIL; and a State the plant sent on time that the transport held past the
    tick (TCP behind a retransmission) is the system's too, however late the plant was
    elsewhere."""
    lost = set(range(PLANT_LATE_EVERY - 1, JUDGED, PLANT_LATE_EVERY))
    m = _measure(tmp_path, "lost", lose_states=lost)
    t = m.timing
    assert (t["samples_without_command"], t["samples_without_command_plant_late"]) == (9, 0)
    assert _judged(m).outcome == "FAIL"
    # States sent from 400 ms to 430 ms all arrive at 430.2 ms: 15 samples without a command
    # (400 .. 428 ms: at the tick of 431 ms the 430 ms State is the newest), none the plant's.
    t = _measure(tmp_path, "held", hold_states=(400 * MS, 30 * MS)).timing
    assert t["samples_without_command"] == 15
    assert t["samples_without_command_plant_late"] == 0


# TCP holds what was sent from 900 ms on behind a retransmission until 1.1 s, and the run
# stops its receivers a period after the last sample (998 ms): what was held never arrives,
# and nothing sent after it did.
HELD = (900 * MS, 200 * MS)


def test_messages_held_by_the_transport_when_the_run_stopped_are_in_flight_not_lost(tmp_path):
    """Held at the end, never lost: every one of them in flight at the stop, none lost, no
    lost-messages reason; the wait is in the command age. States 900 .. 998 ms (50); commands
    (States flowing) up to 998 - 2 P = 994 ms, sent from 901.2 ms (sample 900 ms's) on: 47."""
    m = _measure(tmp_path, "states", hold_states=HELD, receivers_stop=P)
    st = m.messages["state"]
    assert (st["lost"], st["in_flight_at_stop"], st["lost_not_injected"]) == (0, 50, 0)
    assert st["received"] + st["in_flight_at_stop"] == st["sent"] == 500
    assert m.timing["command_age_zenoh"]["max_us"] > 90_000  # the wait, in D
    assert not any(r.startswith("lost messages") for r in _judged(m).reasons)
    m = _measure(tmp_path, "commands", hold_commands=HELD, receivers_stop=P)
    z = m.messages["torque_zenoh"]
    assert (z["lost"], z["in_flight_at_stop"]) == (0, 47)
    assert z["received"] + z["in_flight_at_stop"] == z["sent"]
    assert m.timing["command_age_zenoh"]["max_us"] > 90_000
    assert not any(r.startswith("lost messages") for r in _judged(m).reasons)


def test_messages_missing_before_one_that_arrived_are_lost_even_at_the_end(tmp_path):
    """The same States and commands lost on the wire, the last one of each arriving: all lost,
    none in flight; and [faults] drops at the end stay lost (injected), never in flight."""
    last = 499
    states = set(range(450, last))  # 900 .. 996 ms lost, 998 ms's arrives
    m = _measure(tmp_path, "lost", lose_states=states, receivers_stop=P)
    st = m.messages["state"]
    assert (st["lost"], st["in_flight_at_stop"], st["lost_not_injected"]) == (49, 0, 49)
    m = _measure(tmp_path, "dropped", drop_state_every=2, receivers_stop=P)
    st = m.messages["state"]
    assert st["in_flight_at_stop"] == 0 and st["lost"] == st["injected_drops"] == 250


# A 100 Hz controller on a 500 Hz plant (hil run --rate 100): slot k is due at 10 k + 5 ms and
# takes the newest State of the samples since the last deadline (10 k - 4 .. 10 k + 4 ms; slot
# 0: 0, 2, 4 ms). 500 samples (0 .. 998 ms) are judged up to 998 - 2 x 10 = 978 ms: the slots
# whose every sample is judged are 0 .. 97 (slot 97's newest is 974 ms, slot 98's 984 ms).
SLOW_P, FAST_S, SLOW_JUDGED = 10 * MS, 2 * MS, 98


def test_a_controller_below_the_plants_rate_is_judged_on_one_sample_per_period(tmp_path):
    """Nothing lost: no sample without a command, whatever the 4 of 5 samples no slot takes
    (on c20de4f: 392 of 490, 80 %, a FAIL by construction)."""
    t = _measure(tmp_path, "run", period=SLOW_P, sensor_period=FAST_S).timing
    assert (t["samples_without_command"], t["samples_judged"]) == (0, SLOW_JUDGED)
    assert t["samples_without_command_rate"] == 0.0
    assert (t["late_commands"], t["late_commands_rate"]) == (0, 0.0)
    _constant(t["sample_gap"], SLOW_P / US)


def test_commands_dropped_below_the_plants_rate_are_exactly_the_slots_without(tmp_path):
    """Every 7th command (cmd_seq = slot k = 6, 13, ..., 97) dropped: 14 of the 98 slots."""
    m = _measure(tmp_path, "run", period=SLOW_P, sensor_period=FAST_S, drop_command_every=7)
    t = m.timing
    dropped = len(range(6, SLOW_JUDGED, 7))
    assert (t["samples_without_command"], t["samples_judged"]) == (dropped, SLOW_JUDGED) == (14, 98)
    assert t["samples_without_command_rate"] == 14 / 98
    assert t["sample_gap"]["max_us"] == 2 * SLOW_P / US  # across each dropped command


def test_a_slot_the_plants_stall_left_without_a_command_is_the_benchs(tmp_path):
    """Below the plant's rate: the plant stalls from 396 ms to 406 ms, so none of slot 40's
    samples (396 .. 404 ms, due 405 ms) is in hand at its tick (396's State arrives at
    406.32 ms; 402 .. 404 are never taken) and slot 41 takes 414 ms's: one slot without a
    command, the plant's. A command dropped instead (slot 6's) stays the system's."""
    t = _measure(tmp_path, "run", period=SLOW_P, sensor_period=FAST_S,
                 plant_stall=(396 * MS, 10 * MS)).timing  # fmt: skip
    assert (t["samples_without_command"], t["samples_without_command_plant_late"]) == (1, 1)
    t = _measure(tmp_path, "drop", period=SLOW_P, sensor_period=FAST_S,
                 drop_command_every=7).timing  # fmt: skip
    assert (t["samples_without_command"], t["samples_without_command_plant_late"]) == (14, 0)


def test_a_sensor_slower_than_the_controller_has_every_sample_judged(tmp_path):
    """[realtime] sensor_rate below the control rate (100 Hz samples, 500 Hz ticks): each
    sample is one the controller was meant to answer, and answered once (the ticks between
    samples find no fresh State and send nothing). 100 samples (0 .. 990 ms), judged up to
    990 - 2 x 2 ms: 0 .. 980 ms, 99 of them."""
    t = _measure(tmp_path, "run", period=P, sensor_period=5 * P, n=100).timing
    assert (t["samples_without_command"], t["samples_judged"]) == (0, 99)
    m = _measure(tmp_path, "lossy", period=P, sensor_period=5 * P, n=100, drop_state_every=7)
    assert m.timing["samples_without_command"] == len(range(6, 99, 7)) == 14


def test_a_controller_on_state_answers_every_sample_whatever_its_period(tmp_path):
    """on_state computes on every fresh State: each sample is one it was meant to answer."""
    t = _measure(tmp_path, "run", period=SLOW_P, sensor_period=FAST_S, trigger="on_state").timing
    assert t["samples_judged"] == 490  # samples 0 .. 978 ms, every one
    # The scripted controller still ticks every 10 ms: 4 of 5 samples unanswered, and counted.
    assert t["samples_without_command"] == 490 - 98


# =================================================================================================
# Figures whose definitions change (docs/realtime.md after the slot-based misses, the age from
# t = 0 and the stall totals): these are written to the new definitions.
# =================================================================================================


@calibrates(
    "deadline_misses",
    "slots",
    "deadline_miss_rate",
    injects="no tick from 400 ms to 430 ms",
    found="1 late tick + 14 skipped = 15 missed of 499 slots, exactly",
)
def test_new_a_30ms_controller_stall_is_15_missed_slots(tmp_path):
    """1 late tick + 14 skipped slots = 15 misses, over the 499 slots of the window."""
    t = _measure(tmp_path, "run", controller_stall=(400 * MS, 30 * MS)).timing
    assert t["late_ticks"] == 1 and t["skipped_slots"] == 14
    assert t["deadline_misses"] == 15
    assert t["ticks"] == TICKS - 14 and t["slots"] == TICKS
    assert t["deadline_miss_rate"] == 15 / TICKS


def test_new_a_clean_loop_misses_no_slot(clean):
    t = clean.timing
    assert (t["deadline_misses"], t["late_ticks"], t["skipped_slots"]) == (0, 0, 0)
    assert t["slots"] == t["ticks"] == TICKS and t["deadline_miss_rate"] == 0.0
    assert (t["plant_deadline_misses"], t["plant_slots"]) == (0, 500)


@calibrates(
    "plant_deadline_misses",
    "plant_slots",
    "plant_deadline_miss_rate",
    "plant_skipped_slots",
    injects="no plant sample from 600 ms to 630 ms",
    found="1 late sample + 15 skipped = 16 missed of 500 sensor slots, exactly",
)
def test_new_a_30ms_plant_stall_is_16_missed_sensor_slots(tmp_path):
    """1 late sample + 15 skipped sensor slots, over the 500 slots of the window."""
    t = _measure(tmp_path, "run", plant_stall=(600 * MS, 30 * MS)).timing
    assert t["plant_skipped_slots"] == 15
    assert t["plant_deadline_misses"] == 16
    assert t["plant_slots"] == 500
    assert t["plant_deadline_miss_rate"] == 16 / 500


def test_new_on_state_runs_have_no_periodic_figures(tmp_path):
    t = _measure(tmp_path, "run", trigger="on_state").timing
    for key in ("wakeup_lateness", "deadline_misses", "late_ticks", "skipped_slots", "slots",
                "deadline_miss_rate", "period_jitter", "ticks"):  # fmt: skip
        assert key not in t, key
    assert t["compute"]["count"] > 0 and "plant_deadline_misses" in t


@calibrates(
    "startup_hold_s",
    "command_age_zenoh (applied)",
    injects="the controller's first tick at 40 ms",
    found="startup_hold 40.195 ms, D = 40.195 ms counted from t = 0, every plant step of "
    "the window counted, exactly",
)
def test_new_the_command_age_counts_from_the_first_sample(tmp_path, clean):
    """The controller wakes first at 40 ms (a late start): the plant holds zero torque until
    the first command lands at 40.195 ms, so D = 40.195 ms (age from t = 0), and the age is
    sampled at every plant step of the window, the start-up's too."""
    m = _measure(tmp_path, "run", controller_stall=(0, 40 * MS))
    t, cert = m.timing, m.certificate
    assert t["startup_hold_s"] == 0.040195
    assert t["command_age_zenoh"]["max_us"] == 40_195.0 and cert["d_max_s"] == 0.040195
    assert cert["held"] is False
    steps = (499 * P) // H  # the plant's steps from its first sample to its last
    assert t["command_age_zenoh"]["count"] == steps
    first = cert["stalls"][0]
    assert first["cause"] == "startup" and first["t_s"] == 0.0 and first["age_s"] == 0.040195
    assert first["owner"] == "system"  # no bench evidence: the plant woke on time
    # A clean start: D stays one period past the loop's latency; the start-up's ages (0 to
    # 1.2 ms on the grid) join the count.
    c = clean.timing["command_age_zenoh"]
    assert c["count"] == steps and c["max_us"] == P / US + S2A_ZENOH
    assert c["p50_us"] == 2200.0


def test_new_stalls_have_owners_and_the_system_age_leaves_the_bench_out(tmp_path):
    c = _measure(tmp_path, "c", controller_stall=(400 * MS, 30 * MS)).certificate
    p = _measure(tmp_path, "p", plant_stall=(600 * MS, 30 * MS)).certificate
    assert [(s["cause"], s["owner"]) for s in c["stalls"]] == [("controller_late", "system")]
    assert c["stall_count"] == 1 and c["d_system_s"] == c["d_max_s"] == 0.032195
    # The plant's stall is one excursion (the age never fell below the threshold in it).
    assert [(s["cause"], s["owner"]) for s in p["stalls"]] == [("plant_late", "bench")]
    assert p["stall_count"] == 1 and p["d_max_s"] == 0.03321
    assert p["d_system_s"] == (P / US + S2A_ZENOH) / 1e6  # the loop's own age, outside it
    # Time above the threshold: from the crossing (sample in force + threshold) to the landing
    # that brings the age below it: 430.195 ms for the controller's stall (sample 398 ms); for
    # the plant's, 633.21 ms (sample 598 ms): the stalled sample's command (631.21 ms) is
    # itself 31.21 ms old, the next one's brings the age down.
    thr = c["stall_threshold_s"]
    assert c["stalled_time_s"] == pytest.approx(0.032195 - thr, abs=1e-9)
    assert p["stalled_time_s"] == pytest.approx(0.03521 - thr, abs=1e-9)


def test_new_every_stall_is_counted_beyond_the_20_listed(tmp_path):
    """25 stretches of 10 lost states, 38 samples apart: 25 excursions of 11 P + 1.21 ms."""
    lost = {s for i in range(25) for s in range(20 + 38 * i, 30 + 38 * i)}
    cert = _measure(tmp_path, "run", n=1000, lose_states=lost).certificate
    assert len(cert["stalls"]) == 20 and cert["stall_count"] == 25
    peak = (11 * P / US + S2A_ZENOH) / 1e6
    assert all(s["age_s"] == peak and s["owner"] == "system" for s in cert["stalls"])
    assert cert["stalled_time_s"] == pytest.approx(
        25 * (peak - cert["stall_threshold_s"]), abs=1e-8
    )
    assert cert["d_system_s"] == cert["d_max_s"] == peak


def test_new_a_controller_stopped_between_its_send_stamp_and_the_send_is_controller_late(tmp_path):
    """A SIGSTOP that lands just after a tick stamped its command's send and before the command
    left (seen in a real run): stopped from 401.1 ms to 431.1 ms, the command stamped at
    401.06 ms arrives 150 µs after the resume. Its 30.19 ms "hop" is the sender's stall, as a
    State held up by a stalled receiver is the receiver's: the cause is the controller."""
    stop, resume = 401_100 * US, 431_100 * US
    send = 400 * MS + P // 2 + (TICK_WAKE + TO_COMPUTE + COMPUTE + TO_SEND) * US
    m = _measure(
        tmp_path, "run", controller_stall=(stop, resume - stop),
        late_command=(200, resume + HOP_CMD * US - (send + HOP_CMD * US)),
    )  # fmt: skip
    assert m.timing["hop_cmd_zenoh"]["max_us"] == (resume - send) / US + HOP_CMD
    worst = m.certificate["stalls"][0]
    assert (worst["cause"], worst["owner"]) == ("controller_late", "system"), worst


def test_new_states_held_on_the_wire_and_superseded_before_use_are_transport_late(tmp_path):
    """TCP holds the States sent from 400 ms for 40 ms behind a lost segment, then delivers
    them all at once (seen with 5 % loss on the Zenoh links): the tick after takes the newest,
    whose own hop is short, so only the arrival rows of the superseded States show the hold.
    The stall is the wire's: transport_late, the worst hold its evidence."""
    m = _measure(tmp_path, "run", hold_states=(400 * MS, 40 * MS))
    worst = m.certificate["stalls"][0]
    assert (worst["cause"], worst["owner"]) == ("transport_late", "system"), worst
    # The first State held: sent at 400.12 ms (sample 400 ms + wake 20 µs + send 100 µs),
    # delivered at 440 ms + the 200 µs hop.
    assert worst["evidence"]["transport_worst_s"] == pytest.approx((40_200 - 120) / 1e6)


# =================================================================================================
# docs/realtime.md's calibration table is written from the @calibrates of the tests that exist
# =================================================================================================


def _own_text(source: str) -> str:
    """A test's source without its docstring: the figures it reads, not those it mentions."""
    import ast

    body = ast.parse(source).body[0].body
    if body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant):
        lines = source.splitlines()
        source = "\n".join(lines[: body[0].lineno - 1] + lines[body[0].end_lineno :])
    return source


def _coverage_problems(decls, figures) -> list[str]:
    """What is wrong with the declarations against the document's figures."""
    declared = {f for d in decls for f in d.figures}
    problems = [f"declared but not a figure of the table: {f}" for f in declared - set(figures)]
    for kind in ("synthetic logs", "real processes"):
        for f in figures:
            if not any(f in d.figures and d.kind == kind for d in decls):
                problems.append(f"no {kind} known answer for {f}")
    for d in decls:
        text = _own_text(d.source)
        for f in d.figures:
            name = f.split(" (")[0]
            if not re.search(rf"\b{re.escape(name)}\b", text):
                problems.append(f"{d.module}::{d.test} declares {f} and never reads it")
    return problems


def test_every_figure_has_a_synthetic_and_a_real_known_answer_and_the_doc_lists_them():
    from tools.calibration_table import DOC, declarations, doc_figures, generated, render

    text = DOC.read_text()
    figures = doc_figures(text)
    some = {"wakeup_lateness", "hop_cmd_can", "sample_gap", "late_commands_rate"}
    assert some | {"sample_to_apply_can (applied)", "command_age_can (shadow)"} <= set(figures)
    decls = declarations()
    assert _coverage_problems(decls, figures) == []
    assert generated(text) == render(decls, figures), (
        "docs/realtime.md's calibration table is not the tests': "
        "python -m tools.calibration_table --write"
    )


def test_the_coverage_check_finds_a_missing_a_stray_and_an_unread_figure(tmp_path):
    """The check above can fail: a figure no real test calibrates, a declared name that is no
    figure, and a declaration whose test never reads the figure (a docstring does not count)."""
    from tools.calibration_table import declarations

    synthetic, real = tmp_path / "ka.py", tmp_path / "cal.py"
    synthetic.write_text(
        "@calibrates('hop_state', 'compute', injects='x', found='y')\n"
        "def test_a():\n    t['hop_state'], t['compute']\n"
    )
    real.write_text(
        "@calibrates('hop_state', injects='x', found='y')\n"
        'def test_b():\n    """hop_state, compute: mentioned"""\n    pass\n'
        "@calibrates('hop_sate', injects='x', found='y')\ndef test_c():\n    t['hop_sate']\n"
    )
    decls = declarations({"synthetic logs": (synthetic,), "real processes": (real,)})
    assert [d.test for d in decls] == ["test_a", "test_b", "test_c"]
    assert sorted(_coverage_problems(decls, ["hop_state", "compute"])) == [
        "cal.py::test_b declares hop_state and never reads it",
        "declared but not a figure of the table: hop_sate",
        "no real processes known answer for compute",
    ]
