"""The shipped DBC decodes the whole robot: every message of CANSimple 0.6 for axes 0-7, laid out
as in ODrive's own DBC (0.6.10, shipped by the PyPI odrive-can client), and ``cantools decode``
names the frames of node 1 as well as node 0. ``hil can-dbc`` writes one for any node ids."""

from __future__ import annotations

import subprocess
import sys
from importlib import resources
from pathlib import Path

import cantools
import pytest
from odrive_can.utils import get_dbc_path

from protocol.can import codec
from protocol.can.codec import SetInputTorque
from protocol.can.dbc import parse_nodes, render

SHIPPED = Path(str(resources.files("protocol.can").joinpath(codec.DBC_NAME)))


def test_can_shipped_dbc_is_the_generated_one_for_axes_0_to_7():
    assert SHIPPED.read_text(encoding="utf-8") == render(range(8))


def test_can_dbc_matches_odrives_own_for_every_message():
    ours = cantools.database.load_file(str(SHIPPED))
    official = cantools.database.load_file(str(get_dbc_path("odrive-cansimple-0.6.10")))
    assert len(official.messages) == len(ours.messages) == 8 * 28
    for theirs in official.messages:
        mine = ours.get_message_by_frame_id(theirs.frame_id)
        assert (mine.name, mine.length) == (theirs.name, theirs.length)
        assert {s.name for s in mine.signals} == {s.name for s in theirs.signals}, theirs.name
        for s in theirs.signals:
            m = mine.get_signal_by_name(s.name)
            layout = (m.start, m.length, m.byte_order, m.is_float, m.scale, m.offset)
            assert layout == (s.start, s.length, s.byte_order, s.is_float, s.scale, s.offset)
            if not s.is_float:  # a float's sign bit is the float's own
                assert m.is_signed == s.is_signed, (theirs.name, s.name)


def _candump(frames) -> str:
    return "".join(
        f"  vcan0  {f.arbitration_id:03X}   [{len(f.data)}]  {f.data.hex(' ').upper()}\n"
        for f in frames
    )


def test_can_cantools_decode_names_both_wheels_frames():
    frames = [codec.encode(SetInputTorque(0, 0.25)), codec.encode(SetInputTorque(1, -0.5))]
    frames.append(codec.encode(codec.EncoderEstimates(1, 3.0, 1.5)))
    out = subprocess.run(
        [sys.executable, "-m", "cantools", "decode", str(SHIPPED)],
        input=_candump(frames),
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert out.returncode == 0, out.stderr
    assert "Axis0_Set_Input_Torque(" in out.stdout and "Input_Torque: 0.25 Nm" in out.stdout
    assert "Axis1_Set_Input_Torque(" in out.stdout and "Input_Torque: -0.5 Nm" in out.stdout
    assert "Axis1_Get_Encoder_Estimates(" in out.stdout and "Pos_Estimate: 3.0 rev" in out.stdout


def test_can_dbc_command_writes_one_for_other_node_ids(tmp_path):
    out = subprocess.run(
        [sys.executable, "-m", "hil", "can-dbc", "--nodes", "0,1,12", "--out", str(tmp_path)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert out.returncode == 0, out.stderr
    db = cantools.database.load_file(str(tmp_path / "odrive_cansimple.dbc"))
    frame = codec.encode(SetInputTorque(12, 0.125))
    msg = db.get_message_by_frame_id(frame.arbitration_id)
    assert msg.name == "Axis12_Set_Input_Torque"
    assert msg.decode(frame.data)["Input_Torque"] == 0.125
    assert {m.frame_id >> 5 for m in db.messages} == {0, 1, 12}
    bad = subprocess.run(
        [sys.executable, "-m", "hil", "can-dbc", "--nodes", "70"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert bad.returncode == 2 and "0..63" in bad.stderr


@pytest.mark.parametrize(("text", "nodes"), [("0-7", tuple(range(8))), ("3,1,1-2", (1, 2, 3))])
def test_can_node_lists(text, nodes):
    assert parse_nodes(text) == nodes
