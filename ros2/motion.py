"""Conversions of the vehicle's and the arm's messages to ROS 2: navigation, joints and /tf,
velocity references, goals, the operator mode, /tf_static. Each: (abyss message, header of the
topic's frame, session) -> ROS 2 message or None."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from abyss.interface.messages import (
    ArmGoal,
    ArmVelocityRef,
    Image,
    JointState,
    NavState,
    OperatorMode,
    SonarImage,
    Telemetry,
    VelocityRef,
    Waypoints,
)
from abyss.ros2.msgs import (
    BASE_LINK,
    ROS,
    WORLD,
    Floats,
    floats,
    optical_frame,
    pose_msg,
    ros_time,
    tf_msg,
    transform_msg,
    vector_msg,
    yaw_wxyz,
)
from abyss.ros2.session import Session


def odometry(nav: NavState, head: Any, session: Session) -> Any:
    """On `simulation/nav` the pose is the latest USBL fix with the IMU's attitude, the twist the
    DVL's and the gyro's. Odometry has no counterpart for the fix's measurement time
    (`usbl_time_s`), the pressure sensor's depth (`depth_m`) nor the DVL's bottom lock
    (`dvl_valid`): they do not cross to ROS 2."""
    zeros = np.zeros(36)  # covariance unknown
    return ROS["nav_msgs/msg/Odometry"](
        header=head,
        child_frame_id=BASE_LINK,
        pose=ROS["geometry_msgs/msg/PoseWithCovariance"](
            pose=pose_msg(nav.position_m_world, nav.orientation_wxyz_world), covariance=zeros
        ),
        twist=ROS["geometry_msgs/msg/TwistWithCovariance"](
            twist=ROS["geometry_msgs/msg/Twist"](
                linear=vector_msg(nav.velocity_mps_body), angular=vector_msg(nav.angular_velocity_radps_body)
            ),
            covariance=zeros,
        ),
    )


def vehicle_tf(nav: NavState, head: Any, session: Session) -> Any:
    return tf_msg(
        [transform_msg(head.stamp, WORLD, BASE_LINK, nav.position_m_world, nav.orientation_wxyz_world)]
    )


def _joint_state(head: Any, names: list[str], positions: Floats, velocities: Floats) -> Any:
    return ROS["sensor_msgs/msg/JointState"](
        header=head,
        name=names,
        position=floats(positions),
        velocity=floats(velocities),
        effort=floats([]),
    )


def joint_state(joints: JointState, head: Any, session: Session) -> Any:
    """The arm's joints and each finger at half the gripper's opening; the fingers' velocities are
    not measured (NaN)."""
    robot = session.robot
    fingers = len(robot.gripper_joints)
    finger_m = joints.gripper_opening_m / fingers
    return _joint_state(
        head,
        [*robot.arm_joints, *robot.gripper_joints],
        [*joints.positions_rad, *[finger_m] * fingers],
        [*joints.velocities_radps, *[math.nan] * fingers],
    )


def arm_tf(joints: JointState, head: Any, session: Session) -> Any:
    links = session.arm.transforms(joints.positions_rad, joints.gripper_opening_m, moving=True)
    return tf_msg([transform_msg(head.stamp, *link) for link in links])


def joint_velocities(ref: ArmVelocityRef, head: Any, session: Session) -> Any:
    """A velocity command as ros2_control's forward velocity controller takes it: a
    Float64MultiArray of the arm's joints' velocities [rad/s] in model order, then the gripper's
    opening speed [m/s]."""
    size = len(session.robot.arm_joints) + 1
    dim = ROS["std_msgs/msg/MultiArrayDimension"](label=session.arm_command_label, size=size, stride=size)
    return ROS["std_msgs/msg/Float64MultiArray"](
        layout=ROS["std_msgs/msg/MultiArrayLayout"](dim=[dim], data_offset=0),
        data=floats([*ref.joint_velocities_radps, ref.gripper_velocity_mps]),
    )


def twist(ref: VelocityRef, head: Any, session: Session) -> Any:
    """The vehicle's velocity reference in base_link; the yaw rate about its z axis."""
    return ROS["geometry_msgs/msg/TwistStamped"](
        header=head,
        twist=ROS["geometry_msgs/msg/Twist"](
            linear=vector_msg(ref.linear_mps_body), angular=vector_msg((0.0, 0.0, ref.yaw_rate_radps))
        ),
    )


def path(waypoints: Waypoints, head: Any, session: Session) -> Any:
    """Each waypoint a pose: x, y, z and the heading as a rotation about z."""
    return ROS["nav_msgs/msg/Path"](
        header=head,
        poses=[
            ROS["geometry_msgs/msg/PoseStamped"](header=head, pose=pose_msg(row[:3], yaw_wxyz(float(row[3]))))
            for row in waypoints.waypoints
        ],
    )


def goal_pose(goal: ArmGoal, head: Any, session: Session) -> Any:
    return ROS["geometry_msgs/msg/PoseStamped"](
        header=head, pose=pose_msg(goal.position_m_world, goal.orientation_wxyz_world)
    )


def end_effector_pose(telemetry: Telemetry, head: Any, session: Session) -> Any:
    """Where onboard sees the tool, in the world."""
    return ROS["geometry_msgs/msg/PoseStamped"](
        header=head, pose=pose_msg(telemetry.ee_position_m_world, telemetry.ee_orientation_wxyz_world)
    )


def operator_mode(mode: OperatorMode, head: Any, session: Session) -> Any:
    return ROS["std_msgs/msg/String"](data=mode.mode)


def static_tf(session: Session, stamp_s: float, mounts: dict[str, np.ndarray]) -> Any:
    """/tf_static: the arm's fixed links, and each sensor's frame on the vehicle from its mounting
    (`mounts`: a frame's name, a camera's optical frame or the sonar's own, to its pose as the
    simulation sends it: x, y, z, w, x, y, z in base_link; `sensor_mounts`)."""
    stamp = ros_time(stamp_s)
    arm = [
        transform_msg(stamp, parent, child, translation, rotation)
        for parent, child, translation, rotation in session.arm.transforms(
            np.zeros(len(session.robot.arm_joints)), 0.0, moving=False
        )
    ]
    sensors = [
        transform_msg(stamp, BASE_LINK, frame, pose[:3], pose[3:]) for frame, pose in sorted(mounts.items())
    ]
    return tf_msg(arm + sensors)


def sensor_mount(message: Any) -> tuple[str, np.ndarray] | None:
    """A sensor's frame and its pose on the vehicle from a message the simulation sent (a camera's
    Image: its optical frame; the sonar's SonarImage: the frame named as the sonar, which its
    images' headers name); None for another message or one posed elsewhere."""
    if isinstance(message, Image) and message.pose_frame == "vehicle":
        return optical_frame(message.camera), message.pose_camera
    if isinstance(message, SonarImage) and message.pose_frame == "vehicle":
        return message.sonar, message.pose_sonar
    return None
