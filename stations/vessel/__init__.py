"""The vessel station: relays telemetry to shore, downsampled for the satellite link, operator
commands down to the vehicle and onboard's answers to them back up; beats a heartbeat to
onboard that says whether shore is still heard. In a thread of its own it keeps the scene model
(an octree from the onboard clouds, or from the sonar's echoes while the cameras see nothing),
recognises the panel, tells shore what perception works with, and streams the scene, with a
small camera frame and a sonar frame now and then, to shore, paced by shore's acknowledgements.
The relay, perception's bookkeeping and the stream are plain cores (`core.py`); this module is
their I/O shell."""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING

import numpy as np

from abyss.common import keys
from abyss.common.bus import Bus, Inbox, messages_of
from abyss.common.clouds import unpack_cloud
from abyss.common.config import Config
from abyss.common.errors import BadInput
from abyss.common.images import decode_image
from abyss.common.messages import (
    CommandAck,
    Image,
    PointCloud,
    RecognisedObjects,
    SceneAck,
    SonarImage,
    Telemetry,
)
from abyss.common.rate import Rate
from abyss.common.sonar import ECHO_RGB, echo_arcs
from abyss.common.workers import Workers
from abyss.stations.vessel.core import RELAYED_DOWN, Perception, Relay, RelayInputs, SceneStream

if TYPE_CHECKING:
    from abyss.common.scene import SceneModel

POLL_PERIOD_S = 0.05  # how long an operator command may wait on the vessel
log = logging.getLogger(__name__)


def loops(config: Config) -> tuple[str, ...]:
    """The station's named loops (lockstep runs no period before they are all there)."""
    return ("relay", "scene", "scene send")


def run(config: Config, bus: Bus) -> None:
    """The relay in the main thread; the scene model and its stream in threads of their own.
    With `ros2.station = "vessel"`, a ROS 2 node is the scene model: the ROS 2 gateway hands it
    the clouds, and the model adopts each map it publishes instead of inserting them itself."""
    from abyss.common.scene import SceneModel

    cfg = config.vessel
    model = SceneModel(
        cfg.octree_resolution_m, cfg.octree_max_range_m, cfg.scene_update_bytes, cfg.scene_track_period_s
    )
    images = bus.subscribe("onboard", "image", maxlen=2)
    sim_time_s = [0.0]  # of the latest cloud, shared by the model and the stream
    objects: list[RecognisedObjects | None] = [None]  # recognition's latest, for the relay
    sonar: list[SonarImage | None] = [None]  # the sonar's latest frame, for the stream
    gateway = None
    if config.ros2.station == "vessel":
        from abyss.ros2.gateway import Gateway

        gateway = Gateway(config, bus, on_up={"scene": lambda update: model.adopt(update.octree)})
    try:
        with Workers(bus.stop) as workers:
            workers.start(
                "scene", _scene_loop, config, bus, model, images, sim_time_s, objects, sonar, gateway is None
            )
            workers.start("scene send", _send_loop, config, bus, model, images, sim_time_s, sonar)
            if gateway is not None:
                workers.start("ros2 gateway", gateway.run)
            _relay_loop(config, bus, objects)
    finally:
        if gateway is not None:
            gateway.close()


def _relay_loop(config: Config, bus: Bus, objects: list[RecognisedObjects | None]) -> None:
    """The I/O shell of the relay (`core.Relay`)."""
    telemetry = bus.subscribe("onboard", "telemetry", maxlen=8)
    operator = {topic: bus.subscribe("onshore", topic) for topic in RELAYED_DOWN}
    acks = bus.subscribe("onboard", "ack")
    shore_beats = bus.subscribe("onshore", "heartbeat", maxlen=4)
    rate = bus.loop("relay", POLL_PERIOD_S)
    relay = Relay(config.vessel, bus.clock.now_s())
    while True:
        latest = telemetry.latest()
        onboard_state = latest.message if latest and isinstance(latest.message, Telemetry) else None
        inputs = RelayInputs(
            commands=[(topic, r.message) for topic, inbox in operator.items() for r in inbox.drain()],
            acks=messages_of(acks.drain(), CommandAck),
            shore_heard=bool(shore_beats.drain()),
            telemetry=(latest.seq, onboard_state) if latest and onboard_state else None,
            objects=objects[0],
        )
        for topic, message in relay.step(inputs, bus.clock.now_s()):
            bus.publish(topic, message)
        if not rate.sleep():
            break


def _scene_loop(
    config: Config,
    bus: Bus,
    model: SceneModel,
    images: Inbox,
    sim_time_s: list[float],
    recognised: list[RecognisedObjects | None],
    sonar: list[SonarImage | None],
    insert: bool = True,
) -> None:
    """Integrate the clouds (unless a ROS 2 node maps them: `insert` False), or the sonar's
    echoes while the cameras see nothing, recognise the panel, and tell shore what perception
    works with; another thread (`_send_loop`) streams the result, so that a slow insertion (a
    second or more for a stereo cloud on a loaded machine) never holds the stream back."""
    from abyss.stations.vessel.recognition import PanelTracker

    cfg = config.vessel
    clouds = bus.subscribe("onboard", "cloud", maxlen=4)
    pings = bus.subscribe("onboard", "sonar", maxlen=4)
    tracker = PanelTracker(bias_m_world=cfg.recognition_bias_m)
    perception = Perception(cfg)
    rate = Rate(POLL_PERIOD_S, bus.stop, bus.clock, "scene")  # with simulated time, an insertion holds it
    last_recognition_s = last_status_s = -float("inf")
    inserted_s = bus.clock.now_s()  # when the model last took a cloud or echoes
    points: np.ndarray | None = None
    while rate.sleep():
        for received in clouds.drain():
            assert isinstance(received.message, PointCloud)
            cloud = received.message
            cloud_points, colors = unpack_cloud(cloud)
            perception.received(cloud.source, len(cloud_points), bus.clock.now_s())
            if insert:
                model.insert(cloud_points, colors, cloud.sensor_m_world, cloud.sim_time_s)
                inserted_s = bus.clock.now_s()
            sim_time_s[0] = cloud.sim_time_s
            if cloud.source == "depth" or points is None:
                points = cloud_points
        for received in pings.drain():
            assert isinstance(received.message, SonarImage)
            sonar[0] = received.message
            try:
                echoes, origin = echo_arcs(received.message, cfg.octree_resolution_m)
            except BadInput as exc:
                bus.reject(received.key, str(exc))
                continue
            perception.received("sonar", len(echoes), bus.clock.now_s())
            if insert and perception.sonar_feeds(bus.clock.now_s()) and len(echoes):
                model.insert(
                    echoes,
                    np.tile(np.array(ECHO_RGB, np.uint8), (len(echoes), 1)),
                    origin,
                    received.message.sim_time_s,
                )
                inserted_s = bus.clock.now_s()
                sim_time_s[0] = max(sim_time_s[0], received.message.sim_time_s)
        now_s = bus.clock.now_s()
        if insert and now_s - inserted_s >= cfg.scene_track_period_s:
            model.flush()  # what the last clouds changed, once no more came for a period
        if now_s - last_status_s >= cfg.perception_period_s:
            last_status_s = now_s
            bus.publish("perception", perception.status(now_s, recognised[0], sim_time_s[0]))
        image = images.latest()
        due = now_s - last_recognition_s >= cfg.recognition_period_s
        if due and (image is not None or points is not None):
            last_recognition_s = now_s
            rgb = None
            if image is not None:
                assert isinstance(image.message, Image)
                try:
                    if image.message.pose_frame != "world":
                        raise BadInput(
                            f"camera pose in the {image.message.pose_frame} frame; the vessel "
                            "needs it in the world frame"
                        )
                    rgb = decode_image(image.message)
                except BadInput as exc:
                    bus.reject(image.key, str(exc))
            tracker.update(rgb, image.message if image is not None else None, points)  # type: ignore[arg-type]
            objects = tracker.objects(sim_time_s[0])
            if objects is not None:
                recognised[0] = objects
                bus.publish("objects", objects)


def _send_loop(
    config: Config,
    bus: Bus,
    model: SceneModel,
    images: Inbox,
    sim_time_s: list[float],
    sonar: list[SonarImage | None],
) -> None:
    """The I/O shell of the scene stream (`core.SceneStream`), paced by shore's acknowledgements."""
    requests = bus.subscribe("onshore", "scene_request")
    acks = bus.subscribe("onshore", "scene_ack", maxlen=256)
    stream = SceneStream(config.vessel, model)
    rate = Rate(POLL_PERIOD_S, bus.stop, bus.clock, "scene send")
    while rate.sleep():
        image = images.latest()
        frame = image.message if image and isinstance(image.message, Image) else None
        out = stream.step(
            bus.clock.now_s(),
            sim_time_s[0],
            messages_of(acks.drain(), SceneAck),
            bool(requests.drain()),
            frame,
            sonar[0],
        )
        for topic, reason in out.rejected:
            bus.reject(keys.spec("onboard", topic).key(bus.system), reason)
        for topic, message in out.messages:
            bus.publish(topic, message)
