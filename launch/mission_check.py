"""What a run's packages and mission must agree on, checked before any station starts: each part
the mission's interventions work lies within the robot's arm's reach from where the vehicle holds
(its last waypoint), as onboard judges it (onboard.commands.CommandGate.check_arm) once the
waypoints are flown. A mission that cannot be worked fails at start, naming the field, rather
than a minute into the run."""

from __future__ import annotations

import numpy as np

from abyss.common.errors import ConfigError
from abyss.config import Config, robot_of, site_of


def check_reach(config: Config) -> None:
    """ConfigError naming `mission.interventions[i]` for a part whose grasp (at rest) lies beyond
    the arm's reach from its shoulder where the vehicle holds at the last waypoint."""
    if not config.mission.interventions:
        return
    from abyss.stations.onboard.arm_control import ArmKinematics  # Pinocchio's, on first use
    from abyss.stations.onboard.commands import shoulder_distance_m

    robot, panel = robot_of(config), site_of(config).panel
    shoulder_m_vehicle, reach_m = ArmKinematics(robot).reach()
    last = np.asarray(config.mission.waypoints[-1])
    x, y, z, _ = last
    for i, (part, _) in enumerate(config.mission.interventions):
        pivot, _, grasp = panel.part_geometry(part)
        grasp_m_world = np.add(panel.position_m_world, pivot + grasp)  # the panel's frame: the world's, moved
        distance_m = shoulder_distance_m(shoulder_m_vehicle, last, grasp_m_world)
        if distance_m > reach_m:
            raise ConfigError(
                f"mission.interventions[{i}]",
                f"{part}'s grasp is {distance_m:.2f} m from the arm's shoulder where the vehicle holds "
                f"(the last waypoint, {x:.2f}, {y:.2f}, {z:.2f} m); {robot.name}'s arm reaches "
                f"{reach_m:.2f} m: end the waypoints nearer the part, or fly a robot or site that reaches it",
            )
