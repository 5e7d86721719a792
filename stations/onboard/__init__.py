"""The onboard station: high-level vehicle control close to the vehicle; telemetry up."""

from __future__ import annotations

import numpy as np

from common.bus import Bus, Inbox
from common.config import Config
from common.geometry import yaw_of
from common.messages import JointState, NavState, Telemetry, VelocityRef, Waypoints
from common.rate import Rate
from stations.onboard.vehicle_control import VehicleController


def arm_positions(joints: Inbox) -> np.ndarray:
    latest = joints.latest()
    return latest.message.positions_rad if latest and isinstance(latest.message, JointState) else np.zeros(6)


def run(config: Config, bus: Bus) -> None:
    cfg = config.onboard
    controller = VehicleController(cfg, config.mission)
    nav = bus.subscribe("simulation", "nav", maxlen=4)
    goals = bus.subscribe("vessel", "goal/waypoints")
    joints = bus.subscribe("simulation", "joints", maxlen=4)
    rate = Rate(cfg.control_period_s, bus.stop)
    every = max(1, round(cfg.telemetry_period_s / cfg.control_period_s))
    tick = 0
    while rate.sleep():
        for goal in goals.drain():
            assert isinstance(goal.message, Waypoints)
            controller.set_waypoints(goal.message.command_id, goal.message.waypoints)
        latest = nav.latest()
        if latest is None:
            continue
        state = latest.message
        assert isinstance(state, NavState)
        yaw = yaw_of(state.orientation_wxyz_world)
        out = controller.step(state.position_m_world, yaw, cfg.control_period_s)
        bus.publish("cmd/vehicle_velocity", VelocityRef(out.linear_mps_body, out.yaw_rate_radps))
        if tick % every == 0:
            bus.publish("telemetry", Telemetry(
                position_m_world=state.position_m_world, yaw_rad=yaw, mode=out.mode,
                command_id=controller.command_id, waypoint_index=out.waypoint_index,
                waypoints_total=out.waypoints_total,
                position_error_m=float(np.linalg.norm(out.position_error_m_world)),
                heading_error_rad=out.heading_error_rad, arm_positions_rad=arm_positions(joints),
                sim_time_s=state.sim_time_s))
        tick += 1
