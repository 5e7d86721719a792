"""The onboard station: the high-level controllers close to the vehicle. Waypoints and an
end-effector goal come down from the vessel; body and joint velocity references go to the
low level; the controllers' state goes up as telemetry. The arm moves once the vehicle holds
its last waypoint (with `onboard.whole_body`, the vehicle then moves with the arm); both hold
still while the failsafe is on or the operator says hold (in teleop mode the arm follows its
goal at once). Each operator command is checked (`commands.py`) and acknowledged with its fate
before it is flown. Perception runs in a thread of its own: the camera frames
become coloured clouds in the world frame, and the left camera's frames go on to the vessel."""

from __future__ import annotations

import dataclasses
import logging
import threading
import time

import numpy as np
from abyss.common import keys
from abyss.common.bus import Bus
from abyss.common.config import Config
from abyss.common.geometry import quat_wxyz_of, yaw_of
from abyss.common.messages import (
    ArmGoal,
    ArmVelocityRef,
    Heartbeat,
    Image,
    JointState,
    NavState,
    OperatorMode,
    Telemetry,
    VelocityRef,
    Waypoints,
)
from abyss.common.models import ARM_JOINTS, CAMERAS
from abyss.common.rate import Rate
from abyss.stations.onboard.arm_control import ArmController
from abyss.stations.onboard.commands import CommandGate
from abyss.stations.onboard.failsafe import Failsafe
from abyss.stations.onboard.navigation import NavFilter
from abyss.stations.onboard.perception import PoseHistory
from abyss.stations.onboard.vehicle_control import VehicleController

GRIPPER_OPENING_M = 0.03  # opened while reaching, so the fingers pass either side of a handle
GRIPPER_GAIN_PER_S = 2.0
log = logging.getLogger(__name__)


class Shared:
    """What the control loop hands the perception thread: poses, and where the arm is."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.poses = PoseHistory()
        self.arm_m_world = np.zeros((0, 3))


def run(config: Config, bus: Bus) -> None:
    cfg = config.onboard
    vehicle = VehicleController(cfg, config.mission)
    arm = ArmController(cfg, config.mission)
    nav_filter = NavFilter(cfg.nav_time_constant_s)
    failsafe = Failsafe(cfg.goal_timeout_s, cfg.hold_on_shore_loss)
    gate = CommandGate(config.mission, *arm.kinematics.reach())
    operator_mode = "auto"
    nav = bus.subscribe("simulation", "nav", maxlen=8)
    joints = bus.subscribe("simulation", "joints", maxlen=4)
    waypoint_goals = bus.subscribe("vessel", "goal/waypoints")
    arm_goals = bus.subscribe("vessel", "goal/arm")
    mode_goals = bus.subscribe("vessel", "goal/mode")
    heartbeats = bus.subscribe("vessel", "heartbeat", maxlen=4)
    shared = Shared()
    perception = threading.Thread(target=_perception_loop, args=(config, bus, shared), name="perception",
                                  daemon=True)
    perception.start()
    rate = Rate(cfg.control_period_s, bus.stop)
    every = max(1, round(cfg.telemetry_period_s / cfg.control_period_s))
    position_m_world: np.ndarray | None = None
    orientation_wxyz_world = np.array([1.0, 0.0, 0.0, 0.0])
    tick = 0
    while rate.sleep():
        now_s = time.monotonic()
        for goal in (*waypoint_goals.drain(), *arm_goals.drain(), *mode_goals.drain()):
            command = goal.message
            where = vehicle.waypoints[-1] if len(vehicle.waypoints) else (  # where the vehicle will hold
                np.r_[position_m_world, yaw_of(orientation_wxyz_world)] if position_m_world is not None
                else np.zeros(4))
            ack, taken = gate.answer(command, where)
            bus.publish("ack", ack)
            if not taken:
                log.info("%s command %d not taken: %s", ack.command, ack.command_id, ack.reason or "a resend")
            elif isinstance(command, Waypoints):
                vehicle.set_waypoints(command.command_id, command.waypoints)
            elif isinstance(command, ArmGoal):
                arm.set_goal(command.command_id, command.position_m_world, command.orientation_wxyz_world)
            elif isinstance(command, OperatorMode):
                operator_mode = command.mode
        for beat in heartbeats.drain():
            assert isinstance(beat.message, Heartbeat)
            failsafe.heard(now_s, beat.message)
        for fix in nav.drain():
            assert isinstance(fix.message, NavState)
            position_m_world, orientation_wxyz_world = nav_filter.update(fix.message)
            sim_time_s = fix.message.sim_time_s
            with shared.lock:
                shared.poses.add(sim_time_s, position_m_world, orientation_wxyz_world)
        latest_joints = joints.latest()
        if position_m_world is None or latest_joints is None:
            continue
        assert isinstance(latest_joints.message, JointState)
        arm_rad = latest_joints.message.positions_rad
        hold = failsafe.check(now_s, bus.link_down("tether")) or (
            "operator hold" if operator_mode == "hold" else "")
        yaw = yaw_of(orientation_wxyz_world)
        out = vehicle.step(position_m_world, yaw, cfg.control_period_s, hold=bool(hold))
        arm_free = out.mode in ("reached", "idle") or operator_mode == "teleop"
        arm_out = arm.step(position_m_world, orientation_wxyz_world, arm_rad, enabled=not hold and arm_free)
        with shared.lock:
            shared.arm_m_world = arm.kinematics.chain_m_world()
        linear, yaw_rate = out.linear_mps_body, out.yaw_rate_radps
        if arm_out.vehicle_velocity is not None and arm_out.mode in ("moving", "reached"):
            linear, yaw_rate = arm_out.vehicle_velocity[:3], float(arm_out.vehicle_velocity[3])
        bus.publish("cmd/vehicle_velocity", VelocityRef(linear, yaw_rate))
        gripper_mps = 0.0
        if arm_out.mode in ("moving", "reached"):
            opening_error_m = GRIPPER_OPENING_M - latest_joints.message.gripper_opening_m
            gripper_mps = float(np.clip(GRIPPER_GAIN_PER_S * opening_error_m, -0.05, 0.05))
        bus.publish("cmd/arm_velocity", ArmVelocityRef(arm_out.joint_velocities_radps, gripper_mps))
        if tick % every == 0:
            ee_pose = arm.kinematics.pose(arm.kinematics.ee)
            state = Telemetry(
                position_m_world=position_m_world, yaw_rad=yaw, mode=out.mode, command_id=vehicle.command_id,
                waypoint_index=out.waypoint_index, waypoints_total=out.waypoints_total,
                position_error_m_world=out.position_error_m_world, heading_error_rad=out.heading_error_rad,
                arm_mode=arm_out.mode, arm_command_id=arm.command_id,
                ee_position_error_m_world=arm_out.position_error_m_world,
                ee_orientation_error_rad=arm_out.orientation_error_rad,
                ee_position_m_world=ee_pose.translation,
                ee_orientation_wxyz_world=quat_wxyz_of(ee_pose.rotation),
                arm_positions_rad=arm_rad[:len(ARM_JOINTS)], failsafe=hold,
                failsafe_events=failsafe.events, sim_time_s=sim_time_s, operator_mode=operator_mode)
            bus.publish("telemetry", state)
            bus.observe(keys.onboard_state_key(bus.system), state)
        tick += 1
    perception.join(timeout=5.0)


def _perception_loop(config: Config, bus: Bus, shared: Shared) -> None:
    """Clouds from each complete set of frames (taken at one instant), placed with the pose
    estimated for that instant; the left frame re-encoded to the vessel at its own rate."""
    from abyss.common.images import decode_image, encode_jpeg
    from abyss.stations.onboard.perception import CloudSettings, camera_in_world, clouds_of

    cfg = config.onboard
    settings = CloudSettings(cfg.cloud_voxel_m, cfg.cloud_max_range_m, cfg.cloud_scale_m,
                             cfg.stereo_disparities,
                             cfg.self_filter_radius_m)
    needed = {"cam_left"} | ({"cam_depth"} if "depth" in cfg.cloud_sources else set()) | (
        {"cam_right"} if "stereo" in cfg.cloud_sources else set())
    inboxes = {camera: bus.subscribe("simulation", f"camera/{camera}", maxlen=4) for camera in CAMERAS}
    sets: dict[float, dict[str, Image]] = {}
    last_image_s = -float("inf")
    key = keys.spec("simulation", "camera/cam_left").key(bus.system)  # where bad frames are counted
    rate = Rate(0.05, bus.stop)
    while rate.sleep():
        for camera, inbox in inboxes.items():
            for received in inbox.drain():
                assert isinstance(received.message, Image)
                sets.setdefault(received.message.sim_time_s, {})[camera] = received.message
        complete = [t for t, frames in sets.items() if needed <= set(frames)]
        if not complete:
            for t in sorted(sets)[:-4]:  # a set that never completes (a frame lost) is let go
                del sets[t]
            continue
        t = max(complete)
        frames = sets.pop(t)
        for older in [s for s in sets if s < t]:
            del sets[older]
        with shared.lock:
            pose = shared.poses.at(t)
            arm_m_world = shared.arm_m_world.copy()
        if pose is None:
            log.debug("no navigation estimate at %.2f s; frames skipped", t)
            continue
        try:
            for cloud in clouds_of(frames, pose, arm_m_world, cfg.cloud_sources, settings):
                bus.publish("cloud", cloud)
            now_s = time.monotonic()
            if cfg.image_rate_hz > 0 and now_s - last_image_s >= 1.0 / cfg.image_rate_hz:
                left = frames["cam_left"]
                bus.publish("image", dataclasses.replace(
                    left, pose_frame="world", pose_camera=camera_in_world(left, pose),
                    data=encode_jpeg(decode_image(left), cfg.image_jpeg_quality)))
                last_image_s = now_s
        except ValueError as exc:  # frames that do not decode, or a camera pose in the wrong frame
            bus.reject(key, str(exc))
