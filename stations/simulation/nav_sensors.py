"""Navigation as a real ROV gets it. A USBL fix about once a second, delivered after the ping's
travel up to the transceiver and the processing, now and then an outlier metres off or none at
all; depth from a pressure sensor; velocity from a DVL, read a little off, and only with bottom
lock (all four beams on the seabed within its altitude range, not on the panel); attitude and
rates from an IMU whose gyro's bias wanders. Each with its own seeded noise; ground truth stays
separate, for scoring only. `Navigation` is MuJoCo-free; `DvlBeams` casts the beams."""

from __future__ import annotations

import math
from dataclasses import dataclass

import mujoco
import numpy as np

from abyss.common.geometry import quat_multiply, small_rotation_wxyz
from abyss.config.simulation import SimulationConfig
from abyss.description.robot_file import NavSensorsSection
from abyss.interface.messages import NavState

SOUND_SPEED_MPS = 1500.0
SEAWATER_PA_PER_M = 1025.0 * 9.81  # hydrostatic pressure per metre of depth [Pa/m]
# where the beams start in the vehicle's frame [m], for a robot whose model has no site of its DVL's
# name (robot.toml's [nav_sensors] dvl): under the work-class ROV's skid
DVL_M_BODY = np.array([0.0, 0.0, -0.7])
DVL_BEAM_RAD = math.radians(30.0)  # each beam off the vertical
SEABED_GEOM = "seabed"


@dataclass(frozen=True)
class Fix:
    position_m_world: np.ndarray
    measured_s: float  # [s] when the ping came back
    delivered_s: float  # [s] when the fix reaches the vehicle


class Navigation:
    def __init__(
        self, config: SimulationConfig, rng: np.random.Generator, sensors: NavSensorsSection
    ) -> None:
        self.config = config
        self.rng = rng
        self.sensors = sensors  # the robot's names of its sensors, as faults target them
        self.scale = dict.fromkeys(
            (sensors.usbl, sensors.depth, sensors.dvl, sensors.imu), 1.0
        )  # faults raise these
        self.gyro_bias_radps = np.zeros(3)
        self.pending: list[Fix] = []  # measured, not delivered yet
        self.latest: Fix | None = None  # the latest delivered
        self._next_fix_s: float | None = None  # when the next ping goes out [s]
        self._time_s: float | None = None

    def measure(self, truth: NavState, bottom_lock: bool) -> NavState:
        """The sensors' readings at the truth's time; call it every control period."""
        c, k, n = self.config, self.scale, self.rng.normal
        now_s = truth.sim_time_s
        dt = 0.0 if self._time_s is None else max(0.0, now_s - self._time_s)
        self._time_s = now_s
        if self._next_fix_s is None or now_s >= self._next_fix_s - 1e-6:  # the clock: a sum of steps
            self._ping(truth)
            period_s = 1.0 / c.usbl_rate_hz
            self._next_fix_s = (
                now_s + period_s if self._next_fix_s is None else max(self._next_fix_s + period_s, now_s)
            )
        for fix in [f for f in self.pending if f.delivered_s <= now_s]:
            self.pending.remove(fix)
            self.latest = fix
        self.gyro_bias_radps = self.gyro_bias_radps + n(0, c.gyro_bias_walk_radps * math.sqrt(dt), 3)
        attitude_error = small_rotation_wxyz(n(0, c.imu_sigma_rad * k[self.sensors.imu], 3))
        orientation = quat_multiply(truth.orientation_wxyz_world, attitude_error)
        pressure_pa = -truth.position_m_world[2] * SEAWATER_PA_PER_M + n(
            0, c.pressure_sigma_pa * k[self.sensors.depth]
        )
        velocity = np.zeros(3)
        if bottom_lock:
            velocity = (
                (1.0 + c.dvl_scale_error) * truth.velocity_mps_body
                + np.array(c.dvl_offset_mps_body)
                + n(0, c.dvl_sigma_mps * k[self.sensors.dvl], 3)
            )
        return NavState(
            position_m_world=np.zeros(3) if self.latest is None else self.latest.position_m_world,
            orientation_wxyz_world=orientation / np.linalg.norm(orientation),
            velocity_mps_body=velocity,
            angular_velocity_radps_body=(
                truth.angular_velocity_radps_body
                + self.gyro_bias_radps
                + n(0, 0.1 * c.imu_sigma_rad * k[self.sensors.imu], 3)
            ),
            sim_time_s=now_s,
            usbl_time_s=-1.0 if self.latest is None else self.latest.measured_s,
            depth_m=float(pressure_pa / SEAWATER_PA_PER_M),
            dvl_valid=bottom_lock,
        )

    def _ping(self, truth: NavState) -> None:
        """A fix taken now, delivered once the reply has travelled and been processed (or lost)."""
        c, n = self.config, self.rng.normal
        if self.rng.random() < c.usbl_dropout_probability:
            return
        position = truth.position_m_world + n(0, c.usbl_sigma_m * self.scale[self.sensors.usbl], 3)
        if self.rng.random() < c.usbl_outlier_probability:
            heading_rad = self.rng.uniform(0.0, 2 * math.pi)
            position = position + c.usbl_outlier_m * np.array(
                [math.cos(heading_rad), math.sin(heading_rad), 0.0]
            )
        slant_m = float(np.linalg.norm(truth.position_m_world - np.array(c.usbl_transceiver_m_world)))
        self.pending.append(
            Fix(
                position, truth.sim_time_s, truth.sim_time_s + slant_m / SOUND_SPEED_MPS + c.usbl_processing_s
            )
        )


class DvlBeams:
    """The DVL's four Janus beams, 30 degrees off the vertical, 45 degrees off the bow, cast
    in MuJoCo from the robot's DVL (its site, where the model has one on the vehicle; else
    DVL_M_BODY): bottom lock when every beam meets the seabed within the altitude range."""

    def __init__(
        self,
        model: mujoco.MjModel,
        vehicle_body: int,
        min_altitude_m: float,
        max_altitude_m: float,
        site: str = "",
    ) -> None:
        self.model = model
        self.vehicle_body = vehicle_body
        site_id = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, site) if site else -1
        on_vehicle = site_id >= 0 and model.site_bodyid[site_id] == vehicle_body
        self.origin_m_body = model.site_pos[site_id].copy() if on_vehicle else DVL_M_BODY
        self.seabed = model.geom(SEABED_GEOM).id
        self.min_altitude_m, self.max_altitude_m = min_altitude_m, max_altitude_m
        s, h = math.sin(DVL_BEAM_RAD) / math.sqrt(2), -math.cos(DVL_BEAM_RAD)
        self.beams_body = np.array([[s, s, h], [s, -s, h], [-s, s, h], [-s, -s, h]])
        self._geom = np.zeros(1, dtype=np.int32)

    def altitudes_m(self, data: mujoco.MjData) -> np.ndarray:
        """Each beam's range times the cosine of its angle [m]; NaN where it meets nothing but
        the seabed within range."""
        m = self.model
        rotation = data.xmat[self.vehicle_body].reshape(3, 3)
        origin = data.xpos[self.vehicle_body] + rotation @ self.origin_m_body
        reach_m = self.max_altitude_m / math.cos(DVL_BEAM_RAD)
        out = np.full(len(self.beams_body), np.nan)
        for i, beam in enumerate(self.beams_body):
            direction = rotation @ beam
            start, travelled_m = origin.copy(), 0.0
            while travelled_m < reach_m:  # through the robot's own parts (the arm), to what lies beyond
                range_m = mujoco.mj_ray(m, data, start, direction, None, 1, self.vehicle_body, self._geom)
                geom = int(self._geom[0])
                if geom < 0:
                    break
                travelled_m += range_m
                if m.body_rootid[m.geom_bodyid[geom]] != self.vehicle_body:
                    if geom == self.seabed and travelled_m <= reach_m:
                        out[i] = travelled_m * math.cos(DVL_BEAM_RAD)
                    break
                start = start + direction * (range_m + 1e-4)
                travelled_m += 1e-4
        return out

    def bottom_lock(self, data: mujoco.MjData) -> bool:
        altitudes_m = self.altitudes_m(data)
        return bool(np.all(np.isfinite(altitudes_m)) and np.all(altitudes_m >= self.min_altitude_m))
