"""Waypoint following: PI on position and PI on heading (the paper's vehicle controller),
with anti-windup, acceptance tolerances and a reported state."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from abyss.common.config import MissionConfig, OnboardConfig
from abyss.common.geometry import wrap_rad


@dataclass(frozen=True)
class ControlOutput:
    linear_mps_body: np.ndarray
    yaw_rate_radps: float
    mode: str  # idle | moving | reached | hold
    waypoint_index: int  # waypoints reached so far
    waypoints_total: int
    position_error_m_world: np.ndarray
    heading_error_rad: float


class VehicleController:
    """u = Kp e + Ki int(e) [m/s, world]; r = Kp,psi psi_err + Ki,psi int(psi_err) [rad/s]."""

    def __init__(self, gains: OnboardConfig, mission: MissionConfig) -> None:
        self.gains = gains
        self.mission = mission
        self.waypoints = np.zeros((0, 4))
        self.command_id = -1
        self.index = 0
        self._integral_m_s = np.zeros(3)
        self._integral_rad_s = 0.0
        self._hold: np.ndarray | None = None  # x, y, z, yaw held while the failsafe is on

    def set_waypoints(self, command_id: int, waypoints: np.ndarray) -> bool:
        """Take a new list unless it is the one already being flown; True if taken."""
        if command_id == self.command_id:
            return False
        self.command_id, self.waypoints, self.index = command_id, np.array(waypoints), 0
        self._reset_integrals()
        return True

    def step(self, position_m_world: np.ndarray, yaw_rad: float, dt_s: float,
             hold: bool = False) -> ControlOutput:
        """One control period; with `hold`, the pose where holding began is held instead."""
        total = len(self.waypoints)
        if hold:
            if self._hold is None:
                self._hold = np.r_[position_m_world, yaw_rad]
                self._reset_integrals()
            linear, r, error, heading_error = self._track(self._hold, position_m_world, yaw_rad, dt_s)
            return ControlOutput(linear, r, "hold", min(self.index, total), total, error, heading_error)
        if self._hold is not None:
            self._hold = None
            self._reset_integrals()
        if total == 0:
            return ControlOutput(np.zeros(3), 0.0, "idle", 0, 0, np.zeros(3), 0.0)
        target = self.waypoints[min(self.index, total - 1)]
        error = target[:3] - position_m_world
        if (self.index < total and np.linalg.norm(error) < self.mission.position_tolerance_m
                and abs(wrap_rad(target[3] - yaw_rad)) < self.mission.heading_tolerance_rad):
            self.index += 1
            self._reset_integrals()
            target = self.waypoints[min(self.index, total - 1)]
        linear, r, error, heading_error = self._track(target, position_m_world, yaw_rad, dt_s)
        mode = "reached" if self.index >= total else "moving"
        return ControlOutput(linear, r, mode, self.index, total, error, heading_error)

    def _reset_integrals(self) -> None:
        self._integral_m_s[:], self._integral_rad_s = 0.0, 0.0

    def _track(self, target: np.ndarray, position_m_world: np.ndarray, yaw_rad: float,
               dt_s: float) -> tuple[np.ndarray, float, np.ndarray, float]:
        """PI towards `target` (x, y, z, yaw): body velocity, yaw rate, errors."""
        g = self.gains
        error = target[:3] - position_m_world
        heading_error = wrap_rad(target[3] - yaw_rad)
        # anti-windup by conditional integration: the integral grows only while the command is
        # not saturated (or while the error would shrink it), so a long leg flown at full speed
        # winds nothing up to overshoot with
        u_world = g.kp_position * error + g.ki_position * self._integral_m_s
        if float(np.linalg.norm(u_world)) < g.max_speed_mps or float(error @ self._integral_m_s) < 0:
            self._integral_m_s = self._integral_m_s + error * dt_s
            u_world = g.kp_position * error + g.ki_position * self._integral_m_s
        speed = float(np.linalg.norm(u_world))
        if speed > g.max_speed_mps:
            u_world *= g.max_speed_mps / speed
        r = g.kp_heading * heading_error + g.ki_heading * self._integral_rad_s
        if abs(r) < g.max_yaw_rate_radps or heading_error * self._integral_rad_s < 0:
            self._integral_rad_s += heading_error * dt_s
            r = g.kp_heading * heading_error + g.ki_heading * self._integral_rad_s
        r = float(np.clip(r, -g.max_yaw_rate_radps, g.max_yaw_rate_radps))
        c, s = math.cos(yaw_rad), math.sin(yaw_rad)
        u_body = np.array([c * u_world[0] + s * u_world[1], -s * u_world[0] + c * u_world[1], u_world[2]])
        return u_body, r, error, heading_error
