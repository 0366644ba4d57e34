"""A run's two hop logs written from a script: a loop whose every stamp is known, with stalls,
losses and re-arms injected where a test wants them (known answers for hil.analysis.measure)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from protocol.hoplog import (
    CONTROLLER_TABLES,
    NO_NODE,
    NO_SEQ,
    PLANT_TABLES,
    SAMPLE_DROPPED,
    TICK_DROPPED,
    TICK_NO_SEND,
    ApplyOutcome,
    CmdPath,
    HopLogWriter,
    RxVerdict,
)

# Rows are written as positional tuples, as the services wrote them before the row types of
# protocol.hoplog (the same bytes on disk): hil.analysis.measure must keep reading such logs.
ZENOH, CAN, ACCEPTED = CmdPath.ZENOH, CmdPath.CAN, RxVerdict.ACCEPTED

MS = 1_000_000
US = 1_000


@dataclass
class Loop:
    """A periodic loop: plant samples at epoch + k P, the state arrives ``hop_state`` later,
    the controller ticks at + P/2 (periodic), computes ``compute``, its command arrives
    ``hop_cmd`` after the send and lands at once (plus ``delay``)."""

    period: int = 2 * MS
    n: int = 500
    epoch: int = 10_000 * MS
    hop_state: int = 200 * US
    compute: int = 30 * US
    hop_cmd: int = 150 * US
    delay: int = 0
    plant_step: int = 200 * US
    cmd_path: str = "zenoh"
    # Injections
    controller_stall: tuple[int, int] | None = None  # (from ns after epoch, length ns)
    plant_stall: tuple[int, int] | None = None
    drop_state_every: int = 0
    drop_command_every: int = 0
    lose_states: set[int] = field(default_factory=set)  # lost on the wire (not injected)
    duplicate_commands: set[int] = field(default_factory=set)
    rearm_at: int | None = None  # sample index after which the CAN lifecycle re-sends zeros
    lose_can_frames: set[int] = field(default_factory=set)  # commands whose frames are lost
    named_frames: bool = True  # the bus names each frame (zenoh_can) or not (socketcan)
    refuse_can_frames: set[int] = field(default_factory=set)  # commands the drives refuse
    slow_can_from: tuple[int, int] | None = None  # (cmd_seq, extra ns): its frames and later
    forget_can_frames: set[int] = field(default_factory=set)  # received, never applied (a bug)
    # (cmd_seq, extra ns): its frames and later ones are put on the bus that much after compute
    late_can_send_from: tuple[int, int] | None = None
    # Every command sends the same torque to a wheel (a saturated law): identical payloads
    constant_can_values: bool = False
    # Commands whose frames arrive twice, and single wheels' frames lost: (cmd_seq, node)
    duplicate_can_frames: set[int] = field(default_factory=set)
    lose_can_wheel_frames: set[tuple[int, int]] = field(default_factory=set)
    watchdog_zero_cmds: set[int] = field(default_factory=set)  # the watchdog's zero torques
    trigger: str = "periodic"  # what the controller's log says it ran (on_state: no deadlines)
    can_reader_stops_after: int | None = None  # ns after the last sample: later frames unread
    can_hop: int = 250 * US  # every CAN frame's send to receive
    # Known-answer knobs (tests/test_known_answers.py); the defaults keep the loop above.
    tick_late: tuple[int, ...] = ()  # extra lateness of tick k: tick_late[k % len], ns
    sample_late: tuple[int, ...] = ()  # extra wake-up lateness of plant sample k, ns
    plant_send: int = 100 * US  # plant: sample's wake-up -> its State sent
    # (cmd_seq, extra ns): that Zenoh command arrives so much later (its sender stopped
    # between stamping the send and sending it)
    late_command: tuple[int, int] | None = None
    # (from ns after epoch, length ns): States sent in it are held on the wire and all arrive
    # at its end, in order (TCP's head-of-line blocking behind a retransmission)
    hold_states: tuple[int, int] | None = None
    # The same for the Zenoh commands sent in it (from ns after epoch, length ns)
    hold_commands: tuple[int, int] | None = None
    # ns after the last sample: the receivers stop (the run ends); what arrives later is never
    # logged (None: every message arrives, however late)
    receivers_stop: int | None = None
    # The plant's sample period (0: the control period); a shorter one gives a controller
    # below the plant's sample rate, answering one sample per control period.
    sensor_period: int = 0
    # (since, seen, n) ns after the epoch: the drives' receiving socket dropped n frames
    # between two reads (the plant's socket_drops table); the frames themselves are lost with
    # lose_can_frames
    socket_drops: tuple[tuple[int, int, int], ...] = ()
    # (from ns after epoch, length ns): CAN frames sent in it wait in the drives' socket (the
    # plant stopped) and are read at its end, 50 us apart, in order per node
    hold_can_frames: tuple[int, int] | None = None


def _cyclic(pattern: tuple[int, ...], k: int) -> int:
    """The k-th value of a repeating pattern (0 for none)."""
    return pattern[k % len(pattern)] if pattern else 0


def write(folder: Path, loop: Loop) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    P, E = loop.period, loop.epoch
    S = loop.sensor_period or P
    c = HopLogWriter(
        folder / "controller.hoplog",
        "controller",
        CONTROLLER_TABLES,
        {"period_ns": P, "trigger": loop.trigger, "lockstep": False, "cmd_path": loop.cmd_path,
         "epoch_ns": E},
    )  # fmt: skip
    p = HopLogWriter(
        folder / "plant.hoplog",
        "plant",
        PLANT_TABLES,
        {"sensor_period_ns": S, "control_period_ns": P, "plant_step_ns": loop.plant_step,
         "lockstep": False, "cmd_path": loop.cmd_path, "command_timeout_s": 0.05,
         "delay_s": loop.delay / 1e9, "jitter_s": 0.0, "epoch_ns": E},
    )  # fmt: skip
    # --- the plant's samples (a stall delays its wake-ups and skips slots) ---
    samples: list[tuple[int, int, int]] = []  # (seq, sample_ns, wake_ns)
    seq = 0
    k = 0
    while k < loop.n:
        d = E + k * S
        wake = d + 20 * US + _cyclic(loop.sample_late, k)
        if loop.plant_stall and d >= E + loop.plant_stall[0] and d < E + sum(loop.plant_stall):
            wake = E + sum(loop.plant_stall) + 20 * US
            samples.append((seq, d, wake))
            seq += 1
            k += max(1, (wake - d) // S + 1)
            continue
        samples.append((seq, d, wake))
        seq += 1
        k += 1
    state_arrival: dict[int, int] = {}
    state_sent: dict[int, int] = {}
    for s, d, wake in samples:
        dropped = loop.drop_state_every and s % loop.drop_state_every == loop.drop_state_every - 1
        send = wake + loop.plant_send
        p.append("samples", (s, d, wake, send, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0,
                             SAMPLE_DROPPED if dropped else 0))  # fmt: skip
        if not dropped and s not in loop.lose_states:
            state_sent[s] = send
            state_arrival[s] = send + loop.hop_state
            if loop.hold_states and 0 <= send - E - loop.hold_states[0] < loop.hold_states[1]:
                state_arrival[s] = E + sum(loop.hold_states) + loop.hop_state
    if loop.receivers_stop is not None:
        stop = E + (loop.n - 1) * S + loop.receivers_stop
        state_arrival = {q: a for q, a in state_arrival.items() if a <= stop}
    # --- the controller: ticks at + P/2, the newest state in hand ---
    arrivals = sorted((t, s) for s, t in state_arrival.items())
    for t, s in arrivals:
        d = next(d for q, d, _ in samples if q == s)
        c.append("state_rx", (s, d, state_sent[s], t, ACCEPTED))
    cmd_seq = 0
    used = -1
    k = 0
    last_sample = samples[-1][1]
    tx_index: dict[int, int] = {0: 0, 1: 0}
    can_tx_rows: list[tuple[int, int, int, float]] = []
    # Two lifecycle zeros per node before the run (arming).
    for node in (0, 1):
        can_tx_rows.append((node, E - 50 * MS, NO_SEQ, 0.0))
    while True:
        deadline = E + P // 2 + k * P
        if deadline > last_sample + 5 * P:
            break
        wake = deadline + 15 * US + _cyclic(loop.tick_late, k)
        skipped = 0
        if loop.controller_stall:
            s0 = E + loop.controller_stall[0]
            if s0 <= deadline < s0 + loop.controller_stall[1]:
                wake = s0 + loop.controller_stall[1]
                skipped = int((wake - deadline) // P)
        newest = [(t, s) for t, s in arrivals if t <= wake and s > used]
        if not newest:
            c.append("ticks", (k, deadline, wake, skipped, NO_SEQ, 0, 0, 0, 0, 0, 0, 0, NO_SEQ, 0.0,
                               0.0, TICK_NO_SEND))  # fmt: skip
        else:
            t_rx, s = max(newest, key=lambda x: x[1])
            used = s
            d = next(d for q, d, _ in samples if q == s)
            c0 = wake + 5 * US
            c1 = c0 + loop.compute
            send = c1 + 10 * US
            m = loop.drop_command_every
            dropped = bool(m and cmd_seq % m == m - 1)
            flags = TICK_DROPPED if dropped else 0
            if cmd_seq in loop.watchdog_zero_cmds:  # a zero torque computed from no sample
                s_used, d_used, flags = NO_SEQ, 0, flags | 1
            else:
                s_used, d_used = s, d
            c.append("ticks", (k, deadline, wake, skipped, s_used, d_used, state_sent[s],
                               t_rx, c0, c1, send, send + 5 * US, cmd_seq, 0.1, 0.2,
                               flags))  # fmt: skip
            if not dropped:  # Zenoh always carries the command (applied or as the shadow)
                recv = send + loop.hop_cmd
                if loop.late_command and cmd_seq == loop.late_command[0]:
                    recv += loop.late_command[1]
                held = loop.hold_commands
                if held and 0 <= send - E - held[0] < held[1]:
                    recv = E + sum(held) + loop.hop_cmd
                copies = 2 if cmd_seq in loop.duplicate_commands else 1
                if loop.receivers_stop is not None and recv > last_sample + loop.receivers_stop:
                    copies = 0  # arrives after the plant stopped: never logged
                for _ in range(copies):
                    p.append("cmd_rx", (ZENOH, cmd_seq, s, d, c0, send, recv, 0.1, 0.2, NO_NODE,
                                        ACCEPTED))  # fmt: skip
                if loop.cmd_path == "zenoh" and recv + loop.delay <= last_sample:
                    p.append("apply", (ZENOH, cmd_seq, NO_NODE, recv, recv + loop.delay, 0.1, 0.2,
                                       ApplyOutcome.LANDED))  # fmt: skip
            for node in (0, 1):
                # The torques a command sends alternate like a sign law's (exact in float32).
                value = (0.25 if (cmd_seq + node) % 2 else -0.5) * (1 + node)
                if loop.constant_can_values:
                    value = 0.75 * (1 + node)
                put = send + 5 * US
                if loop.late_can_send_from and cmd_seq >= loop.late_can_send_from[0]:
                    put += loop.late_can_send_from[1]
                can_tx_rows.append((node, put, cmd_seq, value))
            if loop.rearm_at is not None and s == loop.rearm_at:
                for node in (0, 1):
                    can_tx_rows.append((node, send + 50 * US, NO_SEQ, 0.0))
            cmd_seq += 1
        k += 1 + skipped
    # --- CAN: every frame sent arrives 250 µs later, in order per node ---
    drained = {0: 0, 1: 0}  # frames of each node read so far after hold_can_frames
    for node, send, cseq, value in can_tx_rows:
        end = send + 120 * US  # zenoh_can's name for the frame: its modelled end on the bus
        c.append("can_tx", (node, send, cseq, value, end))
        if cseq in loop.lose_can_frames or (cseq, node) in loop.lose_can_wheel_frames:
            continue  # lost on the wire: the receiver never sees it
        if send + 250 * US > last_sample + P:
            # Put on the bus after the plant closed its receiver (a period after its last
            # sample). A frame already on the bus but read late (slow_can_from) is received.
            continue
        i = tx_index[node]
        recv = send + loop.can_hop
        held_can = loop.hold_can_frames
        if held_can and 0 <= send - E - held_can[0] < held_can[1]:
            recv = E + sum(held_can) + 50 * US * drained[node]
            drained[node] += 1
        if loop.slow_can_from and cseq >= loop.slow_can_from[0]:
            recv += loop.slow_can_from[1]
        if (
            loop.can_reader_stops_after is not None
            and recv > last_sample + loop.can_reader_stops_after
        ):
            continue  # still on the bus when the plant stopped reading
        tx_index[node] = i + 1
        p.append("cmd_rx", (CAN, i, NO_SEQ, 0, 0, end if loop.named_frames else 0, recv, value,
                             0.0, node, ACCEPTED))  # fmt: skip
        if cseq in loop.duplicate_can_frames:  # the same frame once more, 10 µs later
            i = tx_index[node]
            tx_index[node] = i + 1
            p.append("cmd_rx", (CAN, i, NO_SEQ, 0, 0, end if loop.named_frames else 0,
                                 recv + 10 * US, value, 0.0, node, ACCEPTED))  # fmt: skip
        forgotten = cseq in loop.forget_can_frames
        if loop.cmd_path == "can" and E <= recv <= last_sample and not forgotten:
            refused = cseq in loop.refuse_can_frames  # the drive refuses it: no landing
            outcome = ApplyOutcome.REFUSED if refused else ApplyOutcome.LANDED
            p.append("apply", (CAN, i, node, recv, recv + loop.delay, 0.0, 0.0, outcome))
    for since, seen, n in loop.socket_drops:
        p.append("socket_drops", (E + since, E + seen, n))
    c.close({"deadline_misses": 0})
    p.close({"extremes": {}})
