"""A mission whose interventions the robot's arm cannot reach from the last waypoint is refused
before any station starts, naming the field (launch/mission_check.py)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from abyss.common.errors import ConfigError
from abyss.config import load
from abyss.launch.mission_check import check_reach


def test_the_default_mission_is_within_reach() -> None:
    check_reach(load(None, []))  # the shipped pair: no error


def test_a_part_beyond_the_arm_is_refused_naming_the_field_the_distance_and_the_reach() -> None:
    # the last waypoint 3 m further off the panel than the default's
    far = load(None, ["mission.waypoints=[[1.5, 0.0, -7.0, 0.0], [0.2, 0.0, -8.0, 0.0]]"])
    with pytest.raises(
        ConfigError, match=r"mission\.interventions\[0\]: valve_1's grasp is 3\.79 m .* reaches 1\.\d\d m"
    ):
        check_reach(far)
    # the BlueROV2's Alpha 5 (0.37 m) from where the work-class ROV holds (1.8 m off the face)
    small = load(None, ["simulation.robot=bluerov2_heavy_alpha5", "simulation.site=valve_panel"])
    with pytest.raises(ConfigError, match=r"interventions\[0\]: .* reaches 0\.\d\d m"):
        check_reach(small)


def test_abyss_up_refuses_it_before_starting_a_station(tmp_path: Path) -> None:
    done = subprocess.run(
        [sys.executable, "-P", "-m", "abyss.cli", "up", "--out", str(tmp_path / "run"), "--set",
         "mission.waypoints=[[0.2, 0.0, -8.0, 0.0]]"],
        capture_output=True, text=True, timeout=60, cwd=tmp_path,
    )  # fmt: skip
    assert done.returncode == 2 and "mission.interventions[0]: valve_1's grasp" in done.stderr, done.stderr
    assert not (tmp_path / "run" / "simulation.log").exists()
