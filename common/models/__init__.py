"""The world description: `robot.xml` (the vehicle and its arm, read by MuJoCo and Pinocchio)
included by `world.xml` (the panel and the seabed too, read by MuJoCo), and the names both use."""

from pathlib import Path

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
