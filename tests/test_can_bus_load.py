"""Frame bit lengths and ``hil can-load`` against a hand computation."""

from __future__ import annotations

import json

import pytest

from hil.cli import main
from protocol.can.bus_load import bus_load_percent, frame_bits, frame_time, profile_frames


def test_can_frame_bits_by_hand():
    # 11-bit id: 47 + 8n + floor((34 + 8n - 1)/4)
    assert frame_bits(8) == 47 + 64 + 24 == 135
    assert frame_bits(0) == 47 + 8 == 55
    assert frame_bits(1) == 47 + 8 + 10 == 65
    assert frame_bits(4) == 47 + 32 + 16 == 95
    assert frame_bits(8, remote=True) == 55
    assert frame_bits(8, extended=True) == 67 + 64 + 29 == 160
    assert frame_bits(8, stuffing=False) == 111
    assert frame_time(8, 500_000) == pytest.approx(270e-6)
    with pytest.raises(ValueError):
        frame_bits(9)


def test_can_profile_load_by_hand():
    # 1 kHz, 2 drives: 2000 torque + 2000 estimates + 20 heartbeats per second, 135 bits each
    frames = profile_frames(1000.0, drives=2)
    assert sum(f.bits_per_second for f in frames) == 4020 * 135 == 542_700
    assert bus_load_percent(frames, 1_000_000) == pytest.approx(54.27)
    assert bus_load_percent(frames, 500_000) == pytest.approx(108.54)


def test_can_load_command_ok_and_overloaded(tmp_path, capsys):
    assert main(["can-load", "--rate", "1000", "--bitrate", "1000000", "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["load_percent"] == pytest.approx(54.27)
    assert [f["bits"] for f in report["frames"]] == [135, 135, 135]
    code = main(["can-load", "--rate", "1000", "--bitrate", "500000", "--out", str(tmp_path)])
    assert code == 1
    err = capsys.readouterr().err
    assert "warning" in err and "108.5" in err
    assert json.loads((tmp_path / "can_load.json").read_text())["load_percent"] > 100


def test_can_load_options_change_the_figure(capsys):
    args = ["can-load", "--rate", "100", "--bitrate", "250000", "--drives", "4"]
    assert main([*args, "--heartbeat-rate", "0", "--encoder-rate", "0", "--json"]) == 0
    # only 4 torque frames per cycle: 400 * 135 / 250000
    assert json.loads(capsys.readouterr().out)["load_percent"] == pytest.approx(21.6)


@pytest.mark.parametrize(
    "args", [["--rate", "0", "--bitrate", "1e6"], ["--rate", "10", "--bitrate", "-5"]]
)
def test_can_load_bad_input_exits_2(args):
    assert main(["can-load", *args]) == 2
