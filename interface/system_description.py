"""The running system's own description, as ROS nodes read `robot_description`: the robot's and the
site's package files (robot.toml's and site.toml's tables) that the system runs by, served on
`<station>/description` by every station the testbed hosts (launch.station; keys.description_key)
and read by every operator tool (`abyss op`, `teleop`, `console`, `fault`), so that a tool checks
its command against the panel and the robot that are running, not against packages of its own.

A JSON object: `system`, `robot` (robot.toml's table) and `site` (site.toml's table), read back
through the same typed reader as the packages themselves (description/robot_file.py,
description/site.py); a malformed one is BadInput with the reason."""

from __future__ import annotations

import json
import tomllib
from dataclasses import dataclass
from typing import Any

from abyss.common.errors import BadInput, ConfigError
from abyss.common.reading import read_table
from abyss.description.models.panel import Panel
from abyss.description.robot import Robot
from abyss.description.robot_file import RobotFile
from abyss.description.site import Site, SiteFile
from abyss.interface.faults import ModelNames, model_names


@dataclass(frozen=True)
class SystemDescription:
    system: str
    robot: RobotFile
    site: SiteFile

    @property
    def panel(self) -> Panel:
        return self.site.panel

    @property
    def model_names(self) -> ModelNames:
        """The parts a fault may target on the running robot and panel (interface.faults)."""
        return model_names(self.robot, self.site.panel)


def description_payload(system: str, robot: Robot, site: Site) -> bytes:
    """What a station serves: the packages' files as their tables."""
    tables = {
        name: tomllib.loads(package.file.read_text()) for name, package in (("robot", robot), ("site", site))
    }
    return json.dumps({"system": system, **tables}).encode()


def description_of(payload: bytes) -> SystemDescription:
    """The description a station served; BadInput naming what is wrong with a malformed one."""
    try:
        table: Any = json.loads(payload)
        if not isinstance(table, dict) or not {"system", "robot", "site"} <= set(table):
            raise BadInput("a description is a JSON object of system, robot and site")
        return SystemDescription(
            str(table["system"]), read_table(RobotFile, table["robot"]), read_table(SiteFile, table["site"])
        )
    except (ValueError, ConfigError) as exc:  # JSON, or a table the typed reader refuses
        raise BadInput(f"a malformed description: {exc}") from None
