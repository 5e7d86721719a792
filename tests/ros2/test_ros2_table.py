"""The ROS 2 table (`ros2.types`) and its docs page (docs/ros2.md) agree."""

from __future__ import annotations

from pathlib import Path

from abyss.ros2.types import topics_table

ROOT = Path(__file__).resolve().parents[2]


def test_docs_topic_table_is_the_generated_one() -> None:
    assert topics_table() in (ROOT / "docs" / "ros2.md").read_text()


def test_docs_list_what_a_ros2_node_states_in_its_diagnostics() -> None:
    from abyss.ros2.from_ros import TELEMETRY_VALUES

    page = (ROOT / "docs" / "ros2.md").read_text()
    for key, meaning in TELEMETRY_VALUES.items():
        assert f"  - `{key}`: {meaning}" in page, key
