"""The simulation station's section of the configuration (`[simulation]`): physics, the low
level, the vehicle's marine model and the current, the navigation sensors, cameras and sonar."""

from __future__ import annotations

import math
import typing
from dataclasses import dataclass
from typing import Literal

from abyss.common.errors import ConfigError
from abyss.config.fields import one_of, positive
from abyss.description.models import PACKAGE_FILES, package_dir, shipped_names

LowLevel = Literal["kinematic", "dynamic"]
LOW_LEVELS: tuple[LowLevel, ...] = typing.get_args(LowLevel)
# optics.WATER_TYPES
Water = Literal["none", "I", "IA", "IB", "II", "III", "1C", "3C", "5C", "7C", "9C"]
WATER_TYPES: tuple[Water, ...] = typing.get_args(Water)
Hydrodynamics = Literal["fossen", "ellipsoid"]
HYDRODYNAMICS: tuple[Hydrodynamics, ...] = typing.get_args(Hydrodynamics)
ArmHydrodynamics = Literal["strips", "ellipsoid", "none"]
ARM_HYDRODYNAMICS: tuple[ArmHydrodynamics, ...] = typing.get_args(ArmHydrodynamics)
CameraSamples = Literal[0, 2, 4, 8]
CAMERA_SAMPLES: tuple[CameraSamples, ...] = typing.get_args(CameraSamples)


@dataclass(frozen=True)
class SimulationConfig:
    low_level: LowLevel = "dynamic"
    physics_step_s: float = 0.002  # [s]
    low_level_period_s: float = 0.01  # [s] the low-level controllers' (and buoyancy's) update
    control_period_s: float = 0.05  # [s] rate of nav output and command intake
    command_timeout_s: float = 0.5  # [s] older commands make the low level hold still
    start_position_m_world: tuple[float, float, float] = (0.0, 0.0, -7.0)
    start_yaw_rad: float = 0.0
    # dynamic low level: PID on surge, sway, heave [N/(m/s)] and yaw rate [N m/(rad/s)]
    # (the damping is fed forward from the marine model; yaw's integral is slow so that the rotors'
    # lag does not wind it up into an overshoot)
    # (): the robot's own, as its package states them or as its masses derive them
    # (description/gains.py: robot_gains); four numbers fly those instead
    vehicle_kp: tuple[float, ...] = ()
    vehicle_ki: tuple[float, ...] = ()
    vehicle_kd: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)
    # the dynamic low level's attitude hold, as a small ROV's autopilot keeps it level (ArduSub's
    # stabilise mode): PD on roll and pitch towards level [N m/rad, N m/(rad/s)] through the
    # thrusters, where they move those axes; 0: roll and pitch left to the hydrostatic restoring
    # moment, which a work-class ROV's weight makes stiff (5 kN m/rad) and a small one's does not
    attitude_kp: tuple[float, float] = (0.0, 0.0)
    attitude_kd: tuple[float, float] = (0.0, 0.0)
    arm_kp: float = 400.0  # [N m/(rad/s)]
    arm_ki: float = 200.0
    gripper_kp: float = 1000.0  # [N/(m/s)]
    # the vehicle's marine model: "fossen" (the robot's marine model, description/marine.py) or "ellipsoid"
    # (MuJoCo's fluid model of its hull's geoms); the robot package also describes its thrusters
    hydrodynamics: Hydrodynamics = "fossen"
    # the arm's (and gripper's) marine model: "strips" (strip theory per link, the testbed's own:
    # stations/simulation/strips.py), "ellipsoid" (MuJoCo's fluid model of their geoms, slower) or
    # "none" (their buoyancy alone, no drag: what `abyss robot check` measures the vehicle's model by)
    arm_hydrodynamics: ArmHydrodynamics = "strips"
    # the robot package (a directory with robot.toml and its model: description/robot.py) every station
    # learns the robot's names, frames and limits from; "" is the shipped work-class ROV
    # (description/models/robots/workclass)
    robot: str = ""
    # the work site package (a directory with site.toml: description/site.py): the seabed, the panel and
    # its parts; "" is the shipped valve panel (description/models/sites/valve_panel)
    site: str = ""
    # the current: a profile of rows (z [m, world], vx, vy, vz [m/s, world]), linear in between and
    # held beyond its ends, plus a first-order Gauss-Markov process on each horizontal component
    current_profile: tuple[tuple[float, float, float, float], ...] = ()
    current_sigma_mps: float = 0.0  # [m/s] the process's standard deviation
    current_time_constant_s: float = 60.0  # [s] its correlation time
    usbl_sigma_m: float = 0.02  # [m] a short-range USBL: 0.2 % of a 10 m slant range
    dvl_sigma_mps: float = 0.005
    imu_sigma_rad: float = 0.002
    # navigation sensors as real ones are (stations/simulation/nav_sensors.py)
    pressure_sigma_pa: float = 100.0  # the depth sensor's noise [Pa]: 1 cm of sea water
    usbl_rate_hz: float = 1.0  # fixes taken [Hz]
    usbl_processing_s: float = 0.3  # [s] a fix is delivered this long after its ping came back
    usbl_transceiver_m_world: tuple[float, float, float] = (0.0, 0.0, 0.0)  # on the vessel, at the surface
    usbl_outlier_probability: float = 0.02  # a fix this often lands usbl_outlier_m off
    usbl_outlier_m: float = 3.0  # [m]
    usbl_dropout_probability: float = 0.05  # a fix this often never comes
    dvl_min_altitude_m: float = 0.3  # [m] bottom lock needs the seabed this far below
    dvl_max_altitude_m: float = 30.0  # [m] ... and no farther
    dvl_scale_error: float = 0.002  # velocity reads this fraction too high
    dvl_offset_mps_body: tuple[float, float, float] = (0.0005, -0.0005, 0.0)  # [m/s] and is this off
    gyro_bias_walk_radps: float = 1e-5  # [rad/s per sqrt(s)] the gyro's bias random walk
    camera_rate_hz: float = 1.0  # 0: no cameras
    camera_width_px: int = 640
    camera_height_px: int = 480
    jpeg_quality: int = 90
    # the render's samples per pixel (multisampling: an edge's pixel mixes both sides, as a
    # sensor's pixel integrates its area); 0: one, at about half the render's CPU on a software
    # rasteriser, edges aliased (docs/performance.md has what it moves)
    camera_samples: CameraSamples = 4
    # underwater optics on the RGB frames (stations/simulation/optics.py): a Jerlov water type
    # (WATER_TYPES, clearest first), or "none" for the plain render in MuJoCo's fog; marine snow
    # is a multiple of the water type's own (0: none)
    water: Water = "none"
    marine_snow: float = 1.0
    sonar_rate_hz: float = 2.0  # the imaging sonar's frames (stations/simulation/sonar.py); 0: none
    # [s] on simulated time, a frame (camera or sonar) leaves the sensor this long after it was
    # taken: a camera's exposure, readout and encoding, and the render's, which run meanwhile
    # (docs/time.md, Bulk work); in real time it leaves when rendered. Below each sensor's period.
    sensor_latency_s: float = 0.2
    # where the physics state is kept (every state_period_s) and resumed from at start, so that
    # a restarted simulation goes on where the vehicle was; "" keeps none (`abyss up` sets it)
    state_file: str = ""
    state_period_s: float = 0.5
    # in real time, the station's threads at this SCHED_FIFO priority (1-99) where the system
    # allows it, so that the physics keeps its deadlines on a loaded machine (common.workers.Realtime);
    # 0: the normal scheduler
    realtime_priority: int = 10

    def __post_init__(self) -> None:
        one_of("simulation.low_level", self.low_level, LOW_LEVELS)
        positive("simulation.physics_step_s", self.physics_step_s)
        positive("simulation.current_time_constant_s", self.current_time_constant_s)
        for name in ("attitude_kp", "attitude_kd"):
            for gain in getattr(self, name):
                positive(f"simulation.{name}", gain, allow_zero=True)
        for kind in (
            "robot",
            "site",
        ):  # the stations run in the run directory: the path is the user's shell's
            value = getattr(self, kind)
            if value:
                directory = package_dir(kind, value)
                if not (directory / PACKAGE_FILES[kind]).is_file():
                    raise ConfigError(
                        f"simulation.{kind}",
                        f"{directory.resolve()}: not a {kind} package (a directory with "
                        f"{PACKAGE_FILES[kind]}), nor a shipped one's name: {', '.join(shipped_names(kind))}",
                    )
                object.__setattr__(self, kind, str(directory.resolve()))
        one_of("simulation.hydrodynamics", self.hydrodynamics, HYDRODYNAMICS)
        one_of("simulation.arm_hydrodynamics", self.arm_hydrodynamics, ARM_HYDRODYNAMICS)
        for row in self.current_profile:
            if len(row) != 4 or not all(math.isfinite(v) and abs(v) < 1e4 for v in row):
                raise ConfigError("simulation.current_profile", f"{list(row)}: rows of [z_m, vx, vy, vz]")
        positive("simulation.state_period_s", self.state_period_s)
        if not 0 <= self.realtime_priority <= 99:
            raise ConfigError(
                "simulation.realtime_priority",
                f"{self.realtime_priority}: 0 (the normal scheduler) or a SCHED_FIFO priority from 1 to 99",
            )
        positive("simulation.arm_kp", self.arm_kp)
        positive("simulation.gripper_kp", self.gripper_kp)
        for name in ("vehicle_kp", "vehicle_ki", "vehicle_kd"):
            if name != "vehicle_kd" and len(getattr(self, name)) not in (0, 4):
                raise ConfigError(
                    f"simulation.{name}", "four numbers: surge, sway, heave, yaw (or none: the robot's)"
                )
            for value in getattr(self, name):
                positive(f"simulation.{name}", value, allow_zero=True)
        self._check_sensors()
        self._check_periods()

    def _check_sensors(self) -> None:
        """The navigation sensors', cameras' and sonar's fields."""
        for name in (
            "arm_ki",
            "current_sigma_mps",
            "usbl_sigma_m",
            "dvl_sigma_mps",
            "imu_sigma_rad",
            "camera_rate_hz",
            "sonar_rate_hz",
            "pressure_sigma_pa",
            "usbl_processing_s",
            "usbl_outlier_m",
            "dvl_min_altitude_m",
            "dvl_scale_error",
            "gyro_bias_walk_radps",
        ):
            positive(f"simulation.{name}", getattr(self, name), allow_zero=True)
        positive("simulation.usbl_rate_hz", self.usbl_rate_hz)
        for name in ("usbl_outlier_probability", "usbl_dropout_probability"):
            if not 0.0 <= getattr(self, name) < 1.0:
                raise ConfigError(f"simulation.{name}", f"{getattr(self, name)} outside [0, 1)")
        if not self.dvl_min_altitude_m < self.dvl_max_altitude_m:
            raise ConfigError(
                "simulation.dvl_max_altitude_m",
                f"{self.dvl_max_altitude_m} m must lie above "
                f"dvl_min_altitude_m = {self.dvl_min_altitude_m} m",
            )
        if any(abs(v) > 1.0 for v in self.dvl_offset_mps_body):
            raise ConfigError("simulation.dvl_offset_mps_body", "each within [-1, 1] m/s")
        if not (16 <= self.camera_width_px <= 4096 and 16 <= self.camera_height_px <= 4096):
            raise ConfigError("simulation.camera_width_px", "camera size must lie in [16, 4096] px")
        if not 1 <= self.jpeg_quality <= 100:
            raise ConfigError("simulation.jpeg_quality", f"{self.jpeg_quality} outside [1, 100]")
        one_of("simulation.water", self.water, WATER_TYPES)
        one_of("simulation.camera_samples", self.camera_samples, CAMERA_SAMPLES)
        positive("simulation.marine_snow", self.marine_snow, allow_zero=True)
        positive("simulation.sensor_latency_s", self.sensor_latency_s, allow_zero=True)
        for name in ("camera_rate_hz", "sonar_rate_hz"):
            rate_hz = getattr(self, name)
            if rate_hz > 0 and self.sensor_latency_s * rate_hz >= 1.0:
                raise ConfigError(
                    "simulation.sensor_latency_s",
                    f"{self.sensor_latency_s} s must stay below the period of {name} = {rate_hz} "
                    f"({1.0 / rate_hz:g} s): a frame leaves before the next is taken",
                )

    def _check_periods(self) -> None:
        """Each period a whole multiple of the one below it: a control period of the low level's,
        both of the physics step."""
        for name, period, base, base_name in (
            ("low_level_period_s", self.low_level_period_s, self.physics_step_s, "physics_step_s"),
            ("control_period_s", self.control_period_s, self.physics_step_s, "physics_step_s"),
            ("control_period_s", self.control_period_s, self.low_level_period_s, "low_level_period_s"),
        ):
            ratio = period / base
            if ratio < 1 - 1e-9 or not math.isclose(ratio, round(ratio), rel_tol=0, abs_tol=1e-9):
                raise ConfigError(
                    f"simulation.{name}", f"{period} s is not a whole multiple of {base_name} = {base} s"
                )
