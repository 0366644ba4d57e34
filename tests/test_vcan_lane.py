"""The vcan lane: every ``vcan``-marked test runs on a real SocketCAN vcan0.

Where this kernel has vcan0 those tests run directly in this session and the lane is skipped.
Otherwise ``test_lane_runs_every_vcan_test_in_guest`` boots the QEMU guest (tools/vcan_guest),
runs them there and checks that each one collected on the host passed in the guest, so a lane
that silently runs nothing fails. Without native vcan and without the guest it fails, unless
``HIL_SKIP_VCAN_LANE=1`` says to skip it. The fast tests below check the harness's pure parts.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from tools.vcan_guest import cpio, initramfs, modules, runner
from tools.vcan_guest.image import (
    GuestUnavailableError,
    is_static_elf,
    parse_depends,
    parse_version,
    prepare,
)
from tools.vcan_guest.native import native_vcan_status

ROOT = Path(__file__).resolve().parent.parent
#: This file's two python-can tests plus the CAN drive-lifecycle case at least.
LANE_MIN_TESTS = 3
# Boot ~8-20 s and ~25x slower Python under TCG on a shared 2-core machine: be generous.
LANE_TIMEOUT_S = 1200.0
VCAN_MARK = re.compile(r"\bpytest\.mark\.vcan\b")
ANSI = re.compile(r"\x1b\[[0-9;?]*[A-Za-z]")


# --- the lane ---------------------------------------------------------------------------------


def _lane_skip_reason() -> str | None:
    if os.environ.get("HIL_IN_VCAN_GUEST") == "1":
        return "already inside the vcan guest"
    usable, _ = native_vcan_status()
    if usable:
        return "vcan0 is native here: the vcan tests run directly in this session"
    if os.environ.get("HIL_SKIP_VCAN_LANE") == "1":
        return "HIL_SKIP_VCAN_LANE=1: the vcan guest lane was explicitly skipped"
    return None


def _guest_image():
    try:
        return prepare()
    except GuestUnavailableError as exc:
        pytest.fail(
            f"no native vcan0 and the vcan guest cannot be built: {exc}\n"
            "Install what is missing (see docs/vcan.md), or set HIL_SKIP_VCAN_LANE=1 to skip "
            "this lane explicitly.",
            pytrace=False,
        )


def vcan_test_files(tests_dir: Path) -> list[str]:
    """Test files that mark anything ``vcan``: the guest collects only these, since importing
    every test module costs minutes under TCG."""
    return sorted(
        str(p.relative_to(tests_dir.parent))
        for p in tests_dir.glob("test_*.py")
        if VCAN_MARK.search(p.read_text(encoding="utf-8"))
    )


def parse_pytest_outcome(text: str) -> tuple[dict[str, int], set[str]]:
    """(counts from pytest's closing line, ids listed PASSED by ``-rA``)."""
    clean = ANSI.sub("", text)
    counts: dict[str, int] = {}
    closing = [ln for ln in clean.splitlines() if re.match(r"^=+ .* in [0-9.]+s", ln)]
    if closing:
        for n, word in re.findall(r"(\d+) (\w+)", closing[-1]):
            counts[{"error": "errors", "warning": "warnings"}.get(word, word)] = int(n)
    passed = set(re.findall(r"^PASSED (\S+)", clean, re.MULTILINE))
    return counts, passed


def _collect_vcan_ids(files: list[str]) -> set[str]:
    argv = [sys.executable, "-m", "pytest", "--collect-only", "-q", "-m", "vcan"]
    res = subprocess.run(
        [*argv, "-p", "no:cacheprovider", *files],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert res.returncode == 0, f"host collection of vcan tests failed:\n{res.stdout}{res.stderr}"
    return {ln.strip() for ln in res.stdout.splitlines() if "::" in ln}


@pytest.mark.slow
@pytest.mark.timeout(LANE_TIMEOUT_S + 300)
def test_lane_runs_every_vcan_test_in_guest(tmp_path):
    if reason := _lane_skip_reason():
        pytest.skip(reason)
    image = _guest_image()
    files = vcan_test_files(ROOT / "tests")
    expected = _collect_vcan_ids(files)
    assert len(expected) >= LANE_MIN_TESTS, f"too few vcan tests collected: {sorted(expected)}"

    log = tmp_path / "guest-console.log"
    argv = ["python", "-m", "pytest", "-m", "vcan", "-p", "no:cacheprovider", "-rA"]
    argv += ["--color=no", "--durations=5", *files]
    try:
        result = runner.run_in_guest(
            argv, cwd=str(ROOT), timeout=LANE_TIMEOUT_S, log_path=log, image=image
        )
    except runner.GuestError as exc:
        pytest.fail(str(exc), pytrace=False)
    counts, passed = parse_pytest_outcome(result.output)
    tail = "\n".join(result.output.splitlines()[-40:])
    print(f"vcan lane: boot {result.boot_s:.1f} s, total {result.total_s:.1f} s, {counts}")
    assert result.exit_code == 0, f"vcan tests failed in the guest ({log}):\n{tail}"
    assert counts.get("failed", 0) == 0 and counts.get("errors", 0) == 0, tail
    assert passed == expected, (
        f"vcan tests collected on the host but not passed in the guest: "
        f"{sorted(expected - passed)}; unexpected: {sorted(passed - expected)}\n{tail}"
    )
    assert counts.get("passed") == len(expected), tail


@pytest.mark.timeout(300)
def test_guest_timeout_kills_qemu_by_pid(tmp_path):
    """A command that outlives the timeout raises GuestError and leaves no qemu behind."""
    if reason := _lane_skip_reason():
        pytest.skip(reason)
    image = _guest_image()
    pids: list[int] = []
    with pytest.raises(runner.GuestError, match="timed out"):
        runner.run_in_guest(
            ["sleep", "600"],
            timeout=3.0,
            log_path=tmp_path / "console.log",
            image=image,
            on_start=pids.append,
        )
    assert len(pids) == 1
    assert not Path(f"/proc/{pids[0]}").exists(), "qemu survived the timeout"


# --- the harness's pure parts -----------------------------------------------------------------


def test_closing_line_and_passed_ids_are_parsed():
    out = (
        "PASSED tests/test_vcan_native.py::test_a\n"
        "PASSED tests/test_can_two_process.py::test_b[vcan]\n"
        "SKIPPED [1] tests/x.py:3: why\n"
        "\x1b[32m===== 2 passed, 1 skipped, 1 error, 3 deselected in 37.73s =====\x1b[0m\n"
    )
    counts, passed = parse_pytest_outcome(out)
    assert counts == {"passed": 2, "skipped": 1, "errors": 1, "deselected": 3}
    assert passed == {
        "tests/test_vcan_native.py::test_a",
        "tests/test_can_two_process.py::test_b[vcan]",
    }
    assert parse_pytest_outcome("===== no tests ran in 0.01s =====\n") == ({}, set())


def test_lane_selects_files_that_mark_vcan():
    files = vcan_test_files(ROOT / "tests")
    assert "tests/test_vcan_native.py" in files
    assert "tests/test_vcan_lane.py" not in files  # never nests a guest in the guest


def test_kernel_package_is_read_from_apt_output():
    depends = (
        "linux-image-amd64\n  Depends: linux-image-6.1.0-50-amd64\n  Depends: <virtual-thing>\n"
    )
    assert parse_depends(depends) == "linux-image-6.1.0-50-amd64"
    assert parse_depends("linux-image-amd64\n") is None
    assert parse_version("Package: x\nVersion: 6.1.176-1\nSize: 1\n") == "6.1.176-1"


def test_marker_needs_this_runs_nonce():
    nonce = "0123abcd"
    assert runner.parse_marker(f"x @@HIL-VCAN-GUEST-EXIT:{nonce}:7@@", nonce) == ("exit", "7")
    assert runner.parse_marker(f"@@HIL-VCAN-GUEST-READY:{nonce}@@", nonce) == ("ready", "")
    assert runner.parse_marker(f"@@HIL-VCAN-GUEST-FAIL:{nonce}:insmod vcan@@", nonce) == (
        "fail",
        "insmod vcan",
    )
    # A command that prints a marker cannot fake the verdict without the nonce.
    assert runner.parse_marker("@@HIL-VCAN-GUEST-EXIT:ffffffff:0@@", nonce) is None


def test_module_order_puts_dependencies_first_and_skips_builtins():
    paths = {n: f"kernel/{n}.ko" for n in ("can", "can_raw", "can_dev", "vcan", "netfs")}
    depends = {"can_raw": ["can"], "vcan": ["can_dev"], "can_dev": [], "can": []}
    order = modules.load_order(["can-raw", "vcan", "virtio"], paths, depends, {"virtio"})
    assert order == ["can", "can_raw", "can_dev", "vcan"]
    with pytest.raises(modules.ModuleError, match="9p"):
        modules.load_order(["9p"], paths, depends, set())


def test_modules_dep_lines_are_parsed():
    text = "kernel/net/can/can-raw.ko.xz: kernel/net/can/can.ko.xz\nkernel/net/can/can.ko.xz:\n"
    assert modules.parse_modules_dep(text) == {
        "can_raw": ("kernel/net/can/can-raw.ko.xz", ["can"]),
        "can": ("kernel/net/can/can.ko.xz", []),
    }


def test_guest_environment_is_curated():
    host = {"PATH": "/usr/bin", "HIL_X": "1", "AWS_SECRET_ACCESS_KEY": "s", "HOME": "/root"}
    env = runner.guest_env(host, {"EXTRA": "2"})
    assert env["HIL_IN_VCAN_GUEST"] == "1" and env["HIL_X"] == "1" and env["EXTRA"] == "2"
    assert "AWS_SECRET_ACCESS_KEY" not in env
    assert env["PYTHONDONTWRITEBYTECODE"] == "1"
    assert env["PATH"].startswith(str(Path(sys.executable).parent) + ":")
    assert runner.guest_argv(["python", "-m", "pytest"])[0] == sys.executable


def test_run_script_keeps_awkward_arguments_intact(tmp_path):
    args = ["it's", "a b", "$HOME", '"q"', "*"]
    code = "import os, sys; print(os.getcwd(), os.environ['K'], sys.argv[1:])"
    script = initramfs.run_script(
        [sys.executable, "-c", code, *args],
        str(tmp_path),
        {"K": "v w"},
    )
    out = subprocess.run(["sh", "-c", script], capture_output=True, text=True, check=True).stdout
    assert out.strip() == f"{tmp_path} v w {args}"


@pytest.mark.skipif(not Path("/bin/busybox").exists(), reason="busybox not installed")
def test_newc_archive_reads_back_with_busybox_cpio(tmp_path):
    entries = [
        cpio.directory("d"),
        cpio.file("d/f", b"hello"),
        cpio.file("d/odd", b"x" * 5),
        cpio.symlink("d/l", "f"),
    ]
    archive = tmp_path / "a.cpio"
    archive.write_bytes(cpio.newc_archive(entries))
    out = tmp_path / "out"
    out.mkdir()
    subprocess.run(
        ["/bin/busybox", "cpio", "-i", "-d", "-F", str(archive)],
        cwd=out,
        check=True,
        capture_output=True,
    )
    assert (out / "d" / "f").read_bytes() == b"hello"
    assert (out / "d" / "odd").read_bytes() == b"xxxxx"
    assert os.readlink(out / "d" / "l") == "f"


def test_init_script_inserts_modules_in_order_and_reports_markers():
    text = initramfs.init_script(["virtio_ring", "can", "vcan"])
    assert "for m in virtio_ring can vcan; do" in text
    assert "ip link add dev vcan0 type vcan" in text
    assert text.index(initramfs.MARK_READY) < text.index(initramfs.MARK_EXIT)
    if shutil.which("sh"):
        # Syntax only: ``sh -n`` parses without running anything.
        subprocess.run(["sh", "-n"], input=text, text=True, check=True)


def test_static_busybox_is_told_from_a_dynamic_binary():
    assert not is_static_elf(Path(sys.executable).resolve())
    if Path("/bin/busybox").exists():
        assert is_static_elf(Path("/bin/busybox"))


def test_tmp_binds_keep_the_outermost_existing_folders_under_tmp(tmp_path):
    venv = tmp_path / "clone" / ".venv"
    (venv / "bin").mkdir(parents=True)
    (venv / "bin" / "python").symlink_to(sys.executable)
    binds = initramfs.tmp_binds(
        [str(venv / "bin" / "python"), str(venv), str(tmp_path / "clone"), "", "rel", "/usr/lib"]
    )
    # The venv's python links out of /tmp; the venv itself must still be carried over.
    assert binds == [str(tmp_path / "clone")]
    other = tmp_path.parent / f"{tmp_path.name}-other"
    other.mkdir()
    try:
        both = initramfs.tmp_binds([str(venv / "bin" / "python"), str(other)])
        assert both == sorted([str(venv / "bin"), str(other)], key=lambda s: (s.count("/"), s))
    finally:
        other.rmdir()


def test_run_script_says_why_when_the_program_is_not_there(tmp_path):
    missing = str(tmp_path / "venv" / "bin" / "python3")
    script = initramfs.run_script([missing, "-c", "pass"], str(tmp_path), {})
    res = subprocess.run(["sh", "-c", script], capture_output=True, text=True, check=False)
    assert res.returncode == 125, res
    assert f"{missing} is not visible inside the guest" in res.stderr
    assert len(res.stderr.strip().splitlines()) == 1


@pytest.mark.slow
@pytest.mark.timeout(600)
def test_guest_runs_an_interpreter_from_a_venv_under_tmp(tmp_path):
    """The guest's /tmp is private: a venv under the host's /tmp must be carried into it."""
    if reason := _lane_skip_reason():
        pytest.skip(reason)
    image = _guest_image()
    assert str(tmp_path).startswith("/tmp/")
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True)
    code = "import sys; print('GUEST-PREFIX', sys.prefix)"
    try:
        result = runner.run_in_guest(
            [str(venv / "bin" / "python3"), "-c", code],
            cwd=str(tmp_path),
            timeout=300,
            log_path=tmp_path / "console.log",
            image=image,
        )
    except runner.GuestError as exc:
        pytest.fail(str(exc), pytrace=False)
    assert result.exit_code == 0, result.output
    assert f"GUEST-PREFIX {venv}" in result.output
