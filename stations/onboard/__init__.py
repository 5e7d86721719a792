"""The onboard station: the high-level controllers close to the vehicle. Waypoints and an
end-effector goal come down from the vessel; body and joint velocity references go to the
low level; the controllers' state goes up as telemetry. The control itself is `core.Onboard`,
a plain step without Zenoh; `run` is its I/O shell. Perception runs in a thread of its own: the
camera frames become coloured clouds in the world frame, and the left camera's frames go on to
the vessel; so do the sonar's, each placed where the vehicle was when it pinged."""

from __future__ import annotations

import dataclasses
import logging
import threading

import numpy as np

from abyss.common import keys
from abyss.common.bus import Bus, messages_of
from abyss.common.config import Config
from abyss.common.errors import BadInput
from abyss.common.messages import (
    ArmGoal,
    Heartbeat,
    Image,
    InterventionGoal,
    JointState,
    NavState,
    OperatorMode,
    SonarImage,
    Waypoints,
)
from abyss.common.models import CAMERAS
from abyss.common.rate import Rate
from abyss.common.workers import Workers
from abyss.stations.onboard.core import Onboard, OnboardInputs
from abyss.stations.onboard.perception import PoseHistory

log = logging.getLogger(__name__)


class Shared:
    """What the control loop hands the perception thread: poses, and where the arm is."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.poses = PoseHistory()
        self.arm_m_world = np.zeros((0, 3))


def loops(config: Config) -> tuple[str, ...]:
    """The station's named loops (lockstep runs no period before they are all there)."""
    return ("control", "perception", "sonar")


def run(config: Config, bus: Bus) -> None:
    """The I/O shell: read what came in, step the core, publish what it returns, keep the rate.
    (With `ros2.station = "onboard"`, a ROS 2 node stands for all of it: the station entry point,
    `stations.runtime.station_main`, runs the ROS 2 gateway in this station's place.)"""
    core = Onboard(config)
    shared = Shared()
    with Workers(bus.stop) as workers:
        workers.start("perception", _perception_loop, config, bus, shared, background=True)
        workers.start("sonar", _sonar_loop, bus, shared)
        _control_loop(config, bus, core, shared)


def _control_loop(config: Config, bus: Bus, core: Onboard, shared: Shared) -> None:
    nav = bus.subscribe("simulation", "nav", maxlen=8)
    joints = bus.subscribe("simulation", "joints", maxlen=4)
    goals = [
        bus.subscribe("vessel", topic)
        for topic in ("goal/waypoints", "goal/arm", "goal/mode", "goal/intervene")
    ]
    heartbeats = bus.subscribe("vessel", "heartbeat", maxlen=4)
    rate = bus.loop("control", config.onboard.control_period_s)
    while rate.sleep():
        latest_joints = messages_of([r for r in (joints.latest(),) if r is not None], JointState)
        commands = [r.message for inbox in goals for r in inbox.drain()]
        inputs = OnboardInputs(
            commands=[
                c for c in commands if isinstance(c, (Waypoints, ArmGoal, OperatorMode, InterventionGoal))
            ],
            heartbeats=messages_of(heartbeats.drain(), Heartbeat),
            nav=messages_of(nav.drain(), NavState),
            joints=latest_joints[-1] if latest_joints else None,
        )
        out = core.step(inputs, bus.clock.now_s())
        with shared.lock:
            for pose in out.poses:
                shared.poses.add(*pose)
            if out.arm_m_world is not None:
                shared.arm_m_world = out.arm_m_world
        for ack in out.acks:
            bus.publish("ack", ack)
        if out.vehicle is not None and out.arm is not None:
            bus.publish("cmd/vehicle_velocity", out.vehicle)
            bus.publish("cmd/arm_velocity", out.arm)
        if out.telemetry is not None:
            bus.publish("telemetry", out.telemetry)
            bus.observe(keys.onboard_state_key(bus.system), out.telemetry)


def _perception_loop(config: Config, bus: Bus, shared: Shared) -> None:
    """Clouds from each complete set of frames (taken at one instant), placed with the pose
    estimated for that instant; the left frame re-encoded to the vessel at its own rate."""
    from abyss.common.images import decode_image, encode_jpeg
    from abyss.stations.onboard.perception import CloudSettings, camera_in_world, clouds_of

    cfg = config.onboard
    settings = CloudSettings.of(cfg)
    needed = (
        {"cam_left"}
        | ({"cam_depth"} if "depth" in cfg.cloud_sources else set())
        | ({"cam_right"} if "stereo" in cfg.cloud_sources else set())
    )
    inboxes = {camera: bus.subscribe("simulation", f"camera/{camera}", maxlen=4) for camera in CAMERAS}
    sets: dict[float, dict[str, Image]] = {}
    last_image_s = -float("inf")
    key = keys.spec("simulation", "camera/cam_left").key(bus.system)  # where bad and shed frames are counted
    # with simulated time, a frame set being worked on holds the simulation (common.clock)
    rate = Rate(0.05, bus.stop, bus.clock, "perception")
    resting_until_s = -float("inf")
    sets_taken = 0
    while rate.sleep():
        for camera, inbox in inboxes.items():
            for received in inbox.drain():
                assert isinstance(received.message, Image)
                sets.setdefault(received.message.sim_time_s, {})[camera] = received.message
        if bus.clock.now_s() < resting_until_s:  # what comes meanwhile waits; the newest set is taken
            continue
        complete = [t for t, frames in sets.items() if needed <= set(frames)]
        if not complete:
            for t in sorted(sets)[:-4]:  # a set that never completes (a frame lost) is let go
                del sets[t]
            continue
        t = max(complete)
        frames = sets.pop(t)
        if len(complete) > 1:  # complete sets not yet processed when a newer one came: shed, the oldest first
            bus.shed(key, len(complete) - 1)
        for older in [s for s in sets if s < t]:
            del sets[older]
        with shared.lock:
            pose = shared.poses.at(t)
            arm_m_world = shared.arm_m_world.copy()
        if pose is None:
            log.debug("no navigation estimate at %.2f s; frames skipped", t)
            continue
        started_s = bus.clock.now_s()
        try:
            stereo_now = sets_taken % cfg.stereo_every == 0
            sources = tuple(s for s in cfg.cloud_sources if s != "stereo" or stereo_now)
            sets_taken += 1
            for cloud in clouds_of(frames, pose, arm_m_world, sources, settings):
                bus.publish("cloud", cloud)
            now_s = bus.clock.now_s()
            if cfg.image_rate_hz > 0 and now_s - last_image_s >= 1.0 / cfg.image_rate_hz:
                left = frames["cam_left"]
                bus.publish(
                    "image",
                    dataclasses.replace(
                        left,
                        pose_frame="world",
                        pose_camera=camera_in_world(left, pose),
                        data=encode_jpeg(decode_image(left), cfg.image_jpeg_quality),
                    ),
                )
                last_image_s = now_s
        except BadInput as exc:  # frames that do not decode, or a camera pose in the wrong frame
            bus.reject(key, str(exc))
        resting_until_s = started_s + (bus.clock.now_s() - started_s) / cfg.perception_max_busy


def _sonar_loop(bus: Bus, shared: Shared) -> None:
    """The sonar's frames on to the vessel, its pose in the world as estimated when it pinged."""
    from abyss.stations.onboard.perception import mount_in_world

    frames = bus.subscribe("simulation", "sonar", maxlen=2)
    rate = Rate(0.05, bus.stop, bus.clock, "sonar")
    while rate.sleep():
        for received in frames.drain():
            sonar = received.message
            assert isinstance(sonar, SonarImage)
            if sonar.pose_frame != "vehicle":
                bus.reject(
                    received.key,
                    f"{sonar.sonar}: pose in the {sonar.pose_frame} frame, expected the vehicle's",
                )
                continue
            with shared.lock:
                pose = shared.poses.at(sonar.sim_time_s)
            if pose is None:
                log.debug("no navigation estimate at %.2f s; sonar frame skipped", sonar.sim_time_s)
                continue
            bus.publish(
                "sonar",
                dataclasses.replace(
                    sonar, pose_frame="world", pose_sonar=mount_in_world(sonar.pose_sonar, pose)
                ),
            )
