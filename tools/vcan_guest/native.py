"""Is there a usable SocketCAN vcan0 on this kernel (natively, or because we are the guest)?"""

from __future__ import annotations

import socket
from pathlib import Path

IFF_UP = 0x1


def native_vcan_status(channel: str = "vcan0") -> tuple[bool, str]:
    """(usable, reason). Usable means the link exists, is up, and a raw CAN socket binds to it."""
    link = Path("/sys/class/net") / channel
    if not hasattr(socket, "AF_CAN"):
        return False, "this Python has no AF_CAN"
    if not link.exists():
        return False, f"no {channel} on this kernel"
    try:
        flags = int((link / "flags").read_text(), 16)
    except (OSError, ValueError):
        flags = 0
    if not flags & IFF_UP:
        return False, f"{channel} exists but is down (run deploy/vcan-setup.sh)"
    try:
        with socket.socket(socket.AF_CAN, socket.SOCK_RAW, socket.CAN_RAW) as s:
            s.bind((channel,))
    except OSError as exc:
        return False, f"cannot bind a raw CAN socket to {channel}: {exc}"
    return True, f"{channel} is up"
