"""Obtain the guest's kernel and initramfs: the current Debian kernel package, cached.

The shell of the harness that touches apt and the file system. Everything is cached under one
directory per kernel package version, so only the first run downloads (one package, ~70 MB).
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import re
import shutil
import struct
import subprocess
import tempfile
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

from tools.vcan_guest import initramfs, modules

KERNEL_META_PACKAGE = "linux-image-amd64"
BUSYBOX_CANDIDATES = ("/bin/busybox", "/usr/bin/busybox")


class GuestUnavailableError(RuntimeError):
    """Something the guest needs cannot be obtained; the message says what and how to fix it."""


@dataclass(frozen=True)
class GuestImage:
    kernel: Path
    initrd_base: Path
    release: str
    modules: tuple[str, ...]


def cache_root() -> Path:
    if env := os.environ.get("HIL_VCAN_GUEST_CACHE"):
        return Path(env)
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "hil-vcan-guest"


def parse_depends(text: str) -> str | None:
    """The kernel image package named in ``apt-cache depends linux-image-amd64`` output."""
    for line in text.splitlines():
        m = re.match(r"\s*\|?Depends:\s*(linux-image-\S+)\s*$", line)
        if m and not m.group(1).startswith("<"):
            return m.group(1)
    return None


def parse_version(text: str) -> str | None:
    """``Version:`` of ``apt-cache show --no-all-versions PKG`` output."""
    m = re.search(r"^Version:\s*(\S+)", text, re.MULTILINE)
    return m.group(1) if m else None


def _run(argv: list[str], cwd: Path | None = None) -> subprocess.CompletedProcess[str]:
    return subprocess.run(argv, cwd=cwd, capture_output=True, text=True, check=False)


def is_static_elf(path: Path) -> bool:
    """True when the ELF64 file has no program interpreter (``PT_INTERP``), i.e. is static."""
    with path.open("rb") as f:
        head = f.read(64)
        if head[:4] != b"\x7fELF" or head[4] != 2:
            return False
        (phoff,) = struct.unpack_from("<Q", head, 0x20)
        phentsize, phnum = struct.unpack_from("<HH", head, 0x36)
        f.seek(phoff)
        table = f.read(phentsize * phnum)
    return all(
        struct.unpack_from("<I", table, i * phentsize)[0] != 3  # PT_INTERP
        for i in range(phnum)
    )


def find_busybox() -> Path:
    for candidate in BUSYBOX_CANDIDATES:
        path = Path(candidate)
        if path.is_file() and is_static_elf(path):
            return path
    raise GuestUnavailableError(
        "no static busybox found (the guest's init needs one): install it with "
        "`apt-get install --no-install-recommends busybox-static`"
    )


def find_qemu() -> Path:
    path = shutil.which("qemu-system-x86_64")
    if not path:
        raise GuestUnavailableError(
            "qemu-system-x86_64 is not installed: install it with "
            "`apt-get install --no-install-recommends qemu-system-x86`"
        )
    return Path(path)


def current_kernel_package(log: Callable[[str], None]) -> tuple[str, str]:
    """(package name, version) of Debian's current kernel image, from the apt lists.

    Debian drops superseded ``linux-image-6.1.0-N-amd64`` packages, so N is looked up on each
    run rather than pinned. ``apt-get update`` runs only when the lists do not name a kernel.
    """
    if not shutil.which("apt-cache") or not shutil.which("apt-get"):
        raise GuestUnavailableError(
            "apt is not available to fetch the guest kernel: on a non-Debian host pass "
            "--kernel-deb with a Debian linux-image-*-amd64 .deb file (see docs/vcan.md)"
        )
    for attempt in range(2):
        name = parse_depends(_run(["apt-cache", "depends", KERNEL_META_PACKAGE]).stdout)
        version = None
        if name:
            version = parse_version(_run(["apt-cache", "show", "--no-all-versions", name]).stdout)
        if name and version:
            return name, version
        if attempt == 0:
            log("apt lists name no kernel package: running apt-get update")
            upd = _run(["apt-get", "update", "-q"])
            if upd.returncode != 0:
                raise GuestUnavailableError(
                    f"apt-get update failed (root needed?): {upd.stderr.strip()[-400:]}"
                )
    raise GuestUnavailableError(
        f"apt knows no {KERNEL_META_PACKAGE} package: the guest kernel cannot be fetched"
    )


@contextlib.contextmanager
def _locked(path: Path) -> Iterator[None]:
    """One preparer at a time per cache (parallel test runs share it)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w") as f:
        fcntl.flock(f, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(f, fcntl.LOCK_UN)


def _download(name: str, into: Path) -> Path:
    into.mkdir(parents=True, exist_ok=True)
    # One exact package name: a glob would fetch every kernel version the archive still has.
    res = _run(["apt-get", "download", name], cwd=into)
    debs = sorted(into.glob(f"{name}_*.deb"))
    if res.returncode != 0 or len(debs) != 1:
        raise GuestUnavailableError(
            f"`apt-get download {name}` failed (exit {res.returncode}): {res.stderr.strip()[-400:]}"
        )
    return debs[0]


def _unpack(deb: Path, kdir: Path) -> None:
    """vmlinuz and the needed modules out of the .deb into ``kdir`` (the rest is dropped)."""
    if not shutil.which("dpkg"):
        raise GuestUnavailableError("dpkg is needed to unpack the kernel package (dpkg -x)")
    with tempfile.TemporaryDirectory(dir=kdir) as tmp:
        res = _run(["dpkg", "-x", str(deb), tmp])
        if res.returncode != 0:
            raise GuestUnavailableError(f"dpkg -x {deb.name} failed: {res.stderr.strip()[-400:]}")
        kernels = sorted(Path(tmp, "boot").glob("vmlinuz-*"))
        if len(kernels) != 1:
            raise GuestUnavailableError(f"{deb.name} holds no single boot/vmlinuz-*")
        release = kernels[0].name.removeprefix("vmlinuz-")
        moddir = Path(tmp, "lib", "modules", release)
        try:
            resolved = modules.resolve(moddir)
        except modules.ModuleError as exc:
            raise GuestUnavailableError(f"{deb.name}: {exc}") from exc
        out = kdir / "modules"
        shutil.rmtree(out, ignore_errors=True)
        out.mkdir()
        for name, blob in resolved:
            (out / f"{name}.ko").write_bytes(blob)
        (out / "order").write_text("\n".join(n for n, _ in resolved) + "\n")
        shutil.copyfile(kernels[0], kdir / "vmlinuz")
        (kdir / "release").write_text(release + "\n")


def prepare(
    cache: Path | None = None,
    kernel_deb: Path | None = None,
    log: Callable[[str], None] = lambda _msg: None,
) -> GuestImage:
    """The guest's kernel and base initramfs, downloading and building only what is missing."""
    root = cache or cache_root()
    busybox = find_busybox()
    if kernel_deb is not None:
        if not kernel_deb.is_file():
            raise GuestUnavailableError(f"--kernel-deb {kernel_deb}: no such file")
        key = kernel_deb.name.removesuffix(".deb")
    else:
        name, version = current_kernel_package(log)
        key = f"{name}_{version}"
    kdir = root / key
    with _locked(root / ".lock"):
        if not (kdir / "vmlinuz").exists() or not (kdir / "modules" / "order").exists():
            kdir.mkdir(parents=True, exist_ok=True)
            if kernel_deb is None:
                log(f"downloading {name} {version} into {kdir}")
                deb = _download(name, kdir)
            else:
                deb = kernel_deb
            log(f"unpacking {deb.name}")
            _unpack(deb, kdir)
            _prune_others(root, keep=kdir, log=log)
        order = (kdir / "modules" / "order").read_text().split()
        blobs = [(n, (kdir / "modules" / f"{n}.ko").read_bytes()) for n in order]
        bb = busybox.read_bytes()
        initrd = kdir / f"initrd-{initramfs.base_digest(bb, blobs)}.cpio.gz"
        if not initrd.exists():
            log(f"building {initrd.name}")
            part = initrd.with_suffix(".part")
            part.write_bytes(initramfs.build_base(bb, blobs))
            part.replace(initrd)
            for stale in kdir.glob("initrd-*.cpio.gz"):
                if stale != initrd:
                    stale.unlink()
        return GuestImage(
            kernel=kdir / "vmlinuz",
            initrd_base=initrd,
            release=(kdir / "release").read_text().strip(),
            modules=tuple(order),
        )


def _prune_others(root: Path, keep: Path, log: Callable[[str], None]) -> None:
    """Drop caches of superseded kernels: Debian no longer serves them anyway."""
    for other in root.iterdir():
        if other.is_dir() and other != keep and other.name.startswith("linux-image-"):
            log(f"removing superseded cache {other.name}")
            shutil.rmtree(other, ignore_errors=True)
