"""``python -m tools.vcan_guest {prepare,run,check}``: the vcan guest from the command line.

``run`` exits with the guest command's exit code; 125 means the guest itself could not run it
(missing qemu/busybox/kernel, boot failure, timeout), in the spirit of ``git bisect run``.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

from tools.vcan_guest.image import GuestUnavailableError, find_busybox, find_qemu, prepare
from tools.vcan_guest.native import native_vcan_status
from tools.vcan_guest.runner import GuestError, run_in_guest

HARNESS_FAILED = 125


def _log(msg: str) -> None:
    print(f"[vcan-guest] {msg}", file=sys.stderr, flush=True)


def _env_pairs(pairs: list[str]) -> dict[str, str]:
    env: dict[str, str] = {}
    for pair in pairs:
        key, sep, value = pair.partition("=")
        if not sep or not key:
            raise SystemExit(f"--env wants KEY=VALUE, got {pair!r}")
        env[key] = value
    return env


def _boot_time(image, repeats: int) -> int:
    """Boot ``repeats`` guests that run ``true``; print per-run and median figures as JSON.
    The machine is shared: quote medians, and only next to figures from the same run."""
    boots, totals = [], []
    for _ in range(repeats):
        result = run_in_guest(["true"], timeout=300.0, image=image)
        if result.exit_code != 0:
            _log(f"guest `true` exited {result.exit_code}")
            return 1
        boots.append(round(result.boot_s, 2))
        totals.append(round(result.total_s, 2))
    summary = {
        "bench": "vcan_guest_boot",
        "repeats": repeats,
        "boot_s": boots,
        "total_s": totals,
        "boot_s_median": statistics.median(boots),
        "total_s_median": statistics.median(totals),
    }
    print(json.dumps(summary, indent=2))
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m tools.vcan_guest", description=__doc__)
    parser.add_argument("--cache", type=Path, help="cache directory (default ~/.cache/...)")
    parser.add_argument("--kernel-deb", type=Path, help="use this linux-image .deb, no apt")
    sub = parser.add_subparsers(dest="cmd", required=True)
    sub.add_parser("prepare", help="fetch the kernel and build the initramfs (cached)")
    sub.add_parser("check", help="report native vcan0 and the guest's prerequisites")
    boot = sub.add_parser("boot-time", help="median boot time over repeated empty runs")
    boot.add_argument("--repeats", type=int, default=5)
    boot.add_argument("--quick", action="store_true", help="3 repeats")
    run = sub.add_parser("run", help="boot the guest and run a command: run -- CMD ARGS...")
    run.add_argument("--timeout", type=float, default=900.0, help="seconds, boot included")
    run.add_argument("--log", type=Path, help="guest console log file")
    run.add_argument("--env", action="append", default=[], help="KEY=VALUE for the command")
    run.add_argument("--quiet", action="store_true", help="do not echo the guest console")
    run.add_argument("command", nargs=argparse.REMAINDER)
    args = parser.parse_args(argv)

    if args.cmd == "check":
        ok, reason = native_vcan_status()
        print(f"native vcan0: {'yes' if ok else 'no'} ({reason})")
        for what, probe in (("qemu", find_qemu), ("static busybox", find_busybox)):
            try:
                print(f"{what}: {probe()}")
            except GuestUnavailableError as exc:
                print(f"{what}: MISSING: {exc}")
        return 0

    try:
        start = time.monotonic()
        image = prepare(args.cache, args.kernel_deb, log=_log)
        took = time.monotonic() - start
        _log(f"kernel {image.release}, initrd {image.initrd_base} ({took:.1f} s)")
        if args.cmd == "prepare":
            return 0
        if args.cmd == "boot-time":
            return _boot_time(image, 3 if args.quick else args.repeats)
        command = args.command[1:] if args.command[:1] == ["--"] else args.command
        if not command:
            parser.error("run needs a command: run -- CMD ARGS...")
        result = run_in_guest(
            command,
            env=_env_pairs(args.env),
            timeout=args.timeout,
            log_path=args.log,
            echo=not args.quiet,
            image=image,
        )
    except (GuestUnavailableError, GuestError) as exc:
        _log(f"error: {exc}")
        return HARNESS_FAILED
    except KeyboardInterrupt:
        _log("interrupted; qemu was stopped")
        return 130
    _log(
        f"exit {result.exit_code}; boot {result.boot_s:.1f} s, total {result.total_s:.1f} s; "
        f"console log {result.log_path}"
    )
    return result.exit_code


if __name__ == "__main__":
    sys.exit(main())
