"""The one world description, `world.xml`, and the names both MuJoCo and Pinocchio use."""

from pathlib import Path

WORLD_FILE = Path(__file__).with_name("world.xml")
ARM_JOINTS = ("shoulder_yaw", "shoulder_pitch", "elbow", "wrist_roll", "wrist_pitch", "tool_roll")
GRIPPER_JOINTS = ("finger_left", "finger_right")
THRUSTERS = ("thr_fl", "thr_fr", "thr_rl", "thr_rr", "thr_vl", "thr_vr")
CAMERAS = ("cam_left", "cam_right", "cam_depth")
END_EFFECTOR_SITE = "ee"
