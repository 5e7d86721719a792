"""What the conversions keep between the messages of one stream of them (an export, a gateway)."""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from abyss.common.geometry import quat_wxyz_of
from abyss.description.robot import Robot, robot_mjcf
from abyss.interface.messages import (
    ArmGoal,
    JointState,
    Message,
    NavState,
    OperatorMode,
    Waypoints,
    new_id,
)
from abyss.ros2.msgs import (
    BASE_LINK,
    Floats,
)
from abyss.scene.receiver import SceneReceiver


# -- what conversions keep between messages -----------------------------------------------
class ArmFrames:
    """The arm's frames relative to their parents for a joint state, as robot_state_publisher
    gives a URDF's: Pinocchio's forward kinematics on the robot's model, the vehicle at the origin.
    The fingers each open by half the gripper's opening."""

    def __init__(self, robot: Robot) -> None:
        self.robot = robot
        self.model = pin.buildModelFromMJCF(str(robot_mjcf(robot)))
        self.data = self.model.createData()
        self.q_index = {
            name: self.model.joints[self.model.getJointId(name)].idx_q
            for name in (*robot.arm_joints, *robot.gripper_joints)
        }
        frames = self.model.frames
        self.vehicle = self.model.getFrameId(robot.base, pin.FrameType.BODY)
        # (parent body, child, moving): each body on the vehicle, the tool point and the navigation
        # sensors' sites (the cameras' and the sonar's frames come from their messages' mountings)
        self.links: list[tuple[int, int, bool]] = []
        sites = {robot.end_effector_site, *robot.nav_sensor_names}
        for i, frame in enumerate(frames):
            if (frame.type == pin.FrameType.BODY and i != self.vehicle) or (
                frame.type == pin.FrameType.OP_FRAME and frame.name in sites
            ):
                parent = frame.parentFrame
                while frames[parent].type != pin.FrameType.BODY:  # past the joint's own frame
                    parent = frames[parent].parentFrame
                self.links.append((parent, i, frame.parentJoint != frames[parent].parentJoint))

    def name(self, frame: int) -> str:
        return BASE_LINK if frame == self.vehicle else str(self.model.frames[frame].name)

    def transforms(
        self, positions_rad: Floats, gripper_opening_m: float, moving: bool
    ) -> list[tuple[str, str, np.ndarray, np.ndarray]]:
        """(parent, child, translation [m], rotation w, x, y, z) of the moving links, or of the
        fixed ones."""
        q = pin.neutral(self.model)
        for name, value in zip(self.robot.arm_joints, positions_rad, strict=True):
            q[self.q_index[name]] = value
        for name in self.robot.gripper_joints:
            q[self.q_index[name]] = gripper_opening_m / 2
        pin.framesForwardKinematics(self.model, self.data, q)
        chosen = []
        for parent, child, is_moving in self.links:
            if is_moving == moving:
                relative = self.data.oMf[parent].actInv(self.data.oMf[child])
                chosen.append(
                    (
                        self.name(parent),
                        self.name(child),
                        np.array(relative.translation),
                        quat_wxyz_of(relative.rotation),
                    )
                )
        return chosen


class Session:
    """What the conversions keep between the messages of one stream of them (an export, a
    gateway): the arm's kinematics, and shore's copy of the scene, onto which each update (a
    snapshot or a delta) is applied, so that every Octomap message is the whole map, as ROS
    consumers take it. A gateway's conversions back to abyss read what it last handed the ROS 2
    node: the navigation, the joints, the goals (with their command ids) and the operator mode."""

    def __init__(self, robot: Robot) -> None:
        """`robot`: the robot the stream is of (description.robot): its names and kinematics."""
        self.robot = robot
        self.arm = ArmFrames(robot)
        self.scene = SceneReceiver()
        self.nav: NavState | None = None
        self.joints: JointState | None = None
        self.waypoints: Waypoints | None = None
        self.arm_goal: ArmGoal | None = None
        self.operator_mode = "auto"
        self.ee_pose: tuple[np.ndarray, np.ndarray] | None = None  # the node's: position, w x y z [world]
        self.boot_id = new_id()
        self.sim_time_s = 0.0  # the latest simulated time handed over

    @property
    def arm_command_label(self) -> str:
        """The velocity command's layout label: the arm's joints in model order, then the gripper."""
        return "velocity: " + ", ".join((*self.robot.arm_joints, "gripper_opening"))

    def handed(self, message: Message) -> None:
        """Remember a message the ROS 2 node was given."""
        self.sim_time_s = max(self.sim_time_s, float(getattr(message, "sim_time_s", 0.0)))
        if isinstance(message, NavState):
            self.nav = message
        elif isinstance(message, JointState):
            self.joints = message
        elif isinstance(message, Waypoints):
            self.waypoints = message
        elif isinstance(message, ArmGoal):
            self.arm_goal = message
        elif isinstance(message, OperatorMode):
            self.operator_mode = message.mode
