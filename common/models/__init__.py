"""The shipped packages (`robots/`: common.robot; `sites/`: common.site) and what holds for any
world composed of them: which camera sets feed stereo, and where a run starts. What a robot names
(its joints, thrusters, cameras, sensors) is its package's, and the panel is its site's; nothing
here names a part of either."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from abyss.common.robot import Robot

MODELS_DIR = Path(__file__).parent


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
