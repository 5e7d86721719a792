"""The one table from abyss messages to ROS 2: per key its ROS 2 topics, types, frames and QoS,
and the conversion of each message to a message of the standard type (`ros2.motion`,
`ros2.sensing`, `ros2.status`, on the building blocks of `ros2.msgs`: rosbags' typestore, ROS 2
Jazzy, plus `octomap_msgs/Octomap`), and back (`ros2.from_ros`) for what a ROS 2 node publishes in
a station's place (onboard's commands, telemetry and clouds; the vessel's map; a real vehicle's
navigation and joints, its driver in the simulation's place). The MCAP export (`ros2.mcap`) writes
by it; the ROS 2 gateway (`ros2.gateway`) publishes and subscribes by it.

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

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from rosbags.interfaces import Qos, QosDurability

from abyss.config.hybrid import ROS2_VEHICLE
from abyss.config.system import ROS2_STATIONS
from abyss.interface import keys
from abyss.interface.messages import (
    Message,
)
from abyss.ros2.from_ros import (
    Parse,
    ee_pose_in,
    joint_state_in,
    joint_velocities_in,
    octomap_in,
    odometry_in,
    point_cloud_in,
    telemetry_in,
    twist_in,
)
from abyss.ros2.motion import (
    arm_tf,
    end_effector_pose,
    goal_pose,
    joint_state,
    joint_velocities,
    odometry,
    operator_mode,
    path,
    twist,
    vehicle_tf,
)
from abyss.ros2.msgs import (
    BASE_LINK,
    CLOCK_QOS,
    RELIABLE_QOS,
    SENSOR_QOS,
    TF_QOS,
    TF_STATIC_QOS,
    TOPIC_PREFIX,
    WORLD,
    optical_frame,
)
from abyss.ros2.sensing import (
    camera_info,
    compressed_image,
    depth_image,
    objects,
    octomap,
    point_cloud,
    raw_image,
    sonar_image,
)
from abyss.ros2.session import Session
from abyss.ros2.status import (
    ack_diagnostics,
    clock,
    heartbeat_diagnostics,
    link_diagnostics,
    mission_diagnostics,
    perception_diagnostics,
    status_diagnostics,
    telemetry_diagnostics,
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
    "NavState": (  # parsed back from a vehicle's driver; the truth's (BY_KEY) never comes from a node
        dataclasses.replace(ODOMETRY, parse=odometry_in),
        RosTopic(TF, TF_MESSAGE, WORLD, vehicle_tf, BASE_LINK, TF_QOS),
    ),
    "JointState": (
        RosTopic("{key}", "sensor_msgs/msg/JointState", "", joint_state, parse=joint_state_in),
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
    "simulation/camera/depth": (
        RosTopic("{key}/image", "sensor_msgs/msg/Image", CAMERA_FRAME, depth_image),
        CAMERA_INFO,
    ),
    "simulation/truth": (ODOMETRY,),  # /tf is the navigation's: what the stations steer by
    "onboard/nav/estimate": (dataclasses.replace(ODOMETRY, parse=odometry_in),),  # ditto
}
NOT_EXPORTED: dict[str, str] = {  # message -> why
    "SceneRequest": "the scene stream's flow control",
    "SceneAck": "the scene stream's flow control",
    "MavlinkFrames": "MAVLink's own frames, for MAVLink's own tools (MAVROS speaks them where wanted)",
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


# the stations whose node keeps its own time and frames: a real vehicle's driver (the simulation's
# place, a hybrid run) runs on its own clock with its own robot description, so the gateway hands
# it no /clock and no /tf_static
OWN_TIME_AND_FRAMES: tuple[str, ...] = ("simulation",)


def gateway_keys(station: str) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """The abyss keys (`<station>/<topic>`) a ROS 2 node in `station`'s place is handed, and
    those it publishes. Onboard: all it receives, all it sends that parse back. The vessel: its
    scene model only, clouds in and the map out; its relay of commands, telemetry and
    acknowledgements (abyss's operator protocol) stays abyss's. The simulation: a real vehicle's
    driver (a hybrid run), handed the velocity commands sent to the simulation, provides its
    navigation and joints (hybrid.ROS2_VEHICLE); the twin renders the sensors."""
    if station == "vessel":
        return ("onboard/cloud",), ("vessel/scene",)
    maps = [(f"{s.station}/{s.topic}", s, key_map(f"{s.station}/{s.topic}")) for s in keys.KEYS]
    up = tuple(
        key
        for key, s, m in maps
        if s.station == station and m is not None and any(t.parse is not None for t in m.topics)
    )
    if station == "simulation":
        up = tuple(key for key in up if key.split("/", 1)[1] in ROS2_VEHICLE)
    return tuple(key for key, s, m in maps if s.to == station and m is not None), up


def stamp_of(message: Message, sent_sim_s: float) -> float:
    """A message's header stamp [s, simulated]: its own `sim_time_s`, else `sent_sim_s`, when
    its sender sent it in simulated time."""
    return float(getattr(message, "sim_time_s", sent_sim_s))


def topics_table() -> str:
    """The Markdown table of the ROS 2 topics; docs/ros2.md holds it. `export`: in `abyss export
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
    nodes = " and ".join(f"{s}'s" for s in ROS2_STATIONS if s not in OWN_TIME_AND_FRAMES)
    rows.append(
        f"| (robot.xml; each camera's first frame) | {code(TF_STATIC)} | {TF_MESSAGE} "
        f"| `{BASE_LINK}`, `arm_link6` | `arm_base`, `ee`, {code(CAMERA_FRAME)} "
        f"| {qos_text(TF_STATIC_QOS)} | yes | to {nodes} nodes |"
    )
    rows.append(
        f"| (the latest simulated time handed over) | {code(CLOCK)} | rosgraph_msgs/msg/Clock "
        f"| - | - | {qos_text(CLOCK_QOS)} | - | to {nodes} nodes |"
    )
    return "\n".join(rows)
