"""The onboard station: the high-level controllers close to the vehicle. Waypoints and an
end-effector goal come down from the vessel; body and joint velocity references go to the
low level; the controllers' state goes up as telemetry. The control itself is `core.Onboard`,
a plain step without Zenoh; `run` is its I/O shell. Perception runs in a thread of its own: the
camera frames become coloured clouds in the world frame, and the left camera's frames go on to
the vessel; so do the sonar's, each placed where the vehicle was when it pinged."""

from __future__ import annotations

import dataclasses
import logging
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from abyss.bus.session import Bus
from abyss.common.shared import Latest
from abyss.common.workers import Workers
from abyss.config import Config, robot_of
from abyss.interface import keys
from abyss.interface.messages import (
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
from abyss.stations.onboard.core import Onboard, OnboardInputs
from abyss.stations.onboard.ground import ground_of
from abyss.stations.onboard.navigation import PoseHistory
from abyss.timing.rate import Rate

if TYPE_CHECKING:
    from abyss.stations.onboard.frame_sets import FrameSetOutputs

log = logging.getLogger(__name__)


@dataclass
class Shared:
    """What the control loop hands the perception and sonar threads: the navigation estimate over
    the last seconds, and where the arm is [m, world] (for the clouds' self-filter)."""

    poses: Latest[PoseHistory] = field(default_factory=lambda: Latest(PoseHistory()))
    arm_m_world: Latest[np.ndarray] = field(default_factory=lambda: Latest(np.zeros((0, 3))))


def loops(config: Config) -> tuple[str, ...]:
    """The station's named loops (lockstep runs no period before they are all there)."""
    return ("control", "perception", "sonar")


def run(config: Config, bus: Bus) -> None:
    """The I/O shell: read what came in, step the core, publish what it returns, keep the rate.
    (With `ros2.station = "onboard"`, a ROS 2 node stands for all of it: the station entry point,
    `launch.station.station_main`, runs the ROS 2 gateway in this station's place.)"""
    core = Onboard(config)
    shared = Shared()
    with Workers(bus.stop) as workers:
        workers.start("perception", _perception_loop, config, bus, shared, background=True)
        workers.start("sonar", _sonar_loop, bus, shared)
        _control_loop(config, bus, core, shared)


def wrong_joints(joints: JointState, arm_joints: int) -> str:
    """Why a JointState does not fit an arm of `arm_joints` joints ("" when it does)."""
    counts = {len(joints.positions_rad), len(joints.velocities_radps)}
    return (
        ""
        if counts == {arm_joints}
        else f"{'/'.join(map(str, sorted(counts)))} joints, the robot's arm has {arm_joints}"
    )


def _control_loop(config: Config, bus: Bus, core: Onboard, shared: Shared) -> None:
    nav = bus.subscribe("simulation", "nav", NavState, maxlen=8)
    joints = bus.subscribe("simulation", "joints", JointState, maxlen=4)
    waypoints = bus.subscribe("vessel", "goal/waypoints", Waypoints)
    arm_goals = bus.subscribe("vessel", "goal/arm", ArmGoal)
    modes = bus.subscribe("vessel", "goal/mode", OperatorMode)
    interventions = bus.subscribe("vessel", "goal/intervene", InterventionGoal)
    heartbeats = bus.subscribe("vessel", "heartbeat", Heartbeat, maxlen=4)
    rate = bus.loop("control", config.onboard.control_period_s)
    arm_joints, latest_joints = len(robot_of(config).arm_joints), None
    ground = ground_of(config, bus, core) if config.mavlink.enabled else None
    while rate.sleep():
        for received in joints.drain():  # a vehicle's joints (a hybrid run's real one) may not fit the robot
            wrong = wrong_joints(received.message, arm_joints)
            if wrong:
                bus.reject(keys.spec("simulation", "joints").key(bus.system), wrong)
            else:
                latest_joints = received
        inputs = OnboardInputs(
            commands=[
                *(r.message for r in waypoints.drain()),
                *(r.message for r in arm_goals.drain()),
                *(r.message for r in modes.drain()),
                *(r.message for r in interventions.drain()),
                *(ground.take(bus.clock.now_s()) if ground is not None else ()),
            ],
            heartbeats=[r.message for r in heartbeats.drain()],
            nav=[r.message for r in nav.drain()],
            joints=latest_joints.message if latest_joints is not None else None,
        )
        out = core.step(inputs, bus.clock.now_s())
        if out.estimates:  # this loop is the only one that writes the poses
            poses = [(e.sim_time_s, e.position_m_world, e.orientation_wxyz_world) for e in out.estimates]
            shared.poses.set(shared.poses.get().added(poses))
        for estimate in out.estimates:
            bus.publish("nav/estimate", estimate)
        if out.arm_m_world is not None:
            arm_m_world = out.arm_m_world.copy()
            arm_m_world.flags.writeable = False
            shared.arm_m_world.set(arm_m_world)
        if ground is not None:  # the ground station's commands' answers are its own
            out.acks = ground.answer(out, bus.clock.now_s())
        for ack in out.acks:
            bus.publish("ack", ack)
        if out.vehicle is not None and out.arm is not None:
            bus.publish("cmd/vehicle_velocity", out.vehicle)
            bus.publish("cmd/arm_velocity", out.arm)
        if out.telemetry is not None:
            bus.publish("telemetry", out.telemetry)
            bus.observe(keys.onboard_state_key(bus.system), out.telemetry)


def _perception_loop(config: Config, bus: Bus, shared: Shared) -> None:
    """The I/O shell of the frame sets (frame_sets.FrameSets): frames in, clouds and the left
    camera's image out, bad frames rejected and shed sets counted on the left camera's key."""
    from abyss.stations.onboard.frame_sets import FrameSetInputs, FrameSets  # OpenCV's, on first use

    robot = robot_of(config)
    core = FrameSets(config.onboard, config.simulation.camera_rate_hz, robot.spec.cameras)
    inboxes = {
        camera: bus.subscribe("simulation", robot.camera_topic(camera), Image, maxlen=4)
        for camera in robot.cameras
    }
    # where bad and shed frames are counted: the stereo pair's left camera's key
    key = keys.spec("simulation", robot.camera_topic(robot.stereo_left)).key(bus.system)
    rate = Rate(0.05, bus.stop, bus.clock, "perception")
    with ThreadPoolExecutor(1, "perception work") as worker:
        while rate.sleep():
            frames = [(camera, frame.message) for camera, inbox in inboxes.items() for frame in inbox.drain()]
            taken_s = bus.clock.now_s()
            out, job = core.take(
                FrameSetInputs(frames, shared.poses.get(), shared.arm_m_world.get()), taken_s
            )
            if job is not None:
                # the set's work runs in a thread of its own; on simulated time its clouds go out
                # onboard.perception_latency_s after the set was taken, the station's other loops
                # and the simulation going on meanwhile (Clock.after_work)
                work = worker.submit(core.work, job, out)
                if not bus.clock.after_work(taken_s, config.onboard.perception_latency_s, bus.stop):
                    break
                work.result()
                rate.forgive()  # its next tick counts from now
            _publish_frame_set(bus, key, out)
            core.finished(bus.clock.now_s())


def _publish_frame_set(bus: Bus, key: str, out: FrameSetOutputs) -> None:
    """What a frame set gave: shed sets and bad frames counted on `key`, its messages published."""
    if out.shed:
        bus.shed(key, out.shed)
    for reason in out.rejected:
        bus.reject(key, reason)
    for cloud in out.clouds:
        bus.publish("cloud", cloud)
    if out.image is not None:
        bus.publish("image", out.image)


def _sonar_loop(bus: Bus, shared: Shared) -> None:
    """The sonar's frames on to the vessel, its pose in the world as estimated when it pinged."""
    from abyss.stations.onboard.perception import mount_in_world

    frames = bus.subscribe("simulation", "sonar", SonarImage, maxlen=2)
    rate = Rate(0.05, bus.stop, bus.clock, "sonar")
    while rate.sleep():
        for received in frames.drain():
            sonar = received.message
            if sonar.pose_frame != "vehicle":
                bus.reject(
                    received.key,
                    f"{sonar.sonar}: pose in the {sonar.pose_frame} frame, expected the vehicle's",
                )
                continue
            pose = shared.poses.get().at(sonar.sim_time_s)
            if pose is None:
                log.debug("no navigation estimate at %.2f s; sonar frame skipped", sonar.sim_time_s)
                continue
            bus.publish(
                "sonar",
                dataclasses.replace(
                    sonar, pose_frame="world", pose_sonar=mount_in_world(sonar.pose_sonar, pose)
                ),
            )
