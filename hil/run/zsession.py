"""Zenoh sessions of the run: loopback only, multicast scouting off.

Topology: the run's well-known endpoint is listened on by the first session that opens it
(the recorder inside ``hil run``, or a router child when ``[zenoh] mode = "router"``); every
other session connects to it and also listens on an ephemeral loopback port, so gossip lets the
controller and the plant link directly (one hop, no forwarding through the recorder).
"""

from __future__ import annotations

import json
from typing import Any

import zenoh


def session_config(endpoint: str, *, listen_endpoint: bool, mode: str = "peer") -> zenoh.Config:
    conf = zenoh.Config()
    listen = [endpoint] if listen_endpoint else ["tcp/127.0.0.1:0"]
    connect = [] if listen_endpoint else [endpoint]
    if mode == "client":
        listen = []
    items: list[tuple[str, Any]] = [
        ("mode", "router" if mode == "router" else ("client" if mode == "client" else "peer")),
        ("scouting/multicast/enabled", False),
        ("listen/endpoints", listen),
        ("connect/endpoints", connect),
    ]
    if mode != "client":
        items.append(("scouting/gossip/enabled", True))
    for key, value in items:
        conf.insert_json5(key, json.dumps(value))
    return conf


def open_session(endpoint: str, *, listen_endpoint: bool = False, mode: str = "peer") -> Any:
    return zenoh.open(session_config(endpoint, listen_endpoint=listen_endpoint, mode=mode))


def publisher(session: Any, key: str) -> Any:
    # express: these messages are small and latency-bound; batching would only delay them.
    return session.declare_publisher(
        key,
        express=True,
        congestion_control=zenoh.CongestionControl.DROP,
        priority=zenoh.Priority.REAL_TIME,
    )


def payload_bytes(sample: Any) -> bytes:
    return bytes(sample.payload.to_bytes())
