"""The ROS 2 gateway: a ROS 2 node stands for a station (`abyss up --ros2
onboard|vessel|simulation`), met on the wire it speaks with RMW_IMPLEMENTATION=rmw_zenoh_cpp
(`ros2.rmw`), with no ROS on abyss's side. It runs in the station's shell, so its abyss side is
the station's: the same keys, links, recording and liveliness token; its ROS 2 side is a Zenoh
router of its own (rmw_zenohd's endpoint, `ros2.listen`) or a session joined to one
(`ros2.connect`). Which keys cross is `types.gateway_keys`: all of onboard's; the vessel's scene
model only (the vessel station runs with the node's map in place of its own octree); for the
simulation, a real vehicle's driver in a hybrid run (its navigation and joints up, the velocity
commands down), beside the twin, which renders the sensors at the vehicle's pose.

- Down to the node, by the table of `ros2.types`: each message on each of its key's ROS 2
  topics (the navigation as Odometry and /tf; joints; camera images and their CameraInfo; the
  goals; the heartbeat; clouds; the velocity commands), /clock with the latest simulated time
  handed over, and /tf_static (transient local) with the arm's fixed links and each camera's
  mounting. A vehicle's driver keeps its own time and frames (`types.OWN_TIME_AND_FRAMES`): it
  is handed neither /clock nor /tf_static, and the commands are stamped with the latest time its
  navigation or joints stated.
- Up from the node: each topic the table can parse back (the velocity references; the telemetry
  from the node's diagnostics and tool pose; clouds; the map; a vehicle's navigation and joints),
  validated (type, type hash, attachment, CDR, frames, the abyss message's bounds); a sample that
  fails is dropped, counted on its topic's key in the station's `rejected` and logged once. What
  is valid goes out on the station's key (a vehicle's navigation and joints so reach onboard and
  the twin alike), or to the station's own handler of it (the vessel's scene model).
- The operator's commands: the node has no command ids, so the gateway answers for it. A
  command is handed over once a ROS 2 subscriber of its topic is known, then acknowledged as
  taken; until then it waits for shore's next send, and a command sent again is answered the
  same way. The telemetry carries the ids of the goals last handed over.
"""

from __future__ import annotations

import functools
import logging
import threading
from collections.abc import Callable
from typing import Any

import numpy as np

from abyss.bus.session import Bus, Inbox, open_session, zenoh_config
from abyss.common.errors import BadInput
from abyss.config import Config, robot_of
from abyss.interface import keys
from abyss.interface.messages import (
    ArmGoal,
    CommandAck,
    JointState,
    Message,
    NavState,
    OperatorMode,
    Telemetry,
    Waypoints,
)
from abyss.ros2 import motion, msgs, rmw, status, types
from abyss.ros2.session import Session
from abyss.timing.rate import Rate

log = logging.getLogger(__name__)

LOOP_PERIOD_S = 0.005  # the latency the gateway adds, at most, to what goes down
Command = Waypoints | ArmGoal | OperatorMode  # an operator command the gateway answers for
COMMAND_KINDS = {Waypoints.TYPE: "waypoints", ArmGoal.TYPE: "arm", OperatorMode.TYPE: "mode"}
INBOX_DEPTH = 64


def node_name(station: str) -> str:
    return f"abyss_{station}_gateway"


def ros_session_config(listen: tuple[str, ...], connect: tuple[str, ...]) -> Any:
    """A Zenoh router on `listen` (where ROS 2 nodes connect, as to rmw_zenohd) joined to
    `connect`, with timestamps, as rmw_zenoh's sessions have them."""
    settings = zenoh_config(listen, connect, mode="router")
    settings.insert_json5("timestamping/enabled", "true")
    return settings


class Gateway:
    """`on_up`: per abyss topic of the station, what takes the node's message in place of the
    bus (BadInput: the message is refused with that reason)."""

    def __init__(
        self, config: Config, bus: Bus, on_up: dict[str, Callable[[Any], object]] | None = None
    ) -> None:
        cfg = config.ros2
        self.bus, self.namespace = bus, cfg.namespace
        self.session = open_session(ros_session_config(cfg.listen, cfg.connect), "the ROS 2 gateway")
        self.node = rmw.Node(self.session, cfg.domain, cfg.namespace, node_name(bus.station))
        self.convert = Session(robot_of(config))
        self._lock = threading.Lock()  # the conversions' session: the loop and Zenoh's callbacks
        self.publishers: dict[str, rmw.Publisher] = {}
        self.downlinks: list[tuple[keys.KeySpec, types.KeyMap, Inbox[Message]]] = []
        self.answers: dict[tuple[str, int], CommandAck] = {}
        self._waiting_logged: set[tuple[str, int]] = set()
        self.on_up = on_up or {}
        down, up = types.gateway_keys(bus.station)
        for key in down:
            spec, mapping = keys.spec(*key.split("/", 1)), types.key_map(key)
            assert mapping is not None
            self.downlinks.append(
                (spec, mapping, bus.subscribe(spec.station, spec.topic, spec.message_class, INBOX_DEPTH))
            )
            for t in mapping.topics:
                name = self.topic(spec, t)
                if name not in self.publishers:
                    self.publishers[name] = self.node.publisher(name, t.type, mapping.qos(t))
        for key in up:
            spec, mapping = keys.spec(*key.split("/", 1)), types.key_map(key)
            assert mapping is not None
            for t in (t for t in mapping.topics if t.parse is not None):
                self.node.subscription(
                    self.topic(spec, t),
                    t.type,
                    mapping.qos(t),
                    functools.partial(self._up, spec, t),
                    bus.reject,
                )
        own = bus.station in types.OWN_TIME_AND_FRAMES  # a vehicle's driver: its own clock and frames
        self.clock = (
            None if own else self.node.publisher(types.CLOCK, "rosgraph_msgs/msg/Clock", msgs.CLOCK_QOS)
        )
        self.clock_s = -1.0
        self.static = (
            None if own else self.node.publisher(types.TF_STATIC, types.TF_MESSAGE, msgs.TF_STATIC_QOS)
        )
        self.sensor_mounts: dict[str, np.ndarray] = {}  # sensor frame -> its pose on the vehicle
        self._publish_static()
        log.info(
            "ROS 2 gateway for %s: node %s/%s in domain %d, Zenoh %s (listen %s, connect %s); %d topics "
            "down, %d up",
            bus.station,
            cfg.namespace,
            self.node.name,
            cfg.domain,
            self.node.zid,
            list(cfg.listen),
            list(cfg.connect),
            len(self.publishers) + sum(p is not None for p in (self.clock, self.static)),
            sum(isinstance(e, rmw.Subscription) for e in self.node.endpoints),
        )

    def topic(self, spec: keys.KeySpec, t: types.RosTopic) -> str:
        return t.topic(f"{spec.station}/{spec.topic}", self.namespace)

    # -- down: abyss -> ROS 2 ------------------------------------------------------------
    def run(self) -> None:
        rate = Rate(LOOP_PERIOD_S, self.bus.stop)
        while rate.sleep():
            for spec, mapping, inbox in self.downlinks:
                for received in inbox.drain():
                    if isinstance(received.message, Command):
                        self._command(spec, mapping, received.message)
                    else:
                        self._down(spec, mapping, received.message)

    def _down(self, spec: keys.KeySpec, mapping: types.KeyMap, message: Message) -> None:
        """Hand a message to the node on each of its key's topics."""
        with self._lock:
            self.convert.handed(message)
            stamp_s = types.stamp_of(message, self.convert.sim_time_s)
            for t in mapping.topics:
                try:
                    converted = t.convert(message, msgs.header(stamp_s, t.frame_id), self.convert)
                except BadInput as exc:
                    self.bus.reject(spec.key(self.bus.system), f"not converted to {t.type}: {exc}")
                    continue
                if converted is not None:
                    self.publishers[self.topic(spec, t)].put(msgs.serialize(converted))
            if self.clock is not None and self.convert.sim_time_s > self.clock_s:
                self.clock_s = self.convert.sim_time_s
                clock = status.clock(None, msgs.header(self.clock_s, ""), self.convert)
                self.clock.put(msgs.serialize(clock))
        mount = motion.sensor_mount(message)
        if mount is not None and mount[0] not in self.sensor_mounts:
            self.sensor_mounts[mount[0]] = mount[1]
            self._publish_static()

    def _publish_static(self) -> None:
        """/tf_static: the arm's fixed links and the sensors mounted so far, all in one message
        (the cache of a transient local publisher of depth 1 keeps the last)."""
        if self.static is None:
            return
        with self._lock:
            static = motion.static_tf(self.convert, self.convert.sim_time_s, self.sensor_mounts)
        self.static.put(msgs.serialize(static))

    def _command(self, spec: keys.KeySpec, mapping: types.KeyMap, command: Command) -> None:
        """Hand an operator command over once the node subscribes to it, and answer for it."""
        answered = self.answers.get((command.TYPE, command.command_id))
        if answered is None:
            topics = [self.topic(spec, t) for t in mapping.topics]
            unmatched = [name for name in topics if not self.publishers[name].matched()]
            if unmatched:
                if (command.TYPE, command.command_id) not in self._waiting_logged:
                    self._waiting_logged.add((command.TYPE, command.command_id))
                    log.info(
                        "%s %d waits for a ROS 2 subscriber of %s; shore sends it again",
                        COMMAND_KINDS[command.TYPE],
                        command.command_id,
                        ", ".join(unmatched),
                    )
                return
            self._down(spec, mapping, command)
            answered = self.answers[command.TYPE, command.command_id] = CommandAck(
                command.command_id, COMMAND_KINDS[command.TYPE], ""
            )
            log.info(
                "%s %d handed to the ROS 2 node on %s",
                COMMAND_KINDS[command.TYPE],
                command.command_id,
                ", ".join(topics),
            )
        self.bus.publish("ack", answered)

    # -- up: ROS 2 -> abyss --------------------------------------------------------------
    def _up(self, spec: keys.KeySpec, t: types.RosTopic, ros_message: Any) -> None:
        """A sample the node published (checked on the wire by rmw.Subscription) to the
        station's key."""
        assert t.parse is not None
        handler = self.on_up.get(spec.topic)
        try:
            with self._lock:
                message = t.parse(ros_message, self.convert)
                if isinstance(message, NavState | JointState):  # a vehicle's: the commands' stamps
                    self.convert.handed(message)
            if message is not None and handler is not None:
                handler(message)
        except BadInput as exc:
            self.bus.reject(rmw.topic_key(self.node.domain, self.topic(spec, t), t.type), str(exc))
            return
        if message is None or handler is not None:
            return
        self.bus.publish(spec.topic, message)
        if isinstance(message, Telemetry):  # the station's own state, for scoring (keys.onboard_state_key)
            self.bus.observe(keys.onboard_state_key(self.bus.system), message)

    def close(self) -> None:
        self.node.close()
        self.session.close()


def run(config: Config, bus: Bus) -> None:
    """Onboard's entry when a ROS 2 node stands for it: the gateway alone."""
    gateway = Gateway(config, bus)
    try:
        gateway.run()
    finally:
        gateway.close()
