"""Session settings from a scenario's [zenoh] table, QoS choices, and the access-control router."""

from __future__ import annotations

import contextlib
import json
import queue
import time

import pytest
import zenoh

from protocol import keys
from protocol.zenoh_config import (
    COMMAND_QOS,
    STATE_QOS,
    STATUS_QOS,
    ZenohConfigError,
    ZenohSettings,
    client_auth_config,
    config_dict,
    is_loopback_endpoint,
    router_acl_config,
    session_config,
)
from tests.procs import free_tcp_port


def test_zenoh_settings_from_table() -> None:
    ep = "tcp/127.0.0.1:7460"
    peer_listener = ZenohSettings.from_table({"endpoints": [ep], "robot_id": "r1"}, role="listen")
    assert (peer_listener.mode, peer_listener.listen, peer_listener.connect) == ("peer", (ep,), ())
    peer_connector = ZenohSettings.from_table({"endpoints": ep})
    assert (peer_connector.listen, peer_connector.connect) == ((), (ep,))
    client = ZenohSettings.from_table({"mode": "client", "endpoints": [ep]}, role="listen")
    assert (client.listen, client.connect) == ((), (ep,))
    router = ZenohSettings.from_table({"mode": "router"})
    assert router.listen == ("tcp/127.0.0.1:7447",)
    explicit = ZenohSettings.from_table({"listen": ["unixsock-stream//tmp/z.sock"], "connect": ep})
    assert explicit.listen == ("unixsock-stream//tmp/z.sock",) and explicit.connect == (ep,)


@pytest.mark.parametrize(
    "table",
    [
        {"mode": "mesh"},
        {"robot_id": "a/b"},
        {"endpoints": ["tcp/0.0.0.0:7447"]},
        {"endpoints": ["tcp/192.168.1.2:7447"]},
        {"endpoints": ["tcp/[::]:0"]},
        {"endpoints": [7447]},
        {"mode": "client"},
        {"mode": "client", "listen": ["tcp/127.0.0.1:1"], "connect": ["tcp/127.0.0.1:2"]},
        {"endpoint": "tcp/127.0.0.1:1"},
        {"allow_non_loopback": "yes"},
    ],
)
def test_zenoh_settings_reject_bad_tables(table: dict) -> None:
    with pytest.raises(ZenohConfigError):
        ZenohSettings.from_table(table)


def test_zenoh_non_loopback_needs_explicit_opt_in() -> None:
    s = ZenohSettings.from_table({"endpoints": ["tcp/10.0.0.2:7447"], "allow_non_loopback": True})
    assert s.connect == ("tcp/10.0.0.2:7447",)
    assert is_loopback_endpoint("tcp/[::1]:7447") and is_loopback_endpoint("udp/127.0.0.1:1")
    assert not is_loopback_endpoint("tcp/127.0.0.1") and not is_loopback_endpoint("127.0.0.1:1")


def test_zenoh_config_values_reach_the_zenoh_config() -> None:
    for settings in (
        ZenohSettings(),
        ZenohSettings(mode="client", connect=("tcp/127.0.0.1:7447",)),
        ZenohSettings(mode="router"),
    ):
        conf = session_config(settings)
        for key, value in config_dict(settings).items():
            assert zenoh.Config.get_json(conf, key) == json.dumps(value), key
    # Zenoh's own default peer listener is every interface; ours is an ephemeral loopback port.
    assert config_dict(ZenohSettings())["listen/endpoints"] == ["tcp/127.0.0.1:0"]
    assert config_dict(ZenohSettings())["scouting/multicast/enabled"] is False


def test_zenoh_qos_choices() -> None:
    # A stale command is worse than none: never block, never wait for a batch.
    for qos in (COMMAND_QOS, STATE_QOS):
        assert qos.express is True
        assert qos.congestion_control == zenoh.CongestionControl.DROP
    assert COMMAND_QOS.priority == zenoh.Priority.REAL_TIME
    assert STATUS_QOS.congestion_control == zenoh.CongestionControl.BLOCK
    # DROP with Zenoh's default 2-batch queue lost states whenever the TX thread starved for
    # 2 ms: the command and state priorities get a 16 ms queue in every session we open.
    ep = ("tcp/127.0.0.1:7447",)
    for settings in (ZenohSettings(), ZenohSettings("client", connect=ep), ZenohSettings("router")):
        conf = session_config(settings)
        sizes = json.loads(conf.get_json("transport/link/tx/queue/size"))
        assert sizes["real_time"] >= 16 and sizes["interactive_high"] >= 16
        assert sizes["data"] == 2  # telemetry keeps the default: dropping it is fine


def test_zenoh_router_access_control_allows_one_user(tmp_path) -> None:
    port = free_tcp_port()
    users = tmp_path / "users.txt"
    users.write_text("alice:alice-pw\nbob:bob-pw\n")
    ep = f"tcp/127.0.0.1:{port}"
    router = zenoh.open(
        router_acl_config(
            [ep],
            router_user="router",
            router_password="router-pw",
            dictionary_file=str(users),
            allowed_user="alice",
        )
    )
    sessions = [router]
    try:
        client = ZenohSettings(mode="client", connect=(ep,))
        alice = zenoh.open(client_auth_config(client, "alice", "alice-pw"))
        bob = zenoh.open(client_auth_config(client, "bob", "bob-pw"))
        listener = zenoh.open(client_auth_config(client, "alice", "alice-pw"))
        sessions += [alice, bob, listener]
        with pytest.raises(zenoh.ZError):
            sessions.append(zenoh.open(client_auth_config(client, "eve", "guess")))
        got: queue.Queue[bytes] = queue.Queue()
        key = keys.torque_key("r1")
        listener.declare_subscriber(keys.ALL_ROBOTS, lambda s: got.put(s.payload.to_bytes()))
        # Bob's puts go first and alice's are resent until one arrives: if the rule let bob
        # through, his earlier puts would be in the queue before alice's.
        received = None
        deadline = time.monotonic() + 20.0
        while received is None and time.monotonic() < deadline:
            for _ in range(5):
                bob.put(key, b"bob")
            alice.put(key, b"alice")
            with contextlib.suppress(queue.Empty):
                received = got.get(timeout=0.2)
        assert received == b"alice"
        alice.put(key, b"alice-last")
        rest = []
        while (item := got.get(timeout=10.0)) != b"alice-last":
            rest.append(item)
        assert b"bob" not in rest
    finally:
        for s in reversed(sessions):
            s.close()
