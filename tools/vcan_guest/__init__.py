"""A throwaway QEMU guest with a real SocketCAN vcan0, for kernels that have no CAN.

``prepare()`` fetches the current Debian kernel package once and builds an initramfs;
``run_in_guest(argv)`` boots it with the host's root file system shared over 9p, creates vcan0
and runs ``argv`` in the project directory with the host's Python. See docs/vcan.md.
"""

from tools.vcan_guest.image import GuestImage, GuestUnavailableError, prepare
from tools.vcan_guest.native import native_vcan_status
from tools.vcan_guest.runner import GuestError, GuestResult, run_in_guest

__all__ = [
    "GuestError",
    "GuestImage",
    "GuestResult",
    "GuestUnavailableError",
    "native_vcan_status",
    "prepare",
    "run_in_guest",
]
