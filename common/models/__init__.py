"""The world description: `robot.xml` (the vehicle and its arm, read by MuJoCo and Pinocchio)
included by `world.xml` (the panel and the seabed too, read by MuJoCo), and the names both use."""

from pathlib import Path
from typing import Any

import numpy as np

MODELS_DIR = Path(__file__).parent
WORLD_FILE = MODELS_DIR / "world.xml"
ROBOT_FILE = MODELS_DIR / "robot.xml"
VEHICLE_FILE = MODELS_DIR / "robot.toml"  # robot.xml's vehicle: its marine model and thrusters
SEABED_CLOUD_FILE = MODELS_DIR / "seabed_cloud.ply"
ARM_JOINTS = ("shoulder_yaw", "shoulder_pitch", "elbow", "wrist_roll", "wrist_pitch", "tool_roll")
# the arm folded under the bow, clear of the hull and the seabed, end-effector level [rad]
ARM_STOWED_RAD = (0.0, 1.3, -2.4, 0.0, 1.1, 0.0)
GRIPPER_JOINTS = ("finger_left", "finger_right")
THRUSTERS = ("thr_fl", "thr_fr", "thr_rl", "thr_rr", "thr_vl", "thr_vr")
CAMERAS = ("cam_left", "cam_right", "cam_depth")
NAV_SENSORS = ("usbl", "depth", "dvl", "imu")  # navigation sensors, as faults name them
END_EFFECTOR_SITE = "ee"


def stereo_set(sim_time_s: float, camera_rate_hz: float, stereo_every: int) -> bool:
    """Whether the frame set taken at `sim_time_s` [s] is one the stereo matcher uses: every
    `stereo_every`-th by the set's index on the simulated clock (sets at `camera_rate_hz`, the
    index `round(t * rate)`, so a set taken a little early or late keeps its index), from the set
    at index 1, the first onboard can place (at 0 s it has no navigation estimate yet). The
    simulation renders cam_right for these sets alone, and onboard waits for it on these alone."""
    return round(sim_time_s * camera_rate_hz) % stereo_every == 1 % stereo_every


def place_at_start(
    model: Any, qpos: Any, position_m_world: tuple[float, float, float], yaw_rad: float
) -> None:
    """A world's first positions in `qpos` (a MuJoCo model's of world.xml): the vehicle at
    `position_m_world` [m] heading `yaw_rad` [rad] about the world's z, level, the arm stowed."""
    p = model.joint("vehicle").qposadr[0]
    qpos[p : p + 3] = position_m_world
    qpos[p + 3 : p + 7] = [np.cos(yaw_rad / 2), 0.0, 0.0, np.sin(yaw_rad / 2)]
    for name, angle_rad in zip(ARM_JOINTS, ARM_STOWED_RAD, strict=True):
        qpos[model.joint(name).qposadr[0]] = angle_rad
