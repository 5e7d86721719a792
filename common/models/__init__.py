"""The world description: the site, `world.xml` (the valve panel and the seabed, read by MuJoCo),
which includes the shipped robot package's model (`robots/workclass/robot.xml`). What a robot
names (its joints, thrusters, cameras, sensors) is its package's, read by common.robot; nothing
here names a part of it."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from abyss.common.errors import ConfigError

if TYPE_CHECKING:
    from abyss.common.robot import Robot

MODELS_DIR = Path(__file__).parent
# the site: the panel and the seabed, with the shipped robot included (a later slice composes a
# site with any robot package)
SITE_WORLD_FILE = MODELS_DIR / "world.xml"
SEABED_CLOUD_FILE = MODELS_DIR / "seabed_cloud.ply"


def world_file(robot: Robot) -> Path:
    """The world MuJoCo loads to fly `robot`: the site with the robot in it. Only the shipped
    robot has one yet (the site includes its model); another is refused, naming the field."""
    if not robot.shipped:
        raise ConfigError(
            "simulation.robot",
            f"{robot.directory}: the site's world includes the shipped robot alone; composing a world "
            "with another robot package is not there yet (its kinematics and names work, its physics not)",
        )
    return SITE_WORLD_FILE


def stereo_set(sim_time_s: float, camera_rate_hz: float, stereo_every: int) -> bool:
    """Whether the frame set taken at `sim_time_s` [s] is one the stereo matcher uses: every
    `stereo_every`-th by the set's index on the simulated clock (sets at `camera_rate_hz`, the
    index `round(t * rate)`, so a set taken a little early or late keeps its index), from the set
    at index 1, the first onboard can place (at 0 s it has no navigation estimate yet). The
    simulation renders the stereo pair's right camera for these sets alone, and onboard waits for
    it on these alone."""
    return round(sim_time_s * camera_rate_hz) % stereo_every == 1 % stereo_every


def place_at_start(
    model: Any, qpos: Any, robot: Robot, position_m_world: tuple[float, float, float], yaw_rad: float
) -> None:
    """A world's first positions in `qpos` (a MuJoCo model's of the world with `robot` in it): the
    vehicle at `position_m_world` [m] heading `yaw_rad` [rad] about the world's z, level, the arm
    stowed."""
    p = model.joint(robot.base).qposadr[0]
    qpos[p : p + 3] = position_m_world
    qpos[p + 3 : p + 7] = [np.cos(yaw_rad / 2), 0.0, 0.0, np.sin(yaw_rad / 2)]
    for name, angle_rad in zip(robot.arm_joints, robot.stowed_rad, strict=True):
        qpos[model.joint(name).qposadr[0]] = angle_rad
