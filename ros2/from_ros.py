"""Back from ROS 2: what a ROS 2 node publishes in a station's place (the gateway), as abyss
messages: onboard's commands, telemetry and clouds, the vessel's map, and a real vehicle's
navigation and joints (its driver in the simulation's place, a hybrid run). Each: (ROS 2 message,
session) -> abyss message, or None when it leaves nothing to send yet; BadInput names what is
wrong with it."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from abyss.common.errors import BadInput
from abyss.common.geometry import rotation_of, wrap_rad, yaw_of
from abyss.interface.clouds import pack_cloud
from abyss.interface.messages import (
    MODES,
    ArmVelocityRef,
    JointState,
    Message,
    NavState,
    PointCloud,
    SceneUpdate,
    Telemetry,
    VelocityRef,
)
from abyss.ros2.msgs import (
    BASE_LINK,
    ROS,
    WORLD,
)
from abyss.ros2.sensing import octree_file
from abyss.ros2.session import Session

Parse = Callable[[Any, Session], Message | None]


def _frame(head: Any, allowed: str) -> None:
    if head.frame_id not in ("", allowed):
        raise BadInput(f"frame_id {head.frame_id!r}, expected {allowed!r}")


def _stamp_s(head: Any) -> float:
    """A header's stamp [s]: exactly the time `msgs.ros_time` was given, where that was on whole
    nanoseconds."""
    return (int(head.stamp.sec) * 10**9 + int(head.stamp.nanosec)) / 1e9


def _finite(what: str, values: Any) -> None:
    if not np.isfinite(np.asarray(values, dtype=np.float64)).all():
        raise BadInput(f"{what} not finite")


def odometry_in(msg: Any, session: Session) -> NavState:
    """A real vehicle's navigation as its driver fuses it: nav_msgs/Odometry in `world` with child
    `base_link` (`motion.odometry`'s frames: the pose in the world, the twist in the body). A fused
    navigation fixes every sample, so the fix's time (`usbl_time_s`) is the header's stamp, as is
    `sim_time_s`; the depth is -z and the DVL taken as locked, which Odometry cannot say."""
    _frame(msg.header, WORLD)
    if msg.child_frame_id not in ("", BASE_LINK):
        raise BadInput(f"child_frame_id {msg.child_frame_id!r}, expected {BASE_LINK!r} (the twist's frame)")
    p, q = msg.pose.pose.position, msg.pose.pose.orientation
    linear, angular = msg.twist.twist.linear, msg.twist.twist.angular
    position = np.array([p.x, p.y, p.z], dtype=np.float64)
    orientation = np.array([q.w, q.x, q.y, q.z], dtype=np.float64)
    _finite("the pose is", [*position, *orientation])
    _finite("the twist is", [linear.x, linear.y, linear.z, angular.x, angular.y, angular.z])
    norm = float(np.linalg.norm(orientation))
    if abs(norm - 1.0) > 1e-3:
        raise BadInput(f"the pose's orientation is not a unit quaternion (norm {norm:.4f})")
    stamp_s = _stamp_s(msg.header)
    return NavState(
        position,
        orientation,
        np.array([linear.x, linear.y, linear.z]),
        np.array([angular.x, angular.y, angular.z]),
        stamp_s,
        usbl_time_s=stamp_s,
        depth_m=float(-p.z),
        dvl_valid=True,
    )


def joint_state_in(msg: Any, session: Session) -> JointState:
    """The arm's joints by their names (the robot's, in any order) and the gripper's opening: its
    finger joints' positions summed (as the simulation defines it; `motion.joint_state` puts each
    finger at its share), within [0, 1] m. Velocities where the message has them, else 0 (as for
    a finger's NaN: not measured). Other joints are ignored; the effort does not cross (the
    gripper's force is 0)."""
    robot = session.robot
    names = [str(name) for name in msg.name]
    positions = np.asarray(msg.position, dtype=np.float64)
    velocities = np.asarray(msg.velocity, dtype=np.float64)
    if len(positions) != len(names) or len(velocities) not in (0, len(names)):
        raise BadInput(f"{len(names)} names, {len(positions)} positions and {len(velocities)} velocities")
    index = {name: i for i, name in enumerate(names)}
    missing = [name for name in (*robot.arm_joints, *robot.gripper_joints) if name not in index]
    if missing:
        raise BadInput(
            f"no joint {', '.join(missing)} in the message (it names {', '.join(names) or 'none'})"
        )
    arm = [index[name] for name in robot.arm_joints]
    fingers = [index[name] for name in robot.gripper_joints]
    _finite("the joints' positions are", positions[arm + fingers])
    speeds = (
        np.where(np.isnan(velocities[arm]), 0.0, velocities[arm]) if len(velocities) else np.zeros(len(arm))
    )
    return JointState(
        positions[arm],
        speeds,
        float(np.clip(positions[fingers].sum(), 0.0, 1.0)),
        _stamp_s(msg.header),
    )


def twist_in(msg: Any, session: Session) -> VelocityRef:
    """The vehicle's velocity reference in base_link: linear x, y, z and the yaw rate (angular z);
    the vehicle is passively stable in roll and pitch, whose rates are not commanded."""
    _frame(msg.header, BASE_LINK)
    linear, angular = msg.twist.linear, msg.twist.angular
    return VelocityRef(np.array([linear.x, linear.y, linear.z]), float(angular.z))


def joint_velocities_in(msg: Any, session: Session) -> ArmVelocityRef:
    data = np.asarray(msg.data, dtype=np.float64)
    joints = len(session.robot.arm_joints)
    if data.shape != (joints + 1,):
        raise BadInput(f"{len(data)} values, expected {joints + 1} ({session.arm_command_label})")
    return ArmVelocityRef(data[:joints], float(data[joints]))


def ee_pose_in(msg: Any, session: Session) -> None:
    """Where the node sees the tool, in the world: kept for the telemetry."""
    _frame(msg.header, WORLD)
    p, q = msg.pose.position, msg.pose.orientation
    orientation = np.array([q.w, q.x, q.y, q.z])
    if not np.isfinite([p.x, p.y, p.z]).all() or abs(np.linalg.norm(orientation) - 1.0) > 1e-3:
        raise BadInput("the pose's position is not finite or its orientation not a unit quaternion")
    session.ee_pose = np.array([p.x, p.y, p.z]), orientation
    return None


CLOUD_SCALE_M = 0.002  # the quantisation of a node's cloud on abyss's wire (onboard.cloud_scale_m's default)


def point_cloud_in(msg: Any, session: Session) -> PointCloud | None:
    """A cloud in the world frame: float32 x, y, z and, where present, PCL's packed `rgb`
    (float32 or uint32 0x00RRGGBB; grey without), NaN points dropped; its rays began where the
    vehicle is (the navigation handed over). None before navigation."""
    _frame(msg.header, WORLD)
    fields = {f.name: f for f in msg.fields}
    float32, uint32 = ROS["sensor_msgs/msg/PointField"].FLOAT32, ROS["sensor_msgs/msg/PointField"].UINT32
    for name in ("x", "y", "z"):
        if name not in fields or fields[name].datatype != float32:
            raise BadInput(f"no float32 field {name!r}: fields {sorted(fields)}")
    count, step = int(msg.width) * int(msg.height), int(msg.point_step)
    if msg.is_bigendian or step < 12 or len(msg.data) < count * step:
        raise BadInput(f"{len(msg.data)} bytes for {count} points of {step} bytes (little-endian)")
    rows = np.asarray(msg.data, np.uint8)[: count * step].reshape(count, step)

    def column(name: str, dtype: str) -> np.ndarray:
        offset = int(fields[name].offset)
        if offset + 4 > step:
            raise BadInput(f"field {name!r} at offset {offset} lies past the point's {step} bytes")
        return rows[:, offset : offset + 4].copy().view(dtype).ravel()

    points_m = np.column_stack([column(name, "<f4") for name in ("x", "y", "z")]).astype(np.float64)
    colors = np.full((count, 3), 128, np.uint8)
    if "rgb" in fields and fields["rgb"].datatype in (float32, uint32):
        rgb = column("rgb", "<u4")
        colors = np.column_stack([(rgb >> 16) & 0xFF, (rgb >> 8) & 0xFF, rgb & 0xFF]).astype(np.uint8)
    finite = np.isfinite(points_m).all(axis=1)
    if session.nav is None:
        return None
    stamp = msg.header.stamp
    return pack_cloud(
        "stereo",
        points_m[finite],
        colors[finite],
        session.nav.position_m_world,
        CLOUD_SCALE_M,
        stamp.sec + stamp.nanosec * 1e-9,
    )


def octomap_in(msg: Any, session: Session) -> SceneUpdate:
    """A node's whole map (binary, in the world frame) as a snapshot of it (no colours: the
    binary form has none), for the vessel's scene model to adopt (`SceneModel.adopt`)."""
    _frame(msg.header, WORLD)
    if not msg.binary or msg.id != "OcTree":
        kind = "binary" if msg.binary else "full"
        raise BadInput(f"a {kind} {msg.id!r} map; the scene takes a binary OcTree")
    stamp = msg.header.stamp
    return SceneUpdate(
        kind="snapshot",
        scene_seq=0,
        resolution_m=float(msg.resolution),
        octree=octree_file(np.asarray(msg.data, np.int8).tobytes(), float(msg.resolution)),
        colors=np.zeros((0, 3), np.uint8),
        sim_time_s=stamp.sec + stamp.nanosec * 1e-9,
    )


TELEMETRY_VALUES = {  # the key-values read from the node's first DiagnosticStatus; the rest are ignored
    "mode": f"the vehicle's: {', '.join(MODES)} (default idle)",
    "waypoint": "the index of the waypoint flown to, counted from 0, as `i` or `i/n` (default 0)",
    "arm_mode": f"the arm's: {', '.join(MODES)} (default idle)",
    "failsafe": "why the vehicle and the arm hold; empty when they do not (default)",
    "failsafe_events": "how many times the failsafe came on (default 0)",
}


def telemetry_in(msg: Any, session: Session) -> Telemetry | None:
    """The controllers' state as the node states it in the values of TELEMETRY_VALUES, the rest
    from what the gateway handed the node: the position and heading from the navigation, the
    errors against the goals (and the tool's pose, /ee_pose, where the node publishes it), the
    command ids of the goals in force, the joints, the operator mode, the attitude and velocity.
    The effort stays zeros: the node does not state it. None before navigation."""
    if not msg.status:
        raise BadInput("no DiagnosticStatus in the array")
    values = {kv.key: kv.value for kv in msg.status[0].values}
    waypoint = values.get("waypoint", "0").partition("/")[0]
    if not waypoint.isdigit():
        raise BadInput(f"waypoint {values['waypoint']!r} is not `i` or `i/n`")
    events = values.get("failsafe_events", "0")
    if not events.isdigit():
        raise BadInput(f"failsafe_events {events!r} is not a count")
    nav = session.nav
    if nav is None:
        return None
    position, yaw = nav.position_m_world, yaw_of(nav.orientation_wxyz_world)
    index, error_m, heading_rad, command_id, total = int(waypoint), np.zeros(3), 0.0, -1, 0
    if session.waypoints is not None:
        rows = session.waypoints.waypoints
        command_id, total = session.waypoints.command_id, len(rows)
        target = rows[min(index, total - 1)]
        error_m, heading_rad = target[:3] - position, wrap_rad(float(target[3]) - yaw)
    ee_m, ee_wxyz = session.ee_pose or (np.zeros(3), np.array([1.0, 0.0, 0.0, 0.0]))
    ee_error_m, ee_error_rad, arm_command_id = np.zeros(3), 0.0, -1
    if session.arm_goal is not None:
        goal = session.arm_goal
        arm_command_id = goal.command_id
        if session.ee_pose is not None:
            ee_error_m = goal.position_m_world - ee_m
            relative = rotation_of(ee_wxyz).T @ rotation_of(goal.orientation_wxyz_world)
            ee_error_rad = float(np.arccos(np.clip((np.trace(relative) - 1) / 2, -1.0, 1.0)))
    joints = (
        session.joints.positions_rad
        if session.joints is not None
        else np.zeros(len(session.robot.arm_joints))
    )
    return Telemetry(
        position_m_world=position,
        yaw_rad=yaw,
        mode=values.get("mode", "idle"),
        command_id=command_id,
        waypoint_index=min(index, total),
        waypoints_total=total,
        position_error_m_world=error_m,
        heading_error_rad=heading_rad,
        arm_mode=values.get("arm_mode", "idle"),
        arm_command_id=arm_command_id,
        ee_position_error_m_world=ee_error_m,
        ee_orientation_error_rad=ee_error_rad,
        ee_position_m_world=ee_m,
        ee_orientation_wxyz_world=ee_wxyz,
        arm_positions_rad=joints,
        failsafe=values.get("failsafe", ""),
        failsafe_events=int(events),
        sim_time_s=session.sim_time_s,
        operator_mode=session.operator_mode,
        boot_id=session.boot_id,
        orientation_wxyz_world=nav.orientation_wxyz_world,
        velocity_mps_body=nav.velocity_mps_body,
    )
