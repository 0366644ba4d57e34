"""What a Foxglove-family viewer (Foxglove Studio, Lichtblick) needs of the live view, checked
without one: the JSON Schemas of the channels the layout shows stay within what their JSON
Schema parser takes (one ``type`` name per field, ``properties`` on every object; a channel
whose schema it refuses is dropped whole), and the Lichtblick layout file is a well-formed
tree of panels those apps know. docs/img/live.png is the same, seen in Foxglove Studio 1.48
(tools/live_screenshot.py)."""

from __future__ import annotations

import json
from typing import Any

import jsonschema
import pytest

from hil import schemas
from hil.bench.live.timing import Bounds, LiveTiming
from protocol.hoplog import NO_STAMP
from protocol.messages import FLAG_WATCHDOG_ZERO, State, TorqueCommand
from tests.viewer_schema import viewer_refuses


def test_the_rules_refuse_what_the_viewers_refused():
    # the timing schema's old nullable figures and Status's counters map, as first served
    assert viewer_refuses({"type": "object", "properties": {"a": {"type": ["number", "null"]}}})
    counters = {"type": "object", "additionalProperties": {"type": "integer"}}
    assert viewer_refuses({"type": "object", "properties": {"counters": counters}})
    # CAN float signals as first recorded: a number or the string "nan"/"inf" (an anyOf)
    union = {"anyOf": [{"type": "number"}, {"type": "string", "enum": ["nan", "inf"]}]}
    fields = {"type": "object", "properties": {"torque_nm": union}}
    assert viewer_refuses({"type": "object", "properties": {"fields": fields}})
    assert viewer_refuses(schemas.CAN_FRAME) == []  # now one type per field


@pytest.mark.parametrize(
    "suffix", ["state", "cmd/torque", "telemetry", "status", schemas.POSE, schemas.TF,
               schemas.REFERENCE, schemas.TIMING],
)  # fmt: skip
def test_every_robot_channel_of_the_live_view_parses_in_the_viewers(suffix):
    schema = schemas.schema_for_topic(f"hil/robot0/{suffix}")
    assert schema is not schemas.GENERIC
    assert viewer_refuses(schema) == []


def test_unknown_timing_figures_are_left_out_and_the_message_still_validates():
    timing = LiveTiming(Bounds(d_star_s=None, ts_s=0.001, phi1=1.0, phi2=2.0))
    snap = timing.snapshot(0)
    for name in ("command_age_now_ms", "d_star_ms", "age_margin_ms", "deadline_misses"):
        assert name not in snap
    jsonschema.Draft202012Validator(schemas.LIVE_TIMING).validate(snap)
    assert snap["verdict"] == "WAITING"
    assert set(snap) >= set(schemas.LIVE_TIMING["required"])


def test_the_lichtblick_layout_is_the_sdk_layout_as_a_panel_tree():
    from tools import live_layout

    legacy = json.loads(live_layout.OUT_LEGACY.read_text())
    sdk = json.loads(live_layout.OUT.read_text())

    def leaves(node: Any) -> list[str]:
        if isinstance(node, str):
            return [node]
        assert 0 < node["splitPercentage"] < 100 and node["direction"] in ("row", "column")
        return leaves(node["first"]) + leaves(node["second"])

    def panels(node: dict[str, Any]) -> list[dict[str, Any]]:
        if node["type"] == "panel":
            return [node]
        return [p for item in node["items"] for p in panels(item["content"])]

    ids = leaves(legacy["layout"])
    assert sorted(ids) == sorted(legacy["configById"])
    known = {"3D", "Plot", "RawMessages"}  # Lichtblick's and Studio's names of the panels
    assert {i.split("!")[0] for i in ids} == known
    for panel_id, panel in zip(ids, panels(sdk["content"]), strict=True):
        config = dict(legacy["configById"][panel_id])
        assert config.pop("foxglovePanelTitle") == panel["title"]
        assert config == panel["config"]


def test_a_watchdog_zero_command_before_the_first_state_is_not_the_command_in_force():
    # Seen in the viewer: the controller, up before the plant's first State, sends watchdog
    # zeros that name no sample (NO_STAMP); the live D was then the monotonic clock's age.
    ms = 1_000_000
    t0 = 7 * 3600 * 1000 * ms  # a machine up for 7 h
    timing = LiveTiming(Bounds(d_star_s=0.02, ts_s=0.001, phi1=1.0, phi2=2.0))
    zero = TorqueCommand("r", 0, 0, NO_STAMP, t0, t0, 0.0, 0.0, "u", FLAG_WATCHDOG_ZERO)
    timing.on_command(zero, t0)
    for k in range(1, 4):
        t = t0 + k * ms
        timing.on_state(State("r", k, t, t, 0.0, 0.0, 0.0, 0.0, 0.0), t)
        cmd = TorqueCommand("r", k, k, t, t, t, 0.0, 0.0, "u")
        timing.on_command(cmd, t)
    snap = timing.snapshot(t0 + 4 * ms)
    assert snap["command_age_max_ms"] == pytest.approx(1.0)  # one Ts: the previous State's
    assert snap["commands"] == 4 and snap["verdict"] == "PASS"
