"""Waypoint following: a proportional law on position (world) and heading, its speed bounded by
a deceleration limit near the waypoint, plus a feed-forward of the steady velocity offset (a
current the low level does not reject, a biased low level) that an observer estimates from the
motion the commands did not explain; acceptance tolerances, a time limit per waypoint and a
reported state.

No integral on the error: the plant from the velocity reference to the position is an
integrator, so a proportional law alone lands on a waypoint. The former PI (kp 0.6, ki 0.05)
had a slow closed-loop pole at about ki/kp (0.08 1/s, the heading's 0.05 1/s) and integrated
the error all the way down every approach below the speed limit: it overshot each waypoint by
5-7 cm and 0.7 deg and crept back over 20-30 s. The observer integrates only what the commands
did not explain, which an approach leaves at nothing."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from abyss.common.geometry import wrap_rad
from abyss.config.stations import OnboardConfig
from abyss.config.system import MissionConfig
from abyss.stations.onboard.modes import Mode

MAX_OFFSET_SHARE = 0.5  # the offset's estimate is kept within this share of the speed limits


@dataclass(frozen=True)
class ControlOutput:
    linear_mps_body: np.ndarray
    yaw_rate_radps: float
    mode: Mode  # missed: a waypoint's time ran out; it is held
    waypoint_index: int  # waypoints reached so far
    waypoints_total: int
    position_error_m_world: np.ndarray
    heading_error_rad: float


class VehicleController:
    """u = v(e) e/|e| - d [m/s, world], v(e) = min(Kp |e|, sqrt(2 a |e|), v_max); r = Kp,psi
    psi_err - d_psi [rad/s]; d: the offset's estimate, from the pose's change against the last
    command, low-passed with `offset_time_constant_s`."""

    def __init__(self, gains: OnboardConfig, mission: MissionConfig) -> None:
        self.gains = gains
        self.mission = mission
        self.waypoints = np.zeros((0, 4))
        self.command_id = -1
        self.index = 0
        self.missed = False  # the waypoint at `index` ran out of time: held, never reached
        self.offset = np.zeros(4)  # x, y, z [m/s, world], yaw [rad/s] the commands do not explain
        self._last: tuple[np.ndarray, np.ndarray] | None = None  # the last pose and command
        self._leg_s = 0.0  # [s] flown towards the waypoint at `index`, holds excluded
        self._leg_limit_s: float | None = None  # set on the leg's first step
        self._hold: np.ndarray | None = None  # x, y, z, yaw held while the failsafe is on

    def set_waypoints(self, command_id: int, waypoints: np.ndarray) -> bool:
        """Take a new list unless it is the one already being flown; True if taken."""
        if command_id == self.command_id:
            return False
        self.command_id, self.waypoints, self.index, self.missed = command_id, np.array(waypoints), 0, False
        self._new_leg()
        return True

    def step(
        self, position_m_world: np.ndarray, yaw_rad: float, dt_s: float, hold: bool = False
    ) -> ControlOutput:
        """One control period; with `hold`, the pose where holding began is held instead."""
        pose = np.r_[position_m_world, yaw_rad]
        self._observe(pose, dt_s)
        total = len(self.waypoints)
        if hold:
            if self._hold is None:
                self._hold = pose
            return self._output(self._hold, pose, Mode.HOLD, min(self.index, total), total)
        self._hold = None
        if total == 0:
            self._last = (pose, np.zeros(4))
            return ControlOutput(np.zeros(3), 0.0, Mode.IDLE, 0, 0, np.zeros(3), 0.0)
        target = self.waypoints[min(self.index, total - 1)]
        if self.index < total and not self.missed:
            if self._leg_limit_s is None:
                self._leg_limit_s = self._limit_s(target, pose)
            if self._within(target, pose):
                self.index += 1
                self._new_leg()
                target = self.waypoints[min(self.index, total - 1)]
            else:
                self._leg_s += dt_s
                self.missed = self._leg_s > self._leg_limit_s
        mode = Mode.MISSED if self.missed else Mode.REACHED if self.index >= total else Mode.MOVING
        return self._output(target, pose, mode, self.index, total)

    def _new_leg(self) -> None:
        self._leg_s, self._leg_limit_s = 0.0, None

    def _limit_s(self, target: np.ndarray, pose: np.ndarray) -> float:
        """The time allowed to the leg from `pose`: flown at the speed limits, plus the margin."""
        if self.mission.waypoint_timeout_s == 0:
            return math.inf
        g = self.gains
        return (
            float(np.linalg.norm(target[:3] - pose[:3])) / g.max_speed_mps
            + abs(wrap_rad(target[3] - pose[3])) / g.max_yaw_rate_radps
            + self.mission.waypoint_timeout_s
        )

    def _within(self, target: np.ndarray, pose: np.ndarray) -> bool:
        return bool(
            np.linalg.norm(target[:3] - pose[:3]) < self.mission.position_tolerance_m
            and abs(wrap_rad(target[3] - pose[3])) < self.mission.heading_tolerance_rad
        )

    def _observe(self, pose: np.ndarray, dt_s: float) -> None:
        """The offset: the pose's change since the last step less what the last command asked
        for, low-passed; nothing without a time constant or a last step."""
        g = self.gains
        if self._last is None or g.offset_time_constant_s == 0:
            return
        last_pose, last_command = self._last
        change = pose - last_pose
        change[3] = wrap_rad(change[3])
        unexplained = change / dt_s - last_command - self.offset
        self.offset = self.offset + dt_s / (g.offset_time_constant_s + dt_s) * unexplained
        self.offset[:3] = _clip_norm(self.offset[:3], MAX_OFFSET_SHARE * g.max_speed_mps)
        self.offset[3] = float(
            np.clip(
                self.offset[3],
                -MAX_OFFSET_SHARE * g.max_yaw_rate_radps,
                MAX_OFFSET_SHARE * g.max_yaw_rate_radps,
            )
        )

    def _output(
        self, target: np.ndarray, pose: np.ndarray, mode: Mode, index: int, total: int
    ) -> ControlOutput:
        """Towards `target` (x, y, z, yaw) from `pose`: the body velocity and yaw rate, and the
        errors; the command (world frame) is kept for the observer."""
        g = self.gains
        error = target[:3] - pose[:3]
        heading_error = wrap_rad(target[3] - pose[3])
        distance = float(np.linalg.norm(error))
        speed = min(g.kp_position * distance, math.sqrt(2.0 * g.max_accel_mps2 * distance), g.max_speed_mps)
        u_world = _clip_norm(
            error * (speed / distance if distance > 0 else 0.0) - self.offset[:3], g.max_speed_mps
        )
        r = float(
            np.clip(
                g.kp_heading * heading_error - self.offset[3], -g.max_yaw_rate_radps, g.max_yaw_rate_radps
            )
        )
        self._last = (pose, np.r_[u_world, r])
        c, s = math.cos(pose[3]), math.sin(pose[3])
        u_body = np.array([c * u_world[0] + s * u_world[1], -s * u_world[0] + c * u_world[1], u_world[2]])
        return ControlOutput(u_body, r, mode, index, total, error, heading_error)


def _clip_norm(vector: np.ndarray, limit: float) -> np.ndarray:
    norm = float(np.linalg.norm(vector))
    return vector * (limit / norm) if norm > limit else vector
