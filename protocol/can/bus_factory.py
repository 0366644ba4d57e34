"""A python-can Bus from the scenario's ``[can]`` table, for any installed interface.

``interface`` is a python-can interface name: ``zenoh_can`` (the default, see
:mod:`protocol.can.zenoh_bus`), ``socketcan`` (``vcan0`` or a real ``can0``), ``virtual``
(in-process only), ``udp_multicast`` (refused unless this process runs in a private network
namespace, since it sends to a multicast group on the default interface), or any hardware
interface python-can knows (``pcan``, ``kvaser``, ``slcan``, ...).
"""

from __future__ import annotations

import argparse
import math
import os
import socket
from collections.abc import Callable, Mapping
from dataclasses import dataclass, fields
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    import can

ALLOW_UDP_MULTICAST_ENV = "HIL_ALLOW_UDP_MULTICAST"


@dataclass(frozen=True)
class CanSettings:
    """The ``[can]`` table: python-can interface and channel, bitrate (bit/s), node ids, the
    host's drive heartbeat timeout (s; an ODrive heartbeats every 100 ms) and the virtual
    drives' watchdog timeout (s; 0 = off, as the firmware ships)."""

    interface: str = "zenoh_can"
    channel: str = "hil0"
    bitrate: int = 1_000_000
    node_left: int = 0
    node_right: int = 1
    heartbeat_timeout: float = 0.5
    watchdog_timeout: float = 0.0

    def __post_init__(self) -> None:
        if not isinstance(self.interface, str) or not self.interface:
            raise ValueError("[can] interface must be a python-can interface name")
        if not isinstance(self.channel, str) or not self.channel:
            raise ValueError("[can] channel must be a non-empty string")
        if not isinstance(self.bitrate, int) or isinstance(self.bitrate, bool):
            raise ValueError(f"[can] bitrate must be an integer, got {self.bitrate!r}")
        if not 10_000 <= self.bitrate <= 1_000_000:
            raise ValueError(f"[can] bitrate {self.bitrate} outside classical CAN's 10k..1M")
        for name in ("node_left", "node_right"):
            node = getattr(self, name)
            if not isinstance(node, int) or isinstance(node, bool) or not 0 <= node <= 0x3F:
                raise ValueError(f"[can] {name} must be an integer in 0..63, got {node!r}")
        if self.node_left == self.node_right:
            raise ValueError("[can] node_left and node_right must differ")
        hb = self.heartbeat_timeout
        if isinstance(hb, bool) or not isinstance(hb, int | float) or not 0.0 < hb < math.inf:
            raise ValueError(f"[can] heartbeat_timeout must be a number > 0 (s), got {hb!r}")
        wd = self.watchdog_timeout
        if isinstance(wd, bool) or not isinstance(wd, int | float) or not 0.0 <= wd < math.inf:
            raise ValueError(f"[can] watchdog_timeout must be a number >= 0 (s), got {wd!r}")

    @classmethod
    def from_table(cls, table: Mapping[str, Any]) -> CanSettings:
        """From a parsed ``[can]`` table; unknown keys are an error (a typo must not pass)."""
        known = {f.name for f in fields(cls)}
        unknown = set(table) - known
        if unknown:
            raise ValueError(f"[can] unknown keys: {sorted(unknown)}")
        return cls(**dict(table))


def network_interfaces() -> list[str]:
    """The names of this process' network namespace's interfaces (from the kernel, by
    ``if_nameindex``: ``/sys/class/net`` shows the mounting namespace's, and ``unshare -n``
    does not remount it)."""
    return sorted(name for _, name in socket.if_nameindex())


def in_private_netns(interfaces: Callable[[], list[str]] = network_interfaces) -> bool:
    """True when the only network interface is ``lo`` (a fresh ``unshare -n`` namespace)."""
    try:
        return interfaces() == ["lo"]
    except OSError:
        return False


def open_bus(settings: CanSettings, **extra: Any) -> can.BusABC:
    """A python-can Bus for ``settings``; ``extra`` keyword arguments go to the interface.

    Raises ``ValueError`` for a refused configuration and python-can's
    ``CanInitializationError`` when the interface cannot be opened (no vcan0, no hardware).
    """
    kwargs: dict[str, Any] = {"interface": settings.interface, "channel": settings.channel}
    if settings.interface == "udp_multicast":
        if not (in_private_netns() or os.environ.get(ALLOW_UDP_MULTICAST_ENV) == "1"):
            raise ValueError(
                "udp_multicast sends to a multicast group on the default interface: run it "
                "in a private network namespace (unshare -n, with lo up, multicast on and a "
                "route 224.0.0.0/4 dev lo) or set "
                f"{ALLOW_UDP_MULTICAST_ENV}=1; interfaces here: {network_interfaces()}"
            )
    elif settings.interface not in ("socketcan", "virtual"):
        # vcan and the virtual bus have no bitrate; everything else takes one
        kwargs["bitrate"] = settings.bitrate
    kwargs.update(extra)
    import can  # here, not at the top: the scenario loader reads CanSettings without python-can

    return can.Bus(**kwargs)


def add_bus_arguments(parser: argparse.ArgumentParser) -> None:
    """The bus options of the stand-alone CAN tools, with :class:`CanSettings`' defaults."""
    d = CanSettings()
    parser.add_argument("--interface", default=d.interface)
    parser.add_argument("--channel", default=d.channel)
    parser.add_argument("--bitrate", type=int, default=d.bitrate)
    parser.add_argument("--endpoint", default=None, help="zenoh_can well-known endpoint")
    parser.add_argument("--node-left", type=int, default=d.node_left)
    parser.add_argument("--node-right", type=int, default=d.node_right)


def open_bus_from_args(args: argparse.Namespace) -> can.BusABC:
    """The bus that :func:`add_bus_arguments`' options describe."""
    settings = CanSettings(
        args.interface, args.channel, args.bitrate, args.node_left, args.node_right
    )
    use_endpoint = args.endpoint and args.interface == "zenoh_can"
    return open_bus(settings, **({"endpoint": args.endpoint} if use_endpoint else {}))
