"""The vcan lane: every ``vcan``-marked test runs on a real SocketCAN vcan0.

Where this kernel has vcan0 those tests run directly in this session and the lane is skipped.
Otherwise the QEMU guest (tools/vcan_guest) runs them, beside the rest of the session from its
start (tests/vcan_lane.py) or, with ``HIL_VCAN_LANE_BESIDE=0``, in the lane test itself, which
checks that each one collected on the host passed in the guest, so a lane
that silently runs nothing fails. Without native vcan and without the guest it fails, unless
``HIL_SKIP_VCAN_LANE=1`` says to skip it. The fast tests below check the harness's pure parts.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from tests import vcan_lane
from tests.vcan_lane import LANE_MIN_TESTS, LANE_TIMEOUT_S, parse_pytest_outcome, vcan_test_files
from tools.vcan_guest import cpio, initramfs, modules, runner
from tools.vcan_guest.image import (
    GuestUnavailableError,
    is_static_elf,
    parse_depends,
    parse_version,
    prepare,
)

ROOT = Path(__file__).resolve().parent.parent
_lane_skip_reason = vcan_lane.lane_skip_reason


# --- the lane ---------------------------------------------------------------------------------


def _guest_unavailable(exc: GuestUnavailableError):
    pytest.fail(
        f"no native vcan0 and the vcan guest cannot be built: {exc}\n"
        "Install what is missing (see docs/vcan.md), or set HIL_SKIP_VCAN_LANE=1 to skip "
        "this lane explicitly.",
        pytrace=False,
    )


def _guest_image():
    try:
        return prepare()
    except GuestUnavailableError as exc:
        _guest_unavailable(exc)


def _lane_result(lane: vcan_lane.Lane) -> tuple[runner.GuestResult, set[str], str]:
    """(the guest's result, the ids it passed, its output's tail), or the test fails saying why
    the guest did not run them."""
    if isinstance(lane.error, GuestUnavailableError):
        _guest_unavailable(lane.error)
    if isinstance(lane.error, (runner.GuestError, TimeoutError)):
        pytest.fail(str(lane.error), pytrace=False)
    if lane.error is not None:
        raise lane.error
    assert lane.result is not None
    _, passed = parse_pytest_outcome(lane.result.output)
    return lane.result, passed, "\n".join(lane.result.output.splitlines()[-40:])


def _beside_left() -> tuple[vcan_lane.Lane | None, list[str] | None]:
    """(the lane run beside the session, the ids it left for the foreground: None for all)."""
    beside = vcan_lane.take_beside(LANE_TIMEOUT_S)
    if beside is None or beside.error is not None or beside.result is None:
        if beside is not None:
            print(f"vcan lane beside the session did not finish: {beside.error}")
        return beside, None
    _, passed = parse_pytest_outcome(beside.result.output)
    print(
        f"vcan lane beside the session: {beside.result.total_s:.0f} s, passed {len(passed)} "
        f"of {len(beside.expected)} (console {beside.log})"
    )
    return beside, sorted(beside.expected - passed)


@pytest.mark.slow
@pytest.mark.timeout(2 * LANE_TIMEOUT_S + 300)
def test_lane_runs_every_vcan_test_in_guest(tmp_path):
    """Run beside the session when it started so (tests/vcan_lane.py), else here; a test that
    failed beside the session runs again here, and this run is its result."""
    if reason := _lane_skip_reason():
        pytest.skip(reason)
    beside, again = _beside_left()
    expected = beside.expected if beside is not None and again is not None else set()
    if again != []:
        lane = vcan_lane.Lane(log=tmp_path / "guest-console.log")
        vcan_lane.run_lane(lane, LANE_TIMEOUT_S, ids=again)
        result, passed, tail = _lane_result(lane)
        counts, _ = parse_pytest_outcome(result.output)
        print(
            f"vcan lane in the foreground ({'again: ' + str(again) if again else 'all'}): boot "
            f"{result.boot_s:.1f} s, total {result.total_s:.1f} s, {counts} (console {lane.log})"
        )
        assert result.exit_code == 0, f"vcan tests failed in the guest ({lane.log}):\n{tail}"
        assert counts.get("failed", 0) == 0 and counts.get("errors", 0) == 0, tail
        missing, unexpected = sorted(lane.expected - passed), sorted(passed - lane.expected)
        assert not missing and not unexpected, (
            f"vcan tests collected on the host but not passed in the guest: {missing}; "
            f"unexpected: {unexpected}\n{tail}"
        )
        assert counts.get("passed") == len(lane.expected), tail
        expected |= lane.expected
    assert len(expected) >= LANE_MIN_TESTS, f"too few vcan tests collected: {sorted(expected)}"


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


def test_the_lane_starts_beside_only_a_session_that_runs_its_test(monkeypatch, tmp_path):
    """Not for --collect-only, not without the lane test, not when told not to: no guest then."""

    class Item:
        def __init__(self, name):
            self.name = name

    started = []
    monkeypatch.setattr(vcan_lane, "_beside", None)
    monkeypatch.setattr(vcan_lane.threading, "Thread", lambda **kw: started.append(kw))
    monkeypatch.setattr(vcan_lane, "lane_skip_reason", lambda: None)
    monkeypatch.setattr(vcan_lane.tempfile, "mkdtemp", lambda prefix: str(tmp_path))
    lane_items = [Item("test_x"), Item(vcan_lane.LANE_TEST)]
    vcan_lane.start_beside(lane_items, collect_only=True)
    vcan_lane.start_beside([Item("test_x")], collect_only=False)
    monkeypatch.setenv("HIL_VCAN_LANE_BESIDE", "0")
    vcan_lane.start_beside(lane_items, collect_only=False)
    assert started == [] and vcan_lane._beside is None
    monkeypatch.delenv("HIL_VCAN_LANE_BESIDE")
    with pytest.raises(AttributeError):  # the stand-in thread has no start(): it was reached
        vcan_lane.start_beside(lane_items, collect_only=False)
    assert started and started[0]["args"][2] == vcan_lane.BESIDE_NICE


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
