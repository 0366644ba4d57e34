"""A time namespace whose ``CLOCK_MONOTONIC`` and ``CLOCK_BOOTTIME`` run ``OFFSET`` seconds
ahead of the machine's (behind when negative), kept alive by a bind mount on ``FILE``:
``python -m hil.bench.lab.timens FILE OFFSET``.

util-linux's ``unshare --monotonic`` takes whole seconds only; this writes the offset with
nanoseconds to ``/proc/self/timens_offsets`` (time_namespaces(7): writable until the first
process enters the namespace), then binds ``/proc/PID/ns/time_for_children`` to ``FILE``.
``nsenter --time=FILE`` then puts a command in it. Run it as a process of its own: the
unshare changes the namespace its caller's later children get.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os
import subprocess
import sys

CLONE_NEWTIME = 0x00000080
NS = 1_000_000_000


def make(file: str, offset_s: float) -> None:
    libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
    if libc.unshare(CLONE_NEWTIME) != 0:
        err = ctypes.get_errno()
        raise OSError(err, f"unshare(CLONE_NEWTIME): {os.strerror(err)}")
    secs, nsecs = divmod(round(offset_s * NS), NS)  # as the kernel takes them: nsecs in [0, 1e9)
    with open("/proc/self/timens_offsets", "w") as f:
        f.write(f"monotonic {secs} {nsecs}\nboottime {secs} {nsecs}\n")
    source = f"/proc/{os.getpid()}/ns/time_for_children"
    subprocess.run(["mount", "--bind", source, file], check=True, capture_output=True)


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    if len(args) != 2:
        print("usage: python -m hil.bench.lab.timens FILE OFFSET_SECONDS", file=sys.stderr)
        return 2
    try:
        make(args[0], float(args[1]))
    except (OSError, ValueError, subprocess.CalledProcessError) as exc:
        detail = getattr(exc, "stderr", b"") or b""
        print(f"error: {exc} {detail.decode(errors='replace').strip()}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
