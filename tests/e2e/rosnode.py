"""A ROS 2 node as rmw_zenoh puts one on the wire, written from the wire contract alone
(rmw_zenoh's docs/design.md and its attachment, GID and QoS code): plain zenoh-python, CDR by
pycdr2 (not the gateway's rosbags), hashes and tokens formatted here. It plays the team's
component in the gateway's tests: it discovers the gateway's endpoints, reads odometry and the
waypoints, and flies them with velocity commands, stating its mode in diagnostics as the
README asks of a ROS 2 onboard node."""

# no `from __future__ import annotations`: pycdr2 reads the fields' types from the annotations
import json
import math
import struct
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pyoctomap
import xxhash
import zenoh
from pycdr2 import IdlStruct
from pycdr2.types import array, float64, int8, int32, sequence, uint8, uint32
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

_HASHES = get_typestore(Stores.ROS2_JAZZY)  # REP 2016 hashes, from a maintained library
_HASHES.register(
    get_types_from_msg(  # octomap_msgs/msg/Octomap.msg, its fields
        "std_msgs/Header header\nbool binary\nstring id\nfloat64 resolution\nint8[] data\n",
        "octomap_msgs/msg/Octomap",
    )
)


# -- the messages, as their .msg files define them ------------------------------------------
@dataclass
class Time(IdlStruct, typename="builtin_interfaces/msg/Time"):
    sec: int32
    nanosec: uint32


@dataclass
class Header(IdlStruct, typename="std_msgs/msg/Header"):
    stamp: Time
    frame_id: str


@dataclass
class Vector3(IdlStruct, typename="geometry_msgs/msg/Vector3"):
    x: float64
    y: float64
    z: float64


@dataclass
class Quaternion(IdlStruct, typename="geometry_msgs/msg/Quaternion"):
    x: float64
    y: float64
    z: float64
    w: float64


@dataclass
class Pose(IdlStruct, typename="geometry_msgs/msg/Pose"):
    position: Vector3  # geometry_msgs/Point: the same three float64
    orientation: Quaternion


@dataclass
class PoseWithCovariance(IdlStruct, typename="geometry_msgs/msg/PoseWithCovariance"):
    pose: Pose
    covariance: array[float64, 36]


@dataclass
class Twist(IdlStruct, typename="geometry_msgs/msg/Twist"):
    linear: Vector3
    angular: Vector3


@dataclass
class TwistWithCovariance(IdlStruct, typename="geometry_msgs/msg/TwistWithCovariance"):
    twist: Twist
    covariance: array[float64, 36]


@dataclass
class Odometry(IdlStruct, typename="nav_msgs/msg/Odometry"):
    header: Header
    child_frame_id: str
    pose: PoseWithCovariance
    twist: TwistWithCovariance


@dataclass
class PoseStamped(IdlStruct, typename="geometry_msgs/msg/PoseStamped"):
    header: Header
    pose: Pose


@dataclass
class Path(IdlStruct, typename="nav_msgs/msg/Path"):
    header: Header
    poses: sequence[PoseStamped]


@dataclass
class TwistStamped(IdlStruct, typename="geometry_msgs/msg/TwistStamped"):
    header: Header
    twist: Twist


@dataclass
class MultiArrayDimension(IdlStruct, typename="std_msgs/msg/MultiArrayDimension"):
    label: str
    size: uint32
    stride: uint32


@dataclass
class MultiArrayLayout(IdlStruct, typename="std_msgs/msg/MultiArrayLayout"):
    dim: sequence[MultiArrayDimension]
    data_offset: uint32


@dataclass
class Float64MultiArray(IdlStruct, typename="std_msgs/msg/Float64MultiArray"):
    layout: MultiArrayLayout
    data: sequence[float64]


@dataclass
class KeyValue(IdlStruct, typename="diagnostic_msgs/msg/KeyValue"):
    key: str
    value: str


@dataclass
class DiagnosticStatus(IdlStruct, typename="diagnostic_msgs/msg/DiagnosticStatus"):
    level: uint8
    name: str
    message: str
    hardware_id: str
    values: sequence[KeyValue]


@dataclass
class DiagnosticArray(IdlStruct, typename="diagnostic_msgs/msg/DiagnosticArray"):
    header: Header
    status: sequence[DiagnosticStatus]


@dataclass
class PointField(IdlStruct, typename="sensor_msgs/msg/PointField"):
    name: str
    offset: uint32
    datatype: uint8
    count: uint32


@dataclass
class PointCloud2(IdlStruct, typename="sensor_msgs/msg/PointCloud2"):
    header: Header
    height: uint32
    width: uint32
    fields: sequence[PointField]
    is_bigendian: bool
    point_step: uint32
    row_step: uint32
    data: sequence[uint8]
    is_dense: bool


@dataclass
class Transform(IdlStruct, typename="geometry_msgs/msg/Transform"):
    translation: Vector3
    rotation: Quaternion


@dataclass
class TransformStamped(IdlStruct, typename="geometry_msgs/msg/TransformStamped"):
    header: Header
    child_frame_id: str
    transform: Transform


@dataclass
class TFMessage(IdlStruct, typename="tf2_msgs/msg/TFMessage"):
    transforms: sequence[TransformStamped]


@dataclass
class Octomap(IdlStruct, typename="octomap_msgs/msg/Octomap"):
    header: Header
    binary: bool
    id: str
    resolution: float64
    data: sequence[int8]


@dataclass
class Clock(IdlStruct, typename="rosgraph_msgs/msg/Clock"):
    clock: Time


# -- the wire contract ----------------------------------------------------------------------
def ros_type(message: type[IdlStruct]) -> str:
    return str(message.__idl_typename__)


def dds_name(type_name: str) -> str:
    package, kind, name = type_name.split("/")
    return f"{package}::{kind}::dds_::{name}_"


def rihs01(type_name: str) -> str:
    return str(_HASHES.hash_rihs01(type_name))


def data_key(domain: int, topic: str, message: type[IdlStruct]) -> str:
    name = ros_type(message)
    return f"{domain}/{topic.strip('/')}/{dds_name(name)}/{rihs01(name)}"


QOS_DEFAULT = "::,10:,:,:,,"  # reliable, volatile, keep-last 10 (rclcpp's default)
QOS_SENSOR = "2::,5:,:,:,,"  # best effort, keep-last 5 (SensorDataQoS)


def attachment(seq: int, gid: bytes) -> bytes:
    return struct.pack("<qqB", seq, time.time_ns(), 16) + gid


@dataclass
class Token:
    """A liveliness token's fields (design.md: Graph Cache)."""

    domain: int
    zid: str
    node_id: int
    entity_id: int
    kind: str
    enclave: str
    namespace: str
    node: str
    topic: str = ""
    type: str = ""
    hash: str = ""
    qos: str = ""

    @classmethod
    def parse(cls, key: str) -> "Token":
        parts = key.split("/")
        assert parts[0] == "@ros2_lv" and len(parts) >= 9, key
        fields: list[Any] = [
            int(parts[1]),
            parts[2],
            int(parts[3]),
            int(parts[4]),
            parts[5],
            *(p.replace("%", "/") for p in parts[6:9]),
        ]
        if parts[5] != "NN":
            fields += [parts[9].replace("%", "/"), parts[10], parts[11], parts[12]]
        return cls(*fields)

    def key(self) -> str:
        parts = [
            "@ros2_lv",
            str(self.domain),
            self.zid,
            str(self.node_id),
            str(self.entity_id),
            self.kind,
            self.enclave.replace("/", "%"),
            self.namespace.replace("/", "%"),
            self.node,
        ]
        if self.kind != "NN":
            parts += [self.topic.replace("/", "%"), self.type, self.hash, self.qos]
        return "/".join(parts)


def session_config(endpoint: str) -> zenoh.Config:
    """rmw_zenoh's session defaults that matter here: a peer connecting to the router, no multicast."""
    config = zenoh.Config()
    config.insert_json5("mode", json.dumps("peer"))
    config.insert_json5("connect/endpoints", json.dumps([endpoint]))
    config.insert_json5("listen/endpoints", json.dumps(["tcp/127.0.0.1:0"]))
    config.insert_json5("scouting/multicast/enabled", "false")
    config.insert_json5("timestamping/enabled", "true")
    return config


class RosNode:
    """One node with the publishers and subscriptions of a ROS 2 onboard controller."""

    def __init__(
        self, endpoint: str, domain: int = 0, namespace: str = "/", name: str = "team_onboard"
    ) -> None:
        self.session = zenoh.open(session_config(endpoint))
        self.domain, self.namespace, self.name = domain, namespace, name
        self.zid = str(self.session.info.zid())
        self.ids = iter(range(1_000_000))
        self.node_id = next(self.ids)
        self.tokens = [
            self.session.liveliness().declare_token(
                Token(domain, self.zid, self.node_id, self.node_id, "NN", "/", namespace, name).key()
            )
        ]
        self.seq: dict[str, int] = {}
        self.publishers: dict[str, tuple[Any, bytes]] = {}
        self.subscribers: list[Any] = []

    def graph(self, timeout_s: float = 3.0) -> list[Token]:
        """Every endpoint in the domain (what `ros2 topic list` reads)."""
        replies = self.session.liveliness().get(f"@ros2_lv/{self.domain}/**", timeout=timeout_s)
        return [Token.parse(str(r.ok.key_expr)) for r in replies if r.ok is not None]

    def _token(self, kind: str, topic: str, message: type[IdlStruct], qos: str) -> str:
        name = ros_type(message)
        return Token(
            self.domain,
            self.zid,
            self.node_id,
            next(self.ids),
            kind,
            "/",
            self.namespace,
            self.name,
            topic,
            dds_name(name),
            rihs01(name),
            qos,
        ).key()

    def publisher(self, topic: str, message: type[IdlStruct], qos: str = QOS_DEFAULT) -> None:
        token = self._token("MP", topic, message, qos)
        self.tokens.append(self.session.liveliness().declare_token(token))
        gid = xxhash.xxh3_128_intdigest(token.encode()).to_bytes(16, "little")
        reliability = zenoh.Reliability.BEST_EFFORT if qos.startswith("2:") else zenoh.Reliability.RELIABLE
        self.publishers[topic] = (
            self.session.declare_publisher(
                data_key(self.domain, topic, message),
                reliability=reliability,
                congestion_control=zenoh.CongestionControl.DROP,
            ),
            gid,
        )

    def publish(self, topic: str, message: IdlStruct) -> None:
        publisher, gid = self.publishers[topic]
        self.seq[topic] = self.seq.get(topic, 0) + 1
        publisher.put(message.serialize(), attachment=attachment(self.seq[topic], gid))

    def subscribe(
        self, topic: str, message: type[IdlStruct], on_message: Callable[[Any], None], qos: str = QOS_DEFAULT
    ) -> None:
        self.tokens.append(self.session.liveliness().declare_token(self._token("MS", topic, message, qos)))

        def on_sample(sample: zenoh.Sample) -> None:
            assert sample.attachment is not None and len(sample.attachment.to_bytes()) == 33
            on_message(message.deserialize(sample.payload.to_bytes()))

        key = data_key(self.domain, topic, message)
        self.subscribers.append(self.session.declare_subscriber(key, on_sample))

    def close(self) -> None:
        for entity in [*self.subscribers, *self.tokens, *(p for p, _ in self.publishers.values())]:
            entity.undeclare()
        self.session.close()


# -- the team's controller -----------------------------------------------------------------
def yaw_of(q: Quaternion) -> float:
    return math.atan2(2 * (q.w * q.z + q.x * q.y), 1 - 2 * (q.y * q.y + q.z * q.z))


def wrap(angle_rad: float) -> float:
    return (angle_rad + math.pi) % (2 * math.pi) - math.pi


@dataclass
class Flight:
    """What the controller has seen and done."""

    odometry: list[Odometry] = field(default_factory=list)
    clock_s: list[float] = field(default_factory=list)
    waypoints: list[tuple[float, float, float, float]] = field(default_factory=list)
    index: int = 0
    commands: int = 0


class WaypointPilot:
    """Flies the waypoints of the gateway's Path with TwistStamped commands at 20 Hz (P on
    position and heading, saturated), and states its mode and waypoint at 10 Hz; the arm is held
    still (zero joint velocities)."""

    GAIN_PER_S, MAX_SPEED_MPS, MAX_YAW_RATE_RADPS = 0.8, 0.4, 0.4
    TOLERANCE_M, TOLERANCE_RAD = 0.12, 0.08

    def __init__(self, node: RosNode, prefix: str = "/abyss") -> None:
        self.node, self.flight = node, Flight()
        self.lock = threading.Lock()
        self.velocity = f"{prefix}/onboard/cmd/vehicle_velocity"
        self.arm = f"{prefix}/onboard/cmd/arm_velocity"
        self.diagnostics = f"{prefix}/onboard/telemetry/diagnostics"
        node.subscribe(f"{prefix}/simulation/nav", Odometry, self._odometry, QOS_SENSOR)
        node.subscribe(f"{prefix}/vessel/goal/waypoints", Path, self._path)
        node.subscribe("/clock", Clock, self._clock, "2::,1:,:,:,,")
        node.publisher(self.velocity, TwistStamped, QOS_SENSOR)
        node.publisher(self.arm, Float64MultiArray, QOS_SENSOR)
        node.publisher(self.diagnostics, DiagnosticArray)

    def _clock(self, clock: Clock) -> None:
        self.flight.clock_s.append(clock.clock.sec + clock.clock.nanosec * 1e-9)

    def _odometry(self, odometry: Odometry) -> None:
        with self.lock:
            self.flight.odometry.append(odometry)

    def _path(self, path: Path) -> None:
        with self.lock:
            self.flight.waypoints = [
                (p.pose.position.x, p.pose.position.y, p.pose.position.z, yaw_of(p.pose.orientation))
                for p in path.poses
            ]
            self.flight.index = 0

    def step(self, tick: int) -> None:
        with self.lock:
            odometry = self.flight.odometry[-1] if self.flight.odometry else None
            waypoints, index = self.flight.waypoints, self.flight.index
        if odometry is None:
            return
        stamp = odometry.header.stamp
        vx = vy = vz = yaw_rate = 0.0
        mode = "idle"
        if waypoints:
            p, yaw = odometry.pose.pose.position, yaw_of(odometry.pose.pose.orientation)
            x, y, z, heading = waypoints[min(index, len(waypoints) - 1)]
            ex, ey, ez, eyaw = x - p.x, y - p.y, z - p.z, wrap(heading - yaw)
            if (
                index < len(waypoints)
                and math.dist((ex, ey, ez), (0, 0, 0)) < self.TOLERANCE_M
                and abs(eyaw) < self.TOLERANCE_RAD
            ):
                index += 1
                with self.lock:
                    self.flight.index = index
            mode = "reached" if index >= len(waypoints) else "moving"
            ux, uy, uz = (self.GAIN_PER_S * e for e in (ex, ey, ez))
            speed = math.dist((ux, uy, uz), (0, 0, 0))
            scale = min(1.0, self.MAX_SPEED_MPS / speed) if speed > 0 else 1.0
            c, s = math.cos(yaw), math.sin(yaw)
            vx, vy, vz = scale * (c * ux + s * uy), scale * (-s * ux + c * uy), scale * uz
            yaw_rate = max(-self.MAX_YAW_RATE_RADPS, min(self.MAX_YAW_RATE_RADPS, self.GAIN_PER_S * eyaw))
        self.node.publish(
            self.velocity,
            TwistStamped(Header(stamp, "base_link"), Twist(Vector3(vx, vy, vz), Vector3(0.0, 0.0, yaw_rate))),
        )
        self.node.publish(self.arm, Float64MultiArray(MultiArrayLayout([], 0), [0.0] * 7))
        self.flight.commands += 1
        if tick % 2 == 0:
            values = [
                KeyValue("mode", mode),
                KeyValue("waypoint", f"{index}/{len(waypoints)}"),
                KeyValue("arm_mode", "idle"),
            ]
            self.node.publish(
                self.diagnostics,
                DiagnosticArray(
                    Header(stamp, ""), [DiagnosticStatus(0, "team onboard", mode, "test", values)]
                ),
            )

    def fly(self, stop: threading.Event, period_s: float = 0.05) -> None:
        tick = 0
        while not stop.wait(period_s):
            self.step(tick)
            tick += 1


class Mapper:
    """A ROS 2 scene model in the vessel's place: every cloud's points marked occupied in an
    OctoMap (octomap's own library), the whole map published as a binary Octomap each period."""

    def __init__(self, node: RosNode, resolution_m: float, prefix: str = "/abyss") -> None:
        self.node, self.resolution_m = node, resolution_m
        self.scene = f"{prefix}/vessel/scene"
        self.lock = threading.Lock()
        self.points_m: list[np.ndarray] = []
        self.maps = 0
        node.subscribe(f"{prefix}/onboard/cloud", PointCloud2, self._cloud, QOS_SENSOR)
        node.publisher(self.scene, Octomap)

    def _cloud(self, cloud: PointCloud2) -> None:
        offsets = {f.name: f.offset for f in cloud.fields}
        rows = np.frombuffer(bytes(cloud.data), np.uint8).reshape(-1, cloud.point_step)
        xyz = np.column_stack(
            [rows[:, offsets[a] : offsets[a] + 4].copy().view("<f4").ravel() for a in "xyz"]
        )
        with self.lock:
            self.points_m.append(xyz[np.isfinite(xyz).all(axis=1)].astype(np.float64))

    def step(self) -> None:
        with self.lock:
            if not self.points_m:
                return
            points_m = np.vstack(self.points_m)
        tree = pyoctomap.OcTree(self.resolution_m)
        tree.updateNodes(points_m, 2.0, True)
        tree.updateInnerOccupancy()
        binary = bytes(tree.writeBinary())
        data = binary[binary.index(b"\ndata\n") + 6 :]
        self.node.publish(
            self.scene,
            Octomap(
                Header(Time(0, 0), "world"),
                True,
                "OcTree",
                self.resolution_m,
                list(np.frombuffer(data, np.int8)),
            ),
        )
        self.maps += 1

    def map_points(self) -> np.ndarray:
        with self.lock:
            return np.vstack(self.points_m) if self.points_m else np.zeros((0, 3))

    def run(self, stop: threading.Event, period_s: float = 1.0) -> None:
        while not stop.wait(period_s):
            self.step()


def gateway_graph(
    node: RosNode, name: str, needs: set[tuple[str, str]], timeout_s: float = 60.0
) -> list[Token]:
    """The graph once the gateway's node and the endpoints `needs` (kind, topic) are in it: the
    gateway declares its node's token first and each endpoint's as it makes it."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        graph = node.graph()
        if needs <= {(t.kind, t.topic) for t in graph if t.node == name}:
            return graph
    raise AssertionError(f"the gateway {name} never showed all of {sorted(needs)}")
