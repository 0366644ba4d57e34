"""Boot the guest under QEMU, run one command in it and return its exit code.

The qemu process is started in its own session and always killed by its PID: on success after
the guest powers off, on timeout, on a harness error and on Ctrl-C.
"""

from __future__ import annotations

import contextlib
import os
import re
import secrets
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from tools.vcan_guest import initramfs
from tools.vcan_guest.image import GuestImage, GuestUnavailableError, find_qemu, prepare

#: Host variables the guest command inherits. Deliberately a short list: the run script is
#: written to a file, and a CI environment may hold tokens that have no business there.
PASSED_ENV = (
    "PATH",
    "HOME",
    "LANG",
    "LC_ALL",
    "TZ",
    "TERM",
    "VIRTUAL_ENV",
    "PYTHONPATH",
    "PYTHONHASHSEED",
    "PYTHONDONTWRITEBYTECODE",
    "CI",
)
PASSED_PREFIXES = ("HIL_", "PYTEST_", "HYPOTHESIS_")
POWEROFF_GRACE_S = 30.0
#: Extra 9p mount options. ``cache=loose`` lets the guest cache the host's files and their
#: metadata: Python's imports (thousands of stat calls) got ~5x faster with it (``import can``
#: 25 s -> 4.4 s under TCG). The price, host edits made during a run stay unseen by that run,
#: does not matter for one throwaway run; ``sync`` before poweroff flushes the guest's writes.
DEFAULT_9P_OPTS = "cache=loose"


class GuestError(RuntimeError):
    """The guest did not run the command to completion (boot failure, timeout, crash)."""

    def __init__(self, message: str, log_path: Path, tail: str) -> None:
        super().__init__(f"{message}\n--- guest console tail ({log_path}) ---\n{tail}")
        self.log_path = log_path


@dataclass
class GuestResult:
    exit_code: int
    boot_s: float  # qemu start to the guest's READY marker (kernel, modules, 9p, vcan0)
    total_s: float  # qemu start to qemu exit
    log_path: Path
    output: str  # console lines the command printed


@dataclass
class _Console:
    nonce: str
    ready_at: float | None = None
    exit_code: int | None = None
    failure: str | None = None
    lines: list[str] = field(default_factory=list)
    tail: list[str] = field(default_factory=list)
    done: threading.Event = field(default_factory=threading.Event)


def qemu_argv(
    qemu: Path, image: GuestImage, initrd: Path, memory_mb: int = 2048, cpus: int = 2
) -> list[str]:
    """The QEMU command line. TCG, not KVM: a KVM guest hung at boot on the build machines."""
    return [
        str(qemu),
        "-accel",
        "tcg",
        "-cpu",
        "max",
        "-m",
        str(memory_mb),
        "-smp",
        str(cpus),
        "-nographic",
        "-no-reboot",
        "-net",
        "none",
        "-kernel",
        str(image.kernel),
        "-initrd",
        str(initrd),
        "-append",
        "console=ttyS0 quiet panic=-1",
        "-fsdev",
        "local,path=/,security_model=passthrough,id=fs0,multidevs=remap",
        "-device",
        "virtio-9p-pci,fsdev=fs0,mount_tag=hostroot",
    ]


def guest_argv(argv: Sequence[str]) -> list[str]:
    """``python``/``python3`` become this interpreter: the same virtual environment, and no
    pyenv shim script to start (every process start costs ~25x under TCG)."""
    if argv and argv[0] in ("python", "python3"):
        return [sys.executable, *argv[1:]]
    return list(argv)


def guest_binds(workdir: str, argv: Sequence[str]) -> list[str]:
    """Host paths under /tmp the guest's run needs: its working directory, this interpreter and
    its virtual environment (wherever they live), every sys.path entry, and the program run."""
    unshareable = ("/proc/", "/sys/", "/dev/")
    for where in (sys.executable, sys.prefix, workdir):
        if str(Path(where).resolve()).startswith(unshareable):
            raise GuestUnavailableError(
                f"{where} lies under /proc, /sys or /dev, which the guest mounts anew: move the "
                "virtual environment or the checkout elsewhere (any other path works)"
            )
    paths = [workdir, sys.executable, sys.prefix, sys.base_prefix, *sys.path]
    if argv and argv[0].startswith("/"):
        paths.append(argv[0])
    return initramfs.tmp_binds(paths)


def guest_env(host: Mapping[str, str], extra: Mapping[str, str]) -> dict[str, str]:
    env = {k: v for k, v in host.items() if k in PASSED_ENV or k.startswith(PASSED_PREFIXES)}
    bindir = str(Path(sys.executable).parent)
    env["PATH"] = bindir + ":" + env.get("PATH", "/usr/local/bin:/usr/bin:/bin")
    # With cache=loose the guest's writes reach the host only at writeback; a guest killed on
    # timeout could leave a renamed but unwritten .pyc behind, which the host would then import.
    env.setdefault("PYTHONDONTWRITEBYTECODE", "1")
    env.update(extra)
    env["HIL_IN_VCAN_GUEST"] = "1"
    return env


def parse_marker(line: str, nonce: str) -> tuple[str, str] | None:
    """('ready'|'exit'|'fail', payload) when ``line`` carries this run's marker."""
    for kind, mark in (
        ("ready", initramfs.MARK_READY),
        ("exit", initramfs.MARK_EXIT),
        ("fail", initramfs.MARK_FAIL),
    ):
        m = re.search(re.escape(f"{mark}:{nonce}") + r"(?::(.*?))?@@", line)
        if m:
            return kind, m.group(1) or ""
    return None


def _read_console(proc: subprocess.Popen[bytes], log: Path, state: _Console, echo: bool) -> None:
    assert proc.stdout is not None
    with log.open("w", encoding="utf-8", errors="replace") as out:
        for raw in proc.stdout:
            line = raw.decode("utf-8", errors="replace").rstrip("\r\n").replace("\r", "")
            out.write(line + "\n")
            out.flush()
            if echo:
                print(line, file=sys.stderr, flush=True)
            state.tail = [*state.tail[-59:], line]
            marker = parse_marker(line, state.nonce)
            if marker is None:
                if state.ready_at is not None and state.exit_code is None:
                    state.lines.append(line)
                continue
            kind, payload = marker
            if kind == "ready":
                state.ready_at = time.monotonic()
            elif kind == "exit":
                state.exit_code = int(payload)
                state.done.set()
            else:
                state.failure = payload
                state.done.set()
    state.done.set()


def _kill(proc: subprocess.Popen[bytes]) -> None:
    if proc.poll() is not None:
        return
    for sig, wait in ((signal.SIGTERM, 3.0), (signal.SIGKILL, 5.0)):
        try:
            os.killpg(proc.pid, sig)
        except ProcessLookupError:
            return
        try:
            proc.wait(timeout=wait)
            return
        except subprocess.TimeoutExpired:
            continue


def run_in_guest(
    argv: Sequence[str],
    cwd: str | None = None,
    env: Mapping[str, str] | None = None,
    timeout: float = 900.0,
    log_path: Path | None = None,
    echo: bool = False,
    image: GuestImage | None = None,
    p9_opts: str | None = None,
    on_start: Callable[[int], None] | None = None,
    nice: int = 0,
) -> GuestResult:
    """Run ``argv`` inside a fresh guest with a real vcan0 and return its exit code.

    Raises GuestUnavailableError when the guest cannot be built and GuestError when it did not run
    the command to completion within ``timeout`` seconds (boot included). ``on_start`` gets
    the qemu PID (tests use it to check that the process is gone afterwards). ``nice`` > 0
    runs every qemu thread at that niceness (``nice -n``, which execs qemu under the same PID):
    a guest run beside other work then takes only the CPU time that work leaves idle.
    """
    image = image or prepare()
    if p9_opts is None:
        p9_opts = os.environ.get("HIL_VCAN_GUEST_9P", DEFAULT_9P_OPTS)
    qemu = find_qemu()
    nonce = secrets.token_hex(8)
    log_path = log_path or Path(tempfile.gettempdir()) / f"hil-vcan-guest-{nonce}.log"
    log_path.parent.mkdir(parents=True, exist_ok=True)
    workdir = str(Path(cwd or os.getcwd()).resolve())
    script = initramfs.run_script(guest_argv(argv), workdir, guest_env(os.environ, env or {}))
    state = _Console(nonce)
    with tempfile.TemporaryDirectory(prefix="hil-vcan-guest-") as tmp:
        initrd = Path(tmp, "initrd.gz")
        run_part = initramfs.build_run_part(script, nonce, p9_opts, guest_binds(workdir, argv))
        initrd.write_bytes(image.initrd_base.read_bytes() + run_part)
        start = time.monotonic()
        argv = qemu_argv(qemu, image, initrd)
        if nice > 0:
            argv = ["nice", "-n", str(nice), *argv]
        proc = subprocess.Popen(
            argv,
            stdin=subprocess.DEVNULL,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )
        reader = threading.Thread(
            target=_read_console, args=(proc, log_path, state, echo), daemon=True
        )
        reader.start()
        try:
            if on_start is not None:
                on_start(proc.pid)
            if not state.done.wait(timeout):
                raise GuestError(
                    f"guest timed out after {timeout:.0f} s", log_path, "\n".join(state.tail)
                )
            # The command's verdict is in; a slow poweroff does not change it.
            with contextlib.suppress(subprocess.TimeoutExpired):
                proc.wait(timeout=POWEROFF_GRACE_S)
        finally:
            _kill(proc)
            reader.join(timeout=5.0)
        total = time.monotonic() - start
    if state.failure is not None:
        raise GuestError(f"guest set-up failed: {state.failure}", log_path, "\n".join(state.tail))
    if state.exit_code is None:
        raise GuestError(
            f"guest stopped (qemu exit {proc.returncode}) without reporting an exit code",
            log_path,
            "\n".join(state.tail),
        )
    boot = (state.ready_at - start) if state.ready_at is not None else float("nan")
    return GuestResult(state.exit_code, boot, total, log_path, "\n".join(state.lines))
