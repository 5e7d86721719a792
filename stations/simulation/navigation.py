"""Navigation as a real ROV gets it: position from a USBL-like acoustic fix, depth from a
pressure sensor, velocity from a DVL, attitude and rates from an IMU, each with its own
seeded Gaussian noise. Ground truth stays separate, for scoring only."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from abyss.common.geometry import quat_multiply, small_rotation_wxyz
from abyss.common.messages import NavState
from abyss.common.models import NAV_SENSORS


@dataclass(frozen=True)
class NoiseSigmas:
    usbl_m: float = 0.05  # horizontal position [m]
    depth_m: float = 0.01  # [m]
    dvl_mps: float = 0.005  # [m/s]
    imu_rad: float = 0.002  # attitude [rad]; rates get a tenth of it per second


class Navigation:
    def __init__(self, sigmas: NoiseSigmas, rng: np.random.Generator) -> None:
        self.sigmas = sigmas
        self.rng = rng
        self.scale = dict.fromkeys(NAV_SENSORS, 1.0)  # faults raise these

    def measure(self, truth: NavState) -> NavState:
        s, k, n = self.sigmas, self.scale, self.rng.normal
        position = truth.position_m_world + np.r_[n(0, s.usbl_m * k["usbl"], 2), n(0, s.depth_m * k["depth"])]
        attitude_error = small_rotation_wxyz(n(0, s.imu_rad * k["imu"], 3))
        orientation = quat_multiply(truth.orientation_wxyz_world, attitude_error)
        return NavState(
            position_m_world=position,
            orientation_wxyz_world=orientation / np.linalg.norm(orientation),
            velocity_mps_body=truth.velocity_mps_body + n(0, s.dvl_mps * k["dvl"], 3),
            angular_velocity_radps_body=(truth.angular_velocity_radps_body
                                         + n(0, 0.1 * s.imu_rad * k["imu"], 3)),
            sim_time_s=truth.sim_time_s,
        )
