"""Writes docs/live-layout.json, the ready-made Foxglove layout of the live view (docs/live.md).

Built with foxglove-sdk's own layout types (``foxglove.layouts``), so the file is what
Foxglove's importer expects; the topics come from :mod:`hil.schemas`, the one place that names
them. ``python tools/live_layout.py [ROBOT_ID] [--check]`` (``--check``: exit 1 if the file
differs, as tests/test_live.py does).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import foxglove.layouts as fl

from hil import schemas

OUT = Path(__file__).resolve().parents[1] / "docs" / "live-layout.json"


def _plot(title: str, paths: list[tuple[str, str]]) -> fl.PlotPanel:
    series = [fl.PlotSeries(value=v, label=label) for v, label in paths]
    return fl.PlotPanel(title=title, config=fl.PlotConfig(paths=series, show_legend=True))


def layout(robot_id: str = "robot0") -> fl.Layout:
    """3D scene (pose, reference, tf) beside plots of v, omega, the torques and the timing."""
    base = f"hil/{robot_id}"
    timing = f"{base}/{schemas.TIMING}"
    scene = fl.ThreeDeePanel(
        title="robot and reference",
        config=fl.ThreeDeeConfig(
            follow_tf=schemas.WORLD_FRAME,
            topics={
                f"{base}/{schemas.POSE}": fl.BaseRendererPoseTopicSettings(visible=True),
                f"{base}/{schemas.REFERENCE}": fl.BaseRendererPoseTopicSettings(
                    visible=True, color="#2ca02c"
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


def text(robot_id: str = "robot0") -> str:
    return json.dumps(json.loads(layout(robot_id).to_json()), indent=2) + "\n"


def main(argv: list[str]) -> int:
    check = "--check" in argv
    args = [a for a in argv if a != "--check"]
    wanted = text(*args[:1])
    if check:
        return 0 if OUT.read_text() == wanted else 1
    OUT.write_text(wanted)
    print(OUT)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
