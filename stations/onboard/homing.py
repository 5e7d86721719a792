"""A whole-body vehicle flies with its arm stowed: before it moves between waypoints (the
mission's, or those handed again to a restarted onboard) and once its intervention has backed off
(done or failed) to fly back onto its mark, the gripper opens, the arm stows, the vehicle held
still meanwhile, and only then does the vehicle fly, by its own controller, the stowed arm tucked
in as it came. The arm's solver moves the vehicle with the tool (the BlueROV2 ended 0.29 m off its
mark); held on the part's pre-grasp pose in the world, the tool kept it there; carried back
unstowed, it swept into the lever it had just thrown (pushed from its stop at -30 to -25.7
degrees), and a restarted onboard's vehicle, flying back with the fingers still about the valve's
handle, turned the valve to -45 degrees. The stowed arm is clear wherever the vehicle flies: it
flew the waypoints so."""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from abyss.common.geometry import rotation_of
from abyss.stations.onboard.arm_control import ArmKinematics, PoseReference
from abyss.stations.onboard.intervention import Grip

STOW_GAIN_PER_S = 2.0  # each joint's speed towards its stowed angle, per radian off [1/s]
STOWED_RAD = 0.02  # every joint this close to its stowed angle: stowed, and the vehicle goes


class Homing:
    """The gripper opened, the arm stowed, then the flight (see the module): `stowed` once there."""

    def __init__(self, stowed_rad: tuple[float, ...], max_joint_speed_radps: float, grip: Grip) -> None:
        self.stowed_rad = np.asarray(stowed_rad, dtype=float)
        self.max_joint_speed_radps, self.grip = max_joint_speed_radps, grip
        self.carried: pin.SE3 | None = None  # the stowed tool's pose on the vehicle
        self.opened = self.stowed = False

    def reference(
        self, kinematics: ArmKinematics, position_m_world: np.ndarray, orientation_wxyz_world: np.ndarray
    ) -> PoseReference:
        """The stowed tool's pose in the world, the vehicle where it is now: what the tool's
        errors are told against."""
        vehicle = pin.SE3(rotation_of(orientation_wxyz_world), np.asarray(position_m_world, dtype=float))
        if self.carried is None:
            kinematics.update(position_m_world, orientation_wxyz_world, self.stowed_rad)
            self.carried = vehicle.actInv(kinematics.pose(kinematics.ee))
        pose = vehicle * self.carried
        return PoseReference(pose.translation.copy(), pose.rotation.copy())

    def step(self, arm_rad: np.ndarray, opening_m: float) -> tuple[np.ndarray, float]:
        """The joints' speeds [rad/s] and the gripper's [m/s]: an arm not stowed opens its
        gripper (it lets go of whatever it holds), then stows, within the speed limit; each, once
        done, stays done (a stowed arm flies with its gripper as it is)."""
        error_rad = self.stowed_rad - np.asarray(arm_rad)
        self.stowed = self.stowed or float(np.abs(error_rad).max()) < STOWED_RAD
        self.opened = self.opened or self.stowed or self.grip.opened(opening_m)
        if not self.opened:
            return np.zeros(len(self.stowed_rad)), self.grip.open_mps(opening_m)
        limit = self.max_joint_speed_radps
        return np.clip(STOW_GAIN_PER_S * error_rad, -limit, limit), 0.0
