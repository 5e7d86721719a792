"""A real vehicle's ROS 2 driver as the contract node (rosnode.py: rmw_zenoh's wire contract,
plain zenoh-python and pycdr2, none of the gateway's code) plays it from a recorded run, for
`abyss up --ros2 simulation`: it publishes the recording's navigation (its truth, a fused
navigation) as nav_msgs/Odometry in `world` with child `base_link`, and its joints as
sensor_msgs/JointState (the arm's joints and each finger at half the gripper's opening), each at
its recorded simulated time after its start and stamped with it, and counts the velocity
commands it is sent (TwistStamped, Float64MultiArray), which it does not act on: it is a
recording."""

# no `from __future__ import annotations`: pycdr2 reads the fields' types from the annotations
import threading
import time
from dataclasses import dataclass
from typing import Any

from pycdr2 import IdlStruct
from pycdr2.types import float64, sequence
from rosnode import (
    QOS_SENSOR,
    Float64MultiArray,
    Header,
    Odometry,
    Pose,
    PoseWithCovariance,
    Quaternion,
    RosNode,
    Time,
    Twist,
    TwistStamped,
    TwistWithCovariance,
    Vector3,
)


@dataclass
class JointState(IdlStruct, typename="sensor_msgs/msg/JointState"):
    header: Header
    name: sequence[str]
    position: sequence[float64]
    velocity: sequence[float64]
    effort: sequence[float64]


def stamp(time_s: float) -> Time:
    sec, nanosec = divmod(round(time_s * 1e9), 10**9)
    return Time(sec, nanosec)


def odometry(time_s: float, position: Any, wxyz: Any, linear: Any, angular: Any) -> Odometry:
    """REP 105's Odometry: the pose in `world`, the twist in `base_link`; covariance unknown."""
    w, x, y, z = (float(v) for v in wxyz)
    return Odometry(
        Header(stamp(time_s), "world"),
        "base_link",
        PoseWithCovariance(Pose(Vector3(*map(float, position)), Quaternion(x, y, z, w)), [0.0] * 36),
        TwistWithCovariance(Twist(Vector3(*map(float, linear)), Vector3(*map(float, angular))), [0.0] * 36),
    )


def joint_state(
    time_s: float,
    arm: tuple[str, ...],
    fingers: tuple[str, ...],
    positions: Any,
    velocities: Any,
    opening_m: float,
) -> JointState:
    """The arm's joints, then each finger at its share of the gripper's opening (no velocity
    measured for them: NaN); no efforts."""
    return JointState(
        Header(stamp(time_s), ""),
        [*arm, *fingers],
        [*map(float, positions), *[opening_m / len(fingers)] * len(fingers)],
        [*map(float, velocities), *[float("nan")] * len(fingers)],
        [],
    )


class VehicleDriver:
    """The driver's node: `samples` are (simulated time [s], "nav" or "joints", message), the
    messages being already ROS 2's (`odometry`, `joint_state`), in time order."""

    def __init__(
        self, node: RosNode, samples: list[tuple[float, str, IdlStruct]], prefix: str = "/abyss"
    ) -> None:
        self.node, self.samples = node, samples
        self.topics = {"nav": f"{prefix}/simulation/nav", "joints": f"{prefix}/simulation/joints"}
        node.publisher(self.topics["nav"], Odometry, QOS_SENSOR)
        node.publisher(self.topics["joints"], JointState, QOS_SENSOR)
        self.lock = threading.Lock()
        self.velocity: list[TwistStamped] = []
        self.arm = 0
        self.sent = {"nav": 0, "joints": 0}
        self.played_s = 0.0  # [s, wall] from the first sample to the last sent
        node.subscribe(f"{prefix}/onboard/cmd/vehicle_velocity", TwistStamped, self._velocity, QOS_SENSOR)
        node.subscribe(f"{prefix}/onboard/cmd/arm_velocity", Float64MultiArray, self._arm, QOS_SENSOR)

    def _velocity(self, command: TwistStamped) -> None:
        with self.lock:
            self.velocity.append(command)

    def _arm(self, command: Float64MultiArray) -> None:
        with self.lock:
            self.arm += 1

    def play(self, stop: threading.Event) -> None:
        """Each sample at its recorded time after the first, until the last or `stop`."""
        t0_sim, t0_wall = self.samples[0][0], time.monotonic()
        for sim_s, topic, message in self.samples:
            if stop.wait(max(0.0, t0_wall + sim_s - t0_sim - time.monotonic())):
                break
            self.node.publish(self.topics[topic], message)
            self.sent[topic] += 1
            self.played_s = time.monotonic() - t0_wall
