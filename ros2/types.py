"""The one table from abyss messages to ROS 2: per key its ROS 2 topics, types, frames and QoS,
and the conversion of each message to a message of the standard type (rosbags' typestore, ROS 2
Jazzy, plus `octomap_msgs/Octomap`), and back for what a ROS 2 node publishes in a station's place.
The MCAP export (`ros2.mcap`) writes by it; the ROS 2 gateway (`ros2.gateway`) publishes and
subscribes by it.

Frames (REP 103, REP 105):
- `world`: abyss's world frame, z up, x towards the panel, taken as ENU with x east and y north.
  It is REP 105's `map` (a global fix, USBL, and no `odom`): the navigation publishes
  world -> base_link directly. No axis flips.
- `base_link`: the vehicle's body frame, abyss's FLU (x forward, y left, z up; robot.xml), its
  origin the hull's centre. NavState's velocities are in it, as Odometry's twist must be.
- the arm: one frame per MJCF body (`arm_base`, `arm_link1` .. `arm_link6`, `finger_left`,
  `finger_right`) and `ee` (the tool point), each relative to its parent body as
  robot_state_publisher would give them: the fixed ones in /tf_static, the moving ones in /tf
  from each JointState (forward kinematics on Pinocchio and the shared robot.xml).
- `<camera>_optical_frame`: z forward, x right, y down (REP 103's optical frames), which are
  OpenCV's axes, in which abyss states every camera pose: the simulation's mounting
  (`Image.pose_camera` in the vehicle frame) is base_link -> `<camera>_optical_frame` in
  /tf_static. Onboard's and the vessel's images (their pose in the world at the frame's time)
  are in the same optical frame, placed through /tf.

Header stamps are simulated time: `sim_time_s` where the message has it, else the sender's
stamp mapped to simulated time by the caller (`stamp_of`); /clock carries the simulated time.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
import pinocchio as pin
from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from abyss.common import keys
from abyss.common.clouds import pack_cloud, unpack_cloud
from abyss.common.config import ROS2_STATIONS
from abyss.common.errors import BadInput
from abyss.common.geometry import quat_wxyz_of, rotation_of, wrap_rad, yaw_of
from abyss.common.images import decode_image
from abyss.common.messages import (
    MODES,
    ArmGoal,
    ArmVelocityRef,
    CommandAck,
    Heartbeat,
    Image,
    JointState,
    LinkStats,
    Message,
    MissionStatus,
    NavState,
    OperatorMode,
    PerceptionStatus,
    PointCloud,
    RecognisedObjects,
    SceneUpdate,
    SimulationStatus,
    SonarImage,
    Telemetry,
    VelocityRef,
    Waypoints,
    new_id,
)
from abyss.common.models import ARM_JOINTS, END_EFFECTOR_SITE, GRIPPER_JOINTS, ROBOT_FILE
from abyss.common.scene import SceneReceiver

WORLD = "world"
BASE_LINK = "base_link"
TOPIC_PREFIX = "/abyss"  # /abyss/<station>/<topic>: the abyss key without abyss/<system>/

# octomap_msgs/msg/Octomap, as octomap_msgs defines it (not in rosbags' stores)
OCTOMAP_MSG = """\
std_msgs/Header header
bool binary
string id
float64 resolution
int8[] data
"""


def _typestore() -> Any:
    store = get_typestore(Stores.ROS2_JAZZY)
    store.register(get_types_from_msg(OCTOMAP_MSG, "octomap_msgs/msg/Octomap"))
    return store


TYPESTORE = _typestore()
_T = TYPESTORE.types


Floats = Sequence[float] | np.ndarray


def optical_frame(camera: str) -> str:
    return f"{camera}_optical_frame"


# -- QoS ------------------------------------------------------------------------------------
def _qos(reliability: QosReliability, depth: int, durability: QosDurability = QosDurability.VOLATILE) -> Qos:
    never = QosTime(0, 0)  # the defaults: no deadline, lifespan or lease
    return Qos(
        QosHistory.KEEP_LAST,
        depth,
        reliability,
        durability,
        never,
        never,
        QosLiveliness.AUTOMATIC,
        never,
        False,
    )


SENSOR_QOS = _qos(QosReliability.BEST_EFFORT, 5)  # rclcpp's SensorDataQoS: a best-effort abyss key
RELIABLE_QOS = _qos(QosReliability.RELIABLE, 10)  # the default QoS: a reliable abyss key
TF_QOS = _qos(QosReliability.RELIABLE, 100)  # tf2's broadcaster
TF_STATIC_QOS = _qos(QosReliability.RELIABLE, 1, QosDurability.TRANSIENT_LOCAL)  # tf2's static broadcaster
CLOCK_QOS = _qos(QosReliability.BEST_EFFORT, 1)  # rclcpp's ClockQoS


# -- building blocks ------------------------------------------------------------------------
def ros_time(stamp_s: float) -> Any:
    """builtin_interfaces/Time of a time [s] (simulated time: not before 0)."""
    sec, nanosec = divmod(max(0, round(stamp_s * 1e9)), 10**9)
    return _T["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec)


def header(stamp_s: float, frame_id: str) -> Any:
    return _T["std_msgs/msg/Header"](stamp=ros_time(stamp_s), frame_id=frame_id)


def _vector(xyz: Floats) -> Any:
    return _T["geometry_msgs/msg/Vector3"](x=float(xyz[0]), y=float(xyz[1]), z=float(xyz[2]))


def _quaternion(wxyz: Floats) -> Any:
    w, x, y, z = (float(v) for v in wxyz)
    return _T["geometry_msgs/msg/Quaternion"](x=x, y=y, z=z, w=w)  # ROS: x, y, z, w


def _pose(position: Floats, orientation_wxyz: Floats) -> Any:
    x, y, z = (float(v) for v in position)
    return _T["geometry_msgs/msg/Pose"](
        position=_T["geometry_msgs/msg/Point"](x=x, y=y, z=z), orientation=_quaternion(orientation_wxyz)
    )


def _yaw_wxyz(yaw_rad: float) -> tuple[float, float, float, float]:
    return math.cos(yaw_rad / 2), 0.0, 0.0, math.sin(yaw_rad / 2)


def _transform(stamp: Any, parent: str, child: str, translation: Floats, rotation_wxyz: Floats) -> Any:
    return _T["geometry_msgs/msg/TransformStamped"](
        header=_T["std_msgs/msg/Header"](stamp=stamp, frame_id=parent),
        child_frame_id=child,
        transform=_T["geometry_msgs/msg/Transform"](
            translation=_vector(translation), rotation=_quaternion(rotation_wxyz)
        ),
    )


def _tf(transforms: list[Any]) -> Any:
    return _T["tf2_msgs/msg/TFMessage"](transforms=transforms)


def _floats(values: Floats) -> np.ndarray:
    return np.asarray(values, dtype=np.float64)


def _diagnostics(head: Any, name: str, level: int, message: str, values: dict[str, object]) -> Any:
    """A DiagnosticArray of one status; `level`: DiagnosticStatus.OK, WARN, ERROR."""
    status = _T["diagnostic_msgs/msg/DiagnosticStatus"](
        level=level,
        name=name,
        message=message,
        hardware_id="abyss",
        values=[
            _T["diagnostic_msgs/msg/KeyValue"](key=k, value=f"{v:g}" if isinstance(v, float) else str(v))
            for k, v in values.items()
        ],
    )
    return _T["diagnostic_msgs/msg/DiagnosticArray"](header=head, status=[status])


OK, WARN, ERROR = 0, 1, 2  # diagnostic_msgs/DiagnosticStatus levels


# -- what conversions keep between messages -----------------------------------------------
class ArmFrames:
    """The arm's frames relative to their parents for a joint state, as robot_state_publisher
    gives a URDF's: Pinocchio's forward kinematics on robot.xml, the vehicle at the origin. The
    fingers each open by half the gripper's opening."""

    def __init__(self) -> None:
        self.model = pin.buildModelFromMJCF(str(ROBOT_FILE))
        self.data = self.model.createData()
        self.q_index = {
            name: self.model.joints[self.model.getJointId(name)].idx_q
            for name in (*ARM_JOINTS, *GRIPPER_JOINTS)
        }
        frames = self.model.frames
        self.vehicle = self.model.getFrameId("vehicle", pin.FrameType.BODY)
        # (parent body, child, moving): each body on the vehicle, and the tool point
        self.links: list[tuple[int, int, bool]] = []
        for i, frame in enumerate(frames):
            if (frame.type == pin.FrameType.BODY and i != self.vehicle) or frame.name == END_EFFECTOR_SITE:
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
        for name, value in zip(ARM_JOINTS, positions_rad, strict=True):
            q[self.q_index[name]] = value
        for name in GRIPPER_JOINTS:
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

    def __init__(self) -> None:
        self.arm = ArmFrames()
        self.scene = SceneReceiver()
        self.nav: NavState | None = None
        self.joints: JointState | None = None
        self.waypoints: Waypoints | None = None
        self.arm_goal: ArmGoal | None = None
        self.operator_mode = "auto"
        self.ee_pose: tuple[np.ndarray, np.ndarray] | None = None  # the node's: position, w x y z [world]
        self.boot_id = new_id()
        self.sim_time_s = 0.0  # the latest simulated time handed over

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


# -- the conversions: (abyss message, header of the topic's frame, session) -> ROS 2 message or None
def odometry(nav: NavState, head: Any, session: Session) -> Any:
    """On `simulation/nav` the pose is the latest USBL fix with the IMU's attitude, the twist the
    DVL's and the gyro's. Odometry has no counterpart for the fix's measurement time
    (`usbl_time_s`), the pressure sensor's depth (`depth_m`) nor the DVL's bottom lock
    (`dvl_valid`): they do not cross to ROS 2."""
    zeros = np.zeros(36)  # covariance unknown
    return _T["nav_msgs/msg/Odometry"](
        header=head,
        child_frame_id=BASE_LINK,
        pose=_T["geometry_msgs/msg/PoseWithCovariance"](
            pose=_pose(nav.position_m_world, nav.orientation_wxyz_world), covariance=zeros
        ),
        twist=_T["geometry_msgs/msg/TwistWithCovariance"](
            twist=_T["geometry_msgs/msg/Twist"](
                linear=_vector(nav.velocity_mps_body), angular=_vector(nav.angular_velocity_radps_body)
            ),
            covariance=zeros,
        ),
    )


def vehicle_tf(nav: NavState, head: Any, session: Session) -> Any:
    return _tf([_transform(head.stamp, WORLD, BASE_LINK, nav.position_m_world, nav.orientation_wxyz_world)])


def _joint_state(head: Any, positions: Floats, velocities: Floats) -> Any:
    return _T["sensor_msgs/msg/JointState"](
        header=head,
        name=[*ARM_JOINTS, *GRIPPER_JOINTS],
        position=_floats(positions),
        velocity=_floats(velocities),
        effort=_floats([]),
    )


def joint_state(joints: JointState, head: Any, session: Session) -> Any:
    """The arm's joints and each finger at half the gripper's opening; the fingers' velocities are
    not measured (NaN)."""
    finger_m = joints.gripper_opening_m / 2
    return _joint_state(
        head, [*joints.positions_rad, finger_m, finger_m], [*joints.velocities_radps, math.nan, math.nan]
    )


def arm_tf(joints: JointState, head: Any, session: Session) -> Any:
    links = session.arm.transforms(joints.positions_rad, joints.gripper_opening_m, moving=True)
    return _tf([_transform(head.stamp, *link) for link in links])


ARM_COMMAND_LABEL = "velocity: " + ", ".join((*ARM_JOINTS, "gripper_opening"))


def joint_velocities(ref: ArmVelocityRef, head: Any, session: Session) -> Any:
    """A velocity command as ros2_control's forward velocity controller takes it: a
    Float64MultiArray of the six joints' velocities [rad/s] in model order, then the gripper's
    opening speed [m/s]."""
    dim = _T["std_msgs/msg/MultiArrayDimension"](label=ARM_COMMAND_LABEL, size=7, stride=7)
    return _T["std_msgs/msg/Float64MultiArray"](
        layout=_T["std_msgs/msg/MultiArrayLayout"](dim=[dim], data_offset=0),
        data=_floats([*ref.joint_velocities_radps, ref.gripper_velocity_mps]),
    )


def twist(ref: VelocityRef, head: Any, session: Session) -> Any:
    """The vehicle's velocity reference in base_link; the yaw rate about its z axis."""
    return _T["geometry_msgs/msg/TwistStamped"](
        header=head,
        twist=_T["geometry_msgs/msg/Twist"](
            linear=_vector(ref.linear_mps_body), angular=_vector((0.0, 0.0, ref.yaw_rate_radps))
        ),
    )


def raw_image(image: Image, head: Any, session: Session) -> Any | None:
    """A colour frame as `rgb8` pixels (image_transport's raw base topic)."""
    if image.encoding != "jpeg":
        return None
    pixels = decode_image(image)
    return _T["sensor_msgs/msg/Image"](
        header=header_of(head, optical_frame(image.camera)),
        height=image.height_px,
        width=image.width_px,
        encoding="rgb8",
        is_bigendian=0,
        step=3 * image.width_px,
        data=np.ascontiguousarray(pixels).ravel(),
    )


def compressed_image(image: Image, head: Any, session: Session) -> Any | None:
    if image.encoding != "jpeg":
        return None
    return _T["sensor_msgs/msg/CompressedImage"](
        header=header_of(head, optical_frame(image.camera)),
        format="jpeg",
        data=np.frombuffer(image.data, np.uint8),
    )


def sonar_image(sonar: SonarImage, head: Any, session: Session) -> Any:
    """The polar image (rows range bins, columns beams port to starboard) as the sonar sent it,
    PNG or JPEG, in the sonar's own frame; its geometry is in the abyss message (marine_acoustic_msgs,
    which carries it, is in no message store rosbags has)."""
    return _T["sensor_msgs/msg/CompressedImage"](
        header=header_of(head, sonar.sonar),
        format="png" if sonar.encoding == "png8" else "jpeg",
        data=np.frombuffer(sonar.data, np.uint8),
    )


def depth_image(image: Image, head: Any, session: Session) -> Any | None:
    """Depth as REP 118's 16UC1 in millimetres: abyss's PNG counts, unchanged."""
    if image.encoding != "png16":
        return None
    depth_mm = cv2.imdecode(np.frombuffer(image.data, np.uint8), cv2.IMREAD_UNCHANGED)
    if depth_mm is None or depth_mm.dtype != np.uint16 or depth_mm.shape != (image.height_px, image.width_px):
        raise BadInput(
            f"{image.camera}: the depth PNG does not decode to "
            f"{image.width_px}x{image.height_px} 16-bit pixels"
        )
    return _T["sensor_msgs/msg/Image"](
        header=header_of(head, optical_frame(image.camera)),
        height=image.height_px,
        width=image.width_px,
        encoding="16UC1",
        is_bigendian=0,
        step=2 * image.width_px,
        data=np.ascontiguousarray(depth_mm, dtype="<u2").view(np.uint8).ravel(),
    )


def camera_info(image: Image, head: Any, session: Session) -> Any:
    """The pinhole intrinsics, no distortion (the rendered cameras have none)."""
    fx, fy, cx, cy = image.fx_px, image.fy_px, image.cx_px, image.cy_px
    return _T["sensor_msgs/msg/CameraInfo"](
        header=header_of(head, optical_frame(image.camera)),
        height=image.height_px,
        width=image.width_px,
        distortion_model="plumb_bob",
        d=np.zeros(5),
        k=_floats([fx, 0, cx, 0, fy, cy, 0, 0, 1]),
        r=_floats([1, 0, 0, 0, 1, 0, 0, 0, 1]),
        p=_floats([fx, 0, cx, 0, 0, fy, cy, 0, 0, 0, 1, 0]),
        binning_x=0,
        binning_y=0,
        roi=_T["sensor_msgs/msg/RegionOfInterest"](
            x_offset=0, y_offset=0, height=0, width=0, do_rectify=False
        ),
    )


CLOUD_POINT = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("rgb", "<u4")])


def point_cloud(cloud: PointCloud, head: Any, session: Session) -> Any:
    """x, y, z float32 [m, world] and `rgb` as PCL packs it: one float32 whose bytes are
    0x00RRGGBB (little-endian: b, g, r, 0)."""
    points_m, colors = unpack_cloud(cloud)
    records = np.empty(len(points_m), CLOUD_POINT)
    records["x"], records["y"], records["z"] = points_m.T
    rgb = colors.astype(np.uint32)
    records["rgb"] = (rgb[:, 0] << 16) | (rgb[:, 1] << 8) | rgb[:, 2]
    field = _T["sensor_msgs/msg/PointField"]
    fields = [
        field(name=name, offset=4 * i, datatype=field.FLOAT32, count=1)
        for i, name in enumerate(("x", "y", "z", "rgb"))
    ]
    return _T["sensor_msgs/msg/PointCloud2"](
        header=head,
        height=1,
        width=len(records),
        fields=fields,
        is_bigendian=False,
        point_step=CLOUD_POINT.itemsize,
        row_step=CLOUD_POINT.itemsize * len(records),
        data=records.view(np.uint8),
        is_dense=True,
    )


def octree_data(octree: bytes) -> bytes:
    """OctoMap's binary stream without its text header (id, size, resolution: the Octomap
    message's fields): what `writeBinaryData` writes and octomap_msgs carries."""
    head, separator, data = octree.partition(b"\ndata\n")
    if not separator or not head.startswith(b"# Octomap OcTree binary file"):
        raise BadInput("not an OctoMap binary tree")
    return data


def octree_file(data: bytes, resolution_m: float) -> bytes:
    """OctoMap's binary file of an Octomap message's data (octree_data's inverse): its header
    needs the node count, which the data holds: two bytes per inner node, whose children are two
    bits each (00 unknown, 01 free, 10 occupied, 11 inner)."""
    children = np.frombuffer(data, np.uint8)[:, None] >> np.array([0, 2, 4, 6], np.uint8) & 3
    inner = int((children == 3).sum())
    if len(data) % 2 or len(data) != 2 * (inner + 1):
        raise BadInput(
            f"{len(data)} bytes are not OctoMap's binary stream of a tree "
            f"({inner} inner children need {2 * (inner + 1)} bytes)"
        )
    size = len(data) // 2 + int(((children == 1) | (children == 2)).sum())
    head = f"# Octomap OcTree binary file\nid OcTree\nsize {size}\nres {resolution_m}\ndata\n"
    return head.encode() + data


def octomap(update: SceneUpdate, head: Any, session: Session) -> Any | None:
    """The whole map shore holds once this update is applied (binary: free or occupied, no
    colours); None after a gap, until the snapshot that ends it."""
    if session.scene.apply(update) != "applied":
        return None
    return _T["octomap_msgs/msg/Octomap"](
        header=head,
        binary=True,
        id="OcTree",
        resolution=session.scene.resolution_m,
        data=np.frombuffer(octree_data(session.scene.binary()), np.int8),
    )


def path(waypoints: Waypoints, head: Any, session: Session) -> Any:
    """Each waypoint a pose: x, y, z and the heading as a rotation about z."""
    return _T["nav_msgs/msg/Path"](
        header=head,
        poses=[
            _T["geometry_msgs/msg/PoseStamped"](header=head, pose=_pose(row[:3], _yaw_wxyz(float(row[3]))))
            for row in waypoints.waypoints
        ],
    )


def goal_pose(goal: ArmGoal, head: Any, session: Session) -> Any:
    return _T["geometry_msgs/msg/PoseStamped"](
        header=head, pose=_pose(goal.position_m_world, goal.orientation_wxyz_world)
    )


def end_effector_pose(telemetry: Telemetry, head: Any, session: Session) -> Any:
    """Where onboard sees the tool, in the world."""
    return _T["geometry_msgs/msg/PoseStamped"](
        header=head, pose=_pose(telemetry.ee_position_m_world, telemetry.ee_orientation_wxyz_world)
    )


def objects(found: RecognisedObjects, head: Any, session: Session) -> Any:
    """A box per object (namespace: its name), after a DELETEALL that clears the previous ones;
    the colour goes from red to green with the confidence."""
    marker_type = _T["visualization_msgs/msg/Marker"]

    def marker(
        action: int,
        ns: str = "",
        index: int = 0,
        pose: Any = None,
        size_m: Floats = (0, 0, 0),
        confidence: float = 0.0,
    ) -> Any:
        return marker_type(
            header=head,
            ns=ns,
            id=index,
            type=marker_type.CUBE,
            action=action,
            pose=pose or _pose((0, 0, 0), (1, 0, 0, 0)),
            scale=_vector(size_m),
            color=_T["std_msgs/msg/ColorRGBA"](r=1.0 - confidence, g=confidence, b=0.0, a=0.6),
            lifetime=_T["builtin_interfaces/msg/Duration"](sec=0, nanosec=0),
            frame_locked=False,
            points=[],
            colors=[],
            texture_resource="",
            texture=_T["sensor_msgs/msg/CompressedImage"](header=head, format="", data=np.zeros(0, np.uint8)),
            uv_coordinates=[],
            text=ns,
            mesh_resource="",
            mesh_file=_T["visualization_msgs/msg/MeshFile"](filename="", data=np.zeros(0, np.uint8)),
            mesh_use_embedded_materials=False,
        )

    found_each = zip(found.names, found.poses_world, found.half_sizes_m, found.confidences, strict=True)
    boxes = [
        marker(marker_type.ADD, name, i, _pose(pose[:3], pose[3:]), 2 * half, float(confidence))
        for i, (name, pose, half, confidence) in enumerate(found_each)
    ]
    return _T["visualization_msgs/msg/MarkerArray"](markers=[marker(marker_type.DELETEALL), *boxes])


def telemetry_diagnostics(t: Telemetry, head: Any, session: Session) -> Any:
    """The controllers' state: WARN while the failsafe holds the vehicle and arm, with why."""
    return _diagnostics(
        head,
        "abyss onboard controllers",
        WARN if t.failsafe else OK,
        f"failsafe: {t.failsafe}" if t.failsafe else f"vehicle {t.mode}, arm {t.arm_mode}",
        {
            "mode": t.mode,
            "arm_mode": t.arm_mode,
            "operator_mode": t.operator_mode,
            "failsafe": t.failsafe,
            "failsafe_events": t.failsafe_events,
            "command_id": t.command_id,
            "waypoint": f"{t.waypoint_index}/{t.waypoints_total}",
            "position_error_m": t.position_error_m,
            "heading_error_rad": t.heading_error_rad,
            "arm_command_id": t.arm_command_id,
            "ee_position_error_m": float(np.linalg.norm(t.ee_position_error_m_world)),
            "ee_orientation_error_rad": t.ee_orientation_error_rad,
            "boot_id": t.boot_id,
        },
    )


def mission_diagnostics(m: MissionStatus, head: Any, session: Session) -> Any:
    return _diagnostics(
        head,
        "abyss mission",
        WARN if m.failsafe else OK,
        "done" if m.done else f"failsafe: {m.failsafe}" if m.failsafe else m.mode,
        {
            "mode": m.mode,
            "arm_mode": m.arm_mode,
            "waypoint": f"{m.waypoint_index}/{m.waypoints_total}",
            "position_error_m": m.position_error_m,
            "heading_error_rad": m.heading_error_rad,
            "ee_position_error_m": m.ee_position_error_m,
            "ee_orientation_error_rad": m.ee_orientation_error_rad,
            "failsafe": m.failsafe,
            "failsafe_events": m.failsafe_events,
            "done": m.done,
        },
    )


def perception_diagnostics(p: PerceptionStatus, head: Any, session: Session) -> Any:
    level = WARN if p.scene_source != "cameras" else OK
    return _diagnostics(
        head,
        "abyss perception",
        level,
        f"scene from {p.scene_source or 'nothing yet'}",
        {
            **{f"{source}_points_per_s": rate for source, rate in p.points_per_s.items()},
            "recognition_confidence": p.recognition_confidence,
            "recognition_method": p.recognition_method,
        },
    )


def link_diagnostics(stats: LinkStats, head: Any, session: Session) -> Any:
    """What a link direction measured (its stats) under its profile (its fields)."""
    return _diagnostics(
        head,
        f"abyss link {stats.hop} {stats.direction}",
        OK,
        f"profile {stats.profile}",
        {"profile": stats.profile, **stats.fields, **stats.stats},
    )


def heartbeat_diagnostics(beat: Heartbeat, head: Any, session: Session) -> Any:
    return _diagnostics(
        head,
        "abyss heartbeat",
        OK if beat.shore_heard else WARN,
        "shore heard" if beat.shore_heard else "shore lost",
        {"shore_heard": beat.shore_heard, "shore_silence_s": beat.shore_silence_s},
    )


def ack_diagnostics(ack: CommandAck, head: Any, session: Session) -> Any:
    return _diagnostics(
        head,
        f"abyss command {ack.command}",
        OK if ack.accepted else ERROR,
        "taken" if ack.accepted else f"refused: {ack.reason}",
        {"command": ack.command, "command_id": ack.command_id, "reason": ack.reason},
    )


def status_diagnostics(status: SimulationStatus, head: Any, session: Session) -> Any:
    """The simulation's pace and its faults (WARN while any is injected)."""
    return _diagnostics(
        head,
        "abyss simulation",
        WARN if status.faults else OK,
        ", ".join(f"{k} {v:g}" for k, v in status.faults.items()) or "no faults",
        {
            "sim_time_s": status.sim_time_s,
            "realtime_factor": status.realtime_factor,
            "deadlines_met": status.deadlines_met,
            **{f"fault {k}": v for k, v in status.faults.items()},
        },
    )


def clock(status: SimulationStatus | None, head: Any, session: Session) -> Any:
    return _T["rosgraph_msgs/msg/Clock"](clock=head.stamp)


def operator_mode(mode: OperatorMode, head: Any, session: Session) -> Any:
    return _T["std_msgs/msg/String"](data=mode.mode)


def header_of(head: Any, frame_id: str) -> Any:
    """`head` with another frame."""
    return _T["std_msgs/msg/Header"](stamp=head.stamp, frame_id=frame_id)


def static_tf(session: Session, stamp_s: float, camera_mounts: dict[str, np.ndarray]) -> Any:
    """/tf_static: the arm's fixed links, and each camera's optical frame on the vehicle from its
    mounting (`Image.pose_camera` as the simulation sends it: x, y, z, w, x, y, z in base_link)."""
    stamp = ros_time(stamp_s)
    arm = [
        _transform(stamp, parent, child, translation, rotation)
        for parent, child, translation, rotation in session.arm.transforms(
            np.zeros(len(ARM_JOINTS)), 0.0, moving=False
        )
    ]
    cameras = [
        _transform(stamp, BASE_LINK, optical_frame(camera), pose[:3], pose[3:])
        for camera, pose in sorted(camera_mounts.items())
    ]
    return _tf(arm + cameras)


# -- back from ROS 2: what a ROS 2 node publishes in a station's place (the gateway) --------
# (ROS 2 message, session) -> abyss message, or None when it leaves nothing to send yet;
# BadInput names what is wrong with it
Parse = Callable[[Any, Session], Message | None]


def _frame(head: Any, allowed: str) -> None:
    if head.frame_id not in ("", allowed):
        raise BadInput(f"frame_id {head.frame_id!r}, expected {allowed!r}")


def twist_in(msg: Any, session: Session) -> VelocityRef:
    """The vehicle's velocity reference in base_link: linear x, y, z and the yaw rate (angular z);
    the vehicle is passively stable in roll and pitch, whose rates are not commanded."""
    _frame(msg.header, BASE_LINK)
    linear, angular = msg.twist.linear, msg.twist.angular
    return VelocityRef(np.array([linear.x, linear.y, linear.z]), float(angular.z))


def joint_velocities_in(msg: Any, session: Session) -> ArmVelocityRef:
    data = np.asarray(msg.data, dtype=np.float64)
    if data.shape != (7,):
        raise BadInput(f"{len(data)} values, expected 7 ({ARM_COMMAND_LABEL})")
    return ArmVelocityRef(data[:6], float(data[6]))


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
    float32, uint32 = _T["sensor_msgs/msg/PointField"].FLOAT32, _T["sensor_msgs/msg/PointField"].UINT32
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
    command ids of the goals in force, the joints, the operator mode. None before navigation."""
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
    joints = session.joints.positions_rad if session.joints is not None else np.zeros(len(ARM_JOINTS))
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
    )


# -- the table ------------------------------------------------------------------------------
Convert = Callable[[Any, Any, Session], Any]  # (abyss message, header, session) -> ROS 2 message | None


@dataclass(frozen=True)
class RosTopic:
    """One ROS 2 topic an abyss key maps to. `name`: `{key}` stands for `/abyss/<station>/<topic>`
    (the abyss key without `abyss/<system>`); /tf and /clock are shared by the keys that feed them.
    `frame_id`: the header's (a camera's topics: its optical frame), `child_frame_id` that of the
    body an Odometry's twist is in; for /tf, the parents and the children of its transforms.
    `qos`: None for the key's (best-effort: SENSOR_QOS, reliable: RELIABLE_QOS). `parse`: the
    conversion back, where a ROS 2 node may publish the topic in the station's place (a gateway);
    `export`: False for a topic only a gateway publishes."""

    name: str
    type: str
    frame_id: str
    convert: Convert
    child_frame_id: str = ""
    qos: Qos | None = None
    parse: Parse | None = None
    export: bool = True

    def topic(self, abyss_topic: str, namespace: str = TOPIC_PREFIX) -> str:
        """The topic's name; `{key}` is `<namespace>/<abyss_topic>`."""
        return self.name.format(key=f"{namespace}/{abyss_topic}")


CAMERA_FRAME = optical_frame("<camera>")
TF, TF_STATIC = "/tf", "/tf_static"  # /tf_static: static_tf(), once, first
TF_MESSAGE = "tf2_msgs/msg/TFMessage"
DIAGNOSTICS = "diagnostic_msgs/msg/DiagnosticArray"
POSE = "geometry_msgs/msg/PoseStamped"
ODOMETRY = RosTopic("{key}", "nav_msgs/msg/Odometry", WORLD, odometry, BASE_LINK)
CAMERA_INFO = RosTopic("{key}/camera_info", "sensor_msgs/msg/CameraInfo", CAMERA_FRAME, camera_info)
ARM_PARENTS, ARM_CHILDREN = "arm_base .. arm_link6", "arm_link1 .. arm_link6, finger_left, finger_right"

CLOCK = "/clock"
BY_MESSAGE: dict[str, tuple[RosTopic, ...]] = {
    "NavState": (ODOMETRY, RosTopic(TF, TF_MESSAGE, WORLD, vehicle_tf, BASE_LINK, TF_QOS)),
    "JointState": (
        RosTopic("{key}", "sensor_msgs/msg/JointState", "", joint_state),
        RosTopic(TF, TF_MESSAGE, ARM_PARENTS, arm_tf, ARM_CHILDREN, TF_QOS),
    ),
    "Image": (
        RosTopic("{key}/image", "sensor_msgs/msg/Image", CAMERA_FRAME, raw_image, export=False),
        RosTopic("{key}/image/compressed", "sensor_msgs/msg/CompressedImage", CAMERA_FRAME, compressed_image),
        CAMERA_INFO,
    ),
    "VelocityRef": (RosTopic("{key}", "geometry_msgs/msg/TwistStamped", BASE_LINK, twist, parse=twist_in),),
    "ArmVelocityRef": (
        RosTopic("{key}", "std_msgs/msg/Float64MultiArray", "", joint_velocities, parse=joint_velocities_in),
    ),
    "Telemetry": (
        RosTopic("{key}/ee_pose", POSE, WORLD, end_effector_pose, parse=ee_pose_in),
        RosTopic("{key}/diagnostics", DIAGNOSTICS, "", telemetry_diagnostics, parse=telemetry_in),
    ),
    "PointCloud": (
        RosTopic("{key}", "sensor_msgs/msg/PointCloud2", WORLD, point_cloud, parse=point_cloud_in),
    ),
    "CommandAck": (RosTopic("{key}", DIAGNOSTICS, "", ack_diagnostics),),
    "Waypoints": (RosTopic("{key}", "nav_msgs/msg/Path", WORLD, path),),
    "ArmGoal": (RosTopic("{key}", POSE, WORLD, goal_pose),),
    "OperatorMode": (RosTopic("{key}", "std_msgs/msg/String", "", operator_mode),),
    "Heartbeat": (RosTopic("{key}", DIAGNOSTICS, "", heartbeat_diagnostics),),
    "SceneUpdate": (RosTopic("{key}", "octomap_msgs/msg/Octomap", WORLD, octomap, parse=octomap_in),),
    "RecognisedObjects": (RosTopic("{key}", "visualization_msgs/msg/MarkerArray", WORLD, objects),),
    "SimulationStatus": (
        RosTopic(CLOCK, "rosgraph_msgs/msg/Clock", "", clock, qos=CLOCK_QOS),
        RosTopic("{key}", DIAGNOSTICS, "", status_diagnostics),
    ),
    "SonarImage": (
        RosTopic("{key}/image/compressed", "sensor_msgs/msg/CompressedImage", "<sonar>", sonar_image),
    ),
    "PerceptionStatus": (RosTopic("{key}", DIAGNOSTICS, "", perception_diagnostics),),
    "LinkStats": (RosTopic("{key}", DIAGNOSTICS, "", link_diagnostics),),
    "MissionStatus": (RosTopic("{key}", DIAGNOSTICS, "", mission_diagnostics),),
}
BY_KEY: dict[str, tuple[RosTopic, ...]] = {  # keys that differ from their message's mapping
    "simulation/camera/cam_depth": (
        RosTopic("{key}/image", "sensor_msgs/msg/Image", CAMERA_FRAME, depth_image),
        CAMERA_INFO,
    ),
    "simulation/truth": (ODOMETRY,),  # /tf is the navigation's: what the stations steer by
}
NOT_EXPORTED: dict[str, str] = {  # message -> why
    "SceneRequest": "the scene stream's flow control",
    "SceneAck": "the scene stream's flow control",
}
# the testbed's observation keys exported (`<station>/<topic>`, `*`: any one level) and their messages
OBSERVED: dict[str, str] = {
    "simulation/truth": "NavState",
    "simulation/status": "SimulationStatus",
    "*/linkstats/*": "LinkStats",
    "onboard/state": "Telemetry",
    "onshore/mission": "MissionStatus",
}


@dataclass(frozen=True)
class KeyMap:
    """The ROS 2 topics of one abyss key, `<station>/<topic>` (`*`: any one level)."""

    key: str
    message: str
    reliability: keys.Reliability
    topics: tuple[RosTopic, ...]

    @property
    def exported(self) -> tuple[RosTopic, ...]:
        return tuple(t for t in self.topics if t.export)

    def qos(self, topic: RosTopic) -> Qos:
        return topic.qos or (SENSOR_QOS if self.reliability == "best-effort" else RELIABLE_QOS)

    def matches(self, abyss_topic: str) -> bool:
        want, got = self.key.split("/"), abyss_topic.split("/")
        return len(want) == len(got) and all(w in ("*", g) for w, g in zip(want, got, strict=True))


def _key_map(key: str, message: str, reliability: keys.Reliability) -> KeyMap:
    return KeyMap(key, message, reliability, BY_KEY.get(key, BY_MESSAGE.get(message, ())))


TABLE: tuple[KeyMap, ...] = (
    *(
        _key_map(f"{s.station}/{s.topic}", s.message, s.reliability)
        for s in keys.KEYS
        if s.message not in NOT_EXPORTED
    ),
    *(_key_map(key, message, "reliable") for key, message in OBSERVED.items()),  # testbed keys: reliable
)


def key_map(abyss_topic: str) -> KeyMap | None:
    """The mapping of an abyss key `<station>/<topic>`; None for a key not exported."""
    return next((m for m in TABLE if m.matches(abyss_topic)), None)


def gateway_keys(station: str) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """The abyss keys (`<station>/<topic>`) a ROS 2 node in `station`'s place is handed, and
    those it publishes. Onboard: all it receives, all it sends that parse back. The vessel: its
    scene model only, clouds in and the map out; its relay of commands, telemetry and
    acknowledgements (abyss's operator protocol) stays abyss's."""
    if station == "vessel":
        return ("onboard/cloud",), ("vessel/scene",)
    maps = [(f"{s.station}/{s.topic}", s, key_map(f"{s.station}/{s.topic}")) for s in keys.KEYS]
    return (
        tuple(key for key, s, m in maps if s.to == station and m is not None),
        tuple(
            key
            for key, s, m in maps
            if s.station == station and m is not None and any(t.parse is not None for t in m.topics)
        ),
    )


def stamp_of(message: Message, sent_sim_s: float) -> float:
    """A message's header stamp [s, simulated]: its own `sim_time_s`, else `sent_sim_s`, when
    its sender sent it in simulated time."""
    return float(getattr(message, "sim_time_s", sent_sim_s))


def msgdef(type_name: str) -> str:
    """The ROS 2 message definition of a type, with those it uses (the MCAP schema's text)."""
    return str(TYPESTORE.generate_msgdef(type_name, ros_version=2)[0])


def serialize(message: Any) -> bytes:
    """CDR, little-endian, with its encapsulation header."""
    return bytes(TYPESTORE.serialize_cdr(message, message.__msgtype__))


def topics_table() -> str:
    """The Markdown table of the ROS 2 topics; the README holds it. `export`: in `abyss export
    mcap`; `gateway`: what the ROS 2 gateway hands a node in a station's place, or takes from it."""
    rows = [
        "| abyss key | ROS 2 topic | type | frame_id | child_frame_id | QoS | export | gateway |",
        "| --- | --- | --- | --- | --- | --- | --- | --- |",
    ]

    def gateway(key: str, t: RosTopic) -> str:
        uses = [f"to {station}'s node" for station in ROS2_STATIONS if key in gateway_keys(station)[0]]
        uses += [
            f"from {station}'s node"
            for station in ROS2_STATIONS
            if key in gateway_keys(station)[1] and t.parse is not None
        ]
        return ", ".join(uses) or "-"

    def code(text: str) -> str:
        return f"`{text}`" if text else "-"

    def qos_text(qos: Qos) -> str:
        durability = ", transient local" if qos.durability == QosDurability.TRANSIENT_LOCAL else ""
        return f"{qos.reliability.name.lower().replace('_', '-')}, depth {qos.depth}{durability}"

    for m in TABLE:
        key = m.key.replace("*/linkstats/*", "<station>/linkstats/<hop>")
        for t in m.topics:
            rows.append(
                f"| {code(key)} | {code(t.topic(key))} | {t.type} | {code(t.frame_id)} "
                f"| {code(t.child_frame_id)} | {qos_text(m.qos(t))} | {'yes' if t.export else '-'} "
                f"| {gateway(m.key, t)} |"
            )
    rows.append(
        f"| (robot.xml; each camera's first frame) | {code(TF_STATIC)} | {TF_MESSAGE} "
        f"| `{BASE_LINK}`, `arm_link6` | `arm_base`, `ee`, {code(CAMERA_FRAME)} "
        f"| {qos_text(TF_STATIC_QOS)} | yes | to the node |"
    )
    rows.append(
        f"| (the latest simulated time handed over) | {code(CLOCK)} | rosgraph_msgs/msg/Clock "
        f"| - | - | {qos_text(CLOCK_QOS)} | - | to the node |"
    )
    return "\n".join(rows)
