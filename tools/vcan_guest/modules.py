"""Kernel module lookup for the guest: name -> file, dependency closure, load order.

Debian's kernel package ships no ``modules.dep`` (``depmod`` writes it when the package is
installed, and ``kmod`` may be missing), so when it is absent the dependencies are read from each
module's own ``.modinfo`` ELF section, which is what ``depmod`` reads too.
"""

from __future__ import annotations

import lzma
import struct
from collections.abc import Iterable, Mapping
from pathlib import Path

#: The modules the guest needs, in the order that worked (docs/vcan.md): virtio PCI and
#: 9p to reach the host's root file system, then CAN, raw CAN sockets and vcan itself.
GUEST_MODULES: tuple[str, ...] = (
    "virtio_ring",
    "virtio",
    "virtio_pci_modern_dev",
    "virtio_pci_legacy_dev",
    "virtio_pci",
    "netfs",
    "fscache",
    "9pnet",
    "9pnet_virtio",
    "9p",
    "can",
    "can-raw",
    "can-dev",
    "vcan",
)

_SUFFIXES = (".ko.xz", ".ko.zst", ".ko.gz", ".ko")


class ModuleError(RuntimeError):
    """A module is missing from the kernel package or cannot be read."""


def canonical(name: str) -> str:
    """Module names treat '-' and '_' alike (``can-raw`` is loaded as ``can_raw``)."""
    return name.replace("-", "_")


def module_name(path: str) -> str:
    base = path.rsplit("/", 1)[-1]
    for suffix in _SUFFIXES:
        if base.endswith(suffix):
            return canonical(base[: -len(suffix)])
    raise ModuleError(f"not a kernel module file: {path}")


def decompress(path: Path) -> bytes:
    """The plain ELF bytes of a module file; ``.ko.xz`` is unpacked with lzma."""
    raw = path.read_bytes()
    if path.name.endswith(".ko.xz"):
        return lzma.decompress(raw)
    if path.name.endswith(".ko.gz"):
        import gzip

        return gzip.decompress(raw)
    if path.name.endswith(".ko.zst"):
        raise ModuleError(f"{path.name}: zstd-compressed modules are not supported")
    return raw


def modinfo_depends(elf: bytes) -> list[str]:
    """The ``depends=`` list from an ELF64 little-endian module's ``.modinfo`` section."""
    if elf[:4] != b"\x7fELF" or elf[4] != 2 or elf[5] != 1:
        raise ModuleError("not an ELF64 little-endian module")
    (shoff,) = struct.unpack_from("<Q", elf, 0x28)
    shentsize, shnum, shstrndx = struct.unpack_from("<HHH", elf, 0x3A)

    def section(i: int) -> tuple[int, int, int]:
        base = shoff + i * shentsize
        (name_off,) = struct.unpack_from("<I", elf, base)
        offset, size = struct.unpack_from("<QQ", elf, base + 0x18)
        return name_off, offset, size

    _, str_off, _ = section(shstrndx)
    for i in range(shnum):
        name_off, offset, size = section(i)
        end = elf.index(b"\0", str_off + name_off)
        if elf[str_off + name_off : end] == b".modinfo":
            for item in elf[offset : offset + size].split(b"\0"):
                if item.startswith(b"depends="):
                    value = item[len(b"depends=") :].decode()
                    return [canonical(d) for d in value.split(",") if d]
            return []
    raise ModuleError("module has no .modinfo section")


def parse_modules_dep(text: str) -> dict[str, tuple[str, list[str]]]:
    """``modules.dep`` lines ``path: dep_path ...`` -> {name: (path, [dependency names])}."""
    table: dict[str, tuple[str, list[str]]] = {}
    for line in text.splitlines():
        if ":" not in line:
            continue
        path, deps = line.split(":", 1)
        table[module_name(path)] = (path.strip(), [module_name(d) for d in deps.split()])
    return table


def scan_tree(moddir: Path) -> dict[str, tuple[str, list[str]]]:
    """The same table as ``modules.dep`` gives, built by walking ``moddir/kernel``."""
    table: dict[str, tuple[str, list[str]]] = {}
    for path in sorted((moddir / "kernel").rglob("*.ko*")):
        try:
            name = module_name(path.name)
        except ModuleError:
            continue
        table[name] = (str(path.relative_to(moddir)), [])
    return table


def builtin_names(moddir: Path) -> set[str]:
    listing = moddir / "modules.builtin"
    if not listing.exists():
        return set()
    return {module_name(line.strip()) for line in listing.read_text().splitlines() if line.strip()}


def load_order(
    wanted: Iterable[str],
    paths: Mapping[str, str],
    depends: Mapping[str, list[str]],
    builtin: set[str],
) -> list[str]:
    """The names to insert, dependencies first, keeping ``wanted``'s order otherwise.

    Built-in modules are skipped (they are already in the kernel image); a module that is
    neither built in nor in ``paths`` is an error.
    """
    order: list[str] = []
    visiting: set[str] = set()

    def visit(name: str) -> None:
        name = canonical(name)
        if name in order or name in builtin:
            return
        if name not in paths:
            raise ModuleError(f"kernel module {name!r} is neither built in nor in the package")
        if name in visiting:
            raise ModuleError(f"module dependency cycle at {name!r}")
        visiting.add(name)
        for dep in depends.get(name, []):
            visit(dep)
        visiting.discard(name)
        order.append(name)

    for name in wanted:
        visit(name)
    return order


def resolve(moddir: Path, wanted: Iterable[str] = GUEST_MODULES) -> list[tuple[str, bytes]]:
    """(name, uncompressed ELF bytes) of every module to insert, in insertion order."""
    dep_file = moddir / "modules.dep"
    if dep_file.exists():
        table = parse_modules_dep(dep_file.read_text())
        paths = {n: p for n, (p, _) in table.items()}
        depends = {n: d for n, (_, d) in table.items()}
        blobs: dict[str, bytes] = {}
    else:
        paths = {n: p for n, (p, _) in scan_tree(moddir).items()}
        blobs = {}
        depends = {}
        # Only the modules reachable from ``wanted`` are opened: reading every .modinfo of a
        # full kernel would take seconds for nothing.
        pending = [canonical(w) for w in wanted]
        builtin = builtin_names(moddir)
        while pending:
            name = pending.pop()
            if name in depends or name in builtin or name not in paths:
                continue
            blobs[name] = decompress(moddir / paths[name])
            depends[name] = modinfo_depends(blobs[name])
            pending.extend(depends[name])
    order = load_order(wanted, paths, depends, builtin_names(moddir))
    return [(n, blobs.get(n) or decompress(moddir / paths[n])) for n in order]
