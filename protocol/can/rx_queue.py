"""How many frames a receiving socket dropped because its queue was full: the kernel's count.

A SocketCAN (or UDP) socket whose reader falls behind drops what arrives while its receive
queue is full, and counts it (``sk_drops``). SocketCAN hands that count out per received frame
as ancillary data when asked (``SO_RXQ_OVFL``), but python-can's receive takes exactly one
ancillary item (its time stamp) and would fail on a second; the same counter is read here with
``getsockopt(SOL_SOCKET, SO_MEMINFO)`` (its ``SK_MEMINFO_DROPS`` entry) on a duplicate of the
bus's socket, at any moment, without touching how python-can receives. A bus without a socket
(``zenoh_can``: frames carried by Zenoh, ``virtual``) has no such count: :class:`RxQueueDrops`
then reads None, never 0.
"""

from __future__ import annotations

import contextlib
import os
import socket
import struct
from typing import Any

SO_MEMINFO = getattr(socket, "SO_MEMINFO", 55)  # Linux; Python names it from 3.12 on
SK_MEMINFO_DROPS = 8  # its index in struct sk_meminfo (linux/sock_diag.h)
_SK_MEMINFO_VARS = 9


def socket_drops(sock: socket.socket) -> int | None:
    """The frames (datagrams) ``sock`` has dropped since it was opened; None where the kernel
    does not say."""
    try:
        raw = sock.getsockopt(socket.SOL_SOCKET, SO_MEMINFO, 4 * _SK_MEMINFO_VARS)
    except OSError:
        return None
    if len(raw) < 4 * (SK_MEMINFO_DROPS + 1):
        return None
    return int(struct.unpack_from("I", raw, 4 * SK_MEMINFO_DROPS)[0])


class RxQueueDrops:
    """The drop count of a python-can bus's receiving socket, read on demand (module
    docstring). ``read()`` is None for a bus without a socket."""

    def __init__(self, bus: Any) -> None:
        self._sock: socket.socket | None = None
        try:
            fd = int(bus.fileno())
        except (AttributeError, NotImplementedError, OSError, TypeError, ValueError):
            return
        if fd < 0:
            return
        with contextlib.suppress(OSError):
            dup = os.dup(fd)
            try:
                self._sock = socket.socket(fileno=dup)
            except OSError:
                os.close(dup)
                return
        if self._sock is not None and socket_drops(self._sock) is None:
            self.close()

    @property
    def available(self) -> bool:
        return self._sock is not None

    def read(self) -> int | None:
        return socket_drops(self._sock) if self._sock is not None else None

    def close(self) -> None:
        if self._sock is not None:
            self._sock.close()
            self._sock = None
