"""The vessel station: relays telemetry to shore, downsampled for the satellite link, operator
commands down to the vehicle and onboard's answers to them back up; beats a heartbeat to
onboard that says whether shore is still heard. In a thread of its own it keeps the scene model
(an octree from the onboard clouds), recognises the panel, and streams both, with a small camera
frame now and then, to shore paced for the satellite link."""

from __future__ import annotations

import logging
import threading
import time
from typing import TYPE_CHECKING

import numpy as np
from abyss.common import keys
from abyss.common.bus import Bus, Inbox
from abyss.common.clouds import unpack_cloud
from abyss.common.config import Config
from abyss.common.images import decode_image, downscale
from abyss.common.messages import Heartbeat, Image, PointCloud
from abyss.common.rate import Rate
from abyss.stations.vessel.pacing import ScenePacer

if TYPE_CHECKING:
    from abyss.common.scene import SceneModel

RELAYED_DOWN = {"op/waypoints": "goal/waypoints", "op/arm": "goal/arm", "op/mode": "goal/mode"}
POLL_PERIOD_S = 0.05  # how long an operator command may wait on the vessel
log = logging.getLogger(__name__)


def run(config: Config, bus: Bus) -> None:
    cfg = config.vessel
    scene = threading.Thread(target=_scene_loop, args=(config, bus), name="scene", daemon=True)
    scene.start()
    telemetry = bus.subscribe("onboard", "telemetry", maxlen=8)
    operator = {topic: bus.subscribe("onshore", topic) for topic in RELAYED_DOWN}
    acks = bus.subscribe("onboard", "ack")
    shore_beats = bus.subscribe("onshore", "heartbeat", maxlen=4)
    rate = Rate(POLL_PERIOD_S, bus.stop)
    shore_heard_s = started_s = time.monotonic()
    last_beat_s = last_relay_s = -float("inf")
    forwarded_seq = -1
    while True:
        now_s = time.monotonic()
        for topic, inbox in operator.items():  # commands go down as soon as they are seen
            for command in inbox.drain():
                bus.publish(RELAYED_DOWN[topic], command.message)
        for ack in acks.drain():
            bus.publish("ack", ack.message)
        if shore_beats.drain():
            shore_heard_s = now_s
        if now_s - last_beat_s >= cfg.heartbeat_period_s:
            silence_s = now_s - max(shore_heard_s, started_s)
            bus.publish("heartbeat", Heartbeat(silence_s, silence_s < cfg.shore_timeout_s))
            last_beat_s = now_s
        latest = telemetry.latest()
        due = now_s - last_relay_s >= cfg.telemetry_period_s
        if due and latest is not None and latest.seq != forwarded_seq:
            bus.publish("telemetry", latest.message)
            forwarded_seq, last_relay_s = latest.seq, now_s
        if not rate.sleep():
            break
    scene.join(timeout=30.0)  # one loop at most: an octree insertion, a recognition


def _scene_loop(config: Config, bus: Bus) -> None:
    """Integrate the clouds and recognise the panel; a thread of its own (`_send_loop`) streams
    the result, so that a slow insertion (a second or more for a stereo cloud on a loaded
    machine) never holds the stream back."""
    from abyss.common.scene import SceneModel
    from abyss.stations.vessel.recognition import PanelTracker

    cfg = config.vessel
    clouds = bus.subscribe("onboard", "cloud", maxlen=4)
    images = bus.subscribe("onboard", "image", maxlen=2)
    model = SceneModel(cfg.octree_resolution_m, cfg.octree_max_range_m, cfg.scene_update_bytes)
    tracker = PanelTracker()
    sim_time_s = [0.0]  # of the latest cloud, shared with the sender
    sender = threading.Thread(target=_send_loop, args=(config, bus, model, images, sim_time_s),
                              name="scene send", daemon=True)
    sender.start()
    rate = Rate(POLL_PERIOD_S, bus.stop)
    last_recognition_s = -float("inf")
    points: np.ndarray | None = None
    while rate.sleep():
        for received in clouds.drain():
            assert isinstance(received.message, PointCloud)
            cloud = received.message
            cloud_points, colors = unpack_cloud(cloud)
            model.insert(cloud_points, colors, cloud.sensor_m_world)
            sim_time_s[0] = cloud.sim_time_s
            if cloud.source == "depth" or points is None:
                points = cloud_points
        now_s = time.monotonic()
        image = images.latest()
        due = now_s - last_recognition_s >= cfg.recognition_period_s
        if due and (image is not None or points is not None):
            last_recognition_s = now_s
            rgb = None
            if image is not None:
                assert isinstance(image.message, Image)
                try:
                    if image.message.pose_frame != "world":
                        raise ValueError(f"camera pose in the {image.message.pose_frame} frame; the vessel "
                                         "needs it in the world frame")
                    rgb = decode_image(image.message)
                except ValueError as exc:
                    bus.reject(image.key, str(exc))
            tracker.update(rgb, image.message if image is not None else None, points)  # type: ignore[arg-type]
            objects = tracker.objects(sim_time_s[0])
            if objects is not None:
                bus.publish("objects", objects)
    sender.join(timeout=10.0)


def _send_loop(config: Config, bus: Bus, model: SceneModel, images: Inbox,
               sim_time_s: list[float]) -> None:
    """Scene updates, and now and then a small camera frame, paced for the satellite link."""
    cfg = config.vessel
    requests = bus.subscribe("onshore", "scene_request")
    satellite = bus.links["satellite"]
    bulk_keys = {keys.spec("vessel", topic).key(bus.system) for topic in ("scene", "image")}  # paced
    first_guess_bps = ScenePacer.first_guess(satellite.profile.rate_bps, cfg.satellite_capacity_bps)
    pacer = ScenePacer(cfg.scene_share, first_guess_bps, cfg.scene_update_bytes)
    rate = Rate(POLL_PERIOD_S, bus.stop)
    last_image_s = -float("inf")
    while rate.sleep():
        if requests.drain():
            model.request_snapshot()
        now_s = time.monotonic()
        pacer.observe(now_s, satellite.snapshot()["bytes_delivered"], satellite.in_flight(bulk_keys))
        while pacer.allows(satellite.in_flight(bulk_keys)):
            image = images.latest()
            if image is not None and now_s - last_image_s >= cfg.image_period_s:
                last_image_s = now_s
                assert isinstance(image.message, Image)
                try:
                    small = downscale(image.message, cfg.image_scale, cfg.image_jpeg_quality)
                except ValueError as exc:
                    bus.reject(image.key, str(exc))
                    continue
                bus.publish("image", small)
                pacer.sent(len(small.data))
                continue
            update = model.next_update(sim_time_s[0], pacer.update_bytes())
            if update is None:
                break
            bus.publish("scene", update)
            pacer.sent(len(update.octree) + update.colors.nbytes)
