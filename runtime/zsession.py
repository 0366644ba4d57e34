"""Zenoh sessions of the run: loopback only, multicast scouting off.

Topology: the run's well-known endpoint is listened on by the first session that opens it
(the recorder inside ``hil run``, or a router child when ``[zenoh] mode = "router"``); every
other session connects to it and also listens on an ephemeral loopback port, so gossip lets the
controller and the plant link directly (one hop, no forwarding through the recorder).

Credentials (:mod:`runtime.credentials`) are applied here and nowhere else: a client session
authenticates with the process's own (from ``HIL_ZENOH_CREDENTIALS`` or
``HIL_ZENOH_USER``/``HIL_ZENOH_PASSWORD``) unless the caller passes explicit ones, or None for
none. Only a router's client uses them: a peer with credentials is refused with a clear error
(a peer mesh has no router to check them, and Zenoh would refuse every unauthenticated link).
"""

from __future__ import annotations

from typing import Any

import zenoh

from protocol import keys, zenoh_config
from protocol.zenoh_config import DEFAULT_PEER_LISTEN, ZenohSettings
from runtime.credentials import Credentials, CredentialsError, from_environment


class _FromEnvironment:
    def __repr__(self) -> str:
        return "FROM_ENVIRONMENT"


FROM_ENVIRONMENT: Any = _FromEnvironment()


def session_config(
    endpoint: str,
    *,
    listen_endpoint: bool,
    mode: str = "peer",
    credentials: Credentials | None = FROM_ENVIRONMENT,
) -> zenoh.Config:
    """The run's session: :mod:`protocol.zenoh_config` settings (loopback, multicast scouting
    off) with the run's rendezvous ``endpoint``, listened on or connected to; a client
    authenticates with ``credentials`` (by default the process's own, see the docstring)."""
    if mode == "client" or (mode == "router" and not listen_endpoint):
        # With a router, every other session is its client: all traffic crosses the router
        # (its access control applies), and a client reconnects by itself after a restart.
        settings = ZenohSettings(mode="client", connect=(endpoint,))
    elif listen_endpoint:
        settings = ZenohSettings(mode="router" if mode == "router" else "peer", listen=(endpoint,))
    else:
        settings = ZenohSettings(mode="peer", listen=DEFAULT_PEER_LISTEN, connect=(endpoint,))
    if credentials is FROM_ENVIRONMENT:
        credentials = from_environment()
    if credentials is None:
        return zenoh_config.session_config(settings)
    if settings.mode != "client":
        raise CredentialsError(
            f"Zenoh credentials are set ({credentials.source}) but this {settings.mode} "
            'session has no router to present them to: use [zenoh] mode = "router" (the '
            "services become the router's clients) or unset them"
        )
    return zenoh_config.client_auth_config(settings, credentials.user, credentials.password)


def open_session(
    endpoint: str,
    *,
    listen_endpoint: bool = False,
    mode: str = "peer",
    credentials: Credentials | None = FROM_ENVIRONMENT,
) -> Any:
    conf = session_config(
        endpoint, listen_endpoint=listen_endpoint, mode=mode, credentials=credentials
    )
    return zenoh.open(conf)


def check_credentials(endpoint: str, mode: str) -> None:
    """Raise :class:`CredentialsError` now if the process's credentials cannot make its session
    (a service calls it before it writes anything, so a bad file leaves no half-written log)."""
    session_config(endpoint, listen_endpoint=False, mode=mode)


_QOS_BY_SUFFIX = (
    ("/cmd/torque", zenoh_config.COMMAND_QOS),
    ("/state", zenoh_config.STATE_QOS),
    ("/telemetry", zenoh_config.TELEMETRY_QOS),
    ("/status", zenoh_config.STATUS_QOS),
)
_TAP_CHUNK = f"/{keys.TAP}/"


def publisher(session: Any, key: str, qos: zenoh_config.PublisherQos | None = None) -> Any:
    """A publisher with ``qos``, by default the QoS that :mod:`protocol.zenoh_config` gives the
    key's message (an unknown key without ``qos`` is an error: no silent default)."""
    if qos is None and _TAP_CHUNK in key:
        qos = zenoh_config.TAP_QOS
    if qos is None:
        qos = next((q for suffix, q in _QOS_BY_SUFFIX if key.endswith(suffix)), None)
    if qos is None:
        raise ValueError(f"no QoS defined for key {key!r}")
    return zenoh_config.declare_publisher(session, key, qos)


def payload_bytes(sample: Any) -> bytes:
    return bytes(sample.payload.to_bytes())
