"""The ROS 2 gateway's cost per message against abyss's own codec on the same messages, in the
same run. Run: .venv/bin/python bench/gateway.py. Prints figures; asserts nothing.

Down (abyss -> ROS 2): each message as onboard receives it goes out either as abyss sends it
(msgpack `encode` and one put) or as the gateway sends it (`ros2.types` conversion to every
topic of its key, CDR, rmw_zenoh's attachment, one put per topic: NavState is Odometry, /tf and
/clock; JointState is JointState and /tf through Pinocchio's forward kinematics, and /clock; a
cloud, the vessel's node's input, is PointCloud2 and /clock: each message advances simulated
time here, as it does live). Up (ROS 2 ->
abyss): a TwistStamped as the gateway takes it (checks, CDR decode, conversion, abyss encode)
against abyss's own decode and encode of the VelocityRef. Both over a second Zenoh session on
loopback in this process: CPU per message (process time over a flood, Zenoh's threads
included), and latency (message in hand to its last sample received, paced)."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

import numpy as np
import zenoh

from abyss.bus.session import open_session, zenoh_config
from abyss.common.samples import Samples
from abyss.interface.clouds import pack_cloud
from abyss.interface.messages import JointState, Message, NavState, VelocityRef, decode, encode
from abyss.launch.station import free_port
from abyss.ros2 import from_ros, motion, msgs, rmw, status, types
from abyss.ros2.session import Session

FLOOD, PACED, PACE_S = 2000, 300, 0.005
NAV = NavState(
    np.array([1.0, 0.2, -7.0]), np.array([0.99, 0.0, 0.0, 0.141]), np.full(3, 0.1), np.full(3, 0.01), 3.5
)
JOINTS = JointState(np.linspace(-0.5, 0.5, 6), np.zeros(6), 0.03, 3.5)
CLOUD = pack_cloud(
    "stereo",
    np.random.default_rng(0).uniform(-1, 1, (8000, 3)) + np.array([4.0, 0.0, -8.5]),
    np.full((8000, 3), 128, np.uint8),
    np.array([1.0, 0.0, -7.0]),
    0.002,
    3.5,
)
Sample = tuple[str, bytes, bytes | None]  # key, payload, attachment


class Wire:
    """A publishing session and a receiving one over loopback; `send` puts samples, the
    receiver counts them."""

    def __init__(self) -> None:
        endpoint = f"tcp/127.0.0.1:{free_port()}"
        self.tx = open_session(zenoh_config(listen=[endpoint]), "bench tx")
        self.rx = open_session(zenoh_config(connect=[endpoint]), "bench rx")
        self.received = 0
        self.arrived = threading.Condition()
        self.publishers: dict[str, zenoh.Publisher] = {}
        self.subscriber = self.rx.declare_subscriber("**", self._on_sample)
        time.sleep(0.5)  # the sessions' declarations meet

    def _on_sample(self, sample: zenoh.Sample) -> None:
        with self.arrived:
            self.received += 1
            self.arrived.notify_all()

    def send(self, samples: list[Sample]) -> None:
        for key, payload, attachment in samples:
            if key not in self.publishers:
                self.publishers[key] = self.tx.declare_publisher(key)
            self.publishers[key].put(payload, attachment=attachment)

    def wait_for(self, count: int, timeout_s: float = 5.0) -> None:
        with self.arrived:
            self.arrived.wait_for(lambda: self.received >= count, timeout_s)

    def close(self) -> None:
        self.subscriber.undeclare()
        self.tx.close()
        self.rx.close()


def abyss_down(message: Message) -> list[Sample]:
    return [("abyss/bench/simulation/x", encode(message, 1, time.time()), None)]


class GatewayDown:
    """The gateway's path for one abyss message: every topic of its key (gateway.Gateway._down)."""

    def __init__(self, abyss_topic: str) -> None:
        self.mapping = types.key_map(abyss_topic)
        assert self.mapping is not None
        self.session = Session()
        self.gids = {t.name: bytes(16) for t in self.mapping.topics}
        self.keys = {t.name: rmw.topic_key(0, t.topic(abyss_topic), t.type) for t in self.mapping.topics}
        self.clock_key = rmw.topic_key(0, types.CLOCK, "rosgraph_msgs/msg/Clock")
        self.seq = 0

    def __call__(self, message: Message) -> list[Sample]:
        assert self.mapping is not None
        self.seq += 1
        stamp_s = types.stamp_of(message, 0.0)
        samples = []
        for t in self.mapping.topics:
            converted = t.convert(message, msgs.header(stamp_s, t.frame_id), self.session)
            samples.append(
                (
                    self.keys[t.name],
                    msgs.serialize(converted),
                    rmw.attachment(self.seq, time.time_ns(), self.gids[t.name]),
                )
            )
        clock = status.clock(None, msgs.header(stamp_s, ""), self.session)
        stamp = rmw.attachment(self.seq, time.time_ns(), bytes(16))
        samples.append((self.clock_key, msgs.serialize(clock), stamp))
        return samples


def twist_cdr() -> bytes:
    twist = motion.twist(
        VelocityRef(np.array([0.2, 0.0, -0.1]), 0.1), msgs.header(3.5, msgs.BASE_LINK), Session()
    )
    return msgs.serialize(twist)


def gateway_up(payload: bytes, attachment: bytes, session: Session) -> list[Sample]:
    """rmw.Subscription's checks and decode, the table's parse, abyss's encode."""
    rmw.parse_attachment(attachment)
    message = from_ros.twist_in(rmw.deserialize(payload, "geometry_msgs/msg/TwistStamped"), session)
    return [("abyss/bench/onboard/cmd/vehicle_velocity", encode(message, 1, time.time()), None)]


def abyss_up(payload: bytes) -> list[Sample]:
    message = decode("abyss/bench/onboard/cmd/vehicle_velocity", payload, VelocityRef).message
    return [("abyss/bench/onboard/cmd/vehicle_velocity", encode(message, 1, time.time()), None)]


def measure(wire: Wire, path: Callable[[], list[Sample]]) -> tuple[float, Samples]:
    """CPU [us] per message over a flood, and latency samples [s] paced."""
    per_message = len(path())
    start = wire.received
    t0 = time.process_time()
    for _ in range(FLOOD):
        wire.send(path())
    wire.wait_for(start + FLOOD * per_message)
    cpu_us = (time.process_time() - t0) / FLOOD * 1e6
    latency = Samples()
    for _ in range(PACED):
        expected = wire.received + per_message
        t = time.perf_counter()
        wire.send(path())
        wire.wait_for(expected)
        latency.add(time.perf_counter() - t)
        time.sleep(PACE_S)
    return cpu_us, latency


def main() -> None:
    wire = Wire()
    abyss_twist = encode(VelocityRef(np.array([0.2, 0.0, -0.1]), 0.1), 1, time.time())
    ros_twist, attachment = twist_cdr(), rmw.attachment(1, time.time_ns(), bytes(16))
    nav_down, joints_down = GatewayDown("simulation/nav"), GatewayDown("simulation/joints")
    cloud_down = GatewayDown("onboard/cloud")
    session = Session()
    cases: list[tuple[str, Callable[[], list[Sample]], Callable[[], list[Sample]]]] = [
        ("down NavState (Odometry, /tf, /clock)", lambda: abyss_down(NAV), lambda: nav_down(NAV)),
        (
            "down JointState (JointState, /tf by FK, /clock)",
            lambda: abyss_down(JOINTS),
            lambda: joints_down(JOINTS),
        ),
        (
            "down PointCloud 8000 points (PointCloud2, /clock)",
            lambda: abyss_down(CLOUD),
            lambda: cloud_down(CLOUD),
        ),
        (
            "up TwistStamped -> VelocityRef",
            lambda: abyss_up(abyss_twist),
            lambda: gateway_up(ros_twist, attachment, session),
        ),
    ]
    print(
        f"{'case':<50} {'abyss CPU us':>12} {'gateway CPU us':>15} {'ratio':>6}  "
        f"{'abyss p50/p95 us':>17} {'gateway p50/p95 us':>19}"
    )
    try:
        for name, abyss_path, gateway_path in cases:
            abyss_cpu, abyss_latency = measure(wire, abyss_path)
            gateway_cpu, gateway_latency = measure(wire, gateway_path)
            a, g = (s.percentiles("l", 1e6, "us") for s in (abyss_latency, gateway_latency))
            print(
                f"{name:<50} {abyss_cpu:>12.0f} {gateway_cpu:>15.0f} {gateway_cpu / abyss_cpu:>5.1f}x  "
                f"{a['l_p50_us']:>8.0f}/{a['l_p95_us']:<8.0f} {g['l_p50_us']:>9.0f}/{g['l_p95_us']:<9.0f}"
            )
    finally:
        wire.close()


if __name__ == "__main__":
    main()
