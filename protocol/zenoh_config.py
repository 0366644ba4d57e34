"""Zenoh session configuration and publisher QoS for the bench (zenoh-python 1.x).

Three modes, all confined to the host by default (no packet may leave it unless asked):

- ``peer``: listens on explicit loopback endpoints (default ``tcp/127.0.0.1:0``, an ephemeral
  loopback port, because Zenoh's own default listens on every interface) and connects to the
  given endpoints; multicast scouting off; gossip on but only over the sessions it already
  has, so peers learn each other's (loopback) listeners and form the full mesh Zenoh peers need.
- ``client``: connects to router endpoints, listens nowhere.
- ``router``: listens on loopback endpoints; :func:`router_acl_config` adds user/password
  authentication and access control (default deny, ``put`` and subscriptions on ``hil/**``
  allowed for one user); the bench's per-role router is :mod:`protocol.zenoh_acl`.

``ZenohSettings`` is what a scenario's ``[zenoh]`` table maps to (docs/scenario.md: mode,
endpoints, robot_id; ``listen`` and ``connect`` may be given explicitly).
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import zenoh

from protocol.keys import ALL_ROBOTS, validate_robot_id

MODES = ("peer", "client", "router")
DEFAULT_PEER_LISTEN = ("tcp/127.0.0.1:0",)
DEFAULT_ROUTER_ENDPOINT = "tcp/127.0.0.1:7447"
_LOOPBACK_HOSTS = ("127.0.0.1", "[::1]", "localhost")


class ZenohConfigError(ValueError):
    """A [zenoh] table or settings value that cannot make a session."""


def is_loopback_endpoint(endpoint: str) -> bool:
    """True for ``tcp/``, ``udp/``, ``tls/``, ``quic/`` on 127.0.0.1, [::1] or localhost, and
    for ``unixsock-stream/`` paths (never routable)."""
    proto, sep, rest = endpoint.partition("/")
    if not sep:
        return False
    if proto == "unixsock-stream":
        return bool(rest)
    address = rest.split("#", 1)[0]
    host, colon, port = address.rpartition(":")
    return bool(colon) and host in _LOOPBACK_HOSTS and port.isdigit()


@dataclass(frozen=True)
class ZenohSettings:
    """The ``[zenoh]`` table: ``mode``, ``listen`` and ``connect`` endpoints, ``robot_id``.

    ``allow_non_loopback`` must be set explicitly to use an endpoint off the host (a real
    robot on a LAN); the bench's own runs and tests never set it.
    """

    mode: str = "peer"
    listen: tuple[str, ...] = ()
    connect: tuple[str, ...] = ()
    robot_id: str = "robot1"
    allow_non_loopback: bool = False

    def __post_init__(self) -> None:
        if self.mode not in MODES:
            raise ZenohConfigError(f"zenoh mode {self.mode!r} is not one of {MODES}")
        try:
            validate_robot_id(self.robot_id)
        except ValueError as e:
            raise ZenohConfigError(str(e)) from None
        for ep in (*self.listen, *self.connect):
            if type(ep) is not str or "/" not in ep:
                raise ZenohConfigError(f"zenoh endpoint {ep!r} is not like tcp/127.0.0.1:7447")
            if not self.allow_non_loopback and not is_loopback_endpoint(ep):
                raise ZenohConfigError(
                    f"zenoh endpoint {ep!r} is not on loopback; set allow_non_loopback = true "
                    "to leave the host on purpose"
                )
        if self.mode == "client" and not self.connect:
            raise ZenohConfigError("a zenoh client needs at least one router endpoint")
        if self.mode == "client" and self.listen:
            raise ZenohConfigError("a zenoh client does not listen")

    @classmethod
    def from_table(cls, table: Mapping[str, Any], *, role: str = "connect") -> ZenohSettings:
        """Map a scenario's ``[zenoh]`` table to settings.

        ``endpoints`` is the rendezvous: a router listens on it, a client connects to it, and
        in peer mode the process started first (``role="listen"``, e.g. the orchestrator's
        choice) listens on it while the other (``role="connect"``) connects to it.
        Explicit ``listen`` / ``connect`` lists override ``endpoints``.
        """
        known = {"mode", "endpoints", "listen", "connect", "robot_id", "allow_non_loopback"}
        unknown = set(table) - known
        if unknown:
            raise ZenohConfigError(f"unknown [zenoh] keys: {sorted(unknown)}")
        if role not in ("listen", "connect"):
            raise ZenohConfigError(f"role {role!r} is not 'listen' or 'connect'")
        mode = table.get("mode", "peer")
        endpoints = _endpoint_list(table.get("endpoints", ()), "endpoints")
        listen = _endpoint_list(table.get("listen", ()), "listen")
        connect = _endpoint_list(table.get("connect", ()), "connect")
        if endpoints and not listen and not connect:
            if mode == "router" or (mode == "peer" and role == "listen"):
                listen = endpoints
            else:
                connect = endpoints
        if mode == "router" and not listen:
            listen = (DEFAULT_ROUTER_ENDPOINT,)
        allow = table.get("allow_non_loopback", False)
        if type(allow) is not bool:
            raise ZenohConfigError("[zenoh] allow_non_loopback must be true or false")
        return cls(
            mode=mode,
            listen=listen,
            connect=connect,
            robot_id=table.get("robot_id", "robot1"),
            allow_non_loopback=allow,
        )


def _endpoint_list(value: Any, name: str) -> tuple[str, ...]:
    if isinstance(value, str):
        value = [value]
    if not isinstance(value, Sequence) or not all(isinstance(v, str) for v in value):
        raise ZenohConfigError(f"[zenoh] {name} must be a string or a list of strings")
    return tuple(value)


TX_QUEUE_BATCHES = 16


def config_dict(settings: ZenohSettings) -> dict[str, Any]:
    """The JSON5 keys to insert (exposed so tests and deploy/ can write them to a file)."""
    listen = list(settings.listen)
    if settings.mode == "peer" and not listen:
        listen = list(DEFAULT_PEER_LISTEN)
    if settings.mode == "router" and not listen:
        listen = [DEFAULT_ROUTER_ENDPOINT]
    return {
        "mode": settings.mode,
        # An explicit empty list for a client: otherwise Zenoh's per-mode default applies.
        "listen/endpoints": listen,
        "connect/endpoints": list(settings.connect),
        "scouting/multicast/enabled": False,
        # Gossip travels only over established sessions and announces only our (loopback)
        # listeners; multihop off keeps it to direct neighbours.
        "scouting/gossip/enabled": settings.mode != "client",
        "scouting/gossip/multihop": False,
        "adminspace/enabled": False,
        # Commands (real_time) and states (interactive_high) are DROP: a put never waits more
        # than wait_before_drop for queue space. Zenoh's default queue of 2 batches per
        # priority drops a state whenever the session's TX thread is not scheduled for 2 ms,
        # which a loaded 2-core host does a few times in ten minutes (the soak lost 4-7). 16
        # batches ride out a 16 ms starvation at 1 kHz; longer outages still drop, counted.
        "transport/link/tx/queue/size/real_time": TX_QUEUE_BATCHES,
        "transport/link/tx/queue/size/interactive_high": TX_QUEUE_BATCHES,
        # Zenoh's shared-memory transport copies every put over 3 KB into a 16 MB pool of
        # /dev/shm that it creates on first use: the second such put (a tap batch) stalled
        # its caller, the real-time thread, for 6 ms (33 ms under SCHED_FIFO in a run). The
        # bench's messages are under 4 KB and cross TCP on loopback anyway.
        "transport/shared_memory/enabled": False,
    }


def session_config(settings: ZenohSettings) -> zenoh.Config:
    """A ``zenoh.Config`` for ``settings`` (peer, client or router)."""
    conf = zenoh.Config()
    for key, value in config_dict(settings).items():
        conf.insert_json5(key, json.dumps(value))
    return conf


def router_acl_config(
    listen: Sequence[str],
    *,
    router_user: str,
    router_password: str,
    dictionary_file: str,
    allowed_user: str,
    key_expr: str = ALL_ROBOTS,
    allow_non_loopback: bool = False,
) -> zenoh.Config:
    """A router with user/password authentication and access control (deploy/README.md).

    ``dictionary_file`` holds ``user:password`` lines of everyone allowed to open a session;
    the access control denies everything by default and allows ``allowed_user`` to put on and
    subscribe to ``key_expr`` (default ``hil/**``). Clients use :func:`client_auth_config`.
    """
    settings = ZenohSettings(
        mode="router", listen=tuple(listen), allow_non_loopback=allow_non_loopback
    )
    conf = session_config(settings)
    conf.insert_json5(
        "transport/auth/usrpwd",
        json.dumps(
            {"user": router_user, "password": router_password, "dictionary_file": dictionary_file}
        ),
    )
    conf.insert_json5(
        "access_control",
        json.dumps(
            {
                "enabled": True,
                "default_permission": "deny",
                "rules": [
                    {
                        "id": "hil_put_sub",
                        "permission": "allow",
                        "flows": ["ingress", "egress"],
                        "messages": ["put", "declare_subscriber"],
                        "key_exprs": [key_expr],
                    }
                ],
                "subjects": [{"id": "hil_user", "usernames": [allowed_user]}],
                "policies": [
                    {"id": "hil_policy", "rules": ["hil_put_sub"], "subjects": ["hil_user"]}
                ],
            }
        ),
    )
    return conf


def client_auth_config(settings: ZenohSettings, user: str, password: str) -> zenoh.Config:
    """A session config (usually a client) that authenticates with user and password."""
    conf = session_config(settings)
    conf.insert_json5("transport/auth/usrpwd", json.dumps({"user": user, "password": password}))
    return conf


@dataclass(frozen=True)
class PublisherQos:
    """Publisher options of zenoh 1.x ``Session.declare_publisher`` (docs/protocol.md)."""

    priority: zenoh.Priority
    congestion_control: zenoh.CongestionControl
    express: bool

    def kwargs(self) -> dict[str, Any]:
        return {
            "priority": self.priority,
            "congestion_control": self.congestion_control,
            "express": self.express,
        }


# Commands and state: the newest sample is what matters and a stale command is worse than
# none, so never wait for queue space (DROP) and never wait for a batch (express); commands
# get the highest data priority so status/telemetry traffic never delays them.
COMMAND_QOS = PublisherQos(zenoh.Priority.REAL_TIME, zenoh.CongestionControl.DROP, True)
STATE_QOS = PublisherQos(zenoh.Priority.INTERACTIVE_HIGH, zenoh.CongestionControl.DROP, True)
# Telemetry is for recording: batching is fine, dropping under load is better than slowing
# the loop. Status is rare and must arrive (a tripped watchdog): BLOCK.
TELEMETRY_QOS = PublisherQos(zenoh.Priority.DATA, zenoh.CongestionControl.DROP, False)
STATUS_QOS = PublisherQos(zenoh.Priority.DATA_HIGH, zenoh.CongestionControl.BLOCK, False)
# A tap batch (protocol.tap) is for observers: the lowest priority, so it never delays a
# command or a state on a shared link, and dropped rather than waited for (its receiver counts
# the batch's sequence gap).
TAP_QOS = PublisherQos(zenoh.Priority.DATA_LOW, zenoh.CongestionControl.DROP, False)


def declare_publisher(session: zenoh.Session, key: str, qos: PublisherQos) -> zenoh.Publisher:
    """``session.declare_publisher(key, **qos.kwargs())``."""
    return session.declare_publisher(key, **qos.kwargs())
