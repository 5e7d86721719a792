"""The vessel station: relays telemetry to shore, downsampled for the satellite link, operator
commands down to the vehicle and onboard's answers to them back up; beats a heartbeat to
onboard that says whether shore is still heard. In a thread of its own it keeps the scene model
(an octree from the onboard clouds, or from the sonar's echoes while the cameras see nothing),
recognises the panel, tells shore what perception works with, and streams the scene, with a
small camera frame and a sonar frame now and then, to shore, paced by shore's acknowledgements.
The relay, perception's bookkeeping (`core.py`), the intake (`intake.py`) and the stream
(`abyss.scene.stream`) are plain cores; this module is their I/O shell."""

from __future__ import annotations

import logging
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import TYPE_CHECKING, Protocol

from abyss.bus.session import Bus, Inbox
from abyss.common.shared import Latest
from abyss.common.workers import Workers
from abyss.config import Config, site_of
from abyss.interface import keys
from abyss.interface.messages import (
    CommandAck,
    Heartbeat,
    Image,
    PointCloud,
    RecognisedObjects,
    SceneAck,
    SceneRequest,
    SceneUpdate,
    SonarImage,
    Telemetry,
)
from abyss.scene.model import SceneModel
from abyss.scene.stream import SceneStream, StreamOutputs
from abyss.stations.vessel.core import RELAYED_DOWN, Relay, RelayInputs
from abyss.stations.vessel.intake import Intake, IntakeInputs, IntakeOutputs
from abyss.timing.rate import Rate

if TYPE_CHECKING:
    from abyss.mavlink.endpoint import Endpoint

POLL_PERIOD_S = 0.05  # how long an operator command may wait on the vessel
log = logging.getLogger(__name__)


class Mapper(Protocol):
    """What maps the clouds in the scene model's place (the ROS 2 gateway, built by the station
    entry point, `launch.station`): it runs in a thread of its own until the bus stops."""

    def run(self) -> None: ...

    def close(self) -> None: ...


# builds the mapper, given what takes each map it makes (a SceneUpdate) into the scene model
MapperFactory = Callable[[Callable[[SceneUpdate], object]], Mapper]


def loops(config: Config) -> tuple[str, ...]:
    """The station's named loops (lockstep runs no period before they are all there)."""
    return ("relay", "scene", "scene send")


def run(config: Config, bus: Bus, mapper: MapperFactory | None = None) -> None:
    """The relay in the main thread; the intake (the scene model) and its stream in threads of
    their own. With `mapper` (`ros2.station = "vessel"`: the entry point's ROS 2 gateway), a ROS 2
    node is the scene model: the gateway hands it the clouds, and the model adopts each map it
    publishes instead of inserting them itself."""
    cfg = config.vessel
    model = SceneModel(
        cfg.octree_resolution_m, cfg.octree_max_range_m, cfg.scene_update_bytes, cfg.scene_track_period_s
    )
    images = bus.subscribe("onboard", "image", Image, maxlen=2)
    intake = Intake(
        cfg, site_of(config).panel, model, bus.clock.now_s(), maps=mapper is None, hybrid=config.hybrid
    )
    gateway = mapper(lambda update: model.adopt(update.octree)) if mapper is not None else None
    endpoint = _endpoint(config) if config.mavlink.enabled else None  # its port taken at start
    try:
        with Workers(bus.stop) as workers:
            if endpoint is not None:  # a ground station on the tether's side, and the satellite's relayed
                workers.start("mavlink", _serve, config, bus, endpoint)
            workers.start("scene", _scene_loop, config, bus, intake, images)
            workers.start("scene send", _send_loop, config, bus, model, images, intake)
            if gateway is not None:
                workers.start("ros2 gateway", gateway.run)
            _relay_loop(config, bus, intake.objects)
    finally:
        if gateway is not None:
            gateway.close()


def _relay_loop(config: Config, bus: Bus, objects: Latest[RecognisedObjects | None]) -> None:
    """The I/O shell of the relay (`core.Relay`)."""
    telemetry = bus.subscribe("onboard", "telemetry", Telemetry, maxlen=8)
    operator = {
        topic: bus.subscribe("onshore", topic, keys.spec("onshore", topic).message_class)
        for topic in RELAYED_DOWN
    }
    acks = bus.subscribe("onboard", "ack", CommandAck)
    shore_beats = bus.subscribe("onshore", "heartbeat", Heartbeat, maxlen=4)
    rate = bus.loop("relay", POLL_PERIOD_S)
    relay = Relay(config.vessel, site_of(config).panel, bus.clock.now_s())
    while True:
        latest = telemetry.latest()
        inputs = RelayInputs(
            commands=[(topic, r.message) for topic, inbox in operator.items() for r in inbox.drain()],
            acks=[r.message for r in acks.drain()],
            shore_heard=bool(shore_beats.drain()),
            telemetry=(latest.seq, latest.message) if latest else None,
            objects=objects.get(),
        )
        for topic, message in relay.step(inputs, bus.clock.now_s()):
            bus.publish(topic, message)
        if not rate.sleep():
            break


def _scene_loop(config: Config, bus: Bus, intake: Intake, images: Inbox[Image]) -> None:
    """The I/O shell of the intake (`intake.Intake`); another thread (`_send_loop`) streams the
    result, so that a slow insertion (a second or more for a stereo cloud on a loaded machine)
    never holds the stream back."""
    clouds = bus.subscribe("onboard", "cloud", PointCloud, maxlen=4)
    pings = bus.subscribe("onboard", "sonar", SonarImage, maxlen=4)
    rate = Rate(POLL_PERIOD_S, bus.stop, bus.clock, "scene")
    with ThreadPoolExecutor(1, "scene insertion") as worker:
        while rate.sleep():
            image = images.latest()
            inputs = IntakeInputs(
                clouds=[r.message for r in clouds.drain()],
                pings=[r.message for r in pings.drain()],
                image=image.message if image else None,
            )
            taken_s = bus.clock.now_s()
            out, cells = intake.take(inputs, taken_s)
            if cells:
                # into the octree in a thread of its own; on simulated time its changes are queued
                # for shore vessel.insertion_latency_s after they came, the relay and the stream
                # going on meanwhile, which never touch the octree (Clock.after_work)
                work = worker.submit(intake.integrate, cells)
                if not bus.clock.after_work(taken_s, config.vessel.insertion_latency_s, bus.stop):
                    break
                work.result()
                rate.forgive()  # its next tick counts from now
            _publish(bus, intake.settle(cells, inputs.image, taken_s, out))


def _publish(bus: Bus, out: IntakeOutputs | StreamOutputs) -> None:
    """What a core returned: its rejections counted on onboard's keys, its messages published."""
    for topic, reason in out.rejected:
        bus.reject(keys.spec("onboard", topic).key(bus.system), reason)
    for topic, message in out.messages:
        bus.publish(topic, message)


def _send_loop(config: Config, bus: Bus, model: SceneModel, images: Inbox[Image], intake: Intake) -> None:
    """The I/O shell of the scene stream (`abyss.scene.stream.SceneStream`), paced by shore's
    acknowledgements."""
    requests = bus.subscribe("onshore", "scene_request", SceneRequest)
    acks = bus.subscribe("onshore", "scene_ack", SceneAck, maxlen=256)
    stream = SceneStream(config.vessel, model)
    rate = Rate(POLL_PERIOD_S, bus.stop, bus.clock, "scene send")
    while rate.sleep():
        image = images.latest()
        frame = image.message if image else None
        out = stream.step(
            bus.clock.now_s(),
            intake.sim_time_s.get(),
            [r.message for r in acks.drain()],
            bool(requests.drain()),
            frame,
            intake.sonar.get(),
        )
        _publish(bus, out)


def _endpoint(config: Config) -> Endpoint:
    """The ground stations' endpoint (mavlink.enabled; pymavlink's, imported only then)."""
    from abyss.mavlink.endpoint import Endpoint

    return Endpoint(config, "vessel")


def _serve(config: Config, bus: Bus, endpoint: Endpoint) -> None:
    from abyss.mavlink.endpoint import serve

    serve(config, bus, endpoint)
