"""The services stand alone: ``python -m controller_service SETTINGS``, ``python -m
plant_emulator SETTINGS`` and ``python -m plant_emulator.drives SETTINGS`` run from the settings
file ``hil`` wrote, in processes where ``hil`` cannot be imported, and close the loop over Zenoh
on loopback (scouting off) and the CAN bus over Zenoh."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.procs import free_tcp_port, stop_pid
from tests.run_helpers import load_log

pytestmark = pytest.mark.realtime

ROOT = Path(__file__).resolve().parent.parent
ROUTER = (
    "import sys, time, zenoh; from runtime.zsession import session_config; "
    "s = zenoh.open(session_config(sys.argv[1], listen_endpoint=True, mode='router')); "
    "print('up', flush=True); time.sleep(1e9)"
)
# First on PYTHONPATH: any import of hil (or of a module of it) leaves a mark and fails.
BLOCKER = """\
import os
with open(os.environ["HIL_IMPORT_MARKER"], "a") as f:
    f.write("hil imported\\n")
raise ImportError("hil is not installed here: the services must run without it")
"""


def _no_hil_env(tmp_path: Path) -> tuple[dict[str, str], Path]:
    blocker = tmp_path / "no_hil"
    (blocker / "hil").mkdir(parents=True)
    (blocker / "hil" / "__init__.py").write_text(BLOCKER)
    marker = tmp_path / "hil_imported.txt"
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(blocker), env.get("PYTHONPATH", "")]).rstrip(
        os.pathsep
    )
    env["HIL_IMPORT_MARKER"] = str(marker)
    return env, marker


def _write_settings(tmp_path: Path, *options: str) -> Path:
    """``hil`` (importable here) resolves the bundled scenario into one settings file."""
    path = tmp_path / "settings.json"
    proc = subprocess.run(
        [sys.executable, "-m", "hil", "emulator", "paper_tracking", *options,
         "--out", str(tmp_path / "run"), "--write-settings", str(path)],
        cwd=ROOT, capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-2000:]
    return path


def test_the_blocker_hides_hil_and_nothing_else(tmp_path: Path) -> None:
    env, marker = _no_hil_env(tmp_path)
    code = "import controller_service.service, plant_emulator.service, plant_emulator.drives\n"
    ok = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, env=env, timeout=120)
    assert ok.returncode == 0 and not marker.exists()
    bad = subprocess.run([sys.executable, "-c", "import hil.cli"], cwd=tmp_path, env=env,
                         capture_output=True, text=True, timeout=60)  # fmt: skip
    assert bad.returncode != 0 and "hil is not installed here" in bad.stderr
    assert marker.exists()


def test_controller_and_plant_close_the_loop_without_hil(spawn, tmp_path: Path) -> None:
    ep = f"tcp/127.0.0.1:{free_tcp_port()}"
    can_ep = f"tcp/127.0.0.1:{free_tcp_port()}"
    epoch = time.monotonic_ns() + 20_000_000_000  # both import and link well before t = 0
    settings = _write_settings(
        tmp_path, "--endpoint", ep, "--can-endpoint", can_ep, "--epoch-ns", str(epoch),
        "--duration", "1.5", "--rate", "200",
    )  # fmt: skip
    s = json.loads(settings.read_text())
    assert s["ts"] == 0.005 and s["controller"]["law"] == "unified" and s["reference"]
    assert s["initial"]["y"] == -0.6 and "design" in s and s["limits"]["varpi2"] == 51.0
    out = Path(s["out_dir"])
    env, marker = _no_hil_env(tmp_path)
    router = spawn.python(["-c", ROUTER, ep], text=True, cwd=ROOT)
    plant = ctrl = None
    try:
        assert router.stdout.readline().strip() == "up"
        plant = spawn.python(["-m", "plant_emulator", str(settings)], cwd=tmp_path, env=env)
        ctrl = spawn.python(["-m", "controller_service", str(settings)], cwd=tmp_path, env=env)
        plant.wait(timeout=90)  # the plant ends by itself after the run's duration
        assert plant.returncode == 0, plant.stderr.read()[-2000:]
        ctrl.send_signal(2)  # the controller runs until stopped (or duration + 2 s)
        ctrl.wait(timeout=30)
        assert ctrl.returncode == 0, ctrl.stderr.read()[-2000:]
    finally:
        for proc in (ctrl, plant, router):
            if proc is not None:
                stop_pid(proc)
    assert not marker.exists(), marker.read_text()
    clog = load_log(out / "controller.hoplog")
    plog = load_log(out / "plant.hoplog")
    assert clog.complete and plog.complete  # both exited cleanly: their footers are there
    assert clog.meta["epoch_ns"] == plog.meta["epoch_ns"] == epoch
    assert clog.meta["period_ns"] == 5_000_000
    assert clog.info["state_counts"]["accepted"] > 200  # ~300 states in 1.5 s at 200 Hz
    assert plog.info["cmd_counts"]["accepted"] > 200
    assert clog.info["can"]["frames_sent"] > 200  # the CAN shadow path carried them too


def test_the_virtual_drives_run_without_hil(spawn, tmp_path: Path) -> None:
    settings = _write_settings(tmp_path, "--can-endpoint", f"tcp/127.0.0.1:{free_tcp_port()}")
    env, marker = _no_hil_env(tmp_path)
    drives = spawn.python(
        ["-m", "plant_emulator.drives", str(settings), "--duration", "1", "--status-period", "0",
         "--out", str(tmp_path / "drives")],
        cwd=tmp_path, env=env, text=True,
    )  # fmt: skip
    try:
        _, stderr = drives.communicate(timeout=90)
    finally:
        stop_pid(drives)
    assert drives.returncode == 0, stderr[-2000:]
    assert not marker.exists()
    summary = json.loads((tmp_path / "drives" / "summary.json").read_text())
    assert summary["stopped_by"] == "duration" and summary["interface"] == "zenoh_can"


@pytest.mark.parametrize(
    ("args", "expect"),
    [(["scenario.toml"], "usage"), ([], "usage"), (["missing.json"], "cannot read")],
)
def test_a_service_without_a_settings_file_exits_2(tmp_path: Path, args, expect) -> None:
    env, marker = _no_hil_env(tmp_path)
    for module in ("controller_service", "plant_emulator"):
        proc = subprocess.run([sys.executable, "-m", module, *args], cwd=tmp_path, env=env,
                              capture_output=True, text=True, timeout=60)  # fmt: skip
        assert proc.returncode == 2 and expect in proc.stderr, proc.stderr
    assert not marker.exists()


def test_a_services_help_explains_its_settings_file_without_hil(tmp_path: Path) -> None:
    env, marker = _no_hil_env(tmp_path)
    for module in ("controller_service", "plant_emulator"):
        proc = subprocess.run([sys.executable, "-m", module, "--help"], cwd=tmp_path, env=env,
                              capture_output=True, text=True, timeout=60)  # fmt: skip
        assert proc.returncode == 0, proc.stderr
        assert "SETTINGS.json" in proc.stdout and "--write-settings" in proc.stdout
    assert not marker.exists()
