"""The station entry point (launch.station.station_main) decides between a station and the ROS 2
gateway: a station runs itself unless `ros2.station` names it; then onboard is the gateway alone,
and the vessel runs with the gateway as its scene model's mapper (stations/ imports no abyss.ros2)."""

from __future__ import annotations

import ast
import dataclasses
from pathlib import Path

import pytest

from abyss.config import Config
from abyss.config.system import Ros2Config
from abyss.launch import station as runtime
from abyss.ros2 import gateway
from abyss.stations import onboard, onshore, vessel

STATIONS_DIR = Path(onboard.__file__).parent.parent


def with_ros2(station: str) -> Config:
    return dataclasses.replace(Config(), ros2=Ros2Config(station=station))


@pytest.mark.parametrize("station", ["", "vessel"])
def test_onboard_runs_itself_unless_the_gateway_stands_for_it(station: str) -> None:
    assert runtime.station_main("onboard", with_ros2(station)) is onboard.run
    assert runtime.station_main("onboard", with_ros2("onboard")) is gateway.run


def test_the_vessel_runs_with_the_gateway_as_its_mapper_when_named() -> None:
    assert runtime.station_main("vessel", with_ros2("onboard")) is vessel.run
    main = runtime.station_main("vessel", with_ros2("vessel"))
    assert main is not vessel.run and main is not gateway.run
    assert runtime.station_main("onshore", with_ros2("vessel")) is onshore.run


def test_no_station_imports_the_ros2_gateway() -> None:
    """The choice lives in the entry point: neither station's package reaches for abyss.ros2."""
    for path in [*(STATIONS_DIR / "onboard").glob("*.py"), *(STATIONS_DIR / "vessel").glob("*.py")]:
        for node in ast.walk(ast.parse(path.read_text())):
            names = (
                [a.name for a in node.names]
                if isinstance(node, ast.Import)
                else [node.module or ""]
                if isinstance(node, ast.ImportFrom)
                else []
            )
            assert not any(n.startswith("abyss.ros2") for n in names), (path, names)
