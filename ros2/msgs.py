"""ROS 2 messages as abyss builds them: the typestore (rosbags', ROS 2 Jazzy, plus
`octomap_msgs/Octomap`), the frames' names, the QoS profiles, and the building blocks of every
conversion (headers, vectors, poses, transforms, diagnostics); CDR out and message definitions."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

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
ROS = TYPESTORE.types  # the message classes by type name


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
    return ROS["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec)


def header(stamp_s: float, frame_id: str) -> Any:
    return ROS["std_msgs/msg/Header"](stamp=ros_time(stamp_s), frame_id=frame_id)


def vector_msg(xyz: Floats) -> Any:
    return ROS["geometry_msgs/msg/Vector3"](x=float(xyz[0]), y=float(xyz[1]), z=float(xyz[2]))


def quaternion_msg(wxyz: Floats) -> Any:
    w, x, y, z = (float(v) for v in wxyz)
    return ROS["geometry_msgs/msg/Quaternion"](x=x, y=y, z=z, w=w)  # ROS: x, y, z, w


def pose_msg(position: Floats, orientation_wxyz: Floats) -> Any:
    x, y, z = (float(v) for v in position)
    return ROS["geometry_msgs/msg/Pose"](
        position=ROS["geometry_msgs/msg/Point"](x=x, y=y, z=z), orientation=quaternion_msg(orientation_wxyz)
    )


def yaw_wxyz(yaw_rad: float) -> tuple[float, float, float, float]:
    return math.cos(yaw_rad / 2), 0.0, 0.0, math.sin(yaw_rad / 2)


def transform_msg(stamp: Any, parent: str, child: str, translation: Floats, rotation_wxyz: Floats) -> Any:
    return ROS["geometry_msgs/msg/TransformStamped"](
        header=ROS["std_msgs/msg/Header"](stamp=stamp, frame_id=parent),
        child_frame_id=child,
        transform=ROS["geometry_msgs/msg/Transform"](
            translation=vector_msg(translation), rotation=quaternion_msg(rotation_wxyz)
        ),
    )


def tf_msg(transforms: list[Any]) -> Any:
    return ROS["tf2_msgs/msg/TFMessage"](transforms=transforms)


def floats(values: Floats) -> np.ndarray:
    return np.asarray(values, dtype=np.float64)


def diagnostics_msg(head: Any, name: str, level: int, message: str, values: dict[str, object]) -> Any:
    """A DiagnosticArray of one status; `level`: DiagnosticStatus.OK, WARN, ERROR."""
    status = ROS["diagnostic_msgs/msg/DiagnosticStatus"](
        level=level,
        name=name,
        message=message,
        hardware_id="abyss",
        values=[
            ROS["diagnostic_msgs/msg/KeyValue"](key=k, value=f"{v:g}" if isinstance(v, float) else str(v))
            for k, v in values.items()
        ],
    )
    return ROS["diagnostic_msgs/msg/DiagnosticArray"](header=head, status=[status])


OK, WARN, ERROR = 0, 1, 2  # diagnostic_msgs/DiagnosticStatus levels


def header_of(head: Any, frame_id: str) -> Any:
    """`head` with another frame."""
    return ROS["std_msgs/msg/Header"](stamp=head.stamp, frame_id=frame_id)


def msgdef(type_name: str) -> str:
    """The ROS 2 message definition of a type, with those it uses (the MCAP schema's text)."""
    return str(TYPESTORE.generate_msgdef(type_name, ros_version=2)[0])


def serialize(message: Any) -> bytes:
    """CDR, little-endian, with its encapsulation header."""
    return bytes(TYPESTORE.serialize_cdr(message, message.__msgtype__))
