"""The virtual drives' edge on a python-can bus: one thread that takes frames and sends the
cyclic ones.

The drive model (:mod:`plant_emulator.odrive`) is pure; this module moves frames.

- The thread stamps every frame as it arrives. Requests (RTR, or a ``Get_*`` id with no
  payload) are answered at once from the drives' current state. Every ``Set_Input_Torque``
  arrival is logged to the hop log's ``cmd_rx`` table with its index among that node's torque
  frames (the controller's ``can_tx`` log is matched to it in per-node order). Other frames are
  applied at once (``immediate``: ``hil drives``, a run's time before its epoch, the CAN path as
  a shadow) or queued in ``inbox`` for the plant's loop, which lands them at their time (the
  applied CAN path of a run, with its injected delay).
- The same thread sends each due Heartbeat / Get_Encoder_Estimates / ... at its own rate, on
  absolute deadlines, whatever the plant's loop does: it waits on the bus until the next one
  is due, so a due frame waits at most for the frame being taken.
- It reads the kernel's drop count of the bus's receiving socket after every receive
  (protocol.can.rx_queue: what ``SO_RXQ_OVFL`` reports): frames that queue dropped while the
  reader was behind are logged to the hop log's ``socket_drops`` table, a loss of the bench's
  own, never the wire's (hil.measure). At the stop, what is still queued unread is read and
  logged (``unread_at_stop``): it reached the bench, it was not lost.
- Frames this process sent and hears back (``udp_multicast`` loops them back) are recognized
  by content within a second and dropped as ``own_frames``, never counted as rejections.

One lock (:attr:`CanDrives.lock`) guards the drives: hold it to touch them.
"""

from __future__ import annotations

import collections
import contextlib
import struct
import threading
import time
from collections.abc import Callable
from math import nan
from typing import Any

from protocol.can.codec import (
    BROADCAST_NODE,
    REQUESTABLE,
    Cmd,
    Frame,
    frame_id,
    is_request,
    split_id,
)
from protocol.can.drive_link import from_message, to_message
from protocol.can.rx_queue import RxQueueDrops
from protocol.faults import Faults, frame_lost
from protocol.hoplog import (
    NO_SEQ,
    NO_STAMP,
    CmdPath,
    CmdRxRow,
    DriveEvent,
    DriveEventRow,
    EncTxRow,
    RxVerdict,
    SocketDropRow,
)
from runtime.delay_line import DelayLine

ECHO_WINDOW_NS = 1_000_000_000
UNREAD_MAX = 100_000  # frames read back from the receive queue at the stop, at most


class EchoFilter:
    """Recognizes this process' own frames coming back from the bus (by content)."""

    def __init__(self, window_ns: int = ECHO_WINDOW_NS) -> None:
        self.window_ns = window_ns
        self._pending: dict[tuple, collections.deque[int]] = {}
        self._order: collections.deque[tuple[int, int, tuple]] = collections.deque()
        self._seq = 0
        self._lock = threading.Lock()

    @staticmethod
    def _key(frame: Frame) -> tuple:
        return (frame.arbitration_id, bytes(frame.data), frame.is_remote, frame.is_extended)

    def sent(self, frame: Frame, now_ns: int) -> None:
        key = self._key(frame)
        with self._lock:
            self._seq += 1
            self._pending.setdefault(key, collections.deque()).append(self._seq)
            self._order.append((now_ns, self._seq, key))
            self._expire(now_ns)

    def take(self, frame: Frame, now_ns: int) -> bool:
        """True (and forgotten) when ``frame`` is one this process sent within the window."""
        key = self._key(frame)
        with self._lock:
            self._expire(now_ns)
            seqs = self._pending.get(key)
            if not seqs:
                return False
            seqs.popleft()
            if not seqs:
                del self._pending[key]
            return True

    def _expire(self, now_ns: int) -> None:
        order = self._order
        while order and now_ns - order[0][0] > self.window_ns:
            _, seq, key = order.popleft()
            seqs = self._pending.get(key)
            if seqs and seqs[0] == seq:  # not taken yet: it never came back
                seqs.popleft()
                if not seqs:
                    del self._pending[key]


class CanDrives:
    """The drives of ``pair`` on ``bus`` (see the module docstring).

    ``on_frame(recv_ns, frame) -> answers`` applies a frame in ``immediate`` mode (called under
    :attr:`lock`); by default ``pair.receive``. ``refresh(now_ns)`` (under the lock) brings the
    drives' feedback up to date before a request is answered or cyclic frames go out.
    """

    def __init__(
        self,
        bus: Any,
        pair: Any,
        hoplog: Any = None,
        on_frame: Callable[[int, Frame], list[Frame]] | None = None,
        refresh: Callable[[int], None] | None = None,
        immediate: bool = True,
        faults: Faults | None = None,
    ) -> None:
        self.bus = bus
        self.pair = pair
        self.hoplog = hoplog
        self.on_frame = on_frame or (lambda ns, f: self.pair.receive(ns / 1e9, f))
        self.refresh = refresh
        self.immediate = immediate
        # Frames received before this (a run's epoch) are applied at once however
        # ``immediate`` is set: the drives armed while the start is announced act before t = 0.
        self.immediate_until_ns = 0
        self.faults = faults or Faults()
        self.injected_frame_losses = 0
        # [faults] feedback_*: encoder-estimate frames held (or lost) on the way to the device
        held = self.faults.feedback_held
        # (the held item: the frame and when its content was taken, for the hop log's enc_tx)
        self.feedback = (
            DelayLine(lambda item: self.send([item[1]], item[0]), "encoder-delay") if held else None
        )
        self._estimates: dict[int, int] = {}  # per node: encoder-estimate frames due so far
        self.feedback_losses = 0
        self.silenced = 0  # frames not sent: the drives were silent ([faults] drive_silent_*)
        # [faults] feedback_frozen_*: per node the last estimate sent before a burst (its data,
        # when its content was taken), and the estimates sent with it instead of their own
        self._unfrozen: dict[int, tuple[bytes, int]] = {}
        self.frozen_frames = 0
        # The bus's name for a received frame, where it has one (zenoh_can): exact matching.
        self._sent_at = getattr(bus, "sent_at_ns", None)
        self.lock = threading.RLock()
        self._send_lock = threading.Lock()
        self._stop = threading.Event()
        self.echo = EchoFilter()
        self._split = split_id
        self._torque_frames: dict[int, int] = {}  # per node: Set_Input_Torque frames seen
        # The ids of a request (RTR) to one of these drives: answered straight from the id
        # (pair.answer_request), the common question of a device and the one it times.
        nodes = frozenset(getattr(pair, "nodes", ()))
        self._nodes = nodes
        self._requests = {frame_id(n, c): (n, c) for n in nodes for c in REQUESTABLE}
        # (receive ns, frame, index among the node's torque frames or NO_SEQ)
        self.inbox: collections.deque[tuple[int, Any, int]] = collections.deque()
        self.frames_in = 0
        self.frames_out = 0
        self.own_frames = 0
        self.requests = 0
        self.send_errors = 0
        self.recv_errors = 0
        self.error_frames = 0
        self.unread_at_stop = 0  # frames still queued when the reader stopped (close)
        self._rx_drops = RxQueueDrops(bus)
        # Frames the receiving socket dropped (None: a bus without a socket, not countable).
        # Stamped before the read: what it does not count was dropped after that stamp.
        self._last_read_ns = time.monotonic_ns()
        first = self._rx_drops.read()
        self.socket_drops: int | None = None if first is None else 0
        self._drops_base = first or 0
        self._threads = [
            threading.Thread(target=self._edge, name="can-edge", daemon=True),
        ]

    def start(self) -> None:
        for t in self._threads:
            t.start()

    def native_ids(self) -> list[int]:
        """The kernel's id of the edge's thread (once started)."""
        return [t.native_id for t in self._threads if t.native_id is not None]

    # --- the edge's thread ----------------------------------------------------------------
    def _edge(self) -> None:
        """Frames as they come, each cyclic frame when it is due: one thread, so no GIL is
        handed between a reader and a sender at every cyclic frame (bench/bench_drive_echo.py,
        docs/can.md). A due frame waits at most for the frame being taken; a frame queued
        while the edge is behind with its sends, for one round of them."""
        behind = False
        while not self._stop.is_set():
            with self.lock:
                due = self.pair.next_due()
            wait = due - time.monotonic()
            if wait <= 0.0 and not behind:
                self._send_due()
                behind = True  # until a frame is looked for: due again at once, it is behind
                continue
            # Behind (a host too slow for the drives' rates: every send due at once), a frame
            # already queued is taken before the next round, so reading never starves behind
            # sending (the QEMU guest: 269 frames left unread, 245 dropped in a 3 s run).
            behind = False
            wait = max(wait, 0.0)
            try:
                msg = self.bus.recv(timeout=min(wait, 0.05))
            except Exception:
                if self._stop.is_set():
                    return
                self.recv_errors += 1
                self._stop.wait(min(max(wait, 0.001), 0.01))
                continue
            if msg is not None:
                self._take(msg, time.monotonic_ns())
            # after the answer, not before it (a system call on a socket's bus)
            self._count_drops()

    def torque_input_node(self, frame: Frame) -> int | None:
        """The node of one of these drives a frame asks a torque of (Set_Input_Torque, a data
        frame, CANSimple's 11-bit id), else None: another node's frame, or an extended one
        (another protocol's), is no command of these drives (they count it as ignored)."""
        node, cmd = self._split(frame.arbitration_id)
        if cmd != Cmd.SET_INPUT_TORQUE or frame.is_remote or frame.is_extended:
            return None
        return node if node in self.pair.nodes else None

    def _take(self, msg: Any, recv_ns: int, act: bool = True) -> None:
        """One frame read from the bus: logged (a torque frame in ``cmd_rx``), then answered,
        applied or queued for the plant's loop; with ``act`` false only logged (a frame left
        in the receive queue when the plant stopped, :meth:`close`)."""
        if msg.is_error_frame:
            self.error_frames += 1
            return
        if act and self._fast(msg, recv_ns):
            return
        frame = from_message(msg)
        # the drives send no remote frame: a request is never their own coming back
        if not frame.is_remote and self.echo.take(frame, recv_ns):
            self.own_frames += 1
            return
        self.frames_in += 1
        node = self.torque_input_node(frame)
        index = NO_SEQ
        if node is not None:
            # Logged with its index among the node's torque frames, its torque and, where
            # the bus names frames (zenoh_can), that name: hil.measure matches it to the
            # controller's can_tx by the name, else by the order.
            i = self._torque_frames.get(node, 0)
            self._torque_frames[node] = i + 1
            lost = frame_lost(self.faults.can_frame_loss, self.faults.seed, node, i)
            if self.hoplog is not None:
                q = struct.unpack_from("<f", frame.data)[0] if len(frame.data) >= 4 else nan
                named = (self._sent_at(msg) if self._sent_at is not None else None) or NO_STAMP
                row = CmdRxRow(
                    path=CmdPath.CAN,
                    seq=i,
                    state_seq=NO_SEQ,
                    state_sample_ns=NO_STAMP,
                    compute_start_ns=NO_STAMP,
                    send_ns=named,
                    recv_ns=recv_ns,
                    tau1=q,
                    tau2=0.0,
                    node=node,
                    verdict=RxVerdict.LOST_BY_FAULT if lost else RxVerdict.ACCEPTED,
                )
                self.hoplog.append("cmd_rx", row)
            if lost:  # the drive's receiver never sees it ([faults] frame loss)
                self.injected_frame_losses += 1
                return
            index = i
        if not act:
            return
        to = self._split(frame.arbitration_id)[0]
        if is_request(frame) and (to in self.pair.nodes or to == BROADCAST_NODE):
            self._answer(recv_ns, lambda now: self.pair.receive(now, frame))
        elif self.immediate or recv_ns < self.immediate_until_ns:
            with self.lock:
                answers = self.on_frame(recv_ns, frame)
            self.send(answers)
        else:
            self.inbox.append((recv_ns, frame, index))

    def _fast(self, msg: Any, recv_ns: int) -> bool:
        """Take the two frames a busy bus is made of without decoding them (what the general
        path would do with them, sooner): a request (RTR) to one of these drives, answered;
        another node's frame, counted as ignored where it would be applied at once. True when
        taken. Every other frame, own echoes and torque commands among them, takes the
        general path of :meth:`_take`."""
        if msg.is_extended_id or msg.is_fd:
            return False
        arb = msg.arbitration_id
        request = self._requests.get(arb) if msg.is_remote_frame else None
        if request is not None:
            self.frames_in += 1
            self._answer(recv_ns, lambda now: self.pair.answer_request(now, *request))
            return True
        node = arb >> 5
        if node in self._nodes or node == BROADCAST_NODE or not 0 <= arb <= 0x7FF:
            return False
        if not (self.immediate or recv_ns < self.immediate_until_ns):
            return False  # queued as every frame is (the plant's loop lands it)
        self.frames_in += 1
        with self.lock:
            self.pair.ignore_other_node()
        return True

    def _answer(self, recv_ns: int, ask: Callable[[float], list[Frame]]) -> None:
        """Answer a request that arrived at ``recv_ns``: the drives' feedback brought up to
        then, ``ask(now)`` under the lock, the answers sent at once."""
        with self.lock:
            if self.refresh is not None:
                self.refresh(recv_ns)
            answers = ask(recv_ns / 1e9)
        self.requests += 1
        self.send(answers, recv_ns)

    def _count_drops(self) -> None:
        """Log what the socket dropped since the last read (module docstring). The read is
        bracketed by two stamps: the drops it counts happened before the stamp after it
        (``seen_ns``), and after the stamp before the previous read (``since_ns``). A thread
        switch between a stamp and the read (the GIL handed to the plant's loop catching up
        after a stall: milliseconds on a loaded host) must not leave a frame dropped then
        outside its window, to be called lost on the wire."""
        before = time.monotonic_ns()
        n = self._rx_drops.read()
        seen = time.monotonic_ns()
        if n is None or self.socket_drops is None:
            return
        grown = n - self._drops_base - self.socket_drops
        if grown > 0:
            self.socket_drops += grown
            if self.hoplog is not None:
                row = SocketDropRow(since_ns=self._last_read_ns, seen_ns=seen, dropped=grown)
                self.hoplog.append("socket_drops", row)
        self._last_read_ns = before

    # --- cyclic frames -----------------------------------------------------------------------
    def _send_due(self) -> None:
        """The cyclic frames due now, sent (the drives' feedback brought up to now first)."""
        now_ns = time.monotonic_ns()
        with self.lock:
            if self.refresh is not None:
                self.refresh(now_ns)
            frames = self.pair.due_frames(now_ns / 1e9)
            self._drain_events()
        self.send(self._hold_estimates(frames, now_ns), now_ns)

    def _silent(self, now_ns: int) -> bool:
        """Whether the drives are silent now ([faults] drive_silent_every/length, by the
        run's time: from its epoch)."""
        f = self.faults
        if f.drive_silent_every <= 0 or self.immediate_until_ns <= 0:
            return False
        return f.drive_silent((now_ns - self.immediate_until_ns) / 1e9)

    def _estimate(self, f: Frame, content_ns: int, now_ns: int) -> tuple[Frame, int]:
        """An encoder-estimate frame as it goes out, and when its content was taken: in a
        [faults] feedback_frozen_* burst (by the run's time) the node's last estimate before
        it, sent again on time."""
        node = self._split(f.arbitration_id)[0]
        t = self.faults
        run_s = (now_ns - self.immediate_until_ns) / 1e9
        frozen = t.feedback_frozen_every > 0 and self.immediate_until_ns > 0
        if frozen and t.feedback_frozen(run_s) and node in self._unfrozen:
            data, content_ns = self._unfrozen[node]
            self.frozen_frames += 1
            return f._replace(data=data), content_ns
        self._unfrozen[node] = (bytes(f.data), content_ns)
        return f, content_ns

    def _drain_events(self) -> None:
        """The drives' events into the hop log (protocol.hoplog.DriveEventRow)."""
        drain = getattr(self.pair, "drain_log", None)
        if self.hoplog is None or drain is None:
            return
        for node, t, event, detail in drain():
            row = DriveEventRow(node, round(t * 1e9), DriveEvent[event.upper()], detail)
            self.hoplog.append("drive_events", row)

    def _hold_estimates(self, frames: list[Frame], now_ns: int) -> list[Frame]:
        """The frames to send now: the encoder estimates go through the feedback delay line
        (or are lost) when [faults] asks for it."""
        if self.feedback is None:
            return frames
        now: list[Frame] = []
        for f in frames:
            node, cmd = self._split(f.arbitration_id)
            if cmd != Cmd.GET_ENCODER_ESTIMATES or f.is_remote:
                now.append(f)
                continue
            i = self._estimates.get(node, 0)
            self._estimates[node] = i + 1
            if self.faults.feedback_lost(i, 1 + node):
                self.feedback_losses += 1
                continue
            held = round(self.faults.feedback_extra_s(i, 1 + node) * 1e9)
            self.feedback.put(now_ns + held, (now_ns, f))
        return now

    # --- transmit -------------------------------------------------------------------------------
    def send(self, frames: list[Frame], sample_ns: int | None = None) -> None:
        """Put ``frames`` on the bus; ``sample_ns``: when their content was taken (the drives'
        feedback brought up to then). Each encoder-estimate frame sent is logged (enc_tx):
        what a device's response time and its torques' age are measured from."""
        if frames and self._silent(time.monotonic_ns()):
            self.silenced += len(frames)  # [faults] drive_silent_*: the drives send nothing
            return
        for f in frames:
            node, cmd = self._split(f.arbitration_id)
            estimate = cmd == Cmd.GET_ENCODER_ESTIMATES and not f.is_remote
            if estimate:
                now = time.monotonic_ns()
                f, content_ns = self._estimate(f, now if sample_ns is None else sample_ns, now)
            with self._send_lock:
                self.echo.sent(f, time.monotonic_ns())
                try:
                    self.bus.send(to_message(f), timeout=0.05)
                    self.frames_out += 1
                except Exception:
                    self.send_errors += 1
                    continue
            if self.hoplog is not None and estimate:
                self.hoplog.append("enc_tx", EncTxRow(node, content_ns, time.monotonic_ns()))

    # --- counters --------------------------------------------------------------------------------
    def counters(self) -> dict[str, Any]:
        """Every counter of the edge and the drives (the summary's ``can`` object)."""
        with self.lock:
            drives = self.pair.counters()
        return {
            "frames_in": self.frames_in,
            "frames_out": self.frames_out,
            "own_frames": self.own_frames,
            "requests": self.requests,
            "send_errors": self.send_errors,
            "recv_errors": self.recv_errors,
            "error_frames": self.error_frames,
            "socket_drops": self.socket_drops,
            "unread_at_stop": self.unread_at_stop,
            "silenced_frames": self.silenced,
            "feedback_losses": self.feedback_losses,
            "frozen_frames": self.frozen_frames,
            **drives,
        }

    def status_counters(self, prefix: str = "can_") -> dict[str, int]:
        """A flat {name: count >= 0} view for a Status message (names <= 32 characters)."""
        c = self.counters()
        out = {
            f"{prefix}rx": c["frames_in"],
            f"{prefix}tx": c["frames_out"],
            f"{prefix}own": c["own_frames"],
            f"{prefix}requests": c["requests"],
            f"{prefix}send_errors": c["send_errors"],
            f"{prefix}rejections": sum(c["rejections"].values()),
        }
        for name, n in c["ignored"].items():
            out[f"{prefix}ign_{name}"[:32]] = n
        for name, n in c["rejections"].items():
            out[f"{prefix}rej_{name}"[:32]] = n
        for node, d in c["drives"].items():
            out[f"{prefix}n{node}_state"] = d["axis_state"]
            out[f"{prefix}n{node}_error"] = d["axis_error"]
        return out

    def close(self) -> None:
        self._stop.set()
        with self.lock:
            self._drain_events()
        if self.feedback is not None:
            self.feedback.close()
        for t in self._threads:
            if t.is_alive():
                t.join(timeout=1.0)
        self._count_drops()
        self._rx_drops.close()
        # What came in and was never read (a reader behind when the plant stopped: seen in
        # the QEMU guest, 300 ms behind) is logged as received now, not lost on the wire: it
        # reached the bench's own queue (hil.measure counts it arrived after the plant stopped).
        with contextlib.suppress(Exception):
            for _ in range(UNREAD_MAX):
                msg = self.bus.recv(timeout=0)
                if msg is None:
                    break
                self.unread_at_stop += 1
                self._take(msg, time.monotonic_ns(), act=False)
        with contextlib.suppress(Exception):  # a bus already gone is fine on the way out
            self.bus.shutdown()
