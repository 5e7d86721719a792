"""The onboard vehicle controller as a pure core: the vehicle integrated kinematically."""

from __future__ import annotations

import math

import numpy as np

from abyss.common.config import MissionConfig, OnboardConfig
from abyss.stations.onboard.vehicle_control import VehicleController


def fly(controller: VehicleController, seconds: float,
        dt_s: float = 0.05) -> tuple[list[str], np.ndarray, float]:
    """Modes over time, then the final position [m] and yaw [rad]."""
    position, yaw, modes = np.array([0.0, 0.0, -5.0]), 0.0, []
    for _ in range(round(seconds / dt_s)):
        out = controller.step(position, yaw, dt_s)
        c, s = math.cos(yaw), math.sin(yaw)
        v = out.linear_mps_body
        position = position + dt_s * np.array([c * v[0] - s * v[1], s * v[0] + c * v[1], v[2]])
        yaw = (yaw + dt_s * out.yaw_rate_radps + math.pi) % (2 * math.pi) - math.pi
        assert np.linalg.norm(v) <= controller.gains.max_speed_mps + 1e-9
        modes.append(out.mode)
    return modes, position, yaw


def test_three_waypoints_reached_in_turn() -> None:
    mission = MissionConfig()
    controller = VehicleController(OnboardConfig(), mission)
    assert fly(controller, 1.0)[0][-1] == "idle"
    assert controller.set_waypoints(7, np.array(mission.waypoints))
    assert not controller.set_waypoints(7, np.array(mission.waypoints))  # the same list again
    modes, position, yaw = fly(controller, 60.0)
    assert modes[0] == "moving" and modes[-1] == "reached" and controller.index == 3
    assert np.linalg.norm(position - np.array(mission.waypoints[-1][:3])) < mission.position_tolerance_m
    assert abs(yaw - mission.waypoints[-1][3]) < mission.heading_tolerance_rad


def test_integral_is_bounded_by_the_speed_limit() -> None:
    gains = OnboardConfig()
    controller = VehicleController(gains, MissionConfig())
    controller.set_waypoints(1, np.array([[1000.0, 0.0, -5.0, 0.0]]))
    for _ in range(10_000):  # a long way off: the integral must not wind up past the limit
        controller.step(np.array([0.0, 0.0, -5.0]), 0.0, 0.05)
    assert np.all(np.abs(controller._integral_m_s * gains.ki_position) <= gains.max_speed_mps + 1e-9)
