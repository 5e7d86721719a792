"""The onboard station: the high-level controllers close to the vehicle. Waypoints and an
end-effector goal come down from the vessel; body and joint velocity references go to the
low level; the controllers' state goes up as telemetry. The arm moves once the vehicle holds
its last waypoint (with `onboard.whole_body`, the vehicle then moves with the arm); both hold
still while the failsafe is on."""

from __future__ import annotations

import time

import numpy as np

from common.bus import Bus
from common.config import Config
from common.geometry import quat_wxyz_of, yaw_of
from common.messages import (
    ArmGoal,
    ArmVelocityRef,
    Heartbeat,
    JointState,
    NavState,
    Telemetry,
    VelocityRef,
    Waypoints,
)
from common.models import ARM_JOINTS
from common.rate import Rate
from stations.onboard.arm_control import ArmController
from stations.onboard.failsafe import Failsafe
from stations.onboard.navigation import NavFilter
from stations.onboard.vehicle_control import VehicleController

GRIPPER_OPENING_M = 0.03  # opened while reaching, so the fingers pass either side of a handle
GRIPPER_GAIN_PER_S = 2.0


def run(config: Config, bus: Bus) -> None:
    cfg = config.onboard
    vehicle = VehicleController(cfg, config.mission)
    arm = ArmController(cfg, config.mission)
    nav_filter = NavFilter(cfg.nav_time_constant_s)
    failsafe = Failsafe(cfg.goal_timeout_s, cfg.hold_on_shore_loss)
    nav = bus.subscribe("simulation", "nav", maxlen=8)
    joints = bus.subscribe("simulation", "joints", maxlen=4)
    waypoint_goals = bus.subscribe("vessel", "goal/waypoints")
    arm_goals = bus.subscribe("vessel", "goal/arm")
    heartbeats = bus.subscribe("vessel", "heartbeat", maxlen=4)
    rate = Rate(cfg.control_period_s, bus.stop)
    every = max(1, round(cfg.telemetry_period_s / cfg.control_period_s))
    position_m_world: np.ndarray | None = None
    tick = 0
    while rate.sleep():
        now_s = time.monotonic()
        for goal in waypoint_goals.drain():
            assert isinstance(goal.message, Waypoints)
            vehicle.set_waypoints(goal.message.command_id, goal.message.waypoints)
        for goal in arm_goals.drain():
            assert isinstance(goal.message, ArmGoal)
            arm.set_goal(goal.message.command_id, goal.message.position_m_world,
                         goal.message.orientation_wxyz_world)
        for beat in heartbeats.drain():
            assert isinstance(beat.message, Heartbeat)
            failsafe.heard(now_s, beat.message)
        for fix in nav.drain():
            assert isinstance(fix.message, NavState)
            position_m_world, orientation_wxyz_world = nav_filter.update(fix.message)
            sim_time_s = fix.message.sim_time_s
        latest_joints = joints.latest()
        if position_m_world is None or latest_joints is None:
            continue
        assert isinstance(latest_joints.message, JointState)
        arm_rad = latest_joints.message.positions_rad
        hold = failsafe.check(now_s, bus.link_down("tether"))
        yaw = yaw_of(orientation_wxyz_world)
        out = vehicle.step(position_m_world, yaw, cfg.control_period_s, hold=bool(hold))
        arm_out = arm.step(position_m_world, orientation_wxyz_world, arm_rad,
                           enabled=not hold and out.mode in ("reached", "idle"))
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
            bus.publish("telemetry", Telemetry(
                position_m_world=position_m_world, yaw_rad=yaw, mode=out.mode, command_id=vehicle.command_id,
                waypoint_index=out.waypoint_index, waypoints_total=out.waypoints_total,
                position_error_m_world=out.position_error_m_world, heading_error_rad=out.heading_error_rad,
                arm_mode=arm_out.mode, arm_command_id=arm.command_id,
                ee_position_error_m_world=arm_out.position_error_m_world,
                ee_orientation_error_rad=arm_out.orientation_error_rad,
                ee_position_m_world=ee_pose.translation,
                ee_orientation_wxyz_world=quat_wxyz_of(ee_pose.rotation),
                arm_positions_rad=arm_rad[:len(ARM_JOINTS)], failsafe=hold,
                failsafe_events=failsafe.events, sim_time_s=sim_time_s))
        tick += 1
