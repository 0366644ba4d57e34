"""``zenoh_can``: a python-can interface carrying classical CAN frames over Zenoh on loopback.

The default bus of the bench: it works across processes on a kernel without CAN, needs no root
and sends nothing off the host. Registered through the ``can.interface`` entry point, so any
python-can tool can use it: ``can.Bus(interface="zenoh_can", channel="hil0", bitrate=500000)``.

Transport. Every bus is a Zenoh peer with multicast scouting off. It listens on the channel's
well-known endpoint (default ``tcp/127.0.0.1:7449``) if that port is free, plus on an ephemeral
loopback port, and connects to the well-known endpoint. The first bus to start owns the
well-known port; later ones connect to it and learn of each other by gossip, so the peers form a
full mesh and the bus outlives its first member. Frames go to the key ``hil/can/<channel>``.
Endpoints other than loopback or unix sockets are refused unless ``allow_remote=True``.

Bitrate model. With ``bitrate`` set, each frame occupies its worst-case bit time
(:func:`protocol.can.bus_load.frame_bits`) on one virtual bus timeline shared by all members.
The timeline is CLOCK_MONOTONIC, common to all processes of one host. Every member keeps
``bus_free`` = the latest end of any frame it has sent or seen. A sender places its frame at
``start = max(now, bus_free)``, ``end = start + bits / bitrate``, and publishes ``end`` with the
frame; receivers deliver it no earlier than ``end`` and stamp it with ``end``. So frames queue
FIFO, and an overloaded bus shows up as growing latency, as on a real bus.
Limits: two senders that send within the Zenoh transit time (about 0.1-0.2 ms here) have not
seen each other's frame, so their frames may overlap on the timeline (no arbitration, no id
priority); a frame's latency is at least the Zenoh transit even when its bit time is shorter;
the sender's own transmit queue is ``tx_queue`` frames deep (``send(timeout)`` waits for room
and raises ``CanOperationError`` when none frees in time). Without ``bitrate`` frames are
delivered on arrival and stamped with their arrival time.
"""

from __future__ import annotations

import atexit
import contextlib
import heapq
import ipaddress
import json
import os
import random
import re
import struct
import threading
import time
import weakref
from collections import deque
from typing import Any

import can
from can import BusABC, CanInitializationError, CanOperationError, Message

from protocol.can.bus_load import frame_bits
from protocol.rejections import RejectionCounter

DEFAULT_ENDPOINT = "tcp/127.0.0.1:7449"
ENDPOINT_ENV = "HIL_ZENOH_CAN_ENDPOINT"
KEY_PREFIX = "hil/can"

# version u8, flags u8, dlc u8, pad, arbitration id u32, sender id u64, end of frame ns u64
_HEADER = struct.Struct("<BBBxIQQ")
_VERSION = 1
_EXTENDED, _REMOTE, _ERROR = 1, 2, 4
_RX_LIMIT = 100_000
_CHANNEL_RE = re.compile(r"^[A-Za-z0-9_.\-]+$")


def _is_loopback_endpoint(endpoint: str) -> bool:
    proto, _, rest = endpoint.partition("/")
    if proto == "unixsock-stream":
        return True
    if proto not in ("tcp", "udp", "tls", "quic"):
        return False
    host = rest.split("#", 1)[0].rsplit(":", 1)[0].strip("[]")
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def pack_frame(msg: Message, sender: int, end_ns: int) -> bytes:
    """The Zenoh payload of one frame (exposed for tests)."""
    flags = (
        (_EXTENDED if msg.is_extended_id else 0)
        | (_REMOTE if msg.is_remote_frame else 0)
        | (_ERROR if msg.is_error_frame else 0)
    )
    data = b"" if msg.is_remote_frame else bytes(msg.data)
    return _HEADER.pack(_VERSION, flags, msg.dlc, msg.arbitration_id, sender, end_ns) + data


def unpack_frame(payload: bytes) -> tuple[Message, int, int]:
    """(message, sender id, end of frame ns) of a payload; ``ValueError`` when malformed."""
    if len(payload) < _HEADER.size or len(payload) > _HEADER.size + 8:
        raise ValueError(f"payload of {len(payload)} bytes")
    version, flags, dlc, arb, sender, end_ns = _HEADER.unpack_from(payload)
    data = payload[_HEADER.size :]
    if version != _VERSION or flags & ~(_EXTENDED | _REMOTE | _ERROR) or dlc > 8:
        raise ValueError("bad header")
    extended, remote = bool(flags & _EXTENDED), bool(flags & _REMOTE)
    if arb > (0x1FFFFFFF if extended else 0x7FF) or (not remote and len(data) != dlc):
        raise ValueError("bad id or length")
    msg = Message(
        arbitration_id=arb,
        is_extended_id=extended,
        is_remote_frame=remote,
        is_error_frame=bool(flags & _ERROR),
        dlc=dlc,
        data=None if remote else data,
        check=False,
    )
    return msg, sender, end_ns


def _shut_down_at_exit(bus: ZenohCanBus) -> None:
    """Shut ``bus`` down when the interpreter ends, before it waits for its threads.

    Zenoh calls a Python callback from a thread of its own that is not a daemon and ends only
    when the subscriber is undeclared: a script that forgets ``shutdown()`` would wait for it
    forever (python-can's own interfaces exit). ``atexit`` runs after that wait, so the hook
    goes where ``concurrent.futures`` puts its own, before it. A weak reference: the hook does
    not keep a bus alive that its user dropped."""
    ref = weakref.ref(bus)

    def hook() -> None:
        alive = ref()
        if alive is not None:
            with contextlib.suppress(Exception):
                alive.shutdown()

    register = getattr(threading, "_register_atexit", None)
    with contextlib.suppress(RuntimeError):  # the interpreter is already shutting down
        (register or atexit.register)(hook)


class ZenohCanBus(BusABC):
    """A CAN bus whose members are processes of one host joined over Zenoh (see module doc).

    Keyword arguments: ``bitrate`` (bit/s; None = no bit-time model), ``endpoint`` (the
    well-known Zenoh endpoint, default ``$HIL_ZENOH_CAN_ENDPOINT`` or ``tcp/127.0.0.1:7449``),
    ``receive_own_messages`` (default False), ``tx_queue`` (default 64 frames),
    ``allow_remote`` (default False).
    """

    def __init__(
        self,
        channel: Any = "hil0",
        can_filters: can.typechecking.CanFilters | None = None,
        bitrate: float | None = None,
        endpoint: str | None = None,
        receive_own_messages: bool = False,
        tx_queue: int = 64,
        allow_remote: bool = False,
        **kwargs: Any,
    ) -> None:
        import zenoh

        channel = str(channel if channel is not None else "hil0")
        if not _CHANNEL_RE.match(channel):
            raise CanInitializationError(f"zenoh_can channel {channel!r}: use [A-Za-z0-9_.-]")
        if bitrate is not None and not float(bitrate) > 0:
            raise CanInitializationError(f"bitrate must be positive, got {bitrate!r}")
        endpoint = endpoint or os.environ.get(ENDPOINT_ENV) or DEFAULT_ENDPOINT
        if not allow_remote and not _is_loopback_endpoint(endpoint):
            raise CanInitializationError(
                f"zenoh_can endpoint {endpoint!r} is not loopback (pass allow_remote=True)"
            )
        self.channel = channel
        self.channel_info = f"zenoh_can {KEY_PREFIX}/{channel} via {endpoint}"
        self.bitrate = float(bitrate) if bitrate is not None else None
        self.endpoint = endpoint
        self.receive_own_messages = bool(receive_own_messages)
        self.tx_queue = max(1, int(tx_queue))
        self.transport_rejections = RejectionCounter()
        self.rx_dropped = 0
        self.last_end_ns = 0  # the end of this member's latest frame on the bus (see sent_at_ns)
        self._sender = random.getrandbits(63) | 1
        self._epoch_offset = time.time() - time.monotonic()
        self._cond = threading.Condition()
        self._rx: list[tuple[int, int, Message]] = []
        self._rx_seq = 0
        self._bus_free_ns = 0
        self._own_ends: deque[int] = deque()
        self._closed = False

        ephemeral = "unixsock-stream" not in endpoint
        listen = [endpoint, "tcp/127.0.0.1:0"] if ephemeral else [endpoint]
        conf = zenoh.Config()
        for key, value in (
            ("mode", "peer"),
            ("scouting/multicast/enabled", False),
            ("scouting/gossip/enabled", True),
            ("listen/endpoints", listen),
            ("listen/exit_on_failure", False),
            ("connect/endpoints", [endpoint]),
            ("connect/exit_on_failure", False),
            ("connect/timeout_ms", 0),
        ):
            conf.insert_json5(key, json.dumps(value))
        try:
            self._session = zenoh.open(conf)
        except Exception as exc:
            raise CanInitializationError(f"zenoh_can: cannot open Zenoh session: {exc}") from exc
        key = f"{KEY_PREFIX}/{channel}"
        # express: a CAN frame is tiny and latency-bound, batching would only delay it;
        # BLOCK: a CAN bus does not silently lose frames, so neither does this one.
        self._pub = self._session.declare_publisher(
            key,
            express=True,
            congestion_control=zenoh.CongestionControl.BLOCK,
            priority=zenoh.Priority.REAL_TIME,
        )
        self._sub = self._session.declare_subscriber(key, self._on_sample)
        super().__init__(channel=channel, can_filters=can_filters, **kwargs)
        _shut_down_at_exit(self)

    # --- receive path -------------------------------------------------------------------
    def _on_sample(self, sample: Any) -> None:
        try:
            msg, sender, end_ns = unpack_frame(bytes(sample.payload.to_bytes()))
        except Exception:
            self.transport_rejections.count("malformed_payload")
            return
        with self._cond:
            self._bus_free_ns = max(self._bus_free_ns, end_ns)
            if sender == self._sender and not self.receive_own_messages:
                return
            if len(self._rx) >= _RX_LIMIT:
                self.rx_dropped += 1  # as a CAN controller's receive FIFO overflows
                return
            msg.channel = self.channel
            msg.is_rx = sender != self._sender
            if self.bitrate is None:
                end_ns = time.monotonic_ns()
            msg.timestamp = end_ns / 1e9 + self._epoch_offset
            self._rx_seq += 1
            heapq.heappush(self._rx, (end_ns, self._rx_seq, msg))
            self._cond.notify_all()

    def _recv_internal(self, timeout: float | None) -> tuple[Message | None, bool]:
        deadline = None if timeout is None else time.monotonic_ns() + int(timeout * 1e9)
        with self._cond:
            while not self._closed:
                now = time.monotonic_ns()
                if self._rx and self._rx[0][0] <= now:
                    return heapq.heappop(self._rx)[2], False
                waits = []
                if self._rx:
                    waits.append(self._rx[0][0] - now)
                if deadline is not None:
                    if now >= deadline:
                        return None, False
                    waits.append(deadline - now)
                self._cond.wait(min(waits) / 1e9 if waits else None)
        return None, False

    # --- transmit path ------------------------------------------------------------------
    def send(self, msg: Message, timeout: float | None = None) -> None:
        if self._closed:
            raise CanOperationError("zenoh_can bus is shut down")
        if msg.is_fd or msg.dlc > 8 or len(msg.data or b"") > 8:
            raise CanOperationError("zenoh_can carries classical CAN frames only (DLC <= 8)")
        give_up = None if timeout is None else time.monotonic_ns() + int(timeout * 1e9)
        while True:
            with self._cond:
                now = time.monotonic_ns()
                while self._own_ends and self._own_ends[0] <= now:
                    self._own_ends.popleft()
                if len(self._own_ends) < self.tx_queue:
                    end_ns = now
                    if self.bitrate is not None:
                        bits = frame_bits(msg.dlc, msg.is_extended_id, msg.is_remote_frame)
                        start = max(now, self._bus_free_ns)
                        end_ns = start + int(bits * 1e9 / self.bitrate)
                        self._bus_free_ns = end_ns
                        self._own_ends.append(end_ns)
                    break
                wait_ns = self._own_ends[0] - now
            if give_up is not None and now + wait_ns > give_up:
                raise CanOperationError("zenoh_can transmit queue full (bus overloaded)")
            time.sleep(wait_ns / 1e9)
        try:
            self._pub.put(pack_frame(msg, self._sender, end_ns))
        except Exception as exc:
            raise CanOperationError(f"zenoh_can: put failed: {exc}") from exc
        self.last_end_ns = end_ns

    def sent_at_ns(self, msg: Message) -> int | None:
        """The modelled end of transmission of a received frame on the sender's clock
        (CLOCK_MONOTONIC ns; the sender's ``last_end_ns`` after its send), which names the frame
        exactly although CAN frames carry no sequence number. None without the bit-time model
        (the timestamp is then the receive time)."""
        if self.bitrate is None or msg.timestamp is None:
            return None
        return round((msg.timestamp - self._epoch_offset) * 1e9)

    def shutdown(self) -> None:
        if self._is_shutdown:
            return
        with self._cond:
            self._closed = True
            self._cond.notify_all()
        for closer in (self._sub.undeclare, self._pub.undeclare, self._session.close):
            # closing twice or after the Zenoh runtime stopped is harmless
            with contextlib.suppress(Exception):
                closer()
        super().shutdown()

    @property
    def bus_free_ns(self) -> int:
        """The end of the latest frame this member knows of (CLOCK_MONOTONIC ns)."""
        with self._cond:
            return self._bus_free_ns
