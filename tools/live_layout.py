"""Writes docs/live-layout.json, the ready-made Foxglove layout of the live view (docs/live.md).

Built with foxglove-sdk's own layout types (``foxglove.layouts``), so the file is what
Foxglove's importer expects; the topics come from :mod:`hil.schemas`, the one place that names
them. ``python tools/live_layout.py [ROBOT_ID] [--check]`` (``--check``: exit 1 if a file
differs, as tests/test_live.py does).

It writes the same layout twice: ``live-layout.json`` in the SDK's format, and
``live-layout-lichtblick.json`` in the format that Lichtblick and Foxglove Studio 1.x import
(``configById`` and a binary split tree, as those apps export layouts), which the SDK does not
write.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

import foxglove.layouts as fl

from hil import schemas

OUT = Path(__file__).resolve().parents[1] / "docs" / "live-layout.json"
OUT_LEGACY = OUT.with_name("live-layout-lichtblick.json")
# The SDK's panel type names that those apps know by another name.
LEGACY_PANEL_TYPES = {"ThreeDee": "3D"}


# Seen from above (2D), centred on the paper's circle (radius vd/wd = 2.5 m about (0, 2.5)),
# wide enough for the robot's start at (-1, -0.6); every field, as Foxglove's own layouts do.
CAMERA = fl.ThreeDeeCameraState(
    distance=15.0,
    perspective=False,
    phi=0.0,
    target=(0.0, 0.0, 0.0),
    target_offset=(0.0, 2.5, 0.0),
    target_orientation=(0.0, 0.0, 0.0, 1.0),
    theta_offset=0.0,
    fovy=45.0,
    near=0.5,
    far=5000.0,
)


def _plot(title: str, paths: list[tuple[str, str]]) -> fl.PlotPanel:
    series = [
        fl.PlotSeries(value=v, label=label, enabled=True, timestamp_method="receiveTime")
        for v, label in paths
    ]
    return fl.PlotPanel(title=title, config=fl.PlotConfig(paths=series, show_legend=True))


def layout(robot_id: str = "robot0") -> fl.Layout:
    """3D scene (pose, reference, tf) beside plots of v, omega, the torques and the timing."""
    base = f"hil/{robot_id}"
    timing = f"{base}/{schemas.TIMING}"
    arrow = (0.6, 0.12, 0.12)  # m: a robot-sized arrow in the scene below
    scene = fl.ThreeDeePanel(
        title="robot and reference",
        config=fl.ThreeDeeConfig(
            follow_tf=schemas.WORLD_FRAME,
            camera_state=CAMERA,
            topics={
                f"{base}/{schemas.POSE}": fl.BaseRendererPoseTopicSettings(
                    visible=True, type="arrow", arrow_scale=arrow, color="#1f77b4"
                ),
                f"{base}/{schemas.REFERENCE}": fl.BaseRendererPoseTopicSettings(
                    visible=True, type="arrow", arrow_scale=arrow, color="#2ca02c"
                ),
            },
        ),
    )
    plots = fl.SplitContainer(
        direction="column",
        items=[
            fl.SplitItem(content=_plot("v, omega (State)", [
                (f"{base}/state.v", "v m/s"), (f"{base}/state.omega", "omega rad/s")])),
            fl.SplitItem(content=_plot("torques (TorqueCommand)", [
                (f"{base}/cmd/torque.tau1", "tau1"), (f"{base}/cmd/torque.tau2", "tau2")])),
            fl.SplitItem(content=_plot("command age vs D* (ms)", [
                (f"{timing}.command_age_now_ms", "age now"),
                (f"{timing}.command_age_max_ms", "age max"),
                (f"{timing}.d_star_ms", "D*")])),
        ],
    )  # fmt: skip
    right = fl.SplitContainer(
        direction="column",
        items=[
            fl.SplitItem(proportion=2, content=plots),
            fl.SplitItem(
                content=fl.RawMessagesPanel(
                    title="timing and verdict so far",
                    config=fl.RawMessagesConfig(topic_path=timing),
                )
            ),
        ],
    )
    return fl.Layout(
        content=fl.SplitContainer(
            direction="row",
            items=[fl.SplitItem(content=scene), fl.SplitItem(content=right)],
        )
    )


def legacy(content: dict[str, Any], config_by_id: dict[str, Any]) -> str | dict[str, Any]:
    """The SDK's layout tree as a react-mosaic tree (what Lichtblick imports); fills config_by_id.

    An n-way split becomes nested two-way splits with the same proportions; a panel's title
    goes into its config as ``foxglovePanelTitle``, where those apps keep it.
    """
    if content["type"] == "panel":
        kind = LEGACY_PANEL_TYPES.get(content["panelType"], content["panelType"])
        panel_id = f"{kind}!{len(config_by_id) + 1}"
        config = dict(content.get("config", {}))
        if "title" in content:
            config["foxglovePanelTitle"] = content["title"]
        config_by_id[panel_id] = config
        return panel_id
    items = content["items"]
    if len(items) == 1:
        return legacy(items[0]["content"], config_by_id)
    weights = [item.get("proportion", 1) for item in items]
    first = legacy(items[0]["content"], config_by_id)
    rest = legacy({**content, "items": items[1:]}, config_by_id)
    return {
        "direction": content["direction"],
        "first": first,
        "second": rest,
        "splitPercentage": round(100 * weights[0] / sum(weights), 3),
    }


def texts(robot_id: str = "robot0") -> dict[Path, str]:
    """Both files' text: the SDK's format and Lichtblick's, of the same layout."""
    sdk = json.loads(layout(robot_id).to_json())
    config_by_id: dict[str, Any] = {}
    tree = legacy(sdk["content"], config_by_id)
    old = {
        "configById": config_by_id,
        "layout": tree,
        "globalVariables": sdk.get("variables", {}),
        "userNodes": {},
        "playbackConfig": {"speed": 1},
    }
    return {OUT: _dump(sdk), OUT_LEGACY: _dump(old)}


def _dump(data: dict[str, Any]) -> str:
    return json.dumps(data, indent=2) + "\n"


def main(argv: list[str]) -> int:
    check = "--check" in argv
    args = [a for a in argv if a != "--check"]
    wanted = texts(*args[:1])
    if check:
        return 0 if all(p.read_text() == t for p, t in wanted.items()) else 1
    for path, text in wanted.items():
        path.write_text(text)
        print(path)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
