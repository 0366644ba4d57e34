"""The default bus (``zenoh_can``) against python-can's BusABC contract, and the bus factory."""

from __future__ import annotations

import itertools
import json
import time

import can
import pytest

from protocol.can.bus_factory import CanSettings, in_private_netns, network_interfaces, open_bus
from protocol.can.bus_load import frame_bits
from protocol.can.zenoh_bus import ZenohCanBus
from tests.procs import free_tcp_port, wait_until


def _pair(bitrate=None, **kw):
    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
    a = can.Bus(interface="zenoh_can", channel="t", endpoint=endpoint, bitrate=bitrate, **kw)
    b = can.Bus(interface="zenoh_can", channel="t", endpoint=endpoint, bitrate=bitrate)
    probe = can.Message(arbitration_id=0x7FF, data=b"probe", is_extended_id=False)

    def linked() -> bool:
        a.send(probe)
        return b.recv(0.05) is not None

    assert wait_until(linked, timeout=10.0), "the two zenoh_can members never met"
    for bus in (a, b):  # drain late probes (and own ones, if a receives them)
        while bus.recv(0.05) is not None:
            pass
    return a, b


@pytest.fixture
def pair():
    a, b = _pair()
    yield a, b
    a.shutdown()
    b.shutdown()


def test_can_zenoh_bus_is_found_through_the_entry_point(pair):
    a, b = pair
    assert isinstance(a, ZenohCanBus) and isinstance(b, ZenohCanBus)
    assert "hil/can/t" in a.channel_info


def test_can_zenoh_bus_carries_every_frame_kind(pair):
    a, b = pair
    sent = [
        can.Message(arbitration_id=0x02E, data=bytes.fromhex("0000c03f"), is_extended_id=False),
        can.Message(arbitration_id=0x1ABCDE, data=b"\x01", is_extended_id=True),
        can.Message(arbitration_id=0x009, is_remote_frame=True, dlc=8, is_extended_id=False),
        can.Message(arbitration_id=0x022, data=b"", is_extended_id=False),
    ]  # fmt: skip
    before = time.time()
    for m in sent:
        a.send(m)
    got = [b.recv(2.0) for _ in sent]
    for s, g in zip(sent, got, strict=True):
        assert g is not None
        assert (g.arbitration_id, g.is_extended_id, g.is_remote_frame, g.dlc) == (
            s.arbitration_id,
            s.is_extended_id,
            s.is_remote_frame,
            s.dlc,
        )
        assert bytes(g.data) == (b"" if s.is_remote_frame else bytes(s.data))
        assert g.is_rx and g.channel == "t"
        assert before - 0.5 < g.timestamp < time.time() + 0.5
    assert a.recv(0.1) is None  # no own messages unless asked


def test_can_zenoh_bus_filters_and_own_messages():
    a, b = _pair(receive_own_messages=True)
    try:
        b.set_filters([{"can_id": 0x02E, "can_mask": 0x7FF, "extended": False}])
        a.send(can.Message(arbitration_id=0x021, data=bytes(8), is_extended_id=False))
        a.send(can.Message(arbitration_id=0x02E, data=bytes(8), is_extended_id=False))
        got = b.recv(2.0)
        assert got is not None and got.arbitration_id == 0x02E
        assert b.recv(0.1) is None
        own = [a.recv(2.0), a.recv(2.0)]
        assert [m.arbitration_id for m in own if m is not None] == [0x021, 0x02E]
        assert not own[-1].is_rx
    finally:
        a.shutdown()
        b.shutdown()


def test_can_zenoh_bus_bitrate_queues_frames_fifo():
    bitrate = 125_000
    a, b = _pair(bitrate=bitrate)
    try:
        n = 40
        for i in range(n):
            a.send(can.Message(arbitration_id=0x02E, data=bytes([i] * 8), is_extended_id=False))
        got = [b.recv(5.0) for _ in range(n)]
        assert all(m is not None for m in got)
        assert [m.data[0] for m in got] == list(range(n))  # FIFO
        slot = frame_bits(8) / bitrate
        gaps = [q.timestamp - p.timestamp for p, q in itertools.pairwise(got)]
        # each frame occupies its bit time on the shared timeline: a burst is spread out
        assert min(gaps) >= slot - 2e-6
        assert got[-1].timestamp - got[0].timestamp >= (n - 1) * slot - 2e-6
        # and nothing was handed out before its end of frame
        now_epoch = time.monotonic() + b._epoch_offset
        assert got[-1].timestamp <= now_epoch + 1e-6
    finally:
        a.shutdown()
        b.shutdown()


def test_can_zenoh_bus_full_transmit_queue_raises_on_timeout():
    bus = ZenohCanBus(
        channel="q", endpoint=f"tcp/127.0.0.1:{free_tcp_port()}", bitrate=10_000, tx_queue=2
    )
    try:
        msg = can.Message(arbitration_id=0x02E, data=bytes(8), is_extended_id=False)
        bus.send(msg, timeout=0)
        bus.send(msg, timeout=0)  # 2 x 13.5 ms of bus time now queued
        with pytest.raises(can.CanOperationError):
            bus.send(msg, timeout=0)
    finally:
        bus.shutdown()
    with pytest.raises(can.CanOperationError):
        bus.send(msg)


def test_can_zenoh_bus_counts_malformed_payloads():
    import zenoh

    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
    bus = ZenohCanBus(channel="m", endpoint=endpoint)
    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
    session = zenoh.open(conf)
    try:
        pub = session.declare_publisher("hil/can/m")

        def counted() -> bool:
            pub.put(b"\x07garbage")
            return bus.transport_rejections.get("malformed_payload") > 0

        assert wait_until(counted, timeout=10.0)
        assert bus.recv(0.05) is None
    finally:
        session.close()
        bus.shutdown()


@pytest.mark.parametrize(
    "kwargs",
    [
        {"endpoint": "tcp/192.0.2.1:7449"},
        {"endpoint": "tcp/0.0.0.0:7449"},
        {"channel": "a/b*"},
        {"bitrate": -1},
    ],
)
def test_can_zenoh_bus_refuses_bad_configuration(kwargs):
    kwargs = {"channel": "x", **kwargs}
    with pytest.raises(can.CanInitializationError):
        ZenohCanBus(**kwargs)


def test_can_zenoh_bus_refuses_fd_frames(pair):
    a, _ = pair
    with pytest.raises(can.CanOperationError):
        a.send(can.Message(arbitration_id=1, data=bytes(12), is_fd=True, is_extended_id=False))


def test_can_bus_factory_settings_are_validated():
    assert CanSettings() == CanSettings("zenoh_can", "hil0", 1_000_000, 0, 1)
    assert CanSettings.from_table({"interface": "socketcan", "channel": "vcan0"}).channel == "vcan0"
    for bad in (
        {"bitrate": 5_000_000},
        {"node_left": 64},
        {"node_left": 1, "node_right": 1},
        {"bitrate": "fast"},
        {"channle": "typo"},
    ):
        with pytest.raises(ValueError):
            CanSettings.from_table(bad)


def test_can_bus_factory_refuses_udp_multicast_outside_a_private_netns(monkeypatch):
    monkeypatch.delenv("HIL_ALLOW_UDP_MULTICAST", raising=False)
    monkeypatch.setattr("protocol.can.bus_factory.in_private_netns", lambda: False)
    with pytest.raises(ValueError, match="namespace"):
        open_bus(CanSettings(interface="udp_multicast", channel="239.74.163.2"))
    assert in_private_netns(lambda: ["lo"])
    assert not in_private_netns(lambda: ["eth0", "lo"])
    # the kernel's view of this namespace, not sysfs (which unshare -n does not remount)
    assert "lo" in network_interfaces()


def test_can_bus_factory_opens_virtual_and_zenoh():
    bus = open_bus(CanSettings(interface="virtual", channel="f"))
    try:
        assert isinstance(bus, can.BusABC)
    finally:
        bus.shutdown()
    bus = open_bus(CanSettings(channel="f"), endpoint=f"tcp/127.0.0.1:{free_tcp_port()}")
    try:
        assert isinstance(bus, ZenohCanBus) and bus.bitrate == 1_000_000
    finally:
        bus.shutdown()


FORGETFUL = """
import sys, time, can
bus = can.Bus(interface="zenoh_can", channel="f", endpoint=sys.argv[1])
bus.send(can.Message(arbitration_id=0x21, data=b"\\x01", is_extended_id=False))
msg = bus.recv(timeout=30)
print("got", hex(msg.arbitration_id) if msg else None, flush=True)
print("end", time.monotonic(), flush=True)  # the script's last statement (one clock per host)
# no bus.shutdown(): the interpreter must exit anyway, as with python-can's own interfaces
"""


def test_can_zenoh_bus_does_not_keep_a_script_alive_that_forgets_shutdown(spawn, tmp_path):
    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
    script = tmp_path / "forgetful.py"
    script.write_text(FORGETFUL)
    ours = can.Bus(interface="zenoh_can", channel="f", endpoint=endpoint)
    try:
        proc = spawn.python([str(script), endpoint], text=True)
        # Answer its frame, so its receive path (the one that used to hold the interpreter)
        # has delivered a frame before it ends.
        first = ours.recv(timeout=30)
        assert first is not None and first.arbitration_id == 0x21
        # It may have joined before or after our answer: send until it has received one.
        answered = wait_until(
            lambda: (
                ours.send(can.Message(arbitration_id=0x22, is_extended_id=False))
                or proc.poll() is not None
            ),
            timeout=30,
            interval=0.05,
        )
        assert answered
        # The old bus never exited (a non-daemon Zenoh callback thread held the interpreter);
        # ours ends with the script's last statement, as python-can's own interfaces do (how
        # long an interpreter's teardown takes on a loaded host is no property of the bus:
        # 10 s bounds a hang).
        out, err = proc.communicate(timeout=10)
        # 0, not an abort: frames still arriving while it ends must not crash it either
        assert proc.returncode == 0, (proc.returncode, err)
        assert "got 0x22" in out and "end " in out, out
    finally:
        ours.shutdown()
